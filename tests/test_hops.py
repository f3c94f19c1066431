"""Hops over lifted runs (``Job.hop_lift``, ``--hop-lifted``): the clearance bound they fly
at, the program they give (gouge-free, rapids clear of the part, the same whatever the
batching), and their G-code."""

from __future__ import annotations

import numpy as np
import pytest

from conformill.cli.main import main
from conformill.cutter import BallCutter
from conformill.errors import PlanningError
from conformill.mesh import synthetic
from conformill.output.gcode import format_gcode, write_gcode
from conformill.passes import HOP_CLEARANCE, PassBuilder
from conformill.pipeline import Job, plan
from conformill.types import ToolPath
from conformill.verify.gcode import read_gcode
from conformill.verify.simulate import rapid_clearance, segment_triangle_distance, verify
from test_gcode_rs274 import _assert_clean, needs_rs274, run_rs274

R = 4.0


# -- the clearance bound ---------------------------------------------------------------
def test_clear_height_on_a_plane_is_the_ball_resting_on_it():
    # every cell's top is 0, so the bound is exactly r (r + c with a clearance c)
    m = synthetic.plane(size=60.0, spacing=3.0, z=0.0)
    c = BallCutter(m.V, m.F, R)
    a = np.array([[-20.0, -20.0], [0.0, 0.0], [5.0, -7.0]])
    b = np.array([[20.0, 15.0], [0.0, 0.0], [-3.0, 9.0]])
    assert np.allclose(c.clear_height(a, b), R, atol=1e-12)
    assert np.allclose(c.clear_height(a, b, clearance=1.5), R + 1.5, atol=1e-12)
    # out of reach of every triangle: nothing to clear
    far = np.array([[500.0, 500.0]])
    assert np.isneginf(c.clear_height(far, far + 10.0))[0]


@pytest.mark.parametrize("part", ["face", "groove"])
def test_clear_height_bounds_the_drop_surface_along_the_segment(part):
    m = synthetic.face_like(spacing=2.0) if part == "face" else synthetic.v_groove(a_deg=60.0, step=0.5)
    c = BallCutter(m.V, m.F, R)
    rng = np.random.default_rng(3)
    lo, hi = m.V[:, :2].min(0) - 3, m.V[:, :2].max(0) + 3
    a = rng.uniform(lo, hi, (120, 2))
    b = a + rng.normal(0.0, 8.0, (120, 2))
    b[:5] = a[:5]  # points
    H = c.clear_height(a, b)
    t = np.linspace(0.0, 1.0, 1500)
    top = np.array([c.drop(a[k] + t[:, None] * (b[k] - a[k])).max() for k in range(len(a))])
    seen = np.isfinite(top)
    assert seen.sum() > 60
    assert np.all(H[seen] >= top[seen])
    # and it is a bound, not a guess far above: within the cells' slack (about a cell's rise)
    assert np.median(H[seen] - top[seen]) < 3.0


def test_clear_height_with_clearance_keeps_the_ball_that_far_from_the_part():
    # the ball of radius r at the bounded height is at least c from every vertex and facet
    m = synthetic.sphere_cap(R=20.0, radius_xy=15.0, spacing=1.5)
    c = BallCutter(m.V, m.F, R)
    rng = np.random.default_rng(0)
    a = rng.uniform(-15, 15, (40, 2))
    b = rng.uniform(-15, 15, (40, 2))
    H = c.clear_height(a, b, clearance=1.0)
    # the exact distance from each move at that height to every triangle
    P = np.column_stack([a, H])
    Q = np.column_stack([b, H])
    seg = np.repeat(np.arange(len(a)), len(m.F))
    tri = np.tile(np.arange(len(m.F)), len(a))
    d = segment_triangle_distance(P, Q, m.V, m.F, seg, tri)
    assert d.min() >= R + 1.0 - 1e-9
    # not far above either: the nearest triangle of some move is within a few mm more
    assert np.median(d.reshape(len(a), -1).min(axis=1)) < R + 4.0


def test_clear_height_rejects_bad_input():
    m = synthetic.plane(size=20.0, spacing=4.0)
    c = BallCutter(m.V, m.F, R)
    with pytest.raises(PlanningError, match="clearance"):
        c.clear_height(np.zeros((1, 2)), np.zeros((1, 2)), clearance=-1.0)
    with pytest.raises(PlanningError, match="same shape"):
        c.clear_height(np.zeros((2, 2)), np.zeros((1, 2)))
    with pytest.raises(PlanningError, match="non-finite"):
        c.clear_height(np.array([[np.nan, 0.0]]), np.zeros((1, 2)))


