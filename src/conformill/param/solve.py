"""The sparse linear system of the convex-combination map (METHOD section 1, section 8).

For interior vertices ``I`` and boundary vertices ``B`` with fixed ``U_B``:
``(Id - W_II) U_I = W_IB U_B``, i.e. ``A U_I = -B U_B`` with ``A = Id - W_II`` and ``B = -W_IB``;
both columns (u and v) are solved with one factorization.

Solvers, fastest first as measured on ``large_igea_face_subdiv1.ply`` (310k vertices,
``benchmarks/bench_solvers.py``):

``"pardiso"``
    MKL Pardiso (the ``libmkl_rt`` that pypardiso installs), real non-symmetric, called through
    ctypes by :class:`_Pardiso`: a fresh solver state for every call, the matrix factorized
    explicitly (``pypardiso.spsolve`` keeps the last factorization and can silently reuse it for
    another matrix of the same shape). Importing pypardiso itself costs most of a second.
``"superlu"``
    ``scipy.sparse.linalg.splu`` with the COLAMD ordering: the pure-scipy fallback when
    pypardiso cannot be imported (several times slower and hungrier).
``"gmres_ilu"``
    GMRES preconditioned with an incomplete LU, the paper's kind of solver; for benchmarks only.
"""

from __future__ import annotations

import logging
import os

import numpy as np
from numba import njit

from conformill.errors import ParameterizationError

log = logging.getLogger(__name__)

#: a solve whose relative residual exceeds this raises ParameterizationError
MAX_RESIDUAL = 1e-8
SOLVERS = ("pardiso", "superlu", "gmres_ilu")
#: MKL Pardiso iparm (1-based) tried first: user settings on, the ordering (below), no
#: iterative refinement, pivot perturbation 1e-13, no scaling or weighted matching, two-level
#: parallel factorization. Every solve also sets iparm[34] (reproducibility with a fixed
#: thread count). The ordering ``2: 0`` is documented as minimum degree and as unsupported
#: with the two-level factorization, which allows only nested dissection (``2: 2``, METIS;
#: the parallel one, ``2: 3``, would rule out reproducible results). MKL 2026.2 then uses
#: its nested dissection anyway: the same memory figures (iparm 15-17) and the same solution
#: bits as ``2: 2`` on igea and on the 620k-face mesh with every weight and boundary
#: (session 41), but an analysis a third quicker (0.60 against 0.93 s on the 620k mesh's
#: 308531 unknowns; igea's map 0.44 -> 0.33 s). ``tests/test_param_solve.py`` holds the two
#: to the same solution; an MKL that refuses ``2: 0`` gets ``2: 2`` (:func:`solve_linear`).
PARDISO_FAST = {1: 1, 2: 0, 8: 0, 10: 13, 11: 0, 13: 0, 24: 1}


def _relative_residual(A, X, rhs) -> float:
    nb = np.linalg.norm(rhs)
    return float(np.linalg.norm(A @ X - rhs) / (nb if nb > 0 else 1.0))


def have_pardiso() -> bool:
    """True when MKL Pardiso can be loaded (``libmkl_rt``, as installed with pypardiso)."""
    try:
        _mkl_pardiso()
    except Exception:  # not found, or MKL failing to load
        return False
    return True


_MKL = []


def _mkl_rt_candidates():
    """Where ``libmkl_rt`` may be: ``$PYPARDISO_MKL_RT``, then the interpreter's own lib folders.

    pypardiso's import searches the whole ``sys.prefix`` tree recursively when
    ``ctypes.util.find_library`` fails (the usual case for a pip-installed MKL), which costs most
    of a second; the library is normally right in ``sys.prefix/lib``.
    """
    import glob
    import site
    import sys

    env = os.environ.get("PYPARDISO_MKL_RT")
    if env:
        yield env
    for base in (sys.prefix, getattr(site, "USER_BASE", None) or sys.prefix):
        for pat in ("lib/libmkl_rt.so*", "lib/libmkl_rt*.dylib", "Library/bin/mkl_rt*.dll"):
            yield from sorted(glob.glob(os.path.join(base, pat)), key=len)


