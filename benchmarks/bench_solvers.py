"""Which sparse solver for the parameterization system (METHOD section 1, section 8)?

Builds the geodesic-weight system with a circle boundary on a mesh (default: the 620k-face
``large_igea_face_subdiv1.ply``) and solves ``A U_I = -B U_B`` (two right-hand sides) with:

- pypardiso, real non-symmetric (mtype 11, MKL defaults: scaling + weighted matching);
- pypardiso, structurally symmetric (mtype 1; the pattern of ``Id - W_II`` is symmetric);
- the package's own driver (``conformill.param.solve._Pardiso``, as the plans call it) with
  ``PARDISO_FAST``, whose ordering ``2: 0`` MKL documents as unsupported under the two-level
  factorization, and with METIS asked for (``2: 2``): MKL 2026.2 uses the same nested
  dissection for both, with a quicker analysis for 0 (session 41); the largest difference of
  the two solutions is printed;
- SuperLU (``splu``, COLAMD);
- GMRES + ILU (the paper's kind of solver; ``--gmres``, slow);
- GMRES + pyamg (``--amg``; only when pyamg is installed).

Each pardiso case uses a fresh ``PyPardisoSolver`` and an explicit ``factorize`` (never
``pypardiso.spsolve``, which can reuse a stale factorization). Prints seconds, the relative
residual and the peak RSS growth of this process.

    python benchmarks/bench_solvers.py [MESH] [--scale S] [--repeat 2] [--gmres] [--amg]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import psutil
import scipy.sparse.linalg as spla

from conformill.mesh.io import read_mesh
from conformill.mesh.topology import boundary_loops
from conformill.param.boundary import circle_map
from conformill.param.solve import PARDISO_FAST, split_system
from conformill.param.weights import interior_weights

DEFAULT = Path("/work/shared/meshes/large_igea_face_subdiv1.ply")


def pardiso(A, rhs, mtype, iparm=None):
    from pypardiso import PyPardisoSolver

    ps = PyPardisoSolver(mtype=mtype)
    ps.set_statistical_info_off()
    for k, v in (iparm or {}).items():
        ps.set_iparm(k, v)
    t0 = time.perf_counter()
    ps.factorize(A)
    t1 = time.perf_counter()
    X = ps.solve(A, rhs)
    t2 = time.perf_counter()
    ps.free_memory(everything=True)
    return X, f"factor {t1 - t0:.2f} s + solve {t2 - t1:.2f} s"


def own_driver(A, rhs, iparm):
    from conformill.param.solve import _Pardiso

    ps = _Pardiso(A, iparm)
    t0 = time.perf_counter()
    ps.factorize()
    t1 = time.perf_counter()
    X = ps.solve(rhs)
    t2 = time.perf_counter()
    ps.free()
    return X, f"analysis + factor {t1 - t0:.2f} s + solve {t2 - t1:.2f} s"


def superlu(A, rhs):
    t0 = time.perf_counter()
    lu = spla.splu(A.tocsc(), permc_spec="COLAMD")
    t1 = time.perf_counter()
    X = lu.solve(rhs)
    return X, f"factor {t1 - t0:.2f} s + solve {time.perf_counter() - t1:.2f} s"


def gmres_with(A, rhs, M, label):
    cols, its = [], []
    for j in range(rhs.shape[1]):
        count = [0]

        def cb(_r, count=count):
            count[0] += 1

        x, info = spla.gmres(A, rhs[:, j], M=M, rtol=1e-12, atol=0.0, restart=50, maxiter=400,
                             callback=cb, callback_type="pr_norm")
        cols.append(x)
        its.append((count[0], info))
    return np.column_stack(cols), f"{label}; iterations/info {its}"


def gmres_ilu(A, rhs):
    t0 = time.perf_counter()
    ilu = spla.spilu(A.tocsc(), drop_tol=1e-4, fill_factor=5)
    M = spla.LinearOperator(A.shape, ilu.solve)
    return gmres_with(A, rhs, M, f"ILU {time.perf_counter() - t0:.2f} s")


def gmres_amg(A, rhs):
    import pyamg

    t0 = time.perf_counter()
    ml = pyamg.ruge_stuben_solver(A.tocsr())
    M = ml.aspreconditioner()
    return gmres_with(A, rhs, M, f"AMG setup {time.perf_counter() - t0:.2f} s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=str(DEFAULT))
    ap.add_argument("--scale", type=float, default=1400.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--gmres", action="store_true", help="also GMRES + ILU (minutes)")
    ap.add_argument("--amg", action="store_true", help="also GMRES + pyamg (needs pyamg)")
    args = ap.parse_args(argv)

    mesh = read_mesh(args.mesh, scale=args.scale)
    loop = boundary_loops(mesh.F, mesh.n_vertices)[0]
    mask = np.zeros(mesh.n_vertices, dtype=bool)
    mask[loop] = True
    W, _ = interior_weights(mesh.V, mesh.F, mask, "geodesic")
    uv_b, _ = circle_map(mesh.V, loop)
    A, WB = split_system(W, np.flatnonzero(~mask), loop)
    rhs = np.ascontiguousarray(WB @ uv_b)
    print(f"{Path(args.mesh).name}: {A.shape[0]} unknowns, {A.nnz} non-zeros, 2 right-hand sides")

    cases = [
        ("pardiso mtype 11 (non-symmetric)", lambda: pardiso(A, rhs, 11)),
        ("pardiso mtype 1 (struct. symmetric)", lambda: pardiso(A, rhs, 1)),
        ("pardiso mtype 11, PARDISO_FAST iparm", lambda: pardiso(A, rhs, 11, PARDISO_FAST)),
        (f"own driver, PARDISO_FAST (2: {PARDISO_FAST[2]})", lambda: own_driver(A, rhs, PARDISO_FAST)),
        ("own driver, PARDISO_FAST with 2: 2", lambda: own_driver(A, rhs, {**PARDISO_FAST, 2: 2})),
        ("superlu COLAMD", lambda: superlu(A, rhs)),
    ]
    if args.gmres:
        cases.append(("gmres + ilu", lambda: gmres_ilu(A, rhs)))
    if args.amg:
        cases.append(("gmres + pyamg (classical)", lambda: gmres_amg(A, rhs)))
    proc = psutil.Process()
    nb = np.linalg.norm(rhs)
    print(f"{'solver':38s} {'best s':>8s} {'residual':>10s} {'RSS MB':>8s}  detail")
    own = {}
    for name, fn in cases:
        times = []
        for _ in range(args.repeat if "gmres" not in name else 1):
            rss0 = proc.memory_info().rss
            t0 = time.perf_counter()
            X, detail = fn()
            times.append(time.perf_counter() - t0)
            rss = (proc.memory_info().rss - rss0) / 2**20
        res = np.linalg.norm(A @ X - rhs) / nb
        print(f"{name:38s} {min(times):8.2f} {res:10.1e} {rss:8.0f}  {detail} (all: {', '.join(f'{t:.2f}' for t in times)})")
        if name.startswith("own driver"):
            own[name] = (min(times), X)
    if len(own) == 2:
        (t0, X0), (t2, X2) = own.values()
        print(f"own driver: 2: {PARDISO_FAST[2]} takes {t0 / t2:.2f}x the time of 2: 2; largest difference of the solutions "
              f"{np.abs(X0 - X2).max():.3g} (bit-identical: {np.array_equal(X0, X2)})")


if __name__ == "__main__":
    main()
