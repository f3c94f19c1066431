"""What a 3-axis ball-end program leaves on a part: an independent simulation.

Model
-----
The cutter is a ball of radius ``r``; the programmed point is the tool tip, so the ball
centre is ``tip + r Z``. Along a feed move (G1, or a chord of G2/G3) the ball sweeps a
*capsule*: the points within ``r`` of the centre segment. The material removed is the
union ``S`` of the capsules (the shank is not modelled).

At a sample ``p`` of the part with unit normal ``n`` (towards the tool):

- remaining material ``t(p) = min {t >= 0 : p + t n in S}`` (ray-capsule intersection);
  ``inf`` ("uncut") when the ray meets no capsule within ``ray_cap`` (default ``2 r``);
- gouge depth ``g(p) = max_j (r - dist(p, segment_j))`` when positive: how far ``p`` lies
  inside the swept volume (the part has been cut below its surface); ``t = 0`` there.

Candidates come from a uniform grid of cells (edge ``cell``, default ``r / 2``) holding every
capsule whose bounding box meets the cell; each ray walks the cells it crosses in order
(Amanatides-Woo) and stops as soon as its best hit lies before the exit of the current
cell, so the answer is exact (no sampling of the tool path).

Rapid moves (G0) are checked against the mesh triangles: the clearance of a rapid is
``dist(centre segment, mesh) - r`` (exact segment-triangle distance), negative when the
ball passes through the part. Vertical upward rapids (retracts) are reported apart: a
retract from the end of a cut starts on the part by design.

The material simulation shares no code with the planner (``conformill.param``,
``geometry``, ``planning``, ``patterns``, ``cutter``, ``mapping``) so that it can catch its
mistakes. One step uses the planner's drop-cutter (through :mod:`conformill.verify.rest`):
with ``judge="reachable"`` (or ``rest``), the search for samples that no ball position
brings within the scallop limit (or the reach depth, if larger), which ``verify`` leaves
out of the reachable set. It only runs where the program left more than the reach depth
(or the limit, if smaller), excuses only samples the program left above the limit, and
only where a second, wider and deeper search finds no ball within the limit either, and
checks with this module's own geometry that the best ball it found
touches the part (a uniformly biased drop-cutter excuses
nothing; one that is wrong only near other centres could hide a better ball).
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from scipy.spatial import cKDTree

from conformill.errors import ConformillError, GCodeError
from conformill.geometry.closest import closest_on_triangle
from conformill.planning.steps import check_ball_size, check_stock
from conformill.verify.gcode import FEED, RAPID, Program
from conformill.verify.samples import SurfaceSamples, sample_surface

__all__ = [
    "CapsuleGrid",
    "check_cuts",
    "remaining_material",
    "rapid_clearance",
    "unreachable_samples",
    "verify",
    "VerifyResult",
    "segment_triangle_distance",
]

log = logging.getLogger(__name__)

_INF = np.inf


# --------------------------------------------------------------------------------------
# geometry kernels


@nb.njit(cache=True, inline="always")
def _seg_point_dist2(ax, ay, az, bx, by, bz, px, py, pz):
    ux, uy, uz = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    uu = ux * ux + uy * uy + uz * uz
    s = 0.0
    if uu > 0.0:
        s = (wx * ux + wy * uy + wz * uz) / uu
        if s < 0.0:
            s = 0.0
        elif s > 1.0:
            s = 1.0
    dx, dy, dz = wx - s * ux, wy - s * uy, wz - s * uz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, inline="always")
def _ray_sphere(px, py, pz, nx, ny, nz, cx, cy, cz, rr):
    """Entry t >= 0 of the ray into a sphere (origin outside), inf if none."""
    ox, oy, oz = px - cx, py - cy, pz - cz
    b = ox * nx + oy * ny + oz * nz
    c = ox * ox + oy * oy + oz * oz - rr
    h = b * b - c
    if h < 0.0:
        return _INF
    t = -b - math.sqrt(h)
    if t < 0.0:
        return _INF
    return t


@nb.njit(cache=True, inline="always")
def _ray_capsule(px, py, pz, nx, ny, nz, ax, ay, az, bx, by, bz, rr):
    """Entry t >= 0 of the ray p + t n (|n| = 1, p outside) into the capsule, inf if none.

    The entry point lies on the cylinder side (with axial coordinate in [0, L]) or on one
    of the end spheres; every candidate lies in the capsule, so the smallest is the entry.
    """
    t = _ray_sphere(px, py, pz, nx, ny, nz, ax, ay, az, rr)
    t2 = _ray_sphere(px, py, pz, nx, ny, nz, bx, by, bz, rr)
    if t2 < t:
        t = t2
    ux, uy, uz = bx - ax, by - ay, bz - az
    L2 = ux * ux + uy * uy + uz * uz
    if L2 <= 0.0:
        return t
    L = math.sqrt(L2)
    ux /= L
    uy /= L
    uz /= L
    wx, wy, wz = px - ax, py - ay, pz - az
    dn = nx * ux + ny * uy + nz * uz
    dw = wx * ux + wy * uy + wz * uz
    # radial parts
    qx, qy, qz = nx - dn * ux, ny - dn * uy, nz - dn * uz
    ex, ey, ez = wx - dw * ux, wy - dw * uy, wz - dw * uz
    a = qx * qx + qy * qy + qz * qz
    if a < 1e-14:
        return t
    b = qx * ex + qy * ey + qz * ez
    c = ex * ex + ey * ey + ez * ez - rr
    h = b * b - a * c
    if h < 0.0:
        return t
    t0 = (-b - math.sqrt(h)) / a
    if t0 >= 0.0 and t0 < t:
        s = dw + t0 * dn
        if 0.0 <= s <= L:
            t = t0
    return t


@nb.njit(cache=True)
def _grid_count(A, B, r, lo, cell, dims):
    s = A.shape[0]
    counts = np.zeros(dims[0] * dims[1] * dims[2] + 1, dtype=np.int64)
    for j in range(s):
        i0 = np.empty(3, np.int64)
        i1 = np.empty(3, np.int64)
        for k in range(3):
            mn = min(A[j, k], B[j, k]) - r
            mx = max(A[j, k], B[j, k]) + r
            i0[k] = max(0, int(math.floor((mn - lo[k]) / cell)))
            i1[k] = min(dims[k] - 1, int(math.floor((mx - lo[k]) / cell)))
        for x in range(i0[0], i1[0] + 1):
            for y in range(i0[1], i1[1] + 1):
                for z in range(i0[2], i1[2] + 1):
                    counts[(x * dims[1] + y) * dims[2] + z + 1] += 1
    return counts


@nb.njit(cache=True)
def _grid_fill(A, B, r, lo, cell, dims, start):
    s = A.shape[0]
    fill = start[:-1].copy()
    items = np.empty(start[-1], dtype=np.int32)
    for j in range(s):
        i0 = np.empty(3, np.int64)
        i1 = np.empty(3, np.int64)
        for k in range(3):
            mn = min(A[j, k], B[j, k]) - r
            mx = max(A[j, k], B[j, k]) + r
            i0[k] = max(0, int(math.floor((mn - lo[k]) / cell)))
            i1[k] = min(dims[k] - 1, int(math.floor((mx - lo[k]) / cell)))
        for x in range(i0[0], i1[0] + 1):
            for y in range(i0[1], i1[1] + 1):
                for z in range(i0[2], i1[2] + 1):
                    c = (x * dims[1] + y) * dims[2] + z
                    items[fill[c]] = j
                    fill[c] += 1
    return items


#: One compiled version for its callers (the literal ``-1`` of the first ray made another;
#: see ``conformill.cutter._DROP_POINT_SIG``).
_CAST_ONE_SIG = nb.int64(nb.int64, *([nb.float64[:, ::1]] * 5), nb.float64[::1], nb.float64, nb.float64[::1],
                         nb.float64, nb.int64[::1], nb.int64[::1], nb.int32[::1], nb.float64, nb.int64,
                         nb.float64[::1], nb.float64[::1], nb.int64[::1], nb.int64[::1])


@nb.njit(_CAST_ONE_SIG, cache=True)
def _cast_one(i, P, N, A, B, Mid, Rb, r, lo, cell, dims, start, items, tcap, prev, t_out, g_out, hit_out, gj_out):
    """One ray (see :func:`_cast`); returns the capsule hit (seed for the next sample)."""
    rr = r * r
    px, py, pz = P[i, 0], P[i, 1], P[i, 2]
    d0, d1, d2 = N[i, 0], N[i, 1], N[i, 2]
    # a hit later than tcap does not matter: start from it, so that the pruning below works
    best = tcap * (1.0 + 1e-12) + 1e-300
    besthit = -1
    gouge = 0.0
    gj = -1
    # seed with the capsules hit by the previous (nearby) sample: a small ``best`` early
    # lets the bounding-sphere test reject most candidates
    if prev >= 0:
        for j in range(max(prev - 2, 0), min(prev + 3, A.shape[0])):
            if _seg_point_dist2(A[j, 0], A[j, 1], A[j, 2], B[j, 0], B[j, 1], B[j, 2], px, py, pz) <= rr:
                best = 0.0
                besthit = j
                break
            t = _ray_capsule(px, py, pz, d0, d1, d2, A[j, 0], A[j, 1], A[j, 2], B[j, 0], B[j, 1], B[j, 2], rr)
            if t < best:
                best = t
                besthit = j
    # clip the ray [0, tcap] to the grid box
    tin = 0.0
    tout = tcap
    for k in range(3):
        o = P[i, k]
        d = N[i, k]
        l = lo[k]
        h = lo[k] + dims[k] * cell
        if abs(d) < 1e-300:
            if o < l or o > h:
                tin = _INF
        else:
            ta = (l - o) / d
            tb = (h - o) / d
            if ta > tb:
                ta, tb = tb, ta
            if ta > tin:
                tin = ta
            if tb < tout:
                tout = tb
    if tin <= tout:
        qx, qy, qz = px + tin * d0, py + tin * d1, pz + tin * d2
        ix = min(max(int(math.floor((qx - lo[0]) / cell)), 0), dims[0] - 1)
        iy = min(max(int(math.floor((qy - lo[1]) / cell)), 0), dims[1] - 1)
        iz = min(max(int(math.floor((qz - lo[2]) / cell)), 0), dims[2] - 1)
        sx = 1 if d0 > 0 else -1
        sy = 1 if d1 > 0 else -1
        sz = 1 if d2 > 0 else -1
        tmx = (lo[0] + (ix + (1 if d0 > 0 else 0)) * cell - px) / d0 if d0 != 0.0 else _INF
        tdx = cell / abs(d0) if d0 != 0.0 else _INF
        tmy = (lo[1] + (iy + (1 if d1 > 0 else 0)) * cell - py) / d1 if d1 != 0.0 else _INF
        tdy = cell / abs(d1) if d1 != 0.0 else _INF
        tmz = (lo[2] + (iz + (1 if d2 > 0 else 0)) * cell - pz) / d2 if d2 != 0.0 else _INF
        tdz = cell / abs(d2) if d2 != 0.0 else _INF
        first = tin == 0.0
        while True:
            c = (ix * dims[1] + iy) * dims[2] + iz
            for q in range(start[c], start[c + 1]):
                j = items[q]
                # bounding-sphere rejection: a hit at t < best (or p inside) needs the
                # segment within r of the ray piece [p, p + best n]
                hb = 0.5 * best
                cx = px + hb * d0 - Mid[j, 0]
                cy = py + hb * d1 - Mid[j, 1]
                cz = pz + hb * d2 - Mid[j, 2]
                rb = Rb[j] + hb
                if cx * cx + cy * cy + cz * cz > rb * rb:
                    continue
                ax, ay, az = A[j, 0], A[j, 1], A[j, 2]
                bx, by, bz = B[j, 0], B[j, 1], B[j, 2]
                if first:
                    d2s = _seg_point_dist2(ax, ay, az, bx, by, bz, px, py, pz)
                    if d2s <= rr:
                        best = 0.0
                        besthit = j
                        g = r - math.sqrt(d2s)
                        if g > gouge:
                            gouge = g
                            gj = j
                        continue
                if best > 0.0:
                    t = _ray_capsule(px, py, pz, d0, d1, d2, ax, ay, az, bx, by, bz, rr)
                    if t < best:
                        best = t
                        besthit = j
            first = False
            texit = min(tmx, min(tmy, tmz))
            if best <= texit or texit > tout:
                break
            if tmx <= tmy and tmx <= tmz:
                ix += sx
                tmx += tdx
                if ix < 0 or ix >= dims[0]:
                    break
            elif tmy <= tmz:
                iy += sy
                tmy += tdy
                if iy < 0 or iy >= dims[1]:
                    break
            else:
                iz += sz
                tmz += tdz
                if iz < 0 or iz >= dims[2]:
                    break
    if besthit < 0 or best > tcap:
        t_out[i] = _INF
        hit_out[i] = -1
    else:
        t_out[i] = best
        hit_out[i] = besthit
    g_out[i] = gouge
    gj_out[i] = gj
    return besthit


@nb.njit(cache=True, parallel=True)
def _cast(order, P, N, A, B, Mid, Rb, r, lo, cell, dims, start, items, tcap, t_out, g_out, hit_out, gj_out):
    """Per sample: remaining material t (inf = none within tcap), gouge depth, capsule ids.

    Samples are visited in ``order`` (sorted by cell) in contiguous blocks, one block per
    task, so that each ray can be seeded with its neighbour's hit.
    """
    n = order.shape[0]
    nblk = (n + 255) // 256
    for b in nb.prange(nblk):
        prev = -1
        for k in range(b * 256, min(n, (b + 1) * 256)):
            prev = _cast_one(order[k], P, N, A, B, Mid, Rb, r, lo, cell, dims, start, items, tcap, prev,
                             t_out, g_out, hit_out, gj_out)


class CapsuleGrid:
    """The swept volume of a ball along segments, indexed for ray queries.

    Parameters
    ----------
    A, B : (s, 3) float64
        Ball-centre segments (``tip + r Z``), mm.
    r : float
        Ball radius, mm.
    cell : float, optional
        Grid cell edge (mm); default ``r / 2``. The grid is coarsened if it would exceed
        ``max_cells`` cells or ``max_entries`` (capsule, cell) pairs.

    Raises
    ------
    ConformillError
        Bad radius or shapes.
    """

    def __init__(self, A, B, r: float, cell: float | None = None, max_cells: int = 20_000_000,
                 max_entries: int = 150_000_000):
        A = np.ascontiguousarray(A, dtype=np.float64).reshape(-1, 3)
        B = np.ascontiguousarray(B, dtype=np.float64).reshape(-1, 3)
        if A.shape != B.shape:
            raise ConformillError(f"segment ends differ in shape: {A.shape} vs {B.shape}")
        if not (np.isfinite(r) and r > 0):
            raise ConformillError(f"tool radius must be > 0 mm, got {r!r}")
        self.A, self.B, self.r = A, B, float(r)
        self.mid = 0.5 * (A + B)
        self.rb = self.r + 0.5 * np.linalg.norm(B - A, axis=1) + 1e-9
        cell = float(cell) if cell else 0.5 * float(r)
        if len(A) == 0:
            self.lo = np.zeros(3)
            self.cell = cell
            self.dims = np.ones(3, dtype=np.int64)
            self.start = np.zeros(2, dtype=np.int64)
            self.items = np.zeros(0, dtype=np.int32)
            return
        lo = np.minimum(A.min(0), B.min(0)) - r - 1e-9
        hi = np.maximum(A.max(0), B.max(0)) + r + 1e-9
        ext = hi - lo
        for _ in range(40):
            dims = np.maximum(1, np.ceil(ext / cell).astype(np.int64))
            if np.prod(dims) > max_cells:
                cell *= 1.25
                continue
            counts = _grid_count(A, B, self.r, lo, cell, dims)
            if counts.sum() > max_entries:
                cell *= 1.25
                continue
            break
        self.lo, self.cell, self.dims = lo, cell, dims
        self.start = np.cumsum(counts)
        self.items = _grid_fill(A, B, self.r, lo, cell, dims, self.start)

    def cast(self, P, N, ray_cap: float):
        """Remaining material along the normals (see the module docstring).

        Returns
        -------
        t : (n,) float64
            Remaining material (mm), ``inf`` when no capsule is met within ``ray_cap``.
        gouge : (n,) float64
            Gouge depth (mm), 0 where none.
        hit : (n,) int64
            Segment whose capsule the ray enters first (-1 if none).
        gouge_seg : (n,) int64
            Segment of the deepest gouge (-1 if none).
        """
        P = np.ascontiguousarray(P, dtype=np.float64)
        N = np.ascontiguousarray(N, dtype=np.float64)
        n = len(P)
        t = np.empty(n)
        g = np.empty(n)
        h = np.empty(n, dtype=np.int64)
        gj = np.empty(n, dtype=np.int64)
        if n:
            ijk = np.clip(np.floor((P - self.lo) / self.cell).astype(np.int64), 0, self.dims - 1)
            key = (ijk[:, 0] * self.dims[1] + ijk[:, 1]) * self.dims[2] + ijk[:, 2]
            order = np.argsort(key, kind="stable")
            _cast(order, P, N, self.A, self.B, self.mid, self.rb, self.r, self.lo, self.cell, self.dims,
                  self.start, self.items, float(ray_cap), t, g, h, gj)
        return t, g, h, gj


def remaining_material(samples: SurfaceSamples, program: Program, tool_radius: float, ray_cap: float | None = None,
                       chunk: int = 65536, progress=None):
    """Remaining material and gouge depth at surface samples after the program's feed moves.

    Parameters
    ----------
    samples : SurfaceSamples
    program : Program
    tool_radius : float
        Ball radius ``r`` (mm).
    ray_cap : float, optional
        Largest remaining material looked for (default ``2 r``); beyond it a sample is uncut.
    chunk : int
        Samples per call of the compiled kernel (progress granularity).
    progress : callable, optional
        Called with the number of samples done after each chunk (e.g. ``tqdm.update``).

    Returns
    -------
    t, gouge, hit, gouge_seg
        See :meth:`CapsuleGrid.cast`; segment ids index the program's feed moves
        (``np.flatnonzero(program.motion == FEED)``).
    """
    r = float(tool_radius)
    A, B = program.segments(FEED)
    up = np.array([0.0, 0.0, r])
    grid = CapsuleGrid(A + up, B + up, r)
    cap = 2 * r if ray_cap is None else float(ray_cap)
    n = len(samples)
    out = [np.empty(n), np.empty(n), np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)]
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        res = grid.cast(samples.points[s:e], samples.normals[s:e], cap)
        for o, v in zip(out, res):
            o[s:e] = v
        if progress is not None:
            progress(e - s)
    return tuple(out)


# --------------------------------------------------------------------------------------
# rapids


@nb.njit(cache=True, inline="always")
def _closest_pt_tri_d2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from a point to a triangle."""
    qx, qy, qz = closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, inline="always")
