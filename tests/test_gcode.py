"""G-code writer: numbers round-trip, header comments, rapids only at safe Z, bytes
deterministic, atomic output, statistics, every bad input."""

from __future__ import annotations

import re

import numpy as np
import pytest

import conformill
from conformill.errors import OutputError, PlanningError
from conformill.output.gcode import format_gcode, write_gcode
from conformill.types import ToolPath

WORD = re.compile(r"([A-Z])(-?\d+(?:\.\d+)?)")


def _toolpath(n_passes=4, k=30, safe_z=12.0, seed=0):
    rng = np.random.default_rng(seed)
    passes = []
    for i in range(n_passes):
        x = np.linspace(-40.0, 40.0, k)
        if i % 2:
            x = x[::-1]
        z = -2.0 + np.sin(x / 7.0) + rng.uniform(-0.3, 0.3, k)
        passes.append(np.column_stack([x, np.full(k, -20.0 + 3.0 * i + rng.uniform(0, 1e-3)), z]))
    return ToolPath(passes=passes, safe_z=safe_z)


def _parse(text):
    """Blocks as (code words dict) with comments stripped; modal positions tracked.

    Returns a list of (motion, position-after, words) for every motion block.
    """
    pos = {"X": None, "Y": None, "Z": None}
    motion = None
    moves = []
    for line in text.splitlines():
        body = re.sub(r"\([^)]*\)", "", line).strip()
        if not body:
            continue
        words = WORD.findall(body)
        g = [float(v) for c, v in words if c == "G"]
        if 0.0 in g:
            motion = "G0"
        if 1.0 in g:
            motion = "G1"
        axes = {c: float(v) for c, v in words if c in "XYZ"}
        if axes:
            before = dict(pos)
            pos.update(axes)
            moves.append((motion, before, dict(pos), body))
    return moves


class TestProgram:
    def test_round_trip_of_cut_points(self):
        tp = _toolpath()
        moves = _parse(format_gcode(tp, feed=1500.0, plunge_feed=400.0))
        feeds = [m for m in moves if m[0] == "G1"]
        # per pass: the plunge (to point 0) then one move per further point
        pts = [np.array([m[2]["X"], m[2]["Y"], m[2]["Z"]]) for m in feeds]
        expect = np.vstack(tp.passes)
        assert len(pts) == len(expect)
        np.testing.assert_allclose(np.array(pts), expect, atol=0.5e-4 + 1e-12, rtol=0)

    def test_structure_and_modal_words(self):
        text = format_gcode(_toolpath(n_passes=2), feed=1500, plunge_feed=400, spindle=12000)
        lines = text.splitlines()
        body = [ln for ln in lines if not ln.startswith("(")]
        assert body[:4] == ["G21 G90 G17 G94", "G40 G49 G80", "M3 S12000", "G0 Z12.0000"]
        assert body[-3:] == ["G0 Z12.0000", "M5", "M30"]
        assert "%" not in text
        assert text.endswith("\n") and "\r" not in text
        # F only when it changes: plunge then feed, in each pass
        assert re.findall(r"F(\d+)", text) == ["400", "1500", "400", "1500"]
        same = format_gcode(_toolpath(n_passes=2), feed=1500)
        assert re.findall(r"F(\d+)", same) == ["1500"]
        assert "M3 " not in same
        for ln in body:  # every number has exactly 4 decimals
            for c, v in WORD.findall(ln):
                if c in "XYZ":
                    assert re.fullmatch(r"-?\d+\.\d{4}", v), ln

    def test_rapids_only_at_safe_z_or_vertical(self):
        tp = _toolpath(n_passes=5)
        for motion, before, after, body in _parse(format_gcode(tp, feed=1000)):
            if motion != "G0":
                continue
            vertical = before["X"] == after["X"] and before["Y"] == after["Y"]
            if vertical:
                assert after["Z"] >= tp.safe_z, body  # retracts go up to safe Z
            else:
                assert before["Z"] >= tp.safe_z and after["Z"] >= tp.safe_z, body

    def test_negative_zero_and_repeated_points(self):
        P = np.array([[-1e-6, 0.0, -0.00004], [1.0, 0.0, -1.0], [1.0, 0.0, -1.0],
                      [1.00001, 0.0, -1.0], [2.0, 0.0, -1.0]])
        text = format_gcode(ToolPath(passes=[P], safe_z=5.0), feed=100)
        assert "-0.0000" not in text
        assert "G0 X0.0000 Y0.0000" in text
        assert "G1 Z0.0000" in text
        cuts = [ln for ln in text.splitlines() if ln.startswith("G1 X")]
        # the repeated point and the one within 1e-4 mm are dropped; unchanged Y omitted
        assert cuts == ["G1 X1.0000 Z-1.0000", "G1 X2.0000"]

    def test_single_point_pass(self):
        text = format_gcode(ToolPath(passes=[np.array([[1.0, 2.0, -3.0]])], safe_z=5.0), feed=100)
        body = [ln for ln in text.splitlines() if not ln.startswith("(")]
        assert body[-5:] == ["G0 X1.0000 Y2.0000", "G1 Z-3.0000 F100", "G0 Z5.0000", "M5", "M30"]

    def test_deterministic_bytes(self, tmp_path):
        tp = _toolpath()
        a = format_gcode(tp, feed=1234.5, header={"b": 1, "a": 2.5})
        b = format_gcode(_toolpath(), feed=1234.5, header={"b": 1, "a": 2.5})
        assert a == b
        write_gcode(tmp_path / "p.nc", tp, feed=1234.5, header={"b": 1, "a": 2.5})
        assert (tmp_path / "p.nc").read_bytes() == a.encode("ascii")
        assert "F1234.5" in a


