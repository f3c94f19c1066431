"""Quadratic-fit differential geometry (METHOD section 3) against analytic surfaces."""

import warnings

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from conformill.errors import ConformillError
from conformill.geometry.differential import (
    frame_normal_curvature,
    interpolate,
    interpolate_frame,
    normal_curvature,
    perpendicular_direction,
    surface_frame,
    vertex_normals,
)
from conformill.mesh import synthetic
from conformill.mesh.topology import boundary_loops
from conformill.planning.steps import side_interval

DIRECTIONS = np.linspace(0, np.pi, 13)


def harmonic_uv(V, F):
    """Cotangent-weight harmonic map, boundary on a circle by chord length (test helper)."""
    n = len(V)
    loop = boundary_loops(F, n)[0]
    seg = np.linalg.norm(V[np.roll(loop, -1)] - V[loop], axis=1)
    t = 2 * np.pi * np.r_[0.0, np.cumsum(seg)[:-1]] / seg.sum()
    uv = np.zeros((n, 2))
    uv[loop] = np.column_stack([np.cos(t), np.sin(t)]) * seg.sum() / (2 * np.pi)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = F[:, (k + 1) % 3], F[:, (k + 2) % 3], F[:, k]
        a, b = V[i] - V[o], V[j] - V[o]
        cot = np.einsum("ij,ij->i", a, b) / np.linalg.norm(np.cross(a, b), axis=1)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    L = (sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W).tocsr()
    inner = np.setdiff1d(np.arange(n), loop)
    uv[inner] = spsolve(L[inner][:, inner].tocsc(), -(L[inner][:, loop] @ uv[loop]))
    return uv


def max_rel_curvature_error(fr, mask, expected):
    errs = [
        np.abs(frame_normal_curvature(fr, np.cos(a), np.sin(a))[mask] / expected - 1).max()
        for a in DIRECTIONS
    ]
    return max(errs)


@pytest.fixture(scope="module")
def dome():
    return synthetic.sphere_cap(R=50.0, radius_xy=30.0, spacing=2.0, jitter=0.2, seed=4)


class TestSphere:
    @pytest.mark.parametrize("concave", [False, True])
    def test_harmonic_uv_umbilic(self, concave):
        R = 50.0
        m = synthetic.sphere_cap(R=R, radius_xy=30.0, spacing=2.0, jitter=0.2, seed=4, concave=concave)
        fr = surface_frame(m.V, m.F, harmonic_uv(m.V, m.F))
        inner = np.linalg.norm(m.V[:, :2], axis=1) < 20.0
        expected = 1 / R if concave else -1 / R
        # measured: 0.5 % (jitter 0.2, 2 mm edges on R = 50)
        assert max_rel_curvature_error(fr, inner, expected) < 0.01

    @pytest.mark.parametrize("concave", [False, True])
    def test_xy_uv_umbilic(self, concave):
        R = 50.0
        m = synthetic.sphere_cap(R=R, radius_xy=30.0, spacing=2.0, jitter=0.1, seed=2, concave=concave)
        fr = surface_frame(m.V, m.F, m.V[:, :2].copy())
        inner = np.linalg.norm(m.V[:, :2], axis=1) < 20.0
        expected = 1 / R if concave else -1 / R
        assert max_rel_curvature_error(fr, inner, expected) < 0.01  # measured 0.6 %
        # everywhere, boundary included, the sign and the order of magnitude hold
        k = frame_normal_curvature(fr, 1.0, 0.0)
        assert np.all(k * expected > 0)
        assert np.abs(k / expected - 1).max() < 0.3

    def test_normal_points_to_tool(self, dome):
        fr = surface_frame(dome.V, dome.F, harmonic_uv(dome.V, dome.F))
        exact = dome.V / np.linalg.norm(dome.V, axis=1, keepdims=True)  # outward = up
        cos = np.einsum("ij,ij->i", fr.n, exact)
        assert cos.min() > 0.999
        assert np.all(fr.n[:, 2] > 0)
        np.testing.assert_allclose(np.linalg.norm(fr.n, axis=1), 1.0, atol=1e-12)

    def test_mirrored_uv_keeps_normal_and_sign(self, dome):
        uv = harmonic_uv(dome.V, dome.F)
        fr = surface_frame(dome.V, dome.F, uv)
        with pytest.warns(RuntimeWarning, match="mirrored"):
            fm = surface_frame(dome.V, dome.F, uv * np.array([1.0, -1.0]))
        np.testing.assert_allclose(fm.n, fr.n, atol=1e-12)
        np.testing.assert_allclose(fm.L, fr.L, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fm.N, fr.N, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fm.M, -fr.M, rtol=1e-9, atol=1e-12)


