"""The written programs run through LinuxCNC's own interpreter, ``rs274`` (Debian package
``linuxcnc-uspace``), in batch mode.

Invocation (no INI file, tool table or variable file is needed for these programs)::

    env -u DISPLAY rs274 -g prog.nc out.canon < /dev/null

``-g`` runs the whole file without prompting; ``out.canon`` receives the canonical machine
calls (``STRAIGHT_TRAVERSE(x, y, z, ...)``, ``STRAIGHT_FEED(...)``, ``COMMENT("...")``...);
stdin is closed so that it can never wait for input. On success the exit code is 0 and
stderr holds only the line ``executing``. On an error the exit code is 1 and stderr holds
the message and the offending line, e.g. ``Cannot do g1 with zero feed rate`` /
``G1 X5 Y5``, ``Bad character 'w' used``, ``Nested comment found``, ``File ended with no
percent sign or program end``. ``test_harness_detects_errors`` checks that once per run so
that the other tests can really fail. Skipped when ``rs274`` is not installed.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from conformill.output.gcode import format_gcode, write_gcode
from conformill.types import ToolPath

#: Skips where ``rs274`` is not installed: this module, and the tests of other modules that
#: run programs through :func:`run_rs274`
needs_rs274 = pytest.mark.skipif(shutil.which("rs274") is None, reason="rs274 (linuxcnc-uspace) is not installed")
pytestmark = needs_rs274

_CANON = re.compile(r"(STRAIGHT_TRAVERSE|STRAIGHT_FEED)\(([^)]*)\)")


def run_rs274(program, tmp_path, name="prog"):
    """Run ``rs274`` on a program file; return (exit code, stderr, canon text)."""
    nc = tmp_path / f"{name}.nc"
    if isinstance(program, str):
        nc.write_text(program)
    canon = tmp_path / f"{name}.canon"
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    with open(os.devnull, "rb") as devnull:
        # looked up at the call: rs274 may have been installed after this module was imported
        proc = subprocess.run([shutil.which("rs274"), "-g", str(nc), str(canon)], stdin=devnull, capture_output=True,
                              text=True, env=env, timeout=300)
    text = canon.read_text() if canon.exists() else ""
    return proc.returncode, proc.stdout + proc.stderr, text


def _assert_clean(rc, out):
    assert rc == 0, out
    extra = [ln for ln in out.splitlines() if ln.strip() and ln.strip() != "executing"]
    assert extra == [], out


def _moves(canon):
    kinds, pts = [], []
    for kind, args in _CANON.findall(canon):
        kinds.append(kind)
        pts.append([float(v) for v in args.split(",")[:3]])
    return np.array(kinds), np.array(pts)


def _toolpath(n_passes, k, seed=0, safe_z=30.0):
    rng = np.random.default_rng(seed)
    passes = []
    for i in range(n_passes):
        x = np.linspace(-60, 60, k) * (1 if i % 2 == 0 else -1)
        y = np.full(k, -40.0 + 80.0 * i / max(n_passes - 1, 1))
        z = 5.0 * np.sin(x / 13.0) * np.cos(y / 17.0) + rng.uniform(-0.01, 0.01, k)
        passes.append(np.column_stack([x, y, z]))
    return ToolPath(passes=passes, safe_z=safe_z)


def _check_against_toolpath(canon, tp):
    kinds, P = _moves(canon)
    feed = P[kinds == "STRAIGHT_FEED"]
    np.testing.assert_allclose(feed, np.vstack(tp.passes), atol=0.5e-4 + 1e-9, rtol=0)
    # traverses: at safe Z, or vertical moves up to it
    prev = None
    for kind, p in zip(kinds, P):
        if kind == "STRAIGHT_TRAVERSE":
            assert p[2] >= tp.safe_z - 1e-9
            if prev is not None and prev[2] < tp.safe_z - 1e-9:
                assert p[0] == prev[0] and p[1] == prev[1]  # a retract is vertical
        prev = p


def test_harness_detects_errors(tmp_path):
    bad = "G21 G90\nG0 Z10\nG1 X5 Y5\nM30\n"  # a feed move with no feed rate
    rc, out, _ = run_rs274(bad, tmp_path, "bad")
    assert rc != 0
    assert "Cannot do g1 with zero feed rate" in out
    rc, out, _ = run_rs274("(a (nested) comment)\nG21\nM30\n", tmp_path, "bad2")
    assert rc != 0 and "Nested comment" in out


def test_a_few_passes(tmp_path):
    tp = _toolpath(3, 40)
    write_gcode(tmp_path / "few.nc", tp, feed=1500, plunge_feed=300, spindle=18000,
                header={"mesh": "synthetic", "tool_radius": 4.0})
    rc, out, canon = run_rs274(None, tmp_path, "few")
    _assert_clean(rc, out)
    _check_against_toolpath(canon, tp)
    assert "START_SPINDLE_CLOCKWISE" in canon and "PROGRAM_END" in canon
    assert re.search(r"SET_FEED_RATE\(300\.0+\)", canon) and re.search(r"SET_FEED_RATE\(1500\.0+\)", canon)


def test_long_program(tmp_path):
    tp = _toolpath(40, 5000, seed=1)  # 200k cut moves
    st = write_gcode(tmp_path / "long.nc", tp, feed=2500)
    rc, out, canon = run_rs274(None, tmp_path, "long")
    _assert_clean(rc, out)
    kinds, _ = _moves(canon)
    assert (kinds == "STRAIGHT_FEED").sum() == st["cut_moves"] + st["passes"]
    _check_against_toolpath(canon, tp)


def test_odd_header_values(tmp_path):
    hdr = {
        "name (v2)": "Ærø façade (copy)\nsecond line",
        "debug, x": "(MSG, hello) ; % #<param> [1] ",
        "PROBEOPEN": str(tmp_path / "probe.txt"),
        f"logopen,{tmp_path / 'log.txt'}": "x",
        "empty": "",
        "long": "y" * 2000,
        "nan": float("nan"),
        "array": np.arange(3.0),
        "µ": "∞",
    }
    text = format_gcode(_toolpath(2, 10), feed=800, header=hdr)
    rc, out, canon = run_rs274(text, tmp_path, "odd")
    _assert_clean(rc, out)
    # every header line reached the interpreter as a plain comment, none as an action
    assert canon.count('COMMENT("param ') == len(hdr)
    actions = [ln for ln in canon.splitlines() if "COMMENT(" not in ln]
    for active in ("MESSAGE", "LOG", "PROBE", "PRINT", "DEBUG"):
        assert not [ln for ln in actions if active in ln]
    assert not (tmp_path / "probe.txt").exists() and not (tmp_path / "log.txt").exists()


@pytest.mark.parametrize("blend, mode", [
    (0.0025, r"SET_MOTION_CONTROL_MODE\(CANON_CONTINUOUS, 0\.002500\)"),
    (0.00025, r"SET_MOTION_CONTROL_MODE\(CANON_CONTINUOUS, 0\.000250\)"),
    (0, r"SET_MOTION_CONTROL_MODE\(CANON_EXACT_PATH\)"),
])
def test_path_control_reaches_the_interpreter(tmp_path, blend, mode):
    tp = _toolpath(2, 30)
    write_gcode(tmp_path / "blend.nc", tp, feed=1200, blend=blend)
    rc, out, canon = run_rs274(None, tmp_path, "blend")
    _assert_clean(rc, out)
    assert re.search(mode, canon)
    if blend:  # Q0: LinuxCNC's naive-CAM detector is off, so no move is merged away
        assert re.search(r"SET_NAIVECAM_TOLERANCE\(0\.0+\)", canon)
    # set before the first motion
    first_move = min(canon.index("STRAIGHT_TRAVERSE"), canon.index("STRAIGHT_FEED"))
    assert re.search(mode, canon[:first_move])
    _check_against_toolpath(canon, tp)


def test_tool_number_reaches_the_interpreter(tmp_path):
    tp = _toolpath(2, 30)
    write_gcode(tmp_path / "tool.nc", tp, feed=1200, blend=0.005, tool=3)
    rc, out, canon = run_rs274(None, tmp_path, "tool")
    _assert_clean(rc, out)
    first_move = min(canon.index("STRAIGHT_TRAVERSE"), canon.index("STRAIGHT_FEED"))
    head = canon[:first_move]
    # the change, then the length offset of tool 3 (rs274's built-in table gives it a length)
    last = head.rindex("USE_TOOL_LENGTH_OFFSET")
    assert head.index("CHANGE_TOOL(3)") < last
    z_offset = float(re.match(r"USE_TOOL_LENGTH_OFFSET\(\S+ \S+ (\S+),", head[last:]).group(1))
    assert z_offset != 0.0  # G43 H3 applied a length (G49 in the preamble had set 0)
    _check_against_toolpath(canon, tp)


@pytest.mark.parametrize("coolant, on, off", [("flood", "FLOOD_ON", "FLOOD_OFF"), ("mist", "MIST_ON", "MIST_OFF")])
def test_coolant_reaches_the_interpreter(tmp_path, coolant, on, off):
    tp = _toolpath(2, 30)
    write_gcode(tmp_path / "cool.nc", tp, feed=1200, spindle=9000, coolant=coolant)
    rc, out, canon = run_rs274(None, tmp_path, "cool")
    _assert_clean(rc, out)
    first_feed, last_feed = canon.index("STRAIGHT_FEED"), canon.rindex("STRAIGHT_FEED")
    assert canon.index("START_SPINDLE_CLOCKWISE") < canon.index(on) < first_feed
    assert canon.rindex(off) > last_feed
    _check_against_toolpath(canon, tp)
