"""Is a triangle mesh a topological disk? If not, say what is wrong and where.

The parameterization (METHOD section 1) needs a single connected, edge- and
vertex-manifold, consistently oriented triangle mesh with exactly one boundary loop and
Euler characteristic ``V - E + F = 1``. :func:`validate_disk` checks these in an order
chosen so that the message names the root cause: a bow-tie vertex also makes two boundary
loops meet, and a flipped face also breaks the boundary walk, so the local defects
(indices, degenerate faces, non-manifold edges and vertices, orientation) are checked
before the global counts (components, boundary loops, Euler characteristic).

A valid disk is confirmed by one linear-time numba pass
(:func:`conformill.mesh.topology.disk_summary` plus a degenerate-face scan); only when that
pass finds something wrong does the diagnosis run, vectorized around one sort of the ``3m``
half-edge keys plus two sparse connected-component labellings (corner fans, vertex
components), to name the defect and where it is.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from conformill.errors import MeshError
from conformill.mesh.topology import disk_summary, half_edges, loops_from_half_edges
from conformill.types import Mesh

#: a face is degenerate when twice its area is below this times the squared bounding-box
#: diagonal (about 1e-6 of the diagonal for the height of a face one diagonal long)
DEGENERATE_AREA_REL = 1e-12

#: how many ids a message quotes before "... (N in all)"
SHOW = 6


def fmt_ids(ids, show: int = SHOW) -> str:
    """``"3, 17, 42"`` or ``"3, 17, 42, ... (12 in all)"`` for an id list or array of rows."""
    ids = list(ids)
    parts = []
    for x in ids[:show]:
        if np.ndim(x) == 0:
            parts.append(str(int(x)))
        else:
            parts.append("(" + ", ".join(str(int(y)) for y in x) + ")")
    text = ", ".join(parts)
    if len(ids) > show:
        text += f", ... ({len(ids)} in all)"
    return text


def _where(mesh: Mesh) -> str:
    return mesh.name if mesh.name else "mesh"


def _plural(k: int, word: str, plural: str | None = None) -> str:
    return f"{k} {word}" if k == 1 else f"{k} {plural or word + 's'}"


def check_arrays(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """Coerce and check shapes, index range and finiteness of a mesh's arrays.

    Returns
    -------
    V : (n, 3) float64
    F : (m, 3) int64

    Raises
    ------
    MeshError
        Bad shapes, no faces, face indices out of range, NaN/inf coordinates of
        referenced vertices, or unreferenced vertices.
    """
    where = _where(mesh)
    V = np.asarray(mesh.V)
    F = np.asarray(mesh.F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise MeshError(f"{where}: vertices must be an (n, 3) array, got shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"{where}: faces must be an (m, 3) array of triangles, got shape {F.shape}")
    if len(F) == 0:
        raise MeshError(f"{where}: the mesh has no faces ({len(V)} vertices)")
    if not np.issubdtype(F.dtype, np.integer):
        raise MeshError(f"{where}: face indices must be integers, got {F.dtype}")
    V = V.astype(np.float64, copy=False)
    F = F.astype(np.int64, copy=False)
    n = len(V)
    bad = np.flatnonzero(((F < 0) | (F >= n)).any(axis=1))
    if len(bad):
        f = int(bad[0])
        raise MeshError(
            f"{where}: {_plural(len(bad), 'face')} reference vertices outside 0..{n - 1}: "
            f"faces {fmt_ids(bad)} (face {f} = {F[f].tolist()})"
        )
    nonfinite = np.flatnonzero(~np.isfinite(V).all(axis=1))
    if len(nonfinite):
        raise MeshError(
            f"{where}: {_plural(len(nonfinite), 'vertex', 'vertices')} with NaN or infinite "
            f"coordinates: vertices {fmt_ids(nonfinite)}"
        )
    used = np.bincount(F.reshape(-1), minlength=n) > 0
    unused = np.flatnonzero(~used)
    if len(unused):
        raise MeshError(
            f"{where}: {_plural(len(unused), 'vertex', 'vertices')} not used by any face: "
            f"vertices {fmt_ids(unused)}"
        )
    return V, F


def degenerate_faces(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces with a repeated vertex index, and faces of (numerically) zero area.

    A face is of zero area when ``|(b - a) x (c - a)| <= DEGENERATE_AREA_REL * d^2`` with
    ``d`` the bounding-box diagonal of the mesh (the mesh scale).

    Returns
    -------
    repeated : (k,) int64
        Face ids with ``F[f, i] == F[f, j]`` for some ``i != j``.
    zero_area : (l,) int64
        Other face ids of zero area.
    """
    repeated = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cross = np.cross(b - a, c - a)
    area2 = np.sqrt(np.einsum("ij,ij->i", cross, cross))
    diag2 = float(np.sum((V.max(axis=0) - V.min(axis=0)) ** 2))
    zero = (area2 <= DEGENERATE_AREA_REL * diag2) & ~repeated
    return np.flatnonzero(repeated), np.flatnonzero(zero)


