"""The sparse system: bare CSR, split, MKL Pardiso through ctypes (METHOD section 1)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from conformill.mesh import synthetic as syn
from conformill.mesh.topology import boundary_loops
from conformill.param import solve as S
from conformill.param.boundary import circle_map
from conformill.param.weights import interior_weights


def _system(kind="geodesic"):
    m = syn.freeform_patch(spacing=2.5)
    loop = boundary_loops(m.F, m.n_vertices)[0]
    mask = np.zeros(m.n_vertices, dtype=bool)
    mask[loop] = True
    W, _ = interior_weights(m.V, m.F, mask, kind)
    uv_b, _ = circle_map(m.V, loop)
    return W, np.flatnonzero(~mask), loop, uv_b


def ref_split(W, interior, boundary):
    """The previous scipy construction of A = Id - W_II and W_IB."""
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
    A = sp.csr_matrix((np.concatenate([np.ones(nI), -Wi.data[ci]]),
                       (np.concatenate([np.arange(nI), rows[ci]]), np.concatenate([np.arange(nI), newidx[cols[ci]]]))),
                      shape=(nI, nI))
    A.sum_duplicates()
    cb = ~ci
    WB = sp.csr_matrix((Wi.data[cb], (rows[cb], newidx[cols[cb]])), shape=(nI, len(boundary)))
    return A, WB


def test_split_system_is_the_scipy_construction_exactly():
    W, interior, loop, uv_b = _system()
    A, WB = S.split_system(W, interior, loop)
    Ar, WBr = ref_split(W, interior, loop)
    for M, R in ((A, Ar), (WB, WBr)):
        R.sort_indices()
        assert np.array_equal(M.indptr, R.indptr) and np.array_equal(M.indices, R.indices)
        assert np.array_equal(M.data, R.data)
    # the right-hand side as scipy computes it, to the bit
    Ac, WBc = S._split(W, interior, loop)
    assert np.array_equal(WBc @ uv_b, WBr @ uv_b)
    X = np.random.default_rng(0).normal(size=(len(interior), 2))
    assert np.array_equal(Ac @ X, Ar @ X)
    assert np.array_equal(Ac @ X[:, 0], Ar @ X[:, 0])


def test_csr_round_trip():
    W, *_ = _system("mean_value")
    C = S._as_csr(W)
    assert C.nnz == W.nnz and C.shape == W.shape
    assert abs(C.tocsr() - W).max() == 0


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
@pytest.mark.parametrize("iparm", [S.PARDISO_FAST, {}])
def test_pardiso_ctypes_matches_superlu(iparm):
    W, interior, loop, uv_b = _system()
    A, WB = S._split(W, interior, loop)
    rhs = WB @ uv_b
    ps = S._Pardiso(A, iparm)
    try:
        ps.factorize()
        X = ps.solve(rhs)
        with pytest.raises(RuntimeError, match="solve once"):
            ps.solve(rhs[:, 1])  # MKL's two-level factorization gets this wrong
    finally:
        ps.free()
    ref = S.solve_linear(A, rhs, "superlu")
    assert np.abs(X - ref).max() < 1e-9
    if not iparm:
        assert ps.iparm[9] == 13  # pardisoinit's defaults were used (pivot perturbation 1e-13)


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
@pytest.mark.parametrize("kind", ["geodesic", "cotangent", "mean_value"])
def test_the_fast_ordering_gives_the_nested_dissection_solution(kind):
    """``PARDISO_FAST`` sets the ordering ``2: 0`` (documented as minimum degree, and as
    unsupported with the two-level factorization); MKL 2026.2 then uses its nested
    dissection, as with ``2: 2``, only its analysis is quicker (session 41): the same bits.
    Held here to the same solution within rounding, so that another MKL whose ordering
    differs still passes."""
    W, interior, loop, uv_b = _system(kind)
    A, WB = S._split(W, interior, loop)
    rhs = WB @ uv_b
    X = {}
    for order in (0, 2):
        ps = S._Pardiso(A, {**S.PARDISO_FAST, 2: order})
        try:
            ps.factorize()
            X[order] = ps.solve(rhs)
        finally:
            ps.free()
    assert S._relative_residual(A, X[0], rhs) < 1e-12
    assert np.abs(X[0] - X[2]).max() <= 1e-12 * np.abs(X[2]).max()


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
@pytest.mark.parametrize("refused, used", [("ordering 0", (2, 1)), ("two-level", (2, 0))])
def test_an_mkl_refusing_the_fast_settings_is_asked_again(monkeypatch, refused, used):
    """``PARDISO_FAST`` relies on how MKL 2026.2 reads the ordering ``2: 0`` under the
    two-level factorization (documented as unsupported). An MKL that returns an error for it
    is asked with the documented ``2: 2``; one that refuses the two-level factorization too
    gets its defaults. ``used``: the (ordering, two-level) of the settings that solved."""
    W, interior, loop, uv_b = _system()
    A, WB = S._split(W, interior, loop)
    rhs = WB @ uv_b
    real = S._Pardiso._call
    tried = []

    def call(self, phase, b=None, x=None):
        key = (int(self.iparm[1]), int(self.iparm[23]))
        if phase == 12:
            tried.append(key)
            if key[1] == 1 and (key[0] == 0 or refused == "two-level"):
                raise RuntimeError(f"MKL Pardiso phase {phase} failed with error -1")
        return real(self, phase, b, x)

    monkeypatch.setattr(S._Pardiso, "_call", call)
    X = S.solve_linear(A, rhs, "pardiso")
    assert S._relative_residual(A, X, rhs) < 1e-12
    assert tried[0] == (0, 1) and tried[-1] == used and len(tried) == (2 if used[1] else 3)


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
def test_a_fast_solve_missing_the_residual_goes_to_the_defaults(monkeypatch):
    """Without scaling and matching a solve may miss the residual (cotangent weights on bad
    triangles): MKL's defaults are asked next, not the fast settings with another ordering."""
    W, interior, loop, uv_b = _system()
    A, WB = S._split(W, interior, loop)
    rhs = WB @ uv_b
    real_call, real_res = S._Pardiso._call, S._relative_residual
    tried, checked = [], []

    def call(self, phase, b=None, x=None):
        if phase == 12:
            tried.append((int(self.iparm[1]), int(self.iparm[23])))
        return real_call(self, phase, b, x)

    def residual(A_, X_, rhs_):
        checked.append(1)
        return 1.0 if len(checked) == 1 else real_res(A_, X_, rhs_)

    monkeypatch.setattr(S._Pardiso, "_call", call)
    monkeypatch.setattr(S, "_relative_residual", residual)
    X = S.solve_linear(A, rhs, "pardiso")
    assert tried == [(0, 1), (2, 0)]  # the fast settings, then MKL's defaults (one-level)
    assert real_res(A, X, rhs) < 1e-12


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
def test_pardiso_rejects_an_empty_row():
    A = S.CSR(np.array([0, 1, 1]), np.array([0]), np.array([1.0]), (2, 2))
    with pytest.raises(ValueError, match="empty row"):
        S.solve_linear(A, np.ones((2, 2)), "pardiso")


