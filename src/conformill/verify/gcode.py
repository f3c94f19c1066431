"""A small, strict reader of 3-axis RS274 (G-code) programs: positions of the tool tip.

Written for :mod:`conformill.verify` and the viewer; it shares no code with the G-code
writer, so that a verification can catch the writer's mistakes.

What is read
------------
- Motion: ``G0`` (rapid), ``G1`` (feed), ``G2``/``G3`` (arcs, clockwise / counter-clockwise
  seen from +Z) in the XY plane (``G17``), with centre offsets ``I J`` (incremental, ``G91.1``,
  the default) or absolute centres (``G90.1``), or the radius form ``R`` (``R < 0`` picks the
  arc longer than half a turn); helical arcs (Z changes linearly); ``P`` = number of turns.
  Arcs are replaced by chords whose deviation from the arc is at most ``chord_tol``.
- Modal motion: a block with coordinates and no motion word continues the current motion mode.
- Units ``G20`` (inch) / ``G21`` (mm): everything is converted to mm. Distance modes ``G90`` /
  ``G91``. ``F`` (feed, converted to mm/min).
- The program ends at the block with ``M2`` or ``M30`` (after its motion): what follows is
  not read, as the machine does not run it.
- The spindle: ``M3``/``M4`` start it, ``M5`` and a tool change ``M6`` stop it (it is stopped
  when the program starts); feed moves made while it is stopped are counted
  (:attr:`Program.spindle_off_feeds`), not refused. In a block, ``M6`` acts before
  ``M3``/``M4``/``M5``, and they act before its motion (RS274NGC's order of execution).
- ``E`` is read only in a block with ``M66``/``M67``/``M68`` (LinuxCNC's inputs and outputs);
  elsewhere it is refused, so that ``X1e3`` (an exponent, which G-code has not) is an error,
  not ``X1`` and ``E3``.
- Ignored: comments ``( ... )`` and after ``;``, line numbers ``N``, ``%`` lines, the other
  ``M`` words and ``S T H D`` words, ``O`` program names in comments, and the modal G-codes
  that do not move the tool tip in program coordinates: ``G4 G17 G40 G43 G49 G54-G59.3 G61
  G61.1 G64 G80 G90.1 G91.1 G93 G94 G98 G99``.
- Block delete: lines starting with ``/`` are skipped (the switch is on), unless
  ``block_delete=False``.

Anything else raises :class:`conformill.errors.GCodeError` naming the line number and its
text: arcs in ``G18``/``G19``, cutter compensation ``G41``/``G42``, canned cycles ``G73 G76
G81-G89``, rotary or extra axes ``A B C U V W``, ``G28 G30 G53 G92 G10``, malformed words.

The tool position before the first move is not known from the program: each axis takes the
first value the program gives it (``start=None``), so the first move is never a made-up
plunge from the machine origin; or pass ``start``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from conformill.errors import GCodeError

__all__ = ["Program", "read_gcode", "program_text", "unbounded_mode", "RAPID", "FEED"]

RAPID = 0
FEED = 1

_INCH = 25.4
#: G-codes accepted and ignored (they do not move the tool tip in program coordinates).
_IGNORED_G = {
    4.0, 17.0, 40.0, 43.0, 49.0, 54.0, 55.0, 56.0, 57.0, 58.0, 59.0, 59.1, 59.2, 59.3,
    61.0, 61.1, 64.0, 80.0, 93.0, 94.0, 98.0, 99.0,
}
_WHY_NOT = {
    18.0: "arcs outside the XY plane (G18) are not supported",
    19.0: "arcs outside the XY plane (G19) are not supported",
    41.0: "cutter radius compensation (G41) is not supported",
    42.0: "cutter radius compensation (G42) is not supported",
    41.1: "cutter radius compensation (G41.1) is not supported",
    42.1: "cutter radius compensation (G42.1) is not supported",
    28.0: "G28 (return home) is not supported: its position is machine-specific",
    30.0: "G30 (return home) is not supported: its position is machine-specific",
    53.0: "machine coordinates (G53) are not supported",
    92.0: "coordinate offsets (G92) are not supported",
    10.0: "G10 (set offsets) is not supported",
}
_CANNED = {73.0, 74.0, 76.0, 81.0, 82.0, 83.0, 84.0, 85.0, 86.0, 87.0, 88.0, 89.0}
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_COMMENT = re.compile(r"\([^)]*\)")
#: A plain linear move with all three axes, as conformill's writer puts most of its lines:
#: read without the general parse (the same result, about a third of the time)
_G1_XYZ = re.compile(r"G1 X([-+]?(?:\d+\.?\d*|\.\d+)) Y([-+]?(?:\d+\.?\d*|\.\d+)) Z([-+]?(?:\d+\.?\d*|\.\d+))")


def unbounded_mode(mode: str) -> bool:
    """Whether a path mode of :attr:`Program.path_modes` is ``G64`` without a positive ``P``
    (LinuxCNC then keeps the speed however far the tool strays from the path)."""
    words = mode.split()
    if not words or words[0] != "G64":
        return False
    p = [float(w[1:]) for w in words[1:] if w.startswith("P")]
    return not (p and p[0] > 0)


@dataclass(frozen=True, eq=False)
class Program:
    """Tool-tip positions of a 3-axis program, in mm, one row per (linearised) move.

    Move ``i`` goes from ``points[i - 1]`` (``start`` for ``i = 0``) to ``points[i]``.

    Attributes
    ----------
    points : (k, 3) float64
        Tool-tip position at the end of each move, mm (program coordinates).
    motion : (k,) int8
        ``0`` (:data:`RAPID`, G0) or ``1`` (:data:`FEED`, G1/G2/G3) for the move that ends
        at each point.
    line : (k,) int64
        1-based line number in the source text of the block that made each move (an arc
        gives several moves with the same line).
    start : (3,) float64
        Position before the first move.
    feed : (k,) float64
        Programmed feed rate (mm/min) of each move; NaN where none was given yet.
    source : str
        File name, or ``"<text>"``.
    units : str
        ``"mm"`` or ``"inch"``: the units the program was written in (last G20/G21 seen).
    path_modes : tuple of str
        The path-control modes the feed moves run in, in order of first use: ``"G64 P<p>
        Q<q>"`` (the words given, in mm), ``"G61"``, ``"G61.1"``, or ``"unset"`` (none set
        yet: the machine's own mode). A ``G64`` without a positive ``P`` (``"G64"``, ``"G64
        P0"``, ``"G64 Q0.1"``) lets LinuxCNC round corners by any amount
        (:func:`unbounded_mode`). Recorded, not simulated: the moves are taken as
        programmed.
    spindle_off_feeds : int
        Feed moves (G1/G2/G3 blocks) made while the spindle is stopped: before the first
        ``M3``/``M4``, or after an ``M5`` or a tool change (``M6``) until the next.
    spindle_off_line : int
        1-based line of the first of them (0: none).
    """

    points: np.ndarray
    motion: np.ndarray
    line: np.ndarray
    start: np.ndarray
    feed: np.ndarray = field(repr=False)
    source: str = "<text>"
    units: str = "mm"
    path_modes: tuple = ()
    spindle_off_feeds: int = 0
    spindle_off_line: int = 0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def segments(self, kind: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points of the moves, optionally only of one kind.

        Returns
        -------
        A, B : (s, 3) float64
            Move ``i`` goes from ``A[i]`` to ``B[i]``.
        """
        prev = np.vstack([self.start[None, :], self.points[:-1]]) if len(self) else np.zeros((0, 3))
        if kind is None:
            return prev, self.points.copy()
        keep = self.motion == kind
        return prev[keep], self.points[keep]

    def for_stock(self, tool_radius: float, stock: float) -> tuple["Program", float]:
        """This program as a ball of radius ``tool_radius + stock`` would run it, and that
        radius: the same ball centres, with the tips ``stock`` lower.

        A ball of radius ``r`` finishing the part's offset by ``stock`` (material left on
        the part; negative: cut into it) touches the offset wherever the ball of radius
        ``r + stock`` about the same centre touches the part: the tests on ball positions
        (reach, rapid clearance) take this program and radius. The material left above the
        offset is not that of the larger ball (its cusps are rounder by the stock); it is
        measured on the offset itself (:func:`conformill.verify.simulate.verify`).
        """
        s = float(stock)
        if s == 0.0:
            return self, float(tool_radius)
        lower = np.array([0.0, 0.0, s])
        return replace(self, points=self.points - lower, start=self.start - lower), float(tool_radius) + s

    def feed_length(self) -> float:
        """Total length (mm) of the feed moves."""
        A, B = self.segments(FEED)
        return float(np.linalg.norm(B - A, axis=1).sum())