def _seg_seg_d2(p1x, p1y, p1z, q1x, q1y, q1z, p2x, p2y, p2z, q2x, q2y, q2z):
    """Squared distance between two segments (Ericson 5.1.9)."""
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    eps = 1e-300
    if a <= eps and e <= eps:
        s = 0.0
        t = 0.0
    elif a <= eps:
        s = 0.0
        t = min(max(f / e, 0.0), 1.0)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e <= eps:
            t = 0.0
            s = min(max(-c / a, 0.0), 1.0)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            den = a * e - b * b
            s = min(max((b * f - c * e) / den, 0.0), 1.0) if den > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((b - c) / a, 0.0), 1.0)
    dx = p1x + d1x * s - (p2x + d2x * t)
    dy = p1y + d1y * s - (p2y + d2y * t)
    dz = p1z + d1z * s - (p2z + d2z * t)
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True)
def _seg_tri_d2(p, q, a, b, c):
    # does the segment cross the triangle? (Moller-Trumbore with t in [0, 1])
    e1 = b - a
    e2 = c - a
    d = q - p
    hx = d[1] * e2[2] - d[2] * e2[1]
    hy = d[2] * e2[0] - d[0] * e2[2]
    hz = d[0] * e2[1] - d[1] * e2[0]
    det = e1[0] * hx + e1[1] * hy + e1[2] * hz
    if abs(det) > 1e-300:
        inv = 1.0 / det
        sx, sy, sz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
        u = (sx * hx + sy * hy + sz * hz) * inv
        if 0.0 <= u <= 1.0:
            qx = sy * e1[2] - sz * e1[1]
            qy = sz * e1[0] - sx * e1[2]
            qz = sx * e1[1] - sy * e1[0]
            v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
            if v >= 0.0 and u + v <= 1.0:
                t = (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv
                if 0.0 <= t <= 1.0:
                    return 0.0
    best = _closest_pt_tri_d2(p[0], p[1], p[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2])
    best = min(best, _closest_pt_tri_d2(q[0], q[1], q[2], a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2]))
    best = min(best, _seg_seg_d2(p[0], p[1], p[2], q[0], q[1], q[2], a[0], a[1], a[2], b[0], b[1], b[2]))
    best = min(best, _seg_seg_d2(p[0], p[1], p[2], q[0], q[1], q[2], b[0], b[1], b[2], c[0], c[1], c[2]))
    best = min(best, _seg_seg_d2(p[0], p[1], p[2], q[0], q[1], q[2], c[0], c[1], c[2], a[0], a[1], a[2]))
    return best