@njit(cache=True)
def _n_suspect_faces(V, F, area2_min):
    """Faces with a repeated index or ``|(b - a) x (c - a)| <= area2_min`` (numba)."""
    bad = 0
    for f in range(F.shape[0]):
        i0 = F[f, 0]
        i1 = F[f, 1]
        i2 = F[f, 2]
        if i0 == i1 or i1 == i2 or i2 == i0:
            bad += 1
            continue
        e1x = V[i1, 0] - V[i0, 0]
        e1y = V[i1, 1] - V[i0, 1]
        e1z = V[i1, 2] - V[i0, 2]
        e2x = V[i2, 0] - V[i0, 0]
        e2y = V[i2, 1] - V[i0, 1]
        e2z = V[i2, 2] - V[i0, 2]
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        if not np.sqrt(cx * cx + cy * cy + cz * cz) > area2_min:
            bad += 1
    return bad


def is_clean_disk(V: np.ndarray, F: np.ndarray) -> bool:
    """Fast check (linear time, numba) that checked arrays form a valid disk.

    True when no face is degenerate (with a 2x margin on :data:`DEGENERATE_AREA_REL`, so
    that borderline faces go to the exact check), every edge is manifold and consistently
    oriented, every vertex has one fan, and there is one component, one boundary loop and
    Euler characteristic 1. False means :func:`validate_disk` must look closer.
    """
    diag2 = float(np.sum((V.max(axis=0) - V.min(axis=0)) ** 2))
    if _n_suspect_faces(V, F, 2.0 * DEGENERATE_AREA_REL * diag2):
        return False
    s = disk_summary(F, len(V))
    return (s["bad_edges"] == 0 and s["bad_vertices"] == 0 and s["components"] == 1
            and s["boundary_loops"] == 1 and s["euler"] == 1)


def _edge_pairs(he: np.ndarray, n: int):
    """Group the half-edges by undirected edge with one sort.

    Returns
    -------
    order : (3m,) int64
        Half-edge ids sorted by edge key.
    starts : (e,) int64
        Position in ``order`` where each edge's run starts.
    counts : (e,) int64
        Faces per edge.
    """
    key = np.minimum(he[:, 0], he[:, 1]) * n + np.maximum(he[:, 0], he[:, 1])
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.ones(len(ks), dtype=bool)
    first[1:] = ks[1:] != ks[:-1]
    starts = np.flatnonzero(first)
    counts = np.diff(np.append(starts, len(ks)))
    return order, starts, counts


