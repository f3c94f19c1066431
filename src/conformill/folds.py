"""Folds of the drop surface: where the ball sits wedged, found on an XY grid.

The drop surface ``D(x, y)`` of a ball of radius ``r`` (the lowest centre height at which
the ball touches the part, :class:`conformill.cutter.BallCutter`) is the upper envelope of
one smooth function per triangle (the ball resting on its facet, an edge or a vertex).
Each such function is concave (a plane, or the top of a cylinder or sphere of radius
``r``), so where the envelope switches from one triangle to another without a common
edge or vertex, ``D`` has a *fold*: a valley whose centres touch the part at two places,
the ball wedged between them. The part between the two contacts (the fold's *shadow*) is
below the ball and no ball touches it: this is where a pattern leaves rest material on a
scan's facet creases and pits, and where pencil passes go (:mod:`conformill.pencil`).

The search visits the folds, not the surface:

1. ``D`` is dropped on an XY grid of spacing ``s`` over the part, with the contact point
   of each drop (the point of its triangle nearest the centre).
2. On a grid edge whose two contacts lie more than ``jump`` apart, the contact jumps
   somewhere between the ends (on smooth ground it moves about ``s``): a fold crosses it.
3. The crossing is found on a two-sided model: ``max`` over the triangles of side A (the
   contacts nearer A's) against ``max`` over side B, starting from the two end
   triangles. The model is a lower bound of ``D``, so where one true drop at the model's
   crossing (with the model's height as floor) finds a triangle rising above it, that
   triangle joins the side of the nearer contact and the crossing is found again; when
   none rises, the crossing is on ``D`` and exact (to ``1e-3 s``). 1.1-1.9 true drops per
   edge on the scans (1.4 on igea; session 23).
4. The shadow's depth: the largest vertical gap between the ball's underside and the
   part at seven points evenly spaced along the XY segment between the two contacts (the
   part's top there: the highest triangle over the point).

A V-shaped crease of two planes whose contacts lie ``J`` apart leaves ``r (1 / cos(a) -
1)`` at its bottom, ``sin(a) = J / 2r``: ``jump`` is set from the shallowest shadow that
matters (:func:`wedge_jump`); the pencil raises it by up to half a spacing, to 1.6 ``s``
at most, the contact's own motion on smooth concave ground
(:func:`conformill.pencil.fold_jump`). A fold narrower than that between contacts but
deeper (a pit narrower than about 0.3 mm at r = 4, h = 0.01, 30 points per mm^2) is still
found when its grid edge's ends touch beyond it, which is the usual case: their contacts
lie about the pit's width plus ``s`` apart.

On igea (155k faces, r = 4 mm, 0.18 mm grid) the search takes about 1.3 s on two cores
(2.4 s of CPU: grid 0.5 s, crossings 0.6 s, shadows 0.2 s of wall), 0.31 of the CPU of
the per-sample search of :func:`conformill.pencil.best_centres` on the same host, and 93 %
of that search's band centres lie within 0.1 mm of a fold point whose shadow is deeper
than 0.15 h (``benchmarks/bench_pencil.py --folds``; docs/issue5.md, "Pencil passes", session 23).
Where the part is steeper than about 78 deg the grid crosses the folds too rarely (a fold
running down a wall projects to a short XY segment): :func:`conformill.pencil.pencil_passes`
searches the samples there one by one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from conformill.cutter import _CHUNK, _drop_point, _drop_scratch, _set_drop, _set_top, cell_at, xy_barycentric
from conformill.errors import PlanningError
from conformill.geometry.closest import closest_on_triangle

__all__ = ["FoldPoints", "fold_points", "part_tops", "shadow_probes", "wedge_jump"]

#: Most triangles per side of a crossing's model (more rounds than this end the search:
#: the crossing is then the model's, its height lifted onto ``D``).
_MAX_SIDE = 8
#: Points along the segment between the contacts where the shadow's depth is read.
_SHADOW_POINTS = 7
#: Slack of the triangle boxes in :func:`_top` (mm).
_BOX_PAD = 1e-6
#: Most grid points (about 60 bytes each while the search runs).
_MAX_GRID = 16_000_000


@dataclass(frozen=True, eq=False)
class FoldPoints:
    """Points where folds of the drop surface cross the grid's edges.

    Attributes
    ----------
    centres : (k, 3) float64
        Ball centres on the drop surface, at the fold.
    contact_a, contact_b : (k, 3) float64
        The two places the ball touches there (one per side of the fold).
    shadow : (k,) float64
        Depth of the shadow (mm): the largest vertical gap between the ball's underside and
        the part between the two contacts.
    stats : dict
        ``grid_points`` (with a drop height), ``edges`` (crossed by a fold),
        ``drops_per_edge``, ``spacing_mm``, ``jump_mm``.
    """

    centres: np.ndarray
    contact_a: np.ndarray
    contact_b: np.ndarray
    shadow: np.ndarray
    stats: dict
    grid: DropGrid | None = None


@dataclass(frozen=True, eq=False)
class DropGrid:
    """The drop heights of an XY grid: node ``(i, j)`` at ``(x0 + i spacing, y0 + j
    spacing)`` has the ball's centre height ``z[j * nx + i]`` (``-inf``: the ball touches
    nothing). The fold search's grid, which the fill stage reuses (:mod:`conformill.fill`)."""

    x0: float
    y0: float
    spacing: float
    nx: int
    ny: int
    z: np.ndarray = field(repr=False)