@nb.njit(cache=True, parallel=True)
def _pairs_d2(P, Q, V, F, seg, tri, out):
    for k in nb.prange(seg.shape[0]):
        s = seg[k]
        f = tri[k]
        out[k] = _seg_tri_d2(P[s], Q[s], V[F[f, 0]], V[F[f, 1]], V[F[f, 2]])


def segment_triangle_distance(P, Q, V, F, seg, tri) -> np.ndarray:
    """Exact distances between segments ``P[seg] Q[seg]`` and triangles ``F[tri]``.

    Returns
    -------
    (k,) float64
    """
    out = np.empty(len(seg))
    if len(seg):
        _pairs_d2(np.ascontiguousarray(P, float), np.ascontiguousarray(Q, float), np.ascontiguousarray(V, float),
                  np.ascontiguousarray(F, np.int64), np.asarray(seg, np.int64), np.asarray(tri, np.int64), out)
    return np.sqrt(out)


def _centroids(V, F):
    """Face centroids and the largest distance from a centroid to a vertex of its face."""
    cen = V[F].mean(axis=1)
    return cen, float(np.sqrt(((V[F] - cen[:, None, :]) ** 2).sum(-1)).max())


def _near_triangles(tree, X, rad):
    """``(owner, tri)``: every face whose centroid (``tree``) lies within ``rad`` of a point
    of ``X`` (``rad`` scalar or per point), as index pairs into ``X`` and the faces."""
    lists = tree.query_ball_point(X, rad, workers=-1)
    lens = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    tri = np.fromiter(itertools.chain.from_iterable(lists), dtype=np.int64, count=int(lens.sum()))
    return np.repeat(np.arange(len(X)), lens), tri


