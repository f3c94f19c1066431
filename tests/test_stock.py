"""Stock to leave (``plan --stock S``, ``verify --stock S``): the program finishes the part's
offset by S. Oracles: the cusp between two balls on an offset circle, planes, a dome."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from conformill.cli.main import main
from conformill.errors import PlanningError
from conformill.mesh import synthetic
from conformill.output.gcode import write_gcode
from conformill.pipeline import Job, check_job, plan
from conformill.planning.steps import check_params, side_interval, side_interval_stock
from conformill.verify.gcode import read_gcode
from conformill.verify.simulate import segment_triangle_distance, verify


def _cusp_on_offset(l_part, R, s, r, convex):
    """Cusp height above the offset (radius ``R + s`` convex, ``R - s`` concave) left by two
    balls of radius ``r`` rolling on it, whose contacts on the part (radius ``R``) are a
    chord ``l_part`` apart: plane geometry, independent of the planner's formula."""
    a = 2.0 * math.asin(l_part / (2.0 * R))  # the angle between the two normals
    if convex:
        d = R + s + r  # ball centres' distance from the circle's centre
        y = d * math.cos(a / 2) - math.sqrt(r * r - (d * math.sin(a / 2)) ** 2)  # the balls' lower crossing
        return y - (R + s)
    d = R - s - r
    y = d * math.cos(a / 2) + math.sqrt(r * r - (d * math.sin(a / 2)) ** 2)  # the outer crossing
    return (R - s) - y


@pytest.mark.parametrize("R", [12.0, 40.0, 300.0])
@pytest.mark.parametrize("s", [0.3, 2.0, -1.5])
@pytest.mark.parametrize("convex", [True, False])
def test_side_interval_stock_leaves_h_on_the_offset(R, s, convex):
    r, h = 4.0, 0.05
    kappa = -1.0 / R if convex else 1.0 / R
    ls, reach = side_interval_stock(h, r, np.array([kappa]), s)
    if not convex and R - s <= r:  # the ball cannot follow the offset
        assert not reach[0]
        return
    assert reach[0]
    assert _cusp_on_offset(float(ls[0]), R, s, r, convex) == pytest.approx(h, rel=1e-9)


def test_side_interval_stock_zero_is_side_interval():
    k = np.linspace(-0.5, 0.3, 41)
    a, ra = side_interval(0.02, 4.0, k)
    b, rb = side_interval_stock(0.02, 4.0, k, 0.0)
    assert np.array_equal(a, b) and np.array_equal(ra, rb)
    c, _ = side_interval_stock(0.02, 4.0, k, 0.0, cap=0.5)
    assert np.array_equal(c, np.minimum(a, 0.5))


def test_side_interval_stock_reach_is_that_of_the_bigger_ball():
    # the ball of radius r on the offset follows it exactly where the ball of radius r + s follows the part
    r, s = 4.0, 1.0
    k = np.array([0.19, 0.1999, 0.2001, 0.21, 1.0 / s, 2.0, np.nan])
    _, reach = side_interval_stock(0.01, r, k, s)
    assert reach.tolist() == [True, True, False, False, False, False, False]
    # with a negative stock a convex radius below -s folds the offset over
    _, reach = side_interval_stock(0.01, r, np.array([-0.4, -0.6]), -2.0)
    assert reach.tolist() == [True, False]


def _program(part, job, tmp_path, name="p.nc"):
    res = plan(part, job)
    nc = tmp_path / name
    write_gcode(nc, res.toolpath, feed=job.feed)
    return res, read_gcode(nc)


def test_plane_tips_at_the_stock_and_paths_as_without(tmp_path):
    part = synthetic.plane(size=40.0, spacing=4.0)
    base = Job(pattern="zigzag", tool_radius=3.0, scallop=0.02, tolerance=0.01)
    r0, _ = _program(part, base, tmp_path, "a.nc")
    for s in (0.4, -0.25):
        rs, prog = _program(part, Job(**{**base.__dict__, "stock": s}), tmp_path, "b.nc")
        a, b = np.concatenate(r0.toolpath.passes), np.concatenate(rs.toolpath.passes)
        # a plane's offset is a plane: the same passes, the tips s higher
        assert a.shape == b.shape
        assert np.allclose(b[:, :2], a[:, :2], atol=1e-9) and np.allclose(b[:, 2], s, atol=1e-9)
        assert rs.report["job"]["stock"] == s
        v = verify(rs.mesh, prog, 3.0, n_samples=30_000, scallop=1.05 * 0.02, gouge=0.01, stock=s).summary
        assert v["pass"], v["failures"]
        assert v["stock"] == s and v["tool_radius"] == 3.0


