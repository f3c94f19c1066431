"""Where the pattern's passes left material: the planner's own estimate (issue 5, session 31).

A ball of radius ``r`` whose centre moves along a straight segment sweeps the capsule of
radius ``r`` around it, and the program's passes sweep the union of their moves'
capsules. At a point ``q`` of the part, the material the passes leave, measured along any
direction, is at least ``dist(q, centre moves) - r``: ``q`` lies that far outside the swept
volume. :func:`uncut_beyond` answers, for many points at once, whether that lower bound
exceeds a depth, that is whether no centre move comes within ``r + depth`` of the point.

The pencil stage (``Job.pencil_left``, ``--pencil-left``) asks it at the shadow of each
fold point (:mod:`conformill.folds`): where the pattern already cut the shadow down to
``depth``, the wedged ball's pass would add little. ``verify`` casts a ray from each sample
into the swept volume instead, independent of the planner by design; on igea (zigzag, r =
4, h = 0.01, fold points at 30 per mm^2) this bound and verify's cast towards the wedged
centre agreed to a median ratio of 0.999 (5-95 %: 0.966-1.018), and at a depth of 0.5 h
they disagreed on 113 of 28.6k points (session 30, docs/issue5.md "What stands in the way").

The moves are binned on an XY grid of 0.5 mm cells, each move in the cells it passes over
(walked in pieces a cell long), and each cell keeps its moves' range of centre heights. A
point visits the cells within ``r + depth`` in XY, skips those whose box (XY and heights)
lies farther than that, and stops at the first move within reach: the centres ride about
``r`` above the part, so on gentle ground only the cells within about ``sqrt(2 r depth)``
of the point are read. On igea (zigzag, 460k moves, 176k probes of 58.8k fold points) the
test takes about 0.3 s on two cores.

A point reads first the 3 x 3 cells around a hint, where a move within reach most likely
passes, then the rest of its window (the same answer in any order). Most points are reached,
so a good hint ends most searches in a few cells: at the tangent ball's centre (the fill's
samples, :mod:`conformill.fill`) the 300k samples of igea's fill took 0.07 s instead of
0.31 s (session 54); at the wedged ball's centre (the pencil's probes) a little less than
at the points themselves, the default.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from conformill.geometry.closest import segment_d2

__all__ = ["MoveGrid", "UncutRows", "centre_moves", "move_grid", "uncut_beyond"]

#: Side of the moves' grid cells (mm), and about the most cells (the cells grow to fit).
_CELL = 0.5
_MAX_CELLS = 4_000_000


def centre_moves(passes, radius: float):
    """The straight centre moves ``(A, B)``, each ``(m, 3)``, of tip ``passes`` (a list of
    ``(k, 3)`` arrays) of a ball of ``radius``: the centre is the tip lifted by ``radius``.
    Moves within a pass only (links between passes are retracts or hops above the part)."""
    A = [p[:-1] for p in passes if len(p) >= 2]
    B = [p[1:] for p in passes if len(p) >= 2]
    if not A:
        return np.zeros((0, 3)), np.zeros((0, 3))
    lift = np.array([0.0, 0.0, float(radius)])
    return np.ascontiguousarray(np.vstack(A) + lift), np.ascontiguousarray(np.vstack(B) + lift)


@njit(cache=True, nogil=True)
def _bin(A, B, x0, y0, cell, ncx, ncy):
    """CSR lists (``start``, ``item``) of the moves that pass over each cell, and each
    cell's lowest and highest centre height over those moves. A move is walked in pieces at
    most a cell long in XY; each piece is entered in the cells its XY box meets (a move
    once per cell), with the piece's heights: the point of a move nearest any other lies in
    a piece, over a cell the move is entered in, within that cell's height range."""
    m = A.shape[0]
    nc = ncx * ncy
    start = np.zeros(nc + 1, dtype=np.int64)
    zlo = np.full(nc, np.inf)
    zhi = np.full(nc, -np.inf)
    last = np.full(nc, -1, dtype=np.int64)
    fill = np.zeros(0, dtype=np.int64)
    item = np.zeros(0, dtype=np.int32)
    for walk in range(2):  # 0: count, 1: fill
        if walk == 1:
            for c in range(nc):
                start[c + 1] += start[c]
            item = np.empty(start[nc], dtype=np.int32)
            fill = start[:-1].copy()
            last[:] = -1
        for k in range(m):
            ax, ay, az = A[k, 0], A[k, 1], A[k, 2]
            vx, vy, vz = B[k, 0] - ax, B[k, 1] - ay, B[k, 2] - az
            n = max(int(math.ceil(math.sqrt(vx * vx + vy * vy) / cell)), 1)
            for s in range(n):
                t0, t1 = s / n, (s + 1) / n
                px, py, pz = ax + t0 * vx, ay + t0 * vy, az + t0 * vz
                qx, qy, qz = ax + t1 * vx, ay + t1 * vy, az + t1 * vz
                i0 = min(max(int(math.floor((min(px, qx) - x0) / cell)), 0), ncx - 1)
                i1 = min(max(int(math.floor((max(px, qx) - x0) / cell)), 0), ncx - 1)
                j0 = min(max(int(math.floor((min(py, qy) - y0) / cell)), 0), ncy - 1)
                j1 = min(max(int(math.floor((max(py, qy) - y0) / cell)), 0), ncy - 1)
                lo, hi = min(pz, qz), max(pz, qz)
                for j in range(j0, j1 + 1):
                    for i in range(i0, i1 + 1):
                        c = j * ncx + i
                        if walk == 0:
                            zlo[c] = min(zlo[c], lo)
                            zhi[c] = max(zhi[c], hi)
                        if last[c] != k:
                            last[c] = k
                            if walk == 0:
                                start[c + 1] += 1
                            else:
                                item[fill[c]] = k
                                fill[c] += 1
    return start, item, zlo, zhi