@nb.njit(cache=True, nogil=True)
def _first_pairs(seg, tri, n_faces):
    """Mask of the first occurrence of each ``(seg, tri)`` pair when ``seg`` does not
    decrease (pairs of one segment together): one pass with the segment that last saw each
    face, where sorting the pairs (``np.unique``) took 3.4 s for 6.3M on a hopped program."""
    last = np.full(n_faces, -1, dtype=np.int64)
    keep = np.empty(seg.shape[0], dtype=np.bool_)
    for i in range(seg.shape[0]):
        t = tri[i]
        keep[i] = last[t] != seg[i]
        last[t] = seg[i]
    return keep


def rapid_clearance(V, F, program: Program, tool_radius: float, cap: float = 5.0, retract_tol: float = 1e-6) -> dict:
    """Clearance between the ball and the mesh along the rapid (G0) moves.

    The clearance of a rapid is ``dist(centre segment, mesh) - r`` with the centre segment
    ``tip + r Z`` (exact segment-triangle distance over candidate triangles from a k-d
    tree of triangle centroids), negative when the ball reaches into the part. A centre
    point on the material side of the facet whose centroid is nearest, and within that
    facet's reach along its normal (the mesh is a surface, the material lies under it),
    gives ``-(distance + r)``, approximately (the centroid distance). Clearances above ``cap`` are not resolved exactly: such
    a rapid reports a lower bound ``>= cap``. A vertical upward rapid (``|dxy| <=
    retract_tol``) right after a feed move is a *retract* from the part, reported apart
    (it starts on the part by design).

    Returns
    -------
    dict
        ``rapid_min_clearance`` (mm, over the non-retract rapids; ``inf`` if there are
        none), ``rapid_min_where`` (tool-tip start and end of that rapid),
        ``rapid_min_line`` (its source line), ``retract_min_clearance``,
        ``n_rapids``, ``n_retracts``, ``clearance`` (per rapid, ``(k,)``),
        ``is_retract`` (``(k,)`` bool), ``rapid_index`` (move index of each rapid).
    """
    r = float(tool_radius)
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    idx = np.flatnonzero(program.motion == RAPID)
    A, B = program.segments(None)
    up = np.array([0.0, 0.0, r])
    P, Q = A[idx] + up, B[idx] + up
    k = len(idx)
    clear = np.full(k, np.inf)
    dxy = np.linalg.norm((B[idx] - A[idx])[:, :2], axis=1)
    prev_feed = np.zeros(k, dtype=bool)
    prev_feed[idx > 0] = program.motion[idx[idx > 0] - 1] == FEED
    retract = (dxy <= retract_tol) & (B[idx, 2] > A[idx, 2]) & prev_feed
    if k and len(F):
        cen, rmax = _centroids(V, F)
        tree = cKDTree(cen)
        step = max(rmax, 0.25 * r, 1e-3)
        L = np.linalg.norm(Q - P, axis=1)
        m = np.maximum(1, np.ceil(L / step).astype(np.int64)) + 1
        sid = np.repeat(np.arange(k), m)
        off = np.cumsum(m) - m
        t = (np.arange(m.sum()) - np.repeat(off, m)) / np.repeat(m - 1, m).clip(1)
        S = P[sid] + t[:, None] * (Q - P)[sid]
        half = 0.5 * L[sid] / np.maximum(m[sid] - 1, 1)
        d0, near_f = tree.query(S, workers=-1)
        lower = np.maximum(d0 - rmax - half, 0.0) - r  # a bound below the clearance near each sample
        lb = np.full(k, np.inf)
        np.minimum.at(lb, sid, lower)
        # a centre under the surface (on the material side of the nearest facet, judged by
        # the facet of the nearest centroid) is in the part: clearance -(distance + r)
        fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        if float(fn[:, 2].sum()) < 0:
            fn = -fn
        un = fn[near_f] / np.linalg.norm(fn[near_f], axis=1, keepdims=True)
        off_n = np.einsum("ij,ij->i", S - cen[near_f], un)
        off_t = np.linalg.norm(S - cen[near_f] - off_n[:, None] * un, axis=1)
        # under that facet along its normal (not merely beside the part's rim)
        below = (off_n < 0) & (off_t <= rmax)
        inside = np.full(k, np.inf)
        np.minimum.at(inside, sid[below], -(d0[below] + r))
        clear = np.maximum(lb, cap)  # resolved below where it may be smaller than cap
        near = lower < cap
        if near.any():
            rad = np.minimum(d0[near] + half[near], cap + r + half[near]) + half[near] + rmax
            owner, tri = _near_triangles(tree, S[near], rad)
            seg = sid[near][owner]  # not decreasing: the samples are in segment order
            keep = _first_pairs(seg, tri, len(F))
            seg, tri = seg[keep], tri[keep]
            d = segment_triangle_distance(P, Q, V, F, seg, tri) - r
            exact = np.full(k, np.inf)
            np.minimum.at(exact, seg, d)
            has = np.isin(np.arange(k), seg)
            clear[has] = np.minimum(exact[has], np.maximum(lb[has], cap))
        clear = np.minimum(clear, inside)
    normal = ~retract
    out = {
        "n_rapids": int(normal.sum()),
        "n_retracts": int(retract.sum()),
        "clearance": clear,
        "is_retract": retract,
        "rapid_index": idx,
        "rapid_min_clearance": float(clear[normal].min()) if normal.any() else math.inf,
        "retract_min_clearance": float(clear[retract].min()) if retract.any() else math.inf,
        "rapid_min_line": None,
        "rapid_min_where": None,
    }
    if normal.any():
        j = np.flatnonzero(normal)[np.argmin(clear[normal])]
        out["rapid_min_line"] = int(program.line[idx[j]])
        out["rapid_min_where"] = [A[idx[j]].tolist(), B[idx[j]].tolist()]
    return out


