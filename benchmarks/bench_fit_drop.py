"""The side step's curvature read from dropped balls instead of the 1-ring fit (issue 5, session 52).

Session 51 proposed reading the spacing from the drop surface D (the ball centres' height
field): where the part has a convex facet edge, D is a cylinder of radius r and two passes
straddling the edge leave the flat scallop, while the 1-ring fit reads a large convex
curvature there and the adaptive rule's minimum makes every row that crosses it dense.
This script measures that idea with the planner unchanged: the per-vertex second
fundamental form ``L, M, N`` of :func:`conformill.geometry.differential.surface_frame` is
replaced, for this process, by one read from balls.

At each vertex ``p`` (fitted normal ``n``, unit tangent ``e1`` along ``r_u``, ``e2 = n x
e1``) and each of three tangent directions ``t`` (0, 60, 120 degrees from ``e1``): the balls
aimed at ``p + r n`` and ``p +- (w / 2) t + r n`` are dropped onto the mesh (centres ``C0``,
``A``, ``B``), and ``s`` is the height along ``n`` of the two side spheres' cusp over the
lowest point of the middle ball, ``C0 - r n``. Then, by mode:

* ``d2``: D's own curvature at the step's scale, ``1/r - 8 s / |AB|^2`` (convex D positive:
  on a sphere of radius R it reads ``1 / (R + r)``), printed only (``--check``);
* ``cc``: the part's curvature in the planner's sign (> 0 concave), ``1/r - 8 s / w_s^2``
  with ``w_s`` the distance between the two side balls' contact points (the planner spaces
  CC points), 0 where ``w_s < 0.3 w`` (both balls on one ridge: the flat scallop), at most
  ``1/r``; and the final reading per direction is the larger (the wider step) of it and
  the 1-ring's (``--combine max``, so that it only relaxes the fit's convex readings) or the
  smaller (``--combine min``: it only tightens them).

The three directions give the quadratic form; vertices whose middle ball the drop lifts by
more than ``--lift-max`` h (undercuts, creases: the ball is not where it was aimed) keep the
1-ring's form. ``w`` is ``--wfrac`` times the flat side interval. Each plan is verified as
``bench_raster.py`` verifies (400k samples, seed 0, reachable p99.9, limit 1.05 h).

``--check`` first prints, on a sphere cap of radius 50 mm (:func:`conformill.mesh.synthetic.sphere_cap`,
0.24 mm spacing, no
plan), the median readings against their exact values: how well each reading is
conditioned on a mesh finer than the step.

    python benchmarks/bench_fit_drop.py [MESH] [--pattern zigzag] [--scan] [--wfrac 0.8]
        [--lift-max 2] [--combine max|min] [--spacing adaptive|local] [--check] [--samples 400000]

Session 52 (igea, zigzag ``--scan``, w = 0.45 mm): the 1-ring 132.3 m at 1.039 h; the
balls (read at 41094 of 77981 vertices) 123.7 m at 1.232 h: 7 % shorter, far beyond the
limit. On the sphere cap ``d2`` reads 0.0205 / mm where 0.0185 is exact (the scallop about
0.918 of the flat one against 0.926), but ``cc`` reads -0.0002 where -0.02 is exact: the
contact points snap to the facets (their spacing, from the two medians, about 0.958 w against 0.926 w), and the part's
curvature, a small difference of two large numbers, cannot be read back through them.
With ``--combine min`` under local spacing (igea contour ``--scan``, whose local program
leaves 1.062 h at 112.5 m) the balls tighten almost nothing (the fit's p1 / p10 readings
-0.55 / -0.21 / mm become -0.56 / -0.21) and the program leaves 1.076 h at 112.5 m: the
balls do not find the spots where local spacing fails either.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402

from conformill.folds import _contacts  # noqa: E402  (the contact point of each drop)

_ANGLES = np.radians([0.0, 60.0, 120.0])


def _dropped(cutter, C):
    """Centres ``C`` lowered onto the drop surface and their contact points."""
    x, y = np.ascontiguousarray(C[:, 0]), np.ascontiguousarray(C[:, 1])
    z, tri = cutter._drop(np.column_stack([x, y]), np.full(len(C), -np.inf))
    return np.column_stack([x, y, z]), _contacts(x, y, z, tri, cutter._T)


def ball_readings(cutter, V, fr, w: float):
    """Per direction of :data:`_ANGLES` and vertex: ``(d2, cc, lift)`` (module notes); NaN
    where a ball touches nothing."""
    r = cutter.radius
    n = fr.n
    e1 = fr.ru / np.linalg.norm(fr.ru, axis=1, keepdims=True)
    e2 = np.cross(n, e1)
    ok = np.isfinite(n).all(1) & np.isfinite(e1).all(1)
    P = np.where(ok[:, None], V, 0.0)
    n = np.where(ok[:, None], n, [0.0, 0.0, 1.0])
    C0, _ = _dropped(cutter, P + r * n)
    lift = C0[:, 2] - (P + r * n)[:, 2]
    bottom = C0 - r * n
    d2, cc = [], []
    for th in _ANGLES:
        t = np.cos(th) * e1 + np.sin(th) * e2
        A, qa = _dropped(cutter, P + 0.5 * w * t + r * n)
        B, qb = _dropped(cutter, P - 0.5 * w * t + r * n)
        with np.errstate(all="ignore"):
            L = np.linalg.norm(B - A, axis=1)
            u = (B - A) / L[:, None]
            m = n - np.einsum("ij,ij->i", n, u)[:, None] * u
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            cusp = 0.5 * (A + B) - np.sqrt(np.maximum(r * r - 0.25 * L * L, 0.0))[:, None] * m
            s = np.maximum(np.einsum("ij,ij->i", cusp - bottom, n), 0.0)
            ws = np.linalg.norm(qa - qb, axis=1)
            d2.append(np.where(L < 2 * r, 1.0 / r - 8.0 * s / (L * L), np.nan))
            k = np.minimum(1.0 / r - 8.0 * s / (ws * ws), 1.0 / r)
            cc.append(np.where(ws < 0.3 * w, 0.0, k))
    bad = ~ok
    d2, cc = np.array(d2), np.array(cc)
    d2[:, bad] = np.nan
    cc[:, bad] = np.nan
    return d2, cc, np.where(ok, lift, np.inf)


def _forms_in_basis(fr, e1, e2):
    """The fit's second fundamental form in the orthonormal basis ``(e1, e2)``: ``(a, b, c)``
    with ``kappa(theta) = a cos^2 + 2 b cos sin + c sin^2``, and ``(|r_u|, r_v.e1, r_v.e2)``."""
    ru = np.linalg.norm(fr.ru, axis=1)
    p1 = np.einsum("ij,ij->i", fr.rv, e1)
    p2 = np.einsum("ij,ij->i", fr.rv, e2)
    with np.errstate(all="ignore"):
        a = fr.L / ru ** 2
        b = (fr.M / ru - a * p1) / p2
        c = (fr.N - a * p1 ** 2 - 2.0 * b * p1 * p2) / p2 ** 2
    return (a, b, c), (ru, p1, p2)


def drop_frame(frame_fn, cutter, w: float, lift_max: float, stats: dict, combine: str = "max"):
    """A ``surface_frame`` that reads ``L, M, N`` from balls (mode ``cc``) where the middle
    ball lands within ``lift_max`` mm of where it was aimed, combined per direction with the
    fit's reading: ``max`` (the wider step of the two) or ``min`` (the narrower)."""
    from conformill.types import SurfaceFrame

    def frame(V, F, uv):
        fr = frame_fn(V, F, uv)
        t0 = time.perf_counter()
        _, cc, lift = ball_readings(cutter, V, fr, w)
        e1 = fr.ru / np.linalg.norm(fr.ru, axis=1, keepdims=True)
        (a, b, c), (ru, p1, p2) = _forms_in_basis(fr, e1, np.cross(fr.n, e1))
        own = np.array([a * np.cos(t) ** 2 + 2 * b * np.cos(t) * np.sin(t) + c * np.sin(t) ** 2 for t in _ANGLES])
        K = np.fmax(cc, own) if combine == "max" else np.fmin(cc, own)
        M3 = np.array([[np.cos(t) ** 2, 2 * np.cos(t) * np.sin(t), np.sin(t) ** 2] for t in _ANGLES])
        a2, b2, c2 = np.linalg.solve(M3, np.nan_to_num(K))
        use = np.isfinite(K).all(0) & (lift < lift_max) & np.isfinite(p2) & (np.abs(p2) > 0)
        L, M, N = fr.L.copy(), fr.M.copy(), fr.N.copy()
        L[use] = (a2 * ru ** 2)[use]
        M[use] = (ru * (a2 * p1 + b2 * p2))[use]
        N[use] = (a2 * p1 ** 2 + 2 * b2 * p1 * p2 + c2 * p2 ** 2)[use]
        stats.update(seconds=time.perf_counter() - t0, used=int(use.sum()), vertices=len(V),
                     own=np.nanpercentile(own[0, use], [1, 10, 50, 90, 99]),
                     read=np.nanpercentile(K[0, use], [1, 10, 50, 90, 99]))
        return SurfaceFrame(ru=fr.ru, rv=fr.rv, ruu=fr.ruu, ruv=fr.ruv, rvv=fr.rvv, n=fr.n,
                            E=fr.E, F=fr.F, G=fr.G, L=L, M=M, N=N)

    return frame


