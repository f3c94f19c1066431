"""The G-code reader of conformill.verify: arcs, modes, units, comments and every error."""

import math
import re

import numpy as np
import pytest

from conformill.errors import ConformillError, GCodeError
from conformill.verify.gcode import FEED, RAPID, read_gcode


def test_linear_modal_comments_line_numbers():
    text = """%
(header comment)
N10 G21 G90 G17 (units and modes)
N20 G0 X1 Y2 Z5 ; rapid
N30 G1 Z0 F300
X4       (modal G1)
/ G1 X99 (block delete)
Y6 M3 S1000 T1
M6 T2
G0 Z5
M30
%
"""
    p = read_gcode(text)
    assert np.allclose(p.points, [[1, 2, 5], [1, 2, 0], [4, 2, 0], [4, 6, 0], [4, 6, 5]])
    assert p.motion.tolist() == [RAPID, FEED, FEED, FEED, RAPID]
    assert p.line.tolist() == [4, 5, 6, 8, 10]
    assert np.allclose(p.start, [1, 2, 5])  # unknown start: the first programmed values
    assert np.isnan(p.feed[0]) and p.feed[1] == 300
    assert p.feed_length() == pytest.approx(5 + 3 + 4)


def test_block_delete_off_and_start():
    p = read_gcode("G0 X0 Y0 Z1\n/G1 X5\n", block_delete=False, start=(0, 0, 10))
    assert np.allclose(p.points[-1], [5, 0, 1])
    assert np.allclose(p.start, [0, 0, 10])
    A, B = p.segments()
    assert np.allclose(A[0], [0, 0, 10]) and np.allclose(B[0], [0, 0, 1])


def test_start_backfills_axes():
    p = read_gcode("G0 Z10\nG0 X3 Y4\n")
    assert np.allclose(p.points, [[3, 4, 10], [3, 4, 10]])


def test_incremental_and_inch():
    p = read_gcode("G20 G90 G0 X1 Y1 Z1\nG91 G1 X1 Y-0.5\nZ-1\nG21 X2\n")
    assert np.allclose(p.points[0], [25.4, 25.4, 25.4])
    assert np.allclose(p.points[1], [50.8, 12.7, 25.4])
    assert np.allclose(p.points[2], [50.8, 12.7, 0])
    assert np.allclose(p.points[3], [52.8, 12.7, 0])
    assert p.units == "mm"
    q = read_gcode("G20\nG0 X0 Y0 Z0\nG1 X1 F10\n")
    assert q.feed[-1] == pytest.approx(254.0) and q.units == "inch"


def _radii(P, c):
    return np.hypot(P[:, 0] - c[0], P[:, 1] - c[1])


@pytest.mark.parametrize("tol", [0.1, 0.01, 0.001])
def test_full_circle_ccw_and_chord_tolerance(tol):
    p = read_gcode("G0 X10 Y0 Z0\nG3 X10 Y0 I-10 J0 F100\n", chord_tol=tol)
    arc = p.points[p.line == 2]
    assert np.allclose(_radii(arc, (0, 0)), 10)
    assert np.allclose(arc[-1], [10, 0, 0])
    ang = np.unwrap(np.arctan2(arc[:, 1], arc[:, 0]))
    assert np.all(np.diff(ang) > 0)  # counter-clockwise
    assert ang[-1] - 0.0 == pytest.approx(2 * math.pi)
    # chord deviation from the arc: sagitta of the largest step
    step = np.max(np.diff(np.concatenate([[0.0], ang])))
    assert 10 * (1 - math.cos(step / 2)) <= tol + 1e-12
    # the feed length converges to the circumference
    assert p.feed_length() == pytest.approx(2 * math.pi * 10, rel=2 * tol / 10 + 1e-9)


