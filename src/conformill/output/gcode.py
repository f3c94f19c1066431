"""G-code writer: a :class:`~conformill.types.ToolPath` as a plain RS274NGC program.

The program is what LinuxCNC's interpreter accepts (checked with its stand-alone ``rs274``
in ``tests/test_gcode_rs274.py``), with no ``%`` delimiters, and it looks like this::

    (conformill 0.1.0)
    (param tool_radius: 4)              one comment per header entry
    G21 G90 G17 G94                     mm, absolute, XY plane, feed per minute
    G40 G49 G80                         no cutter compensation, no tool length offset, no cycle
    G64 P0.0025 Q0                      path control, only when ``blend`` is given (below)
    T1 M6                               tool change and its length offset, only when a
    G43 H1                              tool number is given (below)
    M3 S12000                           only when a spindle speed is given
    M8                                  coolant on (M8 flood, M7 mist), only when asked
    G0 Z25.0000
    G0 X.. Y..                          for every pass: rapid at safe Z above its start,
    G1 Z.. F<plunge>                    vertical plunge to the pass start,
    G1 X.. Y.. Z.. F<feed>              cut moves (F only when it changes),
    G0 Z25.0000                         vertical retract
    M9                                  coolant off, only when it was turned on
    M5
    M30

Rapids (``G0``) are only at the clearance height ``safe_z`` or vertical retracts to it;
or, for a hop over a lifted run (``ToolPath.hops``), a vertical retract to the hop's
height, a rapid across at it, and a vertical rapid down to where the ball is still clear of
the part above the next pass's start, from which it plunges.
Coordinates have 4 decimals (0.1 micron); ``-0.0000`` is written ``0.0000``; a cut move
whose rounded coordinates equal the current position is dropped, and unchanged axis words
are left out (they are modal). The output is a deterministic function of the inputs.

Path control (``blend``): LinuxCNC rounds the corners of a path of short moves ("path
blending"); ``G64`` without ``P``, the mode a machine may start in, keeps the speed *no
matter how far from the programmed path*. ``blend = P > 0`` writes ``G64 P<P> Q0``: the
tool stays within P mm of the programmed path, and ``Q0`` turns off the naive-CAM
detector, which would otherwise merge moves that are within P of collinear and so drop
points the planner placed on purpose. ``blend = 0`` writes ``G61`` (exact path: every
point is reached, at the cost of slowing down at corners); ``None`` writes neither (the
machine's own mode applies).

Tool length: the programmed point is the tool tip. Without a tool number the program
cancels any tool length offset (``G49``), so the work offset must hold the tool's length
(the tip touched off). With ``tool = N`` it changes to tool N (``T N M6``) and applies its
length from the machine's tool table (``G43 H N``), as CAM posts for LinuxCNC do.

Header comments never start with a word that LinuxCNC treats as an active comment
(``MSG``, ``DEBUG``, ``PRINT``, ``LOG...``, ``PROBEOPEN``, ``PY``...): each is written as
``(param KEY: VALUE)`` with parentheses replaced by brackets, non-ASCII characters
transliterated or replaced by ``?``, control characters by spaces, and long values cut.
"""

from __future__ import annotations

import math
import re
import unicodedata

import numpy as np
from numba import njit

from conformill.errors import JobValueError, OutputError, PlanningError
from conformill.output.atomic import atomic_path

__all__ = ["COOLANTS", "coolant_on", "format_gcode", "path_control", "tool_number", "write_gcode"]

#: Decimal places of coordinates (mm).
DECIMALS = 4
_SCALE = 10**DECIMALS
#: RS274NGC limits a line to 255 characters; keep comments well inside.
_MAX_COMMENT = 200


