"""Holder clearance: the stick-out a program needs so that the tool holder never meets the part.

A 3-axis ball-end tool is the ball, its shank (radius ``r``, the drop-cutter's concern) and,
``L`` above the tip (the *stick-out*, gauge line to tip), a holder: here a cylinder of radius
``R`` (> ``r``, the holder's widest radius) that reaches up without end. Along a move from
``a`` to ``b`` the tip is at ``t(s) = a + s (b - a)``, ``s`` in ``[0, 1]``, and the holder's
face at ``t_z(s) + L``. A part point ``p`` within ``R`` of the tool axis in XY meets the
holder unless ``p_z <= t_z(s) + L`` for every ``s`` at which it is within reach:

    L  >=  need(move) = max over p, s with |p_xy - t_xy(s)| <= R  of  p_z - t_z(s).

The program needs the largest ``need`` over its moves (rapids, plunges and hops included).
A stepped holder (a collet nut of radius R, then a body of radius R_k from h_k above the
face) is a cylinder per step, each reaching up without end: it needs ``max_k (need_k -
h_k)``, ``need_k`` being a cylinder of radius ``R_k``'s (each step wider than the one
below it: a narrower one could never meet the part first, and is refused).

Bounds, not a sampling
----------------------
Over a triangle mesh this module brackets ``need`` per move, in three passes:

1. *every move*: the highest triangle top over the cells of an XY raster (cell ``R / 16``,
   or 1/1000 of the part's XY extent if larger)
   within reach of the move's points, by a disk maximum filter of the raster: an upper bound
   (it reaches about 1.7 cells further and takes whole triangles' tops); and the highest
   vertex over the cells wholly within reach: a lower bound;
2. *the moves whose bound can hold the program's largest need*, highest bound first, over
   the triangles whose XY projection comes within ``R`` of the move's segment: the exact
   largest ``p_z`` of each triangle within reach (the maximum of a linear function over the
   convex set triangle ∩ capsule lies at an end of an edge's span in reach or at a support
   point of the capsule) less the move's lowest tip (upper bound), and at those same points
   the exact need (lower bound: they are points of the part). A move that travels in XY and
   climbs is then checked in pieces that climb at most ``climb`` (0.01 mm), so the two
   bounds of the largest need meet within ``climb``;
3. with a stick-out ``L``: the moves whose bounds straddle ``L``, likewise, stopping at the
   first point of the part that certainly hits.

A program is judged clear when ``L`` is at least the largest upper bound; the report gives
both bounds, and where (the move's source line, its lowest tip, and the point of the part).
On the 620k-face igea program (886310 moves) the check takes 0.7-0.9 s on two cores for
R = 8-25 mm, with or without a stick-out it clears; 8.5 s and 5.3 s for stick-outs that 22 %
and 90 % of the moves cannot clear (README, "Holder clearance").

A taper is not modelled (give it as steps at its widest radius), nor are the spindle nose
and the machine's travel. Arcs are
checked on the chords the reader replaces them by (within its ``chord_tol``, 0.001 mm by
default), so on an arc the reach is short by up to that much.

Nothing here imports the planner: the check reads the program as written
(:class:`conformill.verify.gcode.Program`).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numba as nb
import numpy as np

from conformill.errors import ConformillError, PlanningError
from conformill.verify.gcode import Program

__all__ = ["HolderCheck", "holder_clearance"]


@nb.njit(cache=True, inline="always")
def _pt_seg_d2(px, py, ax, ay, bx, by):
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    s = 0.0
    if dd > 0.0:
        s = min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / dd))
    ex, ey = ax + s * dx - px, ay + s * dy - py
    return ex * ex + ey * ey


@nb.njit(cache=True, inline="always")
def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@nb.njit(cache=True, inline="always")
def _inside(px, py, x0, y0, x1, y1, x2, y2):
    d0 = _orient(x0, y0, x1, y1, px, py)
    d1 = _orient(x1, y1, x2, y2, px, py)
    d2 = _orient(x2, y2, x0, y0, px, py)
    neg = d0 < 0.0 or d1 < 0.0 or d2 < 0.0
    pos = d0 > 0.0 or d1 > 0.0 or d2 > 0.0
    return not (neg and pos)


@nb.njit(cache=True, inline="always")
def _disk_span(wx, wy, ex, ey, R2):
    """The u in [0, 1] with |w + u e| <= R (an interval; empty when lo > hi)."""
    ee = ex * ex + ey * ey
    ww = wx * wx + wy * wy
    if ee <= 1e-24:
        return (0.0, 1.0) if ww <= R2 else (2.0, -1.0)
    we = wx * ex + wy * ey
    disc = we * we - ee * (ww - R2)
    if disc < 0.0:
        return 2.0, -1.0
    sq = math.sqrt(disc)
    return max(0.0, (-we - sq) / ee), min(1.0, (-we + sq) / ee)


@nb.njit(cache=True, inline="always")
def _lin_span(alpha, beta, lo, hi, u0, u1):
    """Narrow [u0, u1] to the u with lo <= alpha + beta u <= hi."""
    if abs(beta) <= 1e-300:
        return (u0, u1) if lo <= alpha <= hi else (2.0, -1.0)
    a, b = (lo - alpha) / beta, (hi - alpha) / beta
    if a > b:
        a, b = b, a
    return max(u0, a), min(u1, b)


@nb.njit(cache=True)
def _edge_span(px, py, qx, qy, ax, ay, bx, by, R):
    """The part u in [0, 1] of the edge p + u (q - p) within XY distance R of segment ab: the
    union of its spans in the disks around a and b and in the band between them (an
    interval, the capsule being convex; empty when lo > hi)."""
    ex, ey = qx - px, qy - py
    R2 = R * R
    lo, hi = 2.0, -1.0
    s0, s1 = _disk_span(px - ax, py - ay, ex, ey, R2)
    if s0 <= s1:
        lo, hi = min(lo, s0), max(hi, s1)
    s0, s1 = _disk_span(px - bx, py - by, ex, ey, R2)
    if s0 <= s1:
        lo, hi = min(lo, s0), max(hi, s1)
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    if dd > 1e-24:
        wx, wy = px - ax, py - ay
        s0, s1 = _lin_span((wx * dx + wy * dy) / dd, (ex * dx + ey * dy) / dd, 0.0, 1.0, 0.0, 1.0)
        nd = math.sqrt(dd)
        s0, s1 = _lin_span((dx * wy - dy * wx) / nd, (dx * ey - dy * ex) / nd, -R, R, s0, s1)
        if s0 <= s1:
            lo, hi = min(lo, s0), max(hi, s1)
    return lo, hi


@nb.njit(cache=True)
def _reach_span(px, py, ax, ay, dx, dy, dd, R2):
    """The s in [0, 1] at which the point p (within reach of the move, up to rounding) is
    within R of the tip ``a + s d`` in XY: all of them for a move without XY travel, else an
    interval (its nearest s in XY should rounding leave it empty)."""
    if dd <= 1e-24:
        return 0.0, 1.0
    wx, wy = px - ax, py - ay
    wd = wx * dx + wy * dy
    disc = max(0.0, wd * wd - dd * (wx * wx + wy * wy - R2))
    sq = math.sqrt(disc)
    s0, s1 = max(0.0, (wd - sq) / dd), min(1.0, (wd + sq) / dd)
    if s0 > s1:  # at the rim, by rounding: the nearest s
        s0 = s1 = min(1.0, max(0.0, wd / dd))
    return s0, s1


@nb.njit(cache=True, inline="always")
def _need(px, py, pz, ax, ay, az, dx, dy, dz, dd, R2):
    """``p_z - min t_z(s)`` over :func:`_reach_span`: its ends, t_z being linear."""
    s0, s1 = _reach_span(px, py, ax, ay, dx, dy, dd, R2)
    return pz - min(az + s0 * dz, az + s1 * dz)


@nb.njit(cache=True)
def _tri_need(t, V, F, R, ax, ay, az, bx, by, bz):
    """Over the points of triangle t within XY distance R of the move ab: the largest ``p_z``
    less the move's lowest tip (upper bound of its need), and the largest exact need
    (:func:`_need`) at the points where ``p_z`` can be largest: the ends of the edges' spans
    in reach, the capsule's support points in the direction z climbs and the move's ends,
    where inside t (the maximum of a linear function over the convex set t ∩ capsule is at
    one of them; the ends serve a level t that holds the whole reach, with no edge in it)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    dd = dx * dx + dy * dy
    R2 = R * R
    tipmin = min(az, bz)
    hi, lo, hx, hy, hz = -np.inf, -np.inf, 0.0, 0.0, 0.0
    for q in range(3):
        p0, p1 = F[t, q], F[t, (q + 1) % 3]
        px, py, pz = V[p0, 0], V[p0, 1], V[p0, 2]
        ex, ey, ez = V[p1, 0] - px, V[p1, 1] - py, V[p1, 2] - pz
        u0, u1 = _edge_span(px, py, px + ex, py + ey, ax, ay, bx, by, R)
        if u0 > u1:
            continue
        for u in (u0, u1):
            cx, cy, cz = px + u * ex, py + u * ey, pz + u * ez
            if cz - tipmin > hi:
                hi, hx, hy, hz = cz - tipmin, cx, cy, cz
            lo = max(lo, _need(cx, cy, cz, ax, ay, az, dx, dy, dz, dd, R2))
    f0, f1, f2 = F[t, 0], F[t, 1], F[t, 2]
    x0, y0, z0 = V[f0, 0], V[f0, 1], V[f0, 2]
    x1, y1, z1 = V[f1, 0], V[f1, 1], V[f1, 2]
    x2, y2, z2 = V[f2, 0], V[f2, 1], V[f2, 2]
    nx = (y1 - y0) * (z2 - z0) - (z1 - z0) * (y2 - y0)
    ny = (z1 - z0) * (x2 - x0) - (x1 - x0) * (z2 - z0)
    nz = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    g = math.sqrt(nx * nx + ny * ny)
    if nz != 0.0:  # not vertical (its edges hold its top then)
        gx, gy = 0.0, 0.0  # a level triangle: its top is anywhere, the move's ends will do
        if g > 0.0:
            sgn = -1.0 if nz > 0.0 else 1.0
            gx, gy = sgn * nx / g, sgn * ny / g
        zlo, ztop = min(z0, min(z1, z2)), max(z0, max(z1, z2))
        for k in range(4):  # the support points, then the move's ends (a level triangle over
            # the whole reach has no edge in it)
            cx = (ax if k % 2 == 0 else bx) + (R * gx if k < 2 else 0.0)
            cy = (ay if k % 2 == 0 else by) + (R * gy if k < 2 else 0.0)
            if _inside(cx, cy, x0, y0, x1, y1, x2, y2):
                cz = min(ztop, max(zlo, z0 - (nx * (cx - x0) + ny * (cy - y0)) / nz))
                if cz - tipmin > hi:
                    hi, hx, hy, hz = cz - tipmin, cx, cy, cz
                lo = max(lo, _need(cx, cy, cz, ax, ay, az, dx, dy, dz, dd, R2))
    return hi, lo, hx, hy, hz


