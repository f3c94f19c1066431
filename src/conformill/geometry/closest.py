"""Closest points of a triangle and a segment to a point (compiled, for the cutter, the
verifier, the path families and the pattern's rest)."""

from __future__ import annotations

from numba import njit
from numba import types as _nt

__all__ = ["closest_on_triangle", "segment_d2"]


#: Compiled once and called (not inlined by numba into each caller: the cutter's settle
#: kernel, the fold search and the verifier's distances each held copies, about half of
#: those kernels' compile time on a fresh install).
_SIG = _nt.UniTuple(_nt.float64, 3)(*([_nt.float64] * 12))


@njit(_SIG, cache=True, nogil=True)
def closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Point of triangle ``abc`` nearest to ``p``, as ``(qx, qy, qz)``.

    By the Voronoi regions of the vertices, edges and face (Ericson, *Real-Time Collision
    Detection*, 5.1.5).
    """
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    vc = d1 * d4 - d3 * d2
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz)
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@njit(cache=True, nogil=True, inline="always")
def segment_d2(px, py, pz, ax, ay, az, bx, by, bz):
    """Squared distance from ``p`` to the segment ``ab`` (a segment shorter than 1e-150
    counts as its end ``a``). Inlined into its callers: it is a few operations, called in
    their innermost loops."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    uu = ux * ux + uy * uy + uz * uz
    t = 0.0
    if uu > 1e-300:
        t = min(max((wx * ux + wy * uy + wz * uz) / uu, 0.0), 1.0)
    dx, dy, dz = wx - t * ux, wy - t * uy, wz - t * uz
    return dx * dx + dy * dy + dz * dz
