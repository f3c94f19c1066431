"""Benchmark and independence check of ``conformill verify``.

1. An OpenCAMLib raster program (ball cutter, BatchDropCutter along parallel lines at the
   flat-scallop stepover, G-code written here) on a real scanned mesh is verified with
   :func:`conformill.verify.simulate.verify`, and its scallop figures are compared with two
   computations that share nothing with it:
   a. brute force: for a subset of samples, the ray entry into every capsule (no index,
      Inigo Quilez's closed-form capsule intersection, a different formula);
   b. a Z-map (height field of dexels): the balls of dense centre samples along the feed
      moves are splatted onto a grid, the lowest cut height above each sample is
      interpolated and converted to a thickness along the normal (``dz * n_z``).
2. Timing: 1M samples on face_igea_cut.ply (155k faces, x1400) with an OpenCAMLib raster.

Usage: ``python benchmarks/bench_verify.py [--quick]``. Needs opencamlib and the shared
meshes (/work/shared/meshes or $CONFORMILL_MESHES).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numba as nb
import numpy as np

MESHES = Path(os.environ.get("CONFORMILL_MESHES", "/work/shared/meshes"))


def load(name, scale, rotate_face_to_z=False):
    from conformill.mesh.io import read_mesh
    from conformill.types import Mesh

    m = read_mesh(MESHES / name, scale=scale, validate=False)
    V = m.V.copy()
    if rotate_face_to_z:  # the scan looks along -Y: turn it to look along +Z
        V = np.column_stack([V[:, 0], V[:, 2], -V[:, 1]])
    V -= [V[:, 0].mean(), V[:, 1].mean(), V[:, 2].max()]
    return Mesh(V=V, F=m.F, name=m.name)


def ocl_raster(mesh, r, h, sampling, margin=None):
    """Parallel passes along Y at the flat-scallop stepover; returns G-code text and figures."""
    import opencamlib as ocl

    t0 = time.perf_counter()
    s = ocl.STLSurf()
    for a, b, c in mesh.V[mesh.F]:
        s.addTriangle(ocl.Triangle(ocl.Point(*a), ocl.Point(*b), ocl.Point(*c)))
    cutter = ocl.BallCutter(2 * r, 10 * r)
    w = 2 * math.sqrt(2 * r * h - h * h)  # flat scallop: h = r - sqrt(r^2 - w^2/4)
    lo, hi = mesh.V.min(0), mesh.V.max(0)
    margin = r if margin is None else margin
    xs = np.arange(lo[0] - margin, hi[0] + margin + 1e-9, w)
    ys = np.arange(lo[1] - margin, hi[1] + margin + 1e-9, sampling)
    zmin = lo[2] - 2 * r
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(s)
    bdc.setCutter(cutter)
    for x in xs:
        for y in ys:
            bdc.appendPoint(ocl.CLPoint(float(x), float(y), float(zmin)))
    bdc.run()
    cl = np.array([(p.x, p.y, p.z) for p in bdc.getCLPoints()]).reshape(len(xs), len(ys), 3)
    t_ocl = time.perf_counter() - t0
    safe = hi[2] + 5.0
    out = ["(OpenCAMLib BatchDropCutter raster, ball r = %g mm, stepover %.4f mm)" % (r, w), "G21 G90 G17",
           f"G0 Z{safe:.4f}"]
    for i, row in enumerate(cl):
        row = row if i % 2 == 0 else row[::-1]
        out.append(f"G0 X{row[0, 0]:.4f} Y{row[0, 1]:.4f}")
        out.append(f"G1 Z{row[0, 2]:.4f} F1000")
        out += [f"X{x:.4f} Y{y:.4f} Z{z:.4f}" for x, y, z in row[1:]]
        out.append(f"G0 Z{safe:.4f}")
    out.append("M30")
    return "\n".join(out) + "\n", w, t_ocl, cl.shape[0] * cl.shape[1]


# ---- independent computation a: brute force with Quilez's capsule intersection --------


@nb.njit(cache=True, parallel=True)
def brute_force(P, N, A, B, r, tcap):
    n = P.shape[0]
    out = np.full(n, np.inf)
    for i in nb.prange(n):
        best = np.inf
        ro = P[i]
        rd = N[i]
        for j in range(A.shape[0]):
            pa = A[j]
            pb = B[j]
            ba = pb - pa
            oa = ro - pa
            # inside the capsule already?
            hh = min(max(np.dot(oa, ba) / max(np.dot(ba, ba), 1e-300), 0.0), 1.0)
            dv = oa - hh * ba
            if np.dot(dv, dv) <= r * r:
                best = 0.0
                break
            baba = np.dot(ba, ba)
            bard = np.dot(ba, rd)
            baoa = np.dot(ba, oa)
            rdoa = np.dot(rd, oa)
            oaoa = np.dot(oa, oa)
            a = baba - bard * bard
            b = baba * rdoa - baoa * bard
            c = baba * oaoa - baoa * baoa - r * r * baba
            h = b * b - a * c
            t = np.inf
            if h >= 0.0 and a > 1e-12:
                tt = (-b - math.sqrt(h)) / a
                y = baoa + tt * bard
                if 0.0 < y < baba and tt >= 0.0:
                    t = tt
            if t == np.inf:
                # caps
                for cap in range(2):
                    oc = oa if cap == 0 else ro - pb
                    bb = np.dot(rd, oc)
                    cc = np.dot(oc, oc) - r * r
                    hc = bb * bb - cc
                    if hc > 0.0:
                        tt = -bb - math.sqrt(hc)
                        if 0.0 <= tt < t:
                            t = tt
            if t < best:
                best = t
        out[i] = best if best <= tcap else np.inf
    return out


# ---- independent computation b: Z-map (dexels) ---------------------------------------


@nb.njit(cache=True)
def splat(H, x0, y0, g, C, r):
    """H[iy, ix] = min over balls of (centre z - sqrt(r^2 - d^2)): lowest cut height."""
    ny, nx = H.shape
    k = int(math.ceil(r / g))
    for b in range(C.shape[0]):
        cx, cy, cz = C[b, 0], C[b, 1], C[b, 2]
        ix0 = int((cx - x0) / g)
        iy0 = int((cy - y0) / g)
        for iy in range(max(iy0 - k, 0), min(iy0 + k + 2, ny)):
            dy = y0 + iy * g - cy
            for ix in range(max(ix0 - k, 0), min(ix0 + k + 2, nx)):
                dx = x0 + ix * g - cx
                d2 = dx * dx + dy * dy
                if d2 < r * r:
                    z = cz - math.sqrt(r * r - d2)
                    if z < H[iy, ix]:
                        H[iy, ix] = z


def zmap_thickness(P, N, A, B, r, window, g=0.04, step=0.04):
    """Remaining thickness along the normal from a Z-map of the balls along the segments."""
    (x0, x1), (y0, y1) = window
    L = np.linalg.norm(B - A, axis=1)
    m = np.maximum(1, np.ceil(L / step).astype(np.int64))
    sid = np.repeat(np.arange(len(A)), m + 1)
    off = np.cumsum(m + 1) - (m + 1)
    t = (np.arange(sid.size) - np.repeat(off, m + 1)) / np.repeat(m, m + 1)
    C = A[sid] + t[:, None] * (B - A)[sid]
    keep = (C[:, 0] > x0 - r - g) & (C[:, 0] < x1 + r + g) & (C[:, 1] > y0 - r - g) & (C[:, 1] < y1 + r + g)
    C = np.ascontiguousarray(C[keep])
    nx, ny = int((x1 - x0) / g) + 2, int((y1 - y0) / g) + 2
    H = np.full((ny, nx), np.inf)
    splat(H, x0, y0, g, C, r)
    fx = (P[:, 0] - x0) / g
    fy = (P[:, 1] - y0) / g
    ix, iy = np.floor(fx).astype(int), np.floor(fy).astype(int)
    ax, ay = fx - ix, fy - iy
    z = ((1 - ax) * (1 - ay) * H[iy, ix] + ax * (1 - ay) * H[iy, ix + 1]
         + (1 - ax) * ay * H[iy + 1, ix] + ax * ay * H[iy + 1, ix + 1])
    return np.maximum(z - P[:, 2], 0.0) * N[:, 2], len(C)


def pct(x):
    x = x[np.isfinite(x)]
    return np.percentile(x, [50, 99, 99.9]).tolist() + [float(x.max())]


@nb.njit(parallel=True, cache=True)
def brute_gouge(P, A, B, r):
    """max_j (r - dist(p, segment_j)), no index: the deepest cut below each sample."""
    n = P.shape[0]
    out = np.zeros(n)
    for i in nb.prange(n):
        best = 0.0
        for j in range(A.shape[0]):
            ba = B[j] - A[j]
            pa = P[i] - A[j]
            hh = min(max(np.dot(pa, ba) / max(np.dot(ba, ba), 1e-300), 0.0), 1.0)
            dv = pa - hh * ba
            g = r - math.sqrt(np.dot(dv, dv))
            if g > best:
                best = g
        out[i] = best
    return out


def check_independence(quick, source="ocl"):
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    r, h = 3.0, 0.02
    mesh = load("face_nefertiti_cut.ply", 1.0, rotate_face_to_z=True)
    ext = mesh.V.max(0) - mesh.V.min(0)
    print(f"\n== {source} program ==\nmesh {mesh.name}: {mesh.n_faces} faces, {ext[0]:.1f} x {ext[1]:.1f} x "
          f"{ext[2]:.1f} mm (rotated to look along +Z)")
    if source == "ocl":
        text, w, t_ocl, n_cl = ocl_raster(mesh, r, h, sampling=0.25 if quick else 0.1)
        print(f"OpenCAMLib raster: stepover {w:.4f} mm (flat scallop {h} mm), {n_cl} CL points, {t_ocl:.1f} s")
    else:
        import tempfile

        from conformill.output.gcode import write_gcode
        from conformill.pipeline import Job, plan

        t0 = time.perf_counter()
        res_ = plan(mesh, Job(pattern="spiral", tool_radius=r, scallop=h, tolerance=0.01))
        with tempfile.TemporaryDirectory() as d:
            write_gcode(f"{d}/p.nc", res_.toolpath, feed=1000.0)
            text = open(f"{d}/p.nc").read()
        print(f"conformill spiral: {sum(len(p) for p in res_.toolpath.passes)} CL points, "
              f"{time.perf_counter() - t0:.1f} s")
    prog = read_gcode(text)
    n = 200_000 if quick else 1_000_000
    t0 = time.perf_counter()
    res = verify(mesh, prog, r, n_samples=n, seed=0, scallop=h)
    t_ver = time.perf_counter() - t0
    s = res.summary
    print(f"verify: {n} samples in {t_ver:.1f} s; interior scallop p50/p99/p99.9/max = "
          + " / ".join(f"{s['scallop'][k]:.5f}" for k in ("p50", "p99", "p999", "max"))
          + f" mm, uncut {100 * s['uncut_fraction']:.3f} %, gouge max {s['gouge_max']:.2e} mm, "
          f"rapid clearance {s['rapid_min_clearance']:.3f} mm")

    A, B = prog.segments(1)
    A = A + [0, 0, r]
    B = B + [0, 0, r]
    S = res.samples
    # a. brute force on a subset
    rng = np.random.default_rng(1)
    sub = rng.choice(np.flatnonzero(res.interior), 2000 if quick else 5000, replace=False)
    t0 = time.perf_counter()
    bf = brute_force(S.points[sub], S.normals[sub], A, B, r, 2 * r)
    t_bf = time.perf_counter() - t0
    mine = res.remaining[sub]
    both = np.isfinite(bf) & np.isfinite(mine)
    same_uncut = np.array_equal(np.isfinite(bf), np.isfinite(mine))
    err = np.abs(bf[both] - mine[both]).max()
    print(f"a. brute force ({len(sub)} samples x {len(A)} capsules, no index, Quilez's formula, {t_bf:.1f} s): "
          f"max |difference| {err:.2e} mm, same uncut set: {same_uncut}")
    print("   subset percentiles verify     : " + " / ".join(f"{v:.5f}" for v in pct(mine)))
    print("   subset percentiles brute force: " + " / ".join(f"{v:.5f}" for v in pct(bf)))
    bg = brute_gouge(S.points[sub], A, B, r)
    print(f"   gouge on the subset: verify max {res.gouge[sub].max():.3e} mm, brute force max {bg.max():.3e} mm, "
          f"max |difference| {np.abs(bg - res.gouge[sub]).max():.2e} mm")
    # b. Z-map in a central window, on samples whose normal is within 30 degrees of Z
    c = mesh.V.mean(0)
    win = ((c[0] - 25, c[0] + 25), (c[1] - 25, c[1] + 25))
    P, N = S.points, S.normals
    inw = (res.interior & (P[:, 0] > win[0][0] + 0.1) & (P[:, 0] < win[0][1] - 0.1) & (P[:, 1] > win[1][0] + 0.1)
           & (P[:, 1] < win[1][1] - 0.1) & (N[:, 2] > math.cos(math.radians(30))) & np.isfinite(res.remaining))
    t0 = time.perf_counter()
    zt, nballs = zmap_thickness(P[inw], N[inw], A, B, r, win)
    t_z = time.perf_counter() - t0
    # b1. the same quantity both ways: vertical thickness (verify's kernel with rays along +Z)
    from conformill.verify.samples import SurfaceSamples
    from conformill.verify.simulate import remaining_material

    up = np.tile([0.0, 0.0, 1.0], (int(inw.sum()), 1))
    tv, *_ = remaining_material(SurfaceSamples.from_arrays(P[inw], up), prog, r)
    zv = zt / N[inw, 2]
    ok = np.isfinite(tv)
    a_, b_ = pct(tv[ok]), pct(zv[ok])
    print(f"b. Z-map (dexels 0.04 mm, {nballs} balls every 0.04 mm, window 50 x 50 mm, {inw.sum()} interior "
          f"samples with n_z > cos 30 deg, {t_z:.1f} s)")
    print("   b1. vertical thickness, verify kernel  p50/p99/p99.9/max: " + " / ".join(f"{v:.5f}" for v in a_))
    print("       vertical thickness, Z-map          p50/p99/p99.9/max: " + " / ".join(f"{v:.5f}" for v in b_))
    print("       relative difference                                 : "
          + " / ".join(f"{100 * (y - x) / x:+.2f} %" for x, y in zip(a_, b_))
          + f"; max |diff| {np.abs(tv[ok] - zv[ok]).max():.2e} mm")
    a_, b_ = pct(res.remaining[inw]), pct(zt)
    print("   b2. along the normal, verify            p50/p99/p99.9/max: " + " / ".join(f"{v:.5f}" for v in a_))
    print("       Z-map thickness x n_z              p50/p99/p99.9/max: " + " / ".join(f"{v:.5f}" for v in b_))
    print("       relative difference                                 : "
          + " / ".join(f"{100 * (y - x) / x:+.2f} %" for x, y in zip(a_, b_)))
    sc = res.remaining[inw] < 2 * h
    print(f"       where verify < 2h ({100 * sc.mean():.1f} % of them, the scallop regime): mean "
          f"{res.remaining[inw][sc].mean():.5f} vs {zt[sc].mean():.5f} mm, p99 "
          f"{np.percentile(res.remaining[inw][sc], 99):.5f} vs {np.percentile(zt[sc], 99):.5f} mm")


def time_igea(quick):
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    r, h = 3.0, 0.01
    mesh = load("face_igea_cut.ply", 1400.0)
    ext = mesh.V.max(0) - mesh.V.min(0)
    text, w, t_ocl, n_cl = ocl_raster(mesh, r, h, sampling=0.3)
    prog = read_gcode(text)
    print(f"\nmesh {mesh.name} x1400: {mesh.n_faces} faces, {ext[0]:.1f} x {ext[1]:.1f} x {ext[2]:.1f} mm; "
          f"OpenCAMLib raster {n_cl} CL points, stepover {w:.3f} mm ({t_ocl:.1f} s)")
    t0 = time.perf_counter()
    prog = read_gcode(text)
    t_read = time.perf_counter() - t0
    n = 200_000 if quick else 1_000_000
    for _ in range(2):  # the first run may include numba's compilation/cache load
        t0 = time.perf_counter()
        res = verify(mesh, prog, r, n_samples=n, seed=0, scallop=h)
        t = time.perf_counter() - t0
    s = res.summary
    print(f"read_gcode {len(prog)} moves: {t_read:.2f} s; verify {n} samples: {t:.1f} s "
          f"(budget 60 s); scallop p50/p99/p99.9/max = "
          + " / ".join(f"{s['scallop'][k]:.4f}" for k in ("p50", "p99", "p999", "max"))
          + f" mm, uncut {100 * s['uncut_fraction']:.3f} %, rapid clearance {s['rapid_min_clearance']:.2f} mm")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples, coarser program")
    args = ap.parse_args(argv)
    if not MESHES.is_dir():
        print(f"no meshes at {MESHES}", file=sys.stderr)
        return 1
    check_independence(args.quick, "ocl")
    check_independence(args.quick, "conformill")
    time_igea(args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
