"""Cutter stage: ball-end cutter locations (CL) from cutter-contact (CC) points, gouge-safe.

The cutter is a ball of radius ``r`` on a vertical axis (Z is the tool axis). A tool
position is given by its ball centre; the programmed point is the tool tip, ``centre - r Z``.

Drop-cutter (the classic CAM primitive, as in OpenCAMLib's ``BallCutter``): for a point
``(x, y)``, the drop height is the lowest ball-centre height at which the ball touches the
triangle mesh and does not intersect it, i.e. the ball lowered along -Z until first contact.
For one triangle it is the largest of three kinds of contact, each valid only if the contact
point lies on the feature:

- facet: ``c = cc + r n`` with ``n`` the unit facet normal with ``n_z > 0``; the contact
  ``cc_xy = p - r n_xy`` must lie in the (XY projection of the) triangle; then
  ``z_c = z_plane(cc_xy) + r n_z``;
- edge ``a -> b`` (a cylinder of radius ``r`` around the segment): with ``d`` the XY
  distance from ``p`` to the edge's line, the vertical plane of the edge cuts the ball in a
  circle of radius ``s = sqrt(r^2 - d^2)``; with ``u0`` the position of ``p`` along the edge
  (XY length) and ``m`` the edge slope, ``z_c = z_a + m u0 + s sqrt(1 + m^2)``, valid if the
  contact ``u0 + s m / sqrt(1 + m^2)`` lies in ``[0, |b - a|_xy]``;
- vertex ``v`` (a sphere): ``z_c = v_z + sqrt(r^2 - |p - v|_xy^2)`` if ``|p - v|_xy <= r``.

Over a triangle the height of a ball touching its point ``q`` is concave in ``q``, with its
free maximum at the facet contact; so when the facet contact misses the triangle, only the
one or two edges whose lines separate it from the triangle are tested, each as a closed
segment (the cylinder contact clamped to the segment covers its end vertices).

The drop height over the mesh is the maximum over the triangles (triangles are two-sided).
Because the mesh surface equals the union of its triangles, the ball at the drop height
touches the mesh and intersects no triangle: it cannot gouge the surface.

Speed comes from a uniform XY grid (cells of about ``r/4``) holding, per cell, the
triangles whose XY bounding box overlaps it, sorted by decreasing top, and the cell's highest
top ``zmax_C``. A contact at a point ``q`` of cell ``C`` gives at most
``zmax_C + sqrt(r^2 - dist(p, C)^2)``; and, since all of the cell's triangles lie below a
plane with the slope of their mean normal, at most the height of the ball resting on that
plane with its contact inside the cell (closed form). A cell whose bound is below the best
height found is skipped, and a cell's scan stops at the first triangle whose top gives
such a bound.
A triangle is fully tested only if three upper bounds of its drop height all reach the best
height: its XY box and top; the ball resting on its infinite plane (``a x + b y + c + r / n_z``);
and the tangent plane at its centroid of the concave function ``q_z + sqrt(r^2 - |q - p|^2)``
over the triangle; and once per drop, though several of the cells scanned may hold it.
The previous point's contact triangle (points usually come in path order)
gives the first height; without one, cells are visited by decreasing bound. All pruning
uses a slack of 1e-9 mm, so the result is the exact maximum whatever the visiting order
(bit-identical for shuffled queries or another cell size), except for a ball whose only
contact lies exactly r away in XY, at its equator: rounding in the cell and triangle tests
may then find or miss that contact depending on the warm start.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numba import njit, prange
from numba import types as _nt

from conformill.errors import MeshError, PlanningError
from conformill.geometry.closest import closest_on_triangle

__all__ = ["BallCutter"]

log = logging.getLogger(__name__)

#: Columns of the per-triangle table ``T`` (after the spatial reorder): the vertices, the
#: unit up normal, 1 / det_xy, then per directed edge ``k`` (``1 -> 2``, ``2 -> 0``,
#: ``0 -> 1``, from :data:`_E0`, :data:`_EW` columns apart) its XY length ``L`` (-1 where
#: ``L^2 <= 1e-24``: a vertical edge), XY unit direction ``ux, uy``, slope ``m = dz / L``
#: and ``sqrt(1 + m^2)``: what :func:`_seg_drop` computed at every call (two square roots
#: and three divisions per edge), with the same arithmetic. Session 58, recorded cutter
#: calls on one thread: igea's drops 3 % quicker, the pencil's working-set search 5 %; at
#: 620k faces within 2 % either way (the wider rows cost memory traffic there). The edges
#: in a table of their own were slower on both (an extra random read per full test).
#: The kernels cannot see a table's width: :func:`_tri_drop` refuses any other (a 13-column
#: table would read its edges from the next row).
_X0, _Y0, _Z0, _X1, _Y1, _Z1, _X2, _Y2, _Z2, _NX, _NY, _NZ, _IDET = range(13)
_E0, _EW = 13, 5
_NT = _E0 + 3 * _EW
#: A facet whose unit normal has ``|n_z|`` below this is vertical: only its edges and
#: vertices can be touched (as OpenCAMLib does).
_VERTICAL_NZ = 1e-12
#: Below this ``n_z`` the plane and tangent bounds are not used: their slopes ``1 / n_z``
#: would amplify rounding beyond the pruning slack.
_BOUND_NZ = 1e-3
#: Slack (mm) on the pruning bounds so that rounding can never drop a contact that would
#: raise the result: the answer is then independent of the visiting order.
_PRUNE_SLACK = 1e-9
#: How far below the ideal centre height (mm) the drop search of ``cl_from_cc`` starts.
_FLOOR_SLACK = 1e-6
#: Relative pull of a centre towards its CC point where the ideal centre, r away in XY
#: (a horizontal normal), touches nothing through rounding (:meth:`BallCutter.cl_from_cc`).
_RIM_PULL = 1e-6
#: A contact hint holds its centre up when its drop height there is within this (mm).
_SUPPORT_TOL = 1e-9
#: Points handled by one thread task (consecutive points share the warm start).
_CHUNK = 256
#: Points a move of :meth:`BallCutter.refine` has room for at first (moves that need more
#: are refined again with the full room).
_FIRST_ROOM = 8
#: Most bisection levels of :meth:`BallCutter.refine` below its first pieces.
_MAX_DEPTH = 40
#: Upper bound on grid cells (memory); the cell size grows when exceeded.
_MAX_CELLS = 4_000_000
#: Slots of a drop's table of the triangles it has tested (a power of two, less one: the
#: mask of a triangle's slot). See :func:`_drop_scratch`.
_SEEN_MASK = 1023
#: Entries of a cell read at a time by :func:`_scan_cell` (128 at 620k faces: 3 % quicker
#: than 32 or 64; a cell there holds about 91).
_BATCH = 128

# Explicit signatures of the kernels that other kernels call: one compiled version each.
# Left to inference, a literal argument (``-1`` for "no warm start"), an omitted default
# or an int32 triangle index each made another specialisation, compiled again on a fresh
# install (``_drop_point`` three times). With a signature numba compiles (or loads from
# its cache) when this module is imported, not at the first call.
_F8, _I8, _BOOL = _nt.float64, _nt.int64, _nt.boolean
_M2, _V1, _I1, _I4 = _nt.float64[:, ::1], _nt.float64[::1], _nt.int64[::1], _nt.int32[::1]
#: ``T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP``: the grid a drop scans
_GRID_ARGS = (_M2, _M2, _F8, _F8, _F8, _I8, _I8, _I1, _I4, _V1, _M2, _M2)
_TRI_DROP_SIG = _F8(_F8, _F8, _F8, _F8, _M2, _I8)
_DROP_POINT_SIG = _nt.Tuple((_F8, _I8))(_F8, _F8, _F8, _F8, *_GRID_ARGS, _I8, _I1, _V1, _I1, _F8, _BOOL)
_SET_DROP_SIG = _F8(_F8, _F8, _F8, _F8, _M2, _I1, _I8)


# --------------------------------------------------------------------------------------
# numba kernels
# --------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _drop_scratch(maxwin):
    """Working arrays of :func:`_drop_point`, one set per thread task: ``cid, cbound``
    (the cells of a cold start's window, ``maxwin`` long) and ``seen``.

    ``seen`` remembers the triangles a drop has already tested. A triangle is an entry of
    every cell its XY box overlaps, and a drop that scans two of those cells tested it
    twice: on igea's ``cl_from_cc`` drops 10.1 of the 24.6 full tests per drop were such
    repeats, at 620k faces 6.9 of 24.8 (session 59). A second test can never raise the
    best height (the first left it at least that high), so skipping it changes nothing.
    ``seen[k]`` (``k = t & _SEEN_MASK``, direct-mapped) holds ``stamp << 32 | t`` for
    the last triangle ``t`` in slot ``k`` and ``seen[_SEEN_MASK + 1]`` the count of drops
    made with the table, whose next value is the drop's stamp: a triangle counts as tested
    only when its slot holds it with this drop's stamp. A slot shared by two triangles of
    one drop only costs a repeated test. Zeroed here, so no slot holds a stamp yet. The
    :data:`_BATCH` entries after the count are :func:`_scan_cell`'s batch.
    """
    return (np.empty(maxwin, dtype=np.int64), np.empty(maxwin, dtype=np.float64),
            np.zeros(_SEEN_MASK + 2 + _BATCH, dtype=np.int64))


@njit(cache=True, nogil=True, inline="always")
def _arc_max(rho2, s0, lo, hi, m, k, c0):
    """Largest ``c0 + m s + sqrt(rho2 - (s - s0)^2)`` over ``s`` in ``[lo, hi]`` with
    ``|s - s0| <= sqrt(rho2)``; ``-inf`` when that set is empty. ``k = sqrt(1 + m^2)``
    (given: the edges' come from the triangle table).

    This is the centre height of a ball resting on a line of slope ``m`` (height ``c0 + m s``)
    that passes ``sqrt(r^2 - rho2)`` from the ball's axis: concave in ``s``, so its maximum
    is the free one, ``s0 + rho m / k``, clamped to the interval.
    """
    if rho2 < 0.0:
        return -np.inf
    rho = math.sqrt(rho2)
    lo = max(lo, s0 - rho)
    hi = min(hi, s0 + rho)
    if lo > hi:
        return -np.inf
    s = s0 + rho * m / k
    s = min(max(s, lo), hi)
    w = s - s0
    return c0 + m * s + math.sqrt(max(rho2 - w * w, 0.0))


@njit(cache=True, nogil=True, inline="always")
def _seg_drop(px, py, r2, T, t, k, ax, ay, az, bz):
    """Centre height of a ball at (px, py) resting on the closed segment a-b, edge ``k`` of
    triangle ``t`` (edge or end vertex); -inf if out of reach: :func:`_arc_max` along the
    edge (XY position in ``[0, L]``, slope ``(bz - az) / L``), the cylinder contact clamped
    to the segment. The edge's length, direction and slope come from ``T`` (:data:`_E0`);
    ``ax, ay, az`` are the edge's first vertex and ``bz`` its second's height, as
    :func:`_tri_drop` passes them.
    """
    c = _E0 + _EW * k
    L = T[t, c]
    if L < 0.0:  # vertical edge: its upper end decides
        dx = px - ax
        dy = py - ay
        q = dx * dx + dy * dy
        if q > r2:
            return -np.inf
        return max(az, bz) + math.sqrt(r2 - q)
    ux = T[t, c + 1]
    uy = T[t, c + 2]
    wx = px - ax
    wy = py - ay
    d = wx * uy - wy * ux
    return _arc_max(r2 - d * d, wx * ux + wy * uy, 0.0, L, T[t, c + 3], T[t, c + 4], az)


@njit(cache=True, nogil=True, inline="always")
def _edge_columns(T, t, k, ax, ay, az, bx, by, bz):
    """Fill edge ``k``'s columns of ``T[t]`` (see :data:`_E0`) for the edge ``a -> b``."""
    c = _E0 + _EW * k
    ex = bx - ax
    ey = by - ay
    L2 = ex * ex + ey * ey
    if L2 <= 1e-24:
        T[t, c] = -1.0
        for q in range(1, _EW):
            T[t, c + q] = 0.0
        return
    L = math.sqrt(L2)
    m = (bz - az) / L
    T[t, c] = L
    T[t, c + 1] = ex / L
    T[t, c + 2] = ey / L
    T[t, c + 3] = m
    T[t, c + 4] = math.sqrt(1.0 + m * m)


@njit(_TRI_DROP_SIG, cache=True, nogil=True)
def _tri_drop(px, py, r, r2, T, t):
    """Drop height of the ball centre onto triangle ``t`` (facet, edges, vertices).

    Over the triangle, the height of a ball touching point ``q`` is ``z(q) + sqrt(r^2 -
    |q - p|^2)``: concave, with its free maximum at the facet contact ``p - r n_xy``. When
    that contact lies in the triangle it is the answer; otherwise the maximum lies on an
    edge whose line separates the contact from the triangle (a negative barycentric
    coordinate of the contact: at most two edges), ends included.
    """
    if T.shape[1] != _NT:
        raise ValueError("_tri_drop: the triangle table must have the columns of _tables")
    x0 = T[t, _X0]
    y0 = T[t, _Y0]
    z0 = T[t, _Z0]
    x1 = T[t, _X1]
    y1 = T[t, _Y1]
    z1 = T[t, _Z1]
    x2 = T[t, _X2]
    y2 = T[t, _Y2]
    z2 = T[t, _Z2]
    nz = T[t, _NZ]
    if nz > _VERTICAL_NZ:
        nx = T[t, _NX]
        ny = T[t, _NY]
        cx = px - r * nx
        cy = py - r * ny
        idet = T[t, _IDET]
        # barycentric coordinates of the contact in the XY projection
        l1 = ((cx - x0) * (y2 - y0) - (cy - y0) * (x2 - x0)) * idet
        l2 = ((x1 - x0) * (cy - y0) - (y1 - y0) * (cx - x0)) * idet
        l0 = 1.0 - l1 - l2
        if l1 >= 0.0 and l2 >= 0.0 and l0 >= 0.0:
            return z0 - (nx * (cx - x0) + ny * (cy - y0)) / nz + r * nz
        best = -np.inf
        if l0 < 0.0:
            best = max(best, _seg_drop(px, py, r2, T, t, 0, x1, y1, z1, z2))
        if l1 < 0.0:
            best = max(best, _seg_drop(px, py, r2, T, t, 1, x2, y2, z2, z0))
        if l2 < 0.0:
            best = max(best, _seg_drop(px, py, r2, T, t, 2, x0, y0, z0, z1))
        return best
    # vertical facet: every edge, ends included
    best = _seg_drop(px, py, r2, T, t, 2, x0, y0, z0, z1)
    best = max(best, _seg_drop(px, py, r2, T, t, 0, x1, y1, z1, z2))
    best = max(best, _seg_drop(px, py, r2, T, t, 1, x2, y2, z2, z0))
    return best


@njit(cache=True, nogil=True, inline="always")
def _set_top(x, y, r, r2, T, W, nw):
    """Drop height at ``(x, y)`` over the triangles ``W[:nw]`` only (a lower bound of the
    drop), and the one that sets it (-1 when none touches the ball)."""
    z = -np.inf
    t = -1
    for k in range(nw):
        v = _tri_drop(x, y, r, r2, T, W[k])
        if v > z:
            z = v
            t = W[k]
    return z, t


@njit(_SET_DROP_SIG, cache=True, nogil=True)
def _set_drop(x, y, r, r2, T, W, nw):
    """Drop height at ``(x, y)`` over the triangles ``W[:nw]`` only: :func:`_set_top`'s height."""
    return _set_top(x, y, r, r2, T, W, nw)[0]


@njit(cache=True, nogil=True, inline="always")
def cell_at(x, y, gx0, gy0, cell, ncx, ncy):
    """The cutter's grid cell holding ``(x, y)`` (``j * ncx + i``; -1 outside the grid)."""
    i = int(math.floor((x - gx0) / cell))
    j = int(math.floor((y - gy0) / cell))
    if i < 0 or j < 0 or i >= ncx or j >= ncy:
        return -1
    return j * ncx + i


@njit(cache=True, nogil=True, inline="always")
def xy_barycentric(x, y, T, t):
    """Barycentric coordinates ``(l0, l1, l2)`` of ``(x, y)`` in the XY projection of
    triangle ``t`` (a row of the cutter's table ``T``); NaN when the projection is a line."""
    x0, y0 = T[t, 0], T[t, 1]
    x1, y1 = T[t, 3], T[t, 4]
    x2, y2 = T[t, 6], T[t, 7]
    det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if det == 0.0:
        return np.nan, np.nan, np.nan
    l1 = ((x - x0) * (y2 - y0) - (y - y0) * (x2 - x0)) / det
    l2 = ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) / det
    return 1.0 - l1 - l2, l1, l2


@njit(cache=True, nogil=True, inline="always")
def _tangent_bound(px, py, r2, T, B, t):
    """Upper bound of the drop height onto triangle ``t`` (``+inf`` when not applicable).

    Over the triangle, the height of a ball touching point ``q`` is
    ``f(q) = z(q) + sqrt(r^2 - |q - p|^2)``: a linear function plus a concave one, so
    ``f`` is concave and lies below its tangent plane at the centroid ``c``; the largest
    value of that plane over the triangle is at a vertex.
    """
    if not B[t, 7] < np.inf:  # (nearly) vertical facet: no usable slope
        return np.inf
    cx = B[t, 8]
    cy = B[t, 9]
    dx = cx - px
    dy = cy - py
    w2 = r2 - dx * dx - dy * dy
    if w2 <= 1e-3 * r2:  # centroid out of reach or at the rim: steep, useless bound
        return np.inf
    w = math.sqrt(w2)
    gx = B[t, 5] - dx / w
    gy = B[t, 6] - dy / w
    m = gx * (T[t, _X0] - cx) + gy * (T[t, _Y0] - cy)
    m = max(m, gx * (T[t, _X1] - cx) + gy * (T[t, _Y1] - cy))
    m = max(m, gx * (T[t, _X2] - cx) + gy * (T[t, _Y2] - cy))
    return B[t, 10] + w + m


@njit(cache=True, nogil=True, inline="always")
def _cell_bound(px, py, r2, x0, y0, cell, CP, c):
    """Upper bound of the drop height from contacts in cell ``c`` (the column ``[x0, x0 +
    cell] x [y0, y0 + cell]``), whose triangles all lie below the plane ``z = gx x + gy y
    + gc`` (``CP[c] = gx, gy, gc, r gx / k, r gy / k, r k`` with ``k = sqrt(1 + gx^2 +
    gy^2)``; ``gc = inf`` when the cell has no such plane).

    ``f(q) = gx qx + gy qy + gc + sqrt(r^2 - |q - p|^2)`` (the ball resting on the plane at
    ``q``) is concave; its maximum over the rectangle is the free maximum (the ball on the
    plane, contact at ``p + r g / k``) when that lies inside, otherwise it lies on an edge
    facing the free maximum (:func:`_arc_max` along that edge).
    """
    gx = CP[c, 0]
    gy = CP[c, 1]
    gc = CP[c, 2]
    if not gc < np.inf:
        return np.inf
    free = gx * px + gy * py + gc + CP[c, 5]
    qx = px + CP[c, 3]
    qy = py + CP[c, 4]
    x1 = x0 + cell
    y1 = y0 + cell
    if x0 <= qx <= x1 and y0 <= qy <= y1:
        return free
    bound = -np.inf
    # an edge x = const at XY distance a from p: the line on it, in y, sits at gc + gx x + gy y
    if qx < x0 or qx > x1:
        xe = x0 if qx < x0 else x1
        a = xe - px
        bound = max(bound, _arc_max(r2 - a * a, py, y0, y1, gy, math.sqrt(1.0 + gy * gy), gc + gx * xe))
    if qy < y0 or qy > y1:
        ye = y0 if qy < y0 else y1
        a = ye - py
        bound = max(bound, _arc_max(r2 - a * a, px, x0, x1, gx, math.sqrt(1.0 + gx * gx), gc + gy * ye))
    return bound


@njit(cache=True, nogil=True, inline="always")
def _scan_cell(px, py, r, r2, T, B, cstart, ctri, EB, c, hc, best, besttri, seen, key):
    """Test the triangles of cell ``c`` (``hc = sqrt(r^2 - dist(p, cell)^2)``); ``seen``,
    ``key``: the drop's table of tested triangles, with room for a batch of entries, and
    its stamp (:func:`_drop_scratch`).

    The entries are read in batches: first the cheap test of each entry's box and top,
    without a branch per entry (the entries that pass are written to the batch, and the
    count grows by the test's outcome), then the other tests of those that passed, in
    the same order. At 620k faces a drop reads 440 entries for about 100 that pass: a
    branch on each mispredicted often (session 59: the drops 9-13 % quicker there, 3-5 %
    on igea). The result is the same bit for bit, the contact triangle included: an entry
    that passed with the best as the batch began is tested as if in one pass, since the
    end of the cell's scan is checked again with the current best before each test (a
    triangle tested before its turn could take a tie from the one the single pass found
    first), and a test that the single pass would have skipped cannot raise the best.
    """
    e = cstart[c]
    e1 = cstart[c + 1]
    batch = _SEEN_MASK + 2  # where the batch starts in ``seen`` (its room checked by _drop_point)
    while e < e1:
        n = 0
        stop = False
        while e < e1 and n < _BATCH:
            # triangles are sorted by decreasing top: a contact *inside this cell* of this
            # or any later triangle is at most top + hc (contacts elsewhere are found
            # through the cells that hold them)
            gap = best - _PRUNE_SLACK - EB[e, 4]  # how far the ball must reach above the top
            if gap > hc:
                stop = True
                break
            # cheap bound from the triangle's XY box and top: top + sqrt(r^2 - q) < best.
            # One test for both ways out, the box beyond the ball's reach (q > r^2: then
            # r^2 - q < 0 <= g^2) and the top too low for its distance (gap > 0, gap^2 >
            # r^2 - q): the same decisions as a test per side and per way (the box
            # distances' signs are those of exact differences; session 58)
            dx = max(EB[e, 0] - px, px - EB[e, 2], 0.0)
            dy = max(EB[e, 1] - py, py - EB[e, 3], 0.0)
            g = max(gap, 0.0)
            seen[batch + n] = e
            n += int(g * g <= r2 - (dx * dx + dy * dy))
            e += 1
        for k in range(n):
            eb = seen[batch + k]
            if best - _PRUNE_SLACK - EB[eb, 4] > hc:  # the best rose: the scan ends here
                stop = True
                break
            t = ctri[eb]
            # tested by this drop already, from another cell it overlaps: the
            # triangle-level bounds below only tighten as the best rises, and a second
            # full test cannot raise the best
            slot = t & _SEEN_MASK
            if seen[slot] == key | t:
                continue
            seen[slot] = key | t
            # the ball resting on the triangle's (infinite) plane is never lower
            if B[t, 5] * px + B[t, 6] * py + B[t, 7] + _PRUNE_SLACK < best:
                continue
            if _tangent_bound(px, py, r2, T, B, t) + _PRUNE_SLACK < best:
                continue
            h = _tri_drop(px, py, r, r2, T, t)
            if h > best:
                best = h
                besttri = t
        if stop:
            break
    return best, besttri


@njit(_DROP_POINT_SIG, cache=True, nogil=True)
def _drop_point(px, py, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
                warm, cid, cbound, seen, floor, first):
    """Drop height at one point; returns (height, contact triangle or -1).

    With a warm start (the previous point's contact triangle) or a finite ``floor`` (a
    height known not to exceed the answer, or below which the answer does not matter) the
    cells are scanned in grid order, each skipped when its bound is below the best height;
    without either they are visited by decreasing bound, which finds a good height sooner.
    The result is ``max(drop, floor)``, with triangle -1 when no triangle rises above
    ``floor``. With ``first`` (and a finite ``floor``) it stops at the first cell that
    holds a triangle rising above ``floor``: only whether one does is then exact.
    ``cid, cbound, seen``: working arrays from :func:`_drop_scratch` (``seen`` lets a
    triangle that several scanned cells hold be tested once).
    """
    if seen.shape[0] < _SEEN_MASK + 2 + _BATCH:  # the kernels do not check their indices
        raise ValueError("_drop_point: the working arrays must be those of _drop_scratch")
    best = floor
    besttri = -1
    stamp = seen[_SEEN_MASK + 1] + 1  # this drop's: a slot with an older stamp is free
    seen[_SEEN_MASK + 1] = stamp
    key = stamp << 32
    if warm >= 0:
        seen[warm & _SEEN_MASK] = key | warm
        h = _tri_drop(px, py, r, r2, T, warm)
        if h > best:
            best = h
            besttri = warm
            if first:
                return best, besttri
    i0 = int(math.floor((px - r - gx0) / cell))
    i1 = int(math.floor((px + r - gx0) / cell))
    j0 = int(math.floor((py - r - gy0) / cell))
    j1 = int(math.floor((py + r - gy0) / cell))
    if i1 < 0 or j1 < 0 or i0 >= ncx or j0 >= ncy:
        return best, besttri
    i0 = max(i0, 0)
    j0 = max(j0, 0)
    i1 = min(i1, ncx - 1)
    j1 = min(j1, ncy - 1)
    ordered = best == -np.inf
    n = 0
    for j in range(j0, j1 + 1):
        cy0 = gy0 + j * cell
        dy = 0.0
        if py < cy0:
            dy = cy0 - py
        elif py > cy0 + cell:
            dy = py - cy0 - cell
        for i in range(i0, i1 + 1):
            c = j * ncx + i
            if cstart[c] == cstart[c + 1]:
                continue
            cx0 = gx0 + i * cell
            dx = 0.0
            if px < cx0:
                dx = cx0 - px
            elif px > cx0 + cell:
                dx = px - cx0 - cell
            q = dx * dx + dy * dy
            if ordered:
                if q > r2:
                    continue
                cid[n] = c
                cbound[n] = min(czmax[c] + math.sqrt(r2 - q),
                                _cell_bound(px, py, r2, cx0, cy0, cell, CP, c))
                n += 1
            else:
                # out of reach (q > r2), or too low for its distance: one test, the same
                # decisions (see _scan_cell)
                g = max(best - _PRUNE_SLACK - czmax[c], 0.0)
                if g * g > r2 - q:
                    continue
                if _cell_bound(px, py, r2, cx0, cy0, cell, CP, c) + _PRUNE_SLACK < best:
                    continue
                best, besttri = _scan_cell(px, py, r, r2, T, B, cstart, ctri, EB, c,
                                           math.sqrt(r2 - q), best, besttri, seen, key)
                if first and besttri >= 0:
                    return best, besttri
    # cold start: visit cells by decreasing bound; stop when no cell can raise the best
    while n > 0:
        k = 0
        bmax = cbound[0]
        for m in range(1, n):
            if cbound[m] > bmax:
                bmax = cbound[m]
                k = m
        if bmax + _PRUNE_SLACK < best:
            break
        c = cid[k]
        n -= 1
        cid[k] = cid[n]
        cbound[k] = cbound[n]
        i = c % ncx
        j = c // ncx
        dx = max(gx0 + i * cell - px, px - gx0 - (i + 1) * cell, 0.0)
        dy = max(gy0 + j * cell - py, py - gy0 - (j + 1) * cell, 0.0)
        best, besttri = _scan_cell(px, py, r, r2, T, B, cstart, ctri, EB, c,
                                   math.sqrt(max(r2 - dx * dx - dy * dy, 0.0)), best, besttri, seen, key)
    return best, besttri


@njit(cache=True, nogil=True, parallel=True)
def _drop_many(xy, r, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, maxwin, floor, wa, wb, first):
    """:func:`_drop_point` per point: ``(max(drop, floor), contact triangle or -1)``.

    Hints, triangles near the point (-1: none; only the speed depends on them): ``wb[p]``
    is tried first and, where it rises above the floor, raises the floor to its height;
    ``wa[p]`` is the warm start, otherwise the contact found at the previous point of the
    chunk. With ``first`` each point stops at the first triangle rising above its floor:
    only whether one does (a triangle, not -1) is then exact.
    """
    k = xy.shape[0]
    out = np.empty(k, dtype=np.float64)
    tri = np.empty(k, dtype=np.int64)
    nchunks = (k + _CHUNK - 1) // _CHUNK
    r2 = r * r
    for ch in prange(nchunks):
        cid, cbound, seen = _drop_scratch(maxwin)
        warm = -1
        for p in range(ch * _CHUNK, min(k, (ch + 1) * _CHUNK)):
            w = wa[p] if wa[p] >= 0 else warm
            f = floor[p]
            tb = -1
            if wb[p] >= 0 and wb[p] != w:
                hb = _tri_drop(xy[p, 0], xy[p, 1], r, r2, T, wb[p])
                if hb > f:
                    f = hb
                    tb = wb[p]
            if first and tb >= 0:
                out[p] = f
                tri[p] = tb
                continue
            h, t = _drop_point(xy[p, 0], xy[p, 1], r, r2, T, B, gx0, gy0, cell, ncx, ncy,
                               cstart, ctri, czmax, EB, CP, w, cid, cbound, seen, f, first)
            out[p] = h
            if t >= 0:
                tri[p] = t
                warm = t
            else:
                tri[p] = tb  # nothing above the second hint's height: it is the drop
    return out, tri


@njit(cache=True, nogil=True, inline="always")
def _piece_ok(r, d0, d1, l2, floor2):
    """Whether the bound ``min_t f(t) >= (r - tol/2)^2`` holds (see ``BallCutter.refine``)."""
    fa = (r - d0) * (r - d0)
    fb = (r - d1) * (r - d1)
    ts = (fa - fb + l2) / max(2.0 * l2, 1e-300)
    ts = min(max(ts, 0.0), 1.0)
    return fa + ts * (fb - fa - l2) + ts * ts * l2 >= floor2


#: Flags of a known chord sample in :func:`_refine_move`: its height is the exact drop
#: height (else an upper bound of it), it is a vertex of the refined chord, the sub-move
#: that starts at this vertex is proved safe.
_EXACT, _NODE, _PROVEN = 1, 2, 4


@njit(cache=True, nogil=True)
def _known_room(K, Fl, K2, Fl2, ft, fz, need):
    """The sample buffers of :func:`_refine_move` with room for ``need`` samples (the
    first ones of ``K``, ``Fl`` kept)."""
    cap = K.shape[1]
    if cap >= need:
        return K, Fl, K2, Fl2, ft, fz
    while cap < need:
        cap *= 2
    nK = np.empty((2, cap))
    nF = np.zeros(cap, dtype=np.int8)
    nK[:, :K.shape[1]] = K
    nF[:Fl.shape[0]] = Fl
    return nK, nF, np.empty((2, cap)), np.zeros(cap, dtype=np.int8), np.empty(cap, dtype=np.int64), np.empty(cap)


@njit(cache=True, nogil=True, inline="always")
def _sub_move(K, Fl, i):
    """The node after node ``i`` of :func:`_refine_move`'s samples and the chord between
    them: ``(b, t_i, z_i, slope dz/dt)``."""
    b = i + 1
    while not (Fl[b] & _NODE):
        b += 1
    ta = K[0, i]
    za = K[1, i]
    return b, ta, za, (K[1, b] - za) / (K[0, b] - ta)


@njit(cache=True, nogil=True)
def _refine_move(ax, ay, az, vx, vy, vz, r, thresh, floor2, l_safe, max_depth, T, B, gx0, gy0, cell, ncx, ncy,
                 cstart, ctri, czmax, EB, CP, warm, cid, cbound, seen, K, Fl, K2, Fl2, ft, fz, ot, oz):
    """All the points :meth:`BallCutter.refine` inserts into the move ``a -> a + v``.

    The move's chord is refined as a polyline through *nodes* (its ends and the inserted
    points, each on the drop surface ``D``) over the same XY segment. Every drop made
    along that segment is kept as a *known sample* ``(t, height)``, the height being
    ``max(D, floor)``, so an upper bound of ``D`` that is exact where a triangle rose
    above the floor. Until every sub-move (between consecutive nodes) is proved safe:

    1. in each unproved sub-move, the known sample deepest below its chord, if more than
       ``thresh``, becomes a node (a sample whose height is only a bound is dropped
       exactly first);
    2. otherwise each piece between consecutive known samples of an unproved sub-move is
       tested with the bound of :func:`_piece_ok` (depths below the sub-move's chord, 0
       at its nodes); a sub-move whose pieces all pass is proved;
    3. the midpoints of the failing pieces are dropped (a piece shorter than the first
       pieces over ``2^max_depth`` makes its deeper end a node instead).

    The first pieces are the move cut into equal parts no longer than ``l_safe``. A
    sub-move made by a new node keeps the samples already dropped over it (their heights
    still bound ``D`` there), so it is checked again without dropping them anew; a
    sub-move no longer than ``l_safe`` is proved at once, whatever its samples (on a
    steep move a sample can lie more than ``thresh`` below the chord, vertically, with
    the ball still clear of the part). Session 47, against a version that dropped each
    new sub-move's samples anew: 14-18 % less time in ``refine`` on igea and at 620k
    faces, for 0.5-0.9 % more points.

    Returns ``(count, warm, buffers...)``: ``count`` nodes written to ``ot`` (chord
    parameters, increasing) and ``oz`` (drop heights), or -1 when more than ``len(ot)``
    would be needed or a failing piece cannot be split (then nothing is decided).
    """
    r2 = r * r
    cap = ot.shape[0]
    lxy = math.sqrt(vx * vx + vy * vy)
    L = math.sqrt(vx * vx + vy * vy + vz * vz)
    n = max(int(math.ceil(L / l_safe)), 1)
    K, Fl, K2, Fl2, ft, fz = _known_room(K, Fl, K2, Fl2, ft, fz, n + 1)
    for j in range(n + 1):
        t = j / n
        K[0, j] = t
        if j == 0 or j == n:
            K[1, j] = az + (vz if j == n else 0.0)
            Fl[j] = _EXACT | _NODE
        else:
            h, tri = _drop_point(ax + t * vx, ay + t * vy, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri,
                                 czmax, EB, CP, warm, cid, cbound, seen, az + t * vz, False)
            K[1, j] = h
            Fl[j] = _EXACT if tri >= 0 else 0
            if tri >= 0:
                warm = tri
    k = n + 1
    tmin = 1.0 / n / (2.0 ** max_depth)
    nodes = 0
    while True:
        # 1. the deepest violating sample of each unproved sub-move becomes a node
        changed = False
        i = 0
        while i < k - 1:
            b, ta, za, s = _sub_move(K, Fl, i)
            if not (Fl[i] & _PROVEN):
                ln = (K[0, b] - ta) * math.sqrt(lxy * lxy + s * s)
                if _piece_ok(r, 0.0, 0.0, ln * ln, floor2):  # short enough to be safe whatever lies below
                    Fl[i] |= _PROVEN
                    i = b
                    continue
                best = thresh
                bj = -1
                for j in range(i + 1, b):
                    d = K[1, j] - (za + (K[0, j] - ta) * s)
                    if d > best:
                        best = d
                        bj = j
                if bj >= 0:
                    changed = True
                    if Fl[bj] & _EXACT:
                        Fl[bj] |= _NODE
                        nodes += 1
                    else:  # only a bound: drop it exactly, then look again
                        t = K[0, bj]
                        h, tri = _drop_point(ax + t * vx, ay + t * vy, r, r2, T, B, gx0, gy0, cell, ncx, ncy,
                                             cstart, ctri, czmax, EB, CP, warm, cid, cbound, seen, -np.inf, False)
                        K[1, bj] = h
                        Fl[bj] |= _EXACT
            i = b
        if nodes > cap:
            return -1, warm, K, Fl, K2, Fl2, ft, fz
        if changed:
            continue
        # 2. the bound on the pieces of the unproved sub-moves (room for a midpoint in each)
        K, Fl, K2, Fl2, ft, fz = _known_room(K, Fl, K2, Fl2, ft, fz, 2 * k)
        nf = 0
        i = 0
        while i < k - 1:
            b, ta, za, s = _sub_move(K, Fl, i)
            if not (Fl[i] & _PROVEN):
                per_t = math.sqrt(lxy * lxy + s * s)  # 3D length of this chord per unit of t
                f0 = nf
                d0 = 0.0
                for j in range(i, b):
                    d1 = 0.0 if j + 1 == b else max(K[1, j + 1] - (za + (K[0, j + 1] - ta) * s), 0.0)
                    dt = K[0, j + 1] - K[0, j]
                    ln = dt * per_t
                    if not _piece_ok(r, d0, d1, ln * ln, floor2):
                        if dt > tmin:
                            tm = K[0, j] + 0.5 * dt
                            ft[nf] = j
                            fz[nf] = za + (tm - ta) * s
                            nf += 1
                        else:  # undecided: the deeper end counts as violating
                            e = j + 1 if d1 > d0 else j
                            if Fl[e] & _NODE:
                                e = 2 * j + 1 - e
                            if Fl[e] & _NODE:  # both ends are nodes: no way to split it
                                return -1, warm, K, Fl, K2, Fl2, ft, fz
                            if not (Fl[e] & _EXACT):
                                t = K[0, e]
                                h, tri = _drop_point(ax + t * vx, ay + t * vy, r, r2, T, B, gx0, gy0, cell, ncx,
                                                     ncy, cstart, ctri, czmax, EB, CP, warm, cid, cbound, seen, -np.inf,
                                                     False)
                                K[1, e] = h
                            Fl[e] |= _EXACT | _NODE
                            nodes += 1
                            changed = True
                    d0 = d1
                if nf == f0 and not changed:
                    Fl[i] |= _PROVEN
            i = b
        if nodes > cap:
            return -1, warm, K, Fl, K2, Fl2, ft, fz
        if nf == 0 and not changed:
            break
        # 3. the failing pieces' midpoints, dropped and merged in
        w = 0
        f = 0
        for j in range(k):
            K2[0, w] = K[0, j]
            K2[1, w] = K[1, j]
            Fl2[w] = Fl[j]
            w += 1
            if f < nf and ft[f] == j:
                t = 0.5 * (K[0, j] + K[0, j + 1])
                h, tri = _drop_point(ax + t * vx, ay + t * vy, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart,
                                     ctri, czmax, EB, CP, warm, cid, cbound, seen, fz[f], False)
                K2[0, w] = t
                K2[1, w] = h
                Fl2[w] = _EXACT if tri >= 0 else 0
                if tri >= 0:
                    warm = tri
                w += 1
                f += 1
        K, K2 = K2, K
        Fl, Fl2 = Fl2, Fl
        k = w
    c = 0
    for j in range(1, k - 1):
        if Fl[j] & _NODE:
            ot[c] = K[0, j]
            oz[c] = K[1, j]
            c += 1
    return c, warm, K, Fl, K2, Fl2, ft, fz


@njit(cache=True, nogil=True, parallel=True)
def _refine_moves(P, seg, r, thresh, floor2, l_safe, max_depth, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri,
                  czmax, EB, CP, maxwin, cap):
    """:func:`_refine_move` on each move ``P[seg[i]] -> P[seg[i] + 1]``: ``(count, t, z)``
    with ``count[i]`` points in the first columns of row ``i`` of ``t`` and ``z`` (-1:
    undecided within ``cap`` points)."""
    m = seg.shape[0]
    cnt = np.zeros(m, dtype=np.int64)
    OT = np.empty((m, cap))
    OZ = np.empty((m, cap))
    nchunks = (m + _CHUNK - 1) // _CHUNK
    for ch in prange(nchunks):
        cid, cbound, seen = _drop_scratch(maxwin)
        K = np.empty((2, 64))
        Fl = np.zeros(64, dtype=np.int8)
        K2 = np.empty((2, 64))
        Fl2 = np.zeros(64, dtype=np.int8)
        ft = np.empty(64, dtype=np.int64)
        fz = np.empty(64)
        warm = np.int64(-1)  # not the literal -1: one compiled version of _refine_move
        for i in range(ch * _CHUNK, min(m, (ch + 1) * _CHUNK)):
            s = seg[i]
            ax, ay, az = P[s, 0], P[s, 1], P[s, 2]
            c, warm, K, Fl, K2, Fl2, ft, fz = _refine_move(
                ax, ay, az, P[s + 1, 0] - ax, P[s + 1, 1] - ay, P[s + 1, 2] - az, r, thresh, floor2, l_safe,
                max_depth, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, warm, cid, cbound, seen,
                K, Fl, K2, Fl2, ft, fz, OT[i], OZ[i])
            cnt[i] = c
    return cnt, OT, OZ


@njit(cache=True, nogil=True)
def _contact_slope(px, py, pz, t, T, vx, vy):
    """Slope ``dD/dt`` of the drop surface along ``(vx, vy)`` at the centre ``p`` resting
    on triangle ``t``: ``D``'s unit normal there is ``(p - q) / r`` with ``q`` the contact
    point (the triangle's point nearest to the centre). nan for ``t = -1`` or a vertical
    ``D``."""
    if t < 0:
        return np.nan
    qx, qy, qz = closest_on_triangle(px, py, pz, T[t, _X0], T[t, _Y0], T[t, _Z0], T[t, _X1], T[t, _Y1],
                                     T[t, _Z1], T[t, _X2], T[t, _Y2], T[t, _Z2])
    nx, ny, nz = px - qx, py - qy, pz - qz
    if nz > 1e-9 * math.sqrt(nx * nx + ny * ny + nz * nz):
        return -(nx * vx + ny * vy) / nz
    return np.nan


@njit(cache=True, nogil=True)
def _holding(px, py, pz, t, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, cid, cbound, seen):
    """The triangle holding the centre ``p`` up: ``t`` if its drop height there is ``p_z``
    (within ``_SUPPORT_TOL``), else the one a drop finds at or above ``p_z -
    _FLOOR_SLACK`` (-1: none, the centre floats above ``D``)."""
    if t >= 0 and abs(_tri_drop(px, py, r, r2, T, t) - pz) <= _SUPPORT_TOL:
        return t
    return _drop_point(px, py, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
                       -1, cid, cbound, seen, pz - _FLOOR_SLACK, False)[1]


@njit(cache=True, nogil=True, parallel=True)
def _highest_floats(P, seg, tri, steps, eps, r, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
                    maxwin):
    """Per floating move ``P[seg[i]] -> P[seg[i] + 1]``: the highest float above ``D``
    found by at most ``steps`` tangent steps (see ``BallCutter.settle``; ``eps``: how close
    to the tangent lines a drop must land to end the search), as ``(t, drop height,
    contact, float)`` (float ``-inf`` where no drop found anything below the ball), and
    the triangles holding the two ends up (-1: none; a hint in ``tri`` is kept where it
    holds its centre up)."""
    m = seg.shape[0]
    bt = np.full(m, 0.5)
    bz = np.full(m, np.nan)
    bk = np.full(m, -1, dtype=np.int64)
    bl = np.full(m, -np.inf)
    c0 = np.empty(m, dtype=np.int64)
    c1 = np.empty(m, dtype=np.int64)
    r2 = r * r
    nchunks = (m + _CHUNK - 1) // _CHUNK
    for ch in prange(nchunks):
        cid, cbound, seen = _drop_scratch(maxwin)
        for i in range(ch * _CHUNK, min(m, (ch + 1) * _CHUNK)):
            s = seg[i]
            ax, ay, az = P[s, 0], P[s, 1], P[s, 2]
            vx, vy, vz = P[s + 1, 0] - ax, P[s + 1, 1] - ay, P[s + 1, 2] - az
            kl = _holding(ax, ay, az, tri[s], r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB,
                          CP, cid, cbound, seen)
            kr = _holding(P[s + 1, 0], P[s + 1, 1], P[s + 1, 2], tri[s + 1], r, r2, T, B, gx0, gy0, cell, ncx,
                          ncy, cstart, ctri, czmax, EB, CP, cid, cbound, seen)
            c0[i] = kl
            c1[i] = kr
            tl, zl, sl = 0.0, az, _contact_slope(ax, ay, az, kl, T, vx, vy)
            tr, zr, sr = 1.0, az + vz, _contact_slope(P[s + 1, 0], P[s + 1, 1], P[s + 1, 2], kr, T, vx, vy)
            for _ in range(steps):
                w = tr - tl
                tm = tl + 0.5 * w
                meet = False
                if sr > sl:  # the tangent lines meet inside the bracket
                    tv = (zr - sr * tr - zl + sl * tl) / (sl - sr)
                    if tv > tl + 0.01 * w and tv < tr - 0.01 * w:
                        tm = tv
                        meet = True
                h, k = _drop_point(ax + tm * vx, ay + tm * vy, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart,
                                   ctri, czmax, EB, CP, kl if tm - tl < tr - tm else kr, cid, cbound, seen, -np.inf,
                                   False)
                lift = az + tm * vz - h
                if not math.isfinite(lift):
                    lift = -np.inf
                if lift > bl[i]:
                    bt[i], bz[i], bk[i], bl[i] = tm, h, k, lift
                on_lines = meet and abs(h - (zl + sl * (tm - tl))) <= eps
                sm = _contact_slope(ax + tm * vx, ay + tm * vy, h, k, T, vx, vy)
                if sm >= vz:  # D rises faster than the chord: the top of the float lies left
                    tr, zr, sr, kr = tm, h, sm, k
                else:
                    tl, zl, sl, kl = tm, h, sm, k
                if on_lines or not math.isfinite(sm):
                    break
    return bt, bz, bk, bl, c0, c1


@njit(cache=True, nogil=True, inline="always")
def _seg_box_dist2(ax, ay, bx, by, x0, y0, x1, y1):
    """Squared distance between the segment ``a b`` and the box ``[x0, x1] x [y0, y1]``."""
    # the segment clipped to the box (Liang-Barsky): any part inside gives 0
    t0, t1 = 0.0, 1.0
    dx, dy = bx - ax, by - ay
    inside = True
    for pp, qq in ((-dx, ax - x0), (dx, x1 - ax), (-dy, ay - y0), (dy, y1 - ay)):
        if pp == 0.0:
            if qq < 0.0:
                inside = False
        else:
            t = qq / pp
            if pp < 0.0:
                t0 = max(t0, t)
            else:
                t1 = min(t1, t)
    if inside and t0 <= t1:
        return 0.0
    # apart: the nearest pair has an end of the segment or a corner of the box
    best = np.inf
    for px, py in ((ax, ay), (bx, by)):
        ex = max(x0 - px, 0.0, px - x1)
        ey = max(y0 - py, 0.0, py - y1)
        best = min(best, ex * ex + ey * ey)
    l2 = dx * dx + dy * dy
    for cx, cy in ((x0, y0), (x1, y0), (x0, y1), (x1, y1)):
        t = 0.0 if l2 == 0.0 else min(max(((cx - ax) * dx + (cy - ay) * dy) / l2, 0.0), 1.0)
        ex = ax + t * dx - cx
        ey = ay + t * dy - cy
        best = min(best, ex * ex + ey * ey)
    return best


@njit(cache=True, nogil=True, parallel=True)
def _clear_heights(a, b, r, gx0, gy0, cell, ncx, ncy, czmax):
    """Per segment ``a[i] -> b[i]``: the largest ``zmax_C + sqrt(r^2 - d^2)`` over the grid
    cells ``C`` whose distance ``d`` to the segment is at most ``r`` (``-inf``: none)."""
    m = a.shape[0]
    out = np.full(m, -np.inf)
    r2 = r * r
    for s in prange(m):
        ax, ay, bx, by = a[s, 0], a[s, 1], b[s, 0], b[s, 1]
        i0 = min(max(int(math.floor((min(ax, bx) - r - gx0) / cell)), 0), ncx - 1)
        i1 = min(max(int(math.floor((max(ax, bx) + r - gx0) / cell)), 0), ncx - 1)
        j0 = min(max(int(math.floor((min(ay, by) - r - gy0) / cell)), 0), ncy - 1)
        j1 = min(max(int(math.floor((max(ay, by) + r - gy0) / cell)), 0), ncy - 1)
        best = -np.inf
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                z = czmax[j * ncx + i]
                if z + r <= best:
                    continue
                d2 = _seg_box_dist2(ax, ay, bx, by, gx0 + i * cell, gy0 + j * cell, gx0 + (i + 1) * cell,
                                    gy0 + (j + 1) * cell)
                if d2 <= r2:
                    best = max(best, z + math.sqrt(r2 - d2))
        out[s] = best
    return out


@njit(cache=True, nogil=True, parallel=True)
def _tables(V, F, r):
    """Per-triangle tables ``T (m, 28)`` (vertices, unit up normal, 1 / det_xy, the edges: :data:`_E0`) and
    ``B (m, 11)`` (XY box, top z, plane-bound coefficients, centroid)."""
    m = F.shape[0]
    T = np.empty((m, _NT), dtype=np.float64)
    B = np.empty((m, 11), dtype=np.float64)
    for t in prange(m):
        for v in range(3):
            for q in range(3):
                T[t, 3 * v + q] = V[F[t, v], q]
        x0, y0, z0 = T[t, 0], T[t, 1], T[t, 2]
        e1x, e1y, e1z = T[t, 3] - x0, T[t, 4] - y0, T[t, 5] - z0
        e2x, e2y, e2z = T[t, 6] - x0, T[t, 7] - y0, T[t, 8] - z0
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        nn = math.sqrt(nx * nx + ny * ny + nz * nz)
        if nn > 0.0:
            nx /= nn
            ny /= nn
            nz /= nn
        else:
            nx = 0.0
            ny = 0.0
            nz = 0.0
        if nz < 0.0:  # two-sided: the ball comes from above
            nx = -nx
            ny = -ny
            nz = -nz
        det = e1x * e2y - e1y * e2x
        idet = 1.0 / det if det != 0.0 else 0.0
        if nz <= _VERTICAL_NZ or idet == 0.0:
            nz = 0.0  # facet test off; edges and vertices still apply
        T[t, _NX] = nx
        T[t, _NY] = ny
        T[t, _NZ] = nz
        T[t, _IDET] = idet
        _edge_columns(T, t, 0, T[t, 3], T[t, 4], T[t, 5], T[t, 6], T[t, 7], T[t, 8])
        _edge_columns(T, t, 1, T[t, 6], T[t, 7], T[t, 8], x0, y0, z0)
        _edge_columns(T, t, 2, x0, y0, z0, T[t, 3], T[t, 4], T[t, 5])
        B[t, 0] = min(x0, T[t, 3], T[t, 6])
        B[t, 1] = min(y0, T[t, 4], T[t, 7])
        B[t, 2] = max(x0, T[t, 3], T[t, 6])
        B[t, 3] = max(y0, T[t, 4], T[t, 7])
        B[t, 4] = max(z0, T[t, 5], T[t, 8])
        # plane bound: the ball on the facet's plane sits at a x + b y + c + r / n_z
        if nz < _BOUND_NZ:
            B[t, 5] = 0.0
            B[t, 6] = 0.0
            B[t, 7] = np.inf
        else:
            B[t, 5] = -nx / nz
            B[t, 6] = -ny / nz
            B[t, 7] = z0 + (nx * x0 + ny * y0) / nz + r / nz
        B[t, 8] = (x0 + T[t, 3] + T[t, 6]) / 3.0
        B[t, 9] = (y0 + T[t, 4] + T[t, 7]) / 3.0
        B[t, 10] = (z0 + T[t, 5] + T[t, 8]) / 3.0
    return T, B


@njit(cache=True, nogil=True)
def _build_grid(T, B, r, gx0, gy0, cell, ncx, ncy):
    """CSR lists of triangles per cell (by XY box overlap, in triangle order) and the
    cells' highest top; :func:`_grid_tables` continues once each cell's list is sorted."""
    m = B.shape[0]
    counts = np.zeros(ncx * ncy + 1, dtype=np.int64)
    for t in range(m):
        i0 = min(max(int((B[t, 0] - gx0) / cell), 0), ncx - 1)
        i1 = min(max(int((B[t, 2] - gx0) / cell), 0), ncx - 1)
        j0 = min(max(int((B[t, 1] - gy0) / cell), 0), ncy - 1)
        j1 = min(max(int((B[t, 3] - gy0) / cell), 0), ncy - 1)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                counts[j * ncx + i + 1] += 1
    cstart = np.cumsum(counts)
    fill = cstart[:-1].copy()
    ctri = np.empty(cstart[-1], dtype=np.int32)
    czmax = np.full(ncx * ncy, -np.inf)
    for t in range(m):
        i0 = min(max(int((B[t, 0] - gx0) / cell), 0), ncx - 1)
        i1 = min(max(int((B[t, 2] - gx0) / cell), 0), ncx - 1)
        j0 = min(max(int((B[t, 1] - gy0) / cell), 0), ncy - 1)
        j1 = min(max(int((B[t, 3] - gy0) / cell), 0), ncy - 1)
        for j in range(j0, j1 + 1):
            for i in range(i0, i1 + 1):
                c = j * ncx + i
                ctri[fill[c]] = t
                fill[c] += 1
                if B[t, 4] > czmax[c]:
                    czmax[c] = B[t, 4]
    return cstart, ctri, czmax


@njit(cache=True, nogil=True)
def _grid_tables(T, B, r, cstart, ctri, ncx, ncy):
    """The entries' XY boxes and tops, and each cell's bounding plane (see :func:`_build_grid`)."""
    # the XY box and top of every entry, in entry order: the scan reads memory in sequence
    EB = np.empty((ctri.shape[0], 5), dtype=np.float64)
    for e in range(ctri.shape[0]):
        for q in range(5):
            EB[e, q] = B[ctri[e], q]
    # a plane above every triangle of the cell, with the slope of its mean up-normal
    CP = np.zeros((ncx * ncy, 6), dtype=np.float64)
    for c in range(ncx * ncy):
        sx = 0.0
        sy = 0.0
        sz = 0.0
        for e in range(cstart[c], cstart[c + 1]):
            t = ctri[e]
            sx += T[t, _NX]
            sy += T[t, _NY]
            sz += T[t, _NZ]
        if sz <= _BOUND_NZ * math.sqrt(sx * sx + sy * sy + sz * sz) or cstart[c] == cstart[c + 1]:
            CP[c, 2] = np.inf  # no plane: the bound is off
            continue
        gx = -sx / sz
        gy = -sy / sz
        top = -np.inf
        for e in range(cstart[c], cstart[c + 1]):
            t = ctri[e]
            for v in range(3):
                top = max(top, T[t, 3 * v + 2] - gx * T[t, 3 * v] - gy * T[t, 3 * v + 1])
        CP[c, 0] = gx
        CP[c, 1] = gy
        CP[c, 2] = top
        k = math.sqrt(1.0 + gx * gx + gy * gy)
        CP[c, 3] = r * gx / k
        CP[c, 4] = r * gy / k
        CP[c, 5] = r * k
    return EB, CP


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------


class BallCutter:
    """Ball-end cutter of radius ``radius`` against a triangle mesh: drop-cutter and CC -> CL.

    The spatial index is built once; every query is numba-parallel over points.

    Parameters
    ----------
    V : (n, 3) float64
        Vertex positions, mm.
    F : (m, 3) int64
        Triangles (orientation does not matter: triangles are two-sided).
    radius : float
        Ball radius ``r``, mm.
    cell : float, optional
        Grid cell size (mm); default ``max(r / 4, median triangle XY extent / 2)``.

    Raises
    ------
    MeshError
        Bad vertex or face arrays (shape, non-finite values, indices out of range, no faces).
    PlanningError
        Radius not positive and finite.

    Notes
    -----
    Drop-cutter as in OpenCAMLib's ``BallCutter`` (facet, edge and vertex tests); agreement
    with ``ocl.BatchDropCutter`` is measured in ``benchmarks/bench_cutter.py``.
    """

    def __init__(self, V, F, radius: float, cell: float | None = None):
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F)
        if V.ndim != 2 or V.shape[1] != 3:
            raise MeshError(f"cutter: vertices must be (n, 3), got shape {V.shape}")
        if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0:
            raise MeshError(f"cutter: faces must be (m, 3) with m >= 1, got shape {F.shape}")
        if not np.issubdtype(F.dtype, np.integer):
            raise MeshError(f"cutter: faces must be integers, got dtype {F.dtype}")
        bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
        if bad.size:
            raise MeshError(f"cutter: {bad.size} vertices have non-finite coordinates (first: vertex {bad[0]})")
        F = F.astype(np.int64)
        out = np.flatnonzero(((F < 0) | (F >= V.shape[0])).any(axis=1))
        if out.size:
            raise MeshError(f"cutter: face {out[0]} has a vertex index out of range "
                            f"[0, {V.shape[0]}): {F[out[0]].tolist()}")
        radius = float(radius)
        if not (math.isfinite(radius) and radius > 0):
            raise PlanningError(f"cutter: ball radius must be positive and finite, got {radius}")
        self.radius = radius

        T, B = _tables(V, F, radius)
        ext = np.maximum(B[:, 2] - B[:, 0], B[:, 3] - B[:, 1])
        if cell is None:
            cell = max(radius / 4.0, 0.5 * float(np.median(ext)))
        cell = float(cell)
        if not (math.isfinite(cell) and cell > 0):
            raise PlanningError(f"cutter: grid cell size must be positive and finite, got {cell}")
        gmin = B[:, :2].min(axis=0)
        gmax = B[:, 2:4].max(axis=0)
        span = np.maximum(gmax - gmin, cell)
        while np.prod(np.ceil(span / cell) + 1) > _MAX_CELLS:
            cell *= 1.5
        ncx, ncy = (int(v) for v in np.ceil(span / cell) + 1)
        # spatial reorder so that a cell's triangles sit close together in memory
        key = (np.floor((B[:, 9] - gmin[1]) / cell).astype(np.int64) * ncx
               + np.floor((B[:, 8] - gmin[0]) / cell).astype(np.int64))
        order = np.argsort(key, kind="stable")
        T = T[order]
        B = B[order]
        self._T = np.ascontiguousarray(T)  # (m, 28): vertices, unit up normal, 1 / det_xy, edges
        self._B = np.ascontiguousarray(B)  # (m, 11): xy box, top z, plane-bound coefficients, centroid
        self._order = order
        self._rank = np.empty_like(order)  # input face -> its row in the reordered tables
        self._rank[order] = np.arange(len(order))
        self._grid = (float(gmin[0]), float(gmin[1]), cell, ncx, ncy)
        cstart, ctri, czmax = _build_grid(self._T, self._B, radius, gmin[0], gmin[1], cell, ncx, ncy)
        # highest triangles first in each cell, so that a cell's scan can stop early (one
        # stable sort of all entries by cell, then top: ties keep the triangle order)
        cells = np.repeat(np.arange(ncx * ncy), np.diff(cstart))
        ctri = np.ascontiguousarray(ctri[np.lexsort((-self._B[ctri, 4], cells))])
        self._cstart, self._ctri, self._czmax = cstart, ctri, czmax
        self._EB, self._CP = _grid_tables(self._T, self._B, radius, cstart, ctri, ncx, ncy)
        w = int(math.ceil(2 * radius / cell)) + 2
        self._maxwin = w * w
        log.debug("BallCutter: %d triangles, grid %d x %d cells of %.3g mm, %d entries",
                  len(T), ncx, ncy, cell, len(self._ctri))

    # ------------------------------------------------------------------ drop-cutter
    def drop(self, xy) -> np.ndarray:
        """Drop-cutter: lowest ball-centre height touching, not intersecting, the mesh.

        Parameters
        ----------
        xy : (k, 2) float64
            Query points (ball-centre XY), mm.

        Returns
        -------
        z_center : (k,) float64
            Ball-centre heights; ``-inf`` where the ball (XY distance ``<= r``) touches no
            triangle.

        Raises
        ------
        PlanningError
            ``xy`` is not ``(k, 2)`` or holds non-finite values.
        """
        xy = _as_points(xy, 2, "xy")
        if xy.shape[0] == 0:
            return np.empty(0, dtype=np.float64)
        return self._drop(xy, np.full(xy.shape[0], -np.inf))[0]

    def _drop(self, xy, floor, wa=None, wb=None, first=False):
        """``(max(drop, floor), contact triangle)``: the triangle is -1 where no triangle
        rises above ``floor``.

        A finite floor prunes more cells and triangles from the start; where a triangle is
        returned the height is the exact drop height. ``wa``, ``wb`` (per point, -1: none)
        are triangles tried first, as hints: they change the speed, not the result. With
        ``first`` the search at a point stops at the first triangle rising above its floor
        (only whether one does is then exact: see :func:`_drop_many`).
        """
        gx0, gy0, cell, ncx, ncy = self._grid
        wa = self._hints(wa, len(xy))  # checked: the kernel indexes with them
        wb = self._hints(wb, len(xy))
        return _drop_many(np.ascontiguousarray(xy, dtype=np.float64), self.radius, self._T, self._B,
                          gx0, gy0, cell, ncx, ncy, self._cstart, self._ctri, self._czmax, self._EB, self._CP,
                          self._maxwin, np.ascontiguousarray(floor, dtype=np.float64), wa, wb, bool(first))

    def _kernel_args(self) -> tuple:
        """The index as the compiled kernels take it (after ``r``): for other stages' kernels
        that call :func:`_drop_point` (:mod:`conformill.pencil`)."""
        gx0, gy0, cell, ncx, ncy = self._grid
        return (self._T, self._B, gx0, gy0, cell, ncx, ncy, self._cstart, self._ctri, self._czmax, self._EB,
                self._CP, self._maxwin)

    def _tri_index(self, faces) -> np.ndarray:
        """The kernels' triangle index of input faces ``faces`` (the index is spatially reordered)."""
        faces = np.asarray(faces, dtype=np.int64)
        if faces.size and (faces.min() < 0 or faces.max() >= len(self._rank)):
            raise PlanningError(f"cutter: face index out of range [0, {len(self._rank)})")
        return np.ascontiguousarray(self._rank[faces], dtype=np.int64)

    def clear_height(self, a, b, clearance: float = 0.0) -> np.ndarray:
        """A centre height at and above which the ball touches nothing along each XY segment.

        An upper bound of the drop surface over the segment ``a -> b``, with no drop: a
        ball centred at ``p`` can touch only the triangles listed in the grid cells within
        ``r`` of ``p``, each no higher than its cell's highest top ``zmax_C``, so the drop
        height at ``p`` is at most ``zmax_C + sqrt(r^2 - dist(p, C)^2)`` over those cells;
        over the segment, at most ``zmax_C + sqrt(r^2 - dist(segment, C)^2)``. A straight
        move at this height or above it, from over ``a`` to over ``b``, cannot cut the part.

        Parameters
        ----------
        a, b : (k, 2) float64
            Segment ends (ball-centre XY), mm.
        clearance : float
            Keep the ball this far (mm) from the part: the bound for a ball of radius
            ``r + clearance``.

        Returns
        -------
        z : (k,) float64
            ``-inf`` where no grid cell holding triangles is within reach of the segment
            (a finite value does not mean a triangle is).
        """
        a = _as_points(a, 2, "a")
        b = _as_points(b, 2, "b")
        if a.shape != b.shape:
            raise PlanningError(f"cutter: a and b must have the same shape, got {a.shape} and {b.shape}")
        clearance = float(clearance)
        if not (math.isfinite(clearance) and clearance >= 0):
            raise PlanningError(f"cutter: clearance must be >= 0, got {clearance}")
        gx0, gy0, cell, ncx, ncy = self._grid
        return _clear_heights(a, b, self.radius + clearance, gx0, gy0, cell, ncx, ncy, self._czmax)

    # ------------------------------------------------------------------ CC -> CL
    def cl_from_cc(self, cc, n, contacts: bool = False):
        """Ball centres for cutter-contact points, lifted so that the ball cannot gouge.

        The ideal centre is ``cc + r n`` (the ball touches the surface at ``cc``); its XY is
        kept and its Z replaced by :meth:`drop` there. Since the ball at ``cc + r n``
        touches the mesh at ``cc`` (for ``n_z >= 0``), ``drop >= (cc + r n)_z`` and the lift
        is non-negative up to rounding; it is zero where the surface near ``cc`` is smooth
        on the scale of the ball and ``n`` is the true normal.

        Parameters
        ----------
        cc : (k, 3) float64
            Cutter-contact points on the mesh, mm.
        n : (k, 3) float64
            Normals towards the tool (normalised here).
        contacts : bool
            Also return the triangle each centre rests on (hints for :meth:`settle`).

        Returns
        -------
        center : (k, 3) float64
            Ball centres.
        lift : (k,) float64
            ``drop - (cc + r n)_z``, mm: large values mean the normal was poor, the surface
            curves tighter than the ball (concave, radius < r) or ``cc`` is not reachable.
        tri : (k,) int64
            Only with ``contacts``: the cutter's own index of the triangle each centre
            rests on (meaningful only to this cutter).

        Raises
        ------
        PlanningError
            Shapes differ, values are not finite, a normal has zero length, or a centre
            touches no triangle (the CC point is not on the mesh).
        """
        cc = _as_points(cc, 3, "cc")
        n = _as_points(n, 3, "n")
        if cc.shape != n.shape:
            raise PlanningError(f"cutter: cc and n must have the same shape, got {cc.shape} and {n.shape}")
        ln = np.linalg.norm(n, axis=1)
        zero = np.flatnonzero(ln < 1e-12)
        if zero.size:
            raise PlanningError(f"cutter: {zero.size} normals have zero length (first: point {zero[0]})")
        ideal = cc + self.radius * (n / ln[:, None])
        # The ball at the ideal centre touches the mesh at cc, so the drop height is at
        # least ideal_z (up to rounding): a floor a little below it prunes most of the
        # search. Points where nothing rose above the floor get a plain drop.
        z, tri = self._drop(ideal[:, :2], ideal[:, 2] - _FLOOR_SLACK)
        miss = np.flatnonzero(tri < 0)
        if miss.size:
            z[miss], tri[miss] = self._drop(ideal[miss, :2], np.full(miss.size, -np.inf))
        miss = np.flatnonzero(~np.isfinite(z))
        if miss.size:
            # A horizontal normal (an outward wall at the part's rim) puts the ideal centre
            # exactly r from ``cc`` in XY, where rounding can leave the ball touching nothing.
            # Its centre moves towards ``cc`` by a relative _RIM_PULL: ``cc`` is then within
            # reach, and the centre is an exact drop at its own XY like every other. Its lift
            # then includes the ball's rise at the pull, about r sqrt(2e-6) (5.7 um at r = 4).
            ideal[miss, :2] = cc[miss, :2] + (1.0 - _RIM_PULL) * (ideal[miss, :2] - cc[miss, :2])
            z[miss], tri[miss] = self._drop(ideal[miss, :2], np.full(miss.size, -np.inf))
            miss = miss[~np.isfinite(z[miss])]
        if miss.size:
            i = miss[0]
            raise PlanningError(
                f"cutter: {miss.size} cutter-contact points are not within the ball's reach of the mesh "
                f"(first: point {i}, cc = {cc[i].tolist()})")
        center = ideal.copy()
        center[:, 2] = z
        if contacts:
            return center, z - ideal[:, 2], tri
        return center, z - ideal[:, 2]

    # ------------------------------------------------------------------ chords
    def refine(self, centers, tol: float, max_points: int = 256, max_depth: int = 16):
        """Insert drop-cutter points where a straight centre move could cut into the part.

        A linear move between two safe ball centres can still cut into the part where the
        drop surface ``D`` (the highest safe centre height) bulges above the chord: convex
        regions and creases. Every move is checked exactly against the bound below, by
        bisection; where a chord point lies more than ``tol / 2`` below ``D``, the worst
        such point, lifted onto ``D``, is inserted, and the two new moves are checked again
        with the drops already made over them (:func:`_refine_move`). A move that would
        need more than ``max_points`` points is instead halved until no piece is longer
        than ``L_safe``, with dropped ends, which the bound proves safe.

        The bound. A chord point ``q`` that lies ``d >= 0`` below the drop height at its
        XY is at least ``r - d`` from every point ``c`` of the mesh (the ball at
        ``q + d Z`` touches nothing). For a piece ``q0 q1`` of the chord of length ``l``
        with such depths ``d0, d1``, the point ``p = (1 - t) q0 + t q1`` satisfies the
        identity ``|p - c|^2 = (1 - t)|q0 - c|^2 + t|q1 - c|^2 - t(1 - t) l^2``, so::

            |p - c|^2 >= f(t) = (1 - t)(r - d0)^2 + t (r - d1)^2 - t (1 - t) l^2,

        and the ball at ``p`` cuts at most ``r - sqrt(min_t f)`` into the part. A piece
        whose bound is within ``tol / 2`` is accepted; otherwise its midpoint is dropped
        and both halves are checked (``f`` tends to ``(r - max(d0, d1))^2`` as ``l``
        shrinks, so the bisection ends). Between two points on ``D`` a move no longer than
        ``L_safe = 2 sqrt(r^2 - (r - tol/2)^2)`` passes at once. Unlike sampling the chord,
        the test misses nothing between the points it drops, whatever the curvature of
        ``D``; it can only insert a point that was not needed.

        Parameters
        ----------
        centers : (k, 3) float64
            Ball centres of one continuous pass, on or above the drop surface.
        tol : float
            Allowed cut depth of the centre moves into the part is ``tol / 2``, mm.
        max_points : int
            Most points inserted into one move (0: every move is halved into
            ``L_safe`` pieces at once).
        max_depth : int
            Bisection levels below the first pieces (no longer than ``L_safe``); a piece
            still undecided after them counts as violating at its deeper end.

        Returns
        -------
        centers : (k', 3) float64
            The input points (unchanged, same order) with the inserted drop points.

        Raises
        ------
        PlanningError
            Bad shapes, non-finite values, ``tol`` not positive, ``max_points`` negative,
            ``max_depth`` outside [0, 40].
        """
        P = _as_points(centers, 3, "centers")
        tol, max_points, max_depth = _refine_args(tol, max_points, max_depth)
        if len(P) < 2:
            return P.copy()
        # moves to check: all but the (nearly) vertical ones (a vertical move between two
        # safe centres stays above the drop surface)
        d = np.diff(P, axis=0)
        return self._refine(P, np.hypot(d[:, 0], d[:, 1]) > 1e-9, tol, max_points, max_depth,
                            np.zeros(0, dtype=np.int64))[0]

    def refine_pieces(self, pieces, tol: float, max_points: int = 256, max_depth: int = 16) -> list:
        """:meth:`refine` on each polyline of ``pieces``, in one batch of kernel calls (the
        same points as one call per piece; see :meth:`settle_pieces`)."""
        tol, max_points, max_depth = _refine_args(tol, max_points, max_depth)
        if not pieces:
            return []
        P, check, starts = _stack_pieces(pieces)
        P, starts = self._refine(P, check, tol, max_points, max_depth, starts)
        return np.split(P, starts[1:])

    def _refine(self, P, check, tol, max_points, max_depth, track):
        """:meth:`refine` on the moves flagged in ``check``; ``track``: indices of input
        points whose positions in the output are returned too."""
        if len(P) < 2:
            return P.copy(), track
        r = self.radius
        thresh = min(0.5 * tol, r)
        floor2 = (r - thresh) ** 2
        seg = np.flatnonzero(check)
        undecided = seg
        if seg.size and max_points > 0:
            rows, ts, zs, cnt = self._refine_moves(P, seg, thresh, floor2, max_depth, min(_FIRST_ROOM, max_points))
            over = np.flatnonzero(cnt < 0)
            if over.size and max_points > _FIRST_ROOM:
                r2, t2, z2, c2 = self._refine_moves(P, seg[over], thresh, floor2, max_depth, max_points)
                cnt[over] = c2
                rows = np.concatenate([rows, r2])
                order = np.argsort(rows, kind="stable")  # a move's points come from one call, in order
                rows, ts, zs = rows[order], np.concatenate([ts, t2])[order], np.concatenate([zs, z2])[order]
            undecided = seg[cnt < 0]
            if rows.size:
                newpts = P[rows] + ts[:, None] * (P[rows + 1] - P[rows])
                newpts[:, 2] = zs
                undecided = undecided + np.searchsorted(rows, undecided, side="left")
                P, _, track = _insert(P, rows, newpts, track)
        if undecided.size:
            log.warning("cutter.refine: %d moves still unchecked within %d inserted points each; halved to "
                        "L_safe pieces", undecided.size, max_points)
            P, track = self._split_safe(P, undecided, thresh, track)
        return P, track

    def _refine_moves(self, P, seg, thresh, floor2, max_depth, room):
        """:func:`_refine_moves` on moves ``seg`` with ``room`` points each: ``(rows, t, z,
        count)``, the points to insert after rows ``rows`` (sorted) at chord parameters
        ``t`` with heights ``z``, and per move their count (-1: undecided)."""
        gx0, gy0, cell, ncx, ncy = self._grid
        cnt, T, Z = _refine_moves(P, seg.astype(np.int64), self.radius, thresh, floor2, self._l_safe(thresh),
                                  max_depth, self._T, self._B, gx0, gy0, cell, ncx, ncy, self._cstart, self._ctri,
                                  self._czmax, self._EB, self._CP, self._maxwin, int(room))
        ok = cnt > 0
        keep = np.arange(T.shape[1])[None, :] < cnt[ok, None]
        return np.repeat(seg[ok], cnt[ok]), T[ok][keep], Z[ok][keep], cnt

    def settle(self, centers, tol: float, steps: int = 3, max_iter: int = 4, contacts=None) -> tuple:
        """Insert drop-cutter points where a straight centre move floats above the drop surface.

        The other side of :meth:`refine`. Where the drop surface ``D`` has a valley along a
        move (a crease of ``D`` where the ball sits wedged in a groove narrower than itself,
        or a concave bend), the chord between two centres on ``D`` runs above ``D`` and the
        ball leaves material that no scallop formula accounts for: at a groove it is the
        material at the groove's rims, where only the wedged ball reaches.

        Each move is tested at its midpoint: a compiled test that stops at the first
        triangle lifting the ball there to within ``tol / 2`` of the chord. On a move whose
        midpoint floats more, the highest float is searched by tangent steps. The slope of
        ``D`` at a centre follows from its contact: ``D``'s normal there is the unit vector
        from the contact point to the centre. The tangent lines of ``D`` at the two ends
        of the move meet where a crease with straight sides lies; one drop is made there.
        Where it lands on the lines, the crease is found. Otherwise the point replaces the
        end of the bracket on its side (the side where ``D`` rises faster than the chord
        lies beyond the highest float), for at most ``steps`` drops. A crease between plane
        sides (a V-groove) is thus found exactly in one drop, wherever it lies on the move.
        The highest-floating point found is lowered onto ``D`` and inserted (the midpoint,
        dropped, where the steps found nothing floating more than ``tol / 2``), and the two
        new moves are tested again, for at most ``max_iter`` rounds.

        For a crease with straight sides the float at the midpoint is at least half the
        largest float, so every move that floats more than ``tol`` there is caught; a
        narrower dip between the ends can be missed, and a curved valley may need more
        rounds than ``max_iter`` (those moves are counted, not resolved).

        Parameters
        ----------
        centers : (k, 3) float64
            Ball centres of one continuous pass, on or above the drop surface.
        tol : float
            Allowed float of a move above ``D``, mm.
        steps : int
            Drops of the tangent search per floating move and round.
        max_iter : int
            Rounds of insertion.
        contacts : (k,) int, optional
            The triangle each centre rests on, as :meth:`cl_from_cc` returns it (-1:
            unknown). Checked before use (a triangle that does not hold the centre up is
            replaced by the one found by a drop), so they save drops; the result
            depends on them only where several triangles hold a centre up at once.

        Returns
        -------
        centers : (k', 3) float64
            The input points (unchanged, same order) with the inserted drop points (on
            ``D``; run :meth:`refine` afterwards, since a lowered point can make a
            neighbouring move cut into the part).
        inserted : int
            Points inserted.
        unresolved : int
            Moves made in the last round and not tested again (0 when the rounds ended
            before ``max_iter``).
        contacts : (k',) int64
            Only when ``contacts`` is given: hints for the output points, to pass on to
            the next call (the input hints, those found wrong at the ends of a floating
            move replaced by the exact contact, and the exact contact of every inserted
            point).

        Raises
        ------
        PlanningError
            Bad shapes, non-finite values, ``tol`` not positive, ``steps < 1``,
            ``contacts`` not one integer per centre.
        """
        P = _as_points(centers, 3, "centers")
        tol, steps = _settle_args(tol, steps)
        want = contacts is not None
        tri = self._hints(contacts, len(P))
        if len(P) < 2:
            return (P.copy(), 0, 0, tri) if want else (P.copy(), 0, 0)
        d = np.diff(P, axis=0)
        P, tri, inserted, left, _ = self._settle(P, tri, np.hypot(d[:, 0], d[:, 1]) > 1e-9, tol, steps, max_iter,
                                                 np.zeros(0, dtype=np.int64))
        return (P, inserted, left, tri) if want else (P, inserted, left)

    def settle_pieces(self, pieces, tol: float, steps: int = 3, max_iter: int = 4, contacts=None) -> tuple:
        """:meth:`settle` on each polyline of ``pieces``, in one batch of kernel calls.

        The same points as one :meth:`settle` call per piece (a move is settled on its
        own; the step from one piece's end to the next piece's start is no move), without
        the Python and kernel overhead of a call per piece: the pencil stage settles
        thousands of short chains (igea: 2800 chains in 0.47 s one by one).

        Parameters
        ----------
        pieces : list of (k_i, 3) float64
        tol, steps, max_iter
            As for :meth:`settle`.
        contacts : list of (k_i,) int, optional
            Contact hints per piece, as for :meth:`settle`.

        Returns
        -------
        pieces : list of (k_i', 3) float64
        inserted, unresolved : int
            Summed over the pieces.
        contacts : list of (k_i',) int64
            Only when ``contacts`` is given: the hints for the output points.
        """
        tol, steps = _settle_args(tol, steps)
        want = contacts is not None
        if not pieces:
            return ([], 0, 0, []) if want else ([], 0, 0)
        P, check, starts = _stack_pieces(pieces)
        tri = self._hints(np.concatenate([np.asarray(c) for c in contacts]) if want else None, len(P))
        P, tri, inserted, left, starts = self._settle(P, tri, check, tol, steps, max_iter, starts)
        out = np.split(P, starts[1:])
        if want:
            return out, inserted, left, np.split(tri, starts[1:])
        return out, inserted, left

    def _settle(self, P, tri, check, tol, steps, max_iter, track):
        """The rounds of :meth:`settle` on the moves flagged in ``check``; ``track``: indices
        of input points whose positions in the output are returned too."""
        if len(P) < 2:
            return P.copy(), tri, 0, 0, track
        half = 0.5 * tol
        inserted = 0
        for _ in range(max_iter):
            seg = np.flatnonzero(check)
            if seg.size == 0:
                break
            mid = 0.5 * (P[seg] + P[seg + 1])
            seg = seg[~self._reaches(mid[:, :2], mid[:, 2] - half, tri[seg], tri[seg + 1])]
            if seg.size == 0:
                break
            gx0, gy0, cell, ncx, ncy = self._grid
            t, z, zt, lift, c0, c1 = _highest_floats(P, seg, tri, steps, 0.01 * tol, self.radius, self._T, self._B,
                                                     gx0, gy0, cell, ncx, ncy, self._cstart, self._ctri,
                                                     self._czmax, self._EB, self._CP, self._maxwin)
            tri[seg] = np.where(c0 >= 0, c0, tri[seg])  # hints found wrong, replaced
            tri[seg + 1] = np.where(c1 >= 0, c1, tri[seg + 1])
            v = P[seg + 1] - P[seg]
            # the midpoint is known to float more than tol / 2: dropped where the steps
            # found nothing higher
            low = np.flatnonzero(~(lift > half))
            if low.size:
                q = P[seg[low]] + 0.5 * v[low]
                zm, tm = self._drop(q[:, :2], np.full(low.size, -np.inf), tri[seg[low]])
                lm = q[:, 2] - zm
                up = np.isfinite(lm) & (lm > lift[low])
                i = low[up]
                t[i], z[i], zt[i], lift[i] = 0.5, zm[up], tm[up], lm[up]
            keep = lift > half
            if not keep.any():
                break
            new = P[seg] + t[:, None] * v
            new[:, 2] = z
            after = seg[keep]
            P, check, track = _insert(P, after, new[keep], track)
            tri = np.insert(tri, after + 1, zt[keep])
            d = np.diff(P, axis=0)
            check &= np.hypot(d[:, 0], d[:, 1]) > 1e-9
            inserted += int(keep.sum())
        else:
            return P, tri, inserted, int(check.sum()), track
        return P, tri, inserted, 0, track

    def _hints(self, contacts, k):
        """Contact-triangle hints as a new int64 ``(k,)`` array (-1 for none), checked:
        the kernels index the triangle table with them."""
        if contacts is None:
            return np.full(k, -1, dtype=np.int64)
        c = np.asarray(contacts)
        if k == 0 and c.shape == (0,):
            return np.empty(0, dtype=np.int64)
        if c.shape != (k,) or not np.issubdtype(c.dtype, np.integer):
            raise PlanningError(f"cutter: contacts must be {k} integers (one per centre), got shape {c.shape} "
                                f"and dtype {c.dtype}")
        bad = np.flatnonzero((c < -1) | (c >= len(self._T)))
        if bad.size:
            raise PlanningError(f"cutter: {bad.size} contacts are not triangles of this cutter "
                                f"(first: centre {bad[0]}, {int(c[bad[0]])})")
        return np.array(c, dtype=np.int64)

    def _reaches(self, xy, z, wa=None, wb=None):
        """Whether the drop height at ``xy`` is at least ``z`` (bool per point; ties within
        2e-9 mm either way): a drop with the floor just below ``z`` that stops at the
        first triangle rising above it. ``wa``, ``wb``: triangles tried first (hints, -1:
        none; the contacts of a move's ends)."""
        z = np.asarray(z, dtype=np.float64) - 2.0 * _PRUNE_SLACK
        return self._drop(xy, z, wa, wb, first=True)[1] >= 0

    def _l_safe(self, thresh):
        """``L_safe = 2 sqrt(r^2 - (r - thresh)^2)``, without cancellation: the longest move
        between two points on the drop surface that cannot cut ``thresh`` into the part."""
        return 2.0 * math.sqrt(thresh * (2.0 * self.radius - thresh))

    def _split_safe(self, P, seg, thresh, track, max_levels: int = 60):
        """Halve moves ``seg`` (sorted) until every piece is at most ``L_safe`` long (3D).

        The midpoints are lifted onto the drop surface where the chord lies below it, so
        every piece has its ends on or above the drop surface; such a piece no longer than
        ``L_safe`` cannot cut more than ``thresh`` into the part (the bound of
        :meth:`refine` with ``d0 = d1 = 0``). Moves with (almost) no XY extent are not
        split, as in :meth:`refine`.

        Each move is halved on its own (its pieces do not depend on the other moves), so
        the levels run on the moves' own points and the pieces go into ``P`` once: a move
        down a wall of the drop surface (a near-vertical jump, halved until its XY extent
        vanishes: about 30 levels) no longer costs 30 passes over the whole polyline
        (igea's pencil passes, 52k points: 0.09-0.12 s for one to seven such moves).
        """
        l_safe = self._l_safe(thresh)
        seg = np.asarray(seg, dtype=np.int64)
        m = len(seg)
        if m == 0:
            return P, track
        # the moves side by side: each its two ends, the step from one to the next unchecked
        Q = np.empty((2 * m, 3), dtype=np.float64)
        Q[0::2], Q[1::2] = P[seg], P[seg + 1]
        check = np.zeros(2 * m - 1, dtype=bool)
        check[0::2] = True
        ends = np.arange(0, 2 * m, 2, dtype=np.int64)  # each move's first point in Q
        done = False
        for _ in range(max_levels):
            d = np.diff(Q, axis=0)
            long_ = check & (np.linalg.norm(d, axis=1) > l_safe) & (np.hypot(d[:, 0], d[:, 1]) > 1e-9)
            if not long_.any():
                done = True
                break
            s = np.flatnonzero(long_)
            mid = 0.5 * (Q[s] + Q[s + 1])
            mid[:, 2] = np.maximum(self.drop(mid[:, :2]), mid[:, 2])
            Q, check, ends = _insert(Q, s, mid, ends)
        if not done:
            log.warning("cutter.refine: %d moves still longer than L_safe after %d halvings",
                        int(long_.sum()), max_levels)
        # the points each move gained, in order, go in after its first point
        last = np.append(ends[1:], len(Q)) - 1  # each move's last point in Q
        inner = np.ones(len(Q), dtype=bool)
        inner[ends] = False
        inner[last] = False
        count = last - ends - 1
        if not count.any():
            return P, track
        P, _, track = _insert(P, np.repeat(seg, count), Q[inner], track)
        return P, track

    # ------------------------------------------------------------------ tool tip
    def tip(self, centers) -> np.ndarray:
        """Tool-tip points (the programmed point): ``centers - r Z``, ``(k, 3)``."""
        P = _as_points(centers, 3, "centers")
        out = P.copy()
        out[:, 2] -= self.radius
        return out