def _error(lineno: int, text: str, why: str) -> GCodeError:
    return GCodeError(f"line {lineno}: {why}: {text.strip()[:80]!r}")


def _arc_points(p0, p1, centre, clockwise, turns, chord_tol, radius_tol, lineno, text):
    """Chord points (excluding ``p0``, including ``p1``) of an XY arc, helical in Z."""
    r0 = math.hypot(p0[0] - centre[0], p0[1] - centre[1])
    r1 = math.hypot(p1[0] - centre[0], p1[1] - centre[1])
    if r0 <= 0.0 or r1 <= 0.0:
        raise _error(lineno, text, "arc of zero radius")
    if abs(r0 - r1) > max(radius_tol, 1e-3 * r0):  # LinuxCNC's tolerance
        raise _error(lineno, text, f"arc end is not on the arc (radius {r0:.6g} at the start, {r1:.6g} at the end)")
    a0 = math.atan2(p0[1] - centre[1], p0[0] - centre[0])
    a1 = math.atan2(p1[1] - centre[1], p1[0] - centre[0])
    sweep = a1 - a0
    same = math.hypot(p1[0] - p0[0], p1[1] - p0[1]) <= 1e-9 * max(1.0, r0)
    if clockwise:
        sweep = sweep % (-2 * math.pi) if not same else 0.0
        if sweep == 0.0:
            sweep = -2 * math.pi
        sweep -= 2 * math.pi * (turns - 1)
    else:
        sweep = sweep % (2 * math.pi) if not same else 0.0
        if sweep == 0.0:
            sweep = 2 * math.pi
        sweep += 2 * math.pi * (turns - 1)
    r = 0.5 * (r0 + r1)
    # sagitta r (1 - cos(d/2)) <= chord_tol
    c = 1.0 - min(chord_tol / r, 1.0)
    dmax = 2.0 * math.acos(c) if c > -1.0 else math.pi
    dmax = min(max(dmax, 1e-6), math.pi / 2)
    n = max(1, int(math.ceil(abs(sweep) / dmax)))
    s = np.arange(1, n + 1) / n
    ang = a0 + sweep * s
    rad = r0 + (r1 - r0) * s
    pts = np.column_stack([
        centre[0] + rad * np.cos(ang),
        centre[1] + rad * np.sin(ang),
        p0[2] + (p1[2] - p0[2]) * s,
    ])
    pts[-1] = p1
    return pts


