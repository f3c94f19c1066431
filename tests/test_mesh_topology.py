"""The linear-time topology kernels (numba) against sort-based references and known answers."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_mesh_validate import BAD, grid, torus_grid  # noqa: E402

from conformill.mesh import synthetic, topology  # noqa: E402
from conformill.mesh.validate import check_arrays, is_clean_disk  # noqa: E402
from conformill.types import Mesh  # noqa: E402


def ref_boundary_half_edges(F, n):
    """The previous implementation: one argsort of the undirected edge keys."""
    he = topology.half_edges(F)
    key = np.minimum(he[:, 0], he[:, 1]) * n + np.maximum(he[:, 0], he[:, 1])
    order = np.argsort(key, kind="stable")
    ks = key[order]
    single = np.ones(len(ks), dtype=bool)
    same = ks[1:] == ks[:-1]
    single[1:] &= ~same
    single[:-1] &= ~same
    return he[np.sort(order[single])]


def _cases():
    yield "grid", grid(4)
    yield "freeform", (lambda m: (m.V, m.F))(synthetic.freeform_patch(spacing=4.0))
    yield "torus", torus_grid()
    for name, (V, F, _) in sorted(BAD.items()):
        yield name, (V, F)


CASES = dict(_cases())


@pytest.mark.parametrize("name", sorted(CASES))
def test_boundary_half_edges_match_the_sort(name):
    V, F = CASES[name]
    F = np.asarray(F, dtype=np.int64)
    n = max(len(V), int(F.max()) + 1)
    np.testing.assert_array_equal(topology.boundary_half_edges(F, n), ref_boundary_half_edges(F, n))


def test_disk_summary_of_a_grid_is_known():
    V, F = grid(4)  # 25 vertices, 32 faces, 56 edges
    s = topology.disk_summary(F, len(V))
    assert s == {"bad_edges": 0, "bad_vertices": 0, "components": 1, "boundary_loops": 1, "edges": 56,
                 "euler": 1}


@pytest.mark.parametrize("name, expect", [
    ("torus", dict(boundary_loops=0, euler=0, components=1)),
    ("hole", dict(boundary_loops=2, euler=0)),
    ("two_components", dict(components=2, boundary_loops=2, euler=2)),
    ("handle", dict(euler=-1)),
])
def test_disk_summary_counts(name, expect):
    V, F = CASES[name]
    s = topology.disk_summary(F, len(V))
    for k, v in expect.items():
        assert s[k] == v, (k, s)


@pytest.mark.parametrize("name", ["nonmanifold_edge", "flipped"])
def test_disk_summary_flags_bad_edges(name):
    V, F = CASES[name]
    assert topology.disk_summary(F, len(V))["bad_edges"] > 0


@pytest.mark.parametrize("name", ["bowtie", "double_cone"])
def test_disk_summary_flags_bad_vertices(name):
    V, F = CASES[name]
    assert topology.disk_summary(F, len(V))["bad_vertices"] > 0


@pytest.mark.parametrize("name", sorted(BAD))
def test_no_bad_mesh_passes_the_fast_check(name):
    V, F, _ = BAD[name]
    try:
        Vc, Fc = check_arrays(Mesh(V, F, name))
    except Exception:
        return  # rejected before the fast check
    assert not is_clean_disk(np.ascontiguousarray(Vc), np.ascontiguousarray(Fc))


def test_good_meshes_pass_the_fast_check():
    for m in (synthetic.freeform_patch(spacing=4.0), synthetic.sphere_cap(spacing=4.0)):
        assert is_clean_disk(m.V, m.F)
    V, F = grid(4)
    assert is_clean_disk(V, F)