def format_gcode(toolpath, *, feed: float, plunge_feed: float | None = None,
                 spindle: float | None = None, header: dict | None = None, blend: float | None = None,
                 tool: int | None = None, coolant: str | None = None) -> str:
    """The RS274NGC program of a tool path, as text (pure; see the module docstring).

    Parameters
    ----------
    toolpath : conformill.types.ToolPath
        ``passes``: list of ``(k, 3)`` tool-tip polylines, each cut at feed;
        ``safe_z``: clearance height for rapids.
    feed : float
        Cutting feed, mm/min.
    plunge_feed : float, optional
        Feed of the vertical plunge to each pass start, mm/min (default: ``feed``).
    spindle : float, optional
        Spindle speed (rpm) for ``M3 S..``; no ``M3`` when None.
    header : dict, optional
        Parameters written as comments, in the given order.
    blend : float, optional
        Path control (mm, see the module docstring): ``G64 P<blend> Q0`` when positive,
        ``G61`` when 0, no line when None.
    tool : int, optional
        Tool number N >= 1: ``T N M6`` and ``G43 H N`` (its length from the tool table);
        None: the tip is touched off (``G49`` stays in force).
    coolant : {"flood", "mist"}, optional
        ``M8`` (flood) or ``M7`` (mist) before the first move (after ``M3``, when a spindle
        speed is given), ``M9`` at the end, before ``M5``;
        None: no coolant words.

    Returns
    -------
    str
        The program, ``\\n`` line ends, ending with a newline.

    Raises
    ------
    JobValueError
        A feed/speed that is not positive, a ``blend`` that is negative, not finite or
        below 1e-6 mm, a ``tool`` that is not an integer >= 1, or an unknown ``coolant``.
    PlanningError
        No passes, a pass that is not ``(k, 3)`` finite with ``k >= 1``, a point above
        ``safe_z``, a non-finite ``safe_z``.
    """
    text, _ = _program(toolpath, feed, plunge_feed, spindle, header, blend, tool, coolant)
    return text


def write_gcode(path, toolpath, *, feed: float, plunge_feed: float | None = None,
                spindle: float | None = None, header: dict | None = None, blend: float | None = None,
                tool: int | None = None, coolant: str | None = None) -> dict:
    """Write the program of :func:`format_gcode` to ``path`` atomically; return its statistics.

    Returns
    -------
    dict
        ``passes``, ``cut_points`` (points of the passes), ``cut_moves`` (``G1`` cut lines
        written), ``feed_length_mm`` (cut moves), ``plunge_length_mm``, ``rapid_length_mm``
        (rapids between passes and retracts; the first rapid from the unknown machine
        position is not counted), ``machining_time_min`` (cut and plunge moves at their
        feeds; rapids excluded), ``n_lines``, ``bytes``.

    Raises
    ------
    JobValueError, PlanningError
        See :func:`format_gcode`.
    OutputError
        The folder does not exist or the file cannot be written (no file is left behind).
    """
    text, stats = _program(toolpath, feed, plunge_feed, spindle, header, blend, tool, coolant)
    data = text.encode("ascii")
    with atomic_path(path) as tmp:
        try:
            with open(tmp, "wb") as fh:
                fh.write(data)
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None
    stats["bytes"] = len(data)
    return stats


# --------------------------------------------------------------------------------------


