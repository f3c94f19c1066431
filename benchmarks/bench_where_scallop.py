"""Where the verified scallop exceeds the limit, and why: rest material against spacing.

On the igea scan the default contour program leaves a reachable p99.9 of about 1.26 h
(docs/issue5.md, "What 1.05 H costs on a scan"). This script plans one mesh and pattern, verifies
the program as ``bench_raster.py`` does (400k samples, seed 0, limit 1.05 h, reach depth h,
the reachable judge) and then looks at the reachable samples left above 1.05 h ("over")
against a random control set of reachable samples:

* ``rest``: the least material any ball position leaves there
  (:func:`conformill.verify.rest.rest_material`, the search ``verify`` uses);
* ``own``: what the program leaves above that rest (``remaining - rest``);
* ``gap``: the 3D distance between the nearest CC point and the nearest CC point of
  another path on the sample's other side (the side interval the planner realised there,
  measured point to point: an upper bound, loose where the CC points lie far apart along
  the paths, e.g. on flat ground);
* ``lift``: how far the drop-cutter lifts the ball placed at the nearest CC point (r along
  the interpolated normal): on a faceted scan the facets hold it above the contact the
  spacing assumed, and the cusp rises by about as much (session 35);
* ``model``: the cusp height the planner's own model gives for that gap
  (:func:`conformill.planning.steps.scallop_height` with the normal curvature of the
  planner's quadratic fit at the sample, across the gap; an upper bound as the gap is).

With ``--scan`` the ``gap``, ``model`` and ``lift`` columns read the pattern's CC points only
(``PlanResult.cc_paths``): not the pencil's passes, and still the runs the program hops
over (a hopped point's lift is above 3 mm, hundreds of h: it shows in a high percentile).

If ``model`` is far below the limit where the samples are over it, the paths are not too
far apart for the surface the planner sees; the material comes from features below the
fit's scale (``rest``).

    python benchmarks/bench_where_scallop.py [MESH] [--pattern contour] [--fit mesh|split]
        [--settle 0.5] [--planned 1.0] [--samples 400000] [--control 3000] [--scan]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402


def _nearest(V, F, X):
    """Face and barycentric coordinates of the point of the mesh nearest to each of ``X``."""
    import igl

    _, face, C = igl.point_mesh_squared_distance(np.ascontiguousarray(X), np.ascontiguousarray(V),
                                                 np.ascontiguousarray(F, dtype=np.int64))
    a, b, c = (V[F[face, k]] for k in range(3))
    bary = np.asarray(igl.barycentric_coordinates(np.ascontiguousarray(C), np.ascontiguousarray(a),
                                                  np.ascontiguousarray(b), np.ascontiguousarray(c)))
    return face, bary


def _frame_at(V, F, fr, X):
    """The fit's frame interpolated at the points of the mesh nearest to ``X``."""
    from conformill.geometry.differential import interpolate_frame

    return interpolate_frame(fr, F, *_nearest(V, F, X))


def _curvature_along(f, t3):
    """Normal curvature of frame ``f`` in the domain direction whose image is nearest ``t3``."""
    from conformill.geometry.differential import normal_curvature

    J = np.stack([f.ru, f.rv], axis=2)  # (k, 3, 2)
    Jt = np.transpose(J, (0, 2, 1))
    d = np.linalg.solve(Jt @ J + 1e-12 * np.eye(2), (Jt @ t3[:, :, None]))[:, :, 0]
    return normal_curvature(f.E, f.F, f.G, f.L, f.M, f.N, d[:, 0], d[:, 1])


def _lift(cutter, V, F, X):
    """How far the drop lifts the ball placed at ``X`` (CC points on the mesh), r along the
    vertex normals interpolated there (as the cutter places it): ``drop - (X + r n)_z``, mm."""
    from conformill.geometry.differential import interpolate, vertex_normals

    n = interpolate(vertex_normals(V, F), F, *_nearest(V, F, X))
    centre = X + cutter.radius * n / np.linalg.norm(n, axis=1, keepdims=True)
    return cutter.drop(centre[:, :2]) - centre[:, 2]


