"""Plans checked by the independent simulation (conformill.verify) on analytic parts."""

import numpy as np
import pytest

from conformill.mesh import synthetic
from conformill.output.gcode import write_gcode
from conformill.pipeline import Job, plan
from conformill.verify.gcode import read_gcode
from conformill.verify.simulate import verify


def _check(part, job, tmp_path, n=100_000):
    res = plan(part, job)
    nc = tmp_path / "p.nc"
    write_gcode(nc, res.toolpath, feed=job.feed)
    return res, verify(res.mesh, read_gcode(nc), job.tool_radius, n_samples=n,
                       scallop=1.05 * job.scallop, gouge=job.tolerance).summary


@pytest.mark.parametrize("pattern", ["zigzag", "contour"])
def test_bowl_with_chord_tolerance_equal_to_scallop(pattern, tmp_path):
    """Concave chords ride above the surface: with e = h they must not add to the scallop.

    Measured before forward chords were bounded by h/4: zigzag p99.9 = 1.55 h.
    """
    bowl = synthetic.sphere_cap(R=30.0, radius_xy=18.0, spacing=1.0, concave=True, jitter=0.2)
    _, v = _check(bowl, Job(pattern=pattern, tool_radius=4.0, scallop=0.02, tolerance=0.02), tmp_path)
    assert v["pass"], v["failures"]
    assert v["gouge_max"] <= 0.02


def test_dome_scallop_and_gouge(tmp_path):
    dome = synthetic.sphere_cap(R=40.0, radius_xy=25.0, spacing=1.5, jitter=0.2)
    res, v = _check(dome, Job(pattern="spiral", tool_radius=4.0, scallop=0.1, tolerance=0.01), tmp_path)
    assert v["pass"], v["failures"]
    assert len(res.toolpath.passes) == 1
    assert v["uncut_fraction"] == 0.0 and v["rapid_min_clearance"] >= 0.5
