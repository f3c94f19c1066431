"""End-to-end planning on analytic parts: spacing, CC on the mesh, cutter offset, errors."""

import logging

import numpy as np
import pytest

from conformill.errors import JobValueError, ParameterizationError, PlanningError
from conformill.mesh import synthetic
from conformill.pipeline import Job, plan, with_overrides

R_TOOL, H = 4.0, 0.1
FLAT = 2 * np.sqrt(H * (2 * R_TOOL - H))


@pytest.fixture(scope="module")
def square():
    return synthetic.plane(size=40.0, spacing=2.0, jitter=0.25, seed=3)


@pytest.fixture(scope="module")
def zigzag_square(square):
    return plan(square, Job(pattern="zigzag", tool_radius=R_TOOL, scallop=H, tolerance=0.01))


def test_zigzag_on_plane_spaces_paths_at_exact_flat_interval(zigzag_square):
    dom = zigzag_square.domain_paths
    d = [np.median(p.side_realised) for p in dom.paths[:-2]]
    # the rectangle map of a square plane is a similarity: every step is the flat interval
    np.testing.assert_allclose(d, FLAT, rtol=1e-6)
    last = dom.paths[-2].side_realised
    assert np.all(last <= FLAT * (1 + 1e-9))
    assert len(zigzag_square.toolpath.passes) == 1  # rows linked on the surface


def test_split_fit_on_plane_spaces_paths_at_exact_flat_interval(square):
    # the split fit sees the same plane (zero curvature): the same flat interval, and the
    # planner's finer mesh is the input surface, so every tip is on the plane
    res = plan(square, Job(pattern="zigzag", tool_radius=R_TOOL, scallop=H, tolerance=0.01, fit="split"))
    assert res.report["job"]["fit"] == "split"
    d = [np.median(p.side_realised) for p in res.domain_paths.paths[:-2]]
    np.testing.assert_allclose(d, FLAT, rtol=1e-6)
    tips = np.concatenate(res.toolpath.passes)
    np.testing.assert_allclose(tips[:, 2], 0.0, atol=1e-9)


def test_plane_tool_tip_sits_on_plane(zigzag_square):
    tips = np.concatenate(zigzag_square.toolpath.passes)
    np.testing.assert_allclose(tips[:, 2], 0.0, atol=1e-9)


def test_split_fit_spaces_a_dome_more_densely():
    # on chords the split fit reads twice the curvature at the input's vertices, and with the
    # min rule that sets each path's step: more paths and CL points, every one still within
    # the allowed interval of its neighbour
    dome = synthetic.sphere_cap(R=50.0, radius_xy=25.0, spacing=1.5, jitter=0.2)
    job = Job(pattern="contour", tool_radius=R_TOOL, scallop=0.2, tolerance=0.01)
    a = plan(dome, job)
    b = plan(dome, with_overrides(job, fit="split"))
    assert len(b.domain_paths.paths) > len(a.domain_paths.paths)
    assert b.report["paths"]["cl_points"] > a.report["paths"]["cl_points"]
    for p in b.domain_paths.paths[:-1]:
        assert np.all(p.side_realised <= p.side_allowed * (1 + 1e-9))


@pytest.mark.parametrize("fit", ["mesh", "split"])
def test_cc_points_lie_on_mesh_and_ball_centre_is_r_along_normal(fit):
    dome = synthetic.sphere_cap(R=50.0, radius_xy=25.0, spacing=1.5, jitter=0.2)
    res = plan(dome, Job(pattern="contour", tool_radius=R_TOOL, scallop=0.2, tolerance=0.01, fit=fit))
    cc = np.concatenate(res.cc_paths)
    # on the faceted sphere: vertices are on it, a face lies inside by at most
    # R - sqrt(R^2 - rho^2), rho the largest circumradius
    V, F = dome.V, dome.F
    a, b, c = (np.linalg.norm(V[F[:, i]] - V[F[:, j]], axis=1) for i, j in ((1, 2), (2, 0), (0, 1)))
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    rho = (a * b * c / (4 * area)).max()
    sag = 50.0 - np.sqrt(50.0**2 - rho**2)
    rr = np.linalg.norm(cc, axis=1)
    assert np.all(rr <= 50.0 + 1e-9) and np.all(rr >= 50.0 - sag - 1e-9)
    # ball centre = CC + r n: on the offset sphere of radius R + r, up to faceting
    tips = np.concatenate(res.toolpath.passes)
    centres = tips + [0, 0, R_TOOL]
    d = np.linalg.norm(centres, axis=1)
    assert np.all(d <= 54.0 + 1e-6) and np.all(d >= 54.0 - sag - 1e-6)


