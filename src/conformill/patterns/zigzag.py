"""Direction-parallel (zigzag) paths on the rectangle domain (METHOD section 5).

Iso-u lines walked in v, the first on ``u = 0`` and the last on ``u = X``; consecutive
lines are linked alternately along the domain sides ``v = Y`` and ``v = 0``, which map to
the part's boundary, so a link stays on the surface.
"""

from __future__ import annotations

import numpy as np

from conformill.patterns.domains import IsoU, Segment
from conformill.patterns.pieces import PieceStream, domain_paths
from conformill.patterns.warp import build_warp


def plan_zigzag(planner, X: float, Y: float, delta: float, progress=None, adaptive: bool = True,
                local: bool = False, emit=None):
    """Plan zigzag paths.

    Parameters
    ----------
    planner : conformill.patterns.family.Planner
    X, Y : float
        Rectangle domain size.
    delta : float
        Initial domain sampling step.
    adaptive : bool
        Rows bend to follow the local step (:mod:`conformill.patterns.warp`); False gives
        the paper's iso-u lines spaced by the minimum step over each line.
    local : bool
        With ``adaptive``, rows also dent locally instead of taking the minimum step
        (:meth:`conformill.patterns.family.Planner.run_local`).
    emit : callable, optional
        ``emit(piece)`` with each piece as soon as it is final, in machining order (a row
        once the next one is planned, with the link between them).

    Returns
    -------
    domain : conformill.types.DomainPaths
    """
    fam, s_end = IsoU(Y, delta), X
    if adaptive:
        fam = IsoU(Y, delta, warp=build_warp(planner, fam, 0.0, lambda tau: np.full(np.shape(tau), float(X))))
        s_end = 1.0
    run = planner.run_local if adaptive and local else planner.run

    def link(i, a, b):
        end = 0 if i % 2 == 1 else -1  # along the side v = 0 or v = Y
        return planner.evaluate(Segment(a.sample.uv[end], b.sample.uv[end], delta), 0.0)

    stream = PieceStream(emit, link, reverse=lambda i: i % 2 == 1)
    curves, realised, predicted, shrinks = run(fam, 0.0, s_end, progress=progress, on_curve=stream.on_curve)
    stream.close()
    return domain_paths("zigzag", curves, realised, predicted, shrinks, closed=False)