@nb.njit(cache=True)
def _piece(ax, ay, az, bx, by, bz, V, F, ttop, R, stop, lox, loy, cell, nx, ny, cstart, ctri, ctop, out):
    """Bounds of the need of one straight piece ab: ``out = (lower, upper, x, y, z)``, the
    point being where the upper bound is reached; it returns True as soon as the lower bound
    passes ``stop`` (the bounds are then partial)."""
    tipmin = min(az, bz)
    lo_l, hi_u = out[0], out[1]
    i0 = max(0, int(math.floor((min(ax, bx) - R - lox) / cell)))
    i1 = min(nx - 1, int(math.floor((max(ax, bx) + R - lox) / cell)))
    j0 = max(0, int(math.floor((min(ay, by) - R - loy) / cell)))
    j1 = min(ny - 1, int(math.floor((max(ay, by) + R - loy) / cell)))
    half = 0.7072 * cell  # a cell's half diagonal, rounded up
    for ci in range(i0, i1 + 1):
        for cj in range(j0, j1 + 1):
            c = ci * ny + cj
            if cstart[c] == cstart[c + 1] or ctop[c] - tipmin <= hi_u:
                continue
            mx, my = lox + (ci + 0.5) * cell, loy + (cj + 0.5) * cell
            if _pt_seg_d2(mx, my, ax, ay, bx, by) > (R + half) * (R + half):
                continue
            for k in range(cstart[c], cstart[c + 1]):  # highest triangle first
                t = ctri[k]
                if ttop[t] - tipmin <= hi_u:
                    break
                hi, lo, hx, hy, hz = _tri_need(t, V, F, R, ax, ay, az, bx, by, bz)
                if hi > hi_u:
                    hi_u = hi
                    out[2], out[3], out[4] = hx, hy, hz
                lo_l = max(lo_l, lo)
                if lo_l > stop:
                    out[0], out[1] = lo_l, hi_u
                    return True
    out[0], out[1] = lo_l, hi_u
    return False


