"""validate_disk: every defect gets a MeshError naming what and where; valid disks pass.

The bad meshes are built in code from a regular grid whose answers are known by hand
(loop edge counts and lengths, vertex and face ids).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from conformill.errors import MeshError
from conformill.mesh import synthetic, topology
from conformill.mesh.validate import degenerate_faces, fmt_ids, validate_disk
from conformill.types import Mesh

H = 10.0  # grid spacing, mm


# --------------------------------------------------------------------------- builders
def grid(k: int = 4, h: float = H, skip=()):
    """A k x k grid of squares of side h split by diagonals, CCW from +Z.

    Vertex ``(i, j)`` has id ``i + j (k + 1)``; cell ``(i, j)`` gives faces
    ``(v00, v10, v11)`` and ``(v00, v11, v01)``. Cells in ``skip`` are left out.
    """
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1))
    V = np.column_stack([i.ravel() * h, j.ravel() * h, np.zeros(i.size)])
    F = []
    for cj in range(k):
        for ci in range(k):
            if (ci, cj) in skip:
                continue
            v00 = ci + cj * (k + 1)
            v10, v01, v11 = v00 + 1, v00 + k + 1, v00 + k + 2
            F += [(v00, v10, v11), (v00, v11, v01)]
    return V, np.asarray(F, dtype=np.int64)


def torus_grid(nu: int = 12, nv: int = 8, R: float = 30.0, r: float = 10.0):
    u, v = np.meshgrid(2 * np.pi * np.arange(nu) / nu, 2 * np.pi * np.arange(nv) / nv, indexing="ij")
    V = np.column_stack([((R + r * np.cos(v)) * np.cos(u)).ravel(),
                         ((R + r * np.cos(v)) * np.sin(u)).ravel(), (r * np.sin(v)).ravel()])
    idx = lambda a, b: (a % nu) * nv + (b % nv)  # noqa: E731
    F = []
    for a in range(nu):
        for b in range(nv):
            F += [(idx(a, b), idx(a + 1, b), idx(a + 1, b + 1)), (idx(a, b), idx(a + 1, b + 1), idx(a, b + 1))]
    return V, np.asarray(F, dtype=np.int64)


def bad_meshes() -> dict:
    """name -> (V, F, substrings the message must contain). Shared with the io/CLI tests."""
    out = {}
    ico = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    out["closed"] = (np.asarray(ico.vertices), np.asarray(ico.faces, dtype=np.int64), ["closed"])

    V1, F1 = grid(4)
    V2, F2 = grid(2)
    out["two_components"] = (np.vstack([V1, V2 + [100.0, 0, 0]]), np.vstack([F1, F2 + len(V1)]),
                             ["2 separate components", "32, 8"])

    V, F = grid(6, skip={(2, 2), (3, 2)})
    out["hole"] = (V, F, ["2 boundary loops", "loop 1: 24 edges, 240 mm", "loop 2: 6 edges, 60 mm"])

    # two 2x2 grids sharing one corner vertex: (20, 20) of the first is B's origin
    Va, Fa = grid(2)
    Vb, Fb = grid(2)
    Fb = Fb + len(Va) - 1  # B's vertex 0 is dropped ...
    Fb[Fb == len(Va) - 1] = 8  # ... and replaced by A's vertex 8 at (20, 20)
    out["bowtie"] = (np.vstack([Va, Vb[1:] + [20.0, 20.0, 0]]), np.vstack([Fa, Fb]),
                     ["non-manifold vertex", "vertices 8"])

    # two grids glued at one interior vertex (two closed fans, no boundary edge there)
    Va, Fa = grid(4)
    Vb, Fb = grid(4)
    Fb = np.where(Fb == 12, -1, Fb + len(Va) - 1 * (Fb > 12))
    Fb[Fb == -1] = 12
    Vb = np.delete(Vb, 12, axis=0) + [0, 0, 5.0]
    out["double_cone"] = (np.vstack([Va, Vb]), np.vstack([Fa, Fb]), ["non-manifold vertex", "vertices 12"])

    V, F = grid(3)  # edge (5, 10) is the diagonal of cell (1, 1)
    out["nonmanifold_edge"] = (np.vstack([V, [[15.0, 15.0, 5.0]]]), np.vstack([F, [[5, 10, 16]]]),
                               ["1 non-manifold edge", "(5, 10)"])

    V, F = grid(4)
    F = F.copy()
    F[10] = F[10, ::-1]  # cell (1, 1), first triangle: (6, 7, 12)
    out["flipped"] = (V, F, ["inconsistent face orientation", "3 edges", "(6, 7)", "(7, 12)", "(6, 12)"])

    V, F = grid(3)
    out["repeated_index"] = (V, np.vstack([F, [[1, 1, 6]]]), ["degenerate face", "repeated vertex", "faces 18"])

    V, F = grid(3)  # a zero-area face hanging on the boundary edge (0, 1)
    out["zero_area"] = (np.vstack([V, [[5.0, 0.0, 0.0]]]), np.vstack([F, [[0, 16, 1]]]),
                        ["degenerate face", "zero area", "faces 18"])

    V, F = grid(3)
    V = V.copy()
    V[5] = [np.nan, 0.0, 0.0]
    out["nan_vertex"] = (V, F, ["NaN", "vertices 5"])

    V, F = torus_grid()
    out["handle"] = (V, F[1:], ["Euler characteristic", "= -1", "1 handle"])
    return out


BAD = bad_meshes()


# --------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_mesh_is_named(name):
    V, F, needles = BAD[name]
    with pytest.raises(MeshError) as exc:
        validate_disk(Mesh(V=V, F=F, name=f"{name}.ply"))
    msg = str(exc.value)
    assert msg.startswith(f"{name}.ply: ")
    assert "\n" not in msg
    for s in needles:
        assert s in msg, (s, msg)


def test_root_cause_order_bowtie_before_loops():
    # a bow-tie also makes the boundary walk meaningless: the vertex must be named, not loops
    V, F, _ = BAD["bowtie"]
    with pytest.raises(MeshError, match="non-manifold vertex") as exc:
        validate_disk(Mesh(V=V, F=F))
    assert "loop" not in str(exc.value)


def test_root_cause_order_flip_before_loops():
    V, F, _ = BAD["flipped"]
    with pytest.raises(MeshError) as exc:
        validate_disk(Mesh(V=V, F=F))
    assert "boundary loops" not in str(exc.value)


def test_many_holes_are_counted_and_truncated():
    skip = {(1, 1), (3, 1), (5, 1), (1, 3), (3, 3), (5, 3), (1, 5), (3, 5), (5, 5)}
    V, F = grid(7, skip=skip)
    with pytest.raises(MeshError) as exc:
        validate_disk(Mesh(V=V, F=F))
    msg = str(exc.value)
    assert "10 boundary loops" in msg and "(10 in all)" in msg
    assert "loop 1: 28 edges, 280 mm" in msg and "4 edges, 40 mm" in msg


def test_several_nonmanifold_edges_listed_with_count():
    V, F = grid(4)
    extra = [[5, 11, len(V)], [6, 12, len(V) + 1], [7, 13, len(V) + 2]]
    V = np.vstack([V, [[0, 0, 5.0], [0, 0, 6.0], [0, 0, 7.0]]])
    with pytest.raises(MeshError) as exc:
        validate_disk(Mesh(V=V, F=np.vstack([F, extra])))
    msg = str(exc.value)
    assert "3 non-manifold edges" in msg
    for pair in ["(5, 11)", "(6, 12)", "(7, 13)"]:
        assert pair in msg


def test_unreferenced_vertex():
    V, F = grid(4)
    with pytest.raises(MeshError, match=r"not used by any face: vertices 25"):
        validate_disk(Mesh(V=np.vstack([V, [[1.0, 2.0, 3.0]]]), F=F))


def test_index_out_of_range():
    V, F = grid(2)
    with pytest.raises(MeshError, match=r"outside 0\.\.8: faces 8 \(face 8 = \[0, 1, 99\]\)"):
        validate_disk(Mesh(V=V, F=np.vstack([F, [[0, 1, 99]]])))


def test_no_faces_and_bad_shapes():
    V, _ = grid(2)
    with pytest.raises(MeshError, match="no faces"):
        validate_disk(Mesh(V=V, F=np.zeros((0, 3), dtype=np.int64)))
    with pytest.raises(MeshError, match=r"\(m, 3\)"):
        validate_disk(Mesh(V=V, F=np.zeros((2, 4), dtype=np.int64)))
    with pytest.raises(MeshError, match=r"\(n, 3\)"):
        validate_disk(Mesh(V=V[:, :2], F=np.zeros((1, 3), dtype=np.int64)))
    with pytest.raises(MeshError, match="integers"):
        validate_disk(Mesh(V=V, F=np.zeros((1, 3))))


# --------------------------------------------------------------------------- valid disks
@pytest.mark.parametrize("make", [
    lambda: synthetic.freeform_patch(),
    lambda: synthetic.plane(jitter=0.3),
    lambda: synthetic.sphere_cap(concave=True, jitter=0.2),
    lambda: synthetic.cylinder_patch(),
    lambda: Mesh(*grid(5)),
])
def test_valid_disks_pass_and_are_not_mutated(make):
    m = make()
    V0, F0 = m.V.copy(), m.F.copy()
    validate_disk(m)
    assert np.array_equal(m.V, V0) and np.array_equal(m.F, F0)
    # invariants the validator relied on: one loop, chi = 1
    assert len(topology.boundary_loops(m.F, m.n_vertices)) == 1
    assert topology.euler_characteristic(m.F, m.n_vertices) == 1


def test_a_single_triangle_is_a_disk():
    validate_disk(Mesh(V=np.eye(3), F=np.array([[0, 1, 2]])))


def test_degenerate_area_is_relative_to_mesh_scale():
    # the same shape at 1e-3 and 1e3 scale: nothing is degenerate
    V, F = grid(3)
    for s in (1e-3, 1e3):
        rep, zero = degenerate_faces(V * s, F)
        assert len(rep) == 0 and len(zero) == 0


def test_fmt_ids():
    assert fmt_ids([3, 1]) == "3, 1"
    assert fmt_ids(np.arange(10), show=3) == "0, 1, 2, ... (10 in all)"
    assert fmt_ids(np.array([[1, 2], [3, 4]])) == "(1, 2), (3, 4)"


def test_topology_speedups_keep_results():
    # undirected_edges/euler_characteristic were rewritten around one argsort
    m = synthetic.freeform_patch()
    edges, counts, inverse = topology.undirected_edges(m.F)
    he = topology.half_edges(m.F)
    key = np.sort(he, axis=1)
    ref, ref_inv, ref_cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    assert np.array_equal(edges, ref)
    assert np.array_equal(counts, ref_cnt)
    assert np.array_equal(inverse, ref_inv.reshape(-1))
    assert topology.euler_characteristic(m.F, m.n_vertices) == m.n_vertices - len(edges) + m.n_faces