def test_spiral_is_one_pass_and_contour_has_no_retracts():
    part = synthetic.freeform_patch(spacing=2.5)
    sp = plan(part, Job(pattern="spiral", tool_radius=R_TOOL, scallop=0.5, tolerance=0.02))
    assert len(sp.toolpath.passes) == 1
    co = plan(part, Job(pattern="contour", tool_radius=R_TOOL, scallop=0.5, tolerance=0.02))
    assert len(co.toolpath.passes) <= 1 + co.report["paths"]["retracts_for_long_links"]


def test_adjacent_paths_never_farther_than_allowed():
    part = synthetic.freeform_patch(spacing=2.5)
    for pattern in ("zigzag", "contour"):
        res = plan(part, Job(pattern=pattern, tool_radius=R_TOOL, scallop=0.3, tolerance=0.02))
        for p in res.domain_paths.paths[:-1]:
            assert np.all(p.side_realised <= p.side_allowed * (1 + 1e-9))


@pytest.mark.parametrize(
    "kw, word, code",
    [
        (dict(scallop=4.0), "scallop", 3),
        (dict(scallop=-0.1), "scallop", 2),
        (dict(tolerance=0.0), "tolerance", 2),
        (dict(tool_radius=float("nan")), "radius", 2),
        (dict(pattern="raster"), "pattern", 2),
        (dict(feed=0.0), "feed", 2),
        (dict(settle=-0.1), "settle", 2),
        (dict(settle=float("nan")), "settle", 2),
        (dict(fit="coarse"), "fit", 2),
        (dict(pencil=True, pencil_density=0.0), "pencil-density", 2),
        (dict(pencil=True, pencil_density=float("inf")), "pencil-density", 2),
        (dict(pencil=True, pencil_search="grid"), "pencil-search", 2),
        (dict(blend=4.5), "larger than the tool radius", 3),
        (dict(blend=-1.0), "blend", 2),
        (dict(coolant="oil"), "coolant", 2),
        # the plane is 10 mm across: a ball of radius above 1000 mm is a mistake of units
        (dict(tool_radius=1000.5), r"tool radius 1000.5 mm is more than 100 times the part's size \(10 x 10 x 0 mm\)",
         2),
    ],
)
def test_bad_job_values_are_refused(kw, word, code):
    # exit code 2: a malformed value (JobValueError); 3: values that cannot be met (h >= r)
    part = synthetic.plane(size=10, spacing=2)
    with pytest.raises(PlanningError, match=word) as ei:
        plan(part, Job(**{**dict(tool_radius=R_TOOL, scallop=H), **kw}))
    assert ei.value.exit_code == code and isinstance(ei.value, JobValueError) == (code == 2)


@pytest.mark.parametrize("kw, error, word", [
    (dict(tool_radius=1e9, scallop=1e10), JobValueError, "more than 100 times"),
    (dict(scallop=2 * R_TOOL, stock=float("inf")), JobValueError, "stock"),
    (dict(blend=2 * R_TOOL, feed=0.0), JobValueError, "feed"),
    (dict(pattern="zigzag", corners=(0, 1, 2, 10**6), scallop=2 * R_TOOL), ParameterizationError, "not in the mesh"),
    (dict(pattern="zigzag", corners=(0, 1, 1, 2), blend=2 * R_TOOL), ParameterizationError, "distinct"),
])
def test_a_malformed_value_is_named_before_values_that_cannot_be_met(kw, error, word):
    # the library refuses in the command line's order: every value on its own, the ball's size
    # and the corners against the mesh (exit code 2), then the values together (3)
    part = synthetic.plane(size=10, spacing=2)
    with pytest.raises(error, match=word) as ei:
        plan(part, Job(**{**dict(tool_radius=R_TOOL, scallop=H), **kw}))
    assert ei.value.exit_code == 2


def test_safe_z_below_part_is_refused():
    part = synthetic.sphere_cap(R=30, radius_xy=10, spacing=2)
    with pytest.raises(PlanningError, match="safe-z") as ei:
        plan(part, Job(tool_radius=2, scallop=0.1, safe_z=0.0))
    assert ei.value.exit_code == 3  # a finite height, not met on this part


def test_a_plan_too_large_for_memory_is_refused_before_any_work():
    # 40 x 40 mm at the flat side step: the feed estimate is area / FLAT; 1 MB per metre
    from conformill.pipeline import _check_size

    part = synthetic.plane(size=40.0, spacing=2.0)
    feed_m = 1600.0 / FLAT / 1000.0
    _check_size(part, 1600.0, FLAT, memory=1.01e6 * feed_m)  # just enough: no error
    with pytest.raises(PlanningError, match=r"40 x 40 x 0 mm .*--scale") as ei:
        _check_size(part, 1600.0, FLAT, memory=0.99e6 * feed_m)
    assert f"{feed_m / 1000:.4g} km" in str(ei.value)
    # on this machine: the same plane read as metres (x 1e5: 16 km^2) is refused by plan()
    big = synthetic.plane(size=4e6, spacing=2e5)
    with pytest.raises(PlanningError, match="units") as ei:
        plan(big, Job(tool_radius=R_TOOL, scallop=H))
    assert ei.value.exit_code == 3 and not isinstance(ei.value, JobValueError)


