"""Convex-combination weights of interior vertices (METHOD section 1a, 1b; Zhao et al. 2015 section 2).

Every interior vertex ``v`` gets a row of ``W`` with ``u_v = sum_j W[v, j] u_j``; rows sum to 1,
boundary rows are empty. Four kinds:

``"geodesic"``
    The paper's weights (METHOD 1b): Floater's averaging of barycentric coordinates, but in the
    *unscaled* fan of 3D angles at ``v``; the coordinates are areas of the unfolded pieces
    ``0.5 rho_l rho_j sin(alpha)``, ``0.5 rho_l rho_i sin(beta)`` and the face area. Where no face is
    "opposite" spoke ``l`` (a saddle vertex, angle sum above ``2 pi``) the pair falls back to
    Floater's rule and is counted.
``"floater"``
    Floater's 1997 shape-preserving weights (METHOD 1a): the same construction with the angles
    scaled by ``2 pi / Theta``.
``"mean_value"``
    Floater's 2003 mean-value weights ``(tan(a_{k-1}/2) + tan(a_k/2)) / |v_k - v|``.
``"cotangent"``
    The textbook harmonic weights ``(cot alpha + cot beta) / 2``, normalised per row. They are
    negative across obtuse angles, so unlike the three kinds above they do **not** guarantee a
    bijective (flip-free) map; they are kept as the harmonic reference.

On a mesh whose interior angle sums are all exactly ``2 pi`` (a flat mesh, or a flat sheet folded
along edges) the geodesic and Floater weights coincide: the scale factor is 1 and the opposite
face chosen for every spoke is the same.

Implementation: the spokes of each interior vertex are put in cyclic order from the half-edge
structure (one sort plus a numba walk of the wedge cycles, no Python loop over vertices); all
the geometry is then vectorized over (vertex, spoke) pairs.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
from numba import njit

from conformill.errors import ParameterizationError

log = logging.getLogger(__name__)

WEIGHT_KINDS = ("geodesic", "floater", "mean_value", "cotangent")
#: kinds whose weights are positive, so that a convex boundary gives a bijection (Tutte/Floater)
POSITIVE_KINDS = ("geodesic", "floater", "mean_value")
_ANGLE_TOL = 1e-9


def corner_angles(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Inner angles of every triangle corner, robust for slivers (``atan2(|cross|, dot)``).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64

    Returns
    -------
    (m, 3) float64
        ``[f, c]`` is the angle at ``F[f, c]``, in radians.
    """
    P = V[F]  # (m, 3, 3)
    a = np.roll(P, -1, axis=1) - P  # to the next corner
    b = np.roll(P, -2, axis=1) - P  # to the previous corner
    cr = np.linalg.norm(np.cross(a, b), axis=2)
    dt = np.einsum("fcj,fcj->fc", a, b)
    return np.arctan2(cr, dt)


@njit(cache=True)
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


@njit(cache=True)
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


def interior_weights(V: np.ndarray, F: np.ndarray, boundary_mask: np.ndarray, kind: str = "geodesic"):
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
