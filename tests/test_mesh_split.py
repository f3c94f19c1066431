"""Midpoint split: the same surface, four triangles per triangle, uv carried linearly."""

import numpy as np
import pytest

from conformill.errors import MeshError
from conformill.mesh import synthetic
from conformill.mesh.split import split_midpoints
from conformill.pipeline import face_normals


@pytest.fixture(scope="module")
def dome():
    return synthetic.sphere_cap(R=30.0, radius_xy=12.0, spacing=2.0, jitter=0.3, seed=2)


def test_same_surface_four_children_per_face(dome):
    V, F = dome.V, dome.F
    rng = np.random.default_rng(0)
    uv = V[:, :2] @ rng.normal(size=(2, 2)) + rng.normal(size=2)  # any affine map
    Vs, Fs, uvs = split_midpoints(V, F, uv)
    n, e = len(V), len(Vs) - len(V)
    np.testing.assert_array_equal(Vs[:n], V)  # the input's vertices first, unchanged
    np.testing.assert_array_equal(uvs[:n], uv)
    assert len(Fs) == 4 * len(F)
    # one new vertex per edge, at its midpoint, with the mean uv of the edge's ends
    edges = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    assert e == len(edges)
    mid = 0.5 * (V[edges[:, 0]] + V[edges[:, 1]])
    order = np.lexsort(mid.T)
    got = Vs[n:][np.lexsort(Vs[n:].T)]
    np.testing.assert_allclose(got, mid[order], atol=1e-12)
    A = np.column_stack([Vs[:, :2], np.ones(len(Vs))])
    coef, *_ = np.linalg.lstsq(np.column_stack([V[:, :2], np.ones(n)]), uv, rcond=None)
    np.testing.assert_allclose(uvs, A @ coef, atol=1e-9)  # the affine map, carried exactly
    # the same surface: equal area, and every child lies in its parent's plane and winding
    u0, a0 = face_normals(V, F)
    u1, a1 = face_normals(Vs, Fs)
    np.testing.assert_allclose(a1.sum(), a0.sum(), rtol=1e-12)
    # each child's normal equals one parent's normal (children of a face share its plane)
    best = np.max(u1 @ u0.T, axis=1)
    np.testing.assert_allclose(best, 1.0, atol=1e-12)


def test_without_uv_and_empty():
    m = synthetic.plane(size=4.0, spacing=2.0)
    Vs, Fs, uvs = split_midpoints(m.V, m.F)
    assert uvs is None and len(Fs) == 4 * len(m.F)
    Ve, Fe, ue = split_midpoints(m.V, np.zeros((0, 3), dtype=np.int64))
    assert len(Fe) == 0 and ue is None and len(Ve) == len(m.V)


@pytest.mark.parametrize(
    "V, F, uv, word",
    [
        (np.zeros((3, 2)), np.array([[0, 1, 2]]), None, "V must be"),
        (np.zeros((3, 3)), np.array([[0, 1, 3]]), None, "outside"),
        (np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((2, 2)), "uv must be"),
    ],
)
def test_bad_inputs(V, F, uv, word):
    with pytest.raises(MeshError, match=word):
        split_midpoints(V, F, uv)


def test_split_fit_reads_twice_the_curvature_at_the_input_vertices_of_a_sphere():
    # why --fit split is not the default: on a smooth surface the midpoints lie on chords, so
    # the 1-ring fit at an input vertex sees the sagitta of half-length chords at a quarter of
    # the distance squared: twice the true curvature (1/R on the mesh's own fit)
    import warnings

    from conformill.geometry.differential import surface_frame
    from conformill.param import parameterize

    R = 50.0
    m = synthetic.sphere_cap(R=R, radius_xy=25.0, spacing=2.0, jitter=0.2, seed=1)
    p = parameterize(m, boundary="circle")

    def mean_curvature(V, F, uv):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fr = surface_frame(V, F, uv)
        det = fr.E * fr.G - fr.F ** 2
        return np.abs((fr.E * fr.N + fr.G * fr.L - 2 * fr.F * fr.M) / (2 * det))

    inner = np.linalg.norm(m.V[:, :2], axis=1) < 18.0
    H0 = mean_curvature(m.V, m.F, p.uv)
    Vs, Fs, uvs = split_midpoints(m.V, m.F, p.uv)
    Hs = mean_curvature(Vs, Fs, uvs)
    assert abs(np.median(H0[inner]) * R - 1.0) < 0.02
    assert abs(np.median(Hs[: len(m.V)][inner]) * R - 2.0) < 0.05
