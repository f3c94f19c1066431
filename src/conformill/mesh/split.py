"""Split every triangle into four at its edge midpoints: the same surface at half the scale.

A planar split: each new vertex is the midpoint of an edge, so the split mesh is the input
surface point for point (its facets lie in the input's facets) and a drop-cutter sees the
same heights on both. What changes is the scale of anything fitted per vertex over a
1-ring: the per-vertex quadratic (:func:`conformill.geometry.differential.surface_frame`)
then works at half the edge length (on chords: about twice the curvature at the input's
vertices, see ``Job.fit``).
"""

from __future__ import annotations

import numpy as np

from conformill.errors import MeshError

__all__ = ["split_midpoints"]


def split_midpoints(V: np.ndarray, F: np.ndarray, uv: np.ndarray | None = None):
    """The mesh with every triangle split into four at its edge midpoints.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    uv : (n, 2) float64, optional
        Parameter coordinates, carried to the midpoints linearly (the split parameter mesh
        is the same piecewise-linear map).

    Returns
    -------
    Vs : (n + e, 3) float64
        ``V`` first, then one midpoint per edge (``e`` edges).
    Fs : (4 m, 3) int64
        Triangles wound as their parent.
    uvs : (n + e, 2) float64 or None
        ``uv`` at the split vertices (None without ``uv``).

    Raises
    ------
    MeshError
        Bad shapes or face indices outside the vertices.
    """
    import trimesh  # >= 4.5.3: earlier 4.x put the attributes of the midpoints on the wrong edges

    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"split_midpoints: V must be (n, 3) and F (m, 3), got {V.shape} and {F.shape}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise MeshError(f"split_midpoints: face indices outside [0, {len(V)})")
    if uv is not None:
        uv = np.ascontiguousarray(uv, dtype=np.float64)
        if uv.shape != (len(V), 2):
            raise MeshError(f"split_midpoints: uv must be ({len(V)}, 2) to match V, got {uv.shape}")
    if len(F) == 0:
        return V.copy(), F.copy(), (None if uv is None else uv.copy())
    if uv is None:
        Vs, Fs = trimesh.remesh.subdivide(V, F)
        uvs = None
    else:
        Vs, Fs, attr = trimesh.remesh.subdivide(V, F, vertex_attributes={"uv": uv})
        uvs = np.ascontiguousarray(attr["uv"], dtype=np.float64)
    return (np.ascontiguousarray(Vs, dtype=np.float64), np.ascontiguousarray(Fs, dtype=np.int64), uvs)
