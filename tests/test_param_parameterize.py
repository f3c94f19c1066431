"""parameterize(): linear precision, bijectivity on non-convex outlines, errors."""

import numpy as np
import pytest

from conformill.errors import ParameterizationError
from conformill.mesh import synthetic as syn
from conformill.param import parameterization_quality, parameterize
from conformill.param.solve import solve_interior
from conformill.param.weights import POSITIVE_KINDS, WEIGHT_KINDS
from conformill.types import Mesh


def _similarity_error(P, uv):
    """Max distance between uv and the best similarity image of P (complex least squares)."""
    z = P[:, 0] + 1j * P[:, 1]
    w = uv[:, 0] + 1j * uv[:, 1]
    M = np.column_stack([z, np.ones_like(z)])
    coef, *_ = np.linalg.lstsq(M, w, rcond=None)
    return np.abs(M @ coef - w).max(), abs(coef[0])


@pytest.mark.parametrize("kind", WEIGHT_KINDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_linear_precision_regular_polygon(kind, seed):
    # every polygon side is one mesh edge, so chord-length spacing on the circle is uniform
    outline = syn.regular_polygon(60, 50.0)
    side = 2 * 50.0 * np.sin(np.pi / 60)
    P, F = syn.polygon_disk(outline, side * 1.01, jitter=0.35, seed=seed)
    mesh = Mesh(V=np.column_stack([P, np.full(len(P), 3.0)]), F=F, name="disk")
    p = parameterize(mesh, boundary="circle", weights=kind)
    err, scale = _similarity_error(P, p.uv)
    assert scale == pytest.approx(60 * side / (2 * np.pi) / 50.0, rel=1e-12)
    assert err < 1e-9
    assert p.residual < 1e-12


@pytest.mark.parametrize("solver", ["superlu", "pardiso", "gmres_ilu"])
def test_solvers_agree(solver):
    if solver == "pardiso":
        pytest.importorskip("pypardiso")
    m = syn.freeform_patch(spacing=3.0)
    ref = parameterize(m, solver="superlu")
    p = parameterize(m, solver=solver)
    assert p.solver == solver
    assert np.abs(p.uv - ref.uv).max() < 1e-9


@pytest.mark.parametrize("boundary", ["circle", "rectangle"])
@pytest.mark.parametrize("kind", POSITIVE_KINDS)
@pytest.mark.parametrize("name", ["star", "notched", "freeform"])
def test_no_flips_on_non_convex_outlines(name, kind, boundary):
    m = {
        "star": lambda: syn.height_field(syn.star_outline(), lambda x, y: 0.004 * (x * x + 2 * y * y), 3.0, jitter=0.3),
        "notched": lambda: syn.height_field(syn.notched_outline(), lambda x, y: 10 * np.sin(x / 20) * np.cos(y / 15),
                                            3.0, jitter=0.3),
        "freeform": lambda: syn.freeform_patch(spacing=3.0),
    }[name]()
    p = parameterize(m, boundary=boundary, weights=kind)
    q = parameterization_quality(p)
    assert q.flipped == 0
    assert p.residual < 1e-8


def test_flat_square_rectangle_is_a_similarity():
    m = syn.plane(size=80, spacing=5.0, jitter=0.3)
    p = parameterize(m, boundary="rectangle", weights="geodesic")
    assert p.domain == pytest.approx((80.0, 80.0), rel=1e-12)
    q = parameterization_quality(p)
    assert q.qc_max == pytest.approx(1.0, abs=1e-9)
    assert np.allclose(p.uv, m.V[:, :2] + 40.0, atol=1e-9)


def test_parameterization_fields():
    m = syn.sphere_cap(spacing=3.0)
    p = parameterize(m, boundary="rectangle", weights="geodesic")
    assert p.uv.shape == (m.n_vertices, 2) and p.kind == "rectangle" and len(p.corners) == 4
    assert set(p.timings) == {"boundary", "weights", "solve"}
    assert p.weights == "geodesic" and p.solver in ("pardiso", "superlu")


def test_bad_names_and_meshes():
    m = syn.plane(size=40, spacing=5.0)
    with pytest.raises(ParameterizationError, match="unknown boundary 'square'.*circle, rectangle"):
        parameterize(m, boundary="square")
    with pytest.raises(ParameterizationError, match="unknown weights 'tutte'"):
        parameterize(m, weights="tutte")
    with pytest.raises(ParameterizationError, match="unknown solver"):
        parameterize(m, solver="cg")
    # two disks side by side: two boundary loops
    V2 = np.vstack([m.V, m.V + [100.0, 0, 0]])
    F2 = np.vstack([m.F, m.F + m.n_vertices])
    with pytest.raises(ParameterizationError, match="2 boundary loops"):
        parameterize(Mesh(V=V2, F=F2, name="two"))


def test_large_residual_is_reported(monkeypatch):
    import conformill.param.solve as S

    m = syn.plane(size=40, spacing=5.0)
    monkeypatch.setattr(S, "solve_linear", lambda A, rhs, solver: np.zeros_like(rhs))
    with pytest.raises(ParameterizationError, match=r"relative residual 1 > 1e-08"):
        parameterize(m, solver="superlu")


def test_solve_interior_without_interior():
    import scipy.sparse as sp

    uv, res, _ = solve_interior(sp.csr_matrix((3, 3)), np.arange(3), np.eye(3, 2), "superlu")
    assert res == 0.0 and np.allclose(uv, np.eye(3, 2))