def test_quarter_arcs_cw_ccw_and_helix():
    p = read_gcode("G0 X10 Y0 Z0\nG2 X0 Y-10 I-10 J0 F100\nG3 X10 Y0 Z-2 I0 J10\n")
    a = p.points[p.line == 2]
    ang = np.arctan2(a[:, 1], a[:, 0])
    assert np.all(np.diff(ang) < 0) and ang[-1] == pytest.approx(-math.pi / 2)
    b = p.points[p.line == 3]
    assert np.allclose(_radii(b, (0, 0)), 10)
    assert np.allclose(b[-1], [10, 0, -2])
    assert np.all(np.diff(b[:, 2]) < 0)  # helical: Z linear in the angle
    angb = np.arctan2(b[:, 1], b[:, 0])  # from -pi/2 (exclusive) to 0
    assert np.all(np.diff(angb) > 0)
    assert np.allclose(b[:, 2], -2 * (angb + math.pi / 2) / (math.pi / 2), atol=1e-9)


def test_r_form_short_and_long():
    # G2 short arc from (10,0) to (0,10), R10: centre (10, 10)
    p = read_gcode("G0 X10 Y0 Z0\nG2 X0 Y10 R10 F100\n")
    a = p.points[p.line == 2]
    assert np.allclose(_radii(a, (10, 10)), 10)
    assert p.feed_length() == pytest.approx(math.pi / 2 * 10, rel=1e-4)
    # G3 with R<0: the long way round, centre (10, 10) again, three quarters of a turn
    q = read_gcode("G0 X10 Y0 Z0\nG3 X0 Y10 R-10 F100\n")
    b = q.points[q.line == 2]
    assert np.allclose(_radii(b, (10, 10)), 10)
    assert q.feed_length() == pytest.approx(1.5 * math.pi * 10, rel=1e-4)
    # G3 short: centre (0, 0)
    s = read_gcode("G0 X10 Y0 Z0\nG3 X0 Y10 R10\n")
    assert np.allclose(_radii(s.points[s.line == 2], (0, 0)), 10)


def test_absolute_arc_centres_and_inch_arc():
    p = read_gcode("G90.1\nG0 X10 Y0 Z0\nG3 X-10 Y0 I0 J0\n")
    assert np.allclose(_radii(p.points[p.line == 3], (0, 0)), 10)
    q = read_gcode("G20\nG0 X1 Y0 Z0\nG3 X-1 Y0 I-1 J0\n")
    assert np.allclose(_radii(q.points[q.line == 3], (0, 0)), 25.4)


def test_freecad_and_opencamlib_style_programs():
    freecad = """(Exported by FreeCAD)
(Post Processor: linuxcnc_post)
(Output Time:2024-01-01 00:00:00)
(begin preamble)
G17 G54 G40 G49 G80 G90
G21
(begin operation: Surface)
(machine units: mm/min)
M5
M6 T1 (ball 6mm)
G43 H1
M3 S10000
G0 Z15.000
G0 X-5.000 Y-5.000
G0 Z3.000
G1 X-5.000 Y-5.000 Z0.000 F600.000
G1 X5.000 Y-5.000 Z0.000 F600.000
G2 X10.000 Y0.000 Z0.000 I0.000 J5.000 F600.000
G0 Z15.000
(finish operation: Surface)
M05
G17 G54 G90 G80 G40
M2
"""
    p = read_gcode(freecad)
    assert len(p) > 6 and p.motion[-1] == RAPID
    assert np.allclose(p.points[-2], [10, 0, 0])
    ocl = "G21 F100\nG00 Z10\nG00 X0 Y0\nG01 Z0.5\nG01 X1.000 Y0.000 Z0.4\nG01 X2 Y0 Z0.3\nG00 Z10\n"
    q = read_gcode(ocl)
    assert q.motion.tolist() == [0, 0, 1, 1, 1, 0]


def test_reads_a_file(tmp_path):
    f = tmp_path / "p.nc"
    f.write_text("G0 X0 Y0 Z1\nG1 Z0\n")
    p = read_gcode(f)
    assert p.source == str(f) and len(p) == 2
    p2 = read_gcode(str(f))
    assert len(p2) == 2