class TestHeader:
    def test_every_parameter_and_version(self):
        hdr = {"mesh": "face.ply", "tool_radius": 4.0, "scallop": 0.01, "pattern": "zigzag",
               "passes": 12, "corners": (1, 2, 3, 4)}
        text = format_gcode(_toolpath(), feed=1000, header=hdr)
        comments = [ln for ln in text.splitlines() if ln.startswith("(")]
        assert comments[0] == f"(conformill {conformill.__version__})"
        assert comments[1:] == ["(param mesh: face.ply)", "(param tool_radius: 4.0)",
                                "(param scallop: 0.01)", "(param pattern: zigzag)",
                                "(param passes: 12)", "(param corners: [1, 2, 3, 4])"]

    def test_odd_values_are_sanitised(self):
        hdr = {"name (v2)": "Ærø façade (copy)\nsecond line\ttab", "debug, msg": "(MSG, hello)",
               "long": "x" * 1000, "nan": float("nan"), "unicode µm": "→ ok"}
        text = format_gcode(_toolpath(), feed=1000, header=hdr)
        text.encode("ascii")  # pure ASCII
        comments = [ln for ln in text.splitlines() if ln.startswith("(")]
        assert len(comments) == 1 + len(hdr)
        for c in comments:
            assert re.fullmatch(r"\((conformill|param) [^()]*\)", c), c
            assert len(c) < 256
        assert "(param name [v2]: ?r? facade [copy] second line tab)" in comments
        assert "(param debug, msg: [MSG, hello])" in comments
        assert "(param nan: nan)" in comments
        assert "(param unicode ?m: ? ok)" in comments or "(param unicode um: ? ok)" in comments


class TestStats:
    def test_lengths_and_time(self, tmp_path):
        P1 = np.array([[0.0, 0.0, -1.0], [3.0, 4.0, -1.0], [3.0, 4.0, -3.0]])
        P2 = np.array([[10.0, 4.0, -2.0], [10.0, 0.0, -2.0]])
        tp = ToolPath(passes=[P1, P2], safe_z=5.0)
        st = write_gcode(tmp_path / "s.nc", tp, feed=600.0, plunge_feed=200.0)
        text = (tmp_path / "s.nc").read_text()
        assert st["passes"] == 2 and st["cut_points"] == 5 and st["cut_moves"] == 3
        assert st["feed_length_mm"] == pytest.approx(5.0 + 2.0 + 4.0)
        assert st["plunge_length_mm"] == pytest.approx(6.0 + 7.0)
        # retract 8 + rapid (3,4) -> (10,4) 7 + retract 7
        assert st["rapid_length_mm"] == pytest.approx(8.0 + 7.0 + 7.0)
        assert st["machining_time_min"] == pytest.approx(11.0 / 600.0 + 13.0 / 200.0)
        assert st["n_lines"] == len(text.splitlines())
        assert st["bytes"] == len(text.encode())


