"""The command line's end (:func:`conformill.cli.main.main_exit`): the exit code, the
``atexit`` handlers and everything printed survive the quick exit that skips the
interpreter's teardown; a running thread is waited for, and a profiler still writes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_PRELUDE = """
import atexit, sys, threading, time
atexit.register(lambda: print("atexit ran", flush=False))
sys.argv = ["conformill"] + sys.argv[1:]
"""


#: stdout to a pipe is block-buffered (what a lost flush would lose), whatever this shell sets
_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}


def _run(code: str, *argv: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _PRELUDE + code, *argv], capture_output=True, text=True,
                          timeout=timeout, env=_ENV)


def test_exit_code_output_and_atexit_after_a_plan(tmp_path):
    out = tmp_path / "p.nc"
    rep = tmp_path / "p.json"
    p = _run("from conformill.cli.main import main_exit\nprint('x' * 100000, end='')\nmain_exit()",
             "plan", "sample:patch", "--tool-radius", "4", "--scallop", "0.3", "-o", str(out), "--report", str(rep))
    assert p.returncode == 0, p.stderr
    # the unflushed print before the plan, the plan's summary and the handler's line all arrive
    assert p.stdout.startswith("x" * 100000)
    assert "time" in p.stdout and p.stdout.rstrip().endswith("atexit ran")
    assert out.read_text().rstrip().endswith("M30") and rep.stat().st_size > 0


@pytest.mark.parametrize(("argv", "code"), [(("--version",), 0), (("plan",), 2),
                                            (("plan", "sample:patch", "--tool-radius", "4", "--scallop", "5",
                                              "-o", "never.nc"), 3)])
def test_exit_codes(tmp_path, argv, code):
    p = subprocess.run([sys.executable, "-m", "conformill", *argv], capture_output=True, text=True, timeout=300,
                       cwd=tmp_path, env=_ENV)
    assert p.returncode == code, p.stderr
    assert "Traceback" not in p.stderr
    assert not (tmp_path / "never.nc").exists()


def test_a_running_thread_is_waited_for():
    code = """
def late():
    time.sleep(1.0)
    print("thread done", flush=True)
threading.Thread(target=late).start()
from conformill.cli.main import main_exit
main_exit()
"""
    p = _run(code, "--version")
    assert p.returncode == 0, p.stderr
    assert "thread done" in p.stdout and "atexit ran" in p.stdout


def test_a_profiler_still_writes_its_results(tmp_path):
    prof = tmp_path / "out.prof"
    p = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "conformill", "--version"],
                       capture_output=True, text=True, timeout=300, env=_ENV)
    assert p.returncode == 0, p.stderr
    assert prof.stat().st_size > 0
