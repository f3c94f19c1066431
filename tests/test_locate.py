"""Point location in the parameter domain and mapping to the mesh (METHOD section 5)."""

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from conformill.errors import ConformillError
from conformill.geometry.differential import vertex_normals
from conformill.geometry.locate import Locator, map_normals, map_points
from conformill.mesh import synthetic
from conformill.mesh.topology import boundary_loops


def circle_uv(V, F):
    """Uniform-weight Tutte map onto a circle (test helper; a valid bijective map)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve

    from conformill.mesh.topology import vertex_adjacency

    n = len(V)
    loop = boundary_loops(F, n)[0]
    t = 2 * np.pi * np.arange(len(loop)) / len(loop)
    uv = np.zeros((n, 2))
    uv[loop] = 10.0 * np.column_stack([np.cos(t), np.sin(t)])
    A = vertex_adjacency(F, n)
    L = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()
    inner = np.setdiff1d(np.arange(n), loop)
    uv[inner] = spsolve(L[inner][:, inner].tocsc(), -(L[inner][:, loop] @ uv[loop]))
    return uv


@pytest.fixture(scope="module")
def dome():
    m = synthetic.sphere_cap(R=50.0, radius_xy=30.0, spacing=2.0, jitter=0.3, seed=7)
    return m, circle_uv(m.V, m.F)


@pytest.fixture(scope="module")
def star():
    m = synthetic.height_field(synthetic.star_outline(), lambda x, y: 0.01 * x * y, spacing=3.0, jitter=0.2)
    return m, m.V[:, :2].copy()


def reproduce(uv, F, face, bary):
    return np.einsum("ijk,ij->ik", uv[F[face]], bary)


class TestLocate:
    @pytest.mark.parametrize("which", ["dome", "star"])
    def test_inside_points(self, which, request):
        m, uv = request.getfixturevalue(which)
        loop = boundary_loops(m.F, len(m.V))[0]
        rng = np.random.default_rng(0)
        lo, hi = uv.min(0), uv.max(0)
        P = rng.uniform(lo, hi, (20000, 2))
        loc = Locator(uv, m.F)
        face, bary = loc.locate(P)
        inside = face >= 0
        # agree with a polygon test wherever the point is not within 1e-6 of the boundary
        path = MplPath(uv[loop])
        ref_in = path.contains_points(P, radius=-1e-6) | path.contains_points(P, radius=1e-6)
        ref_in_strict = path.contains_points(P, radius=1e-6) & path.contains_points(P, radius=-1e-6)
        assert np.all(inside[ref_in_strict]) and not np.any(inside[~ref_in])
        np.testing.assert_allclose(reproduce(uv, m.F, face[inside], bary[inside]), P[inside], rtol=0, atol=1e-12)
        assert bary[inside].min() >= 0.0
        np.testing.assert_allclose(bary[inside].sum(1), 1.0, atol=1e-14)
        assert np.isnan(bary[~inside]).all()
        assert inside.sum() > 1000 and (~inside).sum() > 1000

    def test_cc_points_on_face_plane(self, dome):
        m, uv = dome
        rng = np.random.default_rng(1)
        r = np.sqrt(rng.uniform(0, 1, 5000)) * 9.99
        t = rng.uniform(0, 2 * np.pi, 5000)
        P = np.column_stack([r * np.cos(t), r * np.sin(t)])
        face, bary = Locator(uv, m.F).locate(P)
        assert np.all(face >= 0)
        X = map_points(m.V, m.F, face, bary)
        a, b, c = (m.V[m.F[face, k]] for k in range(3))
        nrm = np.cross(b - a, c - a)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        assert np.abs(np.einsum("ij,ij->i", X - a, nrm)).max() < 1e-9
        # below the sphere by at most the sagitta of the face's circumcircle (radius rho)
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (b - c, c - a, a - b))
        area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        rho = la * lb * lc / (2 * area2)
        gap = 50.0 - np.linalg.norm(X, axis=1)
        assert np.all(gap >= -1e-9) and np.all(gap <= 50.0 - np.sqrt(50.0**2 - rho**2) + 1e-9)

    def test_vertices_and_edges(self, dome):
        m, uv = dome
        loc = Locator(uv, m.F)
        face, bary = loc.locate(uv)
        assert np.all(face >= 0)
        np.testing.assert_allclose(reproduce(uv, m.F, face, bary), uv, atol=1e-12)
        mid = 0.5 * (uv[m.F[:, 0]] + uv[m.F[:, 1]])
        face, bary = loc.locate(mid)
        assert np.all(face >= 0)
        np.testing.assert_allclose(reproduce(uv, m.F, face, bary), mid, atol=1e-12)

    def test_boundary_points_found_and_snapped(self, dome):
        m, uv = dome
        loop = boundary_loops(m.F, len(m.V))[0]
        a, b = uv[loop], uv[np.roll(loop, -1)]
        s = np.linspace(0, 1, 11)[:, None, None]
        P = (a[None] * (1 - s) + b[None] * s).reshape(-1, 2)
        loc = Locator(uv, m.F)
        face, bary = loc.locate(P)
        assert np.all(face >= 0)
        np.testing.assert_allclose(reproduce(uv, m.F, face, bary), P, atol=1e-12)
        # a hair outside (1e-11 of the domain size): snapped onto the boundary edge
        out = np.array([[10.0 * (1 + 1e-12), 0.0]])
        Pout = P * (1 + 2e-12)
        face, bary = loc.locate(np.vstack([out, Pout]))
        assert np.all(face >= 0)
        assert bary.min() >= 0 and np.allclose(bary.sum(1), 1.0)
        q = reproduce(uv, m.F, face, bary)
        assert np.abs(q - np.vstack([out, Pout])).max() < 1e-9 * 20
        # farther than the tolerance: outside
        face, _ = loc.locate(P * (1 + 1e-6))
        assert np.all(face == -1)

    def test_outside_and_nonfinite(self, star):
        m, uv = star
        loc = Locator(uv, m.F)
        P = np.array([[1e6, 0], [-100, -100], [np.nan, 0], [0, np.inf], [0.0, 0.0]])
        face, bary = loc.locate(P)
        np.testing.assert_array_equal(face, [-1, -1, -1, -1, face[4]])
        assert face[4] >= 0
        assert np.isnan(bary[:4]).all()

    def test_empty_query(self, star):
        m, uv = star
        face, bary = Locator(uv, m.F).locate(np.zeros((0, 2)))
        assert face.shape == (0,) and bary.shape == (0, 3)

    def test_clockwise_faces(self, star):
        m, uv = star
        F = m.F[:, ::-1].copy()
        rng = np.random.default_rng(2)
        P = rng.uniform(-20, 20, (1000, 2))
        f1, b1 = Locator(uv, m.F).locate(P)
        f2, b2 = Locator(uv, F).locate(P)
        np.testing.assert_array_equal(f1 >= 0, f2 >= 0)
        np.testing.assert_allclose(reproduce(uv, F, f2[f2 >= 0], b2[f2 >= 0]), P[f2 >= 0], atol=1e-12)

    @pytest.mark.parametrize(
        "uv, F, kw, match",
        [
            (np.zeros((3, 3)), np.array([[0, 1, 2]]), {}, "uv must be"),
            (np.zeros((3, 2)), np.zeros((0, 3), dtype=np.int64), {}, "non-empty"),
            (np.eye(3)[:, :2], np.array([[0, 1, 5]]), {}, "face indices"),
            (np.array([[0, 0], [1, 0], [np.nan, 1]]), np.array([[0, 1, 2]]), {}, "non-finite"),
            (np.zeros((3, 2)), np.array([[0, 1, 2]]), {}, "zero extent"),
            (np.eye(3)[:, :2], np.array([[0, 1, 2]]), {"tol": -1.0}, "tol"),
        ],
    )
    def test_bad_input(self, uv, F, kw, match):
        with pytest.raises(ConformillError, match=match):
            Locator(uv, F, **kw)

    def test_bad_query(self, star):
        m, uv = star
        with pytest.raises(ConformillError, match="P must be"):
            Locator(uv, m.F).locate(np.zeros((3, 3)))


class TestMapping:
    def test_normals_renormalised(self, dome):
        m, uv = dome
        N = vertex_normals(m.V, m.F)
        P = np.array([[0.0, 0.0], [3.0, -2.0], [50.0, 0.0]])
        face, bary = Locator(uv, m.F).locate(P)
        nn = map_normals(N, m.F, face, bary)
        np.testing.assert_allclose(np.linalg.norm(nn[:2], axis=1), 1.0, atol=1e-14)
        assert np.isnan(nn[2]).all()
        X = map_points(m.V, m.F, face, bary)
        assert np.isnan(X[2]).all()
        # on a sphere the interpolated normal is close to the radial direction
        cos = np.einsum("ij,ij->i", nn[:2], X[:2] / np.linalg.norm(X[:2], axis=1, keepdims=True))
        assert cos.min() > 0.9999


def test_pick_faces_is_searchsorted():
    # the faces picked for area-weighted samples: np.searchsorted(cum, x, side="right"),
    # the same integers, with zero-area faces (repeated sums), values on the sums, 0 and the total
    from conformill.geometry.locate import pick_faces

    rng = np.random.default_rng(0)
    for m in (1, 2, 17, 1000):
        a = rng.random(m) * (rng.random(m) < 0.7)
        a[0] = 0.5
        cum = np.cumsum(a)
        x = np.concatenate([rng.random(4000) * cum[-1], cum, np.nextafter(cum, -np.inf), [0.0, cum[-1]]])
        np.testing.assert_array_equal(pick_faces(cum, x), np.searchsorted(cum, x, side="right"))
    np.testing.assert_array_equal(pick_faces(np.zeros(3), np.array([0.0, 1.0])), [3, 3])
    # a total that overflows, values that are not numbers: as searchsorted
    for cum, x in ((np.array([1.0, np.inf]), np.array([0.5, 2.0])), (np.array([1.0, 2.0]), np.array([np.nan, 1.0]))):
        np.testing.assert_array_equal(pick_faces(cum, x), np.searchsorted(cum, x, side="right"))
    assert pick_faces(np.ones(4), np.zeros(0)).shape == (0,)