def test_a_tiny_scallop_is_refused_by_its_samples_memory(monkeypatch):
    # the paths are sampled every flat step / 3 (finer than the edges here): 300 bytes a sample
    from conformill.pipeline import _BYTES_PER_SAMPLE, _check_size

    part = synthetic.plane(size=40.0, spacing=2.0)
    flat = 3e-4
    feed_m = 1600.0 / flat / 1000.0
    need = feed_m * 1000.0 / (flat / 3.0) * _BYTES_PER_SAMPLE  # far above 1 MB per metre
    _check_size(part, 1600.0, flat, memory=1.01 * need)
    with pytest.raises(PlanningError, match="needing at least"):
        _check_size(part, 1600.0, flat, memory=0.99 * need)
    # plan() asks before any work. A 40 mm dome at h = 4e-4 (r = 2: 16 m of feed by the
    # estimate, 16 MB at 1 MB per metre, about 180 MB by its samples; it plans in about 300 MB)
    # on a machine of 50 MB: refused by the samples' bound alone. (So small a machine keeps
    # this test from filling the real one if the check breaks: at h = 1e-9 the dome was
    # killed by the OS after 140 s with 24 GB.)
    from conformill import pipeline

    monkeypatch.setattr(pipeline, "_physical_memory", lambda: 50e6)
    dome = synthetic.sphere_cap(R=50, radius_xy=20, spacing=2)
    with pytest.raises(PlanningError, match="needing at least .* GB to plan"):
        plan(dome, Job(tool_radius=2, scallop=4e-4))


def test_a_part_smaller_than_the_ball_is_planned_with_a_units_warning(caplog):
    # choi's face is 0.12 m across: read as mm it is a speck under the ball
    from conformill.types import Mesh

    cap = synthetic.sphere_cap(R=50.0, radius_xy=30.0, spacing=2.0)
    tiny = Mesh(V=cap.V * 1e-3, F=cap.F, name="tiny")
    with caplog.at_level("WARNING", logger="conformill"):
        plan(tiny, Job(tool_radius=R_TOOL, scallop=1e-4, tolerance=1e-4))
    msg = [r.getMessage() for r in caplog.records if "smaller than the ball" in r.getMessage()]
    assert len(msg) == 1 and "0.06 x 0.06 mm" in msg[0] and "--scale 1000" in msg[0]
    caplog.clear()
    with caplog.at_level("WARNING", logger="conformill"):
        plan(cap, Job(tool_radius=R_TOOL, scallop=H))
    assert not any("smaller than the ball" in r.getMessage() for r in caplog.records)


def test_concave_trough_spacing_flat_cap_and_exact_formula():
    """On a concave cylinder the paper's formula spaces wider than flat; the default caps it."""
    from conformill.planning.steps import side_interval

    Rc = 12.0
    part = synthetic.cylinder_patch(R=Rc, length=40.0, half_angle=0.7, spacing=1.0, concave=True)
    h = 0.2
    flat = float(side_interval(h, R_TOOL, np.zeros(1))[0][0])
    concave = float(side_interval(h, R_TOOL, np.array([1.0 / Rc]))[0][0])
    assert concave > 1.1 * flat
    for mode in ("flat", "exact"):
        res = plan(part, Job(pattern="contour", tool_radius=R_TOOL, scallop=h, tolerance=0.02, concave_steps=mode))
        ls = np.concatenate([p.side_allowed for p in res.domain_paths.paths])
        mid = np.concatenate([p.side_realised for p in res.domain_paths.paths[:-1]])
        assert np.nanmax(mid) <= np.nanmax(ls) * (1 + 1e-6)
        if mode == "flat":
            assert np.nanmax(ls) <= flat * (1 + 1e-6)
        else:  # where the rings run along the axis, the step is the concave one (fitted curvature)
            assert np.nanpercentile(ls, 95) == pytest.approx(concave, rel=0.05)