# --------------------------------------------------------------------------------------
# the whole check


@dataclass(frozen=True, eq=False)
class VerifyResult:
    """Outcome of :func:`verify`.

    Attributes
    ----------
    samples : SurfaceSamples
    remaining : (n,) float64
        Remaining material along the normal (mm); ``inf`` where uncut; 0 where gouged.
    gouge : (n,) float64
        Gouge depth (mm), 0 where none.
    interior : (n,) bool
        Samples farther than ``r`` (3D distance) from the mesh boundary.
    reachable : (n,) bool
        The interior samples the reachable judge checks (``summary["reachable"]``; see
        :func:`verify` for the two tests that build it).
    excused : (n,) bool
        Samples the tangent test keeps but for which the rest search finds no ball within
        the scallop limit (or the reach depth, if larger); left out of ``reachable``. All False unless
        ``judge="reachable"`` or ``rest``.
    hit_line, gouge_line : (n,) int64
        Source line of the move that cut each sample / that gouged it deepest (-1: none).
    rapids : dict
        See :func:`rapid_clearance`.
    summary : dict
        Scalar figures (see :func:`verify`).
    """

    samples: SurfaceSamples
    remaining: np.ndarray = field(repr=False)
    gouge: np.ndarray = field(repr=False)
    interior: np.ndarray = field(repr=False)
    hit_line: np.ndarray = field(repr=False)
    gouge_line: np.ndarray = field(repr=False)
    rapids: dict = field(repr=False)
    summary: dict = field(default_factory=dict)
    reachable: np.ndarray | None = field(default=None, repr=False)
    excused: np.ndarray | None = field(default=None, repr=False)


def _stats(rem, gouge, P, gline, H, gouge_tol):
    n = len(rem)
    cut = np.isfinite(rem)
    out = {"samples": int(n)}
    if n == 0:
        out.update(scallop={"p50": math.nan, "p99": math.nan, "p999": math.nan, "max": math.nan},
                   uncut_fraction=math.nan, gouge_max=0.0, gouge_where=None, gouge_line=None,
                   gouged_fraction=math.nan)
        return out
    rc = rem[cut]
    if len(rc):
        q = np.percentile(rc, [50, 99, 99.9])
        out["scallop"] = {"p50": q[0], "p99": q[1], "p999": q[2], "max": float(rc.max())}
        out["scallop_mean"] = float(rc.mean())
    else:
        out["scallop"] = {"p50": math.nan, "p99": math.nan, "p999": math.nan, "max": math.nan}
        out["scallop_mean"] = math.nan
    out["uncut_fraction"] = float((~cut).mean())
    if H is not None:
        out["above_scallop_fraction"] = float(((rem > H) | ~cut).mean())
    j = int(np.argmax(gouge))
    out["gouge_max"] = float(gouge[j])
    out["gouge_where"] = P[j].tolist() if gouge[j] > 0 else None
    out["gouge_line"] = int(gline[j]) if gouge[j] > 0 else None
    out["gouged_fraction"] = float((gouge > gouge_tol).mean())
    return out


#: How far (mm) the independently measured distance from a rest-search centre to the mesh
#: may exceed ``r`` before the drop height there is taken as wrong (see :func:`_beyond_any_ball`).
_TOUCH_TOL = 1e-6


def _mesh_distance(V, F, C, reach):
    """Distance from each point of ``C`` to the mesh, exact where it is at most ``reach``
    (``inf`` beyond): :func:`segment_triangle_distance` of the points (as zero-length
    segments) to the candidate triangles of :func:`_near_triangles`."""
    out = np.full(len(C), np.inf)
    if len(F) == 0 or len(C) == 0:
        return out
    cen, rmax = _centroids(V, F)
    owner, tri = _near_triangles(cKDTree(cen), C, reach + rmax)
    np.minimum.at(out, owner, segment_triangle_distance(C, C, V, F, owner, tri))
    return out


def _beyond_any_ball(V, F, r, samples, rem, ok, depth, limit, full=False):
    """Samples of ``ok`` left with more than ``limit`` that no ball position searched
    brings within ``limit``.

    A sample the program leaves within ``limit`` is not excused (the program's own ball
    did it). At the samples left with more than ``limit`` (with ``full``, more than
    ``depth``, at most ``limit``, so that ``rest`` covers them too) the ball positions
    reachable from above are searched
    (:func:`conformill.verify.rest.rest_material`, centres on the drop surface of the
    planner's drop-cutter). The search's least value is an upper bound of the true rest,
    so a sample it puts above ``limit`` is searched again with the wider and deeper
    :data:`conformill.verify.rest.CONFIRM`, and is excused only where neither finds a
    ball within ``limit``: no program can meet the limit there. The centres come from
    planner code, so the best one found is checked independently: the ball there must
    touch the part, its distance to the mesh (exact, this module's own point-triangle
    distance) at most ``r + 1e-6`` mm. That catches a drop height that is too high at that
    centre (a uniformly biased drop-cutter excuses nothing), but not one that is too high
    only at other centres and hides a better ball there.
    Without ``full``, the searches run only where the tangent ball, dropped, leaves more
    than ``limit`` (elsewhere ``rest`` holds that ball's value, an upper bound, at the
    samples left above ``limit``).

    Returns
    -------
    beyond : (n,) bool
        The excused samples (both searches' least value above ``limit``, confirmed).
    rest : (n,) float64
        The least material found at each searched sample (``nan`` where not searched).
    unconfirmed : int
        Samples the searches would have excused whose best ball does not touch the part
        (or lies off it).
    """
    from conformill.cutter import BallCutter
    from conformill.verify.rest import CONFIRM, rest_material, tangent_rest

    beyond = np.zeros(len(rem), dtype=bool)
    rest = np.full(len(rem), np.nan)
    # uncut samples (inf) too; only ``full`` needs the rest where no sample can be excused
    cand = np.flatnonzero(ok & ~(rem <= (depth if full else limit)))
    if cand.size == 0:
        return beyond, rest, 0
    cutter = BallCutter(V, F, r)
    if not full:
        # the tangent ball dropped onto the part is one of the searched positions: where it
        # leaves at most ``limit`` the sample cannot be excused (one drop instead of a search)
        t0 = tangent_rest(cutter, samples.points[cand], samples.normals[cand])
        rest[cand] = t0
        cand = cand[t0 > limit]
        if cand.size == 0:
            return beyond, rest, 0
    t, C = rest_material(cutter, samples.points[cand], samples.normals[cand], centres=True)
    over = np.flatnonzero((t > limit) & ~(rem[cand] <= limit))
    if over.size:
        t2, C2 = rest_material(cutter, samples.points[cand[over]], samples.normals[cand[over]], centres=True,
                               **CONFIRM)
        better = t2 < t[over]
        t[over[better]], C[over[better]] = t2[better], C2[better]
        over = over[t[over] > limit]
    rest[cand] = t
    if over.size == 0:
        return beyond, rest, 0
    Co = C[over]
    touch = np.isfinite(Co[:, 2])
    dist = np.full(over.size, np.inf)
    if touch.any():
        dist[touch] = _mesh_distance(V, F, Co[touch], r + 1.0)
    confirmed = dist <= r + _TOUCH_TOL
    # a ball off the part (no drop height: -inf) leaves the sample alone: nothing to confirm,
    # and no reason to excuse it either
    beyond[cand[over[confirmed]]] = True
    return beyond, rest, int((~confirmed).sum())


