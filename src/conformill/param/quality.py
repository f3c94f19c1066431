"""Conformal quality of a parameterization (METHOD section 1d).

Per face, the 2x2 Jacobian ``J`` of the affine map from the 3D triangle (in its own plane) to
its 2D triangle has singular values ``s1 >= s2``:

- quasi-conformal distortion ``QC = s1 / s2`` (1 for a similarity);
- angle distortion ``|angle_2D - angle_3D|`` at each of the three corners, in degrees;
- flipped faces: negative signed 2D area (``det J < 0``);
- scale factor ``sigma_f = sqrt(area_3D / area_2D)`` (3D length over 2D length, exact for a
  similarity), averaged per vertex over its faces weighted by 3D area.

Statistics are weighted by 3D face area (each corner of a face by a third of its area);
percentiles are weighted percentiles.
"""

from __future__ import annotations

import logging

import numpy as np
from numba import njit

from conformill.types import Quality

log = logging.getLogger(__name__)


def weighted_percentile(x: np.ndarray, w: np.ndarray, q: float) -> float:
    """The ``q``-th percentile (0..100) of ``x`` with weights ``w`` (lower value at a step).

    The smallest ``x_i`` whose cumulative weight, in ascending order of ``x`` (NaN last),
    reaches ``q / 100`` of the total weight. Found by a weighted quickselect (expected linear
    time) rather than a sort; NaN when the total weight is not positive.
    """
    x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1)
    w = np.ascontiguousarray(w, dtype=np.float64).reshape(-1)
    if len(x) == 0:
        return float("nan")
    return float(_weighted_select(x.copy(), w.copy(), float(q) / 100.0))


@njit(cache=True)
def _key_less(a, b):
    """``a < b`` with NaN above everything (the order of ``np.argsort``)."""
    if np.isnan(a):
        return False
    if np.isnan(b):
        return True
    return a < b


@njit(cache=True)
def _weighted_select(x, w, frac):
    """Weighted quickselect on copies ``x, w`` (reordered in place); see :func:`weighted_percentile`."""
    total = 0.0
    for i in range(x.shape[0]):
        total += w[i]
    if not total > 0:
        return np.nan
    t = frac * total
    lo = 0
    hi = x.shape[0]  # the answer lies in x[lo:hi]; t is the weight still to reach within it
    seed = np.uint64(0x9E3779B97F4A7C15)
    while True:
        size = hi - lo
        if size == 1:
            return x[lo]
        # pivot: median of three pseudo-random elements (deterministic)
        seed = seed * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
        i1 = lo + np.int64((seed >> np.uint64(33)) % np.uint64(size))
        seed = seed * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
        i2 = lo + np.int64((seed >> np.uint64(33)) % np.uint64(size))
        seed = seed * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
        i3 = lo + np.int64((seed >> np.uint64(33)) % np.uint64(size))
        a, b, c = x[i1], x[i2], x[i3]
        if _key_less(b, a):
            a, b = b, a
        if _key_less(c, b):
            b = c
            if _key_less(b, a):
                b = a
        p = b
        # three-way partition: [lo, lt) < p, [lt, gt) == p, [gt, hi) > p
        lt = lo
        gt = hi
        i = lo
        while i < gt:
            xi = x[i]
            if _key_less(xi, p):
                x[i], x[lt] = x[lt], x[i]
                w[i], w[lt] = w[lt], w[i]
                lt += 1
                i += 1
            elif _key_less(p, xi):
                gt -= 1
                x[i], x[gt] = x[gt], x[i]
                w[i], w[gt] = w[gt], w[i]
            else:
                i += 1
        wl = 0.0
        for j in range(lo, lt):
            wl += w[j]
        we = 0.0
        for j in range(lt, gt):
            we += w[j]
        if lt > lo and t <= wl:
            hi = lt
        elif t <= wl + we or gt == hi:
            return p
        else:
            t -= wl + we
            lo = gt


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


