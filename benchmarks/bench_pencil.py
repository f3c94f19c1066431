"""The pencil stage's search alone: cost per sample, how the samples end, A/B of search grids.

Issue 5 asks for 20x OpenCAMLib's raster *with* a verified scallop within 1.05 h on igea;
``--pencil`` meets the scallop but its search (:func:`conformill.pencil.best_centres`) costs
about as much as the rest of the plan. This script times that search on one mesh's pencil
samples (the stage's own, :func:`conformill.pencil.surface_samples`) for each grid setting
given, interleaved ``--repeat`` times so that the host's drift hits all alike, and prints
wall and CPU time, the ratio to the first setting, how the samples ended (tangent only,
searched, given up) and how many centres fall in the band (0.15 h, h], with how many of
the first setting's band centres each other setting keeps.

    python benchmarks/bench_pencil.py [MESH] [--density 30] [--h 0.01] [--radius 4]
        [--grids 7,7,7,7,7 7,7,5,5,5] [--repeat 2] [--folds]

With ``--folds`` the fold search (:func:`conformill.folds.fold_points`, a grid of the same
density per mm^2 of the XY plane) runs interleaved with the others and gets a row: its
time, its fold points with a shadow deeper than 0.15 h, and the share of the first
setting's band centres within 0.1 mm of one of them.

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea``). A grid setting
is the points per side of each of the search's five levels (``pencil._GRIDS``).
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
    ap.add_argument("--grids", nargs="*", default=["7,7,7,7,7", "7,7,5,5,5"])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--folds", action="store_true", help="also time the fold search")
    args = ap.parse_args(argv)

    from conformill import pencil
    from conformill.cutter import BallCutter

    settings = [tuple(int(v) for v in g.split(",")) for g in args.grids]
    for s in settings:
        if len(s) != len(pencil._SPANS) or min(s) < 2:
            ap.error(f"a grid setting needs {len(pencil._SPANS)} sizes of at least 2, got {s}")
    mesh, info = _common.load_part(args.mesh)
    h = args.h
    cut = BallCutter(mesh.V, mesh.F, args.radius)
    P, N, f = pencil.surface_samples(mesh.V, mesh.F, args.density)
    print(f"{_common.machine()}")
    print(f"{args.mesh}: {mesh.n_faces} faces, {len(P)} samples facing the tool at {args.density:g} per mm^2; "
          f"r = {args.radius:g}, h = {h:g}")
    default = pencil._GRIDS
    times = {s: [] for s in settings}
    ends = {}
    from conformill.folds import fold_points

    spacing = 1.0 / np.sqrt(args.density)
    jump = pencil.fold_jump(args.radius, h, spacing)  # the planner's (pencil.fold_centres)
    folds_t, fp = [], None
    try:
        for s in settings:  # compile / warm
            pencil._GRIDS = s
            pencil.best_centres(cut, P[:512], N[:512], f[:512], low=0.15 * h, give_up=1.05 * h)
        if args.folds:
            fold_points(cut, 10 * spacing, jump)
        for _ in range(args.repeat):
            if args.folds:
                t0, c0 = time.perf_counter(), time.process_time()
                fp = fold_points(cut, spacing, jump)
                folds_t.append((time.perf_counter() - t0, time.process_time() - c0))
            for s in settings:
                pencil._GRIDS = s
                t0, c0 = time.perf_counter(), time.process_time()
                C, rest, state = pencil.best_centres(cut, P, N, f, low=0.15 * h, give_up=1.05 * h)
                times[s].append((time.perf_counter() - t0, time.process_time() - c0))
                ends[s] = (rest, state, C)
    finally:
        pencil._GRIDS = default
    band0 = None
    print()
    print("| grids | wall s (runs) | cpu s (runs) | cpu / first | us cpu per sample | tangent only | searched "
          "| given up | band (0.15 h, h] | of the first's band kept |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    c_first = None
    for s in settings:
        rest, state, _ = ends[s]
        band = (state == 1) & (rest > 0.15 * h) & (rest <= h)
        band0 = band if band0 is None else band0
        w = [t[0] for t in times[s]]
        c = [t[1] for t in times[s]]
        c_first = min(c) if c_first is None else c_first
        counts = np.bincount(state, minlength=4)
        kept = f"{100 * np.count_nonzero(band & band0) / band0.sum():.1f} %" if band0.any() else "-"
        print(f"| {','.join(map(str, s))} | {min(w):.2f} ({' '.join(f'{x:.2f}' for x in w)}) | {min(c):.2f} "
              f"({' '.join(f'{x:.2f}' for x in c)}) | {min(c) / c_first:.3f} | {1e6 * min(c) / len(P):.1f} | "
              f"{counts[0]} | {counts[1] + counts[3]} | {counts[2]} | {int(band.sum())} | "
              f"{kept} |")
    if fp is not None:
        from scipy.spatial import cKDTree

        deep = fp.shadow > 0.15 * h
        C0 = ends[settings[0]][2]
        d, _ = cKDTree(fp.centres[deep, :2]).query(C0[band0, :2]) if deep.any() else (np.full(band0.sum(), np.inf), 0)
        w = [t[0] for t in folds_t]
        c = [t[1] for t in folds_t]
        print()
        print(f"folds ({spacing:.3f} mm grid, {fp.stats['grid_points']} points with a drop, jump {jump:.3f} mm): "
              f"wall {min(w):.2f} s ({' '.join(f'{x:.2f}' for x in w)}), cpu {min(c):.2f} s, "
              f"{min(c) / c_first:.3f} x the first setting's cpu; {fp.stats['edges']} edges crossed, "
              f"{fp.stats['drops_per_edge']:.2f} drops each; {int(deep.sum())} fold points with a shadow deeper "
              f"than 0.15 h; {100 * np.mean(d < 0.1):.1f} % of the first setting's band centres within 0.1 mm of one")
    return 0


if __name__ == "__main__":
    sys.exit(main())