@pytest.mark.parametrize(
    "text, line, words",
    [
        ("G0 X0 Y0 Z0\nG18\nG2 X1 Z0 I0.5\n", 3, "G18"),
        ("G0 X0 Y0 Z0\nG19 G3 Y1 Z0 J0.5\n", 2, "G19"),
        ("G0 X0 Y0 Z0\nG41 D1 G1 X5\n", 2, "compensation"),
        ("G0 X0 Y0 Z5\nG81 X1 Y1 Z-1 R2\n", 2, "canned cycle"),
        ("G0 X0 Y0 Z0\nG1 X1 A30\n", 2, "axis A"),
        ("G0 X0 Y0 Z0 B5\n", 1, "axis B"),
        ("G0 X0 Y0 Z0\nG1 X1 C5\n", 2, "axis C"),
        ("G0 X0 Y0 Z0\nG28\n", 2, "G28"),
        ("G0 X0 Y0 Z0\nG92 X0\n", 2, "G92"),
        ("G0 X0 Y0 Z0\nG1 X1 Y$\n", 2, "cannot read"),
        ("G0 X0 Y0 Z0\nG1 X1 (open comment\n", 2, "unclosed comment"),
        ("X1 Y1 Z1\n", 1, "motion mode"),
        ("G0 X0 Y0 Z0\nG2 X1 Y1\n", 2, "without I/J or R"),
        ("G0 X0 Y0 Z0\nG2 X10 Y0 R2\n", 2, "shorter than half the chord"),
        ("G0 X0 Y0 Z0\nG2 X10 Y0 I3 J0\n", 2, "not on the arc"),
        ("G0 X0 Y0 Z0\nG0 G1 X1\n", 2, "two motion"),
        ("G0 X0 Y0 Z0\nG1 X1 X2\n", 2, "twice"),
        ("G0 X0 Y0 Z0\nG1 X1 F-5\n", 2, "negative feed"),
        ("G0 X0 Y0 Z0\nG1 X1 I2\n", 2, "arc words"),
        ("G0 X0 Y0 Z0\nG7 X1\n", 2, "G7"),
        ("G91 G1 X1\n", 1, "unknown"),
    ],
)
def test_errors_name_the_line(text, line, words):
    with pytest.raises(GCodeError) as exc:
        read_gcode(text)
    msg = str(exc.value)
    assert msg.startswith(f"line {line}:"), msg
    assert words.lower() in msg.lower(), msg
    assert isinstance(exc.value, ConformillError)


def test_other_errors(tmp_path):
    with pytest.raises(GCodeError, match="chord tolerance"):
        read_gcode("G0 X0 Y0 Z0\n", chord_tol=0)
    with pytest.raises(GCodeError, match="never gives axis Z"):
        read_gcode("G0 X0 Y0\n")
    with pytest.raises(GCodeError, match="cannot read G-code file"):
        read_gcode(tmp_path)  # a folder
    with pytest.raises(GCodeError, match="file name or text"):
        read_gcode(42)


def test_empty_program():
    p = read_gcode("%\n(nothing)\n%\n")
    assert len(p) == 0 and p.points.shape == (0, 3)


@pytest.mark.parametrize("text, modes", [
    ("G21\nG0 X0 Y0 Z5\nG1 Z0 F100\nG1 X1\nM30\n", ("unset",)),
    ("G21\nG64 P0.005 Q0\nG0 X0 Y0 Z5\nG1 Z0 F100\nM30\n", ("G64 P0.005 Q0",)),
    ("G20\nG64 P0.001\nG0 X0 Y0 Z1\nG1 Z0 F10\nM30\n", ("G64 P0.0254",)),  # inch tolerances in mm
    ("G21 G64\nG0 X0 Y0 Z5\nG1 Z0 F100\nG61\nG1 X1\nG61.1\nG2 X2 Y1 I0.5 J0.5\nG64 P0.01\nG1 X3\nG61\nG1 X4\n",
     ("G64", "G61", "G61.1", "G64 P0.01")),
    ("G21\nG0 X0 Y0 Z5\nG1 Z0 F100\nG64 P0.01\nG0 Z5\nM30\n", ("unset",)),  # set after the only feed move
    ("G21\nG64 P0.01\nG0 X0 Y0 Z5\nG0 X1\nM30\n", ()),  # rapids only
    ("G21\nG0 X0 Y0 Z5\nG64 P0.02 G1 Z0 F100\nG61 G1 X1\n", ("G64 P0.02", "G61")),  # on a motion's line
    ("G21\nG64 P0\nG0 X0 Y0 Z5\nG1 Z0 F100\nG64 Q0.1\nG1 X1\n", ("G64 P0", "G64 Q0.1")),
])
def test_path_modes_of_the_feed_moves(text, modes):
    prog = read_gcode(text)
    assert prog.path_modes == modes
    # recorded, not simulated: the same moves without any mode block
    plain = read_gcode(re.sub(r"G6[14](\.1)?( [PQ][-\d.]+)*", "", text))
    assert np.array_equal(prog.points, plain.points) and np.array_equal(prog.motion, plain.motion)