@pytest.fixture(scope="module")
def dome_programs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dome")
    dome = synthetic.sphere_cap(R=40.0, radius_xy=25.0, spacing=1.5, jitter=0.2)
    job = Job(pattern="spiral", tool_radius=4.0, scallop=0.05, tolerance=0.01)
    plain = _program(dome, job, tmp, "plain.nc")
    stocked = _program(dome, Job(**{**job.__dict__, "stock": 0.3}), tmp, "stock.nc")
    return dome, plain, stocked


def test_dome_with_stock_meets_the_scallop_on_the_offset(dome_programs):
    dome, _, (res, prog) = dome_programs
    v = verify(res.mesh, prog, 4.0, n_samples=60_000, scallop=1.05 * 0.05, gouge=0.01, stock=0.3).summary
    assert v["pass"], v["failures"]
    assert v["gouge_max"] <= 0.005 + 1e-6  # the cutter's budget e/2, now into the stock
    # measured from the part itself, the same program leaves the stock everywhere and never gouges
    w = verify(res.mesh, prog, 4.0, n_samples=60_000, gouge=0.0).summary
    assert w["gouge_max"] == 0.0
    # (along a sample's normal the part is the offset less s: the same ray, s longer)
    # (on all samples: the interior is taken r + s from the boundary with the stock)
    assert w["all"]["scallop"]["p50"] == pytest.approx(0.3 + v["all"]["scallop"]["p50"], abs=1e-9)
    assert w["all"]["scallop"]["max"] == pytest.approx(0.3 + v["all"]["scallop"]["max"], abs=1e-9)
    # every centre is at least r + s from the part (exact point-triangle distances; the
    # moves between them may come e/2 nearer), and some touch it
    c = np.concatenate(res.toolpath.passes) + [0.0, 0.0, 4.0]
    seg, tri = np.divmod(np.arange(len(c) * len(res.mesh.F)), len(res.mesh.F))
    d = segment_triangle_distance(c, c, res.mesh.V, res.mesh.F, seg, tri).reshape(len(c), -1).min(axis=1)
    assert d.min() >= 4.3 - 1e-6 and np.median(d) == pytest.approx(4.3, abs=1e-6)


def test_dome_program_without_stock_gouges_the_stock(dome_programs):
    dome, (res, prog), _ = dome_programs
    v = verify(res.mesh, prog, 4.0, n_samples=60_000, gouge=0.01, stock=0.3).summary
    assert not v["pass"] and v["gouge_max"] == pytest.approx(0.3, abs=0.01)


def test_stock_spacing_on_a_convex_part_is_closer_on_the_part(dome_programs):
    # convex: the centres spread out on the offset, so the contacts on the part come closer
    _, (plain, _), (stocked, _) = dome_programs
    a = plain.report["side_step"]["allowed_mm"]["mean"]
    b = stocked.report["side_step"]["allowed_mm"]["mean"]
    assert b < a


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -4.0, -5.0, True, "x"])
def test_bad_stock_refused(bad):
    with pytest.raises(PlanningError, match="stock"):
        check_params(4.0, 0.1, 0.01, bad)
    with pytest.raises(PlanningError, match="stock"):
        check_job(Job(stock=bad))


def test_safe_z_clears_the_stock():
    part = synthetic.plane(size=20.0, spacing=4.0)
    with pytest.raises(PlanningError, match="stock"):
        plan(part, Job(pattern="zigzag", stock=3.0, safe_z=2.0))


