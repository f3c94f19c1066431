"""Reachability of surface samples by a 3-axis ball (verify.simulate.unreachable_samples)."""

import numpy as np

from conformill.mesh.synthetic import cylinder_patch, height_field, plane, regular_polygon
from conformill.verify.samples import sample_surface
from conformill.verify.simulate import unreachable_samples


def test_plane_is_reachable_everywhere():
    m = plane(size=40.0, spacing=2.0)
    S = sample_surface(m.V, m.F, 5000, seed=1)
    assert not unreachable_samples(S, m.V, 3.0, 0.01).any()


def test_trough_tighter_than_the_ball_is_unreachable_at_its_bottom():
    # concave cylinder of radius 2 with a 3 mm ball: the ball cannot reach the bottom
    m = cylinder_patch(R=2.0, length=20.0, half_angle=1.2, spacing=0.2, concave=True)
    S = sample_surface(m.V, m.F, 5000, seed=2)
    bad = unreachable_samples(S, m.V, 3.0, 0.01)
    bottom = np.abs(S.points[:, 1]) < 0.5
    assert bad[bottom].all()


def test_trough_wider_than_the_ball_is_reachable():
    m = cylinder_patch(R=8.0, length=30.0, half_angle=0.8, spacing=0.5, concave=True)
    S = sample_surface(m.V, m.F, 5000, seed=3)
    assert not unreachable_samples(S, m.V, 3.0, 0.01).any()


def test_overhang_and_downward_normals_are_unreachable():
    # an overhang cannot be a height field: put a "roof" of points over a plane instead
    m = plane(size=40.0, spacing=2.0)
    S = sample_surface(m.V, m.F, 2000, seed=4)
    g = np.linspace(-5, 5, 21)
    roof = np.column_stack([np.repeat(g, 21), np.tile(g, 21), np.full(441, 5.0)])
    V = np.vstack([m.V, roof])
    bad = unreachable_samples(S, V, 1.0, 0.01)
    under = (np.abs(S.points[:, 0]) < 4) & (np.abs(S.points[:, 1]) < 4)
    far = (np.abs(S.points[:, 0]) > 7) | (np.abs(S.points[:, 1]) > 7)
    assert bad[under].all() and not bad[far].any()
    # normals pointing down (an undercut face) are unreachable
    m2 = height_field(regular_polygon(24, 10), lambda x, y: 0 * x, 1.0)
    S2 = sample_surface(m2.V, m2.F, 500, seed=5)
    from conformill.verify.samples import SurfaceSamples

    down = SurfaceSamples.from_arrays(S2.points, -S2.normals)
    assert unreachable_samples(down, m2.V, 1.0, 0.01).all()


def test_shank_test_is_exact_at_the_edge_of_an_overhang():
    # a roof of points at z = 5 over x, y in [-5, 5]; a 1 mm ball touching the plane z = 0
    # at (x, 0): its shank (radius 1) passes under the roof edge (5, 0, 5) exactly when
    # x - 5 < r - depth. The earlier height-map test, shrunk by a cell diagonal, let the
    # band 0.81 < x - 5 < 0.99 through.
    from conformill.verify.samples import SurfaceSamples

    g = np.linspace(-5, 5, 21)
    roof = np.column_stack([np.repeat(g, 21), np.tile(g, 21), np.full(441, 5.0)])
    x = np.linspace(5.0 + 1e-6, 7.0, 401)
    P = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    S = SurfaceSamples.from_arrays(P, np.tile([0.0, 0.0, 1.0], (len(x), 1)))
    plane_pts = np.column_stack([np.repeat(np.linspace(-10, 10, 81), 81), np.tile(np.linspace(-10, 10, 81), 81),
                                 np.zeros(81 * 81)])
    bad = unreachable_samples(S, np.vstack([plane_pts, roof]), 1.0, 0.01)
    expected = (x - 5.0) < 1.0 - 0.01
    assert np.array_equal(bad, expected)
