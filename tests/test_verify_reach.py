"""Reachability of surface samples by a 3-axis ball (verify.simulate.unreachable_samples)."""

import numpy as np
import pytest

from conformill.mesh.synthetic import cylinder_patch, height_field, plane, regular_polygon, v_groove
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


def test_which_tests_only_those_samples():
    # the answer on the samples tested is the full answer there; the others are False
    # (a plane under a roof of points, as in the overhang test below: some of each)
    m = plane(size=40.0, spacing=2.0)
    S = sample_surface(m.V, m.F, 4000, seed=4)
    g = np.linspace(-5, 5, 21)
    V = np.vstack([m.V, np.column_stack([np.repeat(g, 21), np.tile(g, 21), np.full(441, 5.0)])])
    full = unreachable_samples(S, V, 1.0, 0.01)
    which = np.random.default_rng(0).random(len(S)) < 0.4
    assert full[which].sum() > 20 and (~full[which]).sum() > 20
    assert np.array_equal(unreachable_samples(S, V, 1.0, 0.01, which=which), full & which)
    assert not unreachable_samples(S, V, 1.0, 0.01, which=np.zeros(len(S), dtype=bool)).any()


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


def test_rest_material_in_a_v_groove_matches_the_circle():
    # The ball of radius r sits in the groove touching both walls at |x| = r sin(a); a point
    # q of the right wall with x0 < r sin(a) lies u = (r sin(a) - x0) / cos(a) along the wall
    # from that contact, and the ball leaves r - sqrt(r^2 - u^2) along the wall's normal.
    from conformill.cutter import BallCutter
    from conformill.verify.rest import rest_material, tangent_rest

    a, r = np.radians(30.0), 4.0
    m = v_groove()
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


def _rest_cases():
    """Parts and samples where the rest search has work: a V-groove's wall, a bumpy height
    field with pits tighter than the ball, and a floor under a roof (no ball gets near)."""
    from conformill.pencil import surface_samples

    out = []
    a = np.radians(30.0)
    x0 = np.linspace(0.3, 3.0, 28)
    P = np.column_stack([x0, np.full_like(x0, 0.3), x0 * np.tan(a)])
    out.append((v_groove(), P, np.tile([-np.sin(a), 0.0, np.cos(a)], (len(x0), 1))))
    outline = np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]])
    bumpy = height_field(outline, lambda x, y: 0.6 * np.sin(0.9 * x) * np.sin(0.8 * y) + 0.02 * x * y, 0.6,
                         jitter=0.15, seed=2)
    P, N, _ = surface_samples(bumpy.V, bumpy.F, density=1.0, seed=1)
    inner = np.all(np.abs(P[:, :2]) < 11.0, axis=1)
    out.append((bumpy, P[inner][:150], N[inner][:150]))
    floor = plane(size=20.0, spacing=1.0)
    k = len(floor.V)
    V = np.vstack([floor.V, [[-10.0, -10.0, 2.0], [0.0, -10.0, 2.0], [0.0, 10.0, 2.0], [-10.0, 10.0, 2.0]]])
    F = np.vstack([floor.F, [[k, k + 1, k + 2], [k, k + 2, k + 3]]])
    xs = np.linspace(-6.0, 3.0, 19)
    P = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    out.append((type(floor)(V=V, F=F, name="roofed floor"), P, np.tile([0.0, 0.0, 1.0], (len(xs), 1))))
    return out


