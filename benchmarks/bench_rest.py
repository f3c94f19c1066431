"""How much of a program's scallop tail is material no ball position can remove.

``conformill verify --judge reachable`` first drops the samples where the ball touching
along the normal is blocked by other parts of the surface by more than ``depth`` (= h),
judged against the mesh vertices and the samples (points). On a faceted scan that test
lets through samples that no 3-axis ball position can bring within ``h``: at a concave
crease between facets, or at the rim of a pocket tighter than the ball, the best any
program can do leaves some material ("rest"). Since session 10 verify then searches, at
every sample the program left above ``h``, the ball positions reachable from above for
the one that leaves the least material along the sample's normal
(:func:`conformill.verify.rest.rest_material`: centres on the drop surface of
conformill's exact drop-cutter, on grids around the tangent ball's centre), and excuses
the sample when that least value is above the limit ``1.05 h`` (above ``1.2 h`` before
session 12), a second, wider and deeper search (:data:`conformill.verify.rest.CONFIRM`)
finds no ball within it either, and the best ball is confirmed to touch the part. The
least value found is an upper bound of the true rest (a better ball may lie between grid
points).

It prints, per program (``verify(..., scallop=1.05 h, reach_depth=h, judge="reachable",
rest=True)``, 400k samples, seed 0):

* the samples the tangent test keeps, how many of them are excused (and per mille),
  and how many the search would excuse but could not confirm;
* p99.9 / h over the tangent test's set (verify's judged figure before session 10) and
  over the reachable set (today's);
* ``judged``: the reachable samples; ``above 1.05 h``: those left above the limit (in
  brackets the 0.1 % of the judged samples that p99.9 allows above it), and how many of
  them have a rest below half the limit, between half and 0.9 of it, and above that;
* ``p99.9 over rest``: of ``left - rest`` over the reachable samples (the program's own
  share; ``rest`` is taken as 0 where the program leaves at most h, so this never hides a
  sample above h).

Usage::

    python benchmarks/bench_rest.py MESH PROGRAM.nc [PROGRAM.nc ...] [--h 0.01] [--r 4]

``MESH`` is a short name of :data:`_common.MESH_FILES` (turned and scaled as in the other
benchmarks) and the programs must have been planned on that same part, e.g. kept by
``bench_raster.py --keep DIR``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import load_part  # noqa: E402

from conformill.verify.gcode import read_gcode  # noqa: E402
from conformill.verify.simulate import verify  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh")
    ap.add_argument("programs", nargs="+")
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--samples", type=int, default=400_000)
    args = ap.parse_args(argv)
    mesh, info = load_part(args.mesh)
    h, r = args.h, args.r
    print(f"{args.mesh}: {mesh.n_faces} faces, r = {r:g}, h = {h:g}, {args.samples} samples (seed 0)")
    print("| program | reachable (tangent test) | excused: no ball found within 1.05 h | per mille | unconfirmed "
          "| p99.9/h, tangent test | p99.9/h, reachable | judged | above 1.05 h (0.1 % of judged) "
          "| of them with rest < 0.525 / 0.525-0.945 / > 0.945 h | p99.9/h over rest | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for prog in args.programs:
        t = time.perf_counter()
        res = verify(mesh, read_gcode(Path(prog)), r, n_samples=args.samples, seed=0, scallop=1.05 * h,
                     reach_depth=h, judge="reachable", rest=True)
        q = res.summary["reachable"]
        T = q["tangent_test"]
        print(f"| {Path(prog).name} | {T['samples']} | {q['beyond_any_ball']} | {q['beyond_any_ball_per_mille']:.2f} | "
              f"{q['unconfirmed']} | {T['scallop']['p999'] / h:.3f} | {q['scallop']['p999'] / h:.3f} | "
              f"{q['samples']} | {q['rest']['above_limit']} ({q['samples'] // 1000}) | "
              f"{' / '.join(str(k) for k in q['rest']['above_limit_by_rest'])} | "
              f"{q['rest']['p999_over_rest'] / h:.3f} | {time.perf_counter() - t:.1f} |",
              flush=True)


if __name__ == "__main__":
    main()