def test_unbounded_modes_and_one_mode_per_block():
    from conformill.verify.gcode import unbounded_mode

    for mode, loose in [("G64", True), ("G64 P0", True), ("G64 P-1", True), ("G64 Q0.1", True),
                        ("G64 P0.005 Q0", False), ("G64 P0.0254", False), ("G61", False), ("G61.1", False),
                        ("unset", False)]:
        assert unbounded_mode(mode) is loose, mode
    with pytest.raises(GCodeError, match="line 2.*two path-control modes"):
        read_gcode("G21\nG61 G64 P0.1\nG0 X0 Y0 Z1\nG1 Z0 F10\n")


def test_plain_linear_moves_read_as_the_general_parse_reads_them():
    # "G1 X Y Z" lines take a short path; the same moves spelled otherwise (G01, lower case,
    # no spaces, a trailing comment) take the general one: the programs must be identical,
    # in mm and in inches, with a feed set before, and after a G91 (incremental: general only)
    head = "G21 G90 G17\nG0 X0 Y0 Z5\nG1 Z0 F300\n"
    moves = [(1.5, -2.25, 0.125), (3.0, .5, -1.0), (-4.0, 2.0, 0.0)]
    fast = "".join(f"G1 X{x} Y{y} Z{z}\n" for x, y, z in moves)
    slow = "".join(f"g01x{x}y{y}z{z} (c)\n" for x, y, z in moves)
    tail = "G91\nG1 X1 Y1 Z1\nG90\nG1 X7 Y7 Z7\nG20\nG1 X1 Y2 Z3\nG0 Z5\nM30\n"
    a, b = read_gcode(head + fast + tail), read_gcode(head + slow + tail)
    for k in ("points", "motion", "line", "feed", "start"):
        assert np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True), k
    assert a.path_modes == b.path_modes and a.units == b.units
    assert np.allclose(a.points[2:5], moves)
    assert np.allclose(a.points[5], [-3.0, 3.0, 1.0])  # the G91 move, from (-4, 2, 0)
    assert np.allclose(a.points[-2], [25.4, 50.8, 76.2])  # G20: inches


@pytest.mark.parametrize("text, blocks, first", [
    # stopped when the program starts: every feed block counts, the plunge first
    ("G21 G90\nG0 X0 Y0 Z5\nG1 Z0 F100\nG1 X1.0000 Y0.0000 Z0.0000\nG2 X2 Y0 I0.5 J0\nG0 Z5\nM30\n", 3, 3),
    # started before the cut (M3 or M4, with or without a leading zero): none
    ("G21 G90\nM3 S1000\nG0 X0 Y0 Z5\nG1 Z0 F100\nG1 X1.0000 Y0.0000 Z0.0000\nM5\nM30\n", 0, 0),
    ("G21 G90\nM04 S1000\nG0 X0 Y0 Z5\nG1 Z0 F100\nX1\nM5\nM30\n", 0, 0),
    # in one block the spindle words act before the motion
    ("G21 G90\nG0 X0 Y0 Z5\nG1 Z0 F100 M3 S900\nG1 X1 M5\nG1 X2\nM30\n", 2, 4),
    # M5 stops it, M3 starts it again; the fast path (G1 X Y Z lines) counts too
    ("G21 G90\nM3 S1\nG0 X0 Y0 Z5\nG1 Z0 F100\nM5\nG1 X1.0000 Y0.0000 Z0.0000\nM3\nG1 X2.0000 Y0.0000 Z0.0000\n", 1, 6),
    # a tool change stops it (before an M3 in the same block); a rapid never counts
    ("G21 G90\nM3 S1\nG0 X0 Y0 Z5\nT1 M6\nG1 Z0 F100\nT2 M6 M3 S2\nG1 X1\nG0 Z9\n", 1, 5),
])
def test_feed_blocks_with_the_spindle_stopped(text, blocks, first):
    p = read_gcode(text)
    assert (p.spindle_off_feeds, p.spindle_off_line) == (blocks, first)


