"""Every compiled kernel has one compiled version.

A kernel called with a literal argument (``-1``, ``True``), an omitted default, an int32
where another call passes an int64, or a read-only array is compiled once more for each
such variant, and a fresh install compiles every variant before its first plan (session
28: ``_drop_point`` three times, ``_tri_drop`` three, ``_fit_one`` three; the quick start's
first run about 20 % longer). Plans through the pipeline's stages (three patterns; both
pencil searches, the pencil's filter and the fill; hops; adaptive, local and paper spacing;
the split fit; G-code; verify with and without the rest search) must leave each kernel with
at most one. Paths not run here (the ``view`` and ``param`` commands, other weights) are not
checked.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import subprocess
import sys

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

import conformill
from conformill.mesh import synthetic
from conformill.output.gcode import write_gcode
from conformill.pipeline import Job, plan
from conformill.verify.gcode import read_gcode
from conformill.verify.simulate import verify


def _kernels():
    """``name -> dispatcher`` for every numba kernel defined in conformill's modules."""
    out = {}
    for info in pkgutil.walk_packages(conformill.__path__, "conformill."):
        if info.name.endswith("__main__"):  # (runs the command line on import)
            continue
        mod = importlib.import_module(info.name)
        for name, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == mod.__name__:
                out[f"{mod.__name__}.{name}"] = obj
    return out


def _plan_every_stage(tmp):
    """Plans, G-code and verify through every stage; the kernels compiled more than once."""
    part = synthetic.v_groove(a_deg=60.0, half=12.0, step=0.5)
    for pattern, extra in (("zigzag", dict(pencil=True, pencil_search="samples", pencil_density=2.0)),
                           ("contour", dict(pencil=True, pencil_search="folds", pencil_density=2.0, hop_lift=0.5,
                                            pencil_left=0.5, fill=0.7)),
                           ("spiral", dict(spacing="local")),
                           ("zigzag", dict(spacing="paper", fit="split"))):
        res = plan(part, Job(pattern=pattern, tool_radius=4.0, scallop=0.05, tolerance=0.01, **extra))
        path = os.path.join(tmp, f"{pattern}.nc")
        write_gcode(path, res.toolpath, feed=1000.0)
        v = verify(part, read_gcode(path), 4.0, n_samples=5000, seed=0, gouge=0.01, rest=pattern == "spiral")
        assert np.isfinite(v.summary["gouge_max"])
    kernels = _kernels()
    assert "conformill.cutter._drop_point" in kernels  # the walk found the modules
    return {name: [str(s) for s in d.overloads] for name, d in kernels.items() if len(d.overloads) > 1}


@pytest.mark.slow
def test_every_stage_leaves_one_compiled_version_per_kernel(tmp_path):
    # in a child with an empty numba cache: a kernel loaded from the cache does not compile
    # (nor count) the kernels it calls, so only a cold start shows the extra versions
    # (NUMBA_OPT=0: the same typing, so the same versions, in less compile time)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"), NUMBA_OPT="0")
    env.pop("NUMBA_DISABLE_JIT", None)
    here = os.path.dirname(os.path.abspath(__file__))
    code = ("import sys; sys.path.insert(0, sys.argv[2]); import test_kernels; "
            "many = test_kernels._plan_every_stage(sys.argv[1]); print(many); sys.exit(1 if many else 0)")
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path), here], cwd=here, env=env,
                         capture_output=True, text=True, timeout=900)
    out = run.stdout.strip().splitlines()
    assert run.returncode == 0, (f"kernels compiled more than once: {out[-1]}" if out
                                 else f"the child failed: {run.stderr[-3000:]}")
