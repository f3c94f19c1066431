"""Forward steps along a dense path (METHOD section 4, forward direction).

The paper steps ``l_f = sqrt(8 e R - 4 e^2)`` along the path from the normal curvature.
Here the steps are chosen from the dense samples of the path so that the local step
never exceeds ``l_f`` (equidistribution of ``ds / l_f``), no chord is longer than the
longest step allowed, and then every chord is checked
against the dense samples it skips: where one deviates by more than ``e``, the sample
farthest from the chord is added (so the guarantee holds on the mesh, creases included,
not only where the quadratic fit is right).

The tolerance may differ by side: where the path is concave along its direction a chord
rides *above* the surface and the material it leaves adds to the scallop, so it gets the
tight tolerance; where it is convex the chord dips *into* the part, which only the gouge
budget bounds (and the cutter stage checks every move against it), so it may get a wider
one (``e_convex``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from conformill.errors import PlanningError
from conformill.planning.steps import forward_step_one


@njit(cache=True, nogil=True)
def _chord_deviation(X, idx):
    k, m = X.shape[0], idx.shape[0]
    dev = np.zeros(m - 1)
    arg = np.zeros(m - 1, dtype=np.int64)
    for j in range(m - 1):
        a, b = idx[j], idx[j + 1]
        end = b if j < m - 2 else k
        ax, ay, az = X[a, 0], X[a, 1], X[a, 2]
        ux, uy, uz = X[b, 0] - ax, X[b, 1] - ay, X[b, 2] - az
        uu = max(ux * ux + uy * uy + uz * uz, 1e-300)
        best, barg = -1.0, a
        for i in range(a, end):
            wx, wy, wz = X[i, 0] - ax, X[i, 1] - ay, X[i, 2] - az
            t = min(max((wx * ux + wy * uy + wz * uz) / uu, 0.0), 1.0)
            dx, dy, dz = wx - t * ux, wy - t * uy, wz - t * uz
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d > best:  # the first sample of the largest distance
                best, barg = d, i
        dev[j], arg[j] = best, barg
    return dev, arg


def chord_deviation(X: np.ndarray, idx: np.ndarray):
    """Largest distance of the skipped samples from each chord.

    Parameters
    ----------
    X : (k, 3) float64
        Dense polyline.
    idx : (m,) int64
        Increasing indices of the kept samples (first 0, last k - 1).

    Returns
    -------
    dev : (m - 1,) float64
        Max distance of ``X[idx[j] .. idx[j+1]]`` from the chord ``X[idx[j]] X[idx[j+1]]``.
    arg : (m - 1,) int64
        Index in ``X`` of the farthest sample of each chord (the first, on ties).
    """
    X = np.ascontiguousarray(X, dtype=np.float64)
    idx = np.ascontiguousarray(idx, dtype=np.int64)
    if len(idx) < 2:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    return _chord_deviation(X, idx)


def select_forward(X: np.ndarray, kappa: np.ndarray, e: float, max_step: float, max_rounds: int = 30,
                   e_convex: float | None = None):
    """Indices of the dense samples kept as cutter-contact points.

    Parameters
    ----------
    X : (k, 3) float64
        Dense CC samples of the path (mm).
    kappa : (k,) float64
        Normal curvature along the path at the samples (> 0 concave).
    e : float
        Chord deviation tolerance (mm).
    max_step : float
        Longest step allowed (mm): on flat ground the step, and no chord longer (where the
        samples lie closer than this).
    e_convex : float, optional
        Tolerance where the path is convex along its direction (``kappa < 0``); a chord
        that skips a concave or flat sample keeps ``e``. Default ``e``.

    Returns
    -------
    idx : (m,) int64
        Kept sample indices, increasing, including both ends.

    Raises
    ------
    PlanningError
        ``e``, ``e_convex`` or ``max_step`` is not a positive number, ``X`` is not
        ``(k, 3)`` with one curvature per sample, or a point is not finite.
    """
    X = np.ascontiguousarray(X, dtype=np.float64)  # (float32 points are measured in float64)
    kappa = np.ascontiguousarray(kappa, dtype=np.float64)
    for name, v in (("tolerance", e), ("convex tolerance", e if e_convex is None else e_convex),
                    ("longest step", max_step)):
        if not (math.isfinite(v) and v > 0):
            raise PlanningError(f"forward steps: the {name} must be a positive number, got {v}")
    if X.ndim != 2 or X.shape[1] != 3 or kappa.shape != (len(X),):
        raise PlanningError(f"forward steps: points of shape (k, 3) and k curvatures are needed, got {X.shape} "
                            f"and {kappa.shape}")
    if len(X) <= 2:
        return np.arange(len(X), dtype=np.int64)
    idx = _select(X, kappa, float(e), np.nan if e_convex is None else float(e_convex), float(max_step),
                  int(max_rounds))
    if idx.size == 0:
        raise PlanningError("forward steps: the path's points must be finite")
    return idx


@njit(cache=True, nogil=True, error_model="numpy")
def _select(X, kappa, e, e_convex, max_step, max_rounds):
    """:func:`select_forward` for ``k > 2`` samples (``e_convex`` NaN: none), in one
    compiled pass with the arithmetic of its numpy form (the forward step per sample, the
    cumulative ``ds / l_f``, ``linspace`` and ``searchsorted``): the same indices, without
    a dozen array calls per piece (igea zigzag ``--scan``: 0.24 s of the plan's forward
    steps, two thirds of it those calls)."""
    k = X.shape[0]
    # the tolerance per sample and the forward step l_f there
    tol = np.empty(k)
    lf = np.empty(k)
    for i in range(k):
        tol[i] = e_convex if (e_convex == e_convex and kappa[i] < 0) else e
        lf[i] = forward_step_one(tol[i], kappa[i], max_step)
    # N: the cumulative steps in units of l_f (the smaller of each chord's two ends)
    N = np.empty(k)
    N[0] = 0.0
    c = 0.0
    for i in range(k - 1):
        dx, dy, dz = X[i + 1, 0] - X[i, 0], X[i + 1, 1] - X[i, 1], X[i + 1, 2] - X[i, 2]
        c += np.sqrt(dx * dx + dy * dy + dz * dz) / min(lf[i], lf[i + 1])
        N[i + 1] = c
    if not np.isfinite(N[k - 1]):  # a point not finite: the caller says so
        return np.empty(0, dtype=np.int64)
    m = max(1, int(np.ceil(N[k - 1] - 1e-9)))
    # the last sample at or before each of m + 1 evenly spaced targets keeps every step at
    # or below l_f (linspace's targets: i * (N / m), the last exactly N)
    step = N[k - 1] / m
    idx = np.empty(m + 1, dtype=np.int64)
    n = 0
    j = 0  # samples with N <= target so far (the targets increase)
    for i in range(m + 1):
        t = N[k - 1] if i == m else i * step + 0.0
        while j < k and N[j] <= t:
            j += 1
        # (the first is the path's start, also where it starts with repeated points)
        v = k - 1 if i == m else 0 if i == 0 else min(max(j - 1, 0), k - 1)
        if n == 0 or v != idx[n - 1]:
            idx[n] = v
            n += 1
    # the equidistribution keeps a step within l_f plus one sample: no chord longer than
    # max_step (where samples allow), then none deviating more than allowed
    return _add_farthest(X, tol, _cap_steps(X, idx[:n].copy(), max_step), max_rounds)


@njit(cache=True, nogil=True)
def _cap_steps(X, idx, max_step):
    """``idx`` with samples added so that no chord is longer than ``max_step``: after each
    kept sample, the farthest sample within ``max_step`` of it (the next sample where even
    that one is farther)."""
    m = idx.shape[0]
    out = np.empty(X.shape[0], dtype=np.int64)
    n = 0
    m2 = max_step * max_step
    for j in range(m - 1):
        cur = idx[j]
        out[n] = cur
        n += 1
        b = idx[j + 1]
        while True:
            dx, dy, dz = X[b, 0] - X[cur, 0], X[b, 1] - X[cur, 1], X[b, 2] - X[cur, 2]
            if dx * dx + dy * dy + dz * dz <= m2:
                break
            i = cur + 1
            while i + 1 < b:
                ex, ey, ez = X[i + 1, 0] - X[cur, 0], X[i + 1, 1] - X[cur, 1], X[i + 1, 2] - X[cur, 2]
                if ex * ex + ey * ey + ez * ez > m2:
                    break
                i += 1
            cur = i
            if cur >= b:
                break
            out[n] = cur
            n += 1
    out[n] = idx[m - 1]
    n += 1
    return out[:n].copy()


@njit(cache=True, nogil=True)
def _add_farthest(X, tol, idx, max_rounds):
    """Rounds of: every chord whose farthest skipped sample deviates by more than the
    tightest tolerance over the samples it spans (ends included) gets that sample."""
    for _ in range(max_rounds):
        dev, arg = _chord_deviation(X, idx)
        m = idx.shape[0]
        bad = np.zeros(m - 1, dtype=np.bool_)
        nbad = 0
        for j in range(m - 1):
            lim = tol[idx[j]]
            for i in range(idx[j] + 1, idx[j + 1] + 1):
                lim = min(lim, tol[i])
            if dev[j] > lim:
                bad[j] = True
                nbad += 1
        if nbad == 0:
            break
        # merge: the farthest sample of a bad chord lies inside it, so the order holds
        out = np.empty(m + nbad, dtype=np.int64)
        n = 0
        for j in range(m - 1):
            out[n] = idx[j]
            n += 1
            if bad[j] and arg[j] != idx[j] and arg[j] != idx[j + 1]:
                out[n] = arg[j]
                n += 1
        out[n] = idx[m - 1]
        n += 1
        idx = out[:n].copy()
    return idx
