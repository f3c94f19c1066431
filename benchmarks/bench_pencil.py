"""The pencil stage's search alone: cost per sample and how the samples end.

Issue 5 asks for 20x OpenCAMLib's raster *with* a verified scallop within 1.05 h on igea;
``--pencil`` meets the scallop but its search (:func:`conformill.pencil.best_centres`) costs
about as much as the rest of the plan. This script times that search on one mesh's pencil
samples (the stage's own, :func:`conformill.pencil.surface_samples`) ``--repeat`` times and
prints wall and CPU time, the CPU per sample, how the samples ended (tangent only,
searched, given up, roofed) and how many centres fall in the band (0.15 h, h].

    python benchmarks/bench_pencil.py [MESH] [--density 30] [--h 0.01] [--radius 4]
        [--repeat 2] [--folds]

With ``--folds`` the fold search (:func:`conformill.folds.fold_points`, a grid of the same
density per mm^2 of the XY plane) runs interleaved with it and gets a row: its time, its
fold points with a shadow deeper than 0.15 h, and the share of the band centres within
0.1 mm of one of them.

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea``). Until session 60
the search refined on five levels of grids and this script compared grid settings
(``--grids``); since session 61 the coarse grid is followed by a simplex whose settings are
compiled in (``pencil._COARSE_GRID``, ``pencil._SIMPLEX_*``): compare them by editing those
constants, one run each.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--density", type=float, default=30.0)
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--radius", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--folds", action="store_true", help="also time the fold search")
    args = ap.parse_args(argv)

    from conformill import pencil
    from conformill.cutter import BallCutter

    mesh, info = _common.load_part(args.mesh)
    h = args.h
    cut = BallCutter(mesh.V, mesh.F, args.radius)
    P, N, f = pencil.surface_samples(mesh.V, mesh.F, args.density)
    print(f"{_common.machine()}")
    print(f"{args.mesh}: {mesh.n_faces} faces, {len(P)} samples facing the tool at {args.density:g} per mm^2; "
          f"r = {args.radius:g}, h = {h:g}")
    from conformill.folds import fold_points

    spacing = 1.0 / np.sqrt(args.density)
    jump = pencil.fold_jump(args.radius, h, spacing)  # the planner's (pencil.fold_centres)
    folds_t, fp, times = [], None, []
    pencil.best_centres(cut, P[:512], N[:512], f[:512], low=0.15 * h, give_up=1.05 * h)  # compile / warm
    if args.folds:
        fold_points(cut, 10 * spacing, jump)
    for _ in range(args.repeat):
        if args.folds:
            t0, c0 = time.perf_counter(), time.process_time()
            fp = fold_points(cut, spacing, jump)
            folds_t.append((time.perf_counter() - t0, time.process_time() - c0))
        t0, c0 = time.perf_counter(), time.process_time()
        C, rest, state = pencil.best_centres(cut, P, N, f, low=0.15 * h, give_up=1.05 * h)
        times.append((time.perf_counter() - t0, time.process_time() - c0))
    print()
    print("| wall s (runs) | cpu s (runs) | us cpu per sample | tangent only | searched | given up | roofed "
          "| band (0.15 h, h] |")
    print("|---|---|---|---|---|---|---|---|")
    band = (state == 1) & (rest > 0.15 * h) & (rest <= h)
    w = [t[0] for t in times]
    c = [t[1] for t in times]
    c_first = min(c)
    counts = np.bincount(state, minlength=5)
    print(f"| {min(w):.2f} ({' '.join(f'{x:.2f}' for x in w)}) | {min(c):.2f} ({' '.join(f'{x:.2f}' for x in c)}) | "
          f"{1e6 * min(c) / len(P):.1f} | {counts[0]} | {counts[1] + counts[3]} | {counts[2]} | {counts[4]} | "
          f"{int(band.sum())} |")
    if fp is not None:
        from scipy.spatial import cKDTree

        deep = fp.shadow > 0.15 * h
        d, _ = cKDTree(fp.centres[deep, :2]).query(C[band, :2]) if deep.any() else (np.full(band.sum(), np.inf), 0)
        w = [t[0] for t in folds_t]
        c = [t[1] for t in folds_t]
        print()
        print(f"folds ({spacing:.3f} mm grid, {fp.stats['grid_points']} points with a drop, jump {jump:.3f} mm): "
              f"wall {min(w):.2f} s ({' '.join(f'{x:.2f}' for x in w)}), cpu {min(c):.2f} s, "
              f"{min(c) / c_first:.3f} x the search's cpu; {fp.stats['edges']} edges crossed, "
              f"{fp.stats['drops_per_edge']:.2f} drops each; {int(deep.sum())} fold points with a shadow deeper "
              f"than 0.15 h; {100 * np.mean(d < 0.1):.1f} % of the band centres within 0.1 mm of one")
    return 0


if __name__ == "__main__":
    sys.exit(main())