def _positive(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise JobValueError(f"G-code: {name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise JobValueError(f"G-code: {name} must be positive and finite, got {value!r}")
    return v


#: The words that turn the coolant on (``coolant``); ``M9`` turns either off.
COOLANTS = {"flood": "M8", "mist": "M7"}

#: Largest path tolerance written (mm): beyond it ``G64 P`` no longer bounds anything.
_MAX_BLEND = 1000.0


def path_control(blend) -> str | None:
    """The path-control block for ``blend`` (mm): ``G64 P<blend> Q0``, ``G61`` for 0, None for None.

    P is written with at most 6 decimals, rounded down (never looser than asked).

    Raises
    ------
    JobValueError
        ``blend`` not a number (a bool or a string included), negative, not finite, above
        1000 mm, or positive but below 1e-6 mm (0 when rounded down).
    """
    if blend is None:
        return None
    if isinstance(blend, (bool, np.bool_, str)):
        raise JobValueError(f"G-code: blend must be a number (mm), got {blend!r}")
    try:
        b = float(blend)
    except (TypeError, ValueError):
        raise JobValueError(f"G-code: blend must be a number (mm), got {blend!r}") from None
    if not (math.isfinite(b) and 0 <= b <= _MAX_BLEND):
        raise JobValueError(f"G-code: blend must be a number from 0 to {_MAX_BLEND:g} mm, got {blend!r}")
    if b == 0:
        return "G61"
    micro = math.floor(round(b * 1e6, 3))  # whole 1e-6 mm, rounded down
    if micro == 0:
        raise JobValueError(f"G-code: blend {b!r} mm is below the 1e-6 mm that can be written; use 0 for exact path")
    q, r = divmod(micro, 10**6)
    return f"G64 P{q}" + (f".{r:06d}".rstrip("0") if r else "") + " Q0"


def coolant_on(coolant) -> str | None:
    """The word that turns ``coolant`` on (:data:`COOLANTS`), None for None.

    Raises
    ------
    JobValueError
        An unknown kind.
    """
    if coolant is None:
        return None
    if not isinstance(coolant, str) or coolant not in COOLANTS:
        raise JobValueError(f"G-code: coolant must be one of {', '.join(COOLANTS)}, got {coolant!r}")
    return COOLANTS[coolant]


def tool_number(tool) -> int | None:
    """A tool number checked: an integer >= 1 (``T`` and ``H`` words), or None.

    Raises
    ------
    JobValueError
        Not an integer (a float with a fraction, a string, a bool), or below 1.
    """
    if tool is None:
        return None
    if isinstance(tool, (bool, np.bool_)) or not isinstance(tool, (int, np.integer, float, np.floating)) \
            or not float(tool).is_integer() or not 1 <= tool < 2**31:
        raise JobValueError(f"G-code: the tool number must be an integer from 1 to {2**31 - 1}, got {tool!r}")
    return int(tool)


def _num(t: int) -> str:
    """Fixed-point text of an integer number of 1e-4 mm (``0`` is never negative)."""
    sign = "-" if t < 0 else ""
    q, r = divmod(abs(t), _SCALE)
    return f"{sign}{q}.{r:0{DECIMALS}d}"


@njit(cache=True)
def _put_num(t, out, pos):
    """Write ``_num(t)`` as ASCII into ``out[pos:]``; return the new position."""
    if t < 0:
        out[pos] = 45  # '-'
        pos += 1
        t = -t
    q = t // 10000
    r = t - q * 10000
    nd = 1
    x = q
    while x >= 10:
        x //= 10
        nd += 1
    for i in range(nd - 1, -1, -1):
        out[pos + i] = 48 + q % 10
        q //= 10
    pos += nd
    out[pos] = 46  # '.'
    for i in range(4, 0, -1):
        out[pos + i] = 48 + r % 10
        r //= 10
    return pos + 5


@njit(cache=True)
def _format_moves_nb(Q, C):
    k = Q.shape[0]
    out = np.empty(k * 84, dtype=np.uint8)
    pos = 0
    for i in range(k):
        if i > 0:
            out[pos] = 10
            pos += 1
        out[pos] = 71  # 'G'
        out[pos + 1] = 49  # '1'
        pos += 2
        for a in range(3):
            if C[i, a]:
                out[pos] = 32
                out[pos + 1] = 88 + a  # 'X', 'Y', 'Z'
                pos = _put_num(Q[i, a], out, pos + 2)
    return out[:pos]


def _format_moves(Q: np.ndarray, C: np.ndarray) -> str:
    """``G1`` lines (joined by newlines) with the changed axes of ``Q`` (ticks) as ``_num``.

    Written for ``DECIMALS == 4`` (``_put_num``); ``tests/test_gcode.py`` compares it with
    ``_num``.
    """
    return _format_moves_nb(Q.astype(np.int64), C.astype(np.bool_)).tobytes().decode("ascii")


def _ceil_ticks(z: float) -> int:
    """A height rounded up to 1e-4 mm (a clearance height: never below the value)."""
    return int(math.ceil(round(z * _SCALE, 6)))


def _ticks(a) -> np.ndarray:
    """Coordinates rounded to integer multiples of 1e-4 mm (half to even)."""
    return np.rint(np.asarray(a, dtype=np.float64) * _SCALE).astype(np.int64)


def _feed_word(f: float) -> str:
    s = f"{f:.3f}".rstrip("0").rstrip(".")
    return "F" + s


def _clean_comment(text: str) -> str:
    """ASCII, no parentheses or control characters, bounded length."""
    text = unicodedata.normalize("NFKD", str(text))
    text = "".join(ch if ord(ch) < 128 else ("" if unicodedata.combining(ch) else "?") for ch in text)
    text = text.replace("(", "[").replace(")", "]")
    text = re.sub(r"[\x00-\x1f\x7f]", " ", text)
    text = re.sub(r" +", " ", text).strip()
    if len(text) > _MAX_COMMENT:
        text = text[: _MAX_COMMENT - 3] + "..."
    return text


def _header_value(v) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v)) if math.isfinite(float(v)) else str(float(v))
    if isinstance(v, np.ndarray):
        v = v.tolist()
    return str(v)