def test_an_exponent_is_not_read_as_a_number():
    # "X1e400" is X1 and E400 to an RS274 reader; rs274 refuses the E word there, and so does this one
    with pytest.raises(GCodeError, match=r"line 2: word E is only read with M66/M67/M68"):
        read_gcode("G21 G90\nG1 X1e400 Y0 Z0 F100\n")
    # LinuxCNC's inputs and outputs take it (rs274 accepts these)
    p = read_gcode("G21 G90\nM66 E0 L0\nM67 E0 Q2.5\nM68 E1 Q0\nG0 X0 Y0 Z5\nG1 Z0 F100\n")
    assert np.allclose(p.points, [[0, 0, 5], [0, 0, 0]])


def test_the_program_ends_at_m2_or_m30():
    # the block's own motion runs, nothing after it (the machine stops there)
    for end in ("M2", "M30"):
        p = read_gcode(f"G21 G90\nM3 S1\nG0 X0 Y0 Z5\nG1 Z0 F100 {end}\nG1 X1\nG0 Z9\n")
        assert np.allclose(p.points, [[0, 0, 5], [0, 0, 0]]) and p.spindle_off_feeds == 0
        p = read_gcode(f"G21 G90\nG0 X0 Y0 Z5\n{end}\nG1 X7 Z0 F100\n")
        assert np.allclose(p.points, [[0, 0, 5]]) and p.spindle_off_feeds == 0


# -- binary files -----------------------------------------------------------------------
PROGRAM = b"G21 G90\nG0 X0 Y0 Z5\nG1 Z0 F100\nG1 X1\nM30\n"


@pytest.mark.parametrize("data, at", [
    (b"\x11\xc8_\xb0\x00\x1b\xdb\x96" * 100, 0),  # random-looking bytes with NULs
    (PROGRAM + b"\x00\x00junk", len(PROGRAM)),  # text, then a NUL
    (b"G21\n" + bytes(range(0x80, 0x100)) * 40, 4),  # mostly not UTF-8, no NUL
    (b"G21\n" + b"\x01\x02\x03 G1" * 100, 4),  # mostly control bytes
    (np.random.default_rng(0).integers(1, 256, 3000).astype("<u2").tobytes(), 0),  # 16-bit data: NUL high bytes
    (np.random.default_rng(0).integers(1, 256, 3000).astype(">u2").tobytes(), 0),
])
def test_a_binary_file_is_named_as_such(tmp_path, data, at):
    f = tmp_path / "prog.nc"
    f.write_bytes(data)
    with pytest.raises(GCodeError, match=rf"^{re.escape(str(f))} is not a text G-code file \(binary data at byte "
                                         rf"{at}\)$"):
        read_gcode(f)


@pytest.mark.parametrize("codec", ["utf-16", "utf-16-le", "utf-16-be"])
def test_utf16_text_and_a_latin1_comment(tmp_path, codec):
    # UTF-16 with its byte order mark or without (every other byte NUL): named as such
    f = tmp_path / "u16.nc"
    f.write_bytes(PROGRAM.decode().encode(codec))
    with pytest.raises(GCodeError, match="is UTF-16 text.*save it as ASCII or UTF-8"):
        read_gcode(f)
    # a few bytes that are not UTF-8 in a comment (Latin-1) are text: read as before
    g = tmp_path / "latin1.nc"
    g.write_bytes(b"(Temp\xe9rature: 20\xb0C)\n" + PROGRAM)
    p = read_gcode(g)
    assert np.allclose(p.points[-1], [1, 0, 0]) and p.line.tolist() == [3, 4, 5]
    # a UTF-8 byte order mark (Windows editors) is not a block: it was "line 1: cannot read"
    b = tmp_path / "bom.nc"
    b.write_bytes(b"\xef\xbb\xbf" + PROGRAM)
    assert np.array_equal(read_gcode(b).points, read_gcode(PROGRAM.decode()).points)