@pytest.mark.parametrize("search", ["default", "confirm"])
def test_pruned_rest_search_is_the_full_one(search):
    # the refining grids drop only the centres that can beat their start's best so far (a
    # ball whose centre is farther than r + best from the sample cannot): the same values
    # and centres as dropping every centre
    from conformill.cutter import BallCutter
    from conformill.verify.rest import CONFIRM, rest_material

    kw = CONFIRM if search == "confirm" else {}
    for m, P, N in _rest_cases():
        cut = BallCutter(m.V, m.F, 4.0)
        dropped = []
        full_drop = cut.drop
        cut.drop = lambda xy: (dropped.append(len(xy)), full_drop(xy))[1]
        t1, C1 = rest_material(cut, P, N, centres=True, **kw)
        n_pruned = sum(dropped)
        dropped.clear()
        t0, C0 = rest_material(cut, P, N, centres=True, prune=False, **kw)
        np.testing.assert_array_equal(t1, t0)
        np.testing.assert_array_equal(C1, C0)
        assert np.isfinite(t1).any()
        assert n_pruned < 0.8 * sum(dropped), m.name  # the pruning has work to do on each part


def test_pruned_rest_search_on_a_scan():
    # face_choi (x1000, SOURCES.md), where the tangent ball leaves more than 0.01 mm: the
    # samples verify searches. Both searches, pruned and not, give the same values and centres.
    from pathlib import Path

    from conformill.cutter import BallCutter
    from conformill.mesh.io import read_mesh
    from conformill.verify.rest import CONFIRM, rest_material, tangent_rest

    path = Path("/work/shared/meshes/face_choi.ply")
    if not path.exists():
        pytest.skip(f"{path} is absent")
    m = read_mesh(path, scale=1000.0)
    S = sample_surface(m.V, m.F, 20000, seed=3)
    up = S.normals[:, 2] > 0
    P, N = S.points[up], S.normals[up]
    cut = BallCutter(m.V, m.F, 4.0)
    far = np.flatnonzero(tangent_rest(cut, P, N) > 0.01)[:120]
    assert far.size >= 60
    for kw in ({}, CONFIRM):
        t1, C1 = rest_material(cut, P[far], N[far], centres=True, **kw)
        t0, C0 = rest_material(cut, P[far], N[far], centres=True, prune=False, **kw)
        np.testing.assert_array_equal(t1, t0)
        np.testing.assert_array_equal(C1, C0)


def _raster(m, r, dy=0.5, dx=0.05, half=11.5):
    """A drop-cutter raster over ``m``: rows along X, ``dy`` apart (G-code text)."""
    from conformill.cutter import BallCutter

    cut = BallCutter(m.V, m.F, r)
    lines = ["G21 G90", "G0 Z20"]
    for k, yy in enumerate(np.arange(-half, half + 0.01, dy)):
        xs = np.arange(-half, half + 0.01, dx)
        xs = xs if k % 2 == 0 else xs[::-1]
        zc = cut.drop(np.column_stack([xs, np.full_like(xs, yy)])) - r
        lines.append(f"G0 X{xs[0]:.4f} Y{yy:.4f}")
        lines += [f"G1 X{x:.4f} Y{yy:.4f} Z{z:.4f} F1000" for x, z in zip(xs, zc)]
        lines.append("G0 Z20")
    return "\n".join(lines) + "\n"


def _groove_rest(P, a, r):
    """Exact rest at points of a V-groove's walls (see the circle test above)."""
    s = np.abs(P[:, 0]) / np.cos(a)  # along the wall from the crease
    u = np.maximum(r * np.tan(a) - s, 0.0)
    return r - np.sqrt(np.maximum(r * r - u * u, 0.0))


def _groove_case(n=400):
    """A 12-degree V-groove with vertices 2 mm apart, and samples on its right wall only,
    0.02-1 mm from the crease (with the wall's normal): the tangent ball of a sample near
    the crease cuts into the left wall, but between vertices and away from any sample, so
    verify's tangent test (judged against points) keeps it; every ball leaves
    ``_groove_rest`` there, above H = 0.02 mm for ``u > sqrt(2 r H)``."""
    from conformill.verify.samples import SurfaceSamples

    a, r = np.radians(12.0), 2.0
    m = v_groove(a_deg=12.0, step=2.0)
    rng = np.random.default_rng(5)
    x0 = rng.uniform(0.02, 1.0, n)
    y0 = rng.uniform(-4.0, 4.0, n)
    P = np.column_stack([x0, y0, x0 * np.tan(a)])
    N = np.tile([-np.sin(a), 0.0, np.cos(a)], (n, 1))
    S = SurfaceSamples.from_arrays(P, N, boundary_distance=np.full(n, np.inf), area=8.0)
    return m, S, a, r


