"""Speed of the geometry stage: quadratic fit (surface_frame) and point location.

Usage::

    python benchmarks/bench_geometry.py [mesh.ply] [--queries 1000000]

Default mesh: /work/shared/meshes/large_igea_face_subdiv1.ply (310k vertices, 620k faces),
scaled to 120 mm. The parameter domain is a Tutte map (uniform weights, boundary on a
circle by chord length) solved with pypardiso (SuperLU if pypardiso is missing); the real
parameterization lives in conformill.param and is not used here on purpose.

Prints: Tutte solve time, surface_frame time (first call includes JIT unless cached, then
best of 3), locator build + query time for conformill's numba grid and for matplotlib's
TrapezoidMapTriFinder (the reference), and their ratio. Both locators are checked to
agree on which points are inside.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

DEFAULT = Path("/work/shared/meshes/large_igea_face_subdiv1.ply")


def tutte_uv(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Uniform-weight Tutte map with the (single) boundary loop on a circle, chord length."""
    from conformill.mesh.topology import boundary_loops, vertex_adjacency

    n = len(V)
    loop = boundary_loops(F, n)[0]
    seg = np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1)
    L = seg.sum()
    t = 2 * np.pi * np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / L
    R0 = L / (2 * np.pi)
    uv = np.zeros((n, 2))
    uv[loop] = R0 * np.column_stack([np.cos(t), np.sin(t)])
    A = vertex_adjacency(F, n)
    deg = np.asarray(A.sum(axis=1)).ravel()
    is_b = np.zeros(n, dtype=bool)
    is_b[loop] = True
    inner = np.flatnonzero(~is_b)
    Lap = sp.diags(deg) - A
    Aii = Lap[inner][:, inner].tocsr()
    rhs = -(Lap[inner][:, loop] @ uv[loop])
    try:
        import pypardiso

        solver = pypardiso.PyPardisoSolver()  # a fresh solver: no stale factorization
        uv[inner] = solver.solve(Aii, np.ascontiguousarray(rhs))
    except ImportError:  # pragma: no cover
        from scipy.sparse.linalg import splu

        uv[inner] = splu(Aii.tocsc()).solve(rhs)
    return uv


def _best(fn, reps=3):
    best = np.inf
    out = None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=str(DEFAULT))
    ap.add_argument("--queries", type=int, default=1_000_000)
    ap.add_argument("--size", type=float, default=120.0, help="scale the largest extent to this (mm)")
    ap.add_argument("--no-mpl", action="store_true", help="skip the matplotlib reference")
    args = ap.parse_args(argv)

    import trimesh

    from conformill.geometry.differential import surface_frame
    from conformill.geometry.locate import Locator

    if not Path(args.mesh).exists():
        print(f"mesh not found: {args.mesh}")
        return 1
    tm = trimesh.load(args.mesh, process=False)
    V = np.asarray(tm.vertices, dtype=np.float64)
    F = np.asarray(tm.faces, dtype=np.int64)
    V = (V - V.min(0)) * (args.size / np.ptp(V, axis=0).max())
    print(f"mesh {Path(args.mesh).name}: {len(V)} vertices, {len(F)} faces, scaled to {args.size} mm")

    t = time.perf_counter()
    uv = tutte_uv(V, F)
    print(f"Tutte map (uniform weights, circle):  {time.perf_counter() - t:7.3f} s")

    import warnings

    t = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fr = surface_frame(V, F, uv)
    first = time.perf_counter() - t
    for w in caught:
        print(f"  warning: {w.message}")
    best, fr = _best(lambda: surface_frame(V, F, uv))
    print(f"surface_frame first call:             {first:7.3f} s (includes JIT unless cached)")
    print(f"surface_frame best of 3:              {best:7.3f} s  ({best / len(V) * 1e9:.0f} ns/vertex)")
    bad = ~np.isfinite(fr.E)
    print(f"  non-finite frames: {int(bad.sum())}; sigma=sqrt(E) range "
          f"{np.sqrt(np.nanmin(fr.E)):.3g}..{np.sqrt(np.nanmax(fr.E)):.3g}; "
          f"|F|/sqrt(EG) p95 {np.nanpercentile(np.abs(fr.F) / np.sqrt(fr.E * fr.G), 95):.3f}")

    rng = np.random.default_rng(0)
    R0 = np.abs(uv).max()
    # queries: 90% uniform in the bounding square (a part outside the disk), 10% on the boundary
    k = args.queries
    P = rng.uniform(-R0, R0, (k, 2))
    from conformill.mesh.topology import boundary_loops

    loop = boundary_loops(F, len(V))[0]
    nb = k // 10
    e = rng.integers(0, len(loop), nb)
    s = rng.uniform(0, 1, (nb, 1))
    P[:nb] = uv[loop[e]] * (1 - s) + uv[np.roll(loop, -1)[e]] * s

    t = time.perf_counter()
    loc = Locator(uv, F)
    first_build = time.perf_counter() - t
    t = time.perf_counter()
    loc.locate(P[:1000])
    first_q = time.perf_counter() - t
    tb, loc = _best(lambda: Locator(uv, F))
    tq, (face, bary) = _best(lambda: loc.locate(P))
    print(f"Locator first build / first query:    {first_build:7.3f} s / {first_q:.3f} s (JIT unless cached)")
    print(f"Locator build:                        {tb:7.3f} s")
    print(f"Locator {k} queries:                {tq:7.3f} s  ({tq / k * 1e9:.0f} ns/query)")
    print(f"Locator build + queries:              {tb + tq:7.3f} s")
    inside = face >= 0
    rec = np.einsum("ijk,ij->ik", uv[F[face[inside]]], bary[inside])
    print(f"  inside {inside.mean() * 100:.1f} %, boundary points found {np.mean(face[:nb] >= 0) * 100:.2f} %, "
          f"max |uv(bary) - P| = {np.abs(rec - P[inside]).max():.2e}")

    # the same queries sorted along the grid (patterns produce coherent points)
    order = np.lexsort((P[:, 0], np.floor(P[:, 1] * loc._inv)))
    Ps = np.ascontiguousarray(P[order])
    tqs, _ = _best(lambda: loc.locate(Ps))
    print(f"Locator {k} queries, sorted by row: {tqs:7.3f} s")

    if not args.no_mpl:
        from matplotlib.tri import Triangulation, TrapezoidMapTriFinder

        t = time.perf_counter()
        tri = Triangulation(uv[:, 0], uv[:, 1], F)
        finder = TrapezoidMapTriFinder(tri)
        finder(np.zeros(1), np.zeros(1))  # the map is built lazily
        tmb = time.perf_counter() - t
        t = time.perf_counter()
        fm = finder(P[:, 0], P[:, 1])
        tmq = time.perf_counter() - t
        print(f"matplotlib TrapezoidMapTriFinder build: {tmb:7.3f} s, queries {tmq:7.3f} s, "
              f"total {tmb + tmq:7.3f} s (no barycentrics)")
        print(f"  ratio matplotlib / conformill (build + queries): {(tmb + tmq) / (tb + tq):.1f}x")
        agree = np.mean((fm[nb:] >= 0) == (face[nb:] >= 0))
        both = (fm >= 0) & (face >= 0)
        same = np.mean(fm[both] == face[both])
        print(f"  random points: inside/outside agreement {agree * 100:.4f} %; same face where both "
              f"inside {same * 100:.4f} % (others lie on shared edges)")
        print(f"  points on boundary edges found: matplotlib {np.mean(fm[:nb] >= 0) * 100:.1f} %, "
              f"conformill {np.mean(face[:nb] >= 0) * 100:.1f} % (snapping)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