def _program(toolpath, feed, plunge_feed, spindle, header, blend=None, tool=None, coolant=None):
    from conformill import __version__

    control = path_control(blend)
    tool = tool_number(tool)
    coolant = coolant_on(coolant)
    feed = _positive("feed", feed)
    plunge = feed if plunge_feed is None else _positive("plunge_feed", plunge_feed)
    if spindle is not None:
        spindle = _positive("spindle", spindle)
    try:
        safe_z = float(toolpath.safe_z)
    except (TypeError, ValueError, AttributeError):
        raise PlanningError("G-code: the tool path has no numeric safe_z") from None
    if not math.isfinite(safe_z):
        raise PlanningError(f"G-code: safe_z must be finite, got {safe_z}")
    passes = list(getattr(toolpath, "passes", []) or [])
    if not passes:
        raise PlanningError("G-code: the tool path has no passes")
    header = {} if header is None else dict(header)
    hops = getattr(toolpath, "hops", None)
    hops = [None] * len(passes) if hops is None or len(hops) == 0 else list(hops)
    if len(hops) != len(passes):
        raise PlanningError(f"G-code: the tool path has {len(passes)} passes but {len(hops)} hops")

    safe_t = int(_ticks(safe_z))
    safe_s = _num(safe_t)
    lines = [f"(conformill {_clean_comment(__version__)})"]
    for k, v in header.items():
        lines.append(f"(param {_clean_comment(k)}: {_clean_comment(_header_value(v))})")
    lines.append("G21 G90 G17 G94")
    lines.append("G40 G49 G80")
    if control is not None:
        lines.append(control)
    if tool is not None:
        lines.append(f"T{tool} M6")
        lines.append(f"G43 H{tool}")
    if spindle is not None:
        s = int(spindle) if float(spindle).is_integer() else spindle
        lines.append(f"M3 S{s}" if isinstance(s, int) else f"M3 S{s:.1f}")
    if coolant is not None:
        lines.append(coolant)
    lines.append(f"G0 Z{safe_s}")

    fw_feed = _feed_word(feed)
    fw_plunge = _feed_word(plunge)
    cur_f = None
    feed_len = plunge_len = rapid_len = 0.0
    cut_points = cut_moves = 0
    prev_xy = None  # tool XY after the last retract (ticks)
    up_t = safe_t  # the height the tool is at above the next pass's start (ticks)
    down_t = safe_t  # where a hop's rapid down ends (ticks)
    n_lines = 0  # lines inside the bulk blocks beyond one per ``lines`` entry
    for ip, P in enumerate(passes):
        P = np.asarray(P, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or P.shape[0] == 0:
            raise PlanningError(f"G-code: pass {ip} must be (k, 3) with k >= 1, got shape {P.shape}")
        bad = np.flatnonzero(~np.isfinite(P).all(axis=1))
        if bad.size:
            raise PlanningError(f"G-code: pass {ip} point {bad[0]} is not finite: {P[bad[0]].tolist()}")
        Q = _ticks(P)
        above = np.flatnonzero(Q[:, 2] > safe_t)
        if above.size:
            i = above[0]
            raise PlanningError(
                f"G-code: pass {ip} point {i} is above the clearance height: z = {P[i, 2]:.4f} > safe_z = {safe_z:.4f}")
        cut_points += len(P)
        x0, y0, z0 = (int(v) for v in Q[0])
        # rapid at safe Z (or at the hop's height) to above the pass start, then vertical plunge
        lines.append(f"G0 X{_num(x0)} Y{_num(y0)}")
        if prev_xy is not None:
            rapid_len += math.hypot(x0 - prev_xy[0], y0 - prev_xy[1]) / _SCALE
        if up_t < safe_t and z0 < down_t < up_t:  # a hop: rapid down to where the ball is clear above the start
            lines.append(f"G0 Z{_num(down_t)}")
            rapid_len += (up_t - down_t) / _SCALE
            up_t = down_t
        fw = fw_plunge if cur_f != fw_plunge else ""
        cur_f = fw_plunge
        lines.append(f"G1 Z{_num(z0)}" + (f" {fw}" if fw else ""))
        plunge_len += (up_t - z0) / _SCALE
        # cut moves: only axes that change; moves that change nothing are dropped
        if len(Q) > 1:
            D = np.diff(Q, axis=0)
            moved = (D != 0).any(axis=1)
            Qm = Q[1:][moved]
            prev = np.vstack([Q[:1], Qm[:-1]])
            ch = Qm != prev
            seg = (Qm - prev) / _SCALE
            feed_len += float(np.sqrt((seg * seg).sum(axis=1)).sum())
            cut_moves += len(Qm)
            if len(Qm):
                q, c = Qm[0].tolist(), ch[0].tolist()
                words = ["G1"] + [ax + _num(v) for ax, v, on in zip("XYZ", q, c) if on]
                if cur_f != fw_feed:
                    words.append(fw_feed)
                    cur_f = fw_feed
                lines.append(" ".join(words))
            if len(Qm) > 1:  # the bulk of the program: formatted in compiled code
                block = _format_moves(np.ascontiguousarray(Qm[1:]), np.ascontiguousarray(ch[1:]))
                lines.append(block)
                n_lines += len(Qm) - 2  # one entry of ``lines`` holding len(Qm) - 1 lines
            last = Qm[-1] if len(Qm) else Q[0]
        else:
            last = Q[0]
        # retract: to safe Z, or to the hop's height (rounded up) when the next pass is a hop
        up_t = safe_t
        if ip + 1 < len(passes) and hops[ip + 1] is not None:
            try:
                across, down = (float(v) for v in hops[ip + 1])
            except (TypeError, ValueError):
                raise PlanningError(f"G-code: the hop into pass {ip + 1} must be two heights or None, "
                                    f"got {hops[ip + 1]!r}") from None
            if not (math.isfinite(across) and math.isfinite(down)):
                raise PlanningError(f"G-code: the hop into pass {ip + 1} is not finite: {hops[ip + 1]}")
            Pn = np.asarray(passes[ip + 1], dtype=np.float64)
            # (a malformed next pass is reported when its turn comes)
            ok = Pn.ndim == 2 and Pn.shape[1:] == (3,) and len(Pn) and math.isfinite(Pn[0, 2])
            nxt = int(_ticks(Pn[0, 2])) if ok else int(last[2])
            up_t = min(max(_ceil_ticks(across), int(last[2]), nxt), safe_t)
            down_t = _ceil_ticks(down)
        if up_t == safe_t or up_t > int(last[2]):  # (a hop from its own height: no retract)
            lines.append(f"G0 Z{_num(up_t)}")
        rapid_len += (up_t - int(last[2])) / _SCALE
        prev_xy = (int(last[0]), int(last[1]))
    if coolant is not None:
        lines.append("M9")
    lines.append("M5")
    lines.append("M30")
    n_lines += len(lines)
    text = "\n".join(lines) + "\n"
    time_min = feed_len / feed + plunge_len / plunge
    stats = {
        "passes": len(passes),
        "cut_points": cut_points,
        "cut_moves": cut_moves,
        "feed_length_mm": feed_len,
        "plunge_length_mm": plunge_len,
        "rapid_length_mm": rapid_len,
        "machining_time_min": time_min,
        "n_lines": n_lines,
    }
    return text, stats
