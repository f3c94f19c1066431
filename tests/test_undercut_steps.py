"""Side steps where the part faces down (patterns.family.UNDERCUT_NZ): no ball touches there."""

import numpy as np
import pytest

from conformill.geometry.surface import SurfaceSample
from conformill.mesh import synthetic
from conformill.output.gcode import write_gcode
from conformill.patterns import family
from conformill.patterns.family import Planner
from conformill.pipeline import Job, plan
from conformill.planning.steps import side_interval_stock
from conformill.types import PathParams
from conformill.verify.gcode import read_gcode
from conformill.verify.simulate import verify

R_TOOL, H = 4.0, 0.02


def _sample(nz, kappa):
    """Samples with an orthonormal metric, normal curvature ``kappa`` across the u
    direction (``L = kappa``, ``M = N = 0``) and unit normals of the given ``n_z``."""
    k = len(nz)
    n = np.column_stack([np.sqrt(1.0 - nz ** 2), np.zeros(k), nz])
    one, zero = np.ones(k), np.zeros(k)
    return SurfaceSample(uv=np.zeros((k, 2)), face=np.zeros(k, np.int64), bary=np.full((k, 3), 1 / 3),
                         xyz=np.zeros((k, 3)), n=n, I=np.column_stack([one, zero, one]),
                         II=np.column_stack([np.full(k, kappa), zero, zero]))


@pytest.mark.parametrize("stock", [0.0, 0.3])
def test_down_facing_samples_get_the_flat_step_and_the_others_their_own(stock):
    params = PathParams(tool_radius=R_TOOL, scallop=H, tolerance=0.01, stock=stock)
    flat = side_interval_stock(H, R_TOOL, np.zeros(1), stock)[0][0]
    planner = Planner(None, params, seg_len=1.0, concave_cap=flat)
    nz = np.array([1.0, 0.5, 0.0, -0.2, family.UNDERCUT_NZ + 1e-9, family.UNDERCUT_NZ - 1e-9, -0.9, -1.0 + 1e-12])
    t = np.tile([0.0, 1.0], (len(nz), 1))  # paths along v: across is u, where the curvature is
    kappa = -1.0 / 3.0  # convex, radius 3 mm: a step well below the flat one
    ls, reach = planner.allowed(_sample(nz, kappa), t)
    own = side_interval_stock(H, R_TOOL, np.full(1, kappa), stock, flat)[0][0]
    assert own < 0.8 * flat
    down = nz < family.UNDERCUT_NZ
    np.testing.assert_allclose(ls[~down], own, rtol=1e-12)
    np.testing.assert_allclose(ls[down], flat, rtol=1e-12)
    assert reach.all()


def test_a_wider_own_step_is_kept_where_the_part_faces_down():
    flat = side_interval_stock(H, R_TOOL, np.zeros(1), 0.0)[0][0]
    planner = Planner(None, PathParams(tool_radius=R_TOOL, scallop=H, tolerance=0.01), seg_len=1.0)  # no cap
    ls, _ = planner.allowed(_sample(np.array([-0.9]), 0.1), np.array([[0.0, 1.0]]))  # concave, radius 10
    assert ls[0] > flat


@pytest.fixture(scope="module")
def overhang():
    return synthetic.overhang_cylinder(R=8.0, length=40.0, half_angle=2.4, step=0.6)


def _feed(res):
    return sum(float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in res.toolpath.passes)


@pytest.mark.parametrize("pattern", ["contour", "spiral"])
def test_rings_past_the_sides_of_an_overhang_are_sparser_and_the_reachable_part_still_meets_h(
        overhang, pattern, tmp_path, monkeypatch):
    job = Job(pattern=pattern, tool_radius=R_TOOL, scallop=H, tolerance=0.01)
    res = plan(overhang, job)
    nc = tmp_path / "p.nc"
    write_gcode(nc, res.toolpath, feed=job.feed)
    v = verify(res.mesh, read_gcode(nc), R_TOOL, n_samples=100_000, scallop=1.05 * H, gouge=job.tolerance,
               judge="reachable", reach_depth=H).summary
    assert v["pass"], v["failures"]
    assert v["reachable"]["unreachable_fraction"] > 0.1  # the faces past the sides
    # every sample planned for its own curvature: measured 4.5 % (contour) and 5.0 % (spiral) longer
    monkeypatch.setattr(family, "UNDERCUT_NZ", -np.inf)
    assert _feed(res) < 0.98 * _feed(plan(overhang, job))