def test_reachable_judge_excuses_only_what_no_ball_can_reach():
    # Each excusal is checked against the exact rest of the groove: a sample is excused
    # when no ball can bring it within the limit H, never when one can (up to the
    # search's resolution, 3e-4 mm).
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import unreachable_samples, verify

    m, S, a, r = _groove_case()
    H = 0.02
    lim = H
    exact = _groove_rest(S.points, a, r)
    assert not unreachable_samples(S, m.V, r, H).any()  # the tangent test keeps them all
    assert (exact > lim + 3e-4).sum() >= 20 and (exact < H - 3e-4).sum() >= 200
    prog = read_gcode(_raster(m, r, half=9.5))
    res = verify(m, prog, r, samples=S, scallop=H, judge="reachable", rest=True)
    q, t = res.summary["reachable"], res.summary["reachable"]["tangent_test"]
    assert t["samples"] == len(S) and q["unconfirmed"] == 0 and q["searched"]
    excused = ~res.reachable
    assert excused.sum() == q["beyond_any_ball"] == len(S) - q["samples"]
    assert np.all(exact[excused] > lim - 3e-4)
    assert np.all(exact[~excused] <= lim + 3e-4)
    assert np.all(res.remaining[exact > H] > H)  # no program does better than the rest
    assert t["scallop"]["max"] > H and q["scallop"]["max"] < t["scallop"]["max"]
    assert np.array_equal(res.excused, excused)
    # the program's own share above the rest, against the exact rest
    left = res.remaining
    own = np.where(left > H, left - np.minimum(exact, left), left)
    assert abs(q["rest"]["p999_over_rest"] - np.percentile(own[res.reachable], 99.9)) < 5e-4
    # the judged samples above H, counted by their rest (against the exact rest, up to
    # the samples within the search's resolution of a band's edge)
    above = res.reachable & (left > H)
    bands = q["rest"]["above_limit_by_rest"]
    assert sum(bands) == q["rest"]["above_limit"] == above.sum() and bands[0] > 0 and bands[2] > 0
    e = exact[above]
    for k, (lo, hi) in enumerate([(-1.0, 0.5 * H), (0.5 * H, 0.9 * H), (0.9 * H, 1.0)]):
        near = (np.abs(e - lo) < 3e-4) | (np.abs(e - hi) < 3e-4)
        assert abs(bands[k] - ((e >= lo) & (e < hi)).sum()) <= near.sum()
    # the search restricted to where the dropped tangent ball leaves more (without --rest)
    # excuses the same samples; without the reachable judge nothing is searched
    lean = verify(m, prog, r, samples=S, scallop=H, judge="reachable")
    assert np.array_equal(lean.excused, res.excused)
    plain = verify(m, prog, r, samples=S, scallop=H)
    assert not plain.summary["reachable"]["searched"] and not plain.excused.any()
    assert plain.summary["reachable"]["samples"] == len(S)