@nb.njit(cache=True)
def _one(i, A, B, V, F, ttop, R, dz_max, floor, stop, lox, loy, cell, nx, ny, cstart, ctri, ctop, out):
    """Move i, cut into pieces that climb at most ``dz_max`` where it travels in XY too (the
    upper bound takes a piece's lowest tip: that bounds its excess over the need). Only
    needs above ``floor`` are looked for: ``out[i, :2]`` start there, so a bound left at
    ``floor`` says only that the move's own is at most that. It stops once the lower bound
    passes ``stop``."""
    ax, ay, az = A[i, 0], A[i, 1], A[i, 2]
    dx, dy, dz = B[i, 0] - ax, B[i, 1] - ay, B[i, 2] - az
    m = 1
    if dx * dx + dy * dy > 1e-24 and abs(dz) > dz_max:
        m = int(math.ceil(abs(dz) / dz_max))
    out[i, 0], out[i, 1] = floor, floor
    out[i, 2], out[i, 3], out[i, 4] = np.nan, np.nan, np.nan
    for j in range(m):
        s0, s1 = j / m, (j + 1) / m
        if _piece(ax + s0 * dx, ay + s0 * dy, az + s0 * dz, ax + s1 * dx, ay + s1 * dy, az + s1 * dz, V, F, ttop,
                  R, stop, lox, loy, cell, nx, ny, cstart, ctri, ctop, out[i]):
            return