@njit(cache=True, nogil=True, inline="always")
def _cell_reaches(c, qx, qy, qz, dy, x0, cell, ncx, reach2, A, B, start, item, zlo, zhi):
    """Whether a move entered in cell ``c`` comes within ``sqrt(reach2)`` of ``q`` (``dy``:
    the cell's row's distance from ``q`` in Y); the cell is skipped when its box (XY, and
    its moves' height range) lies farther than that."""
    if start[c + 1] == start[c]:
        return False
    cx0 = x0 + (c % ncx) * cell
    dx = max(cx0 - qx, qx - cx0 - cell, 0.0)
    dz = max(zlo[c] - qz, qz - zhi[c], 0.0)
    if dx * dx + dy * dy + dz * dz > reach2:
        return False
    for e in range(start[c], start[c + 1]):
        k = item[e]
        if segment_d2(qx, qy, qz, A[k, 0], A[k, 1], A[k, 2], B[k, 0], B[k, 1], B[k, 2]) <= reach2:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _reached(qx, qy, qz, hx, hy, A, B, reach, x0, y0, cell, ncx, ncy, start, item, zlo, zhi):
    """Whether a move comes within ``reach`` of ``q``. The cells within ``reach`` in XY are
    visited (:func:`_cell_reaches`), first the 3 x 3 around the hint ``(hx, hy)``, where a
    move within reach most likely passes, then the others: the same answer in any order,
    found sooner when the hint is good (session 54: the fill's samples with their tangent
    balls' XY as hints, 4x quicker on igea)."""
    reach2 = reach * reach
    i0 = max(int(math.floor((qx - reach - x0) / cell)), 0)
    i1 = min(int(math.floor((qx + reach - x0) / cell)), ncx - 1)
    j0 = max(int(math.floor((qy - reach - y0) / cell)), 0)
    j1 = min(int(math.floor((qy + reach - y0) / cell)), ncy - 1)
    hi = int(math.floor((hx - x0) / cell)) if hx == hx else -2  # a NaN hint: no cell first
    hj = int(math.floor((hy - y0) / cell)) if hy == hy else -2
    for j in range(max(j0, hj - 1), min(j1, hj + 1) + 1):
        cy0 = y0 + j * cell
        dy = max(cy0 - qy, qy - cy0 - cell, 0.0)
        for i in range(max(i0, hi - 1), min(i1, hi + 1) + 1):
            if _cell_reaches(j * ncx + i, qx, qy, qz, dy, x0, cell, ncx, reach2, A, B, start, item, zlo, zhi):
                return True
    for j in range(j0, j1 + 1):
        cy0 = y0 + j * cell
        dy = max(cy0 - qy, qy - cy0 - cell, 0.0)
        near = abs(j - hj) <= 1
        for i in range(i0, i1 + 1):
            if near and abs(i - hi) <= 1:
                continue  # visited first
            if _cell_reaches(j * ncx + i, qx, qy, qz, dy, x0, cell, ncx, reach2, A, B, start, item, zlo, zhi):
                return True
    return False