def _mkl_pardiso():
    """MKL's ``pardiso`` and ``pardisoinit`` through ctypes (cached); falls back to pypardiso's search."""
    if _MKL:
        return _MKL[0]
    import ctypes

    lib = None
    for path in _mkl_rt_candidates():
        try:
            lib = ctypes.CDLL(path)
            break
        except OSError:
            continue
    if lib is None:  # let pypardiso find it (slow, but it knows more places)
        from pypardiso import PyPardisoSolver

        lib = PyPardisoSolver().libmkl
    fn = lib.pardiso
    fn.restype = None
    fn.argtypes = [ctypes.c_void_p] * 16
    init = lib.pardisoinit
    init.restype = None
    init.argtypes = [ctypes.c_void_p] * 3
    threads = lib.MKL_Set_Num_Threads_Local
    threads.restype = ctypes.c_int
    threads.argtypes = [ctypes.c_int]
    _MKL.append((fn, init, threads))
    return _MKL[0]


def pardiso_threads() -> int:
    """Threads for Pardiso: ``MKL_NUM_THREADS`` (or ``OMP_NUM_THREADS``) when set, else the
    CPUs this process may use.

    The count is fixed for a machine, not taken from its load, and Pardiso runs in MKL's
    conditional numerical reproducibility mode with it (``iparm[34]``): the solution, and
    so the whole program, is then bit-identical from run to run. (Earlier versions used the
    CPUs not busy at the moment and the parallel nested dissection; both made the last
    bits of ``uv``, and so the programs, depend on the machine's load.)
    """
    for var in ("MKL_NUM_THREADS", "OMP_NUM_THREADS"):
        v = os.environ.get(var, "").strip()
        if v.isdigit() and int(v) > 0:
            return int(v)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


class _Pardiso:
    """Minimal MKL Pardiso driver (real, non-symmetric ``mtype 11``), zero-based CSR input.

    One analysis + factorization (phase 12), **one** solve (phase 33, all right-hand sides at
    once), then :meth:`free`. One solve only: with the two-level factorization of
    :data:`PARDISO_FAST` (``iparm[24] = 1``), MKL 2026 returns wrong answers when a later
    solve has fewer right-hand sides than an earlier one. The matrix arrays are held until then, as MKL requires.
    pypardiso does the same but copies and hashes the matrix, shifts the indices to one-based on
    every call and costs most of a second to import.
    """

    def __init__(self, A: CSR, iparm: dict):
        import ctypes

        self._ct = ctypes
        self.fn, init, self._threads = _mkl_pardiso()
        self.n = A.shape[0]
        self.data = np.ascontiguousarray(A.data, dtype=np.float64)
        self.ia = np.ascontiguousarray(A.indptr, dtype=np.int32)
        self.ja = np.ascontiguousarray(A.indices, dtype=np.int32)
        self.pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        if iparm:  # as pypardiso does: zeros, then the given values
            for k, v in iparm.items():
                self.iparm[k - 1] = v
        else:  # MKL's defaults for mtype 11
            init(self.pt.ctypes.data_as(ctypes.c_void_p), ctypes.byref(ctypes.c_int32(11)),
                 self.iparm.ctypes.data_as(ctypes.c_void_p))
        self.iparm[0] = 1  # iparm given
        self.iparm[34] = 1  # zero-based indexing
        self.threads = pardiso_threads()
        # conditional numerical reproducibility with this many threads: the same bits
        # whatever the machine's load (requires the sequential nested dissection)
        if self.iparm[1] == 3:
            self.iparm[1] = 2
        self.iparm[33] = self.threads
        self.active = False
        self.solved = False

    def _call(self, phase: int, b: np.ndarray | None = None, x: np.ndarray | None = None) -> None:
        ct = self._ct
        i32 = ct.c_int32
        err = i32(0)
        nrhs = 1 if b is None or b.ndim == 1 else b.shape[1]
        ptr = lambda a: a.ctypes.data_as(ct.c_void_p)  # noqa: E731
        self.fn(ptr(self.pt), ct.byref(i32(1)), ct.byref(i32(1)), ct.byref(i32(11)), ct.byref(i32(phase)),
                ct.byref(i32(self.n)), ptr(self.data), ptr(self.ia), ptr(self.ja), None, ct.byref(i32(nrhs)),
                ptr(self.iparm), ct.byref(i32(0)), None if b is None else ptr(b), None if x is None else ptr(x),
                ct.byref(err))
        if err.value != 0:
            raise RuntimeError(f"MKL Pardiso phase {phase} failed with error {err.value}")

    def factorize(self) -> None:
        self.active = True
        old = self._threads(self.threads)
        try:
            self._call(12)
        finally:
            self._threads(old)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.solved or not self.active:
            raise RuntimeError("_Pardiso: factorize, then solve once (all right-hand sides together)")
        self.solved = True
        b = np.asfortranarray(rhs, dtype=np.float64)
        x = np.zeros_like(b, order="F")
        self._call(33, b, x)
        return np.ascontiguousarray(x)

    def free(self, quiet: bool = False) -> None:
        """Release MKL's memory; ``quiet``: a failure to do so is logged, not raised (after
        a failed phase, whose error is the one to raise)."""
        if self.active:
            self.active = False
            try:
                self._call(-1)
            except RuntimeError as exc:
                if not quiet:
                    raise
                log.debug("pardiso: release after a failed phase failed too (%s)", exc)