# -- the program --------------------------------------------------------------------------
GROOVE = synthetic.v_groove(a_deg=60.0, half=12.0, step=0.5)


def _job(pattern, hop):
    return Job(pattern=pattern, tool_radius=R, scallop=0.05, tolerance=0.01, hop_lift=hop)


@pytest.mark.parametrize("pattern", ["zigzag", "contour"])
def test_nothing_lifted_that_high_gives_the_same_program(pattern):
    # the hop path of the pass builder (pieces settled and refined together) cuts the same
    # points as the plain one when no run is lifted above the limit
    a = plan(GROOVE, _job(pattern, 0.0)).toolpath
    b = plan(GROOVE, _job(pattern, 1e3)).toolpath
    assert len(a.passes) == len(b.passes)
    for p, q in zip(a.passes, b.passes):
        assert np.array_equal(p, q)
    assert all(h is None for h in b.hops)


@pytest.mark.parametrize("pattern", ["zigzag", "contour"])
def test_hopped_program_is_gouge_free_and_its_rapids_clear_the_part(pattern, tmp_path):
    e = 0.01
    res = plan(GROOVE, _job(pattern, 0.5))
    hops = res.report["cutter"]["hops"]
    assert hops["hops"] > 0 and hops["cc_points_not_cut"] > 0 and hops["minutes_saved"] > 0
    tp = res.toolpath
    assert len(tp.hops) == len(tp.passes)
    assert sum(h is not None for h in tp.hops) == hops["hops"]
    # a hop flies no lower than the ends it joins
    for k, h in enumerate(tp.hops):
        if h is not None:
            across, down = h
            assert across >= max(tp.passes[k - 1][-1, 2], tp.passes[k][0, 2]) - 1e-12
            assert tp.passes[k][0, 2] - 1e-12 <= down <= across + 1e-12
    base = plan(GROOVE, _job(pattern, 0.0))
    assert res.report["paths"]["cl_points"] < base.report["paths"]["cl_points"]
    path = tmp_path / "hop.nc"
    write_gcode(path, tp, feed=1000.0)
    prog = read_gcode(path)
    v = verify(GROOVE, prog, R, n_samples=20000, seed=0, gouge=e)
    assert v.summary["gouge_max"] <= e / 2 + 1e-6
    rc = rapid_clearance(GROOVE.V, GROOVE.F, prog, R)
    assert rc["n_rapids"] >= hops["hops"]  # across (and down) for each; the retracts apart
    assert rc["rapid_min_clearance"] >= HOP_CLEARANCE - 1e-3  # 4-decimal rounding


def test_hops_do_not_depend_on_the_batches():
    # a lifted run that reaches a batch's end waits for the next batch: any batch size
    # gives the same passes and hops
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_passes import record_plan

    res, recorded = record_plan(GROOVE, _job("contour", 0.5))
    assert res.report["cutter"]["hops"]["hops"] > 0
    kw = dict(recorded["kw"])
    for batch, first in [(1, 1), (7, 3), (50, 50)]:
        kw.update(threaded=False, batch=batch, first_batch=first)
        b = PassBuilder(recorded["make_cutter"], *recorded["args"], **kw)
        if batch == 1:  # the pencil's links start early from where the passes will end
            b.cutter = recorded["make_cutter"]()
            for pc in recorded["pieces"]:
                b.add(pc)
            predicted = b.end_xy()
        else:
            for pc in recorded["pieces"]:
                b.add(pc)
        passes, _, _, hops = b.finish()
        if batch == 1:
            assert predicted is not None and np.array_equal(predicted, passes[-1][-1, :2])
        assert len(passes) == len(res.toolpath.passes)
        for p, q in zip(passes, res.toolpath.passes):
            assert np.array_equal(p, q)
        assert hops == list(res.toolpath.hops)


