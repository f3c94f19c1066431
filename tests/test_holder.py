"""The holder check (:mod:`conformill.verify.holder`): analytic needs, bounds against a
brute-force sampling, and the command lines' options, refusals and exit codes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from conformill.cli.main import main
from conformill.errors import ConformillError
from conformill.mesh import synthetic
from conformill.verify.gcode import read_gcode
from conformill.verify.holder import holder_clearance


def _program(moves, start=None):
    """A program of G1 moves through ``moves`` (rows x y z), from ``start``."""
    lines = ["G21 G90"]
    if start is not None:
        lines.append("G0 X{:.6f} Y{:.6f} Z{:.6f}".format(*start))
    lines += ["G1 X{:.6f} Y{:.6f} Z{:.6f} F500".format(*m) for m in moves]
    return read_gcode("\n".join(lines))


def _tilted_square(k: float, half: float = 50.0):
    """The plane z = k x over [-half, half]^2 as two triangles: the support point of the
    holder's disk lies inside a triangle, away from every vertex and edge."""
    V = np.array([[-half, -half, -k * half], [half, -half, k * half], [half, half, k * half],
                  [-half, half, -k * half]], dtype=np.float64)
    return V, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


@pytest.mark.parametrize("k", [0.3, 1.0, 4.0])
def test_tilted_plane_needs_the_rim_height_in_the_climb_direction(k):
    # z = k x: within R of a tip at (x, y) the part is highest at x + R, so a move needs
    # max over its ends of k (x + R) - t_z (the need of a point is linear along the move)
    V, F = _tilted_square(k)
    R = 8.0
    rng = np.random.default_rng(3)
    for _ in range(25):
        a = np.r_[rng.uniform(-30, 30, 2), rng.uniform(-10, 10)]
        b = a + np.r_[rng.normal(size=2) * 3, rng.normal() * 2]
        prog = _program([b], start=a)
        a, b = prog.points[0], prog.points[1]  # as written, to 1e-6 mm
        h = holder_clearance(V, F, prog, R, climb=1e-3)
        want = max(k * (a[0] + R) - a[2], k * (b[0] + R) - b[2], 0.0)
        assert h.lower.max() <= want + 1e-9
        assert want <= h.needed + 1e-9
        assert h.needed - want <= 1e-3 + 1e-9  # the climb of a piece bounds the excess
        assert h.needed_lower == pytest.approx(want, abs=1e-3)


@pytest.mark.parametrize("k, ring", [(1.0, 1), (0.5, 0)])
def test_stepped_holder_needs_its_worst_ring(k, ring):
    # z = k x; a nut of radius 5 at the face and a body of radius 10 from 4 mm above it: at a
    # tip (x, 0, 0) the nut needs k (x + 5), the body k (x + 10) - 4, and the holder the larger
    V, F = _tilted_square(k)
    prog = _program([[0.0, 1.0, 0.0]], start=[0.0, 0.0, 0.0])
    h = holder_clearance(V, F, prog, 5.0, steps=[(10.0, 4.0)], climb=1e-6)
    want = (5.0 * k, 10.0 * k - 4.0)
    assert h.needed == pytest.approx(max(want), abs=1e-6) and h.needed_lower == pytest.approx(max(want), abs=1e-6)
    assert h.worst_part[0] == pytest.approx((5.0, 10.0)[ring], abs=1e-6)  # the rim of the ring that sets it
    assert h.summary()["steps"] == [[10.0, 4.0]] and h.worst_ring == ((5.0, 0.0), (10.0, 4.0))[ring]
    # steps given as a generator of numpy numbers: the same (review of session 33)
    g = holder_clearance(V, F, prog, 5.0, steps=((np.float32(10), np.int64(4)) for _ in range(1)), climb=1e-6)
    assert g.needed == pytest.approx(h.needed, abs=1e-6)
    # a stick-out between the two rings' needs is refused for the ring that needs more
    mid = (5.0 * k + 10.0 * k - 4.0) / 2
    assert not h.hits(mid)["clear"]
    hs = holder_clearance(V, F, prog, 5.0, steps=[(10.0, 4.0)], stick_out=mid)
    assert hs.hits(mid)["moves_may_hit"] == hs.hits(mid)["moves_hit"] == 2


