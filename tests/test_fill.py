"""The fill stage (conformill.fill): passes through the balls that reach what the passes
left, checked on a plane against the scallop formula, and its refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conformill.cutter import BallCutter
from conformill.errors import JobValueError, PlanningError
from conformill.fill import fill_passes
from conformill.mesh.synthetic import plane
from conformill.pattern_rest import UncutRows, centre_moves
from conformill.pencil import surface_samples
from conformill.pipeline import Job, check_job

R, H, E = 4.0, 0.01, 0.01


def _rows(gap: float, half: float = 8.5):
    """Tip passes along X over the plane z = 0 (16 mm square), ``gap`` apart in Y, past its
    rim (tips on the plane's level): between them cusps of ``gap^2 / 8r`` along ``y = k
    gap``, and nothing else left."""
    x = np.linspace(-half, half, 86)
    ys = (np.arange(-int(half / gap) - 1, int(half / gap) + 1) + 0.5) * gap
    return [np.column_stack([x, np.full_like(x, y), np.zeros_like(x)]) for y in ys]


@pytest.fixture(scope="module")
def flat():
    m = plane(size=16.0, spacing=0.5)
    return m, BallCutter(m.V, m.F, R)


def _left(m, passes, depth, seed=3, density=30.0):
    """Samples the passes left more than ``depth`` h, by the distance bound (``seed`` 0:
    the fill's own samples)."""
    P, _, _ = surface_samples(m.V, m.F, density, seed=seed)
    rows = UncutRows(P, R, depth * H)
    rows.add(*centre_moves(passes, R))
    return P[rows.uncut()]


def test_rows_spaced_for_1_3_h_get_a_fill_pass_along_their_cusp(flat):
    # on a plane two passes s apart leave s^2 / 8r at the cusp midway: spaced for 1.3 h, the
    # band where they leave more than 0.7 h is filled, and nothing else is
    m, cut = flat
    gap = math.sqrt(8 * R * 1.3 * H)
    rows = _rows(gap)
    assert len(_left(m, rows, 0.7)) > 0
    out = fill_passes(cut, m.V, m.F, rows, H, depth=0.7, tol=E, link_max=8.0, start_xy=rows[-1][-1, :2])
    assert out.passes and out.stats["balls"] > 0 and out.stats["reached"] > 0
    tips = np.vstack([cut.tip(p) for p in out.passes])
    inner = (np.abs(tips[:, 0]) < 5.0) & (np.abs(tips[:, 1]) < 5.0)
    # over the plane (away from its rim, where a ball hangs over the edge) the ball rests on it
    np.testing.assert_allclose(tips[inner, 2], 0.0, atol=1e-9)
    # where the rows are, the fill runs inside the bands along the cusps that the rows left
    # above 0.7 h, give or take one grid spacing (the balls are grid nodes)
    c = gap / 2  # distance of a cusp from its rows
    # a point y from the nearest cusp lies c - |y| from a row: the rows' rest there is
    # sqrt((c - |y|)^2 + r^2) - r, which falls to 0.7 h at |y| = c - sqrt((r + 0.7 h)^2 - r^2)
    band = c - math.sqrt((R + 0.7 * H) ** 2 - R * R)
    g = 1.0 / math.sqrt(30.0)
    off = np.abs(tips[inner, 1] - gap * np.round(tips[inner, 1] / gap))
    assert off.max() <= band + g
    # afterwards none of the fill's own samples is left more than the depth: each had a ball
    # within its give (0.5 h), and the kept balls lie within a fifth of the sample spacing
    # of those (the thinning)
    after = rows + [cut.tip(p) for p in out.passes]
    assert len(_left(m, after, 0.7, seed=0)) == 0
    # other samples can lie where the fill pass runs off its cusp line by up to a grid node,
    # beside new cusps: measured 2 % of them above 0.7 h, against 27 % before the fill
    n = len(surface_samples(m.V, m.F, 30.0, seed=3)[0])
    assert len(_left(m, rows, 0.7)) > 0.2 * n and len(_left(m, after, 0.7)) < 0.03 * n


def test_rows_close_enough_get_no_fill(flat):
    m, cut = flat
    rows = _rows(math.sqrt(8 * R * 0.6 * H))  # the cusp is 0.6 h < 0.7 h
    assert len(_left(m, rows, 0.7)) == 0
    out = fill_passes(cut, m.V, m.F, rows, H, depth=0.7, tol=E, link_max=8.0, start_xy=rows[-1][-1, :2])
    assert out.passes == [] and out.stats["balls"] == 0


@pytest.mark.parametrize("kw", [{"depth": 0.0}, {"depth": float("nan")}, {"density": -1.0}])
def test_bad_values_are_refused(flat, kw):
    m, cut = flat
    args = {"depth": 0.7, **kw}
    with pytest.raises(PlanningError, match="fill"):
        fill_passes(cut, m.V, m.F, _rows(0.5), H, tol=E, link_max=8.0, start_xy=(0.0, 0.0), **args)


def test_samples_drawn_beforehand_refuse_a_bad_density(flat):
    from conformill.fill import fill_samples

    m, cut = flat
    with pytest.raises(PlanningError, match="fill: fill density must be a positive number, got -1.0"):
        fill_samples(cut, m.V, m.F, -1.0)


@pytest.mark.parametrize("kw, said", [({"fill": 0.0}, "fill must be"), ({"fill": float("inf")}, "fill must be"),
                                      ({"pattern_scallop": 0.0}, "pattern-scallop must be"),
                                      ({"pattern_scallop": 1.3}, "needs --fill")])
def test_job_values_are_checked(kw, said):
    with pytest.raises(JobValueError, match=said):
        check_job(Job(pattern="zigzag", tool_radius=R, scallop=H, **kw))


def test_a_plan_with_wider_paths_and_the_fill_stays_within_the_scallop():
    # a sphere cap (R 60 mm, convex): the pattern spaced for 1.3 h leaves more than the depth
    # between its paths; with the fill, the planner's own estimate finds none of the fill's
    # samples left above it (one plan, without the test of the widening: on a part this
    # smooth plan() drops the fill, below)
    from conformill.mesh.synthetic import sphere_cap
    from conformill.pipeline import FILL_OVER_SAVING, _plan_once, plan, widening_ratio

    m = sphere_cap(R=60.0, radius_xy=12.0, spacing=0.6)
    h = 0.02

    def left(res, depth, seed):
        P, _, _ = surface_samples(res.mesh.V, res.mesh.F, 30.0, seed=seed)
        rows = UncutRows(P, R, depth * h)
        rows.add(*centre_moves(res.toolpath.passes, R))
        return int(rows.uncut().sum())

    base = plan(m, Job(pattern="zigzag", tool_radius=R, scallop=h, tolerance=E))
    job = Job(pattern="zigzag", tool_radius=R, scallop=h, tolerance=E, pattern_scallop=1.3, fill=0.7)
    filled = _plan_once(m, job)
    assert base.report["fill"] is None
    assert filled.report["fill"]["balls"] > 0 and filled.report["job"]["pattern_scallop"] == 1.3
    assert filled.report["paths"]["planned_paths"] < base.report["paths"]["planned_paths"]
    assert left(filled, 0.7, seed=0) == 0
    # the test of the widening: on this smooth cap the fill is longer than the wider paths
    # saved (widening_ratio - 1 of the pattern's feed), so plan() plans again with the
    # pattern spaced for h and no fill: the same passes as that plan
    feed = lambda ps: sum(np.linalg.norm(np.diff(q, axis=0), axis=1).sum() for q in ps)  # noqa: E731
    fill_feed = filled.report["fill"]["feed_mm"]
    pattern = [q for q, i in zip(filled.toolpath.passes, filled.toolpath.pass_ids) if i >= 0]
    ratio = widening_ratio(filled.domain_paths)
    assert fill_feed > FILL_OVER_SAVING * (ratio - 1) * feed(pattern)
    dropped = plan(m, job)
    assert dropped.report["fill"]["dropped"] and dropped.report["fill"]["feed_mm"] == fill_feed
    assert dropped.report["fill"]["widening_ratio"] == ratio
    assert dropped.report["fill"]["saved_mm"] == pytest.approx((ratio - 1) * feed(pattern), rel=1e-12)
    assert all(p.widening == 1.0 for p in dropped.domain_paths.paths)
    assert dropped.report["job"]["pattern_scallop"] == 1.0 and dropped.report["job"]["fill"] is None
    assert len(dropped.toolpath.passes) == len(base.toolpath.passes)
    for a, b in zip(dropped.toolpath.passes, base.toolpath.passes):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("sphere_r, capped", [(60.0, True), (8.0, False)])
def test_the_widening_is_read_from_the_side_intervals_on_a_sphere(sphere_r, capped):
    # on a convex sphere of radius Rs every sample's curvature across the paths is -1 / Rs,
    # so every path's step grows by the same factor. The flat cap (the flat interval at h)
    # holds the step spaced for 1.3 h where 1 + r / Rs < 1.3 (Rs = 60): the saving is then
    # cap / l_s(h) (about sqrt(1 + r / Rs)); on a tighter sphere (Rs = 8) neither step is
    # capped and it is l_s(1.3 h) / l_s(h) (about sqrt(1.3))
    from conformill.mesh.synthetic import sphere_cap
    from conformill.pipeline import _plan_once, widening_ratio
    from conformill.planning.steps import side_interval

    h = 0.02
    m = sphere_cap(R=sphere_r, radius_xy=min(12.0, 0.7 * sphere_r), spacing=0.4)
    res = _plan_once(m, Job(pattern="zigzag", tool_radius=R, scallop=h, tolerance=E, pattern_scallop=1.3,
                            fill=0.7))
    k = -1.0 / sphere_r
    at_h = float(side_interval(h, R, k)[0])
    flat_h = float(side_interval(h, R, 0.0)[0])
    wide = float(side_interval(1.3 * h, R, k)[0])
    assert (wide > flat_h) == capped
    expected = (flat_h if capped else wide) / at_h
    inner = [p.widening for p in res.domain_paths.paths[:-1]]
    assert res.domain_paths.paths[-1].widening == 1.0
    np.testing.assert_allclose(inner, expected, rtol=5e-3)  # (the rim rows: fitted curvature)
    assert widening_ratio(res.domain_paths) == pytest.approx(expected, rel=2e-3)


def test_a_paths_widening_is_that_of_its_tightest_sample():
    # pieces._widening: the largest factor the step taken could be scaled by within the
    # interval allowed as spaced, over the same within the interval allowed at h; samples
    # with no finite positive predicted interval (the last path's NaN) are left out
    from types import SimpleNamespace

    from conformill.patterns.pieces import _widening

    def curve(ls, base):
        return SimpleNamespace(ls=np.array(ls, dtype=float), ls_base=np.array(base, dtype=float))

    # sample 0 binds (ls / predicted = 1.2 against 2.0): its own ratio, 1.2
    assert _widening(curve([1.2, 1.0, 2.0, 1.0], [1.0, 1.0, 1.0, 0.5]), np.array([1.0, 0.5, np.nan, 0.0])) == 1.2
    # the tight sample 0 is capped (no wider) while sample 1 widens 1.3 times: 1.0, not
    # the samples' mean (1.15)
    assert _widening(curve([1.0, 1.3], [1.0, 1.0]), np.array([1.0, 0.5])) == 1.0
    # at h the tight sample moves: 2.0 / 1.0 over min(1.0 / 1.0, 1.5 / 1.0)
    assert _widening(curve([2.0, 2.0], [1.0, 1.5]), np.array([1.0, 1.0])) == 2.0
    assert _widening(curve([1.0], [0.8]), np.array([np.nan])) == 1.0  # nothing to read
    same = curve([1.0, 2.0], [1.0, 2.0])
    same.ls_base = same.ls
    assert _widening(same, np.array([1.0, 1.0])) == 1.0  # not widened


def test_on_a_plane_the_flat_cap_leaves_nothing_to_save():
    # spaced for 1.3 h or for h, every step on a plane is the flat interval at h (the cap)
    from conformill.pipeline import _plan_once, widening_ratio

    res = _plan_once(plane(size=16.0, spacing=0.5), Job(pattern="contour", tool_radius=R, scallop=0.02,
                                                         tolerance=E, pattern_scallop=1.3, fill=0.7))
    assert widening_ratio(res.domain_paths) == 1.0
    assert all(p.widening == 1.0 for p in res.domain_paths.paths)


def test_a_fill_shorter_than_the_saving_is_kept(monkeypatch):
    # the same rule the other way: a fill whose feed is below widening_ratio - 1 of the
    # pattern's is kept (here the fill's feed is reported as 0)
    import conformill.pipeline as pl
    from conformill.mesh.synthetic import sphere_cap

    once = pl._plan_once

    def small_fill(mesh, job, progress=None):
        res = once(mesh, job, progress)
        if res.report["fill"] is not None:
            res.report["fill"]["feed_mm"] = 0.0
        return res

    monkeypatch.setattr(pl, "_plan_once", small_fill)
    m = sphere_cap(R=60.0, radius_xy=12.0, spacing=0.6)
    res = pl.plan(m, Job(pattern="zigzag", tool_radius=R, scallop=0.02, tolerance=E, pattern_scallop=1.3, fill=0.7))
    assert not res.report["fill"].get("dropped") and res.report["job"]["pattern_scallop"] == 1.3


@pytest.mark.parametrize("share, dropped", [(1.0, False), (1.2, False), (1.3, True)])
def test_the_fill_is_kept_up_to_its_share_of_the_saving(monkeypatch, share, dropped):
    # the fill's feed reported as `share` times what the wider paths saved: kept up to
    # FILL_OVER_SAVING (1.25) times, dropped above (the plan spaced for h, no fill). On
    # this cap the flat cap holds the wider step (widening about 1.033, not sqrt(1.3)):
    # a test that took sqrt(F) - 1 for the saving would keep the fill at 1.3
    import conformill.pipeline as pl
    from conformill.mesh.synthetic import sphere_cap

    assert pl.FILL_OVER_SAVING == 1.25
    once = pl._plan_once

    def fill_of(mesh, job, progress=None):
        res = once(mesh, job, progress)
        if res.report["fill"] is not None:
            pattern = [q for q, i in zip(res.toolpath.passes, res.toolpath.pass_ids) if i >= 0]
            feed = sum(np.linalg.norm(np.diff(q, axis=0), axis=1).sum() for q in pattern)
            res.report["fill"]["feed_mm"] = share * (pl.widening_ratio(res.domain_paths) - 1.0) * feed
        return res

    monkeypatch.setattr(pl, "_plan_once", fill_of)
    m = sphere_cap(R=60.0, radius_xy=12.0, spacing=0.6)
    res = pl.plan(m, Job(pattern="zigzag", tool_radius=R, scallop=0.02, tolerance=E, pattern_scallop=1.3, fill=0.7))
    assert bool(res.report["fill"].get("dropped")) == dropped
    assert res.report["job"]["pattern_scallop"] == (1.0 if dropped else 1.3)
    # kept or dropped, the report holds the test's figures
    fill = res.report["fill"]
    assert fill["pattern_scallop"] == 1.3 and fill["widening_ratio"] > 1.0
    assert fill["saved_mm"] == pytest.approx((fill["widening_ratio"] - 1.0) * fill["pattern_feed_mm"], rel=1e-12)
    assert fill["feed_mm"] == pytest.approx(share * fill["saved_mm"], rel=1e-12)


def test_the_hops_into_later_passes_clear_the_part(flat):
    # passes.hops_into: over the plane z = 0 (ball centres at R), the rapid across keeps the
    # ball HOP_CLEARANCE above the plane (tip at least that high) and the rapid down ends
    # between the pass start and that height
    from conformill.passes import HOP_CLEARANCE, hops_into

    m, cut = flat
    pieces = [np.array([[x, y, R], [x + 1.0, y, R]]) for x, y in ((-3.0, 0.0), (2.0, 3.0), (-1.0, -4.0))]
    hops = hops_into(cut, np.array([-6.0, -6.0, R]), pieces)
    assert len(hops) == 3
    for across, down in hops:
        assert across >= HOP_CLEARANCE - 1e-9 and 0.0 <= down <= across
    assert hops_into(cut, np.zeros(3), []) == []


def test_a_huge_part_gets_a_lower_density_with_a_warning(flat, monkeypatch, caplog):
    # as the pencil: more samples than the stage's cap (here lowered to 2000) lower the
    # density, with a warning that names it
    import conformill.pencil as pencil_mod

    monkeypatch.setattr(pencil_mod, "_MAX_SAMPLES", 2000)
    m, cut = flat
    rows = _rows(math.sqrt(8 * R * 1.3 * H))
    with caplog.at_level("WARNING", logger="conformill.fill"):
        out = fill_passes(cut, m.V, m.F, rows, H, depth=0.7, tol=E, link_max=8.0, start_xy=(0.0, 0.0))
    assert out.stats["samples"] <= 2000 and out.stats["density_per_mm2"] < 30.0
    assert "per mm^2" in caplog.text


def test_the_samples_drawn_in_the_pencils_worker_are_the_fills_own(monkeypatch):
    # on two threads the pipeline draws the fill's samples in the pencil's worker and hands
    # them over, and tests them against the pattern's passes while the cutter works; on one
    # thread fill_passes draws and tests them itself (FILL_DENSITY, FILL_SEED): the same
    # samples, so the same fill and the same program
    import numba

    import conformill.fill as fill

    from conformill.mesh.synthetic import sphere_cap
    from conformill.passes import threads_can_overlap
    from conformill.pipeline import _plan_once

    m = sphere_cap(R=60.0, radius_xy=12.0, spacing=0.6)
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.02, tolerance=E, pattern_scallop=1.3, fill=0.7,
              pencil=True, pencil_search="folds", pencil_left=0.5)
    n = numba.get_num_threads()
    if n < 2:
        pytest.skip("one numba thread: the worker never runs")
    out, fed = [], []
    add_grid = fill.FillRows.add_grid
    monkeypatch.setattr(fill.FillRows, "add_grid", lambda self, g: (fed.append(len(g.A)), add_grid(self, g)))
    try:
        for t in (n, 1):
            numba.set_num_threads(t)
            assert threads_can_overlap() == (t > 1)
            out.append(_plan_once(m, job))
            # on two threads the samples' test takes the pattern's passes while the cutter
            # works (the moves binned once with the pencil's filter); on one, all at the end
            assert (len(fed) > 0) == (t > 1)
            fed.clear()
    finally:
        numba.set_num_threads(n)
    a, b = (o.report["fill"] for o in out)
    assert a["samples"] > 1000 and a["balls"] > 0 and a == b
    # the worker's time for the draw is reported where the worker drew
    assert out[0].report["timings_s"]["fill_draw"] > 0 and "fill_draw" not in out[1].report["timings_s"]
    assert len(out[0].toolpath.passes) == len(out[1].toolpath.passes)
    for p, q in zip(out[0].toolpath.passes, out[1].toolpath.passes):
        np.testing.assert_array_equal(p, q)


def test_samples_no_grid_ball_reaches_get_a_searched_ball(monkeypatch):
    # a bumpy part with pits tighter than the ball: where the nearest grid ball lies beyond
    # the give but within FILL_SEARCH_NEAR h (2 h here; off by default), the pencil's model search finds a ball that
    # reaches the sample; every ball lies on the drop surface, within the give of a sample
    # the passes left, and the grid's balls are those of the fill without the search
    import conformill.fill as fill
    from conformill.mesh.synthetic import height_field
    from conformill.pattern_rest import uncut_beyond
    from conformill.pipeline import plan, scan_recipe

    outline = np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]])
    m = height_field(outline, lambda x, y: 0.6 * np.sin(0.9 * x) * np.sin(0.8 * y) + 0.02 * x * y, 0.6,
                     jitter=0.15, seed=2)
    h = 0.05
    res = plan(m, Job(pattern="zigzag", tool_radius=R, scallop=h, tolerance=E, **scan_recipe("zigzag")))
    pattern = [p for p, i in zip(res.toolpath.passes, res.toolpath.pass_ids) if i >= 0]
    cut = BallCutter(m.V, m.F, R)
    drawn = fill.fill_samples(cut, m.V, m.F)
    monkeypatch.setattr(fill, "FILL_SEARCH_NEAR", 2.0)
    B, which, counts, _ = fill.fill_balls(cut, drawn, pattern, h, depth=0.7)
    n_grid = len(B) - counts["searched_reached"]
    assert counts["searched"] > counts["searched_reached"] > 0 and n_grid > 0
    np.testing.assert_allclose(cut.drop(B[:, :2]), B[:, 2], atol=1e-9)
    P = drawn.P[which]
    assert np.all(np.linalg.norm(B - P, axis=1) - R <= fill.FILL_GIVE * h + 1e-12)
    assert uncut_beyond(P, *centre_moves(pattern, R), R, 0.7 * h).all()
    # the searched balls reach samples no grid ball comes within the give of
    _, d, _ = fill._grid_balls(cut, drawn.P, drawn.N, drawn.density)
    assert np.all(d[which[n_grid:]] > fill.FILL_GIVE * h) and np.all(d[which[:n_grid]] <= fill.FILL_GIVE * h)
    monkeypatch.setattr(fill, "FILL_SEARCH_NEAR", fill.FILL_GIVE)
    B0, which0, counts0, _ = fill.fill_balls(cut, drawn, pattern, h, depth=0.7)
    assert counts0["searched"] == 0 and counts0["reached"] == counts["reached"]
    np.testing.assert_array_equal(B0, B[:n_grid])
    np.testing.assert_array_equal(which0, which[:n_grid])