def _settle_args(tol, steps):
    """``tol`` and ``steps`` of :meth:`BallCutter.settle`, checked."""
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0):
        raise PlanningError(f"cutter: settle tolerance must be positive, got {tol}")
    steps = int(steps)
    if steps < 1:
        raise PlanningError(f"cutter: settle needs at least one step, got {steps}")
    return tol, steps


def _refine_args(tol, max_points, max_depth) -> tuple:
    """``tol``, ``max_points`` and ``max_depth`` of :meth:`BallCutter.refine`, checked
    (beyond ``_MAX_DEPTH`` levels the halved pieces' ends would no longer be distinct
    floats)."""
    tol = float(tol)
    if not (math.isfinite(tol) and tol > 0):
        raise PlanningError(f"cutter: refine tolerance must be positive, got {tol}")
    if int(max_points) != max_points or max_points < 0:
        raise PlanningError(f"cutter: refine max_points must be a whole number >= 0, got {max_points}")
    if int(max_depth) != max_depth or not 0 <= max_depth <= _MAX_DEPTH:
        raise PlanningError(f"cutter: refine max_depth must be a whole number in [0, {_MAX_DEPTH}], got {max_depth}")
    return tol, int(max_points), int(max_depth)


def _stack_pieces(pieces):
    """Polylines stacked: ``(P, check, starts)`` with ``check`` flagging the moves inside
    a piece that have an XY extent (not the step from one piece's end to the next's start)
    and ``starts`` the index of each piece's first point.

    The pieces are checked as :func:`_as_points` checks each (the same error for the
    first bad one), but stacked first and tested for non-finite values once: a check per
    piece cost about 12 us, 0.02 s for the pencil's 1900 chains in the plan's serial tail.
    """
    arrs = [np.asarray(c, dtype=np.float64) for c in pieces]
    if not all(a.ndim == 2 and a.shape[1] == 3 for a in arrs):
        arrs = [_as_points(c, 3, "centers") for c in arrs]  # raises, naming the first bad piece's shape
    P = np.vstack(arrs)
    if not np.isfinite(P).all():
        for c in arrs:
            _as_points(c, 3, "centers")  # raises, naming the first bad piece's rows
    lens = np.array([len(c) for c in arrs], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
    d = np.diff(P, axis=0)
    check = np.hypot(d[:, 0], d[:, 1]) > 1e-9
    b = starts[1:]
    check[b[(b > 0) & (b < len(P))] - 1] = False  # from one piece's end to the next one's start
    return P, check, starts


def _insert(P, after, newpts, track):
    """Insert ``newpts`` after rows ``after`` (sorted); return the points, the moves to
    check and ``track`` (row indices) moved past the rows inserted before them.

    The moves that touch an inserted point are flagged for checking; the others are
    already verified.
    """
    k = len(P)
    m = len(after)
    # position of every old point in the new array: shifted by inserts before it
    shift = np.searchsorted(after, np.arange(k), side="left")  # inserts with after < i
    newpos_old = np.arange(k) + shift
    newpos_ins = after + np.arange(m) + 1
    Q = np.empty((k + m, 3), dtype=np.float64)
    Q[newpos_old] = P
    Q[newpos_ins] = newpts
    chk = np.zeros(k + m - 1, dtype=bool)
    chk[newpos_ins - 1] = True
    chk[newpos_ins] = True
    # (a tracked index may be len(P): the start of an empty last piece)
    return Q, chk, track + np.searchsorted(after, track, side="left")


def _as_points(a, dim: int, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != dim:
        raise PlanningError(f"cutter: {name} must be (k, {dim}), got shape {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
    if bad.size:
        raise PlanningError(f"cutter: {name} has {bad.size} non-finite rows (first: row {bad[0]})")
    return np.ascontiguousarray(a)
