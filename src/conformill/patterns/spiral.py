"""One continuous spiral on the circle domain (METHOD section 5).

Between consecutive rings ``rho_k < rho_{k+1}`` of the contour plan,
``rho(theta) = rho_k + theta / (2 pi) (rho_{k+1} - rho_k)``; the revolutions are chained
and end with one turn on the boundary. Because a revolution lies between two rings, the
gap between consecutive revolutions is checked in 3D like the rings' were; where it is
too wide a ring is inserted halfway and the spiral rebuilt.
"""

from __future__ import annotations

import numpy as np

from conformill.patterns.contour import plan_rings
from conformill.patterns.domains import Rings, SpiralTurn
from conformill.patterns.family import pair_distances
from conformill.patterns.pieces import Piece, domain_paths


def _turns(planner, poly, radii, delta):
    turns = [planner.evaluate(SpiralTurn(poly, radii[k], radii[k + 1], delta), radii[k]) for k in range(len(radii) - 1)]
    turns.append(planner.evaluate(Rings(poly, delta), radii[-1]))  # the boundary turn
    return turns


def plan_spiral(planner, poly, delta: float, progress=None, max_rounds: int = 4):
    """Plan a single spiral pass from the centre to the boundary.

    Returns
    -------
    domain : conformill.types.DomainPaths
    pieces : list of Piece
        One path per revolution, with no links: each revolution starts where the last ended.
    """
    _, (rings, _, _, shrinks) = plan_rings(planner, poly, delta, progress)
    radii = np.array([c.s for c in rings])
    for _ in range(max_rounds):
        turns = _turns(planner, poly, radii, delta)
        realised, predicted, bad = [], [], set()
        for k in range(len(turns) - 1):
            a, b = turns[k], turns[k + 1]
            d_fwd, ratio = pair_distances(a, b)
            realised.append(d_fwd)
            step = np.interp(a.tau, [0.0, 1.0], [radii[min(k + 1, len(radii) - 1)] - radii[k],
                                                  radii[min(k + 2, len(radii) - 1)] - radii[min(k + 1, len(radii) - 1)]])
            predicted.append(a.sample.area_factor() / a.sample.length(a.t) * step)
            if ratio > 1.0 + 1e-9:
                bad.update({k, k + 1})
        if not bad:
            break
        new = [0.5 * (radii[k] + radii[k + 1]) for k in sorted(bad) if k + 1 < len(radii)]
        shrinks += len(new)
        radii = np.unique(np.concatenate([radii, new]))
    pieces = [Piece("path", t, False, i) for i, t in enumerate(turns)]
    return domain_paths("spiral", turns, realised, predicted, shrinks, closed=False), pieces
