"""The first run's compiling, shared with a second process.

numba compiles each kernel the first time it is called and caches it on disk
(``cache=True``); a fresh install's first ``conformill plan`` spends about 50 s doing so,
on one core (numba compiles under one lock). The pipeline needs the cutter's kernels
only once the pattern stage has started, and the verifier's at the very end. So when
those kernels are not cached yet, :func:`start` runs ``python -m conformill.warm`` beside
the plan: it calls the cutter and the verifier on a small groove, in that order, which
compiles and caches the same kernels (the same argument types: the public methods are
called, as the pipeline calls them), while the plan compiles its first stages. The plan
then loads them from the cache. The programs are the same bytes; only the cache is
shared. Session 29, the quick start on an empty cache: 30.2-30.6 s wall against 50.0 s
with ``--threads 1``, which starts no helper (README, "Limits").
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
from contextlib import contextmanager

import numpy as np

__all__ = ["beside", "needed", "start", "stop", "warm"]

#: What the helper process compiles, in this order.
PARTS = ("cutter", "verify", "holder")

#: The helper's part: a V-groove with walls at this slope (deg).
_WALL_DEG = 20.0

_proc: subprocess.Popen | None = None
_at_exit = False  # stop() registered with atexit


def _stand_in_cache(module: str, name: str):
    """numba's ``FunctionCache`` for kernel ``name`` of ``module``, made as numba makes it
    (same source file and first line, hence the same index file, stale when the file
    changed) without importing the module: importing ``conformill.cutter`` compiles its
    kernels that have explicit signatures, which is the helper's work."""
    from importlib.util import find_spec

    from numba.core.caching import FunctionCache

    src = find_spec(module).origin
    with open(src, encoding="utf-8") as f:
        lines = f.read().splitlines()
    at = next(i for i, t in enumerate(lines) if t.startswith(f"def {name}("))
    while at > 0 and lines[at - 1].startswith("@"):  # the code starts at the first decorator
        at -= 1

    def stand_in():  # pragma: no cover - never called
        pass

    stand_in.__code__ = stand_in.__code__.replace(co_filename=src, co_firstlineno=at + 1)
    stand_in.__qualname__ = stand_in.__name__ = name
    return FunctionCache(stand_in)


def _cached(module: str, name: str) -> bool:
    """Whether numba's disk cache holds a current entry for kernel ``name`` of ``module``
    (:func:`_stand_in_cache`). Unknown (numba's cache internals differ, no such kernel)
    counts as cached: nothing is started then."""
    try:
        return len(_stand_in_cache(module, name)._cache_file._load_index()) > 0
    except Exception:  # noqa: BLE001 - any surprise: do not warm
        return True


#: The kernels asked by :func:`needed` (the largest of each part), as (module, name).
PROBES = {"cutter": (("conformill.cutter", "_refine_moves"), ("conformill.cutter", "_highest_floats")),
          "verify": (("conformill.verify.simulate", "_pairs_d2"), ("conformill.verify.simulate", "_cast")),
          "holder": (("conformill.verify.holder", "_all"), ("conformill.verify.holder", "_coarse"))}


