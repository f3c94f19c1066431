"""Differential properties of a parameterized mesh (METHOD section 3, paper section 4.1).

At every vertex ``i`` the surface is fitted, by least squares over the vertex and its
1-ring, in parameter coordinates centred at the vertex (``u' = u - u_i``):

``r(u', v') = c1 u'^2 + c2 v'^2 + c3 u' v' + c4 u' + c5 v' + c6``  (each ``c`` a 3-vector),

so that ``r_u = c4, r_v = c5, r_uu = 2 c1, r_vv = 2 c2, r_uv = c3``. The first and second
fundamental forms follow: ``E = r_u.r_u, F = r_u.r_v, G = r_v.r_v`` and
``L = n.r_uu, M = n.r_uv, N = n.r_vv``.

Sign conventions (used by :mod:`conformill.planning.steps` and the path patterns)
--------------------------------------------------------------------------------
* ``n = r_u x r_v / |r_u x r_v|`` points **towards the tool**. This holds when the
  parameterization keeps the orientation of the mesh: faces counter-clockwise seen from
  the tool (:class:`conformill.types.Mesh`) are counter-clockwise in ``uv``. The fit
  checks it against the area-weighted face normals: if the whole ``uv`` is mirrored
  (clockwise), ``n`` is negated so that it still points to the tool, and a warning is
  issued; vertices whose fitted normal disagrees with the mesh normal (folds, broken
  maps) are counted in a warning.
* Normal curvature ``kappa = II / I`` in a domain direction ``(du, dv)``:
  ``kappa = (L du^2 + 2 M du dv + N dv^2) / (E du^2 + 2 F du dv + G dv^2)``.
  ``kappa > 0``: the surface curves **towards** ``n`` (concave seen from the tool, a bowl);
  ``kappa < 0``: it bends away from the tool (convex, a dome); ``kappa = 0``: flat.
  A sphere of radius ``R`` seen from outside has ``kappa = -1/R`` in every direction.

The letter ``F`` is both the face array (``interpolate``) and the first fundamental form
coefficient (``normal_curvature``); each signature says which.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np
from numba import njit, prange
from numba import types as _nt

from conformill.errors import ConformillError
from conformill.types import SurfaceFrame

log = logging.getLogger(__name__)

#: Reciprocal-condition estimate of the scaled 6x6 normal matrix below which a fit is
#: widened to the next ring (the design matrix then has condition above ~1e4).
RCOND_MIN = 1e-8
#: Widest ring tried before falling back to a plane (first-order) fit.
MAX_RING = 3
#: A fitted normal farther than this (degrees) from the area-weighted mesh normal is refitted.
NORMAL_MAX_ANGLE = 60.0


# --------------------------------------------------------------------------------------
# 1-ring adjacency (deduplicated CSR) straight from the faces, in O(m)
# --------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _ring_csr(F, n):
    m = F.shape[0]
    cnt = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            cnt[F[f, k] + 1] += 2
    ptr = np.cumsum(cnt)
    fill = ptr[:-1].copy()
    nb = np.empty(ptr[-1], dtype=np.int64)
    for f in range(m):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        nb[fill[a]] = b
        nb[fill[a] + 1] = c
        fill[a] += 2
        nb[fill[b]] = c
        nb[fill[b] + 1] = a
        fill[b] += 2
        nb[fill[c]] = a
        nb[fill[c] + 1] = b
        fill[c] += 2
    # deduplicate each vertex's list in place (lists are short: 2 * valence)
    out_ptr = np.zeros(n + 1, dtype=np.int64)
    w = 0
    for i in range(n):
        s, e = ptr[i], ptr[i + 1]
        start = w
        for t in range(s, e):
            x = nb[t]
            dup = False
            for q in range(start, w):
                if nb[q] == x:
                    dup = True
                    break
            if not dup:
                nb[w] = x
                w += 1
        out_ptr[i + 1] = w
    return out_ptr, nb[:w].copy()


# --------------------------------------------------------------------------------------
# The per-vertex quadratic fit
# --------------------------------------------------------------------------------------


#: One compiled version for its callers (a literal ``True`` made another; see
#: ``conformill.cutter._DROP_POINT_SIG``).
_FIT_ONE_SIG = _nt.float64(_nt.int64, _nt.int64[::1], _nt.int64, _nt.float64[:, ::1], _nt.float64[:, ::1],
                           _nt.float64[:, :, ::1], _nt.float64[::1], _nt.boolean)


@njit(_FIT_ONE_SIG, cache=True, nogil=True)
def _fit_one(i, ids, cnt, V, uv, coef, rc_out, quadratic):
    """Fit at vertex ``i`` over ``i`` and ``ids[:cnt]``; write ``coef[i]`` (6, 3).

    Columns are scaled by the ring radius ``s`` so that the normal matrix is O(1)
    whatever the domain scale; the reciprocal condition estimate is
    ``min pivot^2 / max diagonal`` of its Cholesky factor. Returns it (0 if singular).
    """
    u0 = uv[i, 0]
    v0 = uv[i, 1]
    s = 0.0
    for t in range(cnt):
        j = ids[t]
        du = uv[j, 0] - u0
        dv = uv[j, 1] - v0
        d = du * du + dv * dv
        if d > s:
            s = d
    s = np.sqrt(s)
    if s == 0.0:
        rc_out[i] = 0.0
        return 0.0
    nc = 6 if quadratic else 3
    A = np.zeros((6, 6))
    B = np.zeros((6, 3))
    row = np.empty(6)
    for t in range(cnt + 1):
        j = i if t == cnt else ids[t]
        x = (uv[j, 0] - u0) / s
        y = (uv[j, 1] - v0) / s
        if quadratic:
            row[0] = x * x
            row[1] = y * y
            row[2] = x * y
            row[3] = x
            row[4] = y
            row[5] = 1.0
        else:
            row[0] = x
            row[1] = y
            row[2] = 1.0
        for a in range(nc):
            ra = row[a]
            for b in range(a + 1):
                A[a, b] += ra * row[b]
            for k in range(3):
                B[a, k] += ra * (V[j, k] - V[i, k])
    # Cholesky (lower), in place
    dmax = 0.0
    for a in range(nc):
        if A[a, a] > dmax:
            dmax = A[a, a]
    pmin = np.inf
    for a in range(nc):
        for b in range(a + 1):
            acc = A[a, b]
            for k in range(b):
                acc -= A[a, k] * A[b, k]
            if a == b:
                if acc <= 0.0:
                    rc_out[i] = 0.0
                    return 0.0
                if acc < pmin:
                    pmin = acc
                A[a, a] = np.sqrt(acc)
            else:
                A[a, b] = acc / A[b, b]
    rc = pmin / dmax
    # forward / back substitution, 3 right-hand sides
    for k in range(3):
        for a in range(nc):
            acc = B[a, k]
            for b in range(a):
                acc -= A[a, b] * B[b, k]
            B[a, k] = acc / A[a, a]
        for a in range(nc - 1, -1, -1):
            acc = B[a, k]
            for b in range(a + 1, nc):
                acc -= A[b, a] * B[b, k]
            B[a, k] = acc / A[a, a]
    # undo the column scaling; c6 is the fitted offset from V[i] (kept for diagnostics)
    for k in range(3):
        if quadratic:
            coef[i, 0, k] = B[0, k] / (s * s)
            coef[i, 1, k] = B[1, k] / (s * s)
            coef[i, 2, k] = B[2, k] / (s * s)
            coef[i, 3, k] = B[3, k] / s
            coef[i, 4, k] = B[4, k] / s
            coef[i, 5, k] = B[5, k]
        else:
            coef[i, 0, k] = 0.0
            coef[i, 1, k] = 0.0
            coef[i, 2, k] = 0.0
            coef[i, 3, k] = B[0, k] / s
            coef[i, 4, k] = B[1, k] / s
            coef[i, 5, k] = B[2, k]
    rc_out[i] = rc
    return rc


@njit(cache=True, nogil=True, parallel=True)
def _fit_1ring(ptr, nb, boundary, V, uv, coef, rc, rcond_min):
    """1-ring fit of every interior vertex; returns a mask of vertices to widen."""
    n = V.shape[0]
    widen = np.zeros(n, dtype=np.bool_)
    nchunk = 64
    step = (n + nchunk - 1) // nchunk
    for c in prange(nchunk):
        for i in range(c * step, min(n, (c + 1) * step)):
            cnt = ptr[i + 1] - ptr[i]
            if boundary[i] or cnt + 1 < 6:
                widen[i] = True
                continue
            r = _fit_one(i, nb[ptr[i]:ptr[i + 1]], cnt, V, uv, coef, rc, True)
            if r < rcond_min:
                widen[i] = True
    return widen


@njit(cache=True, nogil=True, parallel=True)
def _fit_kring(which, depth, ptr, nb, V, uv, coef, rc, rcond_min, quadratic):
    """Fit the vertices ``which`` over their ``depth``-ring; returns which still failed."""
    k = which.shape[0]
    bad = np.zeros(k, dtype=np.bool_)
    for t in prange(k):
        i = which[t]
        cap = max(32, 4 * (ptr[i + 1] - ptr[i]))
        buf = np.empty(cap, dtype=np.int64)
        cnt = 0
        for e in range(ptr[i], ptr[i + 1]):
            buf[cnt] = nb[e]
            cnt += 1
        lo = 0
        # breadth-first, level by level; buf holds the ring without i, deduplicated
        for level in range(1, depth):
            hi = cnt
            for q in range(lo, hi):
                src = buf[q]
                for e in range(ptr[src], ptr[src + 1]):
                    x = nb[e]
                    if x == i:
                        continue
                    dup = False
                    for z in range(cnt):
                        if buf[z] == x:
                            dup = True
                            break
                    if dup:
                        continue
                    if cnt == cap:
                        nbuf = np.empty(2 * cap, dtype=np.int64)
                        # element copy: a slice assignment trips numba's parallel
                        # array analysis (it assumes the two sizes equal)
                        for z in range(cap):
                            nbuf[z] = buf[z]
                        buf = nbuf
                        cap *= 2
                    buf[cnt] = x
                    cnt += 1
            lo = hi
        if cnt + 1 < (6 if quadratic else 3):
            bad[t] = True
            rc[i] = 0.0
            continue
        r = _fit_one(i, buf, cnt, V, uv, coef, rc, quadratic)
        if r < rcond_min:
            bad[t] = True
    return bad


def _vertex_normals(V, F):
    """Area-weighted vertex normals (unnormalised sums of face cross products)."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = len(V)
    out = np.empty((n, 3))
    flat = F.reshape(-1)
    for k in range(3):
        out[:, k] = np.bincount(flat, weights=np.repeat(fn[:, k], 3), minlength=n)
    return out


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals of a mesh (towards the tool for CCW faces).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64

    Returns
    -------
    (n, 3) float64
        Zero rows for unreferenced vertices.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    N = _vertex_normals(V, F)
    ln = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, ln, out=np.zeros_like(N), where=ln > 0)