def sphere_check(r: float, h: float, wfrac: float) -> None:
    """The readings' medians on a sphere cap of radius 50 mm against their exact values."""
    from conformill.cutter import BallCutter
    from conformill.geometry.differential import surface_frame
    from conformill.mesh.synthetic import sphere_cap
    from conformill.param import parameterize
    from conformill.planning.steps import side_interval

    R = 50.0
    mesh = sphere_cap(R=R, radius_xy=18.4, spacing=0.236)
    fr = surface_frame(mesh.V, mesh.F, parameterize(mesh, boundary="circle").uv)
    w = wfrac * float(side_interval(h, r, np.zeros(1))[0][0])
    d2, cc, _ = ball_readings(BallCutter(mesh.V, mesh.F, r), mesh.V, fr, w)
    e1 = fr.ru / np.linalg.norm(fr.ru, axis=1, keepdims=True)
    own = _forms_in_basis(fr, e1, np.cross(fr.n, e1))[0][0]
    print(f"sphere cap R = {R:g} mm, {len(mesh.F)} faces, w = {w:.4f} mm (medians over vertices, direction e1):")
    print(f"  d2 (D's curvature)       {np.nanmedian(d2[0]):+.5f} 1/mm, exact 1/(R + r) = {1 / (R + r):+.5f}")
    print(f"  cc (the part's, via CCs) {np.nanmedian(cc[0]):+.5f} 1/mm, exact -1/R = {-1 / R:+.5f}")
    print(f"  1-ring fit               {np.nanmedian(own):+.5f} 1/mm")


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.add_argument("--scale", type=float, default=1.0, help="for a mesh file: factor to mm")
    ap.add_argument("--scan", action="store_true", help="plan with `plan --scan`'s recipe")
    ap.add_argument("--wfrac", type=float, default=0.8, help="w as a share of the flat side interval")
    ap.add_argument("--lift-max", type=float, default=2.0, help="in h: a middle ball lifted more keeps the fit")
    ap.add_argument("--check", action="store_true", help="the sphere cap's readings first")
    ap.add_argument("--combine", choices=["max", "min"], default="max",
                    help="per direction, the wider (max) or the narrower (min) step of the balls' and the fit's")
    ap.add_argument("--spacing", choices=["adaptive", "local"], default="adaptive")
    args = ap.parse_args(argv)
    h, r, e = args.h, args.r, args.e
    if args.check:
        sphere_check(r, h, args.wfrac)
    from conformill.cutter import BallCutter
    from conformill.geometry import surface as S
    from conformill.pipeline import Job, plan, scan_recipe
    from conformill.planning.steps import side_interval

    mesh, samples = _common.scan_study(args)
    job = Job(pattern=args.pattern, tool_radius=r, scallop=h, tolerance=e, spacing=args.spacing,
              **(scan_recipe(args.pattern) if args.scan else {}))
    w = args.wfrac * float(side_interval(h, r, np.zeros(1))[0][0])
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern}{' --scan' if args.scan else ''}, r = {r:g}, "
          f"h = {h:g}, e = {e:g}, {args.spacing} spacing; w = {w:.4f} mm, lift at most {args.lift_max:g} h", flush=True)
    own, stats, rows = S.surface_frame, {}, []
    for name in ("1-ring", f"balls (cc), {args.combine}"):
        if name != "1-ring":
            S.surface_frame = drop_frame(own, BallCutter(mesh.V, mesh.F, r), w, args.lift_max * h, stats,
                                         args.combine)
        try:
            t0 = time.perf_counter()
            res = plan(mesh, job)
            t = time.perf_counter() - t0
        finally:
            S.surface_frame = own
        prog = _common.program_of(res)
        sc = _common.verify_program(mesh, prog, samples, h, r, e).summary["reachable"]["scallop"]
        rows.append((name, t, res.report["paths"]["cl_points"], BR.cut_length(prog, res.toolpath.safe_z) / 1000,
                     res.report["side_step"]["utilisation_pct"]["mean"], sc["p999"] / h, sc["p99"] / h))
        if stats:
            print(f"  balls read at {stats['used']} of {stats['vertices']} vertices in {stats['seconds']:.2f} s; "
                  f"curvature along e1 (1/mm, p1/10/50/90/99): fit {np.round(stats['own'], 3).tolist()}, "
                  f"used {np.round(stats['read'], 3).tolist()}", flush=True)
    print()
    _common.print_table([("frame", ""), ("plan s", ".2f"), ("CL points", ""), ("feed m", ".1f"),
                         ("side use %", ".1f"), ("reachable p99.9 / h", ".3f"), ("p99 / h", ".3f")], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
