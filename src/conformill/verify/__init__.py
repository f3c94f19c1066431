"""Independent verification of a 3-axis ball-end program on a part.

- :func:`conformill.verify.gcode.read_gcode` reads RS274 G-code into tool-tip positions
  (:class:`~conformill.verify.gcode.Program`).
- :func:`conformill.verify.simulate.verify` sweeps the ball along the feed moves and
  measures remaining material (scallop), gouges, uncut area and rapid clearance at
  area-uniform samples of the mesh.

Nothing here imports the planner, so the check can catch its mistakes.
"""

from conformill.verify.gcode import FEED, RAPID, Program, read_gcode

__all__ = ["Program", "read_gcode", "RAPID", "FEED", "verify"]


def verify(*args, **kwargs):
    """See :func:`conformill.verify.simulate.verify` (imported lazily: it compiles numba kernels)."""
    from conformill.verify.simulate import verify as _verify

    return _verify(*args, **kwargs)