@njit(cache=True, error_model="numpy")
def _face_measures(V, F, uv):
    """Per face: QC, det J, 3D area, sigma_f; per corner: angle error (deg); per vertex: sigma.

    The formulas of :func:`face_jacobian_singular_values` and
    :func:`conformill.param.weights.corner_angles`, in one pass without temporaries.
    """
    m = F.shape[0]
    n = V.shape[0]
    qc = np.empty(m)
    det = np.empty(m)
    area3 = np.empty(m)
    err = np.empty((m, 3))
    num = np.zeros(n)
    den = np.zeros(n)
    deg = 180.0 / np.pi
    for f in range(m):
        i0 = F[f, 0]
        i1 = F[f, 1]
        i2 = F[f, 2]
        e1x = V[i1, 0] - V[i0, 0]
        e1y = V[i1, 1] - V[i0, 1]
        e1z = V[i1, 2] - V[i0, 2]
        e2x = V[i2, 0] - V[i0, 0]
        e2y = V[i2, 1] - V[i0, 1]
        e2z = V[i2, 2] - V[i0, 2]
        l1 = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        x2 = (e2x * e1x + e2y * e1y + e2z * e1z) / l1
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        y2 = np.sqrt(cx * cx + cy * cy + cz * cz) / l1
        a3 = 0.5 * l1 * y2
        area3[f] = a3
        d1x = uv[i1, 0] - uv[i0, 0]
        d1y = uv[i1, 1] - uv[i0, 1]
        d2x = uv[i2, 0] - uv[i0, 0]
        d2y = uv[i2, 1] - uv[i0, 1]
        j11 = d1x / l1
        j21 = d1y / l1
        j12 = (d2x - j11 * x2) / y2
        j22 = (d2y - j21 * x2) / y2
        E = 0.5 * (j11 + j22)
        Fh = 0.5 * (j11 - j22)
        G = 0.5 * (j21 + j12)
        H = 0.5 * (j21 - j12)
        Q = np.hypot(E, H)
        R = np.hypot(Fh, G)
        s1 = Q + R
        s2 = np.abs(Q - R)
        qc[f] = s1 / s2 if s2 > 0 else np.inf
        dj = j11 * j22 - j12 * j21
        det[f] = dj
        for c in range(3):
            p = F[f, c]
            q = F[f, (c + 1) % 3]
            r = F[f, (c + 2) % 3]
            ax = V[q, 0] - V[p, 0]
            ay = V[q, 1] - V[p, 1]
            az = V[q, 2] - V[p, 2]
            bx = V[r, 0] - V[p, 0]
            by = V[r, 1] - V[p, 1]
            bz = V[r, 2] - V[p, 2]
            kx = ay * bz - az * by
            ky = az * bx - ax * bz
            kz = ax * by - ay * bx
            ang3 = np.arctan2(np.sqrt(kx * kx + ky * ky + kz * kz), ax * bx + ay * by + az * bz)
            ux = uv[q, 0] - uv[p, 0]
            uy = uv[q, 1] - uv[p, 1]
            vx = uv[r, 0] - uv[p, 0]
            vy = uv[r, 1] - uv[p, 1]
            kz2 = ux * vy - uy * vx
            ang2 = np.arctan2(np.sqrt(kz2 * kz2), ux * vx + uy * vy)
            err[f, c] = np.abs(ang2 - ang3) * deg
        sig = 1.0 / np.sqrt(np.abs(dj))  # sqrt(area_3D / area_2D)
        if np.isfinite(sig):
            for c in range(3):
                num[F[f, c]] += sig * a3
                den[F[f, c]] += a3
    return qc, det, area3, err, num, den


def quality(V: np.ndarray, F: np.ndarray, uv: np.ndarray) -> Quality:
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
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    uv = np.ascontiguousarray(uv, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        qc, det, area3, err, num, den = _face_measures(V, F, uv)
        sigma = num / den
    w = area3 / area3.sum()
    fin = np.isfinite(qc)
    if not fin.all():
        # e.g. a triangle with three vertices on one side of the rectangle: its image is a segment
        log.warning("%d faces collapse to a segment in the domain (QC infinite); the QC mean "
                    "is over the other faces", int((~fin).sum()))
    err = err.reshape(-1)
    wc = np.repeat(w / 3.0, 3)
    used = den > 0
    return Quality(
        qc_mean=float(np.sum(w[fin] * qc[fin]) / np.sum(w[fin])) if fin.any() else float("inf"),
        qc_p95=weighted_percentile(qc, w, 95.0),
        qc_max=float(qc.max()),
        angle_mean=float(np.sum(wc * err)),
        angle_p95=weighted_percentile(err, wc, 95.0),
        angle_max=float(err.max()),
        flipped=int(np.sum(det < 0)),
        sigma_min=float(np.min(sigma[used])) if used.any() else float("nan"),
        sigma_max=float(np.max(sigma[used])) if used.any() else float("nan"),
        sigma=sigma,
        qc=qc,
    )
