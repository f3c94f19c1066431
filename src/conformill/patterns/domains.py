"""The curve families of the three patterns, in the rectangle and circle domains.

Rectangle ``[0, X] x [0, Y]``: iso-u lines walked in v (direction parallel, zigzag).
Circle of radius ``R0`` at the origin: circles ``rho = const`` (contour parallel) and the
revolutions of a spiral between consecutive circles (METHOD section 5). The circle domain
is bounded by the *polygon* of boundary vertices (its edges are chords of the circle), so
every curve is clipped radially to that polygon: the last ring is the boundary itself.
"""

from __future__ import annotations

import numpy as np

from conformill.patterns.family import Family

TWO_PI = 2.0 * np.pi


class IsoU(Family):
    """Lines ``u = s`` of the rectangle domain, ``v = tau * Y``."""

    closed = False

    def __init__(self, Y: float, delta: float, reverse: bool = False):
        self.Y = float(Y)
        self.delta = float(delta)

    def along(self, s, tau):
        P = np.column_stack([np.full(len(tau), s), tau * self.Y])
        t = np.tile([0.0, 1.0], (len(tau), 1))
        return P, t

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
        self.R0 = float(np.max(np.linalg.norm(uvb, axis=1)))

    def limit(self, theta: np.ndarray) -> np.ndarray:
        """Distance from the origin to the polygon along direction ``theta``."""
        th = np.mod(theta, TWO_PI)
        b = len(self.ang)
        j = np.searchsorted(self.ang, th, side="right") - 1  # edge j -> j+1 (cyclic)
        a = self.pts[j % b]
        c = self.pts[(j + 1) % b]
        d = np.column_stack([np.cos(th), np.sin(th)])
        # ray o + t d meets segment a + w (c - a): solve [d, a - c] [t, w] = a
        e = c - a
        det = d[:, 0] * (-e[:, 1]) - d[:, 1] * (-e[:, 0])
        t = (a[:, 0] * (-e[:, 1]) - a[:, 1] * (-e[:, 0])) / np.where(np.abs(det) > 1e-300, det, 1e-300)
        return np.where(np.isfinite(t) & (t > 0), t, self.R0)

    def clip(self, P: np.ndarray) -> np.ndarray:
        rho = np.linalg.norm(P, axis=1)
        th = np.arctan2(P[:, 1], P[:, 0])
        lim = self.limit(th)
        scale = np.where(rho > lim, lim / np.maximum(rho, 1e-300), 1.0)
        return P * scale[:, None]


class Rings(Family):
    """Circles ``rho = s`` of the circle domain (clipped to the boundary polygon)."""

    closed = True

    def __init__(self, poly: BoundaryPolygon, delta: float, theta0: float = 0.0):
        self.poly = poly
        self.delta = float(delta)
        self.theta0 = float(theta0)

    def along(self, s, tau):
        th = self.theta0 + TWO_PI * tau
        rho = np.minimum(s, self.poly.limit(th))
        P = rho[:, None] * np.column_stack([np.cos(th), np.sin(th)])
        t = np.column_stack([-np.sin(th), np.cos(th)])
        return P, t

    def initial_tau(self, s):
        n = max(32, int(np.ceil(TWO_PI * s / self.delta)))
        return np.linspace(0.0, 1.0, n + 1)


class SpiralTurn(Family):
    """One revolution ``rho = r0 + tau (r1 - r0)``, ``theta = theta0 + 2 pi tau`` (METHOD 5)."""

    closed = False

    def __init__(self, poly: BoundaryPolygon, r0: float, r1: float, delta: float, theta0: float = 0.0):
        self.poly = poly
        self.r0, self.r1 = float(r0), float(r1)
        self.delta = float(delta)
        self.theta0 = float(theta0)

    def along(self, s, tau):
        th = self.theta0 + TWO_PI * tau
        rho_raw = self.r0 + tau * (self.r1 - self.r0)
        rho = np.minimum(rho_raw, self.poly.limit(th))
        c, s_ = np.cos(th), np.sin(th)
        P = rho[:, None] * np.column_stack([c, s_])
        dr = self.r1 - self.r0
        t = np.column_stack([dr * c - TWO_PI * rho * s_, dr * s_ + TWO_PI * rho * c])
        nt = np.linalg.norm(t, axis=1, keepdims=True)
        t = np.where(nt > 1e-300, t / np.maximum(nt, 1e-300), np.column_stack([-s_, c]))
        return P, t

    def initial_tau(self, s):
        n = max(32, int(np.ceil(TWO_PI * max(self.r1, 1e-12) / self.delta)))
        return np.linspace(0.0, 1.0, n + 1)
