"""Contour-parallel rings on the circle domain (METHOD section 5).

The first path is the centre point, the next radius is ``rho + min(drho)``, the last ring
is the boundary. Consecutive rings are linked by a short radial move at ``theta = 0``
(cut at feed, on the surface): no retract between rings.
"""

from __future__ import annotations

from conformill.patterns.domains import Rings, Segment
from conformill.patterns.pieces import Piece, domain_paths
from conformill.patterns.warp import build_warp


def plan_rings(planner, poly, delta: float, progress=None, adaptive: bool = True, local: bool = False):
    """The ring levels and curves of the contour family.

    With ``adaptive`` the rings bend to follow the local step
    (:mod:`conformill.patterns.warp`) and their ``s`` are levels in [0, 1]; without, they
    are the paper's circles ``rho = s`` up to ``R0``. With ``local`` too, the rings dent
    locally instead of taking the minimum step (:meth:`Planner.run_local`).
    """
    fam = Rings(poly, delta)
    if not adaptive:
        return fam, planner.run(fam, 0.0, poly.R0, progress=progress)
    fam = Rings(poly, delta, warp=build_warp(planner, fam, 0.0, fam.end))
    run = planner.run_local if local else planner.run
    return fam, run(fam, 0.0, 1.0, progress=progress)


def plan_contour(planner, poly, delta: float, progress=None, adaptive: bool = True, local: bool = False):
    """Plan contour-parallel rings, centre outwards.

    Returns
    -------
    domain : conformill.types.DomainPaths
    pieces : list of Piece
    """
    fam, (curves, realised, predicted, shrinks) = plan_rings(planner, poly, delta, progress, adaptive, local)
    pieces = []
    for i, c in enumerate(curves):
        pieces.append(Piece("path", c, False, i))
        if i + 1 < len(curves):
            p0 = c.sample.uv[-1]
            p1 = curves[i + 1].sample.uv[0]
            link = Segment(p0, p1, delta, clip=poly.clip)
            pieces.append(Piece("link", planner.evaluate(link, 0.0), False, i))
    return domain_paths("contour", curves, realised, predicted, shrinks, closed=True), pieces