def surface_frame(V: np.ndarray, F: np.ndarray, uv: np.ndarray) -> SurfaceFrame:
    """Per-vertex derivatives and fundamental forms from a quadratic least-squares fit.

    METHOD section 3: at vertex ``i``, fit ``r(u, v) = c1 u^2 + c2 v^2 + c3 uv + c4 u +
    c5 v + c6`` (``u, v`` centred at ``uv[i]``) to the vertex and its 1-ring. The fit is
    widened to the 2-ring (then the 3-ring) for boundary vertices, where the vertex and its
    1-ring have fewer than 6 points, and where the scaled normal matrix is ill-conditioned
    (reciprocal condition estimate below :data:`RCOND_MIN`, e.g. nearly collinear rings).
    A vertex that no ring up to :data:`MAX_RING` resolves gets a plane fit (``c1 = c2 =
    c3 = 0``) and a warning. A fit whose normal is more than :data:`NORMAL_MAX_ANGLE` off the
    area-weighted mesh normal is refitted over the :data:`MAX_RING`-ring, and failing that
    with a plane over the 2-ring (warning). ``r_u = c4, r_v = c5, r_uu = 2 c1, r_vv = 2 c2,
    r_uv = c3``.

    Accuracy: the quadratic fit recovers second derivatives with an error of order
    ``h`` times the third derivative (``h`` the ring size); on irregular rings this is
    about 0.3-2 % of the curvature of a 50 mm sphere at 2 mm spacing (see
    tests/test_differential.py).

    Parameters
    ----------
    V : (n, 3) float64
        Vertex positions (mm).
    F : (m, 3) int64
        Faces, counter-clockwise seen from the tool.
    uv : (n, 2) float64
        Parameter coordinates (an orientation-preserving map; see the module notes).

    Returns
    -------
    SurfaceFrame
        ``ru, rv, ruu, ruv, rvv, n`` (n, 3) and ``E, F, G, L, M, N`` (n,); ``n`` points to
        the tool. Vertices not used by any face get NaN.

    Raises
    ------
    ConformillError
        Shapes do not match, or non-finite coordinates.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F_ = np.ascontiguousarray(F, dtype=np.int64)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    n = len(V)
    if V.ndim != 2 or V.shape[1] != 3 or F_.ndim != 2 or F_.shape[1] != 3:
        raise ConformillError(f"surface_frame: V must be (n, 3) and F (m, 3), got {V.shape}, {F_.shape}")
    if uv.shape != (n, 2):
        raise ConformillError(f"surface_frame: uv must be ({n}, 2) to match V, got {uv.shape}")
    if len(F_) and (F_.min() < 0 or F_.max() >= n):
        raise ConformillError(f"surface_frame: face indices outside [0, {n})")
    bad = ~np.isfinite(uv).all(axis=1) | ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ConformillError(
            f"surface_frame: {int(bad.sum())} vertices with non-finite V or uv, first {np.flatnonzero(bad)[:5].tolist()}"
        )

    ptr, nb = _ring_csr(F_, n)
    # boundary vertex of a manifold disk: one more neighbour than incident faces
    nface = np.bincount(F_.reshape(-1), minlength=n)
    boundary = (np.diff(ptr) != nface) & (nface > 0)

    coef = np.full((n, 6, 3), np.nan)
    rc = np.zeros(n)
    todo = np.flatnonzero(_fit_1ring(ptr, nb, boundary, V, uv, coef, rc, RCOND_MIN) & (nface > 0))
    for depth in range(2, MAX_RING + 1):
        if len(todo) == 0:
            break
        still = _fit_kring(todo, depth, ptr, nb, V, uv, coef, rc, RCOND_MIN, True)
        todo = todo[still]
    if len(todo):
        still = _fit_kring(todo, MAX_RING, ptr, nb, V, uv, coef, rc, 0.0, False)
        warnings.warn(
            f"surface_frame: {len(todo)} vertices have no well-conditioned quadratic fit up to the "
            f"{MAX_RING}-ring; plane fit used (zero curvature), first {todo[:5].tolist()}",
            RuntimeWarning,
            stacklevel=2,
        )
        if still.any():
            coef[todo[still]] = np.nan

    # orientation: compare with the mesh normals (METHOD: n towards the tool)
    ref = _vertex_normals(V, F_)
    ln = np.linalg.norm(ref, axis=1, keepdims=True)
    ref = np.divide(ref, ln, out=np.zeros_like(ref), where=ln > 0)

    def _agreement(idx):
        cr = np.cross(coef[idx, 3], coef[idx, 4])
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.einsum("ij,ij->i", cr, ref[idx]) / np.linalg.norm(cr, axis=1)

    dots = _agreement(slice(None))
    ok = np.isfinite(dots)
    sign = 1.0
    if ok.any() and np.sum(dots[ok]) < 0:
        warnings.warn(
            "surface_frame: the parameterization is mirrored (uv clockwise for faces that are "
            "counter-clockwise seen from the tool); n = -(r_u x r_v) is used so that n still "
            "points to the tool",
            RuntimeWarning,
            stacklevel=2,
        )
        sign = -1.0
    # A fit whose tangent plane is more than NORMAL_MAX_ANGLE off the mesh normal is wrong
    # (seen at valence-4 vertices of strongly anisotropic maps): refit over the widest ring,
    # then with a plane over the 2-ring, which only needs the tangent directions.
    cos_max = np.cos(np.radians(NORMAL_MAX_ANGLE))
    off = np.flatnonzero(ok & (sign * dots < cos_max))
    n_refit = len(off)
    if n_refit:
        _fit_kring(off, MAX_RING, ptr, nb, V, uv, coef, rc, 0.0, True)
        off = off[~(sign * _agreement(off) >= cos_max)]
    if len(off):
        _fit_kring(off, 2, ptr, nb, V, uv, coef, rc, 0.0, False)
        d = sign * _agreement(off)
        warnings.warn(
            f"surface_frame: {len(off)} vertices fitted with a plane (zero curvature) because "
            f"quadratic fits disagree with the mesh normal by more than {NORMAL_MAX_ANGLE} deg, "
            f"first {off[:5].tolist()}",
            RuntimeWarning,
            stacklevel=2,
        )
        against = off[~(d >= 0)]
        if len(against):
            warnings.warn(
                f"surface_frame: at {len(against)} vertices the fitted normal points away from "
                f"the mesh normal (folded or broken parameterization), first {against[:5].tolist()}",
                RuntimeWarning,
                stacklevel=2,
            )
    if n_refit:
        log.info("surface_frame: %d fits refitted for disagreeing with the mesh normal", n_refit)

    ru = coef[:, 3].copy()
    rv = coef[:, 4].copy()
    ruu = 2.0 * coef[:, 0]
    rvv = 2.0 * coef[:, 1]
    ruv = coef[:, 2].copy()
    cr = np.cross(ru, rv)
    ln = np.linalg.norm(cr, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        nrm = sign * cr / ln

    E = np.einsum("ij,ij->i", ru, ru)
    Fm = np.einsum("ij,ij->i", ru, rv)
    G = np.einsum("ij,ij->i", rv, rv)
    L = np.einsum("ij,ij->i", nrm, ruu)
    M = np.einsum("ij,ij->i", nrm, ruv)
    N = np.einsum("ij,ij->i", nrm, rvv)
    return SurfaceFrame(ru=ru, rv=rv, ruu=ruu, ruv=ruv, rvv=rvv, n=nrm,
                        E=E, F=Fm, G=G, L=L, M=M, N=N)


# --------------------------------------------------------------------------------------
# Evaluation at located points
# --------------------------------------------------------------------------------------


def interpolate(values: np.ndarray, F: np.ndarray, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of per-vertex values at located points.

    ``out[p] = sum_k bary[p, k] * values[F[face[p], k]]``.

    Parameters
    ----------
    values : (n,) or (n, c) array
        Per-vertex values.
    F : (m, 3) int64
        Faces.
    face : (k,) int64
        Face of each point (from :meth:`conformill.geometry.locate.Locator.locate`); ``-1``
        marks a point outside the domain, whose output row is NaN.
    bary : (k, 3) float64
        Barycentric coordinates.

    Returns
    -------
    (k,) or (k, c) float64
    """
    values = np.asarray(values, dtype=np.float64)
    face = np.asarray(face, dtype=np.int64)
    bary = np.asarray(bary, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if bary.shape != (len(face), 3):
        raise ConformillError(f"interpolate: bary must be ({len(face)}, 3), got {bary.shape}")
    outside = face < 0
    if len(F) == 0:
        face = np.zeros(len(face), dtype=np.int64)
        F = np.zeros((1, 3), dtype=np.int64)
    cols = np.ascontiguousarray(values.reshape(values.shape[0], -1))
    out = _interp_rows(cols, np.ascontiguousarray(F), np.where(outside, 0, face),
                       np.ascontiguousarray(bary))
    if outside.any():
        out[outside] = np.nan
    return out.reshape((len(face),) + values.shape[1:])


@njit(cache=True, nogil=True)
def _interp_rows(values, F, face, bary):
    """``out[p] = sum_k bary[p, k] values[F[face[p], k]]`` for every column of ``values``."""
    k, c = face.shape[0], values.shape[1]
    out = np.empty((k, c))
    for p in range(k):
        f = face[p]
        a, b, d = F[f, 0], F[f, 1], F[f, 2]
        w0, w1, w2 = bary[p, 0], bary[p, 1], bary[p, 2]
        for j in range(c):
            out[p, j] = w0 * values[a, j] + w1 * values[b, j] + w2 * values[d, j]
    return out


def interpolate_frame(frame: SurfaceFrame, F: np.ndarray, face: np.ndarray, bary: np.ndarray) -> SurfaceFrame:
    """All fields of a :class:`SurfaceFrame` interpolated at located points.

    The normal is renormalised; ``E..N`` are interpolated as they are (not recomputed from
    the interpolated derivatives), which is what :func:`normal_curvature` expects.

    Returns
    -------
    SurfaceFrame
        Indexed by point (``k`` rows); NaN rows where ``face == -1``.
    """
    fields = {}
    for name in ("ru", "rv", "ruu", "ruv", "rvv", "E", "F", "G", "L", "M", "N"):
        fields[name] = interpolate(getattr(frame, name), F, face, bary)
    nn = interpolate(frame.n, F, face, bary)
    ln = np.linalg.norm(nn, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        fields["n"] = nn / ln
    return SurfaceFrame(**fields)


def normal_curvature(E, F, G, L, M, N, du, dv) -> np.ndarray:
    """Normal curvature in the domain direction ``(du, dv)``, vectorized.

    ``kappa = (L du^2 + 2 M du dv + N dv^2) / (E du^2 + 2 F du dv + G dv^2)``
    (METHOD section 3). Along ``v`` (``du = 0``): ``N / G``; along ``u``: ``L / E``.
    Sign: ``kappa > 0`` concave seen from the tool (curves towards ``n``), ``kappa < 0``
    convex (see the module notes).

    Parameters
    ----------
    E, F, G, L, M, N : array_like, broadcastable
        First and second fundamental form coefficients at the points (``F`` here is the
        metric coefficient ``r_u . r_v``, not a face array).
    du, dv : array_like, broadcastable
        Domain direction; its length does not matter.

    Returns
    -------
    ndarray of float64
        NaN where the direction is zero or the metric is degenerate.
    """
    args = [np.asarray(a, dtype=np.float64) for a in (E, F, G, L, M, N, du, dv)]
    shape = np.broadcast_shapes(*(a.shape for a in args))
    k = _normal_curvature(*(_flat(a, shape) for a in args))
    return k.reshape(shape)


def _flat(a: np.ndarray, shape) -> np.ndarray:
    """``a`` broadcast to ``shape`` as a flat, contiguous, writeable float64 array."""
    if a.shape == shape:
        return np.ascontiguousarray(a).reshape(-1)
    return np.broadcast_to(a, shape).flatten()


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def curvature_in(E, F, G, L, M, N, a, b):
    """The normal curvature of one sample in the domain direction ``(a, b)`` (the formula of
    :func:`normal_curvature`; NaN where the first form is not positive there)."""
    num = L * a * a + 2.0 * M * a * b + N * b * b
    den = E * a * a + 2.0 * F * a * b + G * b * b
    return num / den if den > 0 else np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def _normal_curvature(E, F, G, L, M, N, du, dv):
    """:func:`normal_curvature` over flat arrays (compiled; NaN where the form is not positive)."""
    out = np.empty(E.size)
    for i in range(E.size):
        out[i] = curvature_in(E[i], F[i], G[i], L[i], M[i], N[i], du[i], dv[i])
    return out


def frame_normal_curvature(frame: SurfaceFrame, du, dv) -> np.ndarray:
    """:func:`normal_curvature` with the coefficients taken from a (interpolated) frame."""
    return normal_curvature(frame.E, frame.F, frame.G, frame.L, frame.M, frame.N, du, dv)


def perpendicular_direction(E, F, G, tu, tv):
    """Domain direction whose surface image is perpendicular to the image of ``(tu, tv)``.

    With the first fundamental form ``I``, ``d`` solves ``I(t, d) = 0``:
    ``d = (-(F tu + G tv), E tu + F tv)``. For a path along ``v`` (``t = (0, 1)``) this is
    ``(-G, F)``, which is ``-u`` when ``F = 0``. The orientation is
    ``t`` rotated by +90 degrees on the surface (to the left of the path seen from the
    tool) for an orientation-preserving map. Use it for the curvature *across* paths.

    Returns
    -------
    du, dv : ndarray
        Not normalised.
    """
    E, F, G, tu, tv = (np.asarray(a, dtype=np.float64) for a in (E, F, G, tu, tv))
    return -(F * tu + G * tv), E * tu + F * tv


__all__ = [
    "surface_frame",
    "vertex_normals",
    "interpolate",
    "interpolate_frame",
    "normal_curvature",
    "frame_normal_curvature",
    "perpendicular_direction",
    "RCOND_MIN",
    "MAX_RING",
    "NORMAL_MAX_ANGLE",
]