#: Bytes that no G-code text holds: the C0 controls but tab, line feed, vertical tab, form
#: feed, carriage return and Ctrl-Z (an old end-of-file mark), and DEL.
_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x19\x1b-\x1f\x7f]")
#: Share of the bytes (of the first 64 kB) that are controls or not UTF-8 above which a file
#: is binary: random bytes give about 0.6, a program with accented comments in Latin-1 a
#: few per mille.
_BINARY_SHARE = 0.1


def _utf16_without_bom(head: bytes) -> bool:
    """Whether ``head`` reads as UTF-16 text of Latin-1 characters: every other byte NUL
    (the high bytes; all but 2 %), the others text (no NUL, no control byte but tab and the
    line ends), at least four characters. 16-bit binary data has control bytes among its
    low bytes."""
    head = head[:len(head) // 2 * 2]
    if len(head) < 8:
        return False
    for lo, hi in ((head[0::2], head[1::2]), (head[1::2], head[0::2])):  # little-, big-endian
        if hi.count(0) >= 0.98 * len(hi) and lo.count(0) == 0 and not _CONTROL.search(lo):
            return True
    return False


def program_text(data: bytes, name: str) -> str:
    """The text of a G-code program read as bytes, or :class:`GCodeError` when it is binary.

    Binary: a NUL byte anywhere (UTF-16 text included, with or without its byte order
    mark, named as such), or more than
    :data:`_BINARY_SHARE` of the first 64 kB in control bytes and bytes that are not UTF-8.
    Otherwise bytes that are not UTF-8 (a comment in Latin-1) become U+FFFD and the reader
    judges the text line by line (only a comment may hold them).

    Parameters
    ----------
    data : bytes
    name : str
        How the message names the program (its file name).

    Returns
    -------
    str

    Raises
    ------
    GCodeError
        ``"NAME is not a text G-code file (binary data at byte N)"``, N the first byte
        that is no text (counted from 0); ``"NAME is UTF-16 text, ..."`` for UTF-16.
    """
    if data[:2] in (b"\xff\xfe", b"\xfe\xff") or _utf16_without_bom(data[:4096]):
        raise GCodeError(f"{name} is UTF-16 text, not a G-code file the machine reads: save it as ASCII or UTF-8")
    head = data[:65536]
    bad = len(_CONTROL.findall(head)) + head.decode("utf-8", errors="replace").count("\ufffd")
    if b"\0" in data or bad > _BINARY_SHARE * max(len(head), 1):
        nul = data.find(b"\0")
        ctrl = _CONTROL.search(head)
        try:
            head.decode("utf-8")
            first = len(data)
        except UnicodeDecodeError as exc:
            first = exc.start
        at = min(first, ctrl.start() if ctrl else len(data), nul if nul >= 0 else len(data))
        raise GCodeError(f"{name} is not a text G-code file (binary data at byte {at})")
    return data.decode("utf-8-sig", errors="replace")  # a UTF-8 byte order mark is not a block


def read_gcode(source, chord_tol: float = 0.001, start=None, block_delete: bool = True) -> Program:
    """Read a 3-axis RS274 program into tool-tip positions (see the module docstring).

    Parameters
    ----------
    source : str or os.PathLike
        A file name, or the program text itself (any ``str`` containing a newline, or one
        that is not an existing file, is taken as text).
    chord_tol : float
        Largest deviation (mm) of the chords that replace an arc from the arc.
    start : (3,) array_like, optional
        Tool-tip position before the first move (mm). Default: each axis takes the first
        value the program gives it.
    block_delete : bool
        Skip lines starting with ``/``.

    Returns
    -------
    Program

    Raises
    ------
    GCodeError
        Unreadable or binary file (:func:`program_text`), unsupported or malformed block
        (the message gives the line number and text), or a program that never gives some
        axis a value.
    """
    if not chord_tol > 0:
        raise GCodeError(f"chord tolerance must be > 0 mm, got {chord_tol!r}")
    name = "<text>"
    if isinstance(source, os.PathLike) or (isinstance(source, str) and "\n" not in source and source.strip()
                                          and Path(source).is_file()):
        name = str(source)
        try:
            data = Path(source).read_bytes()
        except OSError as exc:
            raise GCodeError(f"cannot read G-code file {source}: {exc.strerror}") from None
        text = program_text(data, name)
    elif isinstance(source, str):
        text = source
    else:
        raise GCodeError(f"G-code source must be a file name or text, got {type(source).__name__}")

    scale = 1.0  # program units -> mm
    absolute = True
    arc_abs = False
    mode = None  # current motion mode: 0, 1, 2, 3
    plane = 17
    feed = math.nan
    pos = [math.nan, math.nan, math.nan] if start is None else [float(c) for c in np.asarray(start, float).reshape(3)]
    pts: list = []  # (x, y, z) per point, the arcs' chords' points included
    mot: list = []
    lin: list = []
    fed: list = []
    units = "mm"
    path_mode = "unset"
    path_modes: list = []
    spindle = False  # stopped when the program starts
    off_feeds = 0  # feed blocks while it is stopped
    off_line = 0  # the first of them

    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if absolute:
            g1 = _G1_XYZ.fullmatch(s)
            if g1 is not None:  # what the general parse below does with such a line
                mode = 1
                target = [float(g1[1]) * scale, float(g1[2]) * scale, float(g1[3]) * scale]
                pts.append(target)
                mot.append(FEED)
                lin.append(lineno)
                fed.append(feed)
                if path_mode not in path_modes:
                    path_modes.append(path_mode)
                if not spindle:
                    off_feeds += 1
                    off_line = off_line or lineno
                pos = target
                continue
        if not s or s.startswith("%"):
            continue
        if s.startswith("/"):
            if block_delete:
                continue
            s = s[1:]
        s = _COMMENT.sub(" ", s)
        if "(" in s:
            raise _error(lineno, raw, "unclosed comment")
        s = s.split(";", 1)[0]
        s = s.upper().replace(" ", "").replace("\t", "")
        if not s:
            continue
        words = _WORD.findall(s)
        if sum(len(a) + len(b) for a, b in words) != len(s):
            bad = _WORD.sub("", s)
            raise _error(lineno, raw, f"cannot read {bad!r}")
        gs = []
        vals = {}
        ms = []
        e_word = False
        for letter, num in words:
            if letter == "G":
                gs.append(round(float(num), 1))
            elif letter == "M":
                ms.append(round(float(num), 1))
            elif letter in "STNHDO":
                if letter == "O":
                    raise _error(lineno, raw, "subroutines (O words) are not supported")
                continue
            elif letter in "ABCUVW":
                raise _error(lineno, raw, f"axis {letter} is not supported (3-axis programs only)")
            elif letter == "E":  # checked below: only LinuxCNC's M66-M68 take it
                e_word = True
            elif letter in "XYZIJKRFPLQ":
                if letter in vals:
                    raise _error(lineno, raw, f"word {letter} appears twice")
                vals[letter] = float(num)
            else:
                raise _error(lineno, raw, f"unknown word {letter}")
        motion_here = None
        for g in gs:
            if g in (0.0, 1.0, 2.0, 3.0):
                if motion_here is not None:
                    raise _error(lineno, raw, "two motion commands in one block")
                motion_here = int(g)
            elif g == 20.0:
                scale, units = _INCH, "inch"
            elif g == 21.0:
                scale, units = 1.0, "mm"
            elif g == 90.0:
                absolute = True
            elif g == 91.0:
                absolute = False
            elif g == 90.1:
                arc_abs = True
            elif g == 91.1:
                arc_abs = False
            elif g in (17.0, 18.0, 19.0):
                plane = int(g)
            elif g == 80.0:
                mode = None
            elif g in _CANNED:
                raise _error(lineno, raw, f"canned cycle G{g:g} is not supported")
            elif g in _WHY_NOT:
                raise _error(lineno, raw, _WHY_NOT[g])
            elif g in _IGNORED_G:
                pass
            else:
                raise _error(lineno, raw, f"G{g:g} is not supported")
        if sum(g in (61.0, 61.1, 64.0) for g in gs) > 1:
            raise _error(lineno, raw, "two path-control modes (G61, G61.1, G64) in one block")
        if 61.0 in gs or 61.1 in gs:
            path_mode = "G61.1" if 61.1 in gs else "G61"
        elif 64.0 in gs:
            path_mode = "G64" + "".join(f" {k}{vals[k] * scale:g}" for k in "PQ" if k in vals)
        if e_word and not any(m in ms for m in (66.0, 67.0, 68.0)):
            # ("X1e3" is X1 and E3 to an RS274 reader, not a number with an exponent)
            raise _error(lineno, raw, "word E is only read with M66/M67/M68 (numbers with an exponent, like 1e3, "
                                      "are not G-code)")
        if 6.0 in ms:  # a tool change stops the spindle (before M3/M4/M5 in the same block)
            spindle = False
        if 3.0 in ms or 4.0 in ms:  # the spindle words act before the block's motion
            spindle = True
        if 5.0 in ms:
            spindle = False
        if "F" in vals:
            if vals["F"] < 0:
                raise _error(lineno, raw, "negative feed rate")
            feed = vals["F"] * scale
        if motion_here is not None:
            mode = motion_here
        axes = [k for k in "XYZ" if k in vals]
        if not axes and not (mode in (2, 3) and motion_here is not None and ("I" in vals or "J" in vals)):
            if motion_here is not None and any(k in vals for k in "IJKR"):
                raise _error(lineno, raw, "arc without an end point")
            if any(k in vals for k in "IJKR"):
                raise _error(lineno, raw, "arc words without a motion")
            if 2.0 in ms or 30.0 in ms:  # the program ends: the machine reads no further
                break
            continue
        if mode is None:
            raise _error(lineno, raw, "coordinates without a motion mode (G0/G1/G2/G3)")
        # target position in mm
        target = list(pos)
        for i, k in enumerate("XYZ"):
            if k in vals:
                v = vals[k] * scale
                if absolute:
                    target[i] = v
                else:
                    if math.isnan(pos[i]):
                        raise _error(lineno, raw, f"incremental move on axis {k} whose position is unknown")
                    target[i] = pos[i] + v
        if mode in (2, 3):
            if plane != 17:
                raise _error(lineno, raw, f"arcs in the G{plane} plane are not supported (XY plane, G17, only)")
            if any(math.isnan(c) for c in pos[:2]) or any(math.isnan(c) for c in target):
                raise _error(lineno, raw, "arc from an unknown position")
            turns = int(vals.get("P", 1))
            if turns < 1 or turns != vals.get("P", 1):
                raise _error(lineno, raw, "arc P (turns) must be a positive integer")
            p0 = np.array(pos)
            p1 = np.array(target)
            if "R" in vals:
                if "I" in vals or "J" in vals:
                    raise _error(lineno, raw, "arc with both R and I/J")
                R = vals["R"] * scale
                dx, dy = p1[0] - p0[0], p1[1] - p0[1]
                d = math.hypot(dx, dy)
                if d <= 1e-12:
                    raise _error(lineno, raw, "R-form arc with the same start and end (use I/J for a full circle)")
                if d > 2 * abs(R) * (1 + 1e-9) + 1e-9:
                    raise _error(lineno, raw, f"arc radius {abs(R):.6g} mm is shorter than half the chord {d / 2:.6g} mm")
                h = math.sqrt(max(R * R - d * d / 4, 0.0))
                # centre to the left of the chord for a short CCW arc (or a long CW one)
                left = (mode == 3) == (R > 0)
                sgn = 1.0 if left else -1.0
                centre = (p0[0] + dx / 2 - sgn * h * dy / d, p0[1] + dy / 2 + sgn * h * dx / d)
            else:
                if "I" not in vals and "J" not in vals:
                    raise _error(lineno, raw, "arc without I/J or R")
                if arc_abs:
                    centre = (vals.get("I", p0[0] / scale) * scale, vals.get("J", p0[1] / scale) * scale)
                else:
                    centre = (p0[0] + vals.get("I", 0.0) * scale, p0[1] + vals.get("J", 0.0) * scale)
            arc = _arc_points(p0, p1, centre, mode == 2, turns, chord_tol, 0.05, lineno, raw)
            pts.extend(arc.tolist())
            mot.extend([FEED] * len(arc))
            lin.extend([lineno] * len(arc))
            fed.extend([feed] * len(arc))
        else:
            if any(k in vals for k in "IJR"):
                raise _error(lineno, raw, f"arc words on a G{mode} move")
            # plain lists, one array each at the end (four small arrays per move were a third
            # of the reading time)
            pts.append(target)
            mot.append(RAPID if mode == 0 else FEED)
            lin.append(lineno)
            fed.append(feed)
        if mode != 0:  # a feed move (G1, or an arc)
            if path_mode not in path_modes:
                path_modes.append(path_mode)
            if not spindle:
                off_feeds += 1
                off_line = off_line or lineno
        pos = target
        if 2.0 in ms or 30.0 in ms:  # the program ends after the block's motion: nothing further runs
            break

    if pts:
        P = np.array(pts, dtype=np.float64).reshape(-1, 3)
        M = np.array(mot, dtype=np.int8)
        L = np.array(lin, dtype=np.int64)
        Fd = np.array(fed, dtype=np.float64)
    else:
        P = np.zeros((0, 3))
        M = np.zeros(0, dtype=np.int8)
        L = np.zeros(0, dtype=np.int64)
        Fd = np.zeros(0)
    if start is None:
        st = np.zeros(3)
        for i, k in enumerate("XYZ"):
            col = P[:, i]
            known = np.flatnonzero(~np.isnan(col))
            if len(col) and not len(known):
                raise GCodeError(f"{name}: the program never gives axis {k} a value")
            if len(known):
                st[i] = col[known[0]]
                col[: known[0]] = col[known[0]]
    else:
        st = np.asarray(start, dtype=np.float64).reshape(3)
        for i in range(3):
            col = P[:, i]
            known = np.flatnonzero(~np.isnan(col))
            first = known[0] if len(known) else len(col)
            col[:first] = st[i]
    return Program(points=P, motion=M, line=L, start=st, feed=Fd, source=name, units=units,
                   path_modes=tuple(path_modes), spindle_off_feeds=off_feeds, spindle_off_line=off_line)
