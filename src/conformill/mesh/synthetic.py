"""Analytic test surfaces as disk meshes, generated in code (tests, benchmarks, samples).

Every generator returns a :class:`conformill.types.Mesh` whose faces are counter-clockwise
seen from +Z (normals towards the tool, for a part machined from above) and whose vertices
lie exactly on the analytic surface, so tests can compare against closed forms.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from conformill.types import Mesh


def _orient_up(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Flip faces whose projected (XY) orientation is clockwise."""
    a, b, c = V[F[:, 0], :2], V[F[:, 1], :2], V[F[:, 2], :2]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    F = F.copy()
    F[cross < 0] = F[cross < 0][:, [0, 2, 1]]
    return F


def polygon_disk(outline: np.ndarray, spacing: float, jitter: float = 0.0, seed: int = 0):
    """Triangulate the inside of a simple polygon (planar, XY) with about ``spacing`` edges.

    Parameters
    ----------
    outline : (k, 2) float64
        Simple polygon, counter-clockwise, not closed (last != first).
    spacing : float
        Target edge length.
    jitter : float
        Random displacement of interior points as a fraction of ``spacing`` (irregular
        triangulations); deterministic for a given ``seed``.

    Returns
    -------
    P : (n, 2) float64
    F : (m, 3) int64
        Counter-clockwise triangles. Boundary vertices come first, in outline order.
    """
    from matplotlib.path import Path as MplPath

    outline = np.asarray(outline, dtype=np.float64)
    # resample the outline at ``spacing``
    closed = np.vstack([outline, outline[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    bpts = []
    for i, L in enumerate(seg):
        k = max(1, int(np.ceil(L / spacing)))
        t = np.arange(k) / k
        bpts.append(closed[i] + t[:, None] * (closed[i + 1] - closed[i]))
    B = np.vstack(bpts)
    lo, hi = outline.min(0), outline.max(0)
    h = spacing * np.sqrt(3) / 2
    ys = np.arange(lo[1] + h / 2, hi[1], h)
    pts = []
    for r, y in enumerate(ys):
        xs = np.arange(lo[0] + (spacing / 2 if r % 2 else 0.0), hi[0], spacing)
        pts.append(np.column_stack([xs, np.full_like(xs, y)]))
    I = np.vstack(pts)
    if jitter > 0:
        rng = np.random.default_rng(seed)
        I = I + rng.uniform(-jitter, jitter, I.shape) * spacing
    path = MplPath(closed)
    inside = path.contains_points(I)
    I = I[inside]
    # keep interior points away from the outline to avoid slivers
    from scipy.spatial import cKDTree

    d, _ = cKDTree(B).query(I)
    I = I[d > 0.5 * spacing]
    P = np.vstack([B, I])
    tri = Delaunay(P)
    F = tri.simplices.astype(np.int64)
    cen = P[F].mean(axis=1)
    F = F[path.contains_points(cen)]
    # Qhull closes runs of collinear outline points with flat triangles: drop them (their
    # middle vertex then leaves the outline, which stays the same polygon)
    a, b, c = P[F[:, 0]], P[F[:, 1]], P[F[:, 2]]
    area2 = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    F = F[area2 > 1e-6 * spacing * spacing]
    used = np.unique(F)
    remap = np.full(len(P), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    P = P[used]
    F = remap[F]
    a, b, c = P[F[:, 0]], P[F[:, 1]], P[F[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    F[cross < 0] = F[cross < 0][:, [0, 2, 1]]
    return P, F


def regular_polygon(n_sides: int, radius: float) -> np.ndarray:
    """Vertices of a regular polygon on a circle, counter-clockwise, ``(n_sides, 2)``."""
    t = 2 * np.pi * np.arange(n_sides) / n_sides
    return radius * np.column_stack([np.cos(t), np.sin(t)])


def star_outline(n_points: int = 5, r_outer: float = 60.0, r_inner: float = 35.0, samples: int = 200):
    """A smooth non-convex (star-like) outline, counter-clockwise."""
    t = 2 * np.pi * np.arange(samples) / samples
    r = 0.5 * (r_outer + r_inner) + 0.5 * (r_outer - r_inner) * np.cos(n_points * t)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def notched_outline(width: float = 120.0, height: float = 80.0, notch: float = 30.0):
    """A rectangle with a rectangular notch cut into its top edge (non-convex), CCW."""
    w, h, n = width / 2, height / 2, notch / 2
    return np.array(
        [[-w, -h], [w, -h], [w, h], [n, h], [n, h - notch], [-n, h - notch], [-n, h], [-w, h]],
        dtype=np.float64,
    )


def height_field(outline, z_func, spacing: float, jitter: float = 0.0, seed: int = 0, name="height_field"):
    """Mesh of ``z = z_func(x, y)`` over a polygon outline.

    Parameters
    ----------
    outline : (k, 2) float64
    z_func : callable
        Vectorized ``(x, y) -> z``.
    spacing, jitter, seed
        See :func:`polygon_disk`.
    """
    P, F = polygon_disk(outline, spacing, jitter, seed)
    V = np.column_stack([P, z_func(P[:, 0], P[:, 1])])
    return Mesh(V=V.astype(np.float64), F=F, name=name)


def plane(size: float = 100.0, spacing: float = 5.0, jitter: float = 0.0, seed: int = 0, z: float = 0.0):
    """A flat square ``[-size/2, size/2]^2`` at height ``z``."""
    s = size / 2
    outline = np.array([[-s, -s], [s, -s], [s, s], [-s, s]], dtype=np.float64)
    return height_field(outline, lambda x, y: np.full_like(x, z), spacing, jitter, seed, name="plane")


def sphere_cap(R: float = 50.0, radius_xy: float = 30.0, spacing: float = 2.0, concave: bool = False,
               jitter: float = 0.0, seed: int = 0):
    """Cap of a sphere of radius ``R`` over a disk of radius ``radius_xy``.

    Convex (dome, centre at ``(0, 0, -sqrt(R^2 - ...))``) or concave (bowl). Vertices lie
    exactly on the sphere.
    """
    outline = regular_polygon(max(16, int(2 * np.pi * radius_xy / spacing)), radius_xy)
    sign = -1.0 if concave else 1.0

    def z(x, y):
        return sign * np.sqrt(np.maximum(R * R - x * x - y * y, 0.0))

    m = height_field(outline, z, spacing, jitter, seed, name="bowl" if concave else "dome")
    return m


def v_groove(a_deg: float = 30.0, half: float = 12.0, step: float = 0.25):
    """A V-groove ``z = |x| tan(a)`` over ``[-half, half]^2`` on a regular grid (``step`` in
    X, ``2 step`` in Y) with a vertex row on the crease ``x = 0``, so both walls are exact
    planes. A ball of radius ``r`` resting on it has its centre at ``|x| tan(a) + r / cos(a)``
    (for ``|x| <= half - r sin(a)``), wedged on the crease at ``x = 0``."""
    x = np.arange(-half, half + 1e-9, step)
    y = np.arange(-half, half + 1e-9, 2 * step)
    X, Y = np.meshgrid(x, y)
    V = np.column_stack([X.ravel(), Y.ravel(), np.abs(X.ravel()) * np.tan(np.radians(a_deg))])
    nx = len(x)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(len(y) - 1))
    v0 = (j * nx + i).ravel()
    F = np.vstack([np.column_stack([v0, v0 + 1, v0 + nx + 1]), np.column_stack([v0, v0 + nx + 1, v0 + nx])])
    return Mesh(V=V, F=F.astype(np.int64), name="v-groove")


def cylinder_patch(R: float = 40.0, length: float = 80.0, half_angle: float = 0.9, spacing: float = 2.0,
                   concave: bool = False, jitter: float = 0.0, seed: int = 0):
    """Part of a cylinder of radius ``R`` with axis along X, seen from +Z.

    Convex: ``z = sqrt(R^2 - y^2)``; concave (a trough): ``z = -sqrt(R^2 - y^2)``.
    ``half_angle`` (rad) limits ``|y| <= R sin(half_angle)``.
    """
    w = R * np.sin(half_angle)
    outline = np.array([[-length / 2, -w], [length / 2, -w], [length / 2, w], [-length / 2, w]])
    sign = -1.0 if concave else 1.0
    return height_field(outline, lambda x, y: sign * np.sqrt(R * R - y * y), spacing, jitter, seed,
                        name="trough" if concave else "cylinder")


def overhang_cylinder(R: float = 8.0, length: float = 40.0, half_angle: float = 2.4, step: float = 0.6):
    """A cylinder of radius ``R`` with axis along X wrapped past its sides: an overhang.

    Vertices ``(x, R sin(t), R cos(t))`` on a regular grid over ``|x| <= length / 2`` and
    ``|t| <= half_angle`` (rad; past ``pi / 2`` the surface faces down, ``n_z = cos(t)``),
    faces oriented outwards (towards the tool on the top). Not a height field, so it is
    built here rather than by :func:`height_field`.
    """
    nx = int(np.ceil(length / step)) + 1
    nt = int(np.ceil(2 * half_angle * R / step)) + 1
    X, T = np.meshgrid(np.linspace(-length / 2, length / 2, nx), np.linspace(-half_angle, half_angle, nt),
                       indexing="ij")
    V = np.column_stack([X.ravel(), R * np.sin(T).ravel(), R * np.cos(T).ravel()])
    idx = np.arange(nx * nt).reshape(nx, nt)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    outward = np.einsum("ij,ij->i", n, V[F].mean(axis=1) * [0.0, 1.0, 1.0])  # from the axis
    if np.count_nonzero(outward < 0) > len(F) // 2:
        F = F[:, ::-1]
    return Mesh(V=V, F=np.ascontiguousarray(F, dtype=np.int64), name="overhang cylinder")


def freeform_patch(spacing: float = 2.0, jitter: float = 0.3, seed: int = 1):
    """A CAD-like free-form patch (smooth bumps and a saddle) over a notched outline.

    About 120 x 80 mm, relief about 20 mm, slopes below 45 degrees.
    """

    def z(x, y):
        return (
            12.0 * np.exp(-((x - 25) ** 2 + (y + 10) ** 2) / 900.0)
            - 6.0 * np.exp(-((x + 30) ** 2 + (y - 5) ** 2) / 600.0)
            + 0.0015 * (x * x - y * y)
            + 3.0 * np.sin(x / 25.0)
        )

    return height_field(notched_outline(), z, spacing, jitter, seed, name="freeform_patch")


def _wavy_outline(rx: float, ry: float, waves, samples: int = 360):
    """A closed outline ``r(t) = 1 + sum a cos(k t + phase)`` on an ellipse, CCW."""
    t = 2 * np.pi * np.arange(samples) / samples
    r = np.ones_like(t)
    for k, a, ph in waves:
        r += a * np.cos(k * t + ph)
    return np.column_stack([rx * r * np.cos(t), ry * r * np.sin(t)])


def face_like(seed: int = 0, spacing: float = 1.1, jitter: float = 0.3, size: float = 130.0):
    """A face-like relief: a dome with a nose, brow, cheeks and eye sockets (seeded variations).

    About ``size`` x ``0.8 size`` mm over a wavy, non-convex outline; relief about 25-30 mm;
    slopes up to about 55 degrees; concave radii above about 10 mm (twice a 4 mm ball and
    more). ``spacing`` 1.1 gives about 20k irregular faces.
    """
    rng = np.random.default_rng(seed)
    a, b = size / 2, 0.4 * size
    waves = [(2, 0.03 * rng.uniform(0.5, 1.0), rng.uniform(0, 2 * np.pi)),
             (3, 0.06 * rng.uniform(0.7, 1.0), rng.uniform(0, 2 * np.pi)),
             (5, 0.025 * rng.uniform(0.5, 1.0), rng.uniform(0, 2 * np.pi))]
    outline = _wavy_outline(0.93 * a, 0.93 * b, waves)
    dome = 16.0 + 4.0 * rng.uniform()
    nose = 9.0 + 3.0 * rng.uniform()
    eye = 4.0 + 1.5 * rng.uniform()
    tilt = rng.uniform(-0.1, 0.1)

    def z(x, y):
        x = x + tilt * y
        q = (x / a) ** 2 + (y / b) ** 2
        base = dome * np.exp(-1.6 * q)
        g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
        return (base
                + nose * g(2.0, 0.0, 14.0, 8.0)  # nose along x
                + 3.0 * g(22.0, 0.0, 6.0, 20.0)  # brow ridge
                - eye * g(15.0, 15.0, 9.0, 8.0) - eye * g(15.0, -15.0, 9.0, 8.0)  # sockets
                + 3.0 * g(-8.0, 22.0, 14.0, 10.0) + 3.0 * g(-8.0, -22.0, 14.0, 10.0)  # cheeks
                + 2.0 * g(-25.0, 0.0, 5.0, 14.0))  # lips

    return height_field(outline, z, spacing, jitter, seed, name=f"face_like_{seed}")


def cad_like(seed: int = 0, spacing: float = 1.1, jitter: float = 0.3, size: float = 130.0):
    """A CAD-like free-form panel: blended bumps, a saddle and a valley (seeded variations).

    About ``size`` x ``0.75 size`` mm over a notched (non-convex) outline with rounded
    corners; relief about 20-30 mm; slopes up to about 50 degrees; concave radii above
    about 10 mm.
    """
    rng = np.random.default_rng(seed + 1000)
    w, h = size, 0.75 * size
    o = notched_outline(w, h, notch=0.25 * size)
    # round the outline: resample finely and smooth the corners with a short moving average
    closed = np.vstack([o, o[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    t = np.concatenate([[0], np.cumsum(seg)])
    s = np.arange(0, t[-1], 0.5)
    P = np.column_stack([np.interp(s, t, closed[:, 0]), np.interp(s, t, closed[:, 1])])
    k = 13
    Pp = np.vstack([P[-k:], P, P[:k]])
    ker = np.ones(2 * k + 1) / (2 * k + 1)
    outline = np.column_stack([np.convolve(Pp[:, 0], ker, "valid"), np.convolve(Pp[:, 1], ker, "valid")])[::4]
    c = rng.uniform(-1, 1, 6)

    def z(x, y):
        g = lambda cx, cy, sx, sy: np.exp(-(((x - cx) / sx) ** 2 + ((y - cy) / sy) ** 2))  # noqa: E731
        return (14.0 * (1 + 0.2 * c[0]) * g(0.25 * w + 5 * c[1], -0.1 * h, 22.0, 18.0)
                - 7.0 * (1 + 0.2 * c[2]) * g(-0.25 * w, 0.05 * h + 5 * c[3], 18.0, 16.0)
                + 0.0012 * (x * x - y * y) * (1 + 0.2 * c[4])
                + 4.0 * np.sin(x / 22.0 + c[5]) + 0.04 * y)

    return height_field(outline, z, spacing, jitter, seed, name=f"cad_like_{seed}")
