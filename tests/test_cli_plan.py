"""``conformill plan`` end to end: every output, the independent check, rs274, bad values."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from conformill.cli.main import main
from conformill.mesh import synthetic
from test_gcode_rs274 import _assert_clean, needs_rs274, run_rs274


@pytest.fixture(scope="module")
def part(tmp_path_factory):
    m = synthetic.freeform_patch(spacing=2.0)
    p = tmp_path_factory.mktemp("part") / "patch.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(p)
    return p


@pytest.mark.parametrize("pattern", ["zigzag", "contour", "spiral"])
def test_plan_all_outputs_verified(part, tmp_path, pattern, capsys):
    out = tmp_path / "p.nc"
    rc = main(["plan", str(part), "--pattern", pattern, "--tool-radius", "4", "--scallop", "0.5",
               "--tolerance", "0.01", "-o", str(out), "--report", str(tmp_path / "r.json"),
               "--plot", str(tmp_path / "p.png"), "--html", str(tmp_path / "v.html"), "--verify",
               "--verify-samples", "60000"])
    text = capsys.readouterr().out
    assert rc == 0, text
    rep = json.loads((tmp_path / "r.json").read_text())
    v = rep["verify"]
    # the independent simulation of the written program meets the job (issue 3's criteria)
    assert v["pass"] and v["failures"] == []
    assert v["scallop"]["p999"] <= 1.05 * 0.5
    assert v["uncut_fraction"] == 0.0
    assert v["gouge_max"] <= 0.01
    assert v["rapid_min_clearance"] >= 0.5
    if pattern == "spiral":
        assert rep["program"]["passes"] == 1
    assert "verify" in rep["timings_s"] and rep["peak_rss_mb"] > 0
    html = (tmp_path / "v.html").read_text()
    assert "<canvas" in html or "three" in html.lower()
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert "PASS" in text


def test_verify_scallop_judges_against_the_given_height(part, tmp_path, capsys):
    # planned with a margin (H = 0.3), judged against the specified 0.5: the same program and
    # simulation, the thresholds and the ratios taken against 0.5
    out, rep = tmp_path / "m.nc", tmp_path / "m.json"
    rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
               "--report", str(rep), "--verify", "--verify-samples", "60000", "--verify-scallop", "0.5"])
    text = capsys.readouterr().out
    v = json.loads(rep.read_text())["verify"]
    assert rc == 0 and v["pass"] and v["judged_h"] == 0.5
    assert v["scallop_over_h"]["p999"] == pytest.approx(v["scallop"]["p999"] / 0.5, abs=2e-6)  # the report keeps 6 decimals
    q = v["reachable"]
    assert q["scallop_over_h"]["p999"] == pytest.approx(q["scallop"]["p999"] / 0.5, abs=2e-6)
    assert "(H = 0.5)" in text and "PASS" in text
    # judged against a height far below the planned one: the check fails (exit 1), files kept;
    # --verify-scallop alone asks for the check (it implies --verify)
    rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5", "-o", str(out),
               "--report", str(rep), "--verify-samples", "60000", "--verify-scallop", "0.05", "-q"])
    v = json.loads(rep.read_text())["verify"]
    assert rc == 1 and not v["pass"] and v["judged_h"] == 0.05 and out.exists()
    assert v["reachable"]["scallop"]["p999"] > 1.05 * 0.05


def test_replan_plans_again_until_the_judged_height_is_met(part, tmp_path, capsys):
    # planned for 0.5 and judged at 0.4: the first program leaves about 0.5 (it fails), the
    # next is planned for less, by the measured excess, and passes
    out, rep = tmp_path / "r.nc", tmp_path / "r.json"
    rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5", "-o", str(out),
               "--report", str(rep), "--verify-samples", "60000", "--verify-scallop", "0.4", "--replan", "3",
               "--plot", str(tmp_path / "r.png"), "--html", str(tmp_path / "r.html"), "--holder-radius", "6"])
    text = capsys.readouterr().out
    r = json.loads(rep.read_text())
    rounds = r["replan"]
    assert rc == 0 and r["verify"]["pass"] and r["verify"]["judged_h"] == 0.4
    assert len(rounds) >= 2 and not rounds[0]["pass"] and rounds[0]["reachable_p999_over_h"] > 1.05
    assert all(not x["pass"] for x in rounds[:-1]) and rounds[-1]["pass"]
    h = [x["scallop"] for x in rounds]
    assert h[0] == 0.5 and all(b < a for a, b in zip(h, h[1:]))
    # each next scallop is the rule's: 0.97 x 1.05 H / p99.9 of the last, within [0.5, 0.95]
    for a, b, x in zip(h, h[1:], rounds):
        assert b == pytest.approx(a * min(max(0.97 * 1.05 / x["reachable_p999_over_h"], 0.5), 0.95), rel=1e-3)
    # the program written and the report are the last plan's
    assert r["job"]["scallop"] == h[-1] and r["verify"]["reachable"]["scallop_over_h"]["p999"] <= 1.05
    assert "replanned" in out.read_text() and "replan" in text
    # the picture, the viewer and the holder check are of the last plan's program
    assert (tmp_path / "r.png").stat().st_size > 10_000 and "PASS" in (tmp_path / "r.html").read_text()
    assert r["holder"]["worst_line"] <= r["program"]["n_lines"]


def test_verify_on_a_bowl_narrower_than_the_ball_judges_nothing(tmp_path, capsys):
    # a 30 mm ball on a 20 mm bowl: no sample lies farther than r from the boundary. The
    # check fails with "nothing judged" (exit 1, files kept), without testing the reach of
    # samples it does not judge (that took 33 s at 60k samples on a 40 mm bowl, minutes at
    # the default 400k)
    m = synthetic.sphere_cap(R=25.0, radius_xy=10.0, spacing=1.0, concave=True)
    bowl = tmp_path / "bowl.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(bowl)
    out, rep = tmp_path / "b.nc", tmp_path / "b.json"
    rc = main(["plan", str(bowl), "--tool-radius", "30", "--scallop", "0.1", "--verify", "-o", str(out),
               "--report", str(rep)])
    v = json.loads(rep.read_text())["verify"]
    assert rc == 1 and out.exists() and not v["pass"] and v["interior_samples"] == 0
    assert v["failures"] == ["nothing judged: the part has no interior sample (one farther than the tool radius, "
                             "30 mm, from its boundary)"]
    said = capsys.readouterr().out
    assert "FAIL (nothing judged" in said and "reachable (no interior sample)" in said


def test_replan_stops_after_n_plans_and_fails(part, tmp_path):
    # judged far below what a plan can reach in one round: each round at most halves the
    # scallop; after --replan 1 the check still fails (exit 1, files kept, both plans listed)
    out, rep = tmp_path / "s.nc", tmp_path / "s.json"
    rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5", "-o", str(out),
               "--report", str(rep), "--verify-samples", "60000", "--verify-scallop", "0.05", "--replan", "1", "-q"])
    r = json.loads(rep.read_text())
    assert rc == 1 and out.exists() and not r["verify"]["pass"]
    assert [x["scallop"] for x in r["replan"]] == [0.5, 0.25]


def test_replan_warns_once(tmp_path, caplog):
    # a V groove tighter than the ball: every plan warns of it; the second plan's repeat is not shown
    m = synthetic.v_groove()
    part = tmp_path / "groove.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(part)
    rep = tmp_path / "g.json"
    with caplog.at_level("WARNING"):
        rc = main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                   "-o", str(tmp_path / "g.nc"), "--report", str(rep), "--verify-samples", "60000",
                   "--verify-scallop", "0.4", "--replan", "2"])
    assert rc == 0 and len(json.loads(rep.read_text())["replan"]) == 2
    said = [r.getMessage() for r in caplog.records if "radius at or below the tool radius" in r.getMessage()]
    assert len(said) == 1


def _figures(p999_over_h, uncut=0.0, gouge=0.001, h=0.01):
    p = p999_over_h * h
    return {"pass": p <= 1.05 * h and uncut == 0 and gouge <= 0.01, "gouge_max": gouge,
            "reachable": {"scallop": {"p999": p}, "uncut_fraction": uncut}}


def test_replan_scallop_rule():
    from conformill.cli.plan import replan_scallop

    # a scallop-only failure: smaller by the measured excess, with a 0.97 margin
    assert replan_scallop(_figures(1.19), 0.01, 0.01, 0.01) == pytest.approx(0.01 * 0.97 * 1.05 / 1.19, rel=1e-3)
    # at least 5 % smaller, at most halved
    assert replan_scallop(_figures(1.06), 0.01, 0.01, 0.01) == pytest.approx(0.0095)
    assert replan_scallop(_figures(40.0), 0.01, 0.01, 0.01) == pytest.approx(0.005)
    # judged at H but planned for less: the step is taken from what was planned
    assert replan_scallop(_figures(1.19), 0.008, 0.01, 0.01) == pytest.approx(0.008 * 0.97 * 1.05 / 1.19, rel=1e-3)
    # passed, or failed on what a smaller scallop does not mend: no more plans
    assert replan_scallop(_figures(1.0), 0.01, 0.01, 0.01) is None
    assert replan_scallop(_figures(1.19, uncut=1e-4), 0.01, 0.01, 0.01) is None
    assert replan_scallop(_figures(1.19, gouge=0.02), 0.01, 0.01, 0.01) is None
    assert replan_scallop(_figures(float("nan")), 0.01, 0.01, 0.01) is None


def test_plan_is_deterministic(part, tmp_path):
    a, b = tmp_path / "a.nc", tmp_path / "b.nc"
    for o in (a, b):
        assert main(["plan", str(part), "--pattern", "zigzag", "--tool-radius", "4", "--scallop", "1",
                     "-o", str(o), "-q"]) == 0
    assert a.read_bytes() == b.read_bytes()


@needs_rs274
@pytest.mark.parametrize("pattern", ["zigzag", "contour", "spiral"])
def test_plan_programs_run_in_linuxcnc(part, tmp_path, pattern):
    out = tmp_path / "p.nc"
    assert main(["plan", str(part), "--pattern", pattern, "--tool-radius", "4", "--scallop", "0.3",
                 "-o", str(out), "-q"]) == 0
    rc, msg, canon = run_rs274(None, tmp_path, name="p")
    _assert_clean(rc, msg)
    assert canon.count("STRAIGHT_FEED") > 100


# exit 2: a malformed value (not a number, not finite, out of its own range, a bad word);
# exit 3: well-formed values that cannot be met (errors.py lists which is which)
@pytest.mark.parametrize("args, code, word", [
    (["--tool-radius", "4", "--scallop", "4"], 3, "scallop"),
    (["--tool-radius", "4", "--scallop", "5"], 3, "scallop"),
    (["--tool-radius", "0", "--scallop", "0.1"], 2, "radius"),
    (["--tool-radius", "-1", "--scallop", "0.1"], 2, "radius"),
    (["--tool-radius", "4", "--scallop", "0.1", "--tolerance", "0"], 2, "tolerance"),
    (["--tool-radius", "4", "--scallop", "-0.1"], 2, "scallop"),
    (["--tool-radius", "4", "--scallop", "0.1", "--verify", "--verify-samples", "0"], 2, "samples"),
    (["--tool-radius", "4", "--scallop", "0.1", "--verify", "--verify-scallop", "0"], 2, "verify-scallop"),
    (["--tool-radius", "4", "--scallop", "0.1", "--verify", "--verify-scallop", "nan"], 2, "verify-scallop"),
    (["--tool-radius", "4", "--scallop", "0.1", "--replan", "-1"], 2, "replan"),
    (["--tool-radius", "4", "--scallop", "0.1", "--pencil", "--pencil-density", "-5"], 2, "pencil-density"),
    (["--tool-radius", "4", "--scallop", "0.1", "--pencil", "--pencil-density", "nan"], 2, "pencil-density"),
    (["--tool-radius", "4", "--scallop", "0.1", "--pencil", "--pencil-search", "folds", "--pencil-left", "-1"], 2,
     "pencil-left"),
    (["--tool-radius", "4", "--scallop", "0.1", "--pencil", "--pencil-left", "0.5"], 2, "pencil-left"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "-0.01"], 2, "blend"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "nan"], 2, "blend"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "1e-8"], 2, "blend"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "5"], 3, "blend"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "1e300"], 2, "blend"),
    (["--tool-radius", "4", "--scallop", "0.1", "--tool-number", "0"], 2, "tool number"),
    # a millimetre part read as metres: refused at once, not planned until memory runs out
    (["--tool-radius", "4", "--scallop", "0.01", "--scale", "10000"], 3, "--scale"),
    (["--tool-radius", "4", "--scallop", "0.1", "--feed", "1e-9"], 2, "f0"),  # rs274: "g1 with zero feed rate"
    (["--tool-radius", "4", "--scallop", "0.1", "--feed", "0.001"], 2, "plunge-feed"),  # feed / 3 is written F0
    (["--tool-radius", "4", "--scallop", "0.1", "--spindle", "0.00001"], 2, "spindle"),  # it was written M3 S0.0
    (["--tool-radius", "4", "--scallop", "0.1", "--spindle", "nan"], 2, "spindle"),
    (["--tool-radius", "4", "--scallop", "0.1", "--safe-z", "nan"], 2, "safe-z"),
    (["--tool-radius", "4", "--scallop", "0.1", "--tolerance", "inf"], 2, "tolerance"),
    (["--tool-radius", "4", "--scallop", "0.1", "--plunge-feed", "-5"], 2, "plunge-feed"),
    (["--tool-radius", "4", "--scallop", "0.1", "--settle", "nan"], 2, "settle"),
    (["--tool-radius", "4", "--scallop", "0.1", "--max-step", "0"], 2, "max-step"),
    (["--tool-radius", "4", "--scallop", "0.1", "--stock", "inf"], 2, "stock"),
    (["--tool-radius", "4", "--scallop", "0.1", "--threads", "0"], 2, "threads"),
    (["--tool-radius", "4", "--scallop", "0.1", "--corners", "0,1,2,3"], 2, "--pattern zigzag"),
    # a ball far larger than the part: a mistake of units, refused at once with its value
    # (it was planned for minutes, or failed with "not within the ball's reach")
    (["--tool-radius", "1e300", "--scallop", "0.01"], 2, "tool radius 1e+300 mm is more than 100 times"),
    (["--tool-radius", "1e9", "--scallop", "0.01"], 2, "--scale"),
    (["--tool-radius", "4", "--scallop", "0.1", "--stock", "1e300"], 2, "plus the stock 1e+300 mm is more than 100"),
    # below the program's 4 decimals (1e-300 ended in a ZeroDivisionError, or a linspace
    # beyond memory, with a traceback)
    (["--tool-radius", "1e-300", "--scallop", "1e-301"], 2, "tool radius 1e-300 mm is below 0.0001 mm"),
    (["--tool-radius", "4", "--scallop", "0.00005"], 2, "scallop height 5e-05 mm is below 0.0001 mm"),
    (["--tool-radius", "4", "--scallop", "0.1", "--tolerance", "1e-300"], 2, "chord tolerance 1e-300 mm is below"),
    (["--tool-radius", "4", "--scallop", "0.1", "--max-step", "1e-300"], 2, "max-step 1e-300 mm is below"),
    # a safe height the writer's 1e-4 mm ticks cannot count (it was refused as "above the clearance")
    (["--tool-radius", "4", "--scallop", "0.1", "--safe-z", "1e15"], 2, "safe-z must be a finite height within"),
    # well formed, but not met on this part
    (["--tool-radius", "4", "--scallop", "0.1", "--safe-z", "1"], 3, "safe-z"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "4.5"], 3, "larger than the tool radius"),
])
def test_bad_values_exit_without_output(part, tmp_path, capsys, args, code, word):
    out = tmp_path / "p.nc"
    rc = main(["plan", str(part), "-o", str(out), "--report", str(tmp_path / "r.json"), *args])
    err = capsys.readouterr().err
    assert rc == code
    assert word in err.lower() and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "r.json").exists()


# a malformed value and a combination that cannot be met in one command: the malformed value
# is named (exit 2), whichever comes first on the line and whichever check owns it
@pytest.mark.parametrize("args, word", [
    (["--tool-radius", "4", "--scallop", "5", "--stock", "inf"], "stock"),
    (["--tool-radius", "4", "--scallop", "5", "--feed", "1e-9"], "f0"),
    (["--tool-radius", "4", "--scallop", "5", "--verify", "--verify-samples", "0"], "samples"),
    (["--tool-radius", "4", "--scallop", "5", "--replan", "-1"], "replan"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "5", "--spindle", "nan"], "spindle"),
    (["--tool-radius", "4", "--scallop", "0.1", "--blend", "5", "--holder-radius", "10", "--stick-out", "-1"],
     "stick-out"),
    (["--tool-radius", "4", "--scallop", "0.1", "--holder-radius", "2", "--verify", "--verify-scallop", "0"],
     "verify-scallop"),
    # the ball's size against the part's (a mistake of units) is read from the mesh
    (["--tool-radius", "1e9", "--scallop", "1e10"], "--scale"),
    # corners that name no four vertices of the mesh (their place on the boundary needs the map)
    (["--pattern", "zigzag", "--tool-radius", "4", "--scallop", "5", "--corners", "1,1,2,3"], "distinct"),
    (["--pattern", "zigzag", "--tool-radius", "4", "--scallop", "0.1", "--corners=-1,1,2,3", "--blend", "5"],
     "not in the mesh"),
    (["--pattern", "zigzag", "--tool-radius", "4", "--scallop", "0.1", "--corners", "0,1,2,999999",
      "--holder-radius", "3"], "not in the mesh"),
])
def test_a_malformed_value_wins_over_one_that_cannot_be_met(part, tmp_path, capsys, args, word):
    out = tmp_path / "p.nc"
    rc = main(["plan", str(part), "-o", str(out), "--report", str(tmp_path / "r.json"), *args])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert word in err.lower() and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "r.json").exists()


def test_a_bad_mesh_wins_over_values_that_cannot_be_met(part, tmp_path, capsys):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\nf 1 2 4\nf 1 2 5\n")
    out = tmp_path / "p.nc"
    for extra in (["--scallop", "5"], ["--scallop", "0.1", "--blend", "5"], ["--scallop", "0.1", "--holder-radius", "2"]):
        rc = main(["plan", str(bad), "--tool-radius", "4", "-o", str(out), *extra])
        err = capsys.readouterr().err
        assert rc == 2 and "Traceback" not in err and not out.exists(), (extra, err)
        assert "bad.obj" in err, err
    # the same values on a good mesh: exit 3, each named
    for extra, word in ((["--scallop", "5"], "smaller than the tool radius"),
                        (["--scallop", "0.1", "--blend", "5"], "larger than the tool radius"),
                        (["--scallop", "0.1", "--holder-radius", "2"], "must be larger than the tool radius")):
        assert main(["plan", str(part), "--tool-radius", "4", "-o", str(out), *extra]) == 3
        assert word in capsys.readouterr().err and not out.exists()


def test_a_refusal_after_a_read_that_warned_is_one_line(part, tmp_path):
    # the read's warnings wait for the checks: printed when they pass, dropped on a refusal
    m = trimesh.load(part, process=False)
    loose = tmp_path / "loose.obj"
    V = np.vstack([m.vertices, [[500.0, 500.0, 500.0]]])
    loose.write_text("".join(f"v {float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in V)
                     + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in m.faces))
    out = tmp_path / "p.nc"

    def run(*extra):
        return subprocess.run([sys.executable, "-m", "conformill", "plan", str(loose), "--tool-radius", "4",
                               "-o", str(out), "-q", *extra], capture_output=True, text=True, timeout=600)

    for extra in (["--scallop", "5"], ["--scallop", "0.3", "--blend", "5"], ["--scallop", "0.3", "--holder-radius", "3"]):
        p = run(*extra)
        assert p.returncode == 3 and len(p.stderr.strip().splitlines()) == 1, (extra, p.stderr)
        assert "larger than the tool radius" in p.stderr or "smaller than the tool radius" in p.stderr
        assert not out.exists()
    p = run("--scallop", "0.3")
    assert p.returncode == 0 and "dropped 1 unreferenced vertices" in p.stderr and out.exists()


def test_corners_starting_with_a_dash_and_ids_not_in_the_mesh(part, tmp_path, capsys):
    # argparse reads "-1,1,2,3" as an option: the error says how to give it
    out = tmp_path / "c.nc"
    base = ["plan", str(part), "--pattern", "zigzag", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out)]
    assert main(base + ["--corners", "-1,1,2,3"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == ["conformill plan: error: argument --corners: expected one argument "
                                "('-1,1,2,3' starts with '-' and is read as an option: write "
                                "--corners=-1,1,2,3) (see conformill plan --help)"]
    n = len(trimesh.load(part, process=False).vertices)
    for ids, bad in (("-1,1,2,3", -1), (f"0,1,2,{n}", n)):
        assert main(base + [f"--corners={ids}"]) == 2
        err = capsys.readouterr().err
        assert err == f"conformill plan: error: corner vertex id {bad} is not in the mesh (ids 0..{n - 1})\n"
    assert not out.exists()


def test_a_value_starting_with_a_dash_gets_the_hint_on_any_option(part, tmp_path, capsys):
    # "-1e-3" is no plain negative number to argparse: the option is left without its value
    assert main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.3", "--stock", "-1e-3",
                 "-o", str(tmp_path / "s.nc")]) == 2
    assert "write --stock=-1e-3)" in capsys.readouterr().err
    assert main(["verify", str(part), "p.nc", "-r", "-1e-3"]) == 2
    assert "write -r=-1e-3)" in capsys.readouterr().err
    assert main(["plan", str(part), "--tool-radius", "4", "--scallop"]) == 2  # no value at all: no hint
    assert "expected one argument (see conformill plan --help)\n" in capsys.readouterr().err
    # a value missing before the next option: no hint to write it as the value
    assert main(["plan", str(part), "--tool-radius", "4", "--feed", "--scallop", "0.3", "-o", str(tmp_path / "f.nc")]) == 2
    assert capsys.readouterr().err == ("conformill plan: error: argument --feed: expected one argument "
                                       "(see conformill plan --help)\n")
    # an unknown option is said by the command's own parser, on one line
    for cmd, rest in (("plan", ["--tool-radius", "4", "--scallop", "0.3", "-o", str(tmp_path / "b.nc")]),
                      ("verify", ["p.nc", "-r", "4"]), ("param", ["-o", str(tmp_path / "b.obj")])):
        assert main([cmd, str(part), *rest, "--bogus"]) == 2
        assert capsys.readouterr().err == (f"conformill {cmd}: error: unrecognized arguments: --bogus "
                                           f"(see conformill {cmd} --help)\n")
    assert not (tmp_path / "s.nc").exists()


def test_missing_output_folder(part, tmp_path, capsys):
    rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.1", "-o", str(tmp_path / "no" / "p.nc")])
    assert rc == 2 and "does not exist" in capsys.readouterr().err


def test_a_tiny_scallop_is_refused_by_its_memory(part, tmp_path, capsys, monkeypatch):
    # the samples of a 0.0004 mm scallop would not fit in a machine of 50 MB (pipeline._check_size)
    from conformill import pipeline

    monkeypatch.setattr(pipeline, "_physical_memory", lambda: 50e6)
    out = tmp_path / "t.nc"
    rc = main(["plan", str(part), "--tool-radius", "2", "--scallop", "0.0004", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 3 and "GB to plan" in err and "scallop" in err and "Traceback" not in err and not out.exists()


def test_outputs_that_collide_or_are_folders_are_refused_before_any_work(part, tmp_path, capsys):
    before = part.read_bytes()
    (tmp_path / "d").mkdir()
    base = ["plan", str(part), "--tool-radius", "4", "--scallop", "0.3"]
    for extra, word in ((["-o", str(tmp_path / "d")], "it is a folder"),
                        (["-o", str(tmp_path / "x"), "--report", str(tmp_path / "x")], "given for two outputs"),
                        (["-o", str(tmp_path / "y.nc"), "--plot", str(tmp_path / "y.nc")], "given for two outputs"),
                        (["-o", str(part)], "it is the input")):
        rc = main(base + extra)
        err = capsys.readouterr().err
        assert rc == 2 and word in err and "Traceback" not in err, err
    assert part.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["d"]


def test_spacing_option_reaches_the_report(part, tmp_path, capsys):
    for spacing in ("paper", "adaptive"):
        out, rep = tmp_path / f"{spacing}.nc", tmp_path / f"{spacing}.json"
        assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                     "--spacing", spacing, "-o", str(out), "--report", str(rep), "-q"]) == 0
        assert json.loads(rep.read_text())["job"]["spacing"] == spacing
    _refused_choice(part, tmp_path, capsys, "--spacing", "dense")


def _refused_choice(part, tmp_path, capsys, flag, value):
    """An unknown choice of ``flag``: exit 2, the flag named, no traceback, no output file."""
    capsys.readouterr()
    bad = tmp_path / "bad.nc"
    try:
        rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.5", flag, value, "-o", str(bad)])
    except SystemExit as exc:  # argparse's own exit for an unknown choice
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2 and flag.lstrip("-") in err and "Traceback" not in err
    assert not bad.exists()


def test_fit_option_reaches_the_report_and_the_header(part, tmp_path, capsys):
    out, rep = tmp_path / "split.nc", tmp_path / "split.json"
    assert main(["plan", str(part), "--pattern", "spiral", "--tool-radius", "4", "--scallop", "0.5",
                 "--fit", "split", "-o", str(out), "--report", str(rep), "-q"]) == 0
    assert json.loads(rep.read_text())["job"]["fit"] == "split"
    assert "fit: split" in out.read_text()
    _refused_choice(part, tmp_path, capsys, "--fit", "coarse")


def test_pencil_option_reaches_the_report_the_header_and_the_summary(part, tmp_path, capsys):
    out, rep = tmp_path / "pencil.nc", tmp_path / "pencil.json"
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                 "--pencil", "--pencil-density", "2", "-o", str(out), "--report", str(rep)]) == 0
    r = json.loads(rep.read_text())
    assert r["job"]["pencil"] is True and r["job"]["pencil_density"] == 2.0 and r["job"]["pencil_search"] == "samples"
    assert r["pencil"]["samples"] > 0 and "pencil" in r["timings_s"]
    assert "(param pencil: samples per mm2 2)" in out.read_text()
    assert "samples)" in capsys.readouterr().out
    # the fold search on request
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                 "--pencil", "--pencil-search", "folds", "--pencil-density", "2", "-o", str(out),
                 "--report", str(rep)]) == 0
    r = json.loads(rep.read_text())
    assert r["job"]["pencil_search"] == "folds" and r["pencil"]["grid_points"] > 0
    assert "(param pencil: folds, grid points per mm2 2)" in out.read_text()
    assert "grid points)" in capsys.readouterr().out
    # and only where the pattern left material
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                 "--pencil", "--pencil-search", "folds", "--pencil-density", "2", "--pencil-left", "0.5",
                 "-o", str(out), "--report", str(rep)]) == 0
    r = json.loads(rep.read_text())
    assert r["job"]["pencil_left"] == 0.5 and r["pencil"]["left_h"] == 0.5
    assert 0 <= r["pencil"]["fold_points_cut"] <= r["pencil"]["centres"] and "pencil_left" in r["timings_s"]
    assert 0 <= r["pencil"]["steep_centres_cut"] <= r["pencil"]["steep_centres"]
    assert "(param pencil: folds, grid points per mm2 2, where the pattern leaves above 0.5 H)" in out.read_text()
    assert (f"{r['pencil']['fold_points_cut']} and {r['pencil']['steep_centres_cut']} of them where the pattern "
            "left above 0.5 H") in capsys.readouterr().out
    _refused_choice(part, tmp_path, capsys, "--pencil-search", "grid")
    # without the option the header says nothing of it (the default program is unchanged)
    plain = tmp_path / "plain.nc"
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.5",
                 "-o", str(plain), "-q"]) == 0
    assert "pencil" not in plain.read_text()


def test_blend_path_control(part, tmp_path, capsys):
    """The program asks the controller for its path tolerance: G64 P min(e, h)/4 Q0 by
    default, the given P, G61 for 0, nothing with off; the moves are the same bytes."""
    def run(*extra, h="0.3", e="0.01"):
        out = tmp_path / "p.nc"
        rc = main(["plan", str(part), "--pattern", "zigzag", "--tool-radius", "4", "--scallop", h, "--tolerance", e,
                   "-o", str(out), "--report", str(tmp_path / "r.json"), *extra])
        text = capsys.readouterr().out
        assert rc == 0, text
        return out.read_text().splitlines(), json.loads((tmp_path / "r.json").read_text()), text

    def moves(lines):
        return [ln for ln in lines if ln.startswith(("G0", "G1"))]

    base, rep, summary = run()
    assert "G64 P0.0025 Q0" in base and rep["job"]["blend"] == 0.0025  # e/4 < h/4
    assert base[base.index("G40 G49 G80") + 1] == "G64 P0.0025 Q0"
    assert "(param path control: G64 P0.0025 Q0: corners rounded by at most 0.0025 mm" in "\n".join(base)
    assert "lines, G64 P0.0025 Q0" in summary
    lines, rep, _ = run(h="0.008", e="0.01")  # h/4 < e/4
    assert "G64 P0.002 Q0" in lines and rep["job"]["blend"] == 0.002
    lines, rep, summary = run("--blend", "0.02")
    assert "G64 P0.02 Q0" in lines and rep["job"]["blend"] == 0.02 and moves(lines) == moves(base)
    lines, rep, summary = run("--blend", "0")
    assert "G61" in lines and not any(ln.startswith("G64") for ln in lines) and "lines, G61" in summary
    assert moves(lines) == moves(base)
    lines, rep, summary = run("--blend", "off")
    assert not any(ln.startswith(("G64", "G61")) for ln in lines) and rep["job"]["blend"] == "off"
    assert "no path control" in summary and "none written" in "\n".join(lines) and moves(lines) == moves(base)
    assert len(lines) == len(base) - 1


def test_blend_that_is_not_a_number(part, tmp_path, capsys):
    out = tmp_path / "p.nc"
    rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.1", "-o", str(out), "--blend", "fine"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err and not out.exists()
    assert err.splitlines() == ["conformill plan: error: argument --blend: expected a number (mm) or off, "
                                "got 'fine' (see conformill plan --help)"]


def test_job_blend_is_checked():
    from conformill.errors import PlanningError
    from conformill.pipeline import Job, check_job

    assert Job(scallop=0.01, tolerance=0.01).blend_tolerance == 0.0025
    assert Job(scallop=0.1, tolerance=0.04).blend_tolerance == 0.01
    assert Job(scallop=0.1, tolerance=0.002).blend_tolerance == 0.0005
    assert Job(blend="off").blend_tolerance is None and Job(blend=0).blend_tolerance == 0.0
    assert str(Job(blend=-0.0).blend_tolerance) == "0.0"
    # a default below what can be written is exact path, not a refusal of an option never given
    # (and such a tolerance is refused anyway, below the program's 4 decimals)
    tiny = Job(scallop=0.1, tolerance=2e-6)
    assert tiny.blend_tolerance == 0.0
    with pytest.raises(PlanningError, match="chord tolerance 2e-06 mm is below 0.0001 mm") as bad:
        check_job(tiny)
    assert bad.value.exit_code == 2
    check_job(Job(tool_radius=4.0, blend=4.0))
    for bad in ("on", "OFF", True, -1.0, float("inf"), float("nan"), 1e-9, 4.01, 1e300):
        with pytest.raises(PlanningError, match="blend"):
            check_job(Job(blend=bad))


def test_tool_number_option(part, tmp_path, capsys):
    out, rep = tmp_path / "t.nc", tmp_path / "t.json"
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
                 "--report", str(rep), "--tool-number", "12", "-q"]) == 0
    lines = out.read_text().splitlines()
    assert lines[lines.index("G64 P0.0025 Q0") + 1:][:2] == ["T12 M6", "G43 H12"]
    assert "(param tool length: T12 M6 G43 H12: from the tool table)" in lines
    assert json.loads(rep.read_text())["job"]["tool_number"] == 12
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
                 "-q"]) == 0
    lines = out.read_text().splitlines()
    assert not any(ln.startswith(("T", "G43")) for ln in lines)
    assert "(param tool length: G49: the work offset holds it [tool tip touched off])" in lines
    rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.3", "-o", str(tmp_path / "u.nc"),
               "--tool-number", "one"])
    assert rc == 2 and "--tool-number" in capsys.readouterr().err and not (tmp_path / "u.nc").exists()


def test_spindle_option_reaches_the_header_the_report_and_the_summary(part, tmp_path, capsys):
    out, rep = tmp_path / "s.nc", tmp_path / "s.json"
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
                 "--report", str(rep), "--spindle", "12000"]) == 0
    lines = out.read_text().splitlines()
    assert "M3 S12000" in lines and "(param spindle: M3 S12000: started before the first move)" in lines
    assert json.loads(rep.read_text())["job"]["spindle"] == 12000
    assert "spindle not started" not in capsys.readouterr().out
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
                 "--report", str(rep)]) == 0
    lines = out.read_text().splitlines()
    assert not [ln for ln in lines if ln.split()[0] in ("M3", "M4")]  # (M30 ends it)
    assert ("(param spindle: not started by this program [no --spindle]: start it by hand before running it)"
            in lines)
    assert json.loads(rep.read_text())["job"]["spindle"] is None
    assert "spindle not started by the program (--spindle RPM)" in capsys.readouterr().out


def test_coolant_option(part, tmp_path, capsys):
    out, rep = tmp_path / "c.nc", tmp_path / "c.json"
    assert main(["plan", str(part), "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out),
                 "--report", str(rep), "--coolant", "flood", "--spindle", "12000", "-q"]) == 0
    lines = out.read_text().splitlines()
    assert lines[lines.index("M3 S12000") + 1] == "M8" and lines[-3:] == ["M9", "M5", "M30"]
    assert "(param coolant: flood)" in lines and json.loads(rep.read_text())["job"]["coolant"] == "flood"
    rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.3", "-o", str(tmp_path / "u.nc"),
               "--coolant", "air"])
    assert rc == 2 and "--coolant" in capsys.readouterr().err and not (tmp_path / "u.nc").exists()
    from conformill.errors import PlanningError
    from conformill.pipeline import Job, check_job

    with pytest.raises(PlanningError, match="coolant"):
        check_job(Job(coolant="air"))