# -- G-code ---------------------------------------------------------------------------------
def test_gcode_of_a_hop():
    tp = ToolPath(passes=[np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 1.0]]),
                          np.array([[20.0, 0.0, 2.0], [30.0, 0.0, 2.0]])],
                  safe_z=25.0, hops=[None, (6.00001, 3.5)])
    text = format_gcode(tp, feed=600.0, plunge_feed=200.0)
    body = text.splitlines()
    i = body.index("G1 X10.0000 F600")
    # retract to the hop's height (rounded up), across, rapid down, plunge
    assert body[i + 1:i + 6] == ["G0 Z6.0001", "G0 X20.0000 Y0.0000", "G0 Z3.5000", "G1 Z2.0000 F200",
                                 "G1 X30.0000 F600"]
    assert body.count("G0 Z25.0000") == 2  # the start and the end only
    # a retract program, for comparison: the plunge from the safe height
    plain = format_gcode(ToolPath(passes=tp.passes, safe_z=25.0), feed=600.0, plunge_feed=200.0)
    assert "G0 Z25.0000\nG0 X20.0000 Y0.0000\nG1 Z2.0000 F200" in plain
    with pytest.raises(PlanningError, match="hops"):
        format_gcode(ToolPath(passes=tp.passes, safe_z=25.0, hops=[None]), feed=600.0)
    with pytest.raises(PlanningError, match="not finite"):
        format_gcode(ToolPath(passes=tp.passes, safe_z=25.0, hops=[None, (np.nan, 1.0)]), feed=600.0)


def test_gcode_hop_is_never_below_the_ends_or_above_the_safe_height():
    P = [np.array([[0.0, 0.0, 4.0], [1.0, 0.0, 4.0]]), np.array([[5.0, 0.0, 3.0], [6.0, 0.0, 3.0]]),
         np.array([[9.0, 0.0, 1.0], [9.5, 0.0, 1.0]])]
    text = format_gcode(ToolPath(passes=P, safe_z=10.0, hops=[None, (2.0, 2.0), (50.0, 0.5)]), feed=600.0)
    lines = text.splitlines()
    # a hop height below the last pass's end is raised to it (no retract then, and no
    # rapid down onto the start: the plunge); one above safe_z is cut to it
    assert "G1 X1.0000\nG0 X5.0000 Y0.0000\nG1 Z3.0000\nG1 X6.0000" in text
    assert "G1 X6.0000\nG0 Z10.0000\nG0 X9.0000 Y0.0000\nG1 Z1.0000" in text
    assert not any(ln.startswith("G0 Z0.5") for ln in lines)


# -- the command line -------------------------------------------------------------------
@pytest.mark.parametrize("opt, value", [("--hop-lifted", "-1"), ("--hop-lifted", "nan"), ("--rapid", "0")])
def test_cli_rejects_bad_hop_options(tmp_path, capsys, opt, value):
    out = tmp_path / "p.nc"
    rc = main(["plan", "sample:patch", "--tool-radius", "4", "--scallop", "0.1", opt, value, "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2  # a malformed job value, as for the other job parameters
    assert "Traceback" not in err and ("hop-lifted" in err or "rapid" in err)
    assert not out.exists()


def test_cli_header_names_the_hops_only_when_on(tmp_path):
    on, off = tmp_path / "on.nc", tmp_path / "off.nc"
    common = ["plan", "sample:patch", "--tool-radius", "4", "--scallop", "0.1", "-q"]
    assert main(common + ["--hop-lifted", "2", "-o", str(on)]) == 0
    assert main(common + ["-o", str(off)]) == 0
    assert "(param hop lifted: runs lifted more than 2 mm, rapid 5000)" in on.read_text()
    assert "hop" not in off.read_text()


@needs_rs274
def test_linuxcnc_accepts_a_hopped_program(tmp_path):
    res = plan(GROOVE, _job("contour", 0.5))
    assert res.report["cutter"]["hops"]["hops"] > 0
    path = tmp_path / "hop.nc"
    write_gcode(path, res.toolpath, feed=1000.0, plunge_feed=300.0)
    rc, out, canon = run_rs274(path.read_text(), tmp_path)
    _assert_clean(rc, out)
    # every hop's rapid across and down are traverses in LinuxCNC's own reading
    assert canon.count("STRAIGHT_TRAVERSE") >= 2 * res.report["cutter"]["hops"]["hops"]


def test_gcode_rejects_malformed_hops_without_a_traceback():
    P = [np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]), np.array([[5.0, 0.0, 1.0], [6.0, 0.0, 1.0]])]
    with pytest.raises(PlanningError, match="two heights"):
        format_gcode(ToolPath(passes=P, safe_z=10.0, hops=[None, 3.0]), feed=600.0)
    # a hop given as an array of two heights
    text = format_gcode(ToolPath(passes=P, safe_z=10.0, hops=[None, np.array([3.0, 2.0])]), feed=600.0)
    assert "G0 Z3.0000\nG0 X5.0000 Y0.0000\nG0 Z2.0000\nG1 Z1.0000" in text
    # a malformed next pass is reported as such, not as an index error
    with pytest.raises(PlanningError, match="pass 1"):
        format_gcode(ToolPath(passes=[P[0], np.zeros((0, 3))], safe_z=10.0, hops=[None, (3.0, 2.0)]), feed=600.0)