@nb.njit(cache=True, parallel=True)
def _all(which, A, B, V, F, ttop, R, dz_max, floor, stop, lox, loy, cell, nx, ny, cstart, ctri, ctop, out):
    for j in nb.prange(which.shape[0]):
        _one(which[j], A, B, V, F, ttop, R, dz_max, floor, stop, lox, loy, cell, nx, ny, cstart, ctri, ctop, out)


@nb.njit(cache=True, parallel=True)
def _coarse(A, B, D, Dl, lox, loy, cell, nx, ny, hi, lo):
    """Bounds of each move's need from the rasters, at points every ``cell / 2`` along its
    XY segment: above, the largest ``D`` (triangle tops dilated by the reach,
    :func:`_dilated`) over their cells less the move's lowest tip; below, the largest
    ``Dl`` (vertex tops dilated by less than the reach, so that every vertex counted is in
    reach of the point) less the tip there, at the points inside the raster."""
    for i in nb.prange(A.shape[0]):
        ax, ay, az = A[i, 0], A[i, 1], A[i, 2]
        dx, dy, dz = B[i, 0] - ax, B[i, 1] - ay, B[i, 2] - az
        m = int(math.ceil(math.sqrt(dx * dx + dy * dy) / (0.5 * cell))) + 1
        best, low = -np.inf, 0.0
        for j in range(m):
            s = j / (m - 1) if m > 1 else 0.0
            fi = int(math.floor((ax + s * dx - lox) / cell))
            fj = int(math.floor((ay + s * dy - loy) / cell))
            ci, cj = min(nx - 1, max(0, fi)), min(ny - 1, max(0, fj))
            best = max(best, D[ci, cj])
            if ci == fi and cj == fj:
                low = max(low, Dl[ci, cj] - (az + s * dz))
        hi[i] = max(best - min(az, az + dz), 0.0)
        lo[i] = min(low, hi[i])


@nb.njit(cache=True)
def _vertex_fill(V, lox, loy, cell, nx, ny, top):
    for v in range(V.shape[0]):
        i = min(nx - 1, max(0, int(math.floor((V[v, 0] - lox) / cell))))
        j = min(ny - 1, max(0, int(math.floor((V[v, 1] - loy) / cell))))
        top[i, j] = max(top[i, j], V[v, 2])


@nb.njit(cache=True)
def _raster_fill(V, F, lox, loy, cell, nx, ny, top):
    for t in range(F.shape[0]):
        x0, x1, y0, y1, zt = np.inf, -np.inf, np.inf, -np.inf, -np.inf
        for q in range(3):
            v = F[t, q]
            x0, x1 = min(x0, V[v, 0]), max(x1, V[v, 0])
            y0, y1 = min(y0, V[v, 1]), max(y1, V[v, 1])
            zt = max(zt, V[v, 2])
        i0 = min(nx - 1, max(0, int(math.floor((x0 - lox) / cell))))
        i1 = min(nx - 1, max(0, int(math.floor((x1 - lox) / cell))))
        j0 = min(ny - 1, max(0, int(math.floor((y0 - loy) / cell))))
        j1 = min(ny - 1, max(0, int(math.floor((y1 - loy) / cell))))
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                top[i, j] = max(top[i, j], zt)


