"""Where the verified scallop exceeds the limit, against the scan's facet creases (issue 5).

The planner spaces its paths from a quadratic fit per vertex; a faceted scan also has
creases between its facets, finer than the fit. At a concave crease of angle phi no ball
comes nearer the crease line than the ball wedged in it, ``r (1 / cos(phi / 2) - 1)``
above it (the crease's *wedge rest*: 0.38 h at 5 deg, 1.5 h at 10 deg for r = 4 mm,
h = 0.01 mm); at a convex edge as sharp the fit reads its largest curvatures and the
drop-cutter lifts the ball (session 35). This script plans one mesh with ``plan --scan``'s
recipe in the process, verifies each program as ``bench_raster.py`` does (400k samples,
seed 0, limit 1.05 h, reach depth h, the reachable judge) and prints

* the share of the upward edge length (both faces with n_z > 0.2) by crease kind and wedge
  rest;
* for three kinds of crease (concave with a rest of 0.3-1 h, concave with 1 h or more,
  convex with 0.3 h or more), how near to one the reachable samples left above 1.05 h lie,
  against a random control set of reachable samples: the share within 0.2 mm and 0.5 mm,
  and the median distance (to points 1/6 of an edge apart along the creases).

Where the samples over the limit sit near creases far more often than the control, the
material is the creases' (docs/issue5.md, "Session 51").

    python benchmarks/bench_creases.py [MESH] [--patterns zigzag contour] [--samples 400000]
        [--control 5000]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402

#: Wedge-rest bands (in h) of the edge-length table.
BANDS = ((0.0, 0.1), (0.1, 0.3), (0.3, 0.5), (0.5, 1.0), (1.0, np.inf))


def creases(mesh, r: float, h: float):
    """Per edge between two upward faces: its two ends, whether it is convex, and its wedge
    rest (in h)."""
    import trimesh

    tm = trimesh.Trimesh(mesh.V, mesh.F, process=False)
    nz = tm.face_normals[:, 2]
    fa = tm.face_adjacency
    up = (nz[fa[:, 0]] > 0.2) & (nz[fa[:, 1]] > 0.2)
    ang = tm.face_adjacency_angles[up]
    E = tm.face_adjacency_edges[up]
    rest = r * (1.0 / np.cos(0.5 * ang) - 1.0) / h
    return tm.vertices[E[:, 0]], tm.vertices[E[:, 1]], tm.face_adjacency_convex[up], rest


def main(argv=None) -> int:
    import argparse

    import tempfile

    from scipy.spatial import cKDTree

    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--patterns", nargs="*", default=["zigzag", "contour"], choices=list(BR.PATTERNS))
    ap.add_argument("--samples", type=int, default=400_000)
    ap.add_argument("--control", type=int, default=5000)
    args = ap.parse_args(argv)
    import logging
    import warnings

    logging.disable(logging.WARNING)
    warnings.simplefilter("ignore", RuntimeWarning)  # (the frame fit's notes on single vertices)
    r, h, e = 4.0, 0.01, 0.01
    BR.SCAN = True
    mesh, _ = _common.load_part(args.mesh)
    A, B, cvx, rest = creases(mesh, r, h)
    length = np.linalg.norm(B - A, axis=1)
    print(_common.machine())
    print(f"{mesh.name}: {mesh.n_faces} faces, median edge {np.median(length):.3f} mm; r = {r:g}, h = {h:g}")
    rows = []
    for lo, hi in BANDS:
        band = (rest >= lo) & (rest < hi)
        rows.append((f"{lo:g}-{hi:g} h", 100 * length[band & ~cvx].sum() / length.sum(),
                     100 * length[band & cvx].sum() / length.sum()))
    _common.print_table([("wedge rest", ""), ("concave % of edge length", ".1f"), ("convex %", ".1f")], rows)
    t = np.linspace(0.0, 1.0, 7)[None, :, None]
    kinds = {"concave, rest 0.3-1 h": ~cvx & (rest >= 0.3) & (rest < 1.0),
             "concave, rest >= 1 h": ~cvx & (rest >= 1.0),
             "convex, rest >= 0.3 h": cvx & (rest >= 0.3)}
    trees = {k: cKDTree((A[m][:, None, :] * (1.0 - t) + B[m][:, None, :] * t).reshape(-1, 3))
             for k, m in kinds.items()}
    samples = _common.verify_samples(mesh, args.samples, r)
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        for pat in args.patterns:
            path = Path(tmp) / f"{pat}.nc"
            res, _, wall, _ = BR.conformill_program(mesh, pat, r, h, e, path)
            # the program as written, read back (bench_raster.measure)
            v = verify(res.mesh, read_gcode(path), r, samples=samples, scallop=1.05 * h, reach_depth=h, gouge=e,
                       judge="reachable")
            ok = v.reachable & v.interior
            over = np.flatnonzero(ok & (v.remaining > 1.05 * h))
            pool = np.flatnonzero(ok)
            ctrl = rng.choice(pool, min(args.control, pool.size), replace=False)
            print(f"\n{pat} --scan: plan {wall:.2f} s; reachable {ok.sum()}, above 1.05 h {over.size}, "
                  f"p99.9 {v.summary['reachable']['scallop']['p999'] / h:.3f} h")
            out = []
            for k, tree in trees.items():
                for lab, idx in (("above 1.05 h", over), ("random reachable", ctrl)):
                    d = tree.query(samples.points[idx])[0] if idx.size else np.array([np.nan])
                    out.append((k, lab, 100 * np.mean(d < 0.2), 100 * np.mean(d < 0.5), float(np.median(d))))
            _common.print_table([("crease", ""), ("samples", ""), ("within 0.2 mm %", ".1f"),
                                 ("within 0.5 mm %", ".1f"), ("median mm", ".2f")], out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