def test_reachable_judge_excuses_above_the_limit_not_the_reach_depth():
    # With a limit above the reach depth (the raster and rest benchmarks judge 1.05 H with
    # a depth of H; 1.5 H here, for a wider band), a sample is excused where no ball meets
    # the limit: the samples whose exact rest lies between H and the limit stay judged.
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m, S, a, r = _groove_case()
    H = 0.02
    exact = _groove_rest(S.points, a, r)
    between = (exact > H + 3e-4) & (exact < 1.5 * H - 3e-4)
    assert between.sum() >= 10
    prog = read_gcode(_raster(m, r, half=9.5))
    res = verify(m, prog, r, samples=S, scallop=1.5 * H, reach_depth=H, judge="reachable")
    excused = res.excused
    assert excused.sum() > 0 and res.summary["reachable"]["unconfirmed"] == 0
    assert np.all(exact[excused] > 1.5 * H - 3e-4)
    assert np.all(exact[~excused] <= 1.5 * H + 3e-4)
    assert res.reachable[between].all()
    # judged at H alone, the same samples are excused
    low = verify(m, prog, r, samples=S, scallop=H, judge="reachable")
    assert not low.reachable[between].any()


def test_a_second_search_confirms_each_excusal(monkeypatch):
    # With a first search too narrow to find the ball in the groove, its upper bound puts
    # samples that a ball can bring within H above H; the second search (rest.CONFIRM)
    # finds that ball, so the excusals still follow the exact rest. Made as weak as the
    # first, it lets wrong excusals through: the test can tell.
    from conformill.verify import rest
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m, S, a, r = _groove_case()
    H = 0.02
    exact = _groove_rest(S.points, a, r)
    prog = read_gcode(_raster(m, r, half=9.5))
    chunk, centres, _, _, _, prune = rest.rest_material.__defaults__
    weak = {"starts": 1, "coarse": (0.02, 3), "refine": (3, (0.005,))}
    monkeypatch.setattr(rest.rest_material, "__defaults__", (chunk, centres, weak["starts"], weak["coarse"],
                                                             weak["refine"], prune))
    res = verify(m, prog, r, samples=S, scallop=H, judge="reachable", rest=True)
    assert np.all(exact[res.excused] > H - 3e-4) and np.all(exact[~res.excused] <= H + 3e-4)
    # every judged sample above H has a searched rest, and falls in one band
    above = res.reachable & (res.remaining > H)
    assert sum(res.summary["reachable"]["rest"]["above_limit_by_rest"]) == above.sum()
    monkeypatch.setattr(rest, "CONFIRM", weak)
    bad = verify(m, prog, r, samples=S, scallop=H, judge="reachable")
    wrong = bad.excused & (exact < H - 3e-4)
    assert wrong.sum() >= 10