def _rest_figures(rem, rest, ok, H):
    """The program's own share above the rest at the judged samples (see ``verify``), and
    the judged samples above ``H`` counted by their rest: below ``H / 2``, from ``H / 2``
    to ``0.9 H`` and above ``0.9 H`` (the rim of what no ball removes)."""
    fin = ok & np.isfinite(rem)
    above = fin & (rem > H)
    t_above = rest[above]  # every judged sample above H was searched (``verify``)
    bands = [int((t_above < 0.5 * H).sum()), int(((t_above >= 0.5 * H) & (t_above <= 0.9 * H)).sum()),
             int((t_above > 0.9 * H).sum())]
    out = {"above_limit": int(above.sum()), "above_limit_by_rest": bands, "p999_over_rest": math.nan}
    if fin.any():
        own = rem.copy()
        t = np.where(np.isfinite(rest), rest, 0.0)
        own[above] = rem[above] - np.minimum(t[above], rem[above])
        out["p999_over_rest"] = float(np.percentile(own[fin], 99.9))
    return out


def unreachable_samples(samples: SurfaceSamples, V: np.ndarray, tool_radius: float, depth: float,
                        which: np.ndarray | None = None) -> np.ndarray:
    """Samples that no 3-axis ball position can bring within ``depth`` of the surface.

    The best a ball of radius ``r`` can do at ``p`` (unit normal ``n``) is to touch it from
    ``c = p + r n``. If another part of the surface lies closer to ``c`` than ``r - depth``,
    the ball cannot sit there and at least ``depth`` of material stays at ``p`` whatever the
    program (a concave region tighter than the ball, a narrow slot). If ``n`` points
    downwards (``n_z <= 0``), or the surface rises more than ``depth`` above ``c_z`` more
    than ``depth`` inside the vertical cylinder of radius ``r`` over ``c`` (an overhang),
    the shank would pass through the part.

    Both tests look at the samples and the mesh vertices (a k-d tree for the ball, a grid
    for the shank, exact against those points). That overestimates the true distance by at
    most the sampling gap, which can only count a sample *reachable* wrongly. The test
    tries only the tangent ball, though, so it errs both ways at concave creases: in a
    V-groove it excuses a band of wall that the ball sitting in the groove does bring
    within ``depth``, and at a crease between facets it keeps samples that no ball brings
    within ``depth`` (``verify`` removes those afterwards, with a search of the ball
    positions where the program left more than ``depth``). It shares nothing with the
    planner's reachability analysis.

    Parameters
    ----------
    samples : SurfaceSamples
    V : (m, 3) float64
        The mesh vertices.
    tool_radius, depth : float
        Ball radius ``r`` and the material depth that makes a sample unreachable (mm).
    which : (n,) bool, optional
        Test only these samples (the others come back False; every sample still counts as
        a point the ball may meet). ``verify`` tests the interior ones, the only ones whose
        reach it uses: near a bowl's centre of curvature every point is nearly as far as the
        nearest, and the k-d tree's query then visits them all (a 60 mm ball on a 40 mm
        bowl of radius 50: 25 s at 60k samples, 155 s at 200k, for samples no figure used).

    Returns
    -------
    (n,) bool
    """
    P, N = samples.points, samples.normals
    r = float(tool_radius)
    sel = np.arange(len(P)) if which is None else np.flatnonzero(which)
    blocked = np.zeros(len(P), dtype=bool)
    if sel.size == 0:
        return blocked
    C = P[sel] + r * N[sel]
    # at most 100k samples (they are in random order) beside the vertices: a denser set
    # barely changes the answer (a few per mille on the face sample) and costs 15x the time
    X = np.vstack([P[:100_000], np.asarray(V, dtype=np.float64)])
    tree = cKDTree(X)
    hit = (N[sel, 2] <= 0.0) | _any_within(tree, C, r - depth, depth)
    # the shank: a cylinder of radius r above the ball centre. A point of X more than
    # ``depth`` inside it (horizontally) and more than ``depth`` above the centre blocks
    # the position: lifting the tool does not clear it and moving it aside leaves more
    # than ``depth`` at p. Checked exactly against every point of X (a grid of cells with
    # their highest point, so most cells are skipped). An earlier version max-filtered a
    # height map over a disc shrunk by a cell diagonal, which let samples under a bulge
    # through (igea: all 1215 uncut "reachable" samples were under the hair's overhang).
    hit |= _shank_blocked(X, C, r - depth, depth)
    blocked[sel] = hit
    return blocked


#: Fewest queries in a cell of :func:`_any_within` for one exact distance to decide them.
_CROWD = 2


def _any_within(tree, C: np.ndarray, rho: float, depth: float) -> np.ndarray:
    """Whether a point of ``tree`` lies within ``rho`` of each of ``C (m, 3)``: the same
    booleans as ``np.isfinite(tree.query(C, distance_upper_bound=rho)[0])``.

    That query prunes the tree by boxes, so where every point lies just beyond ``rho`` it
    visits them all: near a bowl's centre of curvature when the bowl's radius is about
    the ball's, where all the tangent balls' centres crowd (a cap of radius 4.2 at r = 4:
    26 s at 60k samples, growing with their square). Crowded queries are therefore
    decided in groups first: in cells of ``depth / 2`` holding at least :data:`_CROWD`,
    the exact distance ``d`` to the nearest point from one of them decides the others by
    the triangle inequality (none within ``rho`` where ``d - gap > rho``, one where ``d +
    gap < rho``, with a relative slack of 1e-9); the rest, and every query of an ordinary
    part (the samples lie farther apart than ``depth``), are asked as before.
    """
    out = np.zeros(len(C), dtype=bool)
    todo = np.arange(len(C))
    cells = _cells(C, 0.5 * float(depth)) if len(C) >= _CROWD else None
    if cells is not None:
        first, count = cells
        who = np.flatnonzero(count >= _CROWD)
        if who.size:
            lead = first[who]  # the cell's first query decides the others
            piv = np.unique(lead)
            dp = np.empty(len(C))
            dp[piv] = tree.query(C[piv], k=1, workers=-1)[0]
            gap = np.linalg.norm(C[who] - C[lead], axis=1)
            free = dp[lead] - gap > rho * (1.0 + 1e-9)
            near = dp[lead] + gap < rho * (1.0 - 1e-9)
            out[who[near]] = True
            done = np.zeros(len(C), dtype=bool)
            done[who[free | near]] = True
            todo = np.flatnonzero(~done)
    if len(todo):
        d, _ = tree.query(C[todo], k=1, distance_upper_bound=rho, workers=-1)
        out[todo] = np.isfinite(d)
    return out


