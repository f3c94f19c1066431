"""What each use of the fold search's density buys, set apart (issue 5, session 26).

With ``--pencil-search folds`` one density D (``--pencil-density``) sets three things in
:func:`conformill.pencil.pencil_chains`: the XY grid's spacing ``1 / sqrt(D)`` for the
fold points, the density of the steep samples searched one by one, and the spacing the
centres are thinned and chained at. This script plans one mesh and pattern with the fold
pencil once per setting ``GRID,STEEP,CHAIN`` (densities per mm²), each taken apart, and
verifies every program as ``bench_raster.py`` does (400k samples, seed 0, limit 1.05 h,
reach depth h, the reachable judge).

The settings are applied by replacing ``pencil.pencil_chains`` for this process with its
fold branch's steps (:func:`conformill.pencil.fold_centres`, :func:`conformill.pencil.steep_centres`,
the chains), each with its own density; nothing in the package changes.
``30,30,30`` is the package's own default.

    python benchmarks/bench_fold_density.py [MESH] [--pattern contour] [--h 0.01] [--r 4] [--e 0.01]
        [--samples 400000] [--settings 30,30,30 10,10,10 10,30,30 30,10,30 30,30,10]

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea``).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402


def _chains_apart(densities):
    """``pencil_chains`` with the fold search's three densities ``(grid, steep, chain)``."""
    from conformill import pencil

    dg, ds, dc = densities

    def chains(cutter, V, F, h, *, search="samples", density=30.0, low=0.15, high=1.0, min_chain=1,
               settle_tol=0.0, seed=0, progress=None, cancelled=None):
        fp, deep = pencil.fold_centres(cutter, 1.0 / math.sqrt(dg), h, low)
        _, steep, _ = pencil.steep_centres(cutter, V, F, h, ds, low, high, seed)
        B = np.vstack([fp.centres[deep], steep])
        found = pencil.PencilFound(centres=B, probes=np.full((len(B), 1, 3), np.nan), spacing=1.0 / math.sqrt(dc),
                                   stats={"search": "folds", "densities": list(densities)})
        return pencil.chains_of(cutter, found, min_chain, settle_tol)

    return chains


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.add_argument("--settings", nargs="*", default=["30,30,30", "10,10,10", "10,30,30", "30,10,30", "30,30,10"])
    args = ap.parse_args(argv)
    settings = []
    for s in args.settings:
        v = tuple(float(x) for x in s.split(","))
        if len(v) != 3 or min(v) <= 0:
            ap.error(f"a setting is three positive densities GRID,STEEP,CHAIN, got {s!r}")
        settings.append(v)
    from conformill import pencil
    from conformill.pipeline import Job, plan

    h, r, e = args.h, args.r, args.e
    mesh, samples = _common.scan_study(args)
    job = Job(pattern=args.pattern, tool_radius=r, scallop=h, tolerance=e, pencil=True, pencil_search="folds")
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern} with the fold pencil, r = {r:g}, h = {h:g}, e = {e:g}",
          flush=True)
    plan(mesh, job)  # warm numba's caches: the timed plans below compare
    own = pencil.pencil_chains
    rows = []
    for d in settings:
        pencil.pencil_chains = _chains_apart(d)
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            res = plan(mesh, job)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            pencil.pencil_chains = own
        prog = _common.program_of(res)
        s = _common.verify_program(mesh, prog, samples, h, r, e).summary["reachable"]["scallop"]
        rows.append((d, wall, cpu, res.report["pencil"]["feed_mm"] / 1000,
                     BR.cut_length(prog, res.toolpath.safe_z) / 1000, s["p999"] / h, s["p99"] / h))
        print(f"  grid / steep / chain {d}: {wall:.2f} s ({cpu:.2f} cpu), pencil {rows[-1][3]:.1f} m, "
              f"feed {rows[-1][4]:.1f} m, reachable p99.9 {rows[-1][5]:.3f} h, p99 {rows[-1][6]:.3f} h", flush=True)
    print()
    _common.print_table([("grid / steep / chain per mm^2", ""), ("plan s (cpu s)", ""), ("pencil feed m", ".1f"),
                         ("feed m", ".1f"), ("reachable p99.9 / h", ".3f"), ("p99 / h", ".3f")],
                        [(" / ".join(f"{v:g}" for v in d), f"{wall:.2f} ({cpu:.2f})", *rest)
                         for d, wall, cpu, *rest in rows])
    return 0


if __name__ == "__main__":
    sys.exit(main())
