"""How much of a program's scallop tail is material no ball position can remove.

``conformill verify --judge reachable`` excuses a sample when the ball touching it along
its normal is blocked by other parts of the surface by more than ``depth`` (= h), judged
against the mesh vertices and the samples (points). On a faceted scan that test lets
through samples that no 3-axis ball position can bring within ``h``: at a concave crease
between facets, or at the rim of a pocket tighter than the ball, the best any program can
do leaves some material ("rest"), and where that rest is close to ``h`` the program's own
scallop comes on top of it.

For every interior sample that verify counts as reachable and where the program leaves
more than ``1.05 h``, ``verify(..., rest=True)`` (``conformill verify --rest``) searches the
ball positions reachable from above for the one that leaves the least material along the
sample's normal (:func:`conformill.verify.rest.rest_material`: centres on the drop surface
of conformill's exact drop-cutter, on grids around the tangent ball's centre). The least
value found is an upper bound of the true rest (a better ball may lie between grid
points), so "rest > 1.05 h" counts samples that are, as far as this search can tell,
beyond any program.

It prints, per program:

* ``above``: reachable interior samples with more than 1.05 h left, and p99.9 / h;
* ``rest > 1.05 h``: how many of those no ball found by the search brings within 1.05 h,
  as a share of the reachable samples (more than 1 per mille means that p99.9 <= 1.05 h
  cannot be met under verify's reachability test by any program);
* ``p99.9 without them``: the figure once those samples are excused too;
* ``p99.9 over rest``: of ``left - rest`` (the program's own share; ``rest`` is taken as 0
  where the program leaves at most h, so this never hides a sample above h).

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
    print("| program | reachable | above 1.05 h | p99.9/h | of them rest > 1.05 h | per mille of reachable "
          "| p99.9/h without them | p99.9/h over rest | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for prog in args.programs:
        t = time.perf_counter()
        res = verify(mesh, read_gcode(prog), r, n_samples=args.samples, seed=0, scallop=1.05 * h,
                     reach_depth=h, judge="reachable", rest=True)
        q = res.summary["reachable"]
        R = q["rest"]
        print(f"| {Path(prog).name} | {q['samples']} | {R['above_limit']} | {q['scallop']['p999'] / h:.3f} | "
              f"{R['beyond_any_ball']} | {R.get('beyond_any_ball_per_mille', 0.0):.2f} | "
              f"{R['p999_without_them'] / h:.3f} | {R['p999_over_rest'] / h:.3f} | {time.perf_counter() - t:.1f} |",
              flush=True)


if __name__ == "__main__":
    main()