def test_cli_stock_header_report_and_verify(tmp_path, capsys):
    part = tmp_path / "dome.ply"
    import trimesh

    m = synthetic.sphere_cap(R=40.0, radius_xy=20.0, spacing=2.0)
    trimesh.Trimesh(m.V, m.F, process=False).export(part)
    out, rep = tmp_path / "s.nc", tmp_path / "s.json"
    rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.1", "--stock", "0.5",
               "-o", str(out), "--report", str(rep), "--verify", "--verify-samples", "40000"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "stock 0.5" in text and "on the part offset by the stock" in text
    lines = out.read_text().splitlines()
    assert "(param stock: 0.5 mm left on the part [the ball R4 finishes its offset])" in lines
    r = json.loads(rep.read_text())
    assert r["job"]["stock"] == 0.5 and r["verify"]["stock"] == 0.5 and r["verify"]["pass"]
    # verify of the same program: PASS on the offset, a gouge of the stock without it
    assert main(["verify", str(part), str(out), "-r", "4", "--scallop", "0.105", "--gouge", "0.01",
                 "--stock", "0.5", "--samples", "40000"]) == 0
    assert "stock 0.5 mm" in capsys.readouterr().out
    assert main(["verify", str(part), str(out), "-r", "4", "--scallop", "0.105", "--samples", "40000"]) == 1
    # a program without stock has no stock line (its bytes are as before)
    assert main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.1", "-o", str(tmp_path / "n.nc"),
                 "-q"]) == 0
    assert not any(ln.startswith("(param stock") for ln in (tmp_path / "n.nc").read_text().splitlines())


def test_cli_bad_stock(tmp_path, capsys):
    part = "sample:patch"
    out = tmp_path / "b.nc"
    # S <= -r: a ball of no size, a malformed value: 2, as from verify and view
    assert main(["plan", part, "--tool-radius", "4", "--scallop", "0.1", "--stock", "-4", "-o", str(out)]) == 2
    assert "stock" in capsys.readouterr().err and not out.exists()
    assert main(["plan", part, "--tool-radius", "4", "--scallop", "0.1", "--stock", "nan", "-o", str(out)]) == 2
    assert "stock" in capsys.readouterr().err and not out.exists()
    assert main(["plan", part, "--tool-radius", "4", "--scallop", "0.1", "--stock", "lots", "-o", str(out)]) == 2
    assert not out.exists()
    capsys.readouterr()
    prog = tmp_path / "x.nc"
    prog.write_text("G21 G90\nG1 X0 Y0 Z0 F100\nG1 X1\nM30\n")
    assert main(["verify", part, str(prog), "-r", "4", "--stock", "nan"]) == 2
    assert "--stock" in capsys.readouterr().err
    assert main(["view", part, str(prog), "--tool-radius", "4", "--stock", "-9", "-o", str(tmp_path / "v.html")]) == 2
    assert not (tmp_path / "v.html").exists()


# -- the one stock check ----------------------------------------------------------------
def test_check_stock_values_and_messages():
    from conformill.errors import ConformillError, PlanningError
    from conformill.planning.steps import check_stock

    assert check_stock(0.3, 4.0) == 0.3
    z = check_stock(-0.0, 4.0)
    assert z == 0.0 and math.copysign(1.0, z) == 1.0  # -0.0 written as 0.0
    assert check_stock(-9.0, None) == -9.0  # no radius: only finite
    with pytest.raises(PlanningError, match=r"stock must be a finite number of mm above minus the tool radius \(-4\)") \
            as ei:
        check_stock(-4.0, 4.0)
    assert ei.value.exit_code == 2  # a JobValueError: a malformed value, as from verify and view
    for bad in (float("nan"), float("inf"), True):
        with pytest.raises(ConformillError, match=r"^--stock must be a finite number of mm"):
            check_stock(bad, 4.0, ConformillError, "--stock")
    with pytest.raises(ConformillError, match=r"^--stock must be a finite number of mm, got nan$"):
        check_stock(float("nan"), None, ConformillError, "--stock")
    with pytest.raises(ConformillError, match=r"must be a number \(mm\), got 'x'"):
        check_stock("x", 4.0, ConformillError)


def test_simulate_verify_rejects_a_stock_that_is_not_a_number():
    from conformill.errors import ConformillError

    part = synthetic.plane(size=20, spacing=2.0)
    prog = read_gcode("G21 G90\nG0 Z10\nG1 X1 Y1 Z0 F100\nG1 X5 Y1 Z0\nM30\n")
    with pytest.raises(ConformillError, match="stock must be a number"):
        verify(part, prog, 4.0, n_samples=100, stock="x")