class TestExactQuadratic:
    """A quadric graph over an affine uv is inside the fit's model: exact everywhere."""

    def test_paraboloid_boundary_included(self):
        a, b, c = 0.01, -0.004, 0.006
        m = synthetic.height_field(
            synthetic.star_outline(), lambda x, y: a * x * x + b * y * y + c * x * y, spacing=3.0, jitter=0.3
        )
        A = np.array([[0.8, 0.3], [-0.2, 1.1]])  # uv = A^-1 (x, y): r_u, r_v = columns of A
        uv = np.linalg.solve(A, m.V[:, :2].T).T
        fr = surface_frame(m.V, m.F, uv)
        x, y = m.V[:, 0], m.V[:, 1]
        zx, zy = 2 * a * x + c * y, 2 * b * y + c * x
        ru = np.column_stack([np.full_like(x, A[0, 0]), np.full_like(x, A[1, 0]), zx * A[0, 0] + zy * A[1, 0]])
        rv = np.column_stack([np.full_like(x, A[0, 1]), np.full_like(x, A[1, 1]), zx * A[0, 1] + zy * A[1, 1]])
        H = np.array([[2 * a, c], [c, 2 * b]])
        Huv = A.T @ H @ A
        np.testing.assert_allclose(fr.ru, ru, atol=1e-9)
        np.testing.assert_allclose(fr.rv, rv, atol=1e-9)
        np.testing.assert_allclose(fr.ruu[:, 2], Huv[0, 0], atol=1e-9)
        np.testing.assert_allclose(fr.rvv[:, 2], Huv[1, 1], atol=1e-9)
        np.testing.assert_allclose(fr.ruv[:, 2], Huv[0, 1], atol=1e-9)
        np.testing.assert_allclose(fr.ruu[:, :2], 0, atol=1e-9)
        np.testing.assert_allclose(fr.E, np.einsum("ij,ij->i", ru, ru), rtol=1e-9)
        np.testing.assert_allclose(fr.F, np.einsum("ij,ij->i", ru, rv), rtol=1e-9, atol=1e-9)
        nz = np.cross(ru, rv)[:, 2] / np.linalg.norm(np.cross(ru, rv), axis=1)
        np.testing.assert_allclose(fr.L, nz * Huv[0, 0], atol=1e-9)
        np.testing.assert_allclose(fr.M, nz * Huv[0, 1], atol=1e-9)

    def test_plane_zero_curvature(self):
        m = synthetic.plane(size=60.0, spacing=4.0, jitter=0.3, z=5.0)
        uv = m.V[:, :2] * 0.5
        fr = surface_frame(m.V, m.F, uv)
        np.testing.assert_allclose(fr.E, 4.0, rtol=1e-12)
        np.testing.assert_allclose(fr.G, 4.0, rtol=1e-12)
        np.testing.assert_allclose(fr.F, 0.0, atol=1e-12)
        for arr in (fr.L, fr.M, fr.N):
            np.testing.assert_allclose(arr, 0.0, atol=1e-12)
        np.testing.assert_allclose(fr.n, np.tile([0, 0, 1.0], (len(m.V), 1)), atol=1e-12)


class TestCylinder:
    def test_concave_trough(self):
        R, r, h = 40.0, 4.0, 0.1
        m = synthetic.cylinder_patch(R=R, length=60.0, half_angle=0.8, spacing=2.0, concave=True, jitter=0.1)
        fr = surface_frame(m.V, m.F, m.V[:, :2].copy())
        inner = (np.abs(m.V[:, 0]) < 24) & (np.abs(m.V[:, 1]) < 15)  # slope < 0.4
        across = frame_normal_curvature(fr, 0.0, 1.0)[inner]  # y: across the axis
        along = frame_normal_curvature(fr, 1.0, 0.0)[inner]
        np.testing.assert_allclose(across, 1 / R, rtol=0.01)
        assert np.abs(along).max() < 0.01 / R
        assert np.all(fr.n[inner, 2] > 0)
        # the concave side step is wider than the flat one and matches the exact one
        ls, ok = side_interval(h, r, across)
        exact, _ = side_interval(h, r, 1 / R)
        assert ok.all()
        np.testing.assert_allclose(ls, exact, rtol=1e-3)
        assert np.all(ls > 2 * np.sqrt(h * (2 * r - h)))