def test_pardiso_threads_do_not_follow_the_load(monkeypatch):
    # a fixed count (the reproducible mode needs it): the CPUs of this process, or the env
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    import os

    assert S.pardiso_threads() == len(os.sched_getaffinity(0))
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert S.pardiso_threads() == 3
    monkeypatch.setenv("MKL_NUM_THREADS", "1")
    assert S.pardiso_threads() == 1


@pytest.mark.skipif(not S.have_pardiso(), reason="MKL Pardiso not available")
def test_pardiso_runs_in_the_reproducible_mode():
    # a sequential ordering (never the parallel nested dissection, 3) and iparm[34] =
    # threads: MKL's conditional numerical reproducibility, so that the programs do not
    # depend on the machine's load
    A = S.CSR(np.array([0, 2, 4]), np.array([0, 1, 0, 1]), np.array([4.0, -1.0, -1.0, 4.0]), (2, 2))
    for iparm, order in ((S.PARDISO_FAST, 0), ({}, 2), ({**S.PARDISO_FAST, 2: 3}, 2)):
        ps = S._Pardiso(A, iparm)
        assert ps.iparm[1] == order and ps.iparm[33] == S.pardiso_threads() >= 1
        ps.factorize()
        x = ps.solve(np.array([3.0, 3.0]))
        ps.free()
        np.testing.assert_allclose(x.ravel(), [1.0, 1.0], rtol=1e-12)