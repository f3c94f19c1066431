"""The first run's helper process (:mod:`conformill.warm`): it must cache exactly the
kernels the plan then loads, find numba's cache as numba does, and start only when it can
help."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numba
import numpy as np
import pytest

from conformill import warm


@pytest.mark.parametrize("module,name", [q for p in warm.PROBES.values() for q in p])
def test_stand_in_finds_numbas_own_index(module, name):
    # the index file numba itself uses for the kernel: same path (so the same cache entry)
    import importlib

    kernel = getattr(importlib.import_module(module), name)
    assert warm._stand_in_cache(module, name)._cache_file._index_path == kernel._cache._cache_file._index_path


def test_unknown_kernel_counts_as_cached():
    assert warm._cached("conformill.cutter", "_no_such_kernel")
    assert warm._cached("conformill.no_such_module", "_worst_points")


def test_nothing_needed_without_jit(monkeypatch):
    monkeypatch.setenv("NUMBA_DISABLE_JIT", "1")
    assert not warm.needed()


def test_empty_cache_needs_every_part(tmp_path):
    code = ("from conformill import warm; "
            "print(warm.needed(('cutter',)), warm.needed(('verify',)), warm.needed(('holder',)))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("NUMBA_DISABLE_JIT", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True", "True"]


def test_one_thread_starts_nothing():
    warm.stop()  # none left from another test
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert not warm.start()
        assert warm._proc is None
    finally:
        numba.set_num_threads(before)


_PLAN = r"""
import json, sys
from numba.core import event
compiled = []

class Listen(event.Listener):
    def on_start(self, e):
        d = e.data["dispatcher"]
        compiled.append(d.py_func.__module__ + "." + d.py_func.__qualname__)

    def on_end(self, e):
        pass

event.register("numba:compile", Listen())
from conformill.cli.main import main

rc = main(["plan", sys.argv[1], "--pattern", "contour", "--tool-radius", "4", "--scallop", "0.05", "-o", sys.argv[2],
           "-q", "--verify", "--verify-samples", "3000", "--threads", "1", "--holder-radius", "6", "--stick-out", "40"])
print(json.dumps({"rc": rc, "compiled": compiled}))
"""


@pytest.mark.slow
def test_helper_caches_what_the_plan_loads(tmp_path):
    """On an empty cache, the helper's work leaves nothing of the cutter, the verifier or the
    holder check for ``conformill plan --verify --holder-radius`` to compile: same kernels,
    same argument types."""
    import trimesh

    from conformill.mesh.synthetic import v_groove

    # a groove: the moves across its crease float above the drop surface, so the plan's
    # settle runs its tangent search too (a dome alone never calls it)
    m = v_groove(a_deg=20.0, half=15.0, step=0.5)
    part = tmp_path / "groove.ply"
    trimesh.Trimesh(m.V - np.array([0.0, 0.0, m.V[:, 2].max()]), m.F, process=False).export(part)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("NUMBA_DISABLE_JIT", None)
    subprocess.run([sys.executable, "-m", "conformill.warm", "cutter", "verify", "holder"], env=env, check=True,
                   capture_output=True, timeout=600)
    run = subprocess.run([sys.executable, "-c", _PLAN, str(part), str(tmp_path / "groove.nc")], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["rc"] in (0, 1)  # a small part may fail the scallop check; the program is written
    late = [k for k in got["compiled"]
            if k.startswith(("conformill.cutter.", "conformill.verify.simulate.", "conformill.verify.holder."))]
    assert late == [], f"compiled again in the plan: {late}"
    assert any(k.startswith("conformill.") for k in got["compiled"])  # the listener works: earlier stages compiled


def _part_files(tmp_path):
    """The helper's groove as a PLY and a short program along its crease (G-code)."""
    import trimesh

    mesh = warm._tiny_part()
    part = tmp_path / "groove.ply"
    trimesh.Trimesh(mesh.V, mesh.F, process=False).export(part)
    prog = tmp_path / "line.nc"
    prog.write_text("G21 G90 G17\nG0 Z20\nG0 X0 Y-5\nG1 Z1 F300\nG1 Z0.5\nG1 Y5 F1000\nG0 Z20\nM2\n")
    return part, prog


@pytest.mark.parametrize("extra,parts", [([], ("cutter",)), (["--verify", "--verify-samples", "500"],
                                                           ("cutter", "verify")),
                                         (["--holder-radius", "6"], ("cutter", "holder"))])
def test_plan_asks_for_the_parts_it_uses(monkeypatch, tmp_path, extra, parts):
    from conformill.cli.main import main

    asked = []
    monkeypatch.setattr(warm, "start", lambda p=warm.PARTS: asked.append(tuple(p)) or False)
    part, _ = _part_files(tmp_path)
    rc = main(["plan", str(part), "--tool-radius", "4", "--scallop", "0.2", "-o", str(tmp_path / "p.nc"), "-q",
               *extra])
    assert rc in (0, 1) and asked == [parts]


@pytest.mark.parametrize("extra,parts", [([], []), (["--judge", "reachable"], [("cutter",)]),
                                         (["--rest", "--scallop", "0.1"], [("cutter",)]),
                                         (["--holder-radius", "6"], [("holder",)]),
                                         (["--holder-radius", "6", "--judge", "reachable"], [("cutter", "holder")])])
def test_verify_asks_for_the_cutter_when_it_drops_the_ball(monkeypatch, tmp_path, extra, parts):
    from conformill.cli.main import main

    asked = []
    monkeypatch.setattr(warm, "start", lambda p=warm.PARTS: asked.append(tuple(p)) or False)
    part, prog = _part_files(tmp_path)
    rc = main(["verify", str(part), str(prog), "--tool-radius", "4", "--samples", "500", "-q", *extra])
    assert rc in (0, 1) and asked == parts
