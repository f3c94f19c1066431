"""Combinatorial topology of triangle meshes, vectorized with one sort or one numba pass.

Half-edge ``(F[f, k], F[f, (k+1) % 3])``. For a consistently oriented mesh, a boundary
half-edge is one whose reverse does not exist; walking them keeps the interior on the left.

The hot queries (:func:`boundary_half_edges`, :func:`disk_summary`) group the half-edges by
their origin vertex with a counting sort and look twins up in the origin's short list, in
numba: linear time, no ``3m``-element argsort.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def half_edges(F: np.ndarray) -> np.ndarray:
    """All half-edges, face-major.

    Parameters
    ----------
    F : (m, 3) int64

    Returns
    -------
    (3m, 2) int64
        Row ``3 f + k`` is ``(F[f, k], F[f, (k + 1) % 3])``.
    """
    return np.stack([F, np.roll(F, -1, axis=1)], axis=2).reshape(-1, 2)


def undirected_edges(F: np.ndarray):
    """Unique undirected edges and how many faces use each.

    Returns
    -------
    edges : (e, 2) int64
        Sorted pairs ``i < j``, lexicographic order.
    counts : (e,) int64
        Number of faces using each edge.
    inverse : (3m,) int64
        Edge index of each half-edge of :func:`half_edges`.
    """
    he = half_edges(F)
    n = int(F.max()) + 1 if len(F) else 0
    key = _edge_keys(he, n)
    # one int64 key per edge and one argsort: np.unique(return_inverse=True) sorts twice
    # and is about 4x slower on 600k faces
    order = np.argsort(key, kind="stable")
    ks = key[order]
    first = np.ones(len(ks), dtype=bool)
    first[1:] = ks[1:] != ks[:-1]
    starts = np.flatnonzero(first)
    ukey = ks[starts]
    counts = np.diff(np.append(starts, len(ks))).astype(np.int64)
    inverse = np.empty(len(ks), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    edges = np.stack([ukey // max(n, 1), ukey % max(n, 1)], axis=1)
    return edges, counts, inverse


def _edge_keys(he: np.ndarray, n: int) -> np.ndarray:
    """``min(i, j) * n + max(i, j)`` for each half-edge row, ``(k,)`` int64."""
    return np.minimum(he[:, 0], he[:, 1]) * n + np.maximum(he[:, 0], he[:, 1])


@njit(cache=True)
def _out_half_edges(F, n):
    """Half-edges grouped by origin vertex (CSR), in id order within each group.

    Returns ``indptr (n + 1,)``, and per entry: ``ids`` (half-edge id ``3 f + k``), ``dst`` (its
    end vertex) and ``opp`` (the face's third vertex), so that twin and fan look-ups scan short
    contiguous lists.
    """
    m = F.shape[0]
    indptr = np.zeros(n + 1, dtype=np.int64)
    for f in range(m):
        for k in range(3):
            indptr[F[f, k] + 1] += 1
    for v in range(n):
        indptr[v + 1] += indptr[v]
    ids = np.empty(3 * m, dtype=np.int64)
    dst = np.empty(3 * m, dtype=np.int64)
    opp = np.empty(3 * m, dtype=np.int64)
    fill = indptr[:n].copy()
    for f in range(m):
        for k in range(3):
            v = F[f, k]
            j = fill[v]
            ids[j] = 3 * f + k
            dst[j] = F[f, (k + 1) % 3]
            opp[j] = F[f, (k + 2) % 3]
            fill[v] = j + 1
    return indptr, ids, dst, opp


@njit(cache=True)
def _edge_multiplicity(F, n):
    """Per half-edge ``a -> b``: how many *other* half-edges run ``a -> b`` and ``b -> a``."""
    m = F.shape[0]
    indptr, ids, dst, opp = _out_half_edges(F, n)
    same = np.zeros(3 * m, dtype=np.int64)
    rev = np.zeros(3 * m, dtype=np.int64)
    # the faces at a hold a -> dst and opp -> a: both counts come from a's own list
    for a in range(n):
        for j in range(indptr[a], indptr[a + 1]):
            b = dst[j]
            h = ids[j]
            for i in range(indptr[a], indptr[a + 1]):
                if i != j and dst[i] == b:
                    same[h] += 1
                # wedge i's face holds opp[i] -> a (half-edge id below), unless that is h itself
                if opp[i] == b and 3 * (ids[i] // 3) + (ids[i] % 3 + 2) % 3 != h:
                    rev[h] += 1
    return same, rev


def boundary_half_edges(F: np.ndarray, n_vertices: int | None = None) -> np.ndarray:
    """Half-edges whose edge is used by exactly one face, ``(b, 2)`` int64, in half-edge order."""
    F = np.ascontiguousarray(F, dtype=np.int64)
    if len(F) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    n = int(F.max()) + 1 if n_vertices is None else max(int(n_vertices), int(F.max()) + 1)
    same, rev = _edge_multiplicity(F, n)
    return half_edges(F)[(same + rev) == 0]


@njit(cache=True)
def _disk_summary(F, n):
    """Counts that decide whether a triangle mesh is a manifold oriented disk; see :func:`disk_summary`."""
    m = F.shape[0]
    indptr, ids, dst, opp = _out_half_edges(F, n)
    ne = 3 * m
    twin = np.full(ne, -1, dtype=np.int64)  # per CSR entry: the face across its edge
    bad_edges = 0
    n_boundary = 0
    for a in range(n):
        for j in range(indptr[a], indptr[a + 1]):
            b = dst[j]
            n_same = 0
            n_rev = 0
            h = ids[j]
            for i in range(indptr[a], indptr[a + 1]):
                if i != j and dst[i] == b:
                    n_same += 1
                if opp[i] == b and 3 * (ids[i] // 3) + (ids[i] % 3 + 2) % 3 != h:  # that face holds b -> a
                    n_rev += 1
                    twin[j] = ids[i] // 3
            if n_same > 0 or n_rev > 1:
                bad_edges += 1
            elif n_rev == 0:
                n_boundary += 1
    if bad_edges:
        return bad_edges, 0, 0, 0, 0
    # fans: wedge j (a -> b, third vertex c) is followed around a by the half-edge a -> c
    bad_vertices = 0
    nxt = np.full(ne, -1, dtype=np.int64)
    has_prev = np.zeros(ne, dtype=np.bool_)
    for a in range(n):
        s0 = indptr[a]
        s1 = indptr[a + 1]
        for j in range(s0, s1):
            c = opp[j]
            for i in range(s0, s1):
                if dst[i] == c:
                    nxt[j] = i
                    has_prev[i] = True
                    break
        d = s1 - s0
        if d == 0:
            continue
        start = s0
        n_start = 0
        for j in range(s0, s1):
            if not has_prev[j]:
                n_start += 1
                start = j
        if n_start > 1:
            bad_vertices += 1
            continue
        j = start
        steps = 0
        while True:
            steps += 1
            j = nxt[j]
            if j < 0 or j == start or steps > d:
                break
        if steps != d:
            bad_vertices += 1
    # components of faces through shared edges (union-find)
    parent = np.arange(m)
    for j in range(ne):
        if twin[j] >= 0:
            x = ids[j] // 3
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            y = twin[j]
            while parent[y] != y:
                parent[y] = parent[parent[y]]
                y = parent[y]
            if x != y:
                parent[max(x, y)] = min(x, y)
    n_comp = 0
    for f in range(m):
        if parent[f] == f:
            n_comp += 1
    # boundary loops: each boundary half-edge a -> b continues with the one leaving b
    bnext = np.full(n, -1, dtype=np.int64)
    for a in range(n):
        for j in range(indptr[a], indptr[a + 1]):
            if twin[j] < 0:
                bnext[a] = dst[j]
    seen = np.zeros(n, dtype=np.bool_)
    n_loops = 0
    for v in range(n):
        if bnext[v] >= 0 and not seen[v]:
            n_loops += 1
            u = v
            while u >= 0 and not seen[u]:
                seen[u] = True
                u = bnext[u]
    n_edges = (ne + n_boundary) // 2
    return 0, bad_vertices, n_comp, n_loops, n_edges


def disk_summary(F: np.ndarray, n_vertices: int) -> dict:
    """Topological counts of a triangle mesh in one linear-time pass (numba).

    Parameters
    ----------
    F : (m, 3) int64
        Indices in ``0 .. n_vertices - 1``.
    n_vertices : int

    Returns
    -------
    dict
        ``bad_edges``: half-edges whose edge is non-manifold or traversed twice in the same
        direction (when non-zero, the other counts are 0 and meaningless);
        ``bad_vertices``: vertices whose faces do not form one fan; ``components`` (faces
        connected through edges), ``boundary_loops``, ``edges``, ``euler`` (``V - E + F``,
        counting every vertex id below ``n_vertices``). A disk has 0, 0, 1, 1 and euler 1.
    """
    F = np.ascontiguousarray(F, dtype=np.int64)
    n = int(n_vertices)
    bad_e, bad_v, comp, loops, edges = _disk_summary(F, n)
    return {"bad_edges": int(bad_e), "bad_vertices": int(bad_v), "components": int(comp),
            "boundary_loops": int(loops), "edges": int(edges), "euler": int(n - edges + len(F))}


def boundary_loops(F: np.ndarray, n_vertices: int | None = None) -> list[np.ndarray]:
    """Boundary loops as ordered vertex-id arrays, longest first.

    Each loop follows the boundary half-edges, so that for a consistently oriented mesh
    the interior is on the left. The first vertex of each loop is its smallest id, so the
    result is deterministic. Vertices where the boundary touches itself (a bow-tie) are
    not resolved here: :mod:`conformill.mesh.validate` reports them first.

    Parameters
    ----------
    F : (m, 3) int64
    n_vertices : int, optional

    Returns
    -------
    list of (k,) int64
    """
    bhe = boundary_half_edges(F, n_vertices)
    n = (int(F.max()) + 1 if len(F) else 0) if n_vertices is None else int(n_vertices)
    return loops_from_half_edges(bhe, n)


def loops_from_half_edges(bhe: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """Chain boundary half-edges into loops (the walk of :func:`boundary_loops`).

    Parameters
    ----------
    bhe : (b, 2) int64
        Boundary half-edges, e.g. from :func:`boundary_half_edges`.
    n_vertices : int

    Returns
    -------
    list of (k,) int64
        Longest first; each starts at its smallest vertex id.
    """
    if len(bhe) == 0:
        return []
    n = int(n_vertices)
    nxt = np.full(n, -1, dtype=np.int64)
    nxt[bhe[:, 0]] = bhe[:, 1]
    seen = np.zeros(n, dtype=bool)
    loops = []
    for start in np.sort(bhe[:, 0]):
        if seen[start]:
            continue
        # Walk with pointer doubling would be faster for one huge loop; a plain walk over
        # boundary vertices only (a few thousand) costs milliseconds.
        loop = []
        v = int(start)
        while v >= 0 and not seen[v]:
            seen[v] = True
            loop.append(v)
            v = int(nxt[v])
        loops.append(np.asarray(loop, dtype=np.int64))
    loops.sort(key=lambda a: -len(a))
    return loops


def euler_characteristic(F: np.ndarray, n_vertices: int) -> int:
    """``V - E + F`` counting only referenced vertices."""
    F = np.asarray(F)
    if len(F) == 0:
        return 0
    n = max(int(n_vertices), int(F.max()) + 1)
    key = np.sort(_edge_keys(half_edges(F), n))
    n_edges = int(np.count_nonzero(key[1:] != key[:-1])) + 1
    used = int(np.count_nonzero(np.bincount(F.reshape(-1), minlength=n)))
    return int(used - n_edges + len(F))


def face_components(F: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of faces through shared vertices.

    Returns
    -------
    count : int
    labels : (m,) int64
        Component of each face (largest component first is not guaranteed).
    """
    import scipy.sparse as sp
    import scipy.sparse.csgraph  # noqa: F401  (sp.csgraph)

    m = len(F)
    rows = np.repeat(np.arange(m), 3)
    A = sp.csr_matrix((np.ones(3 * m), (rows, F.reshape(-1))), shape=(m, n_vertices))
    # faces adjacent through a vertex: component labels on the bipartite graph
    B = sp.bmat([[None, A], [A.T, None]], format="csr")
    count, labels = sp.csgraph.connected_components(B, directed=False)
    lab = labels[:m]
    uniq, lab = np.unique(lab, return_inverse=True)
    return int(len(uniq)), lab.astype(np.int64)


def vertex_adjacency(F: np.ndarray, n_vertices: int):
    """Symmetric vertex adjacency (1-ring) as a CSR matrix of ones."""
    import scipy.sparse as sp

    he = half_edges(F)
    A = sp.csr_matrix(
        (np.ones(len(he)), (he[:, 0], he[:, 1])), shape=(n_vertices, n_vertices)
    )
    A = ((A + A.T) > 0).astype(np.float64)
    return A.tocsr()