def _cells(C: np.ndarray, cell: float):
    """Per point of ``C (m, 3)``: the first point (index) in its cubic cell of side ``cell``
    and how many the cell holds; ``None`` when ``cell`` is not positive or the cells over
    ``C``'s box outnumber an int64 key (a part kilometres wide)."""
    if not (cell > 0 and np.isfinite(cell)):
        return None
    k = np.floor((C - C.min(axis=0)) / cell)
    n = k.max(axis=0) + 1
    if not float(np.prod(n)) < 2.0 ** 62:
        return None
    k = k.astype(np.int64)
    key = (k[:, 0] * int(n[1]) + k[:, 1]) * int(n[2]) + k[:, 2]
    _, first, inv, count = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    return first[inv], count[inv]


def _shank_blocked(X: np.ndarray, C: np.ndarray, rho: float, depth: float) -> np.ndarray:
    """True where a point of ``X`` lies within XY distance ``rho`` of ``C`` and above ``C_z + depth``."""
    out = np.zeros(len(C), dtype=bool)
    if rho <= 0 or len(X) == 0:
        return out
    g = rho / 4.0
    lo = X[:, :2].min(axis=0)
    ij = np.floor((X[:, :2] - lo) / g).astype(np.int64)
    nx, ny = int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1
    cell = ij[:, 0] * ny + ij[:, 1]
    order = np.argsort(cell, kind="stable")
    start = np.searchsorted(cell[order], np.arange(nx * ny + 1))
    Xs = np.ascontiguousarray(X[order])
    zmax = np.full(nx * ny, -np.inf)
    np.maximum.at(zmax, cell, X[:, 2])
    _shank_kernel(Xs, start, zmax, nx, ny, lo[0], lo[1], g, np.ascontiguousarray(C), rho, depth, out)
    return out


@nb.njit(cache=True)
def _shank_hit(Xs, start, zmax, nx, ny, lox, loy, g, cx, cy, top, rho):
    """Whether a point of ``Xs`` lies within XY distance ``rho`` of ``(cx, cy)`` above ``top``."""
    rr = rho * rho
    i0 = max(int(math.floor((cx - rho - lox) / g)), 0)
    i1 = min(int(math.floor((cx + rho - lox) / g)), nx - 1)
    j0 = max(int(math.floor((cy - rho - loy) / g)), 0)
    j1 = min(int(math.floor((cy + rho - loy) / g)), ny - 1)
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            c = i * ny + j
            if zmax[c] <= top:  # nothing in this cell rises above the centre
                continue
            for k in range(start[c], start[c + 1]):
                if Xs[k, 2] > top:
                    dx, dy = Xs[k, 0] - cx, Xs[k, 1] - cy
                    if dx * dx + dy * dy < rr:
                        return True
    return False


@nb.njit(cache=True, parallel=True)
def _shank_kernel(Xs, start, zmax, nx, ny, lox, loy, g, C, rho, depth, out):
    for q in nb.prange(C.shape[0]):
        out[q] = _shank_hit(Xs, start, zmax, nx, ny, lox, loy, g, C[q, 0], C[q, 1], C[q, 2] + depth, rho)


def check_cuts(program: Program) -> None:
    """Refuse a program that cuts nothing.

    Raises
    ------
    GCodeError
        The program has no feed moves (exit code 2, a program that is no finishing pass).
    """
    if not np.any(program.motion == FEED):
        raise GCodeError(f"{program.source}: the program has no feed moves (nothing is cut)")


