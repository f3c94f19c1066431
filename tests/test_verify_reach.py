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


# ----------------------------------------------------------------------------- rest material


def _v_groove(a_deg=30.0, half=12.0, step=0.25):
    """A V-groove z = |x| tan(a) on a grid with a vertex row on the crease x = 0."""
    from conformill.types import Mesh

    x = np.arange(-half, half + 1e-9, step)
    y = np.arange(-half, half + 1e-9, 2 * step)
    X, Y = np.meshgrid(x, y)
    V = np.column_stack([X.ravel(), Y.ravel(), np.abs(X.ravel()) * np.tan(np.radians(a_deg))])
    nx = len(x)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(len(y) - 1))
    v0 = (j * nx + i).ravel()
    F = np.vstack([np.column_stack([v0, v0 + 1, v0 + nx + 1]), np.column_stack([v0, v0 + nx + 1, v0 + nx])])
    return Mesh(V=V, F=F.astype(np.int64), name="v-groove")


def test_rest_material_in_a_v_groove_matches_the_circle():
    # The ball of radius r sits in the groove touching both walls at |x| = r sin(a); a point
    # q of the right wall with x0 < r sin(a) lies u = (r sin(a) - x0) / cos(a) along the wall
    # from that contact, and the ball leaves r - sqrt(r^2 - u^2) along the wall's normal.
    from conformill.cutter import BallCutter
    from conformill.verify.rest import rest_material, tangent_rest

    a, r = np.radians(30.0), 4.0
    m = _v_groove()
    x0 = np.linspace(0.3, 3.0, 28)
    P = np.column_stack([x0, np.full_like(x0, 0.3), x0 * np.tan(a)])
    N = np.tile([-np.sin(a), 0.0, np.cos(a)], (len(x0), 1))
    u = np.maximum(r * np.sin(a) - x0, 0.0) / np.cos(a)
    exact = r - np.sqrt(r * r - u * u)
    cut = BallCutter(m.V, m.F, r)
    got = rest_material(cut, P, N)
    assert np.all(got >= exact - 1e-9)  # the search can only miss the best ball
    # exact near the rim, where the rest is of the order of a scallop height; deeper in
    # the groove the best ball lies beyond the search (an upper bound, far above any H)
    rim = exact <= 0.05
    assert rim.sum() >= 10
    np.testing.assert_allclose(got[rim], exact[rim], atol=2e-4, rtol=1e-3)
    # the tangent ball alone, dropped onto the part, leaves much more inside the band
    band = exact > 0.01
    assert np.all(tangent_rest(cut, P[band], N[band]) > 2 * exact[band])


def test_rest_figures_of_verify():
    # a raster over the V-groove: every reachable sample left above H either has a rest
    # above H, or is counted in the program's own share
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m = _v_groove()
    r, H = 2.0, 0.02
    lines = ["G21 G90", "G0 Z20"]
    for k, yy in enumerate(np.arange(-11.5, 11.51, 0.5)):
        xs = np.arange(-11.5, 11.51, 0.05)
        xs = xs if k % 2 == 0 else xs[::-1]
        from conformill.cutter import BallCutter

        zc = BallCutter(m.V, m.F, r).drop(np.column_stack([xs, np.full_like(xs, yy)])) - r
        lines.append(f"G0 X{xs[0]:.4f} Y{yy:.4f}")
        lines += [f"G1 X{x:.4f} Y{yy:.4f} Z{z:.4f} F1000" for x, z in zip(xs, zc)]
        lines.append("G0 Z20")
    # a loose reachability depth (1 mm) keeps the groove's rim among the judged samples
    res = verify(m, read_gcode("\n".join(lines) + "\n"), r, n_samples=20000, seed=1, scallop=H,
                 judge="reachable", reach_depth=1.0, rest=True)
    R = res.summary["reachable"]["rest"]
    assert R["above_limit"] > 0 and R["beyond_any_ball"] > 0  # the groove's rims
    p999 = res.summary["reachable"]["scallop"]["p999"]
    assert R["p999_without_them"] < p999
    # above the rest, the raster's own share (rows 0.5 mm apart: flat scallop 0.0157 mm)
    # meets H; the rims' rest material alone does not
    assert R["p999_over_rest"] <= R["p999_without_them"] + 1e-12
    assert R["p999_over_rest"] < H < p999
    assert res.summary["pass"] is False  # the figures do not change the verdict