def needed(parts=PARTS) -> bool:
    """Whether any of ``parts`` has a kernel numba has not cached yet (the largest of each
    part are asked)."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    probes = [q for p in parts for q in PROBES.get(p, ())]
    return not all(_cached(m, n) for m, n in probes)


def start(parts=PARTS) -> bool:
    """Start the helper process for ``parts`` if their kernels are not cached and numba may
    use two or more threads here (at most one helper at a time); returns whether one runs.
    It is stopped by :func:`stop` or when this process exits."""
    global _proc, _at_exit
    parts = tuple(p for p in parts if p in PARTS)
    if _proc is not None or not parts:
        return _proc is not None
    import numba

    if numba.get_num_threads() < 2 or not needed(parts):  # one core (or --threads 1): nothing to share
        return False
    env = dict(os.environ, NUMBA_NUM_THREADS="1")  # its calls are tiny: one core is the point
    try:
        _proc = subprocess.Popen([sys.executable, "-m", "conformill.warm", *parts], env=env,
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        _proc = None
        return False
    if not _at_exit:
        atexit.register(stop)
        _at_exit = True
    return True


@contextmanager
def beside(parts=PARTS):
    """:func:`start` the helper for ``parts`` (none: nothing), :func:`stop` it on leaving."""
    if parts:
        start(parts)
    try:
        yield
    finally:
        stop()


def stop() -> None:
    """Stop the helper process if it still runs (what it cached so far stays cached)."""
    global _proc
    p, _proc = _proc, None
    if p is not None and p.poll() is None:
        p.terminate()
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:  # pragma: no cover - a stuck helper
            p.kill()
            p.wait()


def _tiny_part():
    """A V-groove of 576 triangles (mm, walls at 20 deg): the moves across its crease float
    above the drop surface, so the settle's tangent search runs too (a dome alone never
    calls it; ``tests/test_warm.py`` caught that)."""
    from conformill.mesh.synthetic import v_groove

    return v_groove(a_deg=_WALL_DEG, half=6.0, step=0.5)


def _cutter(mesh, r: float) -> np.ndarray:
    """The pass builder's calls (:mod:`conformill.passes`) on a line across the groove;
    returns the centres of one settled, refined pass."""
    from conformill.cutter import BallCutter

    cut = BallCutter(mesh.V, mesh.F, r)
    x = np.linspace(-5.0, 5.0, 21)
    slope = np.tan(np.radians(_WALL_DEG))
    cc = np.column_stack([x, np.zeros_like(x), np.abs(x) * slope])
    nn = np.column_stack([-np.sign(x) * slope, np.zeros_like(x), np.ones_like(x)])
    centres, lift, tri = cut.cl_from_cc(cc, nn, contacts=True)
    pcs, _, _, _ = cut.settle_pieces([centres], 0.005, contacts=[tri])
    pcs = cut.refine_pieces(pcs, 0.01)
    cut.clear_height(centres[:-1, :2], centres[1:, :2], 1.0)
    return pcs[0]


def _program(mesh, centres, r: float):
    """A short program along ``centres`` (tips ``r`` below), written and read back as
    ``conformill plan`` reads its own."""
    import tempfile
    from pathlib import Path

    from conformill.verify.gcode import read_gcode

    # written here, not by conformill.output.gcode: its kernels would delay the verifier's
    tip = centres - np.array([0.0, 0.0, r])
    top = float(mesh.V[:, 2].max()) + 10.0
    lines = ["G21 G90 G17", f"G0 Z{top:.4f}", f"G0 X{tip[0, 0]:.4f} Y{tip[0, 1]:.4f}", "M3 S10000",
             f"G1 Z{tip[0, 2]:.4f} F300"]
    lines += [f"G1 X{p[0]:.4f} Y{p[1]:.4f} Z{p[2]:.4f} F1000" for p in tip[1:]]
    lines += [f"G0 Z{top:.4f}", "M5", "M2"]
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "warm.nc"
        f.write_text("\n".join(lines) + "\n")
        return read_gcode(f)


def _verify(mesh, program, r: float) -> None:
    """``conformill plan --verify``'s check of a short program."""
    from conformill.verify.simulate import verify

    verify(mesh, program, r, n_samples=2000, scallop=0.0105, gouge=0.01, judge="reachable")


def _holder(mesh, program, r: float) -> None:
    """``--holder-radius``'s check of a short program, with a stick-out it cannot clear
    (every pass of the check runs)."""
    from conformill.verify.holder import holder_clearance

    holder_clearance(mesh.V, mesh.F, program, r + 2.0, stick_out=0.5)


def warm(parts=PARTS) -> None:
    """Compile (or load) the kernels of ``parts`` by calling them on a tiny part."""
    r = 4.0
    mesh = _tiny_part()
    if "cutter" in parts:
        centres = _cutter(mesh, r)
    else:  # a line above the crease: the checks compile the same on any program
        x = np.linspace(-5.0, 5.0, 21)
        centres = np.column_stack([x, np.zeros_like(x), np.abs(x) * np.tan(np.radians(_WALL_DEG)) + r])
    if "verify" in parts or "holder" in parts:
        program = _program(mesh, centres, r)
        if "verify" in parts:
            _verify(mesh, program, r)
        if "holder" in parts:
            _holder(mesh, program, r)


if __name__ == "__main__":  # pragma: no cover - run as the helper process
    warm(tuple(sys.argv[1:]) or PARTS)
