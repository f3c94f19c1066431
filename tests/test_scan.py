"""``plan --scan``: the scan recipe (:func:`conformill.pipeline.scan_recipe`) as one option."""

from __future__ import annotations

import json
import re

import pytest

from conformill.cli.main import main
from conformill.errors import JobValueError
from conformill.pipeline import FILL_OVER_SAVING, SCAN_PATTERN_SCALLOP, SCAN_RECIPE, scan_recipe

COMMON = ["plan", "sample:patch", "--tool-radius", "4", "--scallop", "0.1", "-q", "--pattern", "contour"]


def _header(path):
    return [ln for ln in path.read_text().splitlines() if ln.startswith("(param")]


def test_help_names_the_recipe(capsys):
    assert main(["plan", "--help"]) == 0
    text = re.sub(r"(\w)- (\w)", r"\1-\2", " ".join(capsys.readouterr().out.split()))  # argparse wraps at hyphens
    said = (f"--pencil --pencil-search {SCAN_RECIPE['pencil_search']} --pencil-left {SCAN_RECIPE['pencil_left']:g} "
            f"--hop-lifted {SCAN_RECIPE['hop_lift']:g} --pattern-scallop {SCAN_PATTERN_SCALLOP['zigzag']:g} "
            f"({SCAN_PATTERN_SCALLOP['contour']:g} contour, {SCAN_PATTERN_SCALLOP['spiral']:g} spiral) "
            f"--fill {SCAN_RECIPE['fill']:g}")
    assert SCAN_RECIPE["pencil"] and said in text


def test_the_recipe_by_pattern():
    for pattern, f in SCAN_PATTERN_SCALLOP.items():
        assert scan_recipe(pattern) == {**SCAN_RECIPE, "pattern_scallop": f}
    assert "pattern_scallop" not in SCAN_RECIPE  # (only with its pattern)
    with pytest.raises(JobValueError, match="unknown pattern 'raster'"):
        scan_recipe("raster")


def test_scan_writes_the_same_bytes_as_its_six_options(tmp_path):
    a, b = tmp_path / "scan.nc", tmp_path / "explicit.nc"
    report = tmp_path / "scan.json"
    assert main(COMMON + ["--scan", "-o", str(a), "--report", str(report)]) == 0
    assert main(COMMON + ["--pencil", "--pencil-search", "folds", "--pencil-left", "0.5", "--hop-lifted", "3",
                          "--pattern-scallop", f"{SCAN_PATTERN_SCALLOP['contour']:g}", "--fill", "0.7", "-o",
                          str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()
    head = _header(a)
    assert "(param pencil: folds, grid points per mm2 30, where the pattern leaves above 0.5 H)" in head
    assert "(param hop lifted: runs lifted more than 3 mm, rapid 5000)" in head
    # the shipped patch is smooth: the fill of its wider paths was longer than they saved, so
    # it was planned again without them, and the header says so
    said = [ln for ln in head if ln.startswith("(param fill: none: the fill above 0.7 H of paths spaced for "
            f"{SCAN_PATTERN_SCALLOP['contour']:g} H was ")]
    assert len(said) == 1 and said[0].endswith(" times what the spacing saved; paths spaced for H)")
    fill = json.loads(report.read_text())["fill"]
    times = said[0].split(" was ")[1].split()[0]
    assert times == f"{fill['feed_mm'] / fill['saved_mm']:.1f}" and float(times) > FILL_OVER_SAVING


def test_the_summary_says_what_the_fill_did(tmp_path, capsys):
    # dropped (the shipped patch with --scan): the fill's feed against the saving, and the
    # plan again for H; kept without wider paths: its passes, and no saving
    assert main(COMMON[:-3] + ["--pattern", "contour", "--scan", "-o", str(tmp_path / "a.nc"),
                               "--report", str(tmp_path / "a.json")]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  fill ")]
    fill = json.loads((tmp_path / "a.json").read_text())["fill"]
    assert line == [f"  fill              none: {fill['feed_mm'] / 1000:.2f} m of fill against about "
                    f"{fill['saved_mm'] / 1000:.2f} m saved by the paths spaced for "
                    f"{SCAN_PATTERN_SCALLOP['contour']:g} H ({fill['feed_mm'] / fill['saved_mm']:.1f} times); "
                    f"planned again with the paths spaced for H"]
    assert main(COMMON[:-3] + ["--pattern", "contour", "--fill", "0.7", "-o", str(tmp_path / "b.nc"),
                               "--report", str(tmp_path / "b.json")]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  fill ")]
    fill = json.loads((tmp_path / "b.json").read_text())["fill"]
    assert "saved_mm" not in fill and fill["passes"] > 0
    assert line == [f"  fill              {fill['passes']} pass(es), {fill['cl_points']} CL points, "
                    f"{fill['feed_mm'] / 1000:.2f} m through {fill['balls']} balls where the passes left above 0.7 H"]


def test_given_options_win_over_the_recipe(tmp_path):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--scan", "--pencil-left", "0.8", "--hop-lifted", "0", "--pencil-density", "20",
                          "--pattern-scallop", "1", "--fill", "0.9", "-o", str(out)]) == 0
    head = "\n".join(_header(out))
    assert "(param pencil: folds, grid points per mm2 20, where the pattern leaves above 0.8 H)" in head
    assert "hop" not in head
    assert "(param fill: where the passes leave above 0.9 H)" in head


def test_scan_with_the_sample_search_keeps_every_centre(tmp_path):
    # --pencil-left needs the fold search: the recipe does not add it to the other search
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--scan", "--pencil-search", "samples", "-o", str(out)]) == 0
    head = "\n".join(_header(out))
    assert "(param pencil: samples per mm2 30)" in head
    assert "(param hop lifted: runs lifted more than 3 mm" in head


def test_without_scan_nothing_changes(tmp_path):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["-o", str(out)]) == 0
    head = "\n".join(_header(out))
    assert "pencil" not in head and "hop" not in head and "fill" not in head and "pattern scallop" not in head


@pytest.mark.parametrize("opt, value", [("--pencil-left", "-1"), ("--hop-lifted", "nan"), ("--fill", "0"),
                                        ("--fill", "inf"), ("--pattern-scallop", "-1")])
def test_bad_values_beside_scan_exit_2_without_output(tmp_path, capsys, opt, value):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--scan", opt, value, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and opt.lstrip("-") in err
    assert not out.exists()


def test_wider_paths_without_the_fill_exit_2_without_output(tmp_path, capsys):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--pattern-scallop", "1.3", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "pattern-scallop 1.3" in err and "--fill" in err
    assert not out.exists()


def test_fill_off_beside_scan_leaves_out_the_fill_and_the_wider_paths(tmp_path):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--scan", "--fill", "off", "-o", str(out)]) == 0
    head = "\n".join(_header(out))
    assert "fill" not in head and "pattern scallop" not in head and "pencil: folds" in head


def test_a_fill_that_is_no_number_exits_2(tmp_path, capsys):
    out = tmp_path / "p.nc"
    assert main(COMMON + ["--fill", "lots", "-o", str(out)]) == 2
    assert "off" in capsys.readouterr().err and not out.exists()