def test_bad_holder_steps():
    V, F = _tilted_square(1.0)
    prog = _program([[0.0, 1.0, 0.0]], start=[0.0, 0.0, 0.0])
    for bad, word in [([(10.0,)], "a radius and a height"), ([(10.0, 0.0)], "height must be a positive"),
                      ([(-1.0, 3.0)], "radius must be a positive"), ([(10.0, 3.0), (12.0, 3.0)], "two holder steps"),
                      ((10, 4), "a radius and a height"), ([(5.0, 3.0)], "no wider than the holder below"),
                      ([(12.0, 8.0), (9.0, 9.0)], "no wider than the holder below")]:
        with pytest.raises(ConformillError, match=word):
            holder_clearance(V, F, prog, 5.0, steps=bad)


def test_dome_beside_the_tool_sets_the_need():
    # a dome of radius 30 over a disk of radius 20 (vertices on the sphere): a plunge to z = 0
    # at distance d from its axis meets it at horizontal distance d - R, where the sphere is
    # at sqrt(30^2 - (d - R)^2) - the facets lie below the sphere by at most their sagitta
    m = synthetic.sphere_cap(R=30.0, radius_xy=20.0, spacing=1.0)
    R = 10.0
    for d in (22.0, 25.0, 28.0):
        h = holder_clearance(m.V, m.F, _program([[d, 0.0, 0.0]], start=[d, 0.0, 50.0]), R)
        exact = np.sqrt(30.0**2 - (d - R) ** 2)
        assert exact - 0.05 <= h.needed <= exact + 1e-9
        assert h.needed - h.needed_lower <= 1e-9  # no XY travel: both bounds are exact
        # found on the holder's rim, on the side of the dome
        assert h.worst_line == 3 and np.hypot(h.worst_part[0] - d, h.worst_part[1]) == pytest.approx(R, abs=1e-9)
        assert np.hypot(*h.worst_part[:2]) == pytest.approx(d - R, abs=1e-3)
        assert h.worst_tip == (d, 0.0, 0.0)  # the plunge's lowest tip
    # far enough away, nothing of the part is above the tip: no stick-out needed
    far = holder_clearance(m.V, m.F, _program([[35.0, 0.0, 0.0]], start=[35.0, 0.0, 50.0]), 5.0)
    assert far.needed == 0.0 and far.worst_part is None