@njit(cache=True, nogil=True, parallel=True)
def _first_beyond(Q, H, first, reach, A, B, x0, y0, cell, ncx, ncy, start, item, zlo, zhi,
                  A0, B0, x00, y00, cell0, ncx0, ncy0, start0, item0, zlo0, zhi0):
    """For each row of ``Q (n, p, 3)``: the first point beyond ``reach`` of every move, of
    the new ones (``A, B`` and their grid) and of those handed over before (``A0, B0``
    and theirs), or ``p`` when there is none (a point with a NaN counts as beyond). The
    row's points before ``first[q]`` are known reached, and the point ``first[q]`` (when
    below ``p``) known beyond the earlier moves, so it is tested against the new ones
    only; the row's points after the first beyond are not read, nor a point equal to the
    one before it. ``H (n, p, 2)``: each point's hint (:func:`_reached`)."""
    n, p = Q.shape[0], Q.shape[1]
    out = np.empty(n, dtype=np.int64)
    for q in prange(n):
        out[q] = p
        for s in range(first[q], p):
            qx, qy, qz = Q[q, s, 0], Q[q, s, 1], Q[q, s, 2]
            if not (qx == qx and qy == qy and qz == qz):
                out[q] = s
                break
            if s > 0 and qx == Q[q, s - 1, 0] and qy == Q[q, s - 1, 1] and qz == Q[q, s - 1, 2]:
                continue  # the point before, reached (a steep centre's sample fills every slot)
            hx, hy = H[q, s, 0], H[q, s, 1]
            if _reached(qx, qy, qz, hx, hy, A, B, reach, x0, y0, cell, ncx, ncy, start, item, zlo, zhi):
                continue
            if s > first[q] and _reached(qx, qy, qz, hx, hy, A0, B0, reach, x00, y00, cell0, ncx0, ncy0, start0,
                                         item0, zlo0, zhi0):
                continue
            out[q] = s
            break
    return out


class MoveGrid:
    """Centre moves ``A -> B`` binned on an XY grid (:func:`_bin`), as the kernels take them
    (``args``): made once by :func:`move_grid` and handed to every :class:`UncutRows` that
    tests points against those moves (the pencil's filter and the fill read the same
    pattern passes)."""

    def __init__(self, A, B):
        self.A, self.B = A, B
        if len(A) == 0:  # one empty cell
            self.args = (A, B, 0.0, 0.0, _CELL, 1, 1, np.zeros(2, dtype=np.int64), np.zeros(0, dtype=np.int32),
                         np.full(1, np.inf), np.full(1, -np.inf))
            return
        lo = np.minimum(A[:, :2].min(axis=0), B[:, :2].min(axis=0))
        hi = np.maximum(A[:, :2].max(axis=0), B[:, :2].max(axis=0))
        cell = max(_CELL, math.sqrt(float(np.prod(hi - lo + _CELL)) / _MAX_CELLS))
        ncx, ncy = (int(v) for v in np.floor((hi - lo) / cell) + 1)
        start, item, zlo, zhi = _bin(A, B, float(lo[0]), float(lo[1]), cell, ncx, ncy)
        self.args = (A, B, float(lo[0]), float(lo[1]), cell, ncx, ncy, start, item, zlo, zhi)


def move_grid(A, B) -> MoveGrid:
    """The centre moves ``A -> B`` (``(m, 3)`` each, :func:`centre_moves`) binned for
    :meth:`UncutRows.add_grid`.

    Raises
    ------
    ValueError
        As many starts as ends are not given, or an end is not finite.
    """
    return MoveGrid(*_moves(A, B))


def _moves(A, B):
    A = np.ascontiguousarray(A, dtype=np.float64).reshape(-1, 3)
    B = np.ascontiguousarray(B, dtype=np.float64).reshape(-1, 3)
    if len(A) != len(B):
        raise ValueError(f"as many move starts as ends are needed, got {len(A)} and {len(B)}")
    for name, X in (("A", A), ("B", B)):
        if not np.isfinite(X).all():
            bad = np.flatnonzero(~np.isfinite(X).all(axis=1))
            raise ValueError(f"move ends {name} must be finite; not at rows {bad[:5].tolist()}")
    return A, B


_EMPTY = MoveGrid(np.zeros((0, 3)), np.zeros((0, 3)))


