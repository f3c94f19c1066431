"""What the lifted CC points do: the share of a program whose ball never touches its plan.

The drop-cutter lifts the ball above the planned contact ``cc + r n`` where the surface
there is out of reach (an undercut, a pocket tighter than the ball, a wall): the ball then
rides on other material, a rim or a crease. On igea about half of the default contour's CC
points are lifted by more than 0.1 mm (``bench_cutter_work.py``). This script asks whether
those points can be planned more cheaply: it plans one mesh and pattern as usual, then
again with the runs of CC points lifted more than ``--lift`` thinned to every ``--keep``-th
point (the ends of each run kept; ``settle`` and ``refine`` then run on what is left as on
any pass, so the moves stay gouge-free and within the float limit), and verifies both
programs as ``bench_raster.py`` does (400k samples, seed 0, limit 1.05 h, reach depth h,
the reachable judge).

The thinning is done by wrapping ``BallCutter.cl_from_cc`` for the second plan; nothing
in the package changes.

    python benchmarks/bench_lifted.py [MESH] [--pattern contour] [--lift 1.0] [--keep 8]
        [--samples 400000]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402

LIFT_EDGES = (-np.inf, 1e-3, 1e-2, 0.1, 1.0, 3.0, np.inf)


def thinned(lift, limit: float, keep: int) -> np.ndarray:
    """Mask of the CC points kept: all outside runs lifted above ``limit``; inside each such
    run every ``keep``-th point and the run's last."""
    air = lift > limit
    mask = ~air
    d = np.diff(np.concatenate([[0], air.astype(np.int8), [0]]))
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        mask[a:b:keep] = True
        mask[b - 1] = True
    return mask


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.add_argument("--lift", type=float, default=1.0, help="runs lifted more than this (mm) are thinned")
    ap.add_argument("--keep", type=int, default=8, help="keep every KEEP-th point of such a run")
    args = ap.parse_args(argv)
    from conformill.cutter import BallCutter
    from conformill.pipeline import Job, plan

    h, r, e = args.h, args.r, args.e
    mesh, samples = _common.scan_study(args)
    job = Job(pattern=args.pattern, tool_radius=r, scallop=h, tolerance=e)
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern}, r = {r:g}, h = {h:g}, e = {e:g}; "
          f"thinned: runs lifted > {args.lift:g} mm, every {args.keep}th point kept", flush=True)
    plan(mesh, job)  # warm numba's caches: the timed plans below compare
    original = BallCutter.cl_from_cc
    seen = {"lifts": [], "in": 0, "kept": 0, "thin": False}

    def wrapped(self, cc, n, contacts=False):
        out = original(self, cc, n, contacts=contacts)
        if not seen["thin"]:  # as planned: only the lifts are recorded
            seen["lifts"].append(out[1])
            return out
        m = thinned(out[1], args.lift, args.keep)
        seen["in"] += len(m)
        seen["kept"] += int(m.sum())
        return tuple(x[m] for x in out)

    rows = []
    for name in ("as planned", "thinned"):
        seen["thin"] = name == "thinned"
        try:
            BallCutter.cl_from_cc = wrapped
            t0 = time.perf_counter()
            res = plan(mesh, job)
            t = time.perf_counter() - t0
        finally:
            BallCutter.cl_from_cc = original
        if name == "as planned":
            lift = np.concatenate(seen["lifts"])
            print("CC points by lift (mm): " + ", ".join(
                f"[{a:g}, {b:g}) {100 * np.mean((lift >= a) & (lift < b)):.1f} %"
                for a, b in zip(LIFT_EDGES[:-1], LIFT_EDGES[1:])) + f" of {lift.size}")
        prog = _common.program_of(res)
        v = _common.verify_program(mesh, prog, samples, h, r, e)
        s = v.summary["reachable"]["scallop"]
        rows.append((name, t, res.report["paths"]["cl_points"], BR.cut_length(prog, res.toolpath.safe_z) / 1000,
                     s["p99"] / h, s["p999"] / h))
        print(f"{name}: plan {t:.2f} s, {rows[-1][2]} CL points, feed {rows[-1][3]:.1f} m, "
              f"reachable p99 {rows[-1][4]:.3f} h, p99.9 {rows[-1][5]:.3f} h", flush=True)
    print(f"thinning kept {seen['kept']} of {seen['in']} CC points ({100 * seen['kept'] / seen['in']:.1f} %)")
    print()
    print("| program | plan s | CL points | feed m | reachable p99 / h | reachable p99.9 / h |")
    print("|---|---|---|---|---|---|")
    for name, t, cl, feed, p99, p999 in rows:
        print(f"| {name} | {t:.2f} | {cl} | {feed:.1f} | {p99:.3f} | {p999:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
