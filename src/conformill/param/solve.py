"""The sparse linear system of the convex-combination map (METHOD section 1, section 8).

For interior vertices ``I`` and boundary vertices ``B`` with fixed ``U_B``:
``(Id - W_II) U_I = W_IB U_B``, i.e. ``A U_I = -B U_B`` with ``A = Id - W_II`` and ``B = -W_IB``;
both columns (u and v) are solved with one factorization.

Solvers, fastest first as measured on ``large_igea_face_subdiv1.ply`` (310k vertices,
``benchmarks/bench_solvers.py``):

``"pardiso"``
    MKL Pardiso through ``pypardiso``, real non-symmetric. A fresh ``PyPardisoSolver`` is made for
    every call and the matrix factorized explicitly: ``pypardiso.spsolve`` keeps the last
    factorization and can silently reuse it for another matrix of the same shape.
``"superlu"``
    ``scipy.sparse.linalg.splu`` with the COLAMD ordering: the pure-scipy fallback when
    pypardiso cannot be imported (several times slower and hungrier).
``"gmres_ilu"``
    GMRES preconditioned with an incomplete LU, the paper's kind of solver; for benchmarks only.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from conformill.errors import ParameterizationError

log = logging.getLogger(__name__)

#: a solve whose relative residual exceeds this raises ParameterizationError
MAX_RESIDUAL = 1e-8
SOLVERS = ("pardiso", "superlu", "gmres_ilu")
#: MKL Pardiso iparm (1-based) tried first: user settings on, parallel nested dissection, no
#: iterative refinement, pivot perturbation 1e-13, no scaling or weighted matching, two-level
#: parallel factorization. On the 620k-face mesh: factor 1.0 s + solve 0.05 s against
#: 1.05 s + 0.2 s with the defaults (benchmarks/bench_solvers.py).
PARDISO_FAST = {1: 1, 2: 3, 8: 0, 10: 13, 11: 0, 13: 0, 24: 1}


def _relative_residual(A, X, rhs) -> float:
    nb = np.linalg.norm(rhs)
    return float(np.linalg.norm(A @ X - rhs) / (nb if nb > 0 else 1.0))


def have_pardiso() -> bool:
    """True when pypardiso (MKL) can be imported."""
    try:
        import pypardiso  # noqa: F401
    except Exception:  # ImportError, or MKL failing to load
        return False
    return True


#: below this many unknowns SuperLU wins: loading MKL alone costs about a second
PARDISO_MIN_UNKNOWNS = 50_000


def default_solver(n_unknowns: int | None = None) -> str:
    """``"pardiso"`` when available and the system is large, else ``"superlu"``."""
    if n_unknowns is not None and n_unknowns < PARDISO_MIN_UNKNOWNS:
        return "superlu"
    return "pardiso" if have_pardiso() else "superlu"


def split_system(W: sp.csr_matrix, interior: np.ndarray, boundary: np.ndarray):
    """``A = Id - W_II`` and ``W_IB`` from the full weight matrix.

    Parameters
    ----------
    W : (n, n) csr_matrix
    interior : (nI,) int64
    boundary : (nB,) int64

    Returns
    -------
    A : (nI, nI) csr_matrix
    WB : (nI, nB) csr_matrix
    """
    n = W.shape[0]
    nI = len(interior)
    newidx = np.empty(n, dtype=np.int64)
    newidx[interior] = np.arange(nI)
    newidx[boundary] = np.arange(len(boundary))
    is_int = np.zeros(n, dtype=bool)
    is_int[interior] = True
    Wi = W[interior]
    rows = np.repeat(np.arange(nI), np.diff(Wi.indptr))
    cols = Wi.indices
    ci = is_int[cols]
    A = sp.csr_matrix(
        (
            np.concatenate([np.ones(nI), -Wi.data[ci]]),
            (np.concatenate([np.arange(nI), rows[ci]]), np.concatenate([np.arange(nI), newidx[cols[ci]]])),
        ),
        shape=(nI, nI),
    )
    A.sum_duplicates()
    cb = ~ci
    WB = sp.csr_matrix((Wi.data[cb], (rows[cb], newidx[cols[cb]])), shape=(nI, len(boundary)))
    return A, WB


def solve_linear(A: sp.csr_matrix, rhs: np.ndarray, solver: str):
    """Solve ``A X = rhs`` for all columns of ``rhs`` with one factorization.

    Returns
    -------
    X : (nI, k) float64
    """
    if solver == "pardiso":
        from pypardiso import PyPardisoSolver

        for iparm in (PARDISO_FAST, {}):
            ps = PyPardisoSolver(mtype=11)
            ps.set_statistical_info_off()
            for k, v in iparm.items():
                ps.set_iparm(k, v)
            try:
                ps.factorize(A)
                X = np.asarray(ps.solve(A, rhs)).reshape(rhs.shape)
            finally:
                ps.free_memory(everything=True)
            # the fast settings skip scaling and matching, safe for the M-matrices of positive
            # weights; anything else (cotangent weights on bad triangles) retries MKL's defaults
            if iparm and _relative_residual(A, X, rhs) > MAX_RESIDUAL:
                log.info("pardiso without scaling/matching missed the residual; retrying with defaults")
                continue
            return X
    if solver == "superlu":
        lu = spla.splu(A.tocsc(), permc_spec="COLAMD")
        return lu.solve(rhs)
    if solver == "gmres_ilu":
        ilu = spla.spilu(A.tocsc(), drop_tol=1e-5, fill_factor=10)
        M = spla.LinearOperator(A.shape, ilu.solve)
        cols = []
        for j in range(rhs.shape[1]):
            x, info = spla.gmres(A, rhs[:, j], M=M, rtol=1e-12, atol=0.0, restart=100, maxiter=2000)
            if info != 0:
                log.warning("GMRES did not converge (info %d)", info)
            cols.append(x)
        return np.column_stack(cols)
    raise ParameterizationError(f"unknown solver {solver!r}: choose one of {', '.join(SOLVERS)}")


def solve_interior(W: sp.csr_matrix, boundary: np.ndarray, uv_b: np.ndarray, solver: str | None = None):
    """Positions of all vertices from the weights and the fixed boundary (METHOD section 1).

    Parameters
    ----------
    W : (n, n) csr_matrix
        Interior rows sum to 1; boundary rows are ignored.
    boundary : (b,) int64
        Boundary vertex ids.
    uv_b : (b, 2) float64
        Their fixed parameter positions.
    solver : {"pardiso", "superlu", "gmres_ilu"}, optional
        Default: :func:`default_solver` (pardiso from 50k unknowns when importable, else
        superlu).

    Returns
    -------
    uv : (n, 2) float64
    residual : float
        Relative residual ``|A U_I + B U_B| / |B U_B|`` (Frobenius, both columns).
    solver : str
        The solver used.

    Raises
    ------
    ParameterizationError
        The residual exceeds :data:`MAX_RESIDUAL`, or the solver failed (singular system).
    """
    n = W.shape[0]
    solver = solver or default_solver(n - len(boundary))
    boundary = np.asarray(boundary, dtype=np.int64)
    mask = np.zeros(n, dtype=bool)
    mask[boundary] = True
    interior = np.flatnonzero(~mask)
    uv = np.zeros((n, 2), dtype=np.float64)
    uv[boundary] = uv_b
    if len(interior) == 0:
        return uv, 0.0, solver
    A, WB = split_system(W, interior, boundary)
    rhs = np.ascontiguousarray(WB @ uv_b)
    try:
        X = solve_linear(A, rhs, solver)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        raise ParameterizationError(f"the {solver} solve failed: {exc}") from None
    res = _relative_residual(A, X, rhs)
    if not np.isfinite(res) or res > MAX_RESIDUAL:
        raise ParameterizationError(
            f"the {solver} solve has relative residual {res:.3g} > {MAX_RESIDUAL:g} "
            f"({len(interior)} unknowns): the system is singular or badly conditioned"
        )
    uv[interior] = X
    return uv, res, solver
