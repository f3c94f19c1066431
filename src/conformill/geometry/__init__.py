"""geometry stage: differential properties of the parameterized mesh and point location.

- :mod:`conformill.geometry.differential`: per-vertex quadratic fit (METHOD section 3),
  fundamental forms, normal curvature, barycentric interpolation.
- :mod:`conformill.geometry.locate`: domain point -> face + barycentrics, CC points and
  normals on the mesh (METHOD section 5).
"""

from conformill.geometry.differential import (
    frame_normal_curvature,
    interpolate,
    interpolate_frame,
    normal_curvature,
    perpendicular_direction,
    surface_frame,
    vertex_normals,
)
from conformill.geometry.locate import Locator, map_normals, map_points

__all__ = [
    "surface_frame",
    "vertex_normals",
    "interpolate",
    "interpolate_frame",
    "normal_curvature",
    "frame_normal_curvature",
    "perpendicular_direction",
    "Locator",
    "map_points",
    "map_normals",
]