def wedge_jump(r: float, depth: float) -> float:
    """Distance between the contacts of a ball wedged in a V of two planes whose bottom lies ``depth`` below it.

    ``depth = r (1 / cos(a) - 1)`` and the contacts lie ``2 r sin(a)`` apart.
    """
    c = 1.0 / (1.0 + depth / r)
    return 2.0 * r * math.sqrt(max(1.0 - c * c, 0.0))


@njit(cache=True, nogil=True, inline="always")
def _closest(px, py, pz, T, t):
    """Point of triangle ``t`` (a row of the cutter's table ``T``) nearest ``p``."""
    return closest_on_triangle(px, py, pz, T[t, 0], T[t, 1], T[t, 2], T[t, 3], T[t, 4], T[t, 5],
                               T[t, 6], T[t, 7], T[t, 8])


@njit(cache=True, nogil=True, parallel=True)
def _contacts(X, Y, Z, tri, T):
    """Contact point of each grid drop (NaN where the ball touches nothing)."""
    k = X.shape[0]
    Q = np.full((k, 3), np.nan)
    for i in prange(k):
        t = tri[i]
        if t >= 0:
            Q[i, 0], Q[i, 1], Q[i, 2] = _closest(X[i], Y[i], Z[i], T, t)
    return Q


@njit(cache=True, nogil=True, parallel=True)
def _crossings(A, B, TA, TB, QA, QB, r, tol_t, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
               maxwin):
    """Per grid edge ``A[k] -> B[k]``: the fold crossing on the two-sided model, refined by
    true drops (see the module docstring). Returns ``(x, y, z, contact A xyz, contact B
    xyz, true drops)`` per edge."""
    m = A.shape[0]
    out = np.empty((m, 10))
    r2 = r * r
    # in chunks of edges: the drops' working arrays are made once per chunk
    for ch in prange((m + _CHUNK - 1) // _CHUNK):
        cid, cbound, seen = _drop_scratch(maxwin)
        SA = np.empty(_MAX_SIDE, dtype=np.int64)
        SB = np.empty(_MAX_SIDE, dtype=np.int64)
        for k in range(ch * _CHUNK, min(m, (ch + 1) * _CHUNK)):
            SA[0] = TA[k]
            SB[0] = TB[k]
            na = 1
            nb = 1
            xa, ya, xb, yb = A[k, 0], A[k, 1], B[k, 0], B[k, 1]
            x = xa
            y = ya
            z = -np.inf
            drops = 0
            while True:
                # side A is on top at A, side B at B: bisect for the switch
                lo = 0.0
                hi = 1.0
                while hi - lo > tol_t:
                    t = 0.5 * (lo + hi)
                    x = xa + t * (xb - xa)
                    y = ya + t * (yb - ya)
                    if _set_drop(x, y, r, r2, T, SA, na) >= _set_drop(x, y, r, r2, T, SB, nb):
                        lo = t
                    else:
                        hi = t
                t = 0.5 * (lo + hi)
                x = xa + t * (xb - xa)
                y = ya + t * (yb - ya)
                z = max(_set_drop(x, y, r, r2, T, SA, na), _set_drop(x, y, r, r2, T, SB, nb))
                hz, tt = _drop_point(x, y, r, r2, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
                                     -1, cid, cbound, seen, z + 1e-9, False)
                drops += 1
                if tt < 0:
                    break
                z = hz  # on D from here, whatever follows
                qx, qy, qz = _closest(x, y, hz, T, tt)
                da = (qx - QA[k, 0]) ** 2 + (qy - QA[k, 1]) ** 2 + (qz - QA[k, 2]) ** 2
                db = (qx - QB[k, 0]) ** 2 + (qy - QB[k, 1]) ** 2 + (qz - QB[k, 2]) ** 2
                if da <= db:
                    if na == _MAX_SIDE:
                        break
                    SA[na] = tt
                    na += 1
                else:
                    if nb == _MAX_SIDE:
                        break
                    SB[nb] = tt
                    nb += 1
            ta = _set_top(x, y, r, r2, T, SA, na)[1]
            tb = _set_top(x, y, r, r2, T, SB, nb)[1]
            ta = ta if ta >= 0 else SA[0]
            tb = tb if tb >= 0 else SB[0]
            out[k, 0] = x
            out[k, 1] = y
            out[k, 2] = z
            out[k, 3], out[k, 4], out[k, 5] = _closest(x, y, z, T, ta)
            out[k, 6], out[k, 7], out[k, 8] = _closest(x, y, z, T, tb)
            out[k, 9] = drops
    return out


@njit(cache=True, nogil=True, inline="always")
def _top(x, y, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri):
    """Height of the part's top at ``(x, y)``: the highest triangle over the point (-inf: none).

    Triangles whose XY box (grown by 1e-6 mm, beyond the barycentric test's 1e-12 slack)
    misses the point, or whose highest vertex lies more than 1e-6 mm below the best so far,
    are skipped before the test: the same value, fewer tests (``Bt``: the cutter's box
    table)."""
    c = cell_at(x, y, gx0, gy0, cell, ncx, ncy)
    if c < 0:
        return -np.inf
    best = -np.inf
    for e in range(cstart[c], cstart[c + 1]):
        t = ctri[e]
        if (Bt[t, 4] + _BOX_PAD < best or x < Bt[t, 0] - _BOX_PAD or x > Bt[t, 2] + _BOX_PAD or y < Bt[t, 1] - _BOX_PAD
                or y > Bt[t, 3] + _BOX_PAD):
            continue
        l0, l1, l2 = xy_barycentric(x, y, T, t)  # NaN: a vertical triangle, never over the point
        if l0 >= -1e-12 and l1 >= -1e-12 and l2 >= -1e-12:
            zz = l0 * T[t, 2] + l1 * T[t, 5] + l2 * T[t, 8]
            if zz > best:
                best = zz
    return best


@njit(cache=True, nogil=True, parallel=True)
def _shadows(C, QA, QB, r, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri, npts):
    """Largest vertical gap between the ball's underside and the part's top at ``npts``
    points evenly spaced on the XY segment between the contacts."""
    m = C.shape[0]
    out = np.zeros(m)
    r2 = r * r
    for k in prange(m):
        g = 0.0
        for s in range(1, npts + 1):
            t = s / (npts + 1)
            x = QA[k, 0] + t * (QB[k, 0] - QA[k, 0])
            y = QA[k, 1] + t * (QB[k, 1] - QA[k, 1])
            d2 = (x - C[k, 0]) ** 2 + (y - C[k, 1]) ** 2
            if d2 >= r2:
                continue
            zs = _top(x, y, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri)
            if zs > -np.inf:
                g = max(g, C[k, 2] - math.sqrt(r2 - d2) - zs)
        out[k] = g
    return out


@njit(cache=True, nogil=True, parallel=True)
def _tops(X, Y, T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri):
    """:func:`_top` at each ``(X[i], Y[i])``."""
    out = np.empty(X.shape[0])
    for i in prange(X.shape[0]):
        out[i] = _top(X[i], Y[i], T, Bt, gx0, gy0, cell, ncx, ncy, cstart, ctri)
    return out


def part_tops(cutter, XY) -> np.ndarray:
    """Height of the part's top at each point of ``XY (n, 2)``: the highest triangle over it
    (``-inf`` where none is)."""
    XY = np.asarray(XY, dtype=np.float64).reshape(-1, 2)
    gx0, gy0, cell, ncx, ncy = cutter._grid
    return _tops(np.ascontiguousarray(XY[:, 0]), np.ascontiguousarray(XY[:, 1]), cutter._T, cutter._B, gx0, gy0,
                 cell, ncx, ncy, cutter._cstart, cutter._ctri)


def shadow_probes(cutter, contact_a, contact_b, at=(0.25, 0.5, 0.75)) -> np.ndarray:
    """Points of the part in the shadows of fold points: at the fractions ``at`` of the XY
    segment between the two contacts, on the part's top there (or on the segment itself
    where no triangle is over the point). Returns ``(k, len(at), 3)``."""
    qa = np.asarray(contact_a, dtype=np.float64).reshape(-1, 3)
    qb = np.asarray(contact_b, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(at, dtype=np.float64)
    M = qa[:, None, :] + f[None, :, None] * (qb - qa)[:, None, :]
    z = part_tops(cutter, M[:, :, :2].reshape(-1, 2)).reshape(M.shape[:2])
    M[:, :, 2] = np.where(np.isfinite(z), z, M[:, :, 2])
    return M


def _grid_box(cutter):
    """XY corners ``(lo, hi)`` of the fold grid: the part's XY box grown by the ball's radius."""
    box = cutter._B[:, :4]
    return box[:, :2].min(axis=0) - cutter.radius, box[:, 2:].max(axis=0) + cutter.radius


def grid_shape(cutter, spacing: float):
    """The XY grid of ``spacing`` over the cutter's part (:func:`_grid_box`): ``(lo, hi, nx, ny)``,
    node ``(i, j)`` at ``lo + spacing (i, j)``."""
    lo, hi = _grid_box(cutter)
    nx, ny = (int(v) for v in np.ceil((hi - lo) / spacing) + 1)
    return lo, hi, nx, ny


def drop_grid(cutter, spacing: float):
    """The drop heights of the grid of :func:`grid_shape`, dropped row by row (consecutive
    drops share the warm start): ``(DropGrid, X, Y, tri)``, the nodes' coordinates and
    contact triangles (-1 where the ball touches nothing). The fold search's grid, and the
    fill stage's when the fold search did not run (:mod:`conformill.fill`)."""
    lo, _, nx, ny = grid_shape(cutter, spacing)
    X = np.tile(lo[0] + spacing * np.arange(nx), ny)
    Y = np.repeat(lo[1] + spacing * np.arange(ny), nx)
    z, tri = cutter._drop(np.column_stack([X, Y]), np.full(nx * ny, -np.inf))
    tri = np.where(np.isfinite(z), tri, -1)
    grid = DropGrid(x0=float(lo[0]), y0=float(lo[1]), spacing=float(spacing), nx=nx, ny=ny, z=z)
    return grid, X, Y, tri


def fold_points(cutter, spacing: float, jump: float) -> FoldPoints:
    """Fold points of the drop surface on an XY grid of ``spacing`` over the part.

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
        The ball and the part.
    spacing : float
        Grid spacing (mm); folds are found where they cross the grid's edges.
    jump : float
        Grid edges whose ends' contacts lie at most this far apart (mm) are not searched:
        the contact moves about ``spacing`` on smooth ground (see :func:`wedge_jump`).

    Returns
    -------
    FoldPoints

    Raises
    ------
    PlanningError
        ``spacing`` or ``jump`` is not positive, or the grid would exceed 16M points.
    """
    for name, v in (("fold grid spacing", spacing), ("fold jump", jump)):
        if not (np.isfinite(v) and v > 0):
            raise PlanningError(f"pencil: {name} must be a positive number, got {v}")
    r = cutter.radius
    lo, hi, nx, ny = grid_shape(cutter, spacing)
    if nx * ny > _MAX_GRID:
        raise PlanningError(f"pencil: a fold grid of {spacing:g} mm over {hi[0] - lo[0]:.1f} x {hi[1] - lo[1]:.1f} mm "
                            f"would hold {nx * ny} points (at most {_MAX_GRID})")
    grid, X, Y, tri = drop_grid(cutter, spacing)
    z = grid.z
    Q = _contacts(X, Y, z, tri, cutter._T)
    idx = np.arange(nx * ny).reshape(ny, nx)
    E = np.concatenate([np.column_stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()]),
                        np.column_stack([idx[:-1, :].ravel(), idx[1:, :].ravel()])])
    a, b = E[:, 0], E[:, 1]
    use = (tri[a] >= 0) & (tri[b] >= 0) & (tri[a] != tri[b])
    use[use] = np.linalg.norm(Q[a[use]] - Q[b[use]], axis=1) > jump
    a, b = a[use], b[use]
    XY = np.column_stack([X, Y])
    gx0, gy0, cell, ncx, ncy = cutter._grid
    T = cutter._T
    out = _crossings(XY[a], XY[b], tri[a], tri[b], Q[a], Q[b], r, 1e-3, T, cutter._B, gx0, gy0, cell, ncx, ncy,
                     cutter._cstart, cutter._ctri, cutter._czmax, cutter._EB, cutter._CP, cutter._maxwin)
    C = np.ascontiguousarray(out[:, :3])
    qa = np.ascontiguousarray(out[:, 3:6])
    qb = np.ascontiguousarray(out[:, 6:9])
    depth = _shadows(C, qa, qb, r, T, cutter._B, gx0, gy0, cell, ncx, ncy, cutter._cstart, cutter._ctri,
                     _SHADOW_POINTS)
    stats = {"grid_points": int(np.count_nonzero(tri >= 0)), "edges": int(len(a)),
             "drops_per_edge": float(out[:, 9].mean()) if len(a) else 0.0, "spacing_mm": float(spacing),
             "jump_mm": float(jump)}
    return FoldPoints(centres=C, contact_a=qa, contact_b=qb, shadow=depth, stats=stats, grid=grid)