#: below this many unknowns SuperLU wins: loading MKL alone costs about a second
PARDISO_MIN_UNKNOWNS = 50_000


def default_solver(n_unknowns: int | None = None) -> str:
    """``"pardiso"`` when available and the system is large, else ``"superlu"``."""
    if n_unknowns is not None and n_unknowns < PARDISO_MIN_UNKNOWNS:
        return "superlu"
    return "pardiso" if have_pardiso() else "superlu"


class CSR:
    """A bare CSR matrix with sorted column indices: enough for Pardiso, ``@`` and the residual.

    Importing scipy.sparse costs about half a second of the ``conformill param`` run, so
    the parameterization passes these around and converts (:meth:`tocsr`) only for the scipy
    solvers and the public functions that return scipy matrices.
    """

    __slots__ = ("indptr", "indices", "data", "shape")
    format = "csr"
    has_sorted_indices = True

    def __init__(self, indptr, indices, data, shape):
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.data = np.ascontiguousarray(data, dtype=np.float64)
        self.shape = (int(shape[0]), int(shape[1]))

    @property
    def nnz(self) -> int:
        return int(self.indptr[-1])

    def __matmul__(self, X):
        X = np.ascontiguousarray(X, dtype=np.float64)
        Y = _spmm(self.indptr, self.indices, self.data, X.reshape(X.shape[0], -1))
        return Y.reshape((self.shape[0],) + X.shape[1:])

    def tocsr(self):
        import scipy.sparse as sp

        M = sp.csr_matrix((self.data, self.indices, self.indptr), shape=self.shape)
        M.has_sorted_indices = True
        return M

    def tocsc(self):
        return self.tocsr().tocsc()


def _as_csr(W) -> CSR:
    """A :class:`CSR` view of a scipy sparse matrix (sorted indices) or a :class:`CSR`."""
    if isinstance(W, CSR):
        return W
    W = W.tocsr()
    if not W.has_sorted_indices:
        W = W.sorted_indices()
    return CSR(W.indptr, W.indices, W.data, W.shape)


@njit(cache=True)
def _spmm(indptr, indices, data, X):
    """``A @ X`` for CSR ``A`` and dense ``X (k, c)``, summed in index order like scipy."""
    nr = indptr.shape[0] - 1
    c = X.shape[1]
    Y = np.zeros((nr, c))
    for i in range(nr):
        for p in range(indptr[i], indptr[i + 1]):
            a = data[p]
            j = indices[p]
            for t in range(c):
                Y[i, t] += a * X[j, t]
    return Y


@njit(cache=True)
def _split_kernel(indptr, indices, data, interior, newidx, is_int):
    """CSR arrays of ``A = Id - W_II`` and ``W_IB`` (columns sorted) for :func:`split_system`."""
    nI = interior.shape[0]
    a_ptr = np.zeros(nI + 1, dtype=np.int64)
    b_ptr = np.zeros(nI + 1, dtype=np.int64)
    for r in range(nI):
        v = interior[r]
        na = 1
        nb = 0
        for p in range(indptr[v], indptr[v + 1]):
            if is_int[indices[p]]:
                na += 1
            else:
                nb += 1
        a_ptr[r + 1] = a_ptr[r] + na
        b_ptr[r + 1] = b_ptr[r] + nb
    a_ind = np.empty(a_ptr[nI], dtype=np.int64)
    a_val = np.empty(a_ptr[nI])
    b_ind = np.empty(b_ptr[nI], dtype=np.int64)
    b_val = np.empty(b_ptr[nI])
    for r in range(nI):
        v = interior[r]
        qa = a_ptr[r]
        qb = b_ptr[r]
        diag = False
        for p in range(indptr[v], indptr[v + 1]):
            j = indices[p]
            if is_int[j]:
                c = newidx[j]
                if not diag and c > r:
                    a_ind[qa] = r
                    a_val[qa] = 1.0
                    qa += 1
                    diag = True
                a_ind[qa] = c
                a_val[qa] = -data[p]
                qa += 1
            else:
                # boundary columns: insertion sort by position on the boundary
                c = newidx[j]
                x = data[p]
                t = qb
                while t > b_ptr[r] and b_ind[t - 1] > c:
                    b_ind[t] = b_ind[t - 1]
                    b_val[t] = b_val[t - 1]
                    t -= 1
                b_ind[t] = c
                b_val[t] = x
                qb += 1
        if not diag:
            a_ind[qa] = r
            a_val[qa] = 1.0
    return a_ptr, a_ind, a_val, b_ptr, b_ind, b_val