class UncutRows:
    """:func:`uncut_beyond` for moves handed over in parts: the answer once every part is
    in is the same as one call on all the moves.

    The pipeline hands over the passes cut so far while the cutter works on the rest, and
    the rest once it is done: only the rows whose first unreached point is still unreached
    are then read again, against the new moves.

    Parameters
    ----------
    points : (n, 3) or (n, p, 3) float
        As for :func:`uncut_beyond`.
    radius, depth : float
        As for :func:`uncut_beyond`.
    hints : (n, 2) or (n, p, 2) float, optional
        As for :func:`uncut_beyond`.
    """

    def __init__(self, points, radius: float, depth: float, hints=None):
        Q = np.asarray(points, dtype=np.float64)
        self._Q = np.ascontiguousarray(Q.reshape(-1, 1, 3) if Q.ndim < 3 else Q)
        self._reach = float(radius) + float(depth)
        if not (np.isfinite(self._reach) and radius > 0 and depth >= 0):
            raise ValueError(f"radius must be finite and positive and depth finite and >= 0, got {radius}, {depth}")
        self._H = _hints(self._Q, hints)
        self._first = np.zeros(len(self._Q), dtype=np.int64)
        self._parts = []  # the moves handed over, (A, B) per part
        self._before = None  # a MoveGrid of all of them

    def add(self, A, B) -> None:
        """Hand over more centre moves (``(m, 3)`` each, :func:`centre_moves`)."""
        A, B = _moves(A, B)
        if len(A) == 0 or len(self._Q) == 0:
            return
        self.add_grid(MoveGrid(A, B))

    def add_grid(self, grid: MoveGrid) -> None:
        """Hand over more centre moves already binned (:func:`move_grid`; the same answers
        as :meth:`add` with its moves)."""
        if len(grid.A) == 0 or len(self._Q) == 0:
            return
        if self._Q.shape[1] == 1:  # one point a row: a point beyond the moves so far is tested on the new ones only
            before = _EMPTY.args
        else:
            if self._before is None:  # the moves so far as one grid (none: an empty one)
                self._before = _EMPTY if not self._parts else \
                    MoveGrid(np.vstack([a for a, _ in self._parts]), np.vstack([b for _, b in self._parts]))
            before = self._before.args
        self._first = _first_beyond(self._Q, self._H, self._first, self._reach, *grid.args, *before)
        self._parts.append((grid.A, grid.B))
        self._before = grid if len(self._parts) == 1 else None  # built again by the next add, if any

    def uncut(self) -> np.ndarray:
        """``(n,)`` bool: the rows with a point beyond ``radius + depth`` of every move so far."""
        return self._first < self._Q.shape[1]


def _hints(Q, hints) -> np.ndarray:
    """``(n, p, 2)`` hints for the rows ``Q (n, p, 3)``: ``hints`` per row (``(n, 2)``) or per
    point (``(n, p, 2)``), or the points' own XY."""
    if hints is None:
        return np.ascontiguousarray(Q[:, :, :2])
    H = np.asarray(hints, dtype=np.float64)
    n, p = Q.shape[:2]
    if H.shape == (n, 2):
        H = np.broadcast_to(H[:, None, :], (n, p, 2))
    if H.shape != (n, p, 2):
        raise ValueError(f"hints must be ({n}, 2) or ({n}, {p}, 2) for these points, got {H.shape}")
    # writable too: a broadcast row (p = 1) is contiguous but read-only, and the kernel
    # would be compiled and loaded a second time for it
    return np.require(H, requirements=["C", "W"])


def uncut_beyond(points, A, B, radius: float, depth: float, hints=None) -> np.ndarray:
    """Whether the ball moves ``A -> B`` (centres, :func:`centre_moves`) leave more than
    ``depth`` at each of ``points`` by the distance bound: no move's centre segment comes
    within ``radius + depth`` of the point.

    Parameters
    ----------
    points : (n, 3) or (n, p, 3) float
        Points of the part (a point with a NaN is reported as uncut); with ``p`` points per
        row, whether any point of the row is uncut.
    A, B : (m, 3) float
        Start and end of each centre move.
    radius : float
        The ball's radius (mm).
    depth : float
        Material depth (mm, >= 0).
    hints : (n, 2) or (n, p, 2) float, optional
        Where in XY a centre move within reach of each row (or point) most likely passes:
        those cells are read first (the same answer, found sooner; NaN: no hint). The
        tangent ball's centre at a surface point is a good hint. Default: the points' own XY.

    Returns
    -------
    (n,) bool
    """
    rows = UncutRows(points, radius, depth, hints)
    rows.add(A, B)
    return rows.uncut()