def test_level_triangle_over_the_whole_reach():
    # a level square at z = 10 (two triangles) wider than the reach, the tip under it: no edge
    # is in reach, the top is reached at the move's ends (review of session 33)
    V = np.array([[-50, -50, 10], [50, -50, 10], [50, 50, 10], [-50, 50, 10]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    h = holder_clearance(V, F, _program([[3.0, 1.0, 0.0]], start=[0.0, 0.0, 0.0]), 5.0)
    assert h.needed == pytest.approx(10.0, abs=1e-12) and h.needed_lower == pytest.approx(10.0, abs=1e-12)


def test_the_worst_move_is_named_not_one_left_at_the_floor():
    # plane z = x; line 3 climbs 10 below it (needs R + 10 = 15), line 6 plunges to 15 below it
    # (needs R + 15 = 20): the report names line 6, its lowest tip and a point within R of it
    V, F = _tilted_square(1.0)
    prog = read_gcode("G21 G90\nG0 X0 Y0 Z-10\nG1 X10 Y0 Z0 F500\nG0 Z100\nG0 X0 Y50\nG0 Z-15\n")
    h = holder_clearance(V, F, prog, 5.0)
    assert h.needed == pytest.approx(20.0, abs=1e-9) and h.worst_line == 6
    assert h.worst_tip == pytest.approx((0.0, 50.0, -15.0)) and h.worst_part[2] - h.worst_tip[2] == pytest.approx(20.0)
    assert np.hypot(h.worst_part[0] - h.worst_tip[0], h.worst_part[1] - h.worst_tip[1]) <= 5.0 + 1e-9
    assert 15.0 - 1e-9 <= h.upper[1] < h.needed  # line 3: bounded below the worst, not tied with it


def _bumpy():
    n = 12
    x = np.linspace(-20, 20, n)
    X, Y = np.meshgrid(x, x)
    Z = 6 * np.sin(X / 5) * np.cos(Y / 7) + np.where(X > 8, 15.0, 0.0)  # and a steep wall
    V = np.c_[X.ravel(), Y.ravel(), Z.ravel()]
    idx = np.arange(n * n).reshape(n, n)
    F = np.vstack([np.c_[idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()],
                   np.c_[idx[:-1, :-1].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()]])
    return V, F


def test_bounds_hold_against_sampled_points_of_the_part():
    # every sampled point of every triangle within R of a sampled tip position needs at most
    # the upper bound; the largest lower bound is a need some part point has (so it is at
    # least the sampled need, up to the sampling) and the two meet within the climb
    V, F = _bumpy()
    rng = np.random.default_rng(1)
    w = rng.dirichlet([1, 1, 1], size=300)
    P = np.vstack([np.einsum("kj,fjd->fkd", w, V[F]).reshape(-1, 3), V])
    R = 5.0
    for _ in range(12):
        a = np.r_[rng.uniform(-18, 18, 2), rng.uniform(-8, 10)]
        prog = _program([a + rng.normal(size=3) * 3], start=a)
        a, b = prog.points[0], prog.points[1]  # as written, to 1e-6 mm
        h = holder_clearance(V, F, prog, R, climb=1e-3)
        best = 0.0
        for s in np.linspace(0, 1, 41):
            t = a + s * (b - a)
            near = (P[:, 0] - t[0]) ** 2 + (P[:, 1] - t[1]) ** 2 <= R * R
            if near.any():
                best = max(best, float(P[near, 2].max() - t[2]))
        assert best <= h.needed + 1e-9
        assert h.needed - h.needed_lower <= 1e-3 + 1e-9
        assert h.needed - best <= 0.3  # the sampling's own shortfall on facets up to 4 mm


def test_hits_count_the_moves_and_name_the_first_line():
    V, F = _tilted_square(1.0)
    # level moves at tip z = 0 on z = x, R = 10: a move needs its largest x + 10
    prog = _program([[-20, 0, 0], [-20, 1, 0], [0, 1, 0], [20, 1, 0], [20, 2, 0]], start=[-20, -1, 0])
    h = holder_clearance(V, F, prog, 10.0, stick_out=15.0, climb=1e-6)
    assert np.allclose(h.upper, [0, 0, 0, 10, 30, 30], atol=1e-9)
    assert np.allclose(h.lower, h.upper, atol=1e-9)
    assert h.needed == pytest.approx(30.0, abs=1e-9) and h.worst_line == 6  # the first of the two
    r = h.hits(15.0)
    assert not r["clear"] and r["moves_may_hit"] == r["moves_hit"] == 2
    assert r["first_line"] == 6 and r["clearance"] == pytest.approx(-15.0, abs=1e-9)
    assert h.hits(30.5)["clear"] and h.hits(30.5)["first_line"] is None


def test_deterministic_and_bad_values():
    V, F = _bumpy()
    prog = _program([[0, 0, 0], [5, 5, 1], [-10, 3, 2]], start=[0, 0, 20])
    a = holder_clearance(V, F, prog, 6.0)
    b = holder_clearance(V, F, prog, 6.0)
    assert np.array_equal(a.upper, b.upper) and np.array_equal(a.lower, b.lower)
    for bad in (0.0, -1.0, float("nan"), float("inf"), True):
        with pytest.raises(ConformillError, match="holder radius"):
            holder_clearance(V, F, prog, bad)
    with pytest.raises(ConformillError, match="stick-out"):
        holder_clearance(V, F, prog, 6.0, stick_out=-2.0)


@pytest.fixture(scope="module")
def dome(tmp_path_factory):
    m = synthetic.sphere_cap(R=40.0, radius_xy=25.0, spacing=2.0)
    p = tmp_path_factory.mktemp("dome") / "dome.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(p)
    return p


def _plan(dome, tmp_path, *extra):
    return main(["plan", str(dome), "--pattern", "contour", "--tool-radius", "3", "--scallop", "0.5",
                 "-o", str(tmp_path / "p.nc"), "--report", str(tmp_path / "r.json"), *extra])


def test_plan_reports_the_stick_out_and_refuses_a_short_one(dome, tmp_path, capsys):
    assert _plan(dome, tmp_path, "--holder-radius", "10", "--html", str(tmp_path / "v.html")) == 0
    out = capsys.readouterr().out
    h = json.loads((tmp_path / "r.json").read_text())["holder"]
    assert "holder            R10 needs a stick-out of" in out
    panel = f"stick-out {h['needed_stick_out']:.3f} mm needed (line {h['worst_line']})"
    assert panel in (tmp_path / "v.html").read_text()
    need = h["needed_stick_out"]
    assert 0 < h["needed_lower"] <= need and need - h["needed_lower"] <= 0.01 + 1e-9
    # the program read back and checked independently gives the same figure
    again = holder_clearance(*_mesh(dome), read_gcode(tmp_path / "p.nc"), 10.0)
    assert again.needed == pytest.approx(need, abs=1e-4)  # the report rounds to 0.1 um
    assert "(param holder: radius 10)" in (tmp_path / "p.nc").read_text()
    long_enough = f"{need + 0.5:.3f}"
    assert _plan(dome, tmp_path, "--holder-radius", "10", "--stick-out", long_enough) == 0
    assert f"stick-out {float(long_enough):g}: checked to clear the part" in (tmp_path / "p.nc").read_text()
    assert json.loads((tmp_path / "r.json").read_text())["holder"]["clear"] is True
    assert _plan(dome, tmp_path, "--holder-radius", "10", "--holder-step", "30@2") == 0  # a stepped holder
    assert "(param holder: radius 10, radius 30 from 2 mm above its face)" in (tmp_path / "p.nc").read_text()
    stepped = json.loads((tmp_path / "r.json").read_text())["holder"]
    assert stepped["steps"] == [[30, 2]] and stepped["needed_stick_out"] >= need - 1e-3
    for f in ("p.nc", "r.json", "v.html"):
        (tmp_path / f).unlink()
    capsys.readouterr()
    assert _plan(dome, tmp_path, "--holder-radius", "10", "--stick-out", f"{need - 1:.3f}") == 3
    err = capsys.readouterr().err
    assert "holder R10 at stick-out" in err and "a stick-out of at least" in err and "nothing written" in err
    assert "Traceback" not in err
    assert not (tmp_path / "p.nc").exists() and not (tmp_path / "r.json").exists()


def _mesh(path):
    from conformill.mesh.io import read_mesh

    m = read_mesh(str(path))
    return m.V, m.F


@pytest.mark.parametrize("extra, word", [
    (["--stick-out", "30"], "need --holder-radius"),
    (["--holder-step", "20@10"], "need --holder-radius"),
    (["--holder-radius", "10", "--holder-step", "20"], "expected R@H"),
    (["--holder-radius", "10", "--holder-step", "20@0"], "height must be a positive"),
    (["--holder-radius", "10", "--stick-out", "-1"], "stick-out must be a positive number"),
    (["--holder-radius", "nan"], "holder radius must be a positive number"),
])
def test_plan_bad_holder_values_exit_2_without_output(dome, tmp_path, capsys, extra, word):
    assert _plan(dome, tmp_path, *extra) == 2
    err = capsys.readouterr().err
    assert word in err and "Traceback" not in err
    assert not (tmp_path / "p.nc").exists()


def test_a_holder_not_wider_than_the_tool_exits_3(dome, tmp_path, capsys):
    # two well-formed values that cannot be checked together, as a blend above the tool
    # radius: exit 3, from plan and from verify, nothing written
    assert _plan(dome, tmp_path, "--holder-radius", "2") == 3
    err = capsys.readouterr().err
    assert "must be larger than the tool radius" in err and "Traceback" not in err
    assert not (tmp_path / "p.nc").exists()
    assert _plan(dome, tmp_path) == 0
    args = ["verify", str(dome), str(tmp_path / "p.nc"), "-r", "3", "--samples", "5000", "--holder-radius", "3",
            "--report", str(tmp_path / "v.json")]
    assert main(args) == 3
    assert "must be larger than the tool radius" in capsys.readouterr().err
    assert not (tmp_path / "v.json").exists()
    # with a malformed value beside it, that one is reported (exit 2), from either command
    assert _plan(dome, tmp_path, "--holder-radius", "2", "--holder-step", "20@0") == 2
    assert main(args[:-2] + ["--report", str(tmp_path / "v.json"), "--stick-out", "-1"]) == 2
    assert main(args[:2] + [str(tmp_path / "missing.nc")] + args[3:]) == 2
    assert "does not exist" in capsys.readouterr().err
    # a program or a mesh that cannot be read is input too: named before the holder (exit 2)
    bad = tmp_path / "bad.nc"
    bad.write_text("G21 G90\nG1 X1 Y2 Z3 F100\nG1 X Q\nM2\n")
    assert main(args[:2] + [str(bad)] + args[3:]) == 2
    assert "line 3" in capsys.readouterr().err
    for text in ("", "G21 G90\nM2\n", "G21 G90\nG0 Z30\nG0 X0 Y0\nM2\n"):  # a program that cuts nothing
        bad.write_text(text)
        assert main(args[:2] + [str(bad)] + args[3:]) == 2
        assert "no feed moves" in capsys.readouterr().err
    broken = tmp_path / "broken.obj"
    broken.write_text("v 0 0 0\nf 1 2 3\n")
    assert main(args[:1] + [str(broken)] + args[2:]) == 2
    assert "broken.obj" in capsys.readouterr().err


def test_verify_holder_pass_and_fail(dome, tmp_path, capsys):
    assert _plan(dome, tmp_path, "--holder-radius", "10") == 0
    need = json.loads((tmp_path / "r.json").read_text())["holder"]["needed_stick_out"]
    args = ["verify", str(dome), str(tmp_path / "p.nc"), "-r", "3", "--samples", "5000", "--holder-radius", "10"]
    capsys.readouterr()
    assert main(args + ["--report", str(tmp_path / "v.json")]) == 0  # no stick-out: figures only
    out = capsys.readouterr().out
    assert f"holder R10: needs a stick-out of {need:.3f} mm" in out
    assert main(args + ["--stick-out", f"{need + 0.1:.3f}"]) == 0
    assert "clears the part by" in capsys.readouterr().out
    assert main(args + ["--stick-out", f"{need - 0.5:.3f}", "--report", str(tmp_path / "v.json")]) == 1
    out = capsys.readouterr().out
    assert "FAIL: holder R10 at stick-out" in out
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["pass"] is False and v["holder"]["moves_may_hit"] >= v["holder"]["moves_hit"] >= 1
    assert main(args[:-2] + ["--stick-out", "20"]) == 2  # a stick-out without the holder
    # a stepped holder: its body, wider than the nut, can only need more
    capsys.readouterr()
    assert main(args + ["--holder-step", "30@2", "--report", str(tmp_path / "v.json")]) == 0
    v = json.loads((tmp_path / "v.json").read_text())["holder"]
    assert v["steps"] == [[30, 2]] and v["needed_stick_out"] >= need - 1e-3
    assert "holder R10, R30 from 2 mm: needs a stick-out of" in capsys.readouterr().out
