"""The two 1-D filters of the pattern stage, to the bit of ``scipy.ndimage``'s.

:func:`conformill.patterns.warp.build_warp` smooths its offset table with a Gaussian, and
:meth:`conformill.patterns.family.Planner.run_local` (``--spacing local``) spreads a step's
shrink with a running minimum: ``scipy.ndimage.gaussian_filter1d`` and ``minimum_filter1d``
(``mode="wrap"`` on closed curves, ``"nearest"`` on open ones), here for the arrays these
stages pass. Importing ``scipy.ndimage`` cost every ``conformill plan`` about 0.05 s before
its first path (its array-API dispatch; ``scipy.special``, which it also brings, comes with
``scipy.spatial`` anyway: session 62, ``python -X importtime``), for two short loops. The
results are scipy's to the bit: the same Gaussian weights, computed as scipy computes them,
and the same sums in the same order (``NI_Correlate1D``'s symmetric branch: the centre's
product, then the pairs of samples from the outermost in); ``tests/test_pattern_filters.py``
compares them with scipy's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["gaussian_rows", "gaussian_weights", "running_min"]


def running_min(x, half: int, wrap: bool) -> np.ndarray:
    """``scipy.ndimage.minimum_filter1d(x, 2 * half + 1, mode="wrap" if wrap else "nearest")``
    for a 1-D ``x``: the least of the samples within ``half`` places of each, the array
    repeated end to end (``wrap``) or its end samples repeated (else)."""
    x = np.asarray(x, dtype=np.float64)
    half = int(half)
    if half < 0 or x.ndim != 1:
        raise ValueError(f"running_min: a 1-D array and half >= 0 are needed, got {x.shape}, {half}")
    if len(x) == 0 or half == 0:
        return x.copy()
    xp = np.pad(x, half, mode="wrap" if wrap else "edge")
    return np.lib.stride_tricks.sliding_window_view(xp, 2 * half + 1).min(axis=1)


def gaussian_rows(F, sigma: float, wrap: bool) -> np.ndarray:
    """``scipy.ndimage.gaussian_filter1d(F, sigma, axis=1, mode="wrap" if wrap else
    "nearest")`` for a 2-D ``F`` (truncated at 4 sigma, as scipy's default)."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    sigma = float(sigma)
    if F.ndim != 2 or not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"gaussian_rows: a 2-D array and a positive sigma are needed, got {F.shape}, {sigma}")
    radius = int(4.0 * sigma + 0.5)
    w = gaussian_weights(sigma, radius)
    if F.shape[1] == 0:
        return F.copy()
    return _correlate_rows(F, w[::-1].copy(), radius, wrap)


def gaussian_weights(sigma: float, radius: int) -> np.ndarray:
    """The Gaussian's ``2 radius + 1`` weights, as scipy's ``_gaussian_kernel1d`` computes
    them (scipy 1.17: ``exp(-0.5 / sigma^2 * x^2)`` at the integers ``x``, over their sum)."""
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x ** 2)
    return phi / phi.sum()


@njit(cache=True, nogil=True)
def _correlate_rows(F, w, radius, wrap):
    """Each row of ``F`` correlated with the symmetric weights ``w`` (``2 radius + 1``):
    ``out[i] = x[i] w[c] + sum_{k = radius..1} (x[i - k] + x[i + k]) w[c - k]``, in that
    order, ``c = radius``, with the row extended by wrapping or by its end samples."""
    m, n = F.shape
    out = np.empty((m, n))
    line = np.empty(n + 2 * radius)
    for r in range(m):
        for j in range(n + 2 * radius):
            i = j - radius
            if wrap:
                i %= n
            else:
                i = min(max(i, 0), n - 1)
            line[j] = F[r, i]
        for i in range(n):
            c = i + radius
            s = line[c] * w[radius]
            for k in range(radius, 0, -1):
                s += (line[c - k] + line[c + k]) * w[radius - k]
            out[r, i] = s
    return out