def _gaps(P, cc_paths, k: int = 64):
    """Per sample: nearest CC point A and the nearest CC point B of another path beyond it."""
    from scipy.spatial import cKDTree

    ids = np.concatenate([np.full(len(c), i) for i, c in enumerate(cc_paths)])
    cc = np.vstack(cc_paths)
    _, nn = cKDTree(cc).query(P, k=k)
    A = cc[nn[:, 0]]
    other = (ids[nn] != ids[nn[:, :1]]) & (np.einsum("kmj,kj->km", cc[nn] - P[:, None, :], A - P) < 0)
    first = np.argmax(other, axis=1)
    ok = other[np.arange(len(P)), first]
    B = np.where(ok[:, None], cc[nn[np.arange(len(P)), first]], np.nan)
    return A, B, ok


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.add_argument("--fit", default="mesh", choices=("mesh", "split"))
    ap.add_argument("--settle", type=float, default=0.5)
    ap.add_argument("--planned", type=float, default=1.0, help="paths spaced for this factor times h")
    ap.add_argument("--control", type=int, default=3000)
    ap.add_argument("--scan", action="store_true", help="plan with the scan recipe (plan --scan)")
    args = ap.parse_args(argv)
    from conformill.cutter import BallCutter
    from conformill.geometry.differential import surface_frame
    from conformill.mesh.split import split_midpoints
    from conformill.pipeline import Job, plan, scan_recipe
    from conformill.planning.steps import scallop_height
    from conformill.verify.rest import rest_material

    h, r, e = args.h, args.r, args.e
    mesh, samples = _common.scan_study(args)
    job = Job(pattern=args.pattern, tool_radius=r, scallop=args.planned * h, tolerance=e, settle=args.settle,
              fit=args.fit, **(scan_recipe(args.pattern) if args.scan else {}))
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern}, r = {r:g}, h = {h:g}, e = {e:g}, fit {args.fit}, "
          f"settle {args.settle:g}, planned {args.planned:g} h{', scan recipe' if args.scan else ''}", flush=True)
    t0 = time.perf_counter()
    res = plan(mesh, job)
    prog = _common.program_of(res)
    print(f"plan {time.perf_counter() - t0:.1f} s, {res.report['paths']['cl_points']} CL points, "
          f"feed {BR.cut_length(prog, res.toolpath.safe_z) / 1000:.1f} m", flush=True)
    v = _common.verify_program(mesh, prog, samples, h, r, e)
    rem, ok = v.remaining, v.reachable
    over = np.flatnonzero(ok & (rem > 1.05 * h))
    rng = np.random.default_rng(0)
    pool = np.flatnonzero(ok & np.isfinite(rem))
    control = rng.choice(pool, min(args.control, pool.size), replace=False)
    print(f"reachable samples {int(ok.sum())}, over 1.05 h {over.size} ({1000 * over.size / ok.sum():.2f} per mille; "
          f"p99.9 is met at 1 per mille); reachable p99.9 {v.summary['reachable']['scallop']['p999'] / h:.3f} h")

    cutter = BallCutter(mesh.V, mesh.F, r)
    # the fit the planner spaced the paths from (Job.fit): on the input, or on the mesh split once
    fV, fF, fuv = mesh.V, mesh.F, res.param.uv
    if args.fit == "split":
        fV, fF, fuv = split_midpoints(mesh.V, mesh.F, res.param.uv)
    fr = surface_frame(fV, fF, fuv)
    P, N = samples.points, samples.normals
    rows = []
    for name, S in (("over 1.05 h", over), ("random reachable", control)):
        rest = rest_material(cutter, P[S], N[S])
        A, B, has = _gaps(P[S], res.cc_paths)
        gap = np.linalg.norm(B - A, axis=1)
        kap = _curvature_along(_frame_at(fV, fF, fr, P[S]), np.nan_to_num(B - A))
        model = np.where(has, scallop_height(np.nan_to_num(gap), r, kap), np.nan)
        lift = _lift(cutter, mesh.V, mesh.F, A)
        rows.append((name, S.size, rem[S] / h, rest / h, (rem[S] - rest) / h, gap, model / h, lift / h))
    print()
    print("| samples | n | remaining / h | rest / h | own (remaining - rest) / h | gap mm | model cusp / h | "
          "lift at nearer CC / h | rest > 0.5 h |")
    print("|---|---|---|---|---|---|---|---|---|")

    def q(x):
        if not np.isfinite(x).any():
            return "-"
        a, b, c = np.nanpercentile(x, [10, 50, 90])
        return f"{a:.2f} / {b:.2f} / {c:.2f}"
    for name, n, rm, rs, own, gap, model, lift in rows:
        print(f"| {name} | {n} | {q(rm)} | {q(rs)} | {q(own)} | {q(gap)} | {q(model)} | {q(lift)} | "
              f"{100 * np.mean(rs > 0.5) if n else 0.0:.1f} % |")
    print("\n(each cell: 10th / 50th / 90th percentile)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
