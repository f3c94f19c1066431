"""A plan's work (core seconds on one thread) against its time on all cores (issue 5: speed).

Issue 5's 20x against OpenCAMLib is a question of *work*: the plans keep both cores busy
(sessions 38-48), so a plan on two cores cannot take less than its one-thread work divided
by what the cores give this code. This script measures the three figures that say so, in
one process and one run (the host is shared and noisy: each figure is the lowest of
``--plans`` plans, and the reference is measured in the same run):

* **work**: each pattern planned with one numba thread (every stage runs in turn in the
  calling thread, :func:`conformill.passes.threads_can_overlap` being false): CPU seconds
  and the report's stage timings;
* **reference**: the drop kernel alone on a fixed set of points (the cutter's and the
  pencil's hottest step), on one thread and on all (the lowest of ``max(--plans, 2)``
  runs each): its speed-up in wall time is what the cores give this code when nothing else
  runs;
* **plan**: the same plan on all cores (the pipeline's threads as ``conformill plan`` runs
  them): wall and CPU seconds.

It prints per pattern the work, the *floor* (work / the reference's speed-up: the one-thread
plan's CPU time is its wall time, but for MKL's threads in the map's solve), the plan's
wall time and its ratio to the floor (the cost of the threads: waits, overhead, a serial
tail), the CPU the threads spent beyond the work, and, with ``--raster-s R`` (an
OpenCAMLib raster time, ``bench_raster.py``), the ratio R / wall and how much less work a
plan at today's ratio to the floor would need for 20x.

    python benchmarks/bench_work.py [MESH] [--patterns zigzag contour spiral] [--plans 2]
        [--default] [--raster-s 97.9] [--h 0.01] [--r 4] [--e 0.01]

``MESH`` is a short name of ``_common.MESH_FILES`` (default igea) or a mesh file (with
``--scale``, as ``bench_scale.py`` reads the 620k mesh). The plans use ``plan --scan``'s
recipe unless ``--default``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402


def timed(fn, runs: int):
    """Lowest wall time, its CPU time and its result over ``runs`` calls of ``fn()``."""
    best = None
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        w, c = time.perf_counter() - t0, time.process_time() - c0
        if best is None or w < best[0]:
            best = (w, c, out)
    return best


def drop_reference(mesh, r: float, threads: int, runs: int):
    """The cutter's drop on a 0.3 mm XY grid over the part, on one thread and on
    ``threads``: ``(points, one-thread s, all-thread s)``."""
    import numba

    from conformill.cutter import BallCutter

    cutter = BallCutter(mesh.V, mesh.F, r)
    lo, hi = mesh.V[:, :2].min(axis=0), mesh.V[:, :2].max(axis=0)
    gx, gy = np.arange(lo[0], hi[0], 0.3), np.arange(lo[1], hi[1], 0.3)
    XY = np.column_stack([np.tile(gx, len(gy)), np.repeat(gy, len(gx))])
    floor = np.full(len(XY), -np.inf)
    cutter._drop(XY[:64], floor[:64])  # (load the kernel)
    out = []
    for n in (1, threads):
        numba.set_num_threads(n)
        out.append(timed(lambda: cutter._drop(XY, floor), runs)[0])
    numba.set_num_threads(threads)
    return len(XY), out[0], out[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--scale", type=float, default=1.0, help="for a mesh file: as plan --scale (default 1)")
    ap.add_argument("--patterns", nargs="*", default=["zigzag", "contour", "spiral"],
                    choices=["zigzag", "contour", "spiral"])
    ap.add_argument("--plans", type=int, default=2, help="plans per figure, the lowest kept (default 2)")
    ap.add_argument("--default", action="store_true", help="the default plan instead of --scan's recipe")
    ap.add_argument("--raster-s", type=float, default=None, metavar="R",
                    help="an OpenCAMLib raster time (s) to state the ratio and the 20x work against")
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--e", type=float, default=0.01)
    args = ap.parse_args(argv)
    if args.plans < 1:
        ap.error("--plans must be at least 1")

    import numba

    from conformill.pipeline import Job, orient_mesh, plan, scan_recipe

    logging.disable(logging.WARNING)
    mesh, _ = orient_mesh(_common.study_mesh(args.mesh, args.scale), "none")
    threads = numba.get_num_threads()
    print(_common.machine())
    print(f"{args.mesh}: {len(mesh.F)} faces; r = {args.r:g}, h = {args.h:g}, e = {args.e:g}; "
          f"{'default plan' if args.default else 'plan --scan recipe'}; {threads} numba threads; "
          f"lowest of {args.plans} plans per figure")
    n, t1, tn = drop_reference(mesh, args.r, threads, max(args.plans, 2))
    speedup = t1 / tn
    print(f"reference: the drop of {n} grid points {t1:.3f} s on one thread, {tn:.3f} s on {threads}: "
          f"x{speedup:.2f}")
    rows = []
    for pat in args.patterns:
        recipe = {} if args.default else scan_recipe(pat)
        job = Job(pattern=pat, tool_radius=args.r, scallop=args.h, tolerance=args.e, **recipe)
        plan(mesh, job)  # (numba's caches and the first-plan costs: not timed)
        numba.set_num_threads(1)
        w1, c1, res1 = timed(lambda: plan(mesh, job), args.plans)
        numba.set_num_threads(threads)
        w, c, res = timed(lambda: plan(mesh, job), args.plans)
        floor = c1 / speedup
        stages = ", ".join(f"{k} {v:.2f}" for k, v in res1.report["timings_s"].items() if v >= 0.05)
        print(f"{pat}: work {c1:.2f} CPU-s on one thread (wall {w1:.2f} s; {stages})")
        print(f"{pat}: on {threads} threads {w:.2f} s wall, {c:.2f} CPU-s ({c / c1 - 1:+.1%} over the work); "
              f"floor {floor:.2f} s, wall / floor {w / floor:.2f}; "
              f"{sum(len(q) for q in res.toolpath.passes)} CL points")
        rows.append((pat, c1, floor, w, c, w / floor))
    print()
    cols = [("pattern", ""), ("work (CPU-s, 1 thread)", ".2f"), (f"floor (s, work / {speedup:.2f})", ".2f"),
            (f"wall (s, {threads} threads)", ".2f"), ("CPU-s", ".2f"), ("wall / floor", ".2f")]
    if args.raster_s:
        # 20x needs the wall at R / 20; at today's wall / floor that is this much less work
        cols += [(f"{args.raster_s:g} s raster / wall", ".1f"), ("work cut for 20x", ".0%")]
        rows = [row + (args.raster_s / row[3], max(1.0 - args.raster_s / 20.0 / row[3], 0.0)) for row in rows]
    _common.print_table(cols, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
