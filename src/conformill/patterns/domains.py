"""The curve families of the three patterns, in the rectangle and circle domains.

Rectangle ``[0, X] x [0, Y]``: iso-u lines walked in v (direction parallel, zigzag).
Circle of radius ``R0`` at the origin: circles ``rho = const`` (contour parallel) and the
revolutions of a spiral between consecutive circles (METHOD section 5). The circle domain
is bounded by the *polygon* of boundary vertices (its edges are chords of the circle), so
every curve is clipped radially to that polygon: the last ring is the boundary itself.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from conformill.patterns.family import Family
from conformill.patterns.warp import _bilinear_one

TWO_PI = 2.0 * np.pi


MIN_CROSSING = 0.25  # floor of |det(a, t)| in a warped family's rate


@njit(cache=True, nogil=True)
def _unit_tangent_kernel(P, tau, fallback):
    # np.gradient(P, tau, axis=0) (second order inside, first order at the ends), then
    # normalised; rows of zero length take the fallback
    k = P.shape[0]
    out = np.empty((k, 2))
    for i in range(k):
        if i == 0:
            h = tau[1] - tau[0]
            dx, dy = (P[1, 0] - P[0, 0]) / h, (P[1, 1] - P[0, 1]) / h
        elif i == k - 1:
            h = tau[k - 1] - tau[k - 2]
            dx, dy = (P[k - 1, 0] - P[k - 2, 0]) / h, (P[k - 1, 1] - P[k - 2, 1]) / h
        else:
            hs, hd = tau[i] - tau[i - 1], tau[i + 1] - tau[i]
            a = -hd / (hs * (hd + hs))
            b = (hd - hs) / (hd * hs)
            c = hs / (hd * (hd + hs))
            dx = a * P[i - 1, 0] + b * P[i, 0] + c * P[i + 1, 0]
            dy = a * P[i - 1, 1] + b * P[i, 1] + c * P[i + 1, 1]
        n = np.sqrt(dx * dx + dy * dy)
        if n > 1e-300:
            out[i, 0], out[i, 1] = dx / n, dy / n
        else:
            out[i, 0], out[i, 1] = fallback[i, 0], fallback[i, 1]
    return out


def _unit_tangent(P, tau, fallback):
    """Unit tangents of the domain polyline ``P`` sampled at ``tau`` (finite differences)."""
    if len(tau) < 2:
        return fallback
    return _unit_tangent_kernel(np.ascontiguousarray(P, dtype=np.float64), np.ascontiguousarray(tau, dtype=np.float64),
                                np.ascontiguousarray(fallback, dtype=np.float64))


def _level_rate(fam, levels, tau, a, t):
    """Domain distance a warped curve moves across itself per unit level: ``|det(a, t)| dg/ds``.

    ``a`` is the unit base direction (u or the ray); ``dg/ds`` comes from the family's last
    ``along`` call when it was on these very ``tau``, else from the warp at ``levels``.
    """
    last = getattr(fam, "_last", None)
    if last is not None and last[0] is tau:
        dg = last[1]
    else:
        _, dg = fam.warp.offset(levels, tau)
    det = np.abs(a[:, 0] * t[:, 1] - a[:, 1] * t[:, 0])
    return np.maximum(det, MIN_CROSSING) * dg


def _ray(fam, tau):
    """Unit radial directions of the circle domain at along-parameters ``tau`` (the
    cosines and sines of the family's last ``along`` call when it was on these very
    ``tau``: the same values)."""
    last = getattr(fam, "_last", None)
    if last is not None and last[0] is tau and len(last) == 4:
        return np.column_stack([last[2], last[3]])
    th = fam.theta0 + TWO_PI * tau
    return np.column_stack([np.cos(th), np.sin(th)])


@njit(cache=True, nogil=True)
def _ring_points(c, s, lim, G, lev, tau, closed, start):
    """Points of a warped ring or spiral turn: the warp's base offset ``rho`` at each
    level and ray (:meth:`conformill.patterns.warp.Warp.offset` with ``end = lim``),
    held within the polygon's ``lim`` (as ``np.minimum``), at ``rho (c, s)``. Returns
    ``(P, dg/ds)``."""
    k = tau.shape[0]
    P = np.empty((k, 2))
    dg = np.empty(k)
    for p in range(k):
        x, dx = _bilinear_one(G, lev[p], tau[p], closed)
        span = lim[p] - start
        rho = start + x * span
        dg[p] = dx * span
        if rho > lim[p] or lim[p] != lim[p]:  # (np.minimum: a NaN limit wins, a NaN rho stays)
            rho = lim[p]
        P[p, 0] = rho * c[p]
        P[p, 1] = rho * s[p]
    return P, dg


def _warped_ring(fam, lev, tau, c, s_, lim):
    """``(P, t)`` of a warped :class:`Rings` or :class:`SpiralTurn` curve at levels ``lev``
    (a scalar or one per ``tau``), remembering ``dg/ds`` and the ray for :meth:`rate`."""
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    lev = np.array(np.broadcast_to(np.asarray(lev, dtype=np.float64), tau.shape))
    P, dg = _ring_points(c, s_, lim, fam.warp.G, lev, tau, fam.warp.closed, fam.warp.start)
    fam._last = (tau, dg, c, s_)
    return P, _unit_tangent(P, tau, np.column_stack([-s_, c]))


class IsoU(Family):
    """Lines ``u = s`` of the rectangle domain, ``v = tau * Y``.

    With a ``warp`` (:class:`conformill.patterns.warp.Warp`), ``s`` is a level in [0, 1]
    and the line is ``u = warp.offset(s, tau)``: adaptive spacing.
    """

    closed = False

    def __init__(self, Y: float, delta: float, warp=None):
        self.Y = float(Y)
        self.delta = float(delta)
        self.warp = warp

    def along(self, s, tau):
        up = np.tile([0.0, 1.0], (len(tau), 1))
        if self.warp is None:
            return np.column_stack([np.broadcast_to(s, tau.shape), tau * self.Y]), up
        u, dg = self.warp.offset(s, tau)
        self._last = (tau, dg)
        P = np.column_stack([u, tau * self.Y])
        return P, _unit_tangent(P, tau, up)

    def rate(self, s, tau, P, t):
        if self.warp is None:
            return None
        return _level_rate(self, s, tau, np.tile([1.0, 0.0], (len(tau), 1)), t)

    def initial_tau(self, s):
        return np.linspace(0.0, 1.0, max(8, int(np.ceil(self.Y / self.delta))) + 1)


class Segment(Family):
    """A straight domain segment from ``p0`` to ``p1`` (links between paths)."""

    closed = False

    def __init__(self, p0, p1, delta: float, clip=None):
        self.p0 = np.asarray(p0, dtype=np.float64)
        self.p1 = np.asarray(p1, dtype=np.float64)
        self.delta = float(delta)
        self.clip = clip

    def along(self, s, tau):
        d = self.p1 - self.p0
        P = self.p0 + tau[:, None] * d
        if self.clip is not None:
            P = self.clip(P)
        L = max(np.linalg.norm(d), 1e-300)
        return P, np.tile(d / L, (len(tau), 1))

    def initial_tau(self, s):
        L = np.linalg.norm(self.p1 - self.p0)
        return np.linspace(0.0, 1.0, max(2, int(np.ceil(L / self.delta))) + 1)


@njit(cache=True, nogil=True)
def _edge_angles(theta, ang, phi, start):
    """Per direction: the polygon edge it crosses (``j``, edge ``j -> j + 1`` cyclic, from
    the sorted vertex angles ``ang``) and the angle to that edge's normal ``phi[j]``
    (``theta mod 2 pi`` as ``np.mod``, the edge as ``np.searchsorted(..., side="right") - 1``).

    ``start[i]`` counts the vertex angles up to ``i * 2 pi / nb`` (``nb + 1`` entries): the
    search runs between the counts a bucket either side of the direction's own, which
    hold its answer even where rounding puts it in the next bucket."""
    k = theta.shape[0]
    b = ang.shape[0]
    nb = start.shape[0] - 1
    per = nb / TWO_PI
    j = np.empty(k, dtype=np.int64)
    arg = np.empty(k)
    for p in range(k):
        x = theta[p]
        # np.fmod is exact, so within one turn either side of [0, 2 pi) it is x itself and
        # the sum below is the one np.mod makes: the same bits without the libm call
        if 0.0 < x < TWO_PI:
            th = x
        elif -TWO_PI < x < 0.0:
            th = x + TWO_PI
        else:
            th = np.fmod(x, TWO_PI)
            if th != 0.0:
                if th < 0.0:  # (np.mod: the sign of the divisor)
                    th += TWO_PI
            else:
                th = 0.0
        lo = 0
        hi = b
        if math.isfinite(th) and nb > 0:
            q = min(max(int(th * per), 0), nb - 1)
            lo = start[max(q - 1, 0)]
            hi = start[min(q + 2, nb)]
        while lo < hi:  # first vertex angle above th
            mid = (lo + hi) // 2
            if ang[mid] <= th:
                lo = mid + 1
            else:
                hi = mid
        e = (lo - 1) % b
        j[p] = e
        arg[p] = th - phi[e]
    return j, arg


@njit(cache=True, nogil=True, error_model="numpy")
def _edge_distances(cs, j, p, ok, R0):
    """Distance to the edge ``j`` along a direction at ``cos = cs`` to its normal (``R0``
    where the edge is degenerate or not ahead)."""
    k = cs.shape[0]
    out = np.empty(k)
    for q in range(k):
        c = cs[q]
        e = j[q]
        t = p[e] / (c if c > 1e-300 else 1e-300)
        out[q] = t if (ok[e] and c > 1e-300 and t > 0 and math.isfinite(t)) else R0
    return out


class BoundaryPolygon:
    """Radial clipping to the polygon of boundary vertices in the circle domain.

    Parameters
    ----------
    uvb : (b, 2) float64
        Boundary vertices on the circle, in loop order (counter-clockwise).
    """

    def __init__(self, uvb: np.ndarray):
        ang = np.mod(np.arctan2(uvb[:, 1], uvb[:, 0]), TWO_PI)
        order = np.argsort(ang)
        self.ang = ang[order]
        self.pts = uvb[order]
        # vertex angles up to each of len(ang) equal buckets' edges (_edge_angles' search)
        self._start = np.searchsorted(self.ang, np.arange(len(self.ang) + 1) * (TWO_PI / max(len(self.ang), 1)),
                                      side="right").astype(np.int64)
        # the last edge is 2 pi itself: nb * (2 pi / nb) may round below it, and a vertex
        # angle of 2 pi (np.mod of a tiny negative angle) must stay inside the last bucket
        self._start[-1] = len(self.ang)
        self.R0 = float(np.max(np.linalg.norm(uvb, axis=1)))
        # each edge j -> j+1 (cyclic) as a line: distance p from the origin, normal angle phi;
        # along direction theta the edge is at p / cos(theta - phi)
        a, c = self.pts, np.roll(self.pts, -1, axis=0)
        e = c - a
        nrm = np.column_stack([e[:, 1], -e[:, 0]])
        ln = np.linalg.norm(nrm, axis=1)
        nrm = nrm / np.where(ln > 1e-300, ln, 1.0)[:, None]
        p = np.einsum("ij,ij->i", a, nrm)
        flip = p < 0
        nrm[flip] *= -1.0
        self._p = np.abs(p)
        self._phi = np.arctan2(nrm[:, 1], nrm[:, 0])
        self._ok = ln > 1e-300

    def limit(self, theta: np.ndarray) -> np.ndarray:
        """Distance from the origin to the polygon along direction ``theta``."""
        theta = np.asarray(theta, dtype=np.float64)
        j, arg = _edge_angles(np.ascontiguousarray(theta).reshape(-1), self.ang, self._phi, self._start)
        # (the cosine is numpy's: its bits, not libm's, as the plans have always used)
        t = _edge_distances(np.cos(arg), j, self._p, self._ok, self.R0)
        return t.reshape(theta.shape)

    def clip(self, P: np.ndarray) -> np.ndarray:
        rho = np.linalg.norm(P, axis=1)
        th = np.arctan2(P[:, 1], P[:, 0])
        lim = self.limit(th)
        scale = np.where(rho > lim, lim / np.maximum(rho, 1e-300), 1.0)
        return P * scale[:, None]


def _largest_offset(fam, s):
    """Largest base offset of curve ``s`` (levels map through the warp)."""
    if fam.warp is None:
        return float(s)
    tau = np.linspace(0.0, 1.0, 129)
    return float(np.max(fam.warp.offset(s, tau)[0]))


class Rings(Family):
    """Circles ``rho = s`` of the circle domain (clipped to the boundary polygon).

    With a ``warp``, ``s`` is a level in [0, 1] and the ring is
    ``rho = warp.offset(s, theta)``: adaptive spacing; level 1 is the boundary polygon.
    """

    closed = True

    def __init__(self, poly: BoundaryPolygon, delta: float, theta0: float = 0.0, warp=None):
        self.poly = poly
        self.delta = float(delta)
        self.theta0 = float(theta0)
        self.warp = warp

    def end(self, tau):
        """Base offset of the boundary along the rays ``tau``."""
        return self.poly.limit(self.theta0 + TWO_PI * np.asarray(tau))

    def along(self, s, tau):
        th = self.theta0 + TWO_PI * tau
        c, s_ = np.cos(th), np.sin(th)
        circle = np.column_stack([-s_, c])
        if self.warp is None:
            rho = np.minimum(s, self.poly.limit(th))
            return rho[:, None] * np.column_stack([c, s_]), circle
        return _warped_ring(self, s, tau, c, s_, self.poly.limit(th))

    def rate(self, s, tau, P, t):
        if self.warp is None:
            return None
        return _level_rate(self, s, tau, _ray(self, tau), t)

    def initial_tau(self, s):
        n = max(32, int(np.ceil(TWO_PI * _largest_offset(self, s) / self.delta)))
        return np.linspace(0.0, 1.0, n + 1)


class SpiralTurn(Family):
    """One revolution ``rho = r0 + tau (r1 - r0)``, ``theta = theta0 + 2 pi tau`` (METHOD 5)."""

    closed = False

    def __init__(self, poly: BoundaryPolygon, r0: float, r1: float, delta: float, theta0: float = 0.0,
                 warp=None):
        self.poly = poly
        self.r0, self.r1 = float(r0), float(r1)
        self.delta = float(delta)
        self.theta0 = float(theta0)
        self.warp = warp

    def along(self, s, tau):
        th = self.theta0 + TWO_PI * tau
        rho_raw = self.r0 + tau * (self.r1 - self.r0)
        c, s_ = np.cos(th), np.sin(th)
        lim = self.poly.limit(th)
        if self.warp is not None:  # r0, r1 are levels
            return _warped_ring(self, rho_raw, tau, c, s_, lim)
        rho = np.minimum(rho_raw, lim)
        P = rho[:, None] * np.column_stack([c, s_])
        dr = self.r1 - self.r0
        t = np.column_stack([dr * c - TWO_PI * rho * s_, dr * s_ + TWO_PI * rho * c])
        nt = np.linalg.norm(t, axis=1, keepdims=True)
        t = np.where(nt > 1e-300, t / np.maximum(nt, 1e-300), np.column_stack([-s_, c]))
        return P, t

    def rate(self, s, tau, P, t):
        if self.warp is None:
            return None
        return _level_rate(self, self.r0 + tau * (self.r1 - self.r0), tau, _ray(self, tau), t)

    def initial_tau(self, s):
        n = max(32, int(np.ceil(TWO_PI * max(_largest_offset(self, self.r1), 1e-12) / self.delta)))
        return np.linspace(0.0, 1.0, n + 1)
