"""Drop-cutter speed and agreement with OpenCAMLib on a large real mesh.

Mesh: /work/shared/meshes/large_igea_face_subdiv1.ply (620k faces) scaled x1400 (about
97 x 139 x 69 mm), ball r = 4 mm. Queries: a zigzag raster over the part's XY box (path
order, as the planner produces them) and the same points shuffled (no locality).
Reference: ``ocl.BatchDropCutter`` with ``ocl.BallCutter(2 r, length)`` on a subset of the
points (its CL is the tool tip: centre = CL z + r).

Run: python benchmarks/bench_cutter.py [--mesh PATH] [--scale S] [--points N] [--ocl N]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from conformill.cutter import BallCutter

DEFAULT_MESH = "/work/shared/meshes/large_igea_face_subdiv1.ply"


def load(path, scale):
    import trimesh

    m = trimesh.load(path, process=False, force="mesh")
    return np.asarray(m.vertices, dtype=np.float64) * scale, np.asarray(m.faces, dtype=np.int64)


def raster(V, n_points, margin=0.0):
    lo = V[:, :2].min(0) - margin
    hi = V[:, :2].max(0) + margin
    nl = int(np.sqrt(n_points * (hi[1] - lo[1]) / (hi[0] - lo[0])))
    npl = n_points // nl
    ys = np.linspace(lo[1], hi[1], nl)
    xs = np.linspace(lo[0], hi[0], npl)
    X = np.tile(xs, (nl, 1))
    X[1::2] = X[1::2, ::-1]  # zigzag
    Y = np.repeat(ys[:, None], npl, axis=1)
    return np.column_stack([X.ravel(), Y.ravel()])


def ocl_drop(V, F, r, xy, threads=2):
    from opencamlib import ocl

    surf = ocl.STLSurf()
    P = V[F]
    t0 = time.perf_counter()
    for tri in P.tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*tri[0]), ocl.Point(*tri[1]), ocl.Point(*tri[2])))
    t_load = time.perf_counter() - t0
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(surf)
    cutter = ocl.BallCutter(2 * r, 50.0)  # keep a reference: ocl does not own it
    bdc.setCutter(cutter)
    bdc.setThreads(threads)
    zmin = float(V[:, 2].min()) - 1000.0
    for x, y in xy.tolist():
        bdc.appendPoint(ocl.CLPoint(x, y, zmin))
    t0 = time.perf_counter()
    bdc.run()
    t_run = time.perf_counter() - t0
    z = np.array([p.z for p in bdc.getCLPoints()])
    centre = np.where(z > zmin + 1e-9, z + r, -np.inf)
    return centre, t_load, t_run


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default=DEFAULT_MESH)
    ap.add_argument("--scale", type=float, default=1400.0)
    ap.add_argument("--radius", type=float, default=4.0)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--ocl", type=int, default=100_000, help="points checked against OpenCAMLib (0: skip)")
    a = ap.parse_args(argv)
    if not os.path.exists(a.mesh):
        print(f"mesh {a.mesh} not found; nothing to do")
        return 0
    import numba

    V, F = load(a.mesh, a.scale)
    ext = V.max(0) - V.min(0)
    print(f"mesh {os.path.basename(a.mesh)} x{a.scale:g}: {len(V)} vertices, {len(F)} faces, "
          f"extent {ext[0]:.1f} x {ext[1]:.1f} x {ext[2]:.1f} mm; r = {a.radius} mm; "
          f"numba threads {numba.get_num_threads()}")

    t0 = time.perf_counter()
    cut = BallCutter(V, F, a.radius)
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    cut = BallCutter(V, F, a.radius)
    t_build = time.perf_counter() - t0
    print(f"BallCutter build: {t_build:.2f} s (first call incl. numba load/compile {t_first:.2f} s); "
          f"grid {cut._grid[3]} x {cut._grid[4]} cells of {cut._grid[2]:.3f} mm, {len(cut._ctri)} entries")

    xy = raster(V, a.points)
    cut.drop(xy[:1000])  # JIT warm-up
    t0 = time.perf_counter()
    z = cut.drop(xy)
    t_drop = time.perf_counter() - t0
    hit = np.isfinite(z)
    print(f"drop, raster order: {len(xy)} points in {t_drop:.2f} s = {len(xy) / t_drop / 1e6:.2f} M points/s "
          f"({hit.mean() * 100:.1f} % touch the mesh)")
    perm = np.random.default_rng(0).permutation(len(xy))
    t0 = time.perf_counter()
    z2 = cut.drop(xy[perm])
    t_rand = time.perf_counter() - t0
    same = np.array_equal(z2, z[perm])
    print(f"drop, shuffled:     {len(xy)} points in {t_rand:.2f} s = {len(xy) / t_rand / 1e6:.2f} M points/s "
          f"(bit-identical to raster order: {same})")

    # refine on raster lines at 2 mm spacing (coarse chords over the face)
    centres = np.column_stack([xy, z])[hit]
    lines = centres[:: max(1, len(centres) // 50_000)]
    t0 = time.perf_counter()
    ref = cut.refine(lines, tol=0.01)
    t_ref = time.perf_counter() - t0
    print(f"refine tol 0.01: {len(lines)} -> {len(ref)} centres in {t_ref:.2f} s")

    if a.ocl > 0:
        try:
            import opencamlib  # noqa: F401
        except ImportError:
            print("opencamlib not importable: comparison skipped")
            return 0
        sub = np.sort(np.random.default_rng(1).choice(len(xy), size=min(a.ocl, len(xy)), replace=False))
        zc, t_load, t_run = ocl_drop(V, F, a.radius, xy[sub])
        mine = z[sub]
        both = np.isfinite(zc) & np.isfinite(mine)
        agree_inf = np.array_equal(np.isfinite(zc), np.isfinite(mine))
        d = np.abs(zc[both] - mine[both])
        t0 = time.perf_counter()
        cut.drop(xy[sub])
        t_mine = time.perf_counter() - t0
        print(f"OpenCAMLib BatchDropCutter ({len(sub)} points, 2 threads): load {t_load:.2f} s, run {t_run:.2f} s "
              f"= {len(sub) / t_run / 1e3:.1f} k points/s; conformill on the same points {t_mine:.3f} s; "
              f"speed ratio {t_run / t_mine:.0f}x")
        print(f"agreement: max |dz| = {d.max():.3g} mm, mean {d.mean():.3g} mm, "
              f"{(d > 1e-6).sum()} points over 1e-6 mm; same touch/no-touch set: {agree_inf}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