def _split(W, interior: np.ndarray, boundary: np.ndarray):
    """:func:`split_system` as two :class:`CSR` matrices."""
    W = _as_csr(W)
    n = W.shape[0]
    nI = len(interior)
    newidx = np.empty(n, dtype=np.int64)
    newidx[interior] = np.arange(nI)
    newidx[boundary] = np.arange(len(boundary))
    is_int = np.zeros(n, dtype=np.bool_)
    is_int[interior] = True
    a_ptr, a_ind, a_val, b_ptr, b_ind, b_val = _split_kernel(
        W.indptr, W.indices, W.data, np.ascontiguousarray(interior, dtype=np.int64), newidx, is_int)
    return CSR(a_ptr, a_ind, a_val, (nI, nI)), CSR(b_ptr, b_ind, b_val, (nI, len(boundary)))


def split_system(W, interior: np.ndarray, boundary: np.ndarray):
    """``A = Id - W_II`` and ``W_IB`` from the full weight matrix.

    Parameters
    ----------
    W : (n, n) csr_matrix (or :class:`CSR`)
    interior : (nI,) int64
        Increasing vertex ids.
    boundary : (nB,) int64

    Returns
    -------
    A : (nI, nI) csr_matrix
        Columns sorted; the diagonal is 1.
    WB : (nI, nB) csr_matrix
        Columns (positions in ``boundary``) sorted.
    """
    A, WB = _split(W, interior, boundary)
    return A.tocsr(), WB.tocsr()


def solve_linear(A, rhs: np.ndarray, solver: str):
    """Solve ``A X = rhs`` for all columns of ``rhs`` with one factorization.

    Returns
    -------
    X : (nI, k) float64
    """
    if solver == "pardiso":
        A = _as_csr(A)
        if np.any(np.diff(A.indptr) == 0):
            raise ValueError("the matrix has an empty row (singular)")
        # the fast settings; where MKL refuses them (an error), the same with the ordering
        # it documents for the two-level factorization (2: 2, METIS); where a fast solve
        # misses the residual, MKL's defaults (scaling and matching)
        defaults_only = False
        for iparm in (PARDISO_FAST, {**PARDISO_FAST, 2: 2}, {}):
            if iparm and defaults_only:
                continue
            ps = _Pardiso(A, iparm)
            ok = False
            try:
                ps.factorize()
                X = ps.solve(rhs).reshape(rhs.shape)
                ok = True
            except RuntimeError as exc:
                if not iparm:
                    raise
                log.info("pardiso failed with %s (%s); trying the next settings", iparm, exc)
                continue
            finally:
                ps.free(quiet=not ok)  # after a failed phase, the error that counts is that phase's
            # the fast settings skip scaling and matching, safe for the M-matrices of positive
            # weights; anything else (cotangent weights on bad triangles) retries MKL's defaults
            if iparm and _relative_residual(A, X, rhs) > MAX_RESIDUAL:
                log.info("pardiso without scaling/matching missed the residual; retrying with defaults")
                defaults_only = True
                continue
            return X
    if solver in ("superlu", "gmres_ilu"):
        import scipy.sparse.linalg as spla

        A = A.tocsr()
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


def solve_interior(W, boundary: np.ndarray, uv_b: np.ndarray, solver: str | None = None):
    """Positions of all vertices from the weights and the fixed boundary (METHOD section 1).

    Parameters
    ----------
    W : (n, n) csr_matrix or CSR
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
    A, WB = _split(W, interior, boundary)
    rhs = np.ascontiguousarray(WB @ np.ascontiguousarray(uv_b, dtype=np.float64))
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
