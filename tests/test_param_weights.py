"""Interior weights (METHOD 1a-1b): convex combinations with linear precision."""

import numpy as np
import pytest

from conformill.errors import ParameterizationError
from conformill.mesh import synthetic as syn
from conformill.mesh.topology import boundary_loops
from conformill.param.weights import POSITIVE_KINDS, WEIGHT_KINDS, corner_angles, interior_weights


def _mask(F, n):
    m = np.zeros(n, dtype=bool)
    m[boundary_loops(F, n)[0]] = True
    return m


def _flat(jitter=0.3, seed=0):
    P, F = syn.polygon_disk(syn.regular_polygon(48, 50.0), 6.6, jitter=jitter, seed=seed)
    return np.column_stack([P, np.zeros(len(P))]), F


def _grid(k=12, h=5.0):
    """Regular grid triangulation of [0, k h]^2, every cell cut along the same diagonal."""
    x, y = np.meshgrid(np.arange(k + 1) * h, np.arange(k + 1) * h, indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    idx = np.arange((k + 1) ** 2).reshape(k + 1, k + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return V, F


@pytest.mark.parametrize("kind", WEIGHT_KINDS)
def test_rows_sum_to_one_and_sign(kind):
    m = syn.sphere_cap(R=40, radius_xy=30, spacing=3.0, jitter=0.3)
    mask = _mask(m.F, m.n_vertices)
    W, fb = interior_weights(m.V, m.F, mask, kind)
    rs = np.asarray(W.sum(axis=1)).ravel()
    assert np.allclose(rs[~mask], 1.0, atol=1e-13)
    assert W[mask].nnz == 0
    if kind in POSITIVE_KINDS:
        assert W.data.min() > 0
    # the pattern is exactly the 1-ring of interior vertices
    A = (abs(W) > 0).astype(int)
    from conformill.mesh.topology import vertex_adjacency

    adj = vertex_adjacency(m.F, m.n_vertices)
    assert abs(adj[~mask] - A[~mask]).max() == 0
    if kind != "geodesic":
        assert fb == 0


@pytest.mark.parametrize("kind", WEIGHT_KINDS)
def test_linear_precision_in_the_plane(kind):
    V, F = _flat()
    mask = _mask(F, len(V))
    W, _ = interior_weights(V, F, mask, kind)
    err = np.abs(W @ V - V)[~mask]
    assert err.max() < 1e-12 * 50


def test_geodesic_equals_floater_on_flat_mesh():
    V, F = _flat(seed=3)
    mask = _mask(F, len(V))
    Wg, fb = interior_weights(V, F, mask, "geodesic")
    Wf, _ = interior_weights(V, F, mask, "floater")
    assert fb == 0
    assert abs(Wg - Wf).max() < 1e-14


def test_geodesic_equals_floater_on_folded_sheet():
    """Angle sums stay exactly 2 pi when a flat sheet is folded along a line of edges (METHOD 1b)."""
    V, F = _grid()
    mask = _mask(F, len(V))
    Vf = V.copy()
    right = V[:, 0] > 30.0 + 1e-9  # fold along x = 30, a grid line
    t = np.radians(50.0)
    dx = V[right, 0] - 30.0
    Vf[right, 0] = 30.0 + dx * np.cos(t)
    Vf[right, 2] = dx * np.sin(t)
    ang = np.bincount(F.ravel(), corner_angles(Vf, F).ravel(), len(V))
    assert np.allclose(ang[~mask], 2 * np.pi, atol=1e-12)
    Wg, fb = interior_weights(Vf, F, mask, "geodesic")
    Wf, _ = interior_weights(Vf, F, mask, "floater")
    assert fb == 0
    assert abs(Wg - Wf).max() < 1e-14
    # and both equal the flat sheet's weights (intrinsic)
    W0, _ = interior_weights(V, F, mask, "floater")
    assert abs(W0 - Wf).max() < 1e-13
    # mean-value weights use 3D angles too, so they are intrinsic as well; cotangent likewise
    Wm0, _ = interior_weights(V, F, mask, "mean_value")
    Wm1, _ = interior_weights(Vf, F, mask, "mean_value")
    assert abs(Wm0 - Wm1).max() < 1e-13


def test_geodesic_differs_from_floater_on_curved_mesh_and_has_no_fallback_on_a_dome():
    m = syn.sphere_cap(R=35, radius_xy=30, spacing=3.0, jitter=0.3)
    mask = _mask(m.F, m.n_vertices)
    Wg, fb = interior_weights(m.V, m.F, mask, "geodesic")
    Wf, _ = interior_weights(m.V, m.F, mask, "floater")
    assert fb == 0  # angle sums below 2 pi: an opposite face always exists
    assert abs(Wg - Wf).max() > 1e-4


def test_saddle_falls_back_and_stays_convex():
    outline = syn.regular_polygon(40, 30.0)
    m = syn.height_field(outline, lambda x, y: 0.03 * (x * x - y * y), 3.0, jitter=0.3)
    mask = _mask(m.F, m.n_vertices)
    ang = np.bincount(m.F.ravel(), corner_angles(m.V, m.F).ravel(), m.n_vertices)
    assert np.all(ang[~mask] > 2 * np.pi)
    W, fb = interior_weights(m.V, m.F, mask, "geodesic")
    assert fb > 0
    assert W.data.min() > 0
    assert np.allclose(np.asarray(W.sum(axis=1)).ravel()[~mask], 1.0, atol=1e-13)


def test_sliver_triangles():
    """Near-degenerate triangles (angles near 0 and 180 degrees) still give convex rows."""
    V, F = _grid(k=6)
    V = V.copy()
    # push an interior vertex almost onto the diagonal edge of its neighbours
    i = 3 * 7 + 3
    V[i, :2] += [2.4999, -2.4999 + 1e-7]
    mask = _mask(F, len(V))
    for kind in POSITIVE_KINDS:
        W, _ = interior_weights(V, F, mask, kind)
        assert np.isfinite(W.data).all() and W.data.min() >= 0
        assert np.allclose(np.asarray(W.sum(axis=1)).ravel()[~mask], 1.0)


def test_unknown_kind():
    V, F = _grid(k=3)
    with pytest.raises(ParameterizationError, match="unknown weights 'harmonic'.*geodesic"):
        interior_weights(V, F, _mask(F, len(V)), "harmonic")


def test_inconsistent_orientation_is_reported():
    V, F = _grid(k=4)
    mask = _mask(F, len(V))
    F = F.copy()
    F[5] = F[5, [0, 2, 1]]  # face (6, 11, 12), all interior vertices, turned over
    with pytest.raises(ParameterizationError, match="not consistently oriented|not one closed cycle"):
        interior_weights(V, F, mask, "floater")


def test_duplicate_vertices_are_reported():
    V, F = _grid(k=4)
    V = V.copy()
    mask = _mask(F, len(V))
    i = 2 * 5 + 2
    V[i] = V[i + 1]
    with pytest.raises(ParameterizationError, match="zero-length edge"):
        interior_weights(V, F, mask, "geodesic")