def test_top_view_marks_what_fails_and_what_no_ball_can_reach(tmp_path):
    from conformill.output.plot_verify import overlay_masks, plot_verify
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m, S, a, r = _groove_case()
    H = 0.02
    res = verify(m, read_gcode(_raster(m, r, half=9.5)), r, samples=S, scallop=H, judge="reachable")
    marks = {colour: mask for mask, colour, _ in overlay_masks(res)}
    assert np.array_equal(marks["red"], res.reachable & (res.remaining > H))
    assert np.array_equal(marks["orange"], res.excused) and marks["orange"].sum() > 0
    assert marks["red"].sum() == round(res.summary["reachable"]["above_scallop_fraction"] * res.reachable.sum())
    assert not (marks["red"] & marks["orange"]).any()
    plot_verify(tmp_path / "v.png", res)
    assert (tmp_path / "v.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_reachable_judge_does_not_trust_a_drop_height_it_cannot_confirm(monkeypatch):
    # A drop-cutter that let the ball hover 0.05 mm above the part would excuse every
    # sample left above H: the judge measures the best ball's distance to the mesh with its
    # own geometry and excuses nothing.
    from conformill.cutter import BallCutter
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m, S, a, r = _groove_case()
    H = 0.02
    prog = read_gcode(_raster(m, r, half=9.5))
    drop = BallCutter.drop
    monkeypatch.setattr(BallCutter, "drop", lambda self, xy: drop(self, xy) + 0.05)
    res = verify(m, prog, r, samples=S, scallop=H, judge="reachable")
    q = res.summary["reachable"]
    assert q["beyond_any_ball"] == 0 and q["unconfirmed"] >= (_groove_rest(S.points, a, r) > H).sum()
    assert q["samples"] == q["tangent_test"]["samples"] == len(S)
    assert q["scallop"]["p999"] == q["tangent_test"]["scallop"]["p999"] > H
    assert not res.summary["pass"]


def test_reachable_judge_excuses_nothing_on_a_plane():
    # rows 1.2 mm apart with r = 2 leave 0.09 mm everywhere between them: all of it is the
    # program's, and the check fails
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    m = plane(size=24.0, spacing=1.0)
    r, H = 2.0, 0.02
    res = verify(m, read_gcode(_raster(m, r, dy=1.2, half=11.0)), r, n_samples=20000, seed=2, scallop=H,
                 judge="reachable")
    q = res.summary["reachable"]
    assert q["beyond_any_ball"] == 0 and q["unconfirmed"] == 0
    assert q["scallop"]["p999"] > 4 * H and not res.summary["pass"]


class _Counting:
    """A k-d tree that counts the points asked of its bounded queries."""

    def __init__(self, tree):
        self.tree, self.bounded = tree, 0

    def query(self, X, k=1, distance_upper_bound=np.inf, workers=1):
        if np.isfinite(distance_upper_bound):
            self.bounded += len(X)
        return self.tree.query(X, k=k, distance_upper_bound=distance_upper_bound, workers=workers)


@pytest.mark.parametrize("R, blocked", [(4.2, False), (3.9, True)])
def test_a_bowl_of_about_the_ball_s_radius_is_decided_in_groups(R, blocked):
    # the tangent balls' centres of a spherical bowl crowd near its centre of curvature,
    # where every point lies about R - r from them: a bounded k-d tree query then visits
    # them all (26 s at 60k samples for R = 4.2, r = 4). One exact distance per crowded
    # cell of depth / 2 decides its neighbours; the answers are those of the plain query
    from scipy.spatial import cKDTree

    from conformill.mesh.synthetic import sphere_cap
    from conformill.verify.simulate import _any_within

    m = sphere_cap(R=R, radius_xy=3.0, spacing=0.1, concave=True)
    S = sample_surface(m.V, m.F, 8000, seed=0)
    C = S.points + 4.0 * S.normals
    tree = cKDTree(np.vstack([S.points, m.V]))
    want = np.isfinite(tree.query(C, distance_upper_bound=3.99)[0])
    counting = _Counting(tree)
    got = _any_within(counting, C, 3.99, 0.01)
    np.testing.assert_array_equal(got, want)
    assert want.all() if blocked else not want.any()
    assert counting.bounded < 0.25 * len(C)  # most decided by the groups' exact distances
    assert unreachable_samples(S, m.V, 4.0, 0.01).all() == blocked


def test_crowded_queries_near_the_reach_give_the_plain_answers():
    # clusters of queries (tighter than depth) whose nearest points lie about rho away,
    # some just inside, some just outside, and queries spread apart: the same booleans
    from scipy.spatial import cKDTree

    from conformill.verify.simulate import _any_within

    rng = np.random.default_rng(7)
    X = rng.normal(size=(3000, 3))
    X *= (2.0 + rng.uniform(-0.02, 0.02, (3000, 1))) / np.linalg.norm(X, axis=1, keepdims=True)
    crowds = np.repeat(rng.uniform(-0.01, 0.01, (40, 3)), 50, axis=0) + rng.uniform(-0.003, 0.003, (2000, 3))
    C = np.vstack([crowds, rng.uniform(-1.0, 1.0, (500, 3))])
    tree = cKDTree(X)
    mixed = 0
    for rho in (1.95, 1.965, 1.97, 1.975, 1.98, 2.0):
        want = np.isfinite(tree.query(C, distance_upper_bound=rho)[0])
        np.testing.assert_array_equal(_any_within(tree, C, rho, 0.01), want)
        mixed += 0 < want[:2000].sum() < 2000
    assert mixed >= 2
