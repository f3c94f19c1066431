"""Boundary maps: circle and rectangle, and the choice of rectangle corners (METHOD section 1c).

The boundary loop comes from :func:`conformill.mesh.topology.boundary_loops`, which keeps the
interior on the left. Both maps send it counter-clockwise round the domain, so a mesh whose faces
are counter-clockwise seen from the tool maps to counter-clockwise (positive) triangles: no
global flip.
"""

from __future__ import annotations

import numpy as np

from conformill.errors import ParameterizationError

#: minimum smoothed turning (radians) for a boundary vertex to count as a real corner
CORNER_MIN_TURN = np.radians(30.0)
_TIE = np.radians(5.0)


def chord_lengths(V: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Cumulative chord length along a closed loop.

    Parameters
    ----------
    V : (n, 3) float64
    loop : (b,) int64

    Returns
    -------
    (b + 1,) float64
        ``s[0] = 0``, ``s[k]`` the length from ``loop[0]`` to ``loop[k]``, ``s[b] = L``.
    """
    P = V[loop]
    seg = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def circle_map(V: np.ndarray, loop: np.ndarray):
    """Map the boundary to a circle by chord length (METHOD 1c).

    ``R0 = L / (2 pi)``, centre at the origin, vertex ``k`` at angle ``2 pi s_k / L``
    (``loop[0]`` at angle 0), counter-clockwise.

    Returns
    -------
    uv_b : (b, 2) float64
    radius : float
    """
    s = chord_lengths(V, loop)
    L = s[-1]
    if not L > 0:
        raise ParameterizationError("the boundary loop has zero length")
    R = L / (2 * np.pi)
    t = 2 * np.pi * s[:-1] / L
    return R * np.column_stack([np.cos(t), np.sin(t)]), float(R)


def rectangle_map(V: np.ndarray, loop: np.ndarray, corners):
    """Map the boundary to ``[0, X] x [0, Y]`` by chord length (METHOD 1c).

    ``corners`` are four vertex ids on ``loop`` in loop order; the part from ``corners[0]`` to
    ``corners[1]`` (length ``L1``) goes to the bottom side ``(0,0)-(X,0)``, then the right, top and
    left sides. ``X = (L1 + L3) / 2``, ``Y = (L2 + L4) / 2``; each part is mapped to its side in
    proportion to chord length, so the corners land on the rectangle corners.

    Returns
    -------
    uv_b : (b, 2) float64
    size : (float, float)
        ``(X, Y)``.
    """
    pos = corner_positions(loop, corners, len(V))
    b = len(loop)
    start = pos[0]
    rl = np.roll(loop, -start)  # loop starting at corners[0]
    p = (pos - start) % b
    s = chord_lengths(V, rl)
    ends = np.concatenate([p, [b]])
    Ls = s[ends[1:]] - s[ends[:-1]]
    if np.any(Ls <= 0):
        raise ParameterizationError(f"rectangle corners {tuple(int(c) for c in corners)} make a side of zero length")
    X = 0.5 * (Ls[0] + Ls[2])
    Y = 0.5 * (Ls[1] + Ls[3])
    side = np.searchsorted(ends, np.arange(b), side="right") - 1  # 0..3
    t = (s[:-1] - s[ends[side]]) / Ls[side]  # 0..1 along the side
    c0 = np.array([[0.0, 0.0], [X, 0.0], [X, Y], [0.0, Y]])
    c1 = np.roll(c0, -1, axis=0)
    uv_rl = c0[side] + t[:, None] * (c1[side] - c0[side])
    uv = np.empty_like(uv_rl)
    uv[(np.arange(b) + start) % b] = uv_rl
    return uv, (float(X), float(Y))


def check_corner_ids(corners, n_vertices: int | None = None) -> list:
    """Four corner vertex ids as ints, checked without the boundary: four distinct ids,
    each in the mesh (``0..n_vertices-1``; without ``n_vertices``, 0 or more).

    Raises
    ------
    ParameterizationError
        What is wrong, with the ids (exit code 2: input that names no vertices of a
        rectangle).
    """
    try:
        c = [int(x) for x in corners]
    except (TypeError, ValueError):
        raise ParameterizationError(f"corners must be four vertex ids, got {corners!r}") from None
    if len(c) != 4 or len(set(c)) != 4:
        raise ParameterizationError(f"corners must be four distinct vertex ids, got {tuple(c)}")
    for x in c:
        if x < 0 or (n_vertices is not None and x >= n_vertices):
            ids = "ids are 0 or more" if n_vertices is None else f"ids 0..{int(n_vertices) - 1}"
            raise ParameterizationError(f"corner vertex id {x} is not in the mesh ({ids})")
    return c


def corner_positions(loop: np.ndarray, corners, n_vertices: int | None = None) -> np.ndarray:
    """Positions of four corner vertex ids on the loop, checked.

    Parameters
    ----------
    loop : (b,) int64
        The boundary loop (vertex ids).
    corners : sequence of 4 int
    n_vertices : int, optional
        Vertices of the mesh: an id outside ``0..n_vertices-1`` is named as not in the
        mesh (without it, only a negative id is).

    Raises
    ------
    ParameterizationError
        Not four distinct ids, an id not in the mesh, an id not on the boundary, or not in
        boundary order.
    """
    c = check_corner_ids(corners, n_vertices)
    where = np.full(int(loop.max()) + 1, -1, dtype=np.int64)
    where[loop] = np.arange(len(loop))
    pos = np.array([where[x] if x < len(where) else -1 for x in c], dtype=np.int64)
    off = [x for x, p in zip(c, pos) if p < 0]
    if off:
        raise ParameterizationError(f"corner vertices {off} are not on the boundary loop")
    rel = (pos - pos[0]) % len(loop)
    if not np.all(np.diff(rel) > 0):
        raise ParameterizationError(
            f"corners {tuple(c)} are not in boundary order (positions on the loop {pos.tolist()}); "
            f"for example {tuple(int(x) for x in np.asarray(c)[np.argsort(rel)])} is"
        )
    return pos


def boundary_turning(V: np.ndarray, F: np.ndarray, loop: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Geodesic turning ``pi - (sum of face angles)`` at each boundary vertex, ``(b,)``.

    Positive at convex corners (``pi/2`` at a right-angled corner), negative at notches, about
    0 on smooth parts. It is intrinsic: a corner is a corner however the surface is bent.
    """
    n = V.shape[0]
    total = np.bincount(F.reshape(-1), weights=angles.reshape(-1), minlength=n)
    return np.pi - total[loop]


def auto_corners(V: np.ndarray, loop: np.ndarray, turning: np.ndarray) -> tuple:
    """Choose four rectangle corners on the boundary automatically.

    Rule (documented for users):

    1. Put the boundary in the plane of its principal axes (PCA of the boundary points, the
       frame handed so that the loop runs counter-clockwise) and take its bounding box there.
    2. A first guess for each corner is the boundary vertex nearest to each bounding-box corner.
       On rounded outlines (an ellipse, a face) this splits the boundary into four arcs centred
       on the ends of the principal axes, with the rectangle's aspect close to the outline's.
    3. Each guess snaps to the sharpest *real* corner within ``L / 8`` of arc length of it: a
       boundary vertex whose turning summed over ``L / 100`` either side is at least 30 degrees
       and is the largest in that window (ties within 5 degrees: the one nearest the guess).
       On outlines with real corners (rectangles, CAD
       patches) the four corners therefore land on the sharpest turning points, spread out
       round the loop; notches (negative turning) are never chosen.
    4. ``corners[0]`` is the guess of the bounding-box corner at minimum (x, y): the rectangle's
       u axis follows the outline's longest principal axis.

    Returns
    -------
    tuple of 4 int
        Vertex ids in boundary order.
    """
    b = len(loop)
    P = V[loop]
    s = chord_lengths(V, loop)
    L = s[-1]
    seg = np.diff(s)
    wgt = 0.5 * (seg + np.roll(seg, 1))  # arc length around each vertex
    c = (wgt[:, None] * P).sum(0) / wgt.sum()
    Q = P - c
    C = (wgt[:, None, None] * Q[:, :, None] * Q[:, None, :]).sum(0)
    _, vecs = np.linalg.eigh(C)
    e1, e2 = vecs[:, 2], vecs[:, 1]
    x, y = Q @ e1, Q @ e2
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    if area < 0:
        y = -y
    box = np.array([[x.min(), y.min()], [x.max(), y.min()], [x.max(), y.max()], [x.min(), y.max()]])
    d2 = (x[None, :] - box[:, 0:1]) ** 2 + (y[None, :] - box[:, 1:2]) ** 2
    guess = np.argmin(d2, axis=1)  # positions on the loop
    # smoothed corner strength: turning summed over +-L/100 of arc length
    half = L / 100.0
    s3 = np.concatenate([s[:-1] - L, s[:-1], s[:-1] + L])
    t3 = np.concatenate([turning] * 3)
    ct = np.concatenate([[0.0], np.cumsum(t3)])
    lo = np.searchsorted(s3, s[:-1] - half, side="left")
    hi = np.searchsorted(s3, s[:-1] + half, side="right")
    strength = ct[hi] - ct[lo]
    picked = []
    for g in guess:
        dist = np.abs(s[:-1] - s[g])
        dist = np.minimum(dist, L - dist)
        near = np.flatnonzero((dist <= L / 8) & (strength >= CORNER_MIN_TURN))
        if len(near):
            # the sharpest in the neighbourhood (ties within 5 degrees go to the one nearest
            # the guess); within the plateau of the smoothed strength around it, the vertex
            # with the largest turning of its own
            top = strength[near].max() - _TIE
            cand = near[strength[near] >= top]
            g1 = cand[np.argmin(dist[cand])]
            d1 = np.abs(s[:-1] - s[g1])
            d1 = np.minimum(d1, L - d1)
            plateau = np.flatnonzero((d1 <= half) & (strength >= top))
            g = plateau[np.argmax(turning[plateau])]
        picked.append(int(g))
    pos = np.array(picked)
    # keep four distinct positions in loop order, starting from the min-(x, y) corner
    if len(set(pos.tolist())) < 4:
        # degenerate outline (e.g. very few boundary vertices): fall back to equal arc lengths
        # (the vertex at or before each quarter; if two coincide, the nearest to each quarter;
        # if two still coincide, every b/4-th vertex)
        start = pos[0]
        tgt = (s[start] + L * np.arange(4) / 4) % L
        pos = np.searchsorted(s[:-1], tgt, side="right") - 1
        if len(set(pos.tolist())) < 4:
            gap = np.abs(s[:-1][None, :] - tgt[:, None])
            pos = np.argmin(np.minimum(gap, L - gap), axis=1)
        if len(set(pos.tolist())) < 4 and b >= 4:
            pos = (start + np.round(np.arange(4) * b / 4).astype(np.int64)) % b
        if len(set(pos.tolist())) < 4:
            raise ParameterizationError(
                f"cannot choose four distinct rectangle corners on a boundary of {b} vertices"
            )
    rel = (pos - pos[0]) % b
    order = np.argsort(rel)
    return tuple(int(loop[p]) for p in pos[order])
