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

from conformill.types import Quality

log = logging.getLogger(__name__)


def weighted_percentile(x: np.ndarray, w: np.ndarray, q: float) -> float:
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
    from conformill.param.weights import corner_angles

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