def _raster_tops(V, F, lo, n, cell):
    """Highest triangle top over each cell (every cell a triangle's XY box overlaps)."""
    top = np.full((int(n[0]), int(n[1])), -np.inf)
    _raster_fill(V, F, float(lo[0]), float(lo[1]), float(cell), int(n[0]), int(n[1]), top)
    return top


def _dilated(top, reach_cells: float):
    """``D[c] = max top[c']`` over the cells ``c'`` whose centre lies within ``reach_cells``
    cells of ``c``'s: a disk's maximum filter as one 1D filter along X per row offset (one
    filtered copy at a time: the row offsets ``+-dy`` share it)."""
    from scipy.ndimage import maximum_filter1d

    D = top.copy()
    K = int(math.floor(reach_cells))
    for dy in range(K + 1):
        w = int(math.floor(math.sqrt(max(reach_cells * reach_cells - dy * dy, 0.0))))
        M = maximum_filter1d(top, size=2 * w + 1, axis=0, mode="constant", cval=-np.inf)
        if dy == 0:
            np.maximum(D, M, out=D)
        elif dy < top.shape[1]:
            np.maximum(D[:, :-dy], M[:, dy:], out=D[:, :-dy])
            np.maximum(D[:, dy:], M[:, :-dy], out=D[:, dy:])
    return D


