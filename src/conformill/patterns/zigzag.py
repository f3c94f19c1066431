"""Direction-parallel (zigzag) paths on the rectangle domain (METHOD section 5).

Iso-u lines walked in v, the first on ``u = 0`` and the last on ``u = X``; consecutive
lines are linked alternately along the domain sides ``v = Y`` and ``v = 0``, which map to
the part's boundary, so a link stays on the surface.
"""

from __future__ import annotations

from conformill.patterns.domains import IsoU, Segment
from conformill.patterns.pieces import Piece, domain_paths


def plan_zigzag(planner, X: float, Y: float, delta: float, progress=None):
    """Plan zigzag paths.

    Parameters
    ----------
    planner : conformill.patterns.family.Planner
    X, Y : float
        Rectangle domain size.
    delta : float
        Initial domain sampling step.

    Returns
    -------
    domain : conformill.types.DomainPaths
    pieces : list of Piece
    """
    fam = IsoU(Y, delta)
    curves, realised, predicted, shrinks = planner.run(fam, 0.0, X, progress=progress)
    pieces = []
    for i, c in enumerate(curves):
        rev = i % 2 == 1
        pieces.append(Piece("path", c, rev, i))
        if i + 1 < len(curves):
            v = 0.0 if rev else Y
            link = Segment((c.s, v), (curves[i + 1].s, v), delta)
            pieces.append(Piece("link", planner.evaluate(link, 0.0), False, i))
    return domain_paths("zigzag", curves, realised, predicted, shrinks, closed=False), pieces