def test_fill_rows_fed_in_parts_give_the_balls_of_all_passes_at_once():
    # FillRows as the pipeline feeds it: the pattern's passes cut so far (the last in part),
    # the rest, then the pencil's, each binned once: the same balls, samples and counts as
    # fill_balls with every pass at once
    import conformill.fill as fill
    from conformill.mesh.synthetic import height_field
    from conformill.pattern_rest import move_grid

    outline = np.array([[-12.0, -12.0], [12.0, -12.0], [12.0, 12.0], [-12.0, 12.0]])
    m = height_field(outline, lambda x, y: 0.5 * np.sin(0.8 * x) * np.cos(0.7 * y), 0.6, jitter=0.1, seed=4)
    cut = BallCutter(m.V, m.F, R)
    h = 0.05
    gap = math.sqrt(8 * R * 1.6 * h)
    x = np.linspace(-12.5, 12.5, 120)
    tips = [cut.tip(np.column_stack([x, np.full_like(x, y), cut.drop(np.column_stack([x, np.full_like(x, y)]))]))
            for y in np.arange(-12.0, 12.5, gap)]
    drawn = fill.fill_samples(cut, m.V, m.F)
    want = fill.fill_balls(cut, drawn, tips, h, depth=0.7)
    assert len(want[0]) > 0 and want[2]["reached"] > 0
    n, k = len(tips) // 2, 50
    early = tips[:n - 1] + [tips[n - 1][:k]]
    rest = [tips[n - 1][k - 1:]] + tips[n:-2]
    rows = fill.FillRows(cut, drawn, h, depth=0.7)
    for part in (early, rest):
        rows.add_grid(move_grid(*centre_moves(part, R)))
    rows.add(tips[-2:])  # the passes after, as fill_passes adds them
    got = rows.balls()
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2] == want[2] and got[3] == want[3]