def _grid(V, F, cell):
    """Triangles by XY cell (every cell their XY box overlaps), highest top first in a cell."""
    lo = V[:, :2].min(axis=0)
    n = np.maximum(1, np.ceil((V[:, :2].max(axis=0) - lo) / cell).astype(np.int64) + 1)
    T = V[F]
    ttop = T[:, :, 2].max(axis=1)
    c0 = np.floor((T[:, :, :2].min(axis=1) - lo) / cell).astype(np.int64)
    c1 = np.floor((T[:, :, :2].max(axis=1) - lo) / cell).astype(np.int64)
    wx, wy = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
    cnt = wx * wy
    tri = np.repeat(np.arange(len(F)), cnt)
    k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    cx = c0[tri, 0] + k // wy[tri]
    cy = c0[tri, 1] + k % wy[tri]
    key = cx * n[1] + cy
    order = np.lexsort((-ttop[tri], key))
    key, tri = key[order], tri[order]
    cstart = np.zeros(n[0] * n[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(key, minlength=n[0] * n[1]), out=cstart[1:])
    ctop = np.full(n[0] * n[1], -np.inf)
    ctop[key[::-1]] = ttop[tri[::-1]]  # the first (highest) of each cell wins
    return lo, n, ttop, cstart, tri, ctop


@dataclass(frozen=True, eq=False)
class HolderCheck:
    """Stick-out a program needs for a holder of radius ``radius``, per move and in all.

    Attributes
    ----------
    radius : float
        Holder radius R, mm (at its face).
    steps : tuple of (float, float)
        The wider rings above the face, ``(R_k, h_k)`` (:func:`holder_clearance`).
    lower, upper : (k,) float64
        Per move of the program, bounds of the stick-out it needs (mm; module docstring).
        ``upper`` always bounds the move's need from above (0: the part is nowhere above the
        tip within R); ``lower`` from below, 0 where the move was not resolved (its upper
        bound below the program's largest need and below the stick-out checked).
    line : (k,) int64
        Each move's line in the program's source.
    needed : float
        ``upper.max()``: a stick-out at least this long clears the part on every move.
    needed_lower : float
        ``lower.max()``: a stick-out shorter than this hits the part.
    worst_move : int
        The move with the largest ``upper`` (-1 for an empty program).
    worst_line : int or None
        Its line in the program's source.
    worst_tip : tuple of float or None
        The lowest tip of that move from which ``worst_part`` is within R (x, y, z); the
        move's lower end when there is no such point.
    worst_part : tuple of float or None
        The point of the part where that move's upper bound is reached (x, y, z): an end of
        a triangle edge's span in reach, a support point of the reach or a move's end under
        a triangle; None when the part is nowhere above the tip within R.
    worst_ring : tuple of float or None
        ``(R_k, h_k)`` of the cylinder that sets the need there (``(radius, 0)`` for the
        holder's face): the point is within ``R_k`` of ``worst_tip`` and ``needed + h_k``
        above it, up to the climb.
    """

    radius: float
    steps: tuple
    lower: np.ndarray
    upper: np.ndarray
    line: np.ndarray
    needed: float
    needed_lower: float
    worst_move: int
    worst_line: int | None
    worst_tip: tuple | None
    worst_part: tuple | None
    worst_ring: tuple | None = None

    def hits(self, stick_out: float) -> dict:
        """What a stick-out of ``stick_out`` mm gives: clearance and the moves that may hit.

        ``clear`` holds for any ``stick_out``; the counts and the first line are resolved for
        the stick-out the check was run with (:func:`holder_clearance`), and for others are
        bounds (a move that may hit counted for a raster bound only).

        Returns
        -------
        dict
            ``stick_out``, ``clearance`` (``stick_out - needed``: negative when the holder may
            meet the part), ``moves_may_hit`` (moves whose ``upper`` exceeds it),
            ``moves_hit`` (moves whose ``lower`` exceeds it: certain), ``first_line`` (the
            source line of the first move that may hit, or None), ``clear`` (bool).
        """
        may = np.flatnonzero(self.upper > stick_out)
        return {"stick_out": float(stick_out), "clearance": float(stick_out - self.needed),
                "moves_may_hit": int(len(may)), "moves_hit": int((self.lower > stick_out).sum()),
                "first_line": int(self.line[may[0]]) if len(may) else None, "clear": bool(len(may) == 0)}

    def summary(self, stick_out: float | None = None) -> dict:
        """The figures for a JSON report (``hits(stick_out)`` merged in when given)."""
        out = {"radius": self.radius, "steps": [list(x) for x in self.steps], "needed_stick_out": self.needed,
               "needed_lower": self.needed_lower,
               "worst_line": self.worst_line, "worst_tip": self.worst_tip, "worst_part": self.worst_part,
               "worst_ring": None if self.worst_ring is None else list(self.worst_ring)}
        if stick_out is not None:
            out.update(self.hits(stick_out))
        return out


def _lowest_tip(a, b, p, R: float) -> np.ndarray:
    """The lowest tip of the move ab from which the part point p is within R in XY (an end of
    :func:`_reach_span`, t_z being linear)."""
    d = b - a
    s0, s1 = _reach_span(float(p[0]), float(p[1]), float(a[0]), float(a[1]), float(d[0]), float(d[1]),
                         float(d[0] * d[0] + d[1] * d[1]), float(R * R))
    t0, t1 = a + s0 * d, a + s1 * d
    return t0 if t0[2] <= t1[2] else t1


def check_holder(radius, stick_out=None) -> None:
    """Refuse a holder radius or stick-out that is not a positive finite number (bad input:
    exit code 2)."""
    for name, v in (("holder radius", radius), ("stick-out", stick_out)):
        if v is None:
            continue
        if not _positive_mm(v):
            raise ConformillError(f"the {name} must be a positive number of mm, got {v!r}")


def check_holder_fits(radius, tool_radius) -> None:
    """Refuse a holder not wider than the tool: two well-formed values that cannot be
    checked together (:class:`PlanningError`, exit code 3, as a blend above the tool
    radius; the command lines ask it after their checks of single values, which exit 2).
    A holder step no wider than the part below it is a holder described wrongly, and
    :func:`check_steps` refuses it with exit code 2."""
    if radius is not None and tool_radius is not None and radius <= tool_radius:
        raise PlanningError(f"the holder radius ({radius:g} mm) must be larger than the tool radius "
                            f"({tool_radius:g} mm): up to the holder the tool is the ball and its shank of the "
                            f"ball's radius, which this check does not model")


def _ring(V, F, A, B, radius: float, stick_out, climb: float, cell):
    """``(lower, upper, at)`` of one cylinder of radius ``radius`` whose face is at the tip
    (:func:`holder_clearance`, which offsets the rings of a stepped holder)."""
    k = len(A)
    R = float(radius)
    lower, upper, at = np.zeros(k), np.zeros(k), np.full((k, 3), np.nan)
    capped = np.zeros(k, dtype=bool)  # upper is only the floor the move was checked above
    if k and len(F):
        lo = V[:, :2].min(axis=0)
        span = V[:, :2].max(axis=0) - lo
        # 1. every move: a bound from the part's tops on a raster, dilated by the reach
        fine = max(R / 16.0, float(span.max()) / 1000.0, 1e-6)
        n = np.maximum(1, np.ceil(span / fine).astype(np.int64) + 1)
        D = _dilated(_raster_tops(V, F, lo, n, fine), R / fine + 1.7)
        Dl = np.full((int(n[0]), int(n[1])), -np.inf)
        if R / fine > math.sqrt(2.0):  # cells wholly within R of every point of a cell
            _vertex_fill(V, float(lo[0]), float(lo[1]), fine, int(n[0]), int(n[1]), Dl)
            Dl = _dilated(Dl, R / fine - math.sqrt(2.0))
        _coarse(A, B, D, Dl, float(lo[0]), float(lo[1]), fine, int(n[0]), int(n[1]), upper, lower)
        # 2. the moves that can hold the largest need, highest bound first, exactly
        if cell is None:
            edge = float(np.linalg.norm(V[F[:, 1], :2] - V[F[:, 0], :2], axis=1).mean())
            cell = max(R / 4.0, 2.0 * edge, float(span.max()) / 500.0, 1e-6)
        g0, gn, ttop, cstart, ctri, ctop = _grid(V, F, cell)
        grid = (float(g0[0]), float(g0[1]), float(cell), int(gn[0]), int(gn[1]), cstart, ctri, ctop)

        out = np.zeros((k, 5))  # rows of the moves checked, each written whole by _one

        def exact(which, floor, dz_max, stop=np.inf):
            if not len(which):
                return
            _all(which, A, B, V, F, ttop, R, dz_max, floor, stop, *grid, out)
            o = out[which]
            done = o[:, 0] <= stop  # not stopped early: the upper bound holds
            stopped = which[~done]
            which, o = which[done], o[done]
            # a bound reached at a point of the part (not left at the floor) names where
            better = (o[:, 1] <= upper[which]) & np.isfinite(o[:, 2])
            upper[which] = np.minimum(upper[which], o[:, 1])
            capped[which] = np.isnan(o[:, 2])
            at[which[better]] = o[better, 2:]
            lower[which] = np.where(o[:, 0] > floor, np.maximum(lower[which], o[:, 0]), lower[which])
            lower[stopped] = np.maximum(lower[stopped], out[stopped, 0])

        order = np.argsort(-upper, kind="stable")
        pos, size = 0, 64
        while pos < k and upper[order[pos]] > lower.max():
            floor = float(lower.max())
            chunk = order[pos:pos + size]
            exact(chunk[upper[chunk] > floor], floor, np.inf)
            pos, size = pos + size, min(4 * size, 16384)
        # 3. those whose bound still exceeds the largest need found, in pieces of small climb
        # (from just below it: a move that needs exactly that much is found, with its point)
        floor = float(lower.max())
        floor = max(floor - 1e-9 * max(1.0, floor), 0.0)  # no need is below 0
        exact(np.flatnonzero((upper > floor) & ~capped), floor, float(climb))
        # 4. the moves a given stick-out may not clear, resolved against it: whole moves
        # first, stopping at the first part point that certainly hits, then in pieces
        if stick_out is not None:
            L = float(stick_out)
            exact(np.flatnonzero((upper > L) & (lower <= L)), L, np.inf, stop=L)
            exact(np.flatnonzero((upper > L) & (lower <= L)), L, float(climb), stop=L)
    return lower, upper, at


def _positive_mm(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v) and v > 0


def check_steps(steps, radius=None) -> list:
    """The steps of a stepped holder as ``[(R_k, h_k), ...]``; refuses (bad input: exit code
    2) a step that is not a radius and a height, both positive numbers, two steps at one
    height, or a step no wider than the holder below it (``radius`` its face's; such a step
    could never touch the part first)."""
    out = []
    for st in steps:
        try:
            r, at = st
        except (TypeError, ValueError):
            raise ConformillError(f"a holder step is a radius and a height above the holder's face, got {st!r}") \
                from None
        for name, v in (("radius", r), ("height", at)):
            if not _positive_mm(v):
                raise ConformillError(f"a holder step's {name} must be a positive number of mm, got {v!r}")
        out.append((float(r), float(at)))
    heights = [at for _, at in out]
    if len(set(heights)) < len(heights):
        raise ConformillError(f"two holder steps at one height above the face: {sorted(heights)}")
    if radius is not None:
        wide = float(radius)
        for r, at in sorted(out, key=lambda x: x[1]):
            if r <= wide:
                raise ConformillError(f"the holder step of radius {r:g} mm at {at:g} mm above the face is no wider "
                                      f"than the holder below it ({wide:g} mm): it could never meet the part first")
            wide = r
    return out


def holder_clearance(V, F, program: Program, radius: float, stick_out: float | None = None, climb: float = 0.01,
                     cell: float | None = None, steps=()) -> HolderCheck:
    """Bounds of the stick-out each move of ``program`` needs for a holder of radius ``radius``.

    A stepped holder (a collet nut, then a wider body) adds ``steps``: rings of radius
    ``R_k`` whose lower face is ``h_k`` above the holder's face, each reaching up without
    end, each wider than the one below it. A ring needs ``L + h_k`` of what a cylinder of
    its radius needs, so the program needs ``max_k (need_k - h_k)``.

    Parameters
    ----------
    V : (n, 3) float64
        Part vertices, mm (program coordinates; +Z is the tool axis).
    F : (m, 3) int64
        Triangles.
    program : Program
        The program as read (:func:`conformill.verify.gcode.read_gcode`); every move counts.
    radius : float
        Holder radius R, mm.
    stick_out : float, optional
        The stick-out to be judged (:meth:`HolderCheck.hits`): the moves whose bounds
        straddle it are resolved to ``climb`` too.
    climb : float
        Moves that travel in XY and climb more than this (mm) are checked again in pieces
        that climb at most this much, where they matter (their upper bound above the
        largest lower bound, or their bounds straddling ``stick_out``): then ``needed``
        exceeds the need by at most this, plus the rounding of the arithmetic.
    cell : float, optional
        XY grid cell of the exact pass's triangle index (default ``max(R / 4, 2 x the mean
        edge, 1/500 of the part's XY extent)``).
    steps : sequence of (float, float)
        ``(R_k, h_k)``: the wider rings above the face, ``h_k > 0`` mm above it.

    Returns
    -------
    HolderCheck

    Raises
    ------
    ConformillError
        When ``radius``, ``stick_out``, a step's radius or height is not a positive number.
    """
    check_holder(radius, stick_out)
    rings = ((float(radius), 0.0),) + tuple(check_steps(steps, radius))
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    A, B = program.segments(None)
    A, B = np.ascontiguousarray(A), np.ascontiguousarray(B)
    k = len(A)
    lower, upper, at = np.zeros(k), np.zeros(k), np.full((k, 3), np.nan)
    which_ring = np.zeros(k, dtype=np.int64)
    for j, (Rj, hj) in enumerate(rings):
        lo_j, up_j, at_j = _ring(V, F, A, B, Rj, None if stick_out is None else stick_out + hj, climb, cell)
        up_j, lo_j = up_j - hj, lo_j - hj
        if j == 0:
            lower, upper, at = lo_j, up_j, at_j
            continue
        more = up_j > upper
        upper = np.where(more, up_j, upper)
        at[more] = at_j[more]
        which_ring[more] = j
        lower = np.maximum(lower, lo_j)
    upper, lower = np.maximum(upper, 0.0), np.maximum(lower, 0.0)
    worst, line, tip, part, ring = -1, None, None, None, None
    if k:
        worst = int(np.lexsort((-lower, -upper))[0])  # the largest bound; of equal ones, the surest
        line = int(program.line[worst])
        a, b = A[worst], B[worst]
        t = a if a[2] <= b[2] else b
        if np.isfinite(at[worst, 0]) and upper[worst] > 0:
            part = tuple(float(x) for x in at[worst])
            t = _lowest_tip(a, b, at[worst], rings[which_ring[worst]][0])
            ring = rings[which_ring[worst]]
        tip = tuple(float(x) for x in t)
    return HolderCheck(radius=float(radius), steps=rings[1:], lower=lower, upper=upper, line=np.asarray(program.line),
                       needed=float(upper.max()) if k else 0.0, needed_lower=float(lower.max()) if k else 0.0,
                       worst_move=worst, worst_line=line, worst_tip=tip, worst_part=part, worst_ring=ring)