class TestErrors:
    def test_folder_missing(self, tmp_path):
        target = tmp_path / "nope" / "p.nc"
        with pytest.raises(OutputError, match="does not exist"):
            write_gcode(target, _toolpath(), feed=1000)
        assert not target.parent.exists()

    def test_failed_write_leaves_nothing(self, tmp_path):
        with pytest.raises(PlanningError):
            write_gcode(tmp_path / "p.nc", ToolPath(passes=[], safe_z=1.0), feed=1000)
        assert list(tmp_path.iterdir()) == []

    def test_existing_file_kept_on_error(self, tmp_path):
        target = tmp_path / "p.nc"
        target.write_text("old\n")
        with pytest.raises(PlanningError):
            write_gcode(target, _toolpath(), feed=-1)
        assert target.read_text() == "old\n"

    @pytest.mark.parametrize("kw, msg", [
        ({"feed": 0.0}, "feed must be positive"),
        ({"feed": float("nan")}, "feed must be positive"),
        ({"feed": "fast"}, "feed must be a number"),
        ({"feed": 100, "plunge_feed": -5}, "plunge_feed must be positive"),
        ({"feed": 100, "spindle": 0}, "spindle must be positive"),
    ])
    def test_bad_numbers(self, kw, msg):
        with pytest.raises(PlanningError, match=msg):
            format_gcode(_toolpath(), **kw)

    def test_bad_passes(self):
        with pytest.raises(PlanningError, match="no passes"):
            format_gcode(ToolPath(passes=[], safe_z=5.0), feed=100)
        with pytest.raises(PlanningError, match=r"pass 1 must be \(k, 3\)"):
            format_gcode(ToolPath(passes=[np.zeros((2, 3)), np.zeros((2, 2))], safe_z=5.0), feed=100)
        with pytest.raises(PlanningError, match=r"pass 0 must be \(k, 3\) with k >= 1"):
            format_gcode(ToolPath(passes=[np.zeros((0, 3))], safe_z=5.0), feed=100)
        P = np.zeros((3, 3))
        P[2, 0] = np.nan
        with pytest.raises(PlanningError, match="pass 0 point 2 is not finite"):
            format_gcode(ToolPath(passes=[P], safe_z=5.0), feed=100)
        P = np.zeros((3, 3))
        P[1, 2] = 6.0
        with pytest.raises(PlanningError, match=r"pass 0 point 1 is above the clearance height: z = 6\.0000"):
            format_gcode(ToolPath(passes=[P], safe_z=5.0), feed=100)
        with pytest.raises(PlanningError, match="safe_z must be finite"):
            format_gcode(ToolPath(passes=[np.zeros((2, 3))], safe_z=float("inf")), feed=100)


def test_compiled_formatter_matches_reference():
    from conformill.output.gcode import _format_moves, _num

    rng = np.random.default_rng(7)
    Q = np.concatenate([rng.integers(-10**9, 10**9, (500, 3)), [[0, -1, 1], [-9999, 10000, -10000], [5, 0, 0]]])
    C = rng.random(Q.shape) < 0.7
    C[-3:] = True
    ref = "\n".join(" ".join(["G1"] + [ax + _num(int(v)) for ax, v, on in zip("XYZ", q, c) if on])
                    for q, c in zip(Q, C))
    assert _format_moves(Q, C) == ref


# -- path control (blend) -------------------------------------------------------------------


@pytest.mark.parametrize("blend, block", [
    (None, None), (0, "G61"), (0.0, "G61"), (0.0025, "G64 P0.0025 Q0"), (0.005, "G64 P0.005 Q0"),
    (1, "G64 P1 Q0"), (2.5, "G64 P2.5 Q0"), (1e-6, "G64 P0.000001 Q0"), (0.00025, "G64 P0.00025 Q0"),
    (np.float32(0.5), "G64 P0.5 Q0"), (0.0029, "G64 P0.0029 Q0"), (1000, "G64 P1000 Q0"),
    (1.9e-6, "G64 P0.000001 Q0"), (0.0123456789, "G64 P0.012345 Q0"),  # rounded down: never looser
])
def test_path_control_block(blend, block):
    from conformill.output.gcode import path_control

    assert path_control(blend) == block


@pytest.mark.parametrize("blend", [-1.0, -1e-9, float("nan"), float("inf"), "x", "0.1", [0.1], True, 1e-7, 9e-7,
                                   1000.5, 1e300])