def _fans_per_vertex(F: np.ndarray, he: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Number of face fans around each vertex (1 for a manifold vertex).

    Corner ``h = 3 f + k`` is face ``f`` at vertex ``F[f, k]``; half-edge ``h`` goes from
    corner ``h`` to corner ``next(h) = 3 f + (k + 1) % 3``. Two faces sharing an edge join
    their corners at both ends of the edge; the fans of a vertex are the connected
    components of its corners.

    Parameters
    ----------
    a, b : (p,) int64
        The two half-edges of every edge used by exactly two faces.

    Returns
    -------
    (n,) int64
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    m3 = 3 * len(F)
    nxt = lambda h: 3 * (h // 3) + (h % 3 + 1) % 3  # noqa: E731
    same_dir = he[a, 0] == he[b, 0]
    na, nb = nxt(a), nxt(b)
    # same direction: start-start and end-end; opposite (the usual case): start-end
    u = np.concatenate([a, na])
    v = np.concatenate([np.where(same_dir, b, nb), np.where(same_dir, nb, b)])
    G = sp.coo_matrix((np.ones(len(u), dtype=np.int8), (u, v)), shape=(m3, m3)).tocsr()
    ncomp, labels = connected_components(G, directed=False)
    comp_vertex = np.empty(ncomp, dtype=np.int64)
    comp_vertex[labels] = F.reshape(-1)
    return np.bincount(comp_vertex, minlength=int(F.max()) + 1)


def validate_disk(mesh: Mesh) -> None:
    """Check that a mesh is a topological disk; raise :class:`MeshError` naming the defect.

    Checks, in this order (the first that fails raises):

    1. arrays: ``(n, 3)`` vertices, ``(m, 3)`` integer faces, ``m > 0``, indices in range,
       finite coordinates, every vertex used by a face;
    2. degenerate faces: a repeated vertex index, or zero area relative to the mesh scale
       (:data:`DEGENERATE_AREA_REL` times the squared bounding-box diagonal);
    3. non-manifold edges: an edge used by more than two faces;
    4. non-manifold vertices: the faces around a vertex form more than one fan (bow-tie);
    5. inconsistent orientation: two faces traverse their shared edge in the same
       direction;
    6. one connected component;
    7. exactly one boundary loop (none: a closed surface);
    8. Euler characteristic ``V - E + F = 1`` (otherwise the surface has handles).

    Parameters
    ----------
    mesh : Mesh
        ``V (n, 3)``, ``F (m, 3)``; ``mesh.name`` is quoted in messages.

    Raises
    ------
    MeshError
        The message names the defect and where it is: vertex ids, face ids, edges as
        vertex pairs (first few and the count), loop counts with edge counts and lengths.
    """
    where = _where(mesh)
    V, F = check_arrays(mesh)
    if is_clean_disk(np.ascontiguousarray(V), np.ascontiguousarray(F)):
        return
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n, m = len(V), len(F)

    repeated, zero = degenerate_faces(V, F)
    if len(repeated):
        f = int(repeated[0])
        raise MeshError(
            f"{where}: {_plural(len(repeated), 'degenerate face')} with a repeated vertex: "
            f"faces {fmt_ids(repeated)} (face {f} = {F[f].tolist()})"
        )
    if len(zero):
        raise MeshError(
            f"{where}: {_plural(len(zero), 'degenerate face')} of zero area (collinear "
            f"vertices): faces {fmt_ids(zero)} (face {int(zero[0])} = {F[zero[0]].tolist()})"
        )

    he = half_edges(F)
    order, starts, counts = _edge_pairs(he, n)

    nonman = np.flatnonzero(counts > 2)
    if len(nonman):
        hs = order[starts[nonman]]
        pairs = np.sort(he[hs], axis=1)
        k = int(nonman[0])
        faces0 = np.sort(order[starts[k]:starts[k] + counts[k]] // 3)
        raise MeshError(
            f"{where}: {_plural(len(nonman), 'non-manifold edge')} (used by more than two "
            f"faces), as vertex pairs: {fmt_ids(pairs)}; edge {tuple(pairs[0].tolist())} is "
            f"used by faces {fmt_ids(faces0)}"
        )

    two = starts[counts == 2]
    a, b = order[two], order[two + 1]
    fans = _fans_per_vertex(F, he, a, b)
    bad_v = np.flatnonzero(fans > 1)
    if len(bad_v):
        raise MeshError(
            f"{where}: {_plural(len(bad_v), 'non-manifold vertex', 'non-manifold vertices')} "
            f"(its faces form {int(fans[bad_v[0]])} separate fans that share only the vertex, "
            f"e.g. a bow-tie): "
            f"vertices {fmt_ids(bad_v)}"
        )

    flipped = he[a, 0] == he[b, 0]
    if flipped.any():
        idx = np.flatnonzero(flipped)
        pairs = np.sort(he[a[idx]], axis=1)
        fa, fb = int(a[idx[0]] // 3), int(b[idx[0]] // 3)
        faces = np.unique(np.concatenate([a[idx] // 3, b[idx] // 3]))
        raise MeshError(
            f"{where}: inconsistent face orientation on {_plural(len(idx), 'edge')} (the two faces "
            f"traverse the edge in the same direction: a flipped face), as vertex pairs: {fmt_ids(pairs)}; "
            f"e.g. faces {fa} and {fb}; faces involved: {fmt_ids(faces)}"
        )

    # with manifold vertices, faces connected through vertices are connected through edges
    e = he[order[starts]]
    A = sp.coo_matrix((np.ones(len(e), dtype=np.int8), (e[:, 0], e[:, 1])), shape=(n, n))
    ncomp, vlab = connected_components(A.tocsr(), directed=False)
    if ncomp > 1:
        sizes = np.bincount(vlab[F[:, 0]], minlength=ncomp)
        sizes = np.sort(sizes)[::-1]
        raise MeshError(
            f"{where}: {ncomp} separate components (a disk is one piece); faces per "
            f"component: {fmt_ids(sizes)}"
        )

    single = order[starts[counts == 1]]
    if len(single) == 0:
        raise MeshError(
            f"{where}: the mesh is closed (no boundary edges, Euler characteristic "
            f"{n - len(starts) + m}); a disk needs one boundary loop: cut it open"
        )
    bhe = he[np.sort(single)]
    loops = loops_from_half_edges(bhe, n)
    if len(loops) > 1:
        parts = []
        for i, loop in enumerate(loops[:SHOW]):
            length = float(np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1).sum())
            parts.append(f"loop {i + 1}: {len(loop)} edges, {length:.4g} mm")
        more = f", ... ({len(loops)} in all)" if len(loops) > SHOW else ""
        raise MeshError(
            f"{where}: {len(loops)} boundary loops (a disk has exactly one; the others are "
            f"holes): " + "; ".join(parts) + more
        )

    chi = n - len(starts) + m
    if chi != 1:
        genus = (1 - chi) / 2
        raise MeshError(
            f"{where}: Euler characteristic V - E + F = {n} - {len(starts)} + {m} = {chi}, a "
            f"disk has 1 (one boundary loop and {genus:g} handle(s))"
        )