def test_concave_regions_are_components_sorted_by_area():
    """The report's concave regions against a per-component loop (two disjoint blobs)."""
    from conformill.mesh.topology import face_components
    from conformill.pipeline import _regions, face_normals

    m = synthetic.plane(size=40.0, spacing=2.0, jitter=0.25, seed=3)
    _, fa = face_normals(m.V, m.F)
    cen = m.V[m.F].mean(axis=1)
    mask = (np.hypot(cen[:, 0] + 10, cen[:, 1]) < 6) | (np.hypot(cen[:, 0] - 10, cen[:, 1] - 8) < 4)
    got = _regions(mask, m, fa)
    idx = np.flatnonzero(mask)
    n, lab = face_components(m.F[idx], m.n_vertices)
    assert n == 2 and len(got) == 2
    want = []
    for c in range(n):
        w = fa[idx][lab == c]
        want.append((w.sum(), (cen[idx][lab == c] * w[:, None]).sum(0) / w.sum(), int((lab == c).sum())))
    want.sort(key=lambda t: -t[0])
    for g, (a, c, k) in zip(got, want):
        assert g["faces"] == k
        np.testing.assert_allclose(g["area_mm2"], a, rtol=1e-12)
        np.testing.assert_allclose(g["centre"], c, atol=1e-9)
    np.testing.assert_allclose(got[0]["centre"][:2], [-10, 0], atol=0.5)
    assert _regions(np.zeros(len(m.F), bool), m, fa) == []


@pytest.mark.parametrize("mode,flip", [("none", False), ("none", True), ("auto", False), ("auto", True)])
def test_orient_mesh_normals_are_those_of_the_returned_mesh(mode, flip):
    """The face normals orient_mesh hands on equal face_normals of the mesh it returns,
    bit for bit (re-wound faces: negated; turned part: recomputed), and face +Z on average."""
    from conformill.pipeline import face_normals, orient_mesh
    from conformill.types import Mesh

    m = synthetic.cylinder_patch(R=30.0, length=40.0, half_angle=0.6, spacing=2.0)
    V = m.V @ np.array([[1.0, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]]).T
    F = m.F[:, [0, 2, 1]] if flip else m.F
    out, info, n, a = orient_mesh(Mesh(V=V, F=F), mode, normals=True)
    n2, a2 = face_normals(out.V, out.F)
    assert np.array_equal(n, n2) and np.array_equal(a, a2)
    assert info["rewound"] == flip
    mean = (n * a[:, None]).sum(0)
    assert mean[2] > 0
    if mode == "auto":
        np.testing.assert_allclose(mean / np.linalg.norm(mean), [0, 0, 1], atol=1e-12)


def test_settle_lowers_moves_into_a_groove_narrower_than_the_ball():
    """A V-groove (walls at 30 degrees) that the ball bridges: with the settle check no move
    floats more than about settle * H above the drop surface where it crosses the crease;
    without it the moves ride over the groove."""
    from conformill.cutter import BallCutter

    outline = np.array([[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]])
    part = synthetic.height_field(outline, lambda x, y: np.minimum(np.abs(x), 6.0) * np.tan(np.radians(30.0)),
                                  0.5, name="groove")
    cut = BallCutter(part.V, part.F, R_TOOL)
    h = 0.05
    floats = {}
    for settle in (0.0, 0.5):
        res = plan(part, Job(pattern="zigzag", tool_radius=R_TOOL, scallop=h, tolerance=0.01, settle=settle))
        assert (res.report["cutter"]["settled_points"] > 0) == (settle > 0)
        worst = []
        for tips in res.toolpath.passes:
            P = tips + [0.0, 0.0, R_TOOL]
            t = np.arange(1, 16) / 16
            Q = P[:-1, None, :] + t[None, :, None] * np.diff(P, axis=0)[:, None, :]
            D = cut.drop(Q[:, :, :2].reshape(-1, 2)).reshape(Q.shape[:2])
            worst.append(np.max(np.where(np.isfinite(D), Q[:, :, 2] - D, -np.inf)))
        floats[settle] = max(worst)
    assert floats[0.0] > 4 * h
    assert floats[0.5] <= 0.5 * h


def test_concave_warning_points_to_the_pencil(caplog):
    """A bowl tighter than the ball: the warning names the region and, without the pencil,
    the option that adds passes there and the scan settings that include it."""
    m = synthetic.sphere_cap(R=10.0, radius_xy=7.0, spacing=1.0, concave=True)
    for pencil in (False, True):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            res = plan(m, Job(pattern="contour", tool_radius=12.0, scallop=0.5, pencil=pencil,
                              pencil_search="folds", pencil_density=5.0))
        assert res.report["reachability"]["concave_below_tool_radius_share"] > 0.5
        msgs = [r.getMessage() for r in caplog.records if "the ball cannot follow it there" in r.getMessage()]
        assert len(msgs) == 1
        assert ("--pencil adds passes" in msgs[0]) is (not pencil)
        assert ("--scan" in msgs[0]) is (not pencil)  # and the scan settings, the pencil among them
