"""Adaptive spacing: a warp of the offset coordinate so that paths follow the local step.

The paper spaces consecutive paths by the *minimum* of the allowed domain step over the
whole current path (METHOD 4-5). On a scan the bottleneck moves: the nose needs small
steps at one place along a path, the cheek at another, so the min rule packs every path
as densely as the worst point of each path, and paths came out 3-8x the length floor.

Going past the paper, the offset coordinate ``g`` of a family (``u`` of the rectangle,
``rho`` of the circle) is replaced by a *level* ``s`` in [0, 1]. Along every line of
constant ``tau`` (a ``v``-line, a ray), the level is the normalised count of allowed steps
from the first curve:

    F(g, tau) = integral_{g0}^{g} dg' / delta(g', tau),      s = F(g, tau) / F(g_end, tau)

with ``delta`` the allowed domain step across the curves (METHOD 4, the same rule as the
planner's). A curve ``s = const`` is therefore not an iso-line: it advances, along each
ray, in proportion to what that ray needs, and every curve still runs from one side of
the domain to the other (rows from ``v = 0`` to ``Y``; closed rings around the centre) and
the last one is the boundary. The planner then steps in ``s`` with its usual rule (the
minimum over the path of the allowed step, now measured in levels) and its usual 3D
spacing check, so the warp decides only where the paths bend; it can make the plan longer
or shorter, never unsafe.

``F`` is smoothed along ``tau`` (a Gaussian over a few percent of the domain) so that the
curves bend gently, and mixed with a small share of the identity, which bounds how far
apart two curves can open where a ray needs almost no steps.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from conformill.patterns.filters import gaussian_rows


@njit(cache=True, nogil=True, inline="always")
def _bilinear_one(G, s, t, closed):
    """``(x, dx/ds)`` of the bilinear interpolation of ``G`` (levels x columns) at level
    ``s`` (clipped to [0, 1]) and along-parameter ``t`` (periodic when ``closed``)."""
    m, n = G.shape
    fs = min(max(s, 0.0), 1.0) * (m - 1)
    j0 = min(int(math.floor(fs)), m - 2)
    ws = fs - j0
    if closed:
        f = (t - math.floor(t)) * n  # tau mod 1, as np.mod for a positive period
        i0 = int(math.floor(f)) % n
        i1 = (i0 + 1) % n
        wt = f - math.floor(f)
    else:
        f = min(max(t, 0.0), 1.0) * (n - 1)
        i0 = min(int(math.floor(f)), n - 2)
        i1 = i0 + 1
        wt = f - i0
    g00 = G[j0, i0]
    g01 = G[j0, i1]
    g10 = G[j0 + 1, i0]
    g11 = G[j0 + 1, i1]
    lo = g00 + wt * (g01 - g00)
    hi = g10 + wt * (g11 - g10)
    return lo + ws * (hi - lo), (hi - lo) * (m - 1)


@njit(cache=True, nogil=True)
def _offsets(G, s, tau, closed, start, end):
    """:meth:`Warp.offset` per point: ``start + x (end - start)`` and ``dx (end - start)``,
    with ``(x, dx/ds)`` the bilinear interpolation of the table (:func:`_bilinear_one`)."""
    k = tau.shape[0]
    g = np.empty(k)
    dg = np.empty(k)
    for p in range(k):
        x, dx = _bilinear_one(G, s[p], tau[p], closed)
        span = end[p] - start
        g[p] = start + x * span
        dg[p] = dx * span
    return g, dg


class Warp:
    """Levels ``s`` in [0, 1] to base offsets, on a grid of ``tau``.

    Parameters
    ----------
    tau : (n,) float64
        Along-parameters of the grid columns, increasing in [0, 1].
    G : (m, n) float64
        Fraction ``x`` in [0, 1] of the way from the first curve to the end of each column
        at the levels ``linspace(0, 1, m)``; monotone in the level.
    start : float
        Base offset of level 0.
    end : callable
        ``end(tau) -> (k,)``: base offset of level 1 (the domain's far side).
    closed : bool
        Columns are periodic in ``tau`` (rings).
    """

    def __init__(self, tau, G, start: float, end, closed: bool):
        self.tau = np.asarray(tau, dtype=np.float64)
        self.G = np.ascontiguousarray(G, dtype=np.float64)
        self.start = float(start)
        self.end = end
        self.closed = bool(closed)

    def offset(self, s, tau, end=None):
        """Base offsets ``g`` and ``dg/ds`` at levels ``s`` (scalar or per ``tau``).

        ``end`` may pass ``self.end(tau)`` when the caller has it already.
        """
        tau = np.ascontiguousarray(tau, dtype=np.float64)
        if end is None:
            end = self.end(tau)
        s = np.array(np.broadcast_to(np.asarray(s, dtype=np.float64), tau.shape))
        end = np.array(np.broadcast_to(np.asarray(end, dtype=np.float64), tau.shape))
        g, dg = _offsets(self.G, s.reshape(-1), tau.reshape(-1), self.closed, self.start, end.reshape(-1))
        return g.reshape(tau.shape), dg.reshape(tau.shape)


def build_warp(planner, family, start: float, end, n_tau: int = 257, n_off: int = 193,
               n_levels: int = 1025, smooth: float = 0.02, identity_share: float = 0.05) -> Warp:
    """Measure the allowed step on a grid of the base family and build its :class:`Warp`.

    Parameters
    ----------
    planner : conformill.patterns.family.Planner
        Gives the surface and the side-interval rule (:meth:`Planner.allowed`).
    family : conformill.patterns.family.Family
        The un-warped family (:class:`IsoU` or :class:`Rings`); ``along`` must accept one
        offset per ``tau``.
    start : float
        Base offset of the first curve.
    end : callable
        ``end(tau)``: base offset of the last curve along each column.
    n_tau, n_off : int
        Grid columns along the curves and samples along each column.
    n_levels : int
        Rows of the inverse table.
    smooth : float
        Gaussian width of the smoothing along ``tau``, as a share of the ``tau`` range.
    identity_share : float
        Share of the uniform spacing mixed in (bounds the opening between curves).
    """
    closed = family.closed
    tau = np.arange(n_tau) / n_tau if closed else np.linspace(0.0, 1.0, n_tau)
    span = np.asarray(end(tau), dtype=np.float64) - start
    x = np.linspace(0.0, 1.0, n_off)
    g = start + x[:, None] * span[None, :]  # (n_off, n_tau)
    tt = np.broadcast_to(tau, g.shape)
    P, t = family.along(g.ravel(), tt.ravel())
    S = planner.surface.sample(P)
    ls, _ = planner.allowed(S, t)
    delta = ls * S.length(t) / S.area_factor()  # allowed base-offset step
    delta = delta.reshape(g.shape)
    good = np.isfinite(delta) & (delta > 0)
    fill = np.median(delta[good]) if good.any() else 1.0
    delta = np.where(good, delta, fill)
    # steps needed per unit fraction x along each column
    dens = span[None, :] / delta
    F = np.zeros_like(dens)
    F[1:] = np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(x)[:, None], axis=0)
    total = F[-1]
    Fn = F / np.where(total > 0, total, 1.0)[None, :]
    Fn[:, total <= 0] = x[:, None]
    if smooth > 0:
        sig = smooth * n_tau
        Fn = gaussian_rows(Fn, sig, closed)  # scipy.ndimage.gaussian_filter1d's, without its import
    Fn = (1.0 - identity_share) * Fn + identity_share * x[:, None]
    Fn[0], Fn[-1] = 0.0, 1.0
    levels = np.linspace(0.0, 1.0, n_levels)
    G = np.empty((n_levels, n_tau))
    for i in range(n_tau):
        G[:, i] = np.interp(levels, Fn[:, i], x)
    G[0], G[-1] = 0.0, 1.0
    return Warp(tau, G, start, end, closed)
