"""The numba kernels of weights and quality against the vectorized implementations they replaced.

The reference code below is the previous numpy implementation of
:func:`conformill.param.weights.interior_weights` (one argsort of the wedges, a numba walk of
the fan cycles, vectorized geometry) and :func:`conformill.param.quality.quality` (argsort-based
weighted percentiles), kept verbatim as an oracle: the new kernels must give the same numbers
to rounding (1e-12) on meshes with saddles (geodesic fallbacks), obtuse triangles (negative
cotangent weights) and flipped faces.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import scipy.sparse as sp
from numba import njit

from conformill.errors import ParameterizationError
from conformill.mesh import synthetic as syn
from conformill.mesh.topology import boundary_loops
from conformill.param.quality import quality, weighted_percentile
from conformill.param.weights import WEIGHT_KINDS, corner_angles, interior_weights
from conformill.types import Quality

log = logging.getLogger(__name__)
_ANGLE_TOL = 1e-9

# --------------------------------------------------------------------------- reference: weights
@njit(cache=False)
def _cycles(nxt, group_start, group_size, theta):
    """Walk each vertex's wedge cycle: slot order and the angle before each slot.

    ``nxt[w]`` is the wedge following ``w`` around its vertex (indices into the sorted wedge
    arrays); wedges of one vertex are contiguous from ``group_start``. Returns ``order`` (slot ->
    wedge), ``phi`` (angle swept from the group's first spoke to the slot's spoke) and the number
    of groups whose wedges do not form one closed cycle (non-manifold or inconsistently oriented).
    """
    n_w = nxt.shape[0]
    order = np.empty(n_w, dtype=np.int64)
    phi = np.empty(n_w, dtype=np.float64)
    seen = np.zeros(n_w, dtype=np.bool_)
    bad = 0
    for g in range(group_start.shape[0]):
        s = group_start[g]
        d = group_size[g]
        w = s
        acc = 0.0
        ok = True
        for r in range(d):
            if w < 0 or seen[w]:
                ok = False
                break
            seen[w] = True
            order[s + r] = w
            phi[s + r] = acc
            acc += theta[w]
            w = nxt[w]
        if not ok or w != s:
            bad += 1
            for r in range(d):  # keep arrays defined; the caller raises
                order[s + r] = s + r
                phi[s + r] = 0.0
    return order, phi, bad


@njit(cache=False)
def _opposite_slot(phi, theta, group_start, group_size, slot_group):
    """For each slot ``l``, the slot ``k`` whose wedge contains direction ``phi_l + Theta/2``.

    Works in unscaled angles: Floater's scaled direction ``phi'_l + pi`` is the same wedge because
    the scaling is linear. Returns ``k`` and ``alpha_k = (phi_k - phi_l) mod Theta``.
    """
    n_s = phi.shape[0]
    k_out = np.empty(n_s, dtype=np.int64)
    alpha = np.empty(n_s, dtype=np.float64)
    for l in range(n_s):
        g = slot_group[l]
        s = group_start[g]
        d = group_size[g]
        total = phi[s + d - 1] + theta[s + d - 1]
        tgt = phi[l] + 0.5 * total
        if tgt >= total:
            tgt -= total
        # binary search: last slot in the group with phi <= tgt
        lo = s
        hi = s + d - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if phi[mid] <= tgt:
                lo = mid
            else:
                hi = mid - 1
        k_out[l] = lo
        a = phi[lo] - phi[l]
        if a < 0.0:
            a += total
        alpha[l] = a
    return k_out, alpha


class _Fans:
    """Spokes of interior vertices in cyclic order, as flat arrays over slots (vertex, spoke)."""

    def __init__(self, V, F, boundary_mask):
        n = V.shape[0]
        m = F.shape[0]
        vert = F.reshape(-1)
        spoke = F[:, [1, 2, 0]].reshape(-1)  # wedge (v -> s -> t) is CCW around v for a CCW face
        other = F[:, [2, 0, 1]].reshape(-1)
        keep = ~boundary_mask[vert]
        wid = np.flatnonzero(keep)
        vert, spoke, other = vert[wid], spoke[wid], other[wid]
        key = vert * n + spoke
        srt = np.argsort(key, kind="stable")
        key = key[srt]
        wid, vert, spoke, other = wid[srt], vert[srt], spoke[srt], other[srt]
        if len(key) > 1 and np.any(key[1:] == key[:-1]):
            dup = np.flatnonzero(key[1:] == key[:-1])[0]
            raise ParameterizationError(
                f"edge ({vert[dup]}, {spoke[dup]}) is used twice in the same direction: "
                "the mesh is not consistently oriented or not manifold there"
            )
        nkey = vert * n + other
        nxt = np.searchsorted(key, nkey)
        nxt[nxt >= len(key)] = 0
        miss = key[nxt] != nkey
        if np.any(miss):
            i = np.flatnonzero(miss)[0]
            raise ParameterizationError(
                f"interior vertex {vert[i]} has an open fan (edge ({vert[i]}, {other[i]}) has no "
                "twin): the mesh is not a consistently oriented manifold there"
            )
        nxt = np.where(miss, -1, nxt)
        # 3D wedge geometry, per sorted wedge
        pv = V[vert]
        a = V[spoke] - pv
        b = V[other] - pv
        cr = np.linalg.norm(np.cross(a, b), axis=1)
        dt = np.einsum("ij,ij->i", a, b)
        theta = np.arctan2(cr, dt)
        verts, group_start, group_size = np.unique(vert, return_index=True, return_counts=True)
        order, phi, bad = _cycles(nxt, group_start.astype(np.int64), group_size.astype(np.int64), theta)
        if bad:
            raise ParameterizationError(
                f"{bad} interior vertices have fans that are not one closed cycle of faces "
                "(non-manifold vertex or inconsistent orientation)"
            )
        self.n = n
        self.order = order  # slot -> sorted wedge (sorted by (v, spoke))
        self.vert = vert[order]
        self.spoke = spoke[order]
        self.theta = theta[order]
        self.area2 = cr[order]  # twice the area of the slot's face (v, s_k, s_k+1)
        self.dot = dt[order]
        self.rho = np.linalg.norm(a, axis=1)[order]
        self.rho_next = np.linalg.norm(b, axis=1)[order]
        self.phi = phi
        self.verts = verts
        self.group_start = group_start.astype(np.int64)
        self.group_size = group_size.astype(np.int64)
        gid = np.repeat(np.arange(len(verts)), group_size)
        self.gid = gid
        self.deg = group_size[gid].astype(np.float64)
        self.total = np.add.reduceat(theta[order], group_start) if len(verts) else np.zeros(0)
        pos = np.arange(len(order)) - self.group_start[gid]
        self.next = np.where(pos == self.group_size[gid] - 1, self.group_start[gid], np.arange(len(order)) + 1)
        self.prev = np.where(pos == 0, self.group_start[gid] + self.group_size[gid] - 1, np.arange(len(order)) - 1)
        short = np.flatnonzero(self.rho <= 0.0)
        if len(short):
            i = short[0]
            raise ParameterizationError(
                f"zero-length edge ({self.vert[i]}, {self.spoke[i]}): duplicate vertices"
            )

    def to_csr(self, w_slot: np.ndarray) -> sp.csr_matrix:
        """CSR matrix ``(n, n)`` from one weight per slot; column indices sorted per row."""
        n = self.n
        data = np.empty_like(w_slot)
        data[self.order] = w_slot  # back to (v, spoke)-sorted order
        cols = np.empty(len(w_slot), dtype=np.int64)
        cols[self.order] = self.spoke
        counts = np.zeros(n, dtype=np.int64)
        counts[self.verts] = self.group_size
        indptr = np.concatenate([[0], np.cumsum(counts)])
        W = sp.csr_matrix((data, cols, indptr), shape=(n, n))
        W.has_sorted_indices = True
        return W


def _barycentric_pairs(fan: _Fans, scaled: bool):
    """Barycentric coordinates of ``v`` for every spoke ``l`` (METHOD 1a/1b).

    Returns ``(k, mu_l, mu_k, mu_k1, ok)`` over slots ``l``: the opposite wedge ``k`` (between
    spokes ``k`` and ``k+1``), the three normalised coordinates, and for the unscaled (geodesic)
    construction whether the wedge qualifies (both swept angles below pi).
    """
    k, alpha = _opposite_slot(fan.phi, fan.theta, fan.group_start, fan.group_size, fan.gid)
    total = fan.total[fan.gid]
    theta_k = fan.theta[k]
    beta = total - alpha - theta_k  # angle swept from spoke k+1 on to spoke l
    rho_l = fan.rho
    rho_k = fan.rho[k]
    rho_k1 = fan.rho_next[k]
    if scaled:
        s = 2.0 * np.pi / total
        # mu ~ areas of the planar triangles opposite each corner, divided by rho_l rho_k rho_k1
        m_l = np.sin(theta_k * s) / rho_l
        m_k = np.sin(np.maximum(beta, 0.0) * s) / rho_k
        m_k1 = np.sin(alpha * s) / rho_k1
        ok = np.ones(len(k), dtype=bool)
    else:
        m_l = fan.area2[k] / (rho_k * rho_k1 * rho_l)  # the face's own area, exactly
        m_k = np.sin(np.maximum(beta, 0.0)) / rho_k
        m_k1 = np.sin(alpha) / rho_k1
        # a tolerance: on regular meshes the geodesic runs exactly along the opposite spoke
        # (alpha or beta = pi up to rounding); the degenerate triangle still gives valid
        # coordinates (the sine is clipped to 0 below)
        ok = (alpha < np.pi + _ANGLE_TOL) & (beta < np.pi + _ANGLE_TOL)
    # a scaled wedge wider than pi (a cone vertex with one huge angle) puts the origin outside
    # the triangle: clip the negative coordinate, which keeps the combination convex
    neg = (m_l < 0) | (m_k < 0) | (m_k1 < 0)
    m_l, m_k, m_k1 = np.maximum(m_l, 0.0), np.maximum(m_k, 0.0), np.maximum(m_k1, 0.0)
    tot = m_l + m_k + m_k1
    return k, m_l / tot, m_k / tot, m_k1 / tot, ok, neg


def _averaged(fan: _Fans, k, mu_l, mu_k, mu_k1) -> np.ndarray:
    """``w_j = (1/d) sum_l mu^l_j`` as one weight per slot."""
    ns = len(fan.vert)
    idx = np.concatenate([np.arange(ns), k, fan.next[k]])
    val = np.concatenate([mu_l, mu_k, mu_k1]) / np.concatenate([fan.deg] * 3)
    return np.bincount(idx, weights=val, minlength=ns)


def ref_interior_weights(V: np.ndarray, F: np.ndarray, boundary_mask: np.ndarray, kind: str = "geodesic"):
    """Weight matrix of the convex-combination map (METHOD section 1a-1b).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        Consistently oriented disk triangulation.
    boundary_mask : (n,) bool
        True on boundary vertices (their rows stay empty).
    kind : {"geodesic", "floater", "mean_value", "cotangent"}

    Returns
    -------
    W : scipy.sparse.csr_matrix (n, n)
        ``W[i, j]`` for interior ``i`` and 1-ring neighbour ``j``; interior rows sum to 1.
        Positive for every kind except ``"cotangent"``.
    fallbacks : int
        ``"geodesic"``: the number of (vertex, spoke) pairs that had no opposite face (saddle
        vertices) and used Floater's rule instead; 0 for the other kinds.

    Raises
    ------
    ParameterizationError
        Unknown ``kind``; an interior vertex without a closed fan; a zero-length edge; a
        cotangent row whose weights sum to zero or less.
    """
    if kind not in WEIGHT_KINDS:
        raise ParameterizationError(
            f"unknown weights {kind!r}: choose one of {', '.join(WEIGHT_KINDS)}"
        )
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    boundary_mask = np.asarray(boundary_mask, dtype=bool)
    fan = _Fans(V, F, boundary_mask)
    fallbacks = 0
    if kind in ("geodesic", "floater"):
        k, mu_l, mu_k, mu_k1, ok, neg = _barycentric_pairs(fan, scaled=(kind == "floater"))
        if kind == "geodesic":
            bad = ~ok
            fallbacks = int(bad.sum())
            if fallbacks:
                k2, f_l, f_k, f_k1, _, neg2 = _barycentric_pairs(fan, scaled=True)
                # same opposite wedge k: only the coordinates change
                mu_l = np.where(bad, f_l, mu_l)
                mu_k = np.where(bad, f_k, mu_k)
                mu_k1 = np.where(bad, f_k1, mu_k1)
                neg = np.where(bad, neg2, neg)
        if np.any(neg):
            log.info("%d (vertex, spoke) pairs had a scaled wedge wider than pi; coordinates clipped",
                     int(neg.sum()))
        w = _averaged(fan, k, mu_l, mu_k, mu_k1)
    elif kind == "mean_value":
        # tan(theta/2) = |a x b| / (|a||b| + a.b), per wedge (spoke k -> k+1)
        th = fan.area2 / (fan.rho * fan.rho_next + fan.dot)
        w = (th + th[fan.prev]) / fan.rho
        w = w / np.bincount(fan.gid, weights=w)[fan.gid]
    else:  # cotangent
        # wedge k = face (v, s_k, s_k+1): angle at s_k+1 faces edge (v, s_k), angle at s_k faces (v, s_k+1)
        # cot at s_k+1: (v - s_k+1).(s_k - s_k+1) / |cross| = (rho_next^2 - dot) / area2
        cot_t = (fan.rho_next**2 - fan.dot) / fan.area2
        cot_s = (fan.rho**2 - fan.dot) / fan.area2
        w = 0.5 * (cot_t + cot_s[fan.prev])
        rs = np.bincount(fan.gid, weights=w)
        badrow = np.flatnonzero(~(rs > 0))
        if len(badrow):
            raise ParameterizationError(
                f"cotangent weights of interior vertices {fan.verts[badrow[:10]].tolist()} sum to "
                "zero or less (degenerate triangles): use geodesic, floater or mean_value weights"
            )
        w = w / rs[fan.gid]
    if not np.all(np.isfinite(w)):
        i = np.flatnonzero(~np.isfinite(w))[0]
        raise ParameterizationError(
            f"non-finite {kind} weight at vertex {fan.vert[i]}, spoke {fan.spoke[i]} (degenerate triangles)"
        )
    return fan.to_csr(w), fallbacks


# --------------------------------------------------------------------------- reference: quality
def ref_weighted_percentile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    """The ``q``-th percentile (0..100) of ``x`` with weights ``w`` (lower value at a step)."""
    o = np.argsort(x, kind="stable")
    cw = np.cumsum(w[o])
    if cw[-1] <= 0:
        return float("nan")
    i = int(np.searchsorted(cw, q / 100.0 * cw[-1], side="left"))
    return float(x[o[min(i, len(o) - 1)]])


def face_jacobian_singular_values(V: np.ndarray, F: np.ndarray, uv: np.ndarray):
    """Singular values of the 3D-to-2D Jacobian of every face and its sign.

    Returns
    -------
    s1, s2 : (m,) float64
        ``s1 >= s2 >= 0``.
    det : (m,) float64
        ``det J``: negative for flipped faces.
    area3 : (m,) float64
        3D face areas.
    """
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1 = b - a
    e2 = c - a
    l1 = np.linalg.norm(e1, axis=1)
    x2 = np.einsum("ij,ij->i", e2, e1) / l1
    y2 = np.linalg.norm(np.cross(e1, e2), axis=1) / l1  # > 0: the face's own frame
    area3 = 0.5 * l1 * y2
    ua, ub, uc = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    d1 = ub - ua
    d2 = uc - ua
    # J [l1, 0]^T = d1, J [x2, y2]^T = d2
    j11 = d1[:, 0] / l1
    j21 = d1[:, 1] / l1
    j12 = (d2[:, 0] - j11 * x2) / y2
    j22 = (d2[:, 1] - j21 * x2) / y2
    # closed-form 2x2 SVD
    E = 0.5 * (j11 + j22)
    Fh = 0.5 * (j11 - j22)
    G = 0.5 * (j21 + j12)
    H = 0.5 * (j21 - j12)
    Q = np.hypot(E, H)
    R = np.hypot(Fh, G)
    s1 = Q + R
    s2 = np.abs(Q - R)
    det = j11 * j22 - j12 * j21
    return s1, s2, det, area3


def ref_quality(V: np.ndarray, F: np.ndarray, uv: np.ndarray) -> Quality:
    """Conformal quality figures of a map (METHOD 1d).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    uv : (n, 2) float64

    Returns
    -------
    conformill.types.Quality
        ``qc`` per face (``inf`` for a face collapsed to a segment, which the QC mean leaves
        out with a logged warning; the p95 and max include it), ``sigma`` per vertex.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    uv = np.asarray(uv, dtype=np.float64)
    n = V.shape[0]
    s1, s2, det, area3 = face_jacobian_singular_values(V, F, uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        qc = np.where(s2 > 0, s1 / s2, np.inf)
    w = area3 / area3.sum()
    fin = np.isfinite(qc)
    if not fin.all():
        # e.g. a triangle with three vertices on one side of the rectangle: its image is a segment
        log.warning("%d faces collapse to a segment in the domain (QC infinite); the QC mean "
                    "is over the other faces", int((~fin).sum()))
    ang3 = corner_angles(V, F)
    uv3 = np.column_stack([uv, np.zeros(n)])
    ang2 = corner_angles(uv3, F)
    err = np.degrees(np.abs(ang2 - ang3)).reshape(-1)
    wc = np.repeat(w / 3.0, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        sig_f = 1.0 / np.sqrt(np.abs(det))  # sqrt(area_3D / area_2D)
    sig_f = np.where(np.isfinite(sig_f), sig_f, np.nan)
    fa = np.repeat(area3, 3)
    ok = np.isfinite(np.repeat(sig_f, 3))
    num = np.bincount(F.reshape(-1)[ok], weights=(np.repeat(sig_f, 3) * fa)[ok], minlength=n)
    den = np.bincount(F.reshape(-1)[ok], weights=fa[ok], minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = num / den
    used = den > 0
    return Quality(
        qc_mean=float(np.sum(w[fin] * qc[fin]) / np.sum(w[fin])) if fin.any() else float("inf"),
        qc_p95=ref_weighted_percentile(qc, w, 95.0),
        qc_max=float(qc.max()),
        angle_mean=float(np.sum(wc * err)),
        angle_p95=ref_weighted_percentile(err, wc, 95.0),
        angle_max=float(err.max()),
        flipped=int(np.sum(det < 0)),
        sigma_min=float(np.min(sigma[used])) if used.any() else float("nan"),
        sigma_max=float(np.max(sigma[used])) if used.any() else float("nan"),
        sigma=sigma,
        qc=qc,
    )


# --------------------------------------------------------------------------- tests
def _meshes():
    yield "sphere_cap", syn.sphere_cap(R=40, radius_xy=30, spacing=3.0, jitter=0.3)
    yield "saddle", syn.height_field(syn.regular_polygon(40, 30.0), lambda x, y: 0.02 * (x * x - y * y), 2.5,
                                     jitter=0.35, seed=3)
    yield "freeform", syn.freeform_patch(spacing=3.0)
    yield "cylinder_concave", syn.cylinder_patch(spacing=3.0, concave=True)


MESHES = dict(_meshes())


def _mask(m):
    mask = np.zeros(m.n_vertices, dtype=bool)
    mask[boundary_loops(m.F, m.n_vertices)[0]] = True
    return mask


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("kind", WEIGHT_KINDS)
def test_weights_match_the_vectorized_reference(name, kind):
    m = MESHES[name]
    mask = _mask(m)
    W, fb = interior_weights(m.V, m.F, mask, kind)
    R, fb_ref = ref_interior_weights(m.V, m.F, mask, kind)
    assert fb == fb_ref
    assert np.array_equal(W.indptr, R.indptr) and np.array_equal(W.indices, R.indices)
    assert np.abs(W.data - R.data).max() <= 1e-12


def test_the_saddle_mesh_exercises_the_geodesic_fallback():
    m = MESHES["saddle"]
    _, fb = interior_weights(m.V, m.F, _mask(m), "geodesic")
    assert fb > 0


@pytest.mark.parametrize("name", sorted(MESHES))
def test_quality_matches_the_vectorized_reference(name):
    m = MESHES[name]
    rng = np.random.default_rng(7)
    uv = m.V[:, :2] + rng.normal(scale=0.8, size=(m.n_vertices, 2))  # some faces flip
    q, r = quality(m.V, m.F, uv), ref_quality(m.V, m.F, uv)
    assert q.flipped == r.flipped and q.flipped > 0
    for k, v in r.as_dict().items():
        assert q.as_dict()[k] == pytest.approx(v, rel=1e-12, abs=1e-12), k
    np.testing.assert_allclose(q.qc, r.qc, rtol=1e-12)
    np.testing.assert_allclose(q.sigma, r.sigma, rtol=1e-12)


def test_quality_with_a_collapsed_face_matches_the_reference():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.2]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    uv = np.array([[0.0, 0], [1, 0], [2, 0], [1, 1]])  # face 0 is a segment
    q, r = quality(V, F, uv), ref_quality(V, F, uv)
    assert np.isinf(q.qc[0]) and q.qc_max == r.qc_max and q.qc_p95 == r.qc_p95
    assert q.qc_mean == pytest.approx(r.qc_mean, rel=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_weighted_percentile_matches_the_sort(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    x = np.round(rng.normal(size=n), 1 if seed % 2 else 6)  # many ties when rounded to 0.1
    if seed >= 2:
        x[rng.integers(0, n, size=max(1, n // 50))] = np.inf
    if seed >= 4:
        x[rng.integers(0, n, size=max(1, n // 50))] = np.nan
    w = rng.random(n) * (rng.random(n) > 0.2)  # some zero weights
    for q in (0.0, 1.0, 37.5, 50.0, 95.0, 99.9, 100.0):
        a, b = weighted_percentile(x, w, q), ref_weighted_percentile(x, w, q)
        assert (np.isnan(a) and np.isnan(b)) or a == b, (q, a, b)


def test_weighted_percentile_without_weight_is_nan():
    assert np.isnan(weighted_percentile(np.arange(3.0), np.zeros(3), 50))
    assert np.isnan(weighted_percentile(np.zeros(0), np.zeros(0), 50))