class TestInterpolation:
    def test_linear_fields_exact(self):
        m = synthetic.plane(size=40.0, spacing=5.0, jitter=0.2)
        rng = np.random.default_rng(0)
        face = rng.integers(0, len(m.F), 100)
        bary = rng.dirichlet([1, 1, 1], 100)
        P = np.einsum("ijk,ij->ik", m.V[m.F[face]], bary)
        lin = 3 * m.V[:, 0] - 2 * m.V[:, 1] + 1
        np.testing.assert_allclose(interpolate(lin, m.F, face, bary), 3 * P[:, 0] - 2 * P[:, 1] + 1, atol=1e-12)
        np.testing.assert_allclose(interpolate(m.V, m.F, face, bary), P, atol=1e-12)

    def test_outside_nan(self):
        m = synthetic.plane(size=40.0, spacing=5.0)
        face = np.array([0, -1])
        bary = np.array([[1.0, 0, 0], [np.nan] * 3])
        out = interpolate(m.V, m.F, face, bary)
        np.testing.assert_array_equal(out[0], m.V[m.F[0, 0]])
        assert np.isnan(out[1]).all()
        with pytest.raises(ConformillError, match="bary"):
            interpolate(m.V, m.F, face, bary[:, :2])

    def test_interpolate_frame(self, dome):
        fr = surface_frame(dome.V, dome.F, harmonic_uv(dome.V, dome.F))
        face = np.array([0, 5, -1])
        bary = np.array([[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [np.nan] * 3])
        fi = interpolate_frame(fr, dome.F, face, bary)
        np.testing.assert_allclose(np.linalg.norm(fi.n[:2], axis=1), 1.0)
        assert fi.E[1] == fr.E[dome.F[5, 0]]
        assert np.isnan(fi.E[2]) and np.isnan(fi.n[2]).all()


class TestNormalCurvature:
    def test_axes_and_scale_invariance(self):
        E, F, G, L, M, N = 2.0, 0.3, 1.5, -0.4, 0.1, 0.7
        assert normal_curvature(E, F, G, L, M, N, 0, 1) == pytest.approx(N / G)
        assert normal_curvature(E, F, G, L, M, N, 1, 0) == pytest.approx(L / E)
        k = normal_curvature(E, F, G, L, M, N, np.array([1.0, 3.0]), np.array([2.0, 6.0]))
        assert k[0] == pytest.approx(k[1])
        assert np.isnan(normal_curvature(E, F, G, L, M, N, 0.0, 0.0))

    def test_perpendicular_direction(self):
        rng = np.random.default_rng(1)
        ru, rv = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
        E, F, G = (ru * ru).sum(1), (ru * rv).sum(1), (rv * rv).sum(1)
        tu, tv = rng.normal(size=50), rng.normal(size=50)
        du, dv = perpendicular_direction(E, F, G, tu, tv)
        T = ru * tu[:, None] + rv * tv[:, None]
        D = ru * du[:, None] + rv * dv[:, None]
        np.testing.assert_allclose((T * D).sum(1) / (np.linalg.norm(T, axis=1) * np.linalg.norm(D, axis=1)), 0, atol=1e-12)
        # to the left of the path seen from n = ru x rv
        assert np.all(np.einsum("ij,ij->i", np.cross(T, D), np.cross(ru, rv)) > 0)


class TestRobustness:
    def test_boundary_and_low_valence_finite(self):
        m = synthetic.freeform_patch(spacing=3.0, jitter=0.3)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            fr = surface_frame(m.V, m.F, m.V[:, :2].copy())
        for arr in (fr.E, fr.F, fr.G, fr.L, fr.M, fr.N):
            assert np.isfinite(arr).all()
        cos = np.einsum("ij,ij->i", fr.n, vertex_normals(m.V, m.F))
        assert cos.min() > 0.95

    def test_single_triangle_plane_fit(self):
        V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.5]], dtype=float)
        F = np.array([[0, 1, 2]])
        with pytest.warns(RuntimeWarning, match="plane fit"):
            fr = surface_frame(V, F, V[:, :2].copy())
        np.testing.assert_allclose(fr.ru, np.tile([1, 0, 0.0], (3, 1)), atol=1e-12)
        np.testing.assert_allclose(fr.rv, np.tile([0, 1, 0.5], (3, 1)), atol=1e-12)
        np.testing.assert_allclose(fr.L, 0, atol=1e-12)

    @pytest.mark.parametrize(
        "V, F, uv, match",
        [
            (np.zeros((3, 2)), np.array([[0, 1, 2]]), np.zeros((3, 2)), "V must be"),
            (np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((4, 2)), r"uv must be \(3, 2\)"),
            (np.zeros((3, 3)), np.array([[0, 1, 3]]), np.zeros((3, 2)), "face indices"),
            (np.zeros((3, 3)), np.array([[0, 1, 2]]), np.array([[0, 0], [1, 0], [np.nan, 1]]), "non-finite"),
        ],
    )
    def test_bad_input(self, V, F, uv, match):
        with pytest.raises(ConformillError, match=match):
            surface_frame(V, F, uv)
