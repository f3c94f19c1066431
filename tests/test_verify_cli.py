"""`conformill verify` end to end: table, report, plot, exit codes."""

import json

import numpy as np
import pytest

from conformill.cli.main import main
from conformill.mesh.synthetic import plane


@pytest.fixture()
def files(tmp_path):
    import trimesh

    m = plane(size=30.0, spacing=2.0)
    mesh = tmp_path / "plane.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(mesh)

    def program(name, w=1.0, dip=None):
        lines = ["(test raster)", "G21 G90", "G0 Z10"]
        for i, x in enumerate(np.arange(-20, 20.001, w)):
            z = -dip if dip is not None and i == 20 else 0.0
            lines += [f"G0 X{x:.4f} Y-20 Z10", f"G1 Z{z:.4f} F500", "G1 Y20", "G0 Z10"]
        p = tmp_path / name
        p.write_text("\n".join(lines) + "\n")
        return p

    return mesh, program


def test_pass_report_and_plot(files, tmp_path, capsys):
    mesh, program = files
    nc = program("good.nc")
    rep, png = tmp_path / "r.json", tmp_path / "r.png"
    rc = main(["verify", str(mesh), str(nc), "--tool-radius", "3", "--scallop", "0.05", "--gouge", "0.01",
               "--samples", "20000", "--report", str(rep), "--plot", str(png)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "scallop p99.9" in out and "PASS" in out
    r = json.loads(rep.read_text())
    assert set(r["scallop"]) == {"p50", "p99", "p999", "max"}
    assert r["scallop"]["max"] == pytest.approx(3 - np.sqrt(9 - 0.25), abs=2e-4)
    assert r["pass"] is True and r["tool_radius"] == 3 and r["samples"] == 20000
    assert r["thresholds"] == {"scallop": 0.05, "gouge": 0.01, "reach_depth": 0.05}  # the depth defaults to H
    assert r["uncut_fraction"] == 0 and r["gouge_max"] < 1e-6
    assert r["rapid_min_clearance"] > 0.5
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_exit_1_when_limits_exceeded(files, capsys):
    mesh, program = files
    nc = program("dip.nc", dip=0.05)
    assert main(["verify", str(mesh), str(nc), "-r", "3", "--gouge", "0.01", "--samples", "20000", "-q"]) == 1
    assert main(["verify", str(mesh), str(nc), "-r", "3", "--samples", "20000", "-q"]) == 0  # no limit given
    coarse = program("coarse.nc", w=2.0)
    assert main(["verify", str(mesh), str(coarse), "-r", "3", "--scallop", "0.05", "--samples", "20000"]) == 1
    assert "FAIL: scallop p99.9" in capsys.readouterr().out


def test_rest_figures_on_a_plane(files, tmp_path, capsys):
    # a raster too coarse for the limit on a plane: nothing is rest material, all of it is
    # the program's own scallop
    mesh, program = files
    coarse = program("coarse.nc", w=2.0)
    rep = tmp_path / "r.json"
    assert main(["verify", str(mesh), str(coarse), "-r", "3", "--scallop", "0.05", "--samples", "20000",
                 "--judge", "reachable", "--rest", "--report", str(rep)]) == 1
    out = capsys.readouterr().out
    assert "tangent ball reaches, 0 (0 per mille)" in out and "the program's own share is" in out
    R = json.loads(rep.read_text())["reachable"]
    assert R["rest"]["above_limit"] > 0 and R["beyond_any_ball"] == 0 and R["unconfirmed"] == 0
    assert R["samples"] == R["tangent_test"]["samples"]
    assert R["rest"]["p999_over_rest"] == pytest.approx(R["scallop"]["p999"], abs=1e-9)


def test_bad_input_exit_2(files, tmp_path, capsys):
    mesh, program = files
    nc = program("good.nc")
    bad = tmp_path / "bad.nc"
    bad.write_text("G0 X0 Y0 Z0\nG81 X1 Y1 Z-1 R2\n")
    assert main(["verify", str(mesh), str(bad), "-r", "3"]) == 2
    err = capsys.readouterr().err
    assert "line 2" in err and "canned cycle" in err
    assert main(["verify", str(mesh), str(nc), "-r", "0"]) == 2
    assert "--tool-radius" in capsys.readouterr().err
    assert main(["verify", str(tmp_path / "none.ply"), str(nc), "-r", "3"]) == 2
    # a program file that is not there is named as such (not read as G-code text)
    assert main(["verify", str(mesh), str(tmp_path / "none.nc"), "-r", "3"]) == 2
    err = capsys.readouterr().err
    assert f"G-code file {tmp_path / 'none.nc'} does not exist" in err and "Traceback" not in err
    assert main(["verify", str(mesh), str(nc), "-r", "3", "--report", str(tmp_path / "no" / "r.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["verify", str(mesh), str(nc), "-r", "3", "--samples", "0"]) == 2
    capsys.readouterr()
    assert main(["verify", str(mesh), str(nc), "-r", "3", "--rest"]) == 2
    assert "--rest needs --scallop" in capsys.readouterr().err
    for bad_depth in ("0", "-0.01", "nan"):
        assert main(["verify", str(mesh), str(nc), "-r", "3", "--reach-depth", bad_depth]) == 2
        assert "--reach-depth must be > 0" in capsys.readouterr().err


def test_reach_depth_is_the_functions_and_a_deeper_one_excuses_less(tmp_path, capsys):
    # A 12-degree V-groove, tighter than a ball of r = 2 at its crease: samples near the
    # crease are unreachable. `--reach-depth` is verify()'s reach_depth (the raster and
    # trade-off benchmarks judge 1.05 H with a depth of H; without it the depth is the
    # limit), and a deeper one can only mark fewer samples unreachable: the tangent ball
    # is allowed to cut deeper into the other wall, and the search behind it has the same
    # limit.
    import trimesh

    from conformill.mesh.synthetic import v_groove
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify
    from test_verify_reach import _raster

    m, r, H = v_groove(a_deg=12.0, step=0.5), 2.0, 0.02
    mesh = tmp_path / "groove.ply"
    trimesh.Trimesh(m.V, m.F, process=False).export(mesh)
    nc = tmp_path / "raster.nc"
    nc.write_text(_raster(m, r, half=9.5))
    args = ["verify", str(mesh), str(nc), "-r", str(r), "--scallop", str(1.5 * H), "--judge", "reachable",
            "--samples", "20000", "-q"]
    reports = {}
    for depth in (None, H, 0.25 * H):
        rep = tmp_path / f"r{depth}.json"
        main(args + ([] if depth is None else ["--reach-depth", str(depth)]) + ["--report", str(rep)])
        reports[depth] = json.loads(rep.read_text())
    assert reports[None]["thresholds"]["reach_depth"] == 1.5 * H
    assert reports[H]["thresholds"]["reach_depth"] == H
    ref = verify(m, read_gcode(nc), r, n_samples=20000, scallop=1.5 * H, reach_depth=H, judge="reachable").summary
    # (the report keeps 6 significant digits)
    assert reports[H]["reachable"]["unreachable_fraction"] == pytest.approx(ref["reachable"]["unreachable_fraction"],
                                                                             rel=1e-5)
    assert reports[H]["reachable"]["scallop"] == pytest.approx(ref["reachable"]["scallop"], rel=1e-5)
    frac = [reports[d]["reachable"]["unreachable_fraction"] for d in (None, H, 0.25 * H)]
    assert 0 < frac[0] <= frac[1] <= frac[2]
    assert frac[0] < frac[2]  # the depth does matter here
    capsys.readouterr()


def test_a_ball_far_larger_than_the_part_exit_2(files, tmp_path, capsys):
    # the plane is 30 mm across: a radius above 3000 mm is a mistake of units (1e300 ended
    # in an IndexError of the rapid check, with a traceback)
    mesh, program = files
    nc = program("good.nc")
    rep, html = tmp_path / "r.json", tmp_path / "v.html"
    for radius in ("1e300", "3001"):
        assert main(["verify", str(mesh), str(nc), "-r", radius, "--scallop", "0.1", "--report", str(rep)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"conformill verify: error: --tool-radius {float(radius):g} mm is more than 100 times "
                              f"the part's size (30 x 30 x 0 mm)") and err.count("\n") == 1, err
        assert main(["view", str(mesh), str(nc), "--tool-radius", radius, "-o", str(html)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"conformill view: error: --tool-radius {float(radius):g} mm is more than 100 times")
    # the ball that touches the part is r + stock: a stock of 1e300 is the same mistake
    # (it failed "nothing judged", or "heat has no finite value" in view); a radius below
    # the programs' 4 decimals is one too (1e-100 ended in an IndexError)
    for cmd, words in ((["verify", str(mesh), str(nc), "-r", "4", "--stock", "1e300", "--report", str(rep)],
                        "--tool-radius 4 mm plus the stock 1e+300 mm is more than 100 times"),
                       (["view", str(mesh), str(nc), "--tool-radius", "4", "--stock", "1e300", "-o", str(html)],
                        "--tool-radius 4 mm plus the stock 1e+300 mm is more than 100 times"),
                       (["verify", str(mesh), str(nc), "-r", "1e-100", "--report", str(rep)],
                        "--tool-radius 1e-100 mm is below 0.0001 mm"),
                       (["view", str(mesh), str(nc), "--tool-radius", "1e-100", "-o", str(html)],
                        "--tool-radius 1e-100 mm is below 0.0001 mm")):
        assert main(cmd) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"conformill {cmd[0]}: error: {words}") and err.count("\n") == 1, err
    assert not rep.exists() and not html.exists()


def test_a_binary_program_exit_2(files, tmp_path, capsys, monkeypatch):
    # it was read with its bytes replaced: "line 1: cannot read '\x11\ufffd_...'"
    import io

    mesh, _ = files
    data = bytes(range(256)) * 20
    prog, rep = tmp_path / "bin.nc", tmp_path / "r.json"
    prog.write_bytes(data)
    assert main(["verify", str(mesh), str(prog), "-r", "3", "--report", str(rep)]) == 2
    err = capsys.readouterr().err
    assert err == f"conformill verify: error: {prog} is not a text G-code file (binary data at byte 0)\n"
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(data)))
    assert main(["verify", str(mesh), "-", "-r", "3", "--report", str(rep)]) == 2
    err = capsys.readouterr().err
    assert err == "conformill verify: error: standard input is not a text G-code file (binary data at byte 0)\n"
    assert main(["view", str(mesh), str(prog), "-o", str(tmp_path / "v.html")]) == 2
    assert "is not a text G-code file" in capsys.readouterr().err
    assert not rep.exists() and not (tmp_path / "v.html").exists()


def test_a_program_on_standard_input(files, capsys, monkeypatch):
    import io

    mesh, program = files
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(program("good.nc").read_bytes())))
    assert main(["verify", str(mesh), "-", "-r", "3", "--scallop", "0.05", "--samples", "5000"]) == 0
    assert "PASS" in capsys.readouterr().out


def test_path_control_is_reported_not_simulated(files, tmp_path, capsys):
    mesh, program = files
    nc = program("good.nc")
    text = nc.read_text()
    runs = {}
    for name, mode in (("none", ""), ("blend", " G64 P0.005 Q0"), ("any", " G64"), ("zero", " G64 P0 Q0.1")):
        p = tmp_path / f"{name}.nc"
        p.write_text(text.replace("G21 G90\n", f"G21 G90{mode}\n"))  # the same line numbers
        rep = tmp_path / f"{name}.json"
        assert main(["verify", str(mesh), str(p), "-r", "3", "--scallop", "0.05", "--samples", "20000",
                     "--report", str(rep)]) == 0
        runs[name] = capsys.readouterr().out, json.loads(rep.read_text())
    out, rep = runs["blend"]
    assert rep["path_control"] == ["G64 P0.005 Q0"] and "path control of the feed moves: G64 P0.005 Q0" in out
    assert "any amount" not in out
    assert runs["any"][1]["path_control"] == ["G64"] and "G64 without a positive P" in runs["any"][0]
    assert runs["zero"][1]["path_control"] == ["G64 P0 Q0.1"] and "G64 without a positive P" in runs["zero"][0]
    assert runs["none"][1]["path_control"] == ["unset"] and "machine's own mode" in runs["none"][0]
    # the figures are the same: the mode is recorded, not simulated
    strip = ("path_control", "seconds", "program")
    assert {k: v for k, v in rep.items() if k not in strip} == \
        {k: v for k, v in runs["none"][1].items() if k not in strip}


def test_feed_with_the_spindle_stopped_is_reported(files, tmp_path, capsys):
    mesh, program = files
    nc = program("raster.nc")
    rows = nc.read_text().count("G1 Z")
    started = tmp_path / "started.nc"
    started.write_text(nc.read_text().replace("G21 G90\n", "G21 G90 M3 S10000\n"))  # the same line numbers
    runs = {}
    for p in (nc, started):
        rep = tmp_path / f"{p.stem}.json"
        assert main(["verify", str(mesh), str(p), "-r", "3", "--scallop", "0.05", "--samples", "20000",
                     "--report", str(rep)]) == 0
        runs[p.stem] = capsys.readouterr().out, json.loads(rep.read_text())
    out, rep = runs["raster"]
    assert rep["spindle"] == {"feed_blocks_stopped": 2 * rows, "first_line": 5}
    assert f"spindle: {2 * rows} feed block(s) run with the spindle stopped" in out and "line 5" in out
    out, rep2 = runs["started"]
    assert rep2["spindle"] == {"feed_blocks_stopped": 0, "first_line": None} and "spindle:" not in out
    # a warning, not a verdict: the figures are the same
    strip = ("spindle", "seconds", "program")
    assert {k: v for k, v in rep.items() if k not in strip} == {k: v for k, v in rep2.items() if k not in strip}