def test_path_control_refuses_bad_values(blend):
    from conformill.output.gcode import path_control

    with pytest.raises(PlanningError, match="blend"):
        path_control(blend)
    with pytest.raises(PlanningError, match="blend"):
        format_gcode(_toolpath(1, 5), feed=500, blend=blend)


@pytest.mark.parametrize("blend, block", [(0.0025, "G64 P0.0025 Q0"), (0, "G61")])
def test_path_control_sits_in_the_preamble_and_changes_nothing_else(tmp_path, blend, block):
    tp = _toolpath(3, 20)
    plain = format_gcode(tp, feed=900, plunge_feed=300, spindle=12000, header={"a": 1})
    text = format_gcode(tp, feed=900, plunge_feed=300, spindle=12000, header={"a": 1}, blend=blend)
    lines, base = text.splitlines(), plain.splitlines()
    i = lines.index("G40 G49 G80")
    assert lines[i + 1] == block and lines[i + 2].startswith("M3 S12000")  # before the spindle and any motion
    assert lines[:i + 1] + lines[i + 2:] == base
    assert not any(ln.startswith(("G64", "G61")) for ln in base)
    # the statistics count the extra line and nothing else
    a = write_gcode(tmp_path / "a.nc", tp, feed=900, blend=blend)
    b = write_gcode(tmp_path / "b.nc", tp, feed=900)
    assert a["n_lines"] == b["n_lines"] + 1 and a["bytes"] == b["bytes"] + len(block) + 1
    assert {k: v for k, v in a.items() if k not in ("n_lines", "bytes")} == \
        {k: v for k, v in b.items() if k not in ("n_lines", "bytes")}
    # the reader takes the block as a mode (the blending is not simulated): the same points
    from conformill.verify.gcode import read_gcode

    pa, pb = read_gcode(tmp_path / "a.nc"), read_gcode(tmp_path / "b.nc")
    assert np.array_equal(pa.points, pb.points) and np.array_equal(pa.motion, pb.motion)


def test_tool_number_changes_the_tool_and_applies_its_length():
    tp = _toolpath(2, 10)
    plain = format_gcode(tp, feed=900, spindle=12000, blend=0.005).splitlines()
    lines = format_gcode(tp, feed=900, spindle=12000, blend=0.005, tool=7).splitlines()
    i = lines.index("G64 P0.005 Q0")
    # after the modes, before the spindle starts and before any motion; nothing else changes
    assert lines[i + 1:i + 4] == ["T7 M6", "G43 H7", "M3 S12000"]
    assert lines[:i + 1] + lines[i + 3:] == plain
    assert not any(ln.startswith(("T", "G43")) for ln in plain) and "G40 G49 G80" in plain
    assert format_gcode(tp, feed=900, tool=np.int64(2)).splitlines()[format_gcode(tp, feed=900).splitlines().index(
        "G40 G49 G80") + 1] == "T2 M6"


@pytest.mark.parametrize("tool", [0, -3, 1.5, True, "1", 2**31, float("nan"), float("inf")])
def test_tool_number_refuses_bad_values(tool):
    from conformill.output.gcode import tool_number

    with pytest.raises(PlanningError, match="tool number"):
        tool_number(tool)
    with pytest.raises(PlanningError, match="tool number"):
        format_gcode(_toolpath(1, 5), feed=500, tool=tool)


@pytest.mark.parametrize("coolant, word", [("flood", "M8"), ("mist", "M7")])
def test_coolant_on_after_the_spindle_and_off_before_it_stops(coolant, word):
    tp = _toolpath(2, 10)
    plain = format_gcode(tp, feed=900, spindle=12000).splitlines()
    lines = format_gcode(tp, feed=900, spindle=12000, coolant=coolant).splitlines()
    i = lines.index("M3 S12000")
    assert lines[i + 1] == word and lines[i + 2].startswith("G0 Z")  # before any motion
    assert lines[-3:] == ["M9", "M5", "M30"] and plain[-2:] == ["M5", "M30"]
    assert [ln for ln in lines if ln not in (word, "M9")] == plain
    assert not any(ln in ("M7", "M8", "M9") for ln in plain)


@pytest.mark.parametrize("coolant", ["air", "", "M8", True])
def test_coolant_refuses_unknown_kinds(coolant):
    with pytest.raises(PlanningError, match="coolant"):
        format_gcode(_toolpath(1, 5), feed=500, coolant=coolant)
