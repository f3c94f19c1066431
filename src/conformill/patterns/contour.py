"""Contour-parallel rings on the circle domain (METHOD section 5).

The first path is the centre point, the next radius is ``rho + min(drho)``, the last ring
is the boundary. Consecutive rings are linked by a short radial move at ``theta = 0``
(cut at feed, on the surface): no retract between rings.
"""

from __future__ import annotations

from conformill.patterns.domains import Rings, Segment
from conformill.patterns.pieces import PieceStream, domain_paths
from conformill.patterns.warp import build_warp


def plan_rings(planner, poly, delta: float, progress=None, adaptive: bool = True, local: bool = False,
               on_curve=None):
    """The ring levels and curves of the contour family.

    With ``adaptive`` the rings bend to follow the local step
    (:mod:`conformill.patterns.warp`) and their ``s`` are levels in [0, 1]; without, they
    are the paper's circles ``rho = s`` up to ``R0``. With ``local`` too, the rings dent
    locally instead of taking the minimum step (:meth:`Planner.run_local`).
    ``on_curve`` is handed to the planner (each ring as soon as it is planned).
    """
    fam = Rings(poly, delta)
    if not adaptive:
        return fam, planner.run(fam, 0.0, poly.R0, progress=progress, on_curve=on_curve)
    fam = Rings(poly, delta, warp=build_warp(planner, fam, 0.0, fam.end))
    run = planner.run_local if local else planner.run
    return fam, run(fam, 0.0, 1.0, progress=progress, on_curve=on_curve)


def plan_contour(planner, poly, delta: float, progress=None, adaptive: bool = True, local: bool = False,
                 emit=None):
    """Plan contour-parallel rings, centre outwards.

    ``emit(piece)``, if given, is called with each piece as soon as it is final, in
    machining order (a ring once the next one is planned, with the link between them).

    Returns
    -------
    domain : conformill.types.DomainPaths
    """
    def link(i, a, b):
        return planner.evaluate(Segment(a.sample.uv[-1], b.sample.uv[0], delta, clip=poly.clip), 0.0)

    stream = PieceStream(emit, link)
    fam, (curves, realised, predicted, shrinks) = plan_rings(planner, poly, delta, progress, adaptive, local,
                                                             on_curve=stream.on_curve)
    stream.close()
    return domain_paths("contour", curves, realised, predicted, shrinks, closed=True)
