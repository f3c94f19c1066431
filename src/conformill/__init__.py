"""conformill: CNC finishing tool paths on triangle meshes from a conformal parameterization.

Implements and extends Zhao, Zou, Li, Zhou, *Tool path planning based on conformal
parameterization for meshes*, Chinese Journal of Aeronautics 28(5), 2015.
"""

from __future__ import annotations

__version__ = "0.1.0"

from conformill.errors import (  # noqa: E402
    ConformillError,
    GCodeError,
    JobValueError,
    MeshError,
    OutputError,
    ParameterizationError,
    PlanningError,
)
from conformill.types import Mesh, Parameterization, PathParams, Quality, SurfaceFrame, ToolPath  # noqa: E402


def read_mesh(path, scale: float = 1.0):
    """Read and validate a disk-topology triangle mesh; see :func:`conformill.mesh.io.read_mesh`."""
    from conformill.mesh.io import read_mesh as _read

    return _read(path, scale=scale)


def parameterize(mesh, boundary: str = "circle", weights: str = "geodesic", corners=None):
    """Parameterize a disk mesh; see :func:`conformill.param.parameterize`."""
    from conformill.param import parameterize as _param

    return _param(mesh, boundary=boundary, weights=weights, corners=corners)


__all__ = [
    "__version__",
    "ConformillError",
    "GCodeError",
    "JobValueError",
    "MeshError",
    "OutputError",
    "ParameterizationError",
    "PlanningError",
    "Mesh",
    "Parameterization",
    "PathParams",
    "Quality",
    "SurfaceFrame",
    "ToolPath",
    "read_mesh",
    "parameterize",
]