def verify(mesh, program: Program, tool_radius: float, n_samples: int = 200_000, seed: int = 0,
           scallop: float | None = None, gouge: float | None = None, normals: str = "vertex",
           ray_cap: float | None = None, clearance_cap: float = 5.0, gouge_tol: float = 1e-3,
           samples: SurfaceSamples | None = None, progress=None, judge: str = "interior",
           reach_depth: float | None = None, rest: bool = False, stock: float = 0.0) -> VerifyResult:
    """Simulate ``program`` with a ball of radius ``tool_radius`` on ``mesh`` and measure it.

    Parameters
    ----------
    mesh : conformill.types.Mesh
        The part surface (mm), faces oriented towards the tool (+Z).
    program : Program
        From :func:`conformill.verify.gcode.read_gcode` (tool tip positions).
    tool_radius : float
        Ball radius ``r`` (mm).
    n_samples, seed, normals
        Area-uniform samples (see :func:`conformill.verify.samples.sample_surface`).
    scallop, gouge : float, optional
        Limits (mm). The check fails when scallop p99.9 > ``scallop``, or any sample is
        uncut (when ``scallop`` is given), or ``gouge_max > gouge``. Both are over the
        interior samples (farther than ``r`` from the boundary, 3D distance).
    ray_cap : float, optional
        Remaining material beyond this (default ``2 r``) counts as uncut.
    clearance_cap : float
        Rapid clearances above this are reported as a lower bound (mm).
    gouge_tol : float
        Gouge depth (mm) above which a sample counts in ``gouged_fraction``.
    samples : SurfaceSamples, optional
        Use these samples instead of drawing them from the mesh.
    progress : callable, optional
        Called with the number of samples done after each chunk.
    judge : {"interior", "reachable"}
        Which samples the scallop and uncut limits are checked on: all interior samples
        (default), or only those some 3-axis ball position can bring close enough. That
        set is built in two steps: :func:`unreachable_samples` (the ball touching the
        sample along its normal, and its shank, tested against points, with a leeway of
        ``reach_depth``) removes undercuts and pockets tighter than the ball; then, at
        the samples left with more than the larger of ``scallop`` and ``reach_depth``
        (the limit), :func:`_beyond_any_ball` searches the ball positions reachable from
        above and removes those for which the least material found exceeds the limit
        (creases between facets, which the first test, judged against points, lets
        through: no program can meet the limit there), confirmed by a second, wider and
        deeper search, the best ball checked against this module's own distance to the
        mesh. The second step runs only with
        ``judge="reachable"`` or ``rest``. The gouge limit is always checked on all
        interior samples. All figure sets are reported either way;
        ``summary["reachable"]["tangent_test"]`` holds the figures of the first step
        alone and ``summary["reachable"]["searched"]`` says whether the second ran.
    reach_depth : float, optional
        Material depth (mm) that makes a sample unreachable; default ``scallop`` (or
        ``0.01 r``).
    rest : bool
        With ``scallop``: search the ball positions at every reachable sample left with
        more than ``reach_depth`` (not only where the tangent ball, dropped, leaves more)
        and report, in ``summary["reachable"]["rest"]``, the p99.9 of the material above
        the least the search finds (the program's own share), how many reachable
        samples are left above ``scallop`` (``above_limit``), and how many of those have
        a rest below ``scallop / 2``, up to ``0.9 scallop`` and above that
        (``above_limit_by_rest``). The pass/fail check does not change.
    stock : float
        Material the program was meant to leave on the part (mm; negative: cut into it,
        above ``-tool_radius``): every figure is then measured from the part's offset by
        ``stock``. The remaining material and the gouge are cast from the samples moved
        ``stock`` along their normals (on the offset), against the ball of radius
        ``tool_radius``; the reach tests and the rapid clearance take the ball of radius
        ``tool_radius + stock`` about the same centres on the part
        (:meth:`Program.for_stock`).

    Returns
    -------
    VerifyResult
        ``summary`` holds ``interior`` and ``all`` figure sets (``scallop`` {p50, p99,
        p999, max}, ``uncut_fraction``, ``gouge_max``, ``gouge_where``, ``gouge_line``,
        ...), the interior figures repeated at the top level, the ``reachable`` set's
        (with ``unreachable_fraction``, ``beyond_any_ball`` and its per-mille share of
        the samples the tangent test keeps, ``unconfirmed`` and ``tangent_test``), the
        rapid clearances, the counts, the thresholds and ``pass``.

    Raises
    ------
    ConformillError
        Bad radius (not positive, or more than 100 times the part's size), sample count or
        mesh; a program with no feed moves.
    """
    r0 = float(tool_radius)
    if not (math.isfinite(r0) and r0 > 0):
        raise ConformillError(f"tool radius must be > 0 mm, got {tool_radius!r}")
    stock = check_stock(stock, r0, ConformillError)
    check_ball_size(r0, mesh.V, ConformillError, stock=stock)
    cut_program = program  # the ball of radius r0 as written: what the material is measured against
    program, r = program.for_stock(r0, stock)  # the ball of radius r0 + stock about the same centres
    if judge not in ("interior", "reachable"):
        raise ConformillError(f"judge must be 'interior' or 'reachable', got {judge!r}")
    for nm, v in (("scallop", scallop), ("gouge", gouge)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ConformillError(f"{nm} limit must be >= 0 mm, got {v!r}")
    check_cuts(program)
    V = np.ascontiguousarray(mesh.V, dtype=np.float64)
    F = np.ascontiguousarray(mesh.F, dtype=np.int64)
    if samples is None:
        samples = sample_surface(V, F, n_samples, seed=seed, normals=normals, boundary_spacing=min(0.1, r / 20),
                                 boundary_max=2 * r)
    rem, g, hit, gj = remaining_material(samples.offset(stock), cut_program, r0, ray_cap=ray_cap, progress=progress)
    feed_lines = program.line[program.motion == FEED]
    hit_line = np.where(hit >= 0, feed_lines[np.maximum(hit, 0)], -1)
    gouge_line = np.where(gj >= 0, feed_lines[np.maximum(gj, 0)], -1)
    interior = samples.boundary_distance > r
    depth = reach_depth if reach_depth is not None else (scallop if scallop is not None else 0.01 * r)
    # only the interior samples' reach is used (tangent_ok, the unreachable fractions)
    blocked = unreachable_samples(samples, V, r, depth, which=interior)
    rap = rapid_clearance(V, F, program, r, cap=clearance_cap)
    s_int = _stats(rem[interior], g[interior], samples.points[interior], gouge_line[interior], scallop, gouge_tol)
    s_all = _stats(rem, g, samples.points, gouge_line, scallop, gouge_tol)
    tangent_ok = interior & ~blocked
    searched = judge == "reachable" or bool(rest and scallop is not None)
    if searched:
        limit = max(depth, scallop) if scallop is not None else depth
        # searched from the smaller of the two, so that --rest knows the rest of every
        # judged sample above the limit; only samples left above ``limit`` are excused
        low = min(depth, scallop) if scallop is not None else depth
        beyond, rest_t, unconfirmed = _beyond_any_ball(V, F, r, samples, rem, tangent_ok, low, limit,
                                                       full=bool(rest and scallop is not None))
    else:
        beyond, rest_t, unconfirmed = np.zeros(len(rem), dtype=bool), np.full(len(rem), np.nan), 0
    ok = tangent_ok & ~beyond
    s_reach = _stats(rem[ok], g[ok], samples.points[ok], gouge_line[ok], scallop, gouge_tol)
    n_int = max(int(interior.sum()), 1)
    s_reach["unreachable_fraction"] = float((interior & ~ok).sum() / n_int)
    s_reach["beyond_any_ball"] = int(beyond.sum())
    s_reach["beyond_any_ball_per_mille"] = 1000.0 * float(beyond.sum()) / max(int(tangent_ok.sum()), 1)
    s_reach["unconfirmed"] = unconfirmed
    s_reach["searched"] = searched
    s_t = _stats(rem[tangent_ok], g[tangent_ok], samples.points[tangent_ok], gouge_line[tangent_ok], scallop,
                 gouge_tol)
    s_reach["tangent_test"] = {"samples": s_t["samples"], "scallop": s_t["scallop"],
                               "unreachable_fraction": float((interior & blocked).sum() / n_int)}
    if rest and scallop is not None:
        s_reach["rest"] = _rest_figures(rem, rest_t, ok, scallop)
    summary = {
        "tool_radius": r0,
        "stock": stock,
        "samples": len(samples),
        "interior_samples": int(interior.sum()),
        "seed": int(seed),
        "normals": normals,
        "area_mm2": samples.area,
        "feed_moves": int((program.motion == FEED).sum()),
        "rapid_moves": int((program.motion == RAPID).sum()),
        "feed_length_mm": program.feed_length(),
        "interior": s_int,
        "all": s_all,
        "reachable": s_reach,
        "judged_on": judge,
        "scallop": s_int["scallop"],
        "uncut_fraction": s_int["uncut_fraction"],
        "gouge_max": s_int["gouge_max"],
        "gouge_where": s_int["gouge_where"],
        "gouge_line": s_int["gouge_line"],
        "rapid_min_clearance": rap["rapid_min_clearance"],
        "rapid_min_line": rap["rapid_min_line"],
        "rapid_min_where": rap["rapid_min_where"],
        "rapid_clearance_exact": bool(rap["rapid_min_clearance"] < clearance_cap),
        "retract_min_clearance": rap["retract_min_clearance"],
        "n_rapids": rap["n_rapids"],
        "n_retracts": rap["n_retracts"],
        "thresholds": {"scallop": scallop, "gouge": gouge, "reach_depth": depth},
    }
    fails = []
    sj = s_reach if judge == "reachable" else s_int
    scope = " (reachable)" if judge == "reachable" else ""
    if scallop is not None:
        p999 = sj["scallop"]["p999"]
        if math.isfinite(p999) and p999 > scallop:
            fails.append(f"scallop p99.9{scope} {p999:.4g} mm > {scallop:g} mm")
        if sj["uncut_fraction"] > 0:
            fails.append(f"uncut area{scope} {100 * sj['uncut_fraction']:.3g} %")
    if gouge is not None and s_int["gouge_max"] > gouge:
        fails.append(f"gouge {s_int['gouge_max']:.4g} mm > {gouge:g} mm")
    if scallop is not None or gouge is not None:  # no verdict on no sample
        if not s_int["samples"]:
            fails.append(f"nothing judged: the part has no interior sample (one farther than the tool radius, "
                         f"{r0:g} mm, from its boundary)")
        elif scallop is not None and not sj["samples"]:
            fails.append("nothing judged: no reachable interior sample")
    summary["failures"] = fails
    summary["pass"] = not fails
    return VerifyResult(samples, rem, g, interior, hit_line, gouge_line, rap, summary, reachable=ok, excused=beyond)
