"""Area-uniform random samples of a triangle mesh, with normals and distance to the boundary.

The verification measures the part at these samples. Every sample lies exactly on a
triangle, so the figures refer to the mesh as given (its facets), not to a smoothed
surface.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from conformill.errors import MeshError
from conformill.geometry.locate import pick_faces

__all__ = ["SurfaceSamples", "sample_surface", "boundary_edges", "vertex_normals"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class SurfaceSamples:
    """Points on a surface with unit normals (towards the tool) and boundary distance.

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64
        Unit normals pointing to the side the tool comes from.
    face : (n,) int64
        Triangle of each sample (-1 when the samples did not come from a mesh).
    boundary_distance : (n,) float64
        3D (Euclidean) distance from each sample to the mesh boundary polyline, mm
        (``inf`` when there is no boundary or it is farther than the bound asked for).
    area : float
        Area the samples stand for (mm^2); each sample weighs ``area / n``.
    """

    points: np.ndarray
    normals: np.ndarray
    face: np.ndarray = field(repr=False)
    boundary_distance: np.ndarray = field(repr=False)
    area: float = 0.0

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def offset(self, distance: float) -> "SurfaceSamples":
        """The samples moved ``distance`` (mm) along their normals: on the surface offset by
        it (the part with its stock; negative: into the part). ``0`` gives ``self``."""
        d = float(distance)
        return self if d == 0.0 else replace(self, points=self.points + d * self.normals)

    @classmethod
    def from_arrays(cls, points, normals, boundary_distance=None, area: float = 0.0) -> "SurfaceSamples":
        """Samples given directly (e.g. exact points of an analytic surface, in tests)."""
        P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        N = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
        if N.shape != P.shape:
            raise MeshError(f"normals {N.shape} do not match points {P.shape}")
        N = N / np.linalg.norm(N, axis=1, keepdims=True)
        bd = np.full(len(P), np.inf) if boundary_distance is None else np.asarray(boundary_distance, float)
        return cls(P, N, np.full(len(P), -1, dtype=np.int64), bd, float(area))


def _face_normals(V, F):
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # length = 2 * area


def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (sum of the adjacent faces' ``cross`` products), unit.

    Returns
    -------
    (n, 3) float64
    """
    Fn = _face_normals(V, F)
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], Fn)
    L = np.linalg.norm(N, axis=1, keepdims=True)
    return N / np.where(L > 0, L, 1.0)


def boundary_edges(F: np.ndarray) -> np.ndarray:
    """Edges used by exactly one triangle, ``(b, 2)`` int64 (any order)."""
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(E, axis=0, return_counts=True)
    return uniq[counts == 1]


def _boundary_distance(V, F, P, spacing, max_distance):
    """Distance from ``P`` to the boundary edges, sampled at ``spacing`` (error <= spacing/2).

    Distances beyond ``max_distance`` are ``inf`` (a bounded query is much faster).
    """
    be = boundary_edges(F)
    if len(be) == 0:
        return np.full(len(P), np.inf)
    a, b = V[be[:, 0]], V[be[:, 1]]
    L = np.linalg.norm(b - a, axis=1)
    k = np.maximum(1, np.ceil(L / spacing).astype(np.int64))
    idx = np.repeat(np.arange(len(be)), k)
    start = np.cumsum(k) - k
    t = (np.arange(k.sum()) - np.repeat(start, k)) / np.repeat(k, k)
    pts = a[idx] + t[:, None] * (b - a)[idx]
    d, _ = cKDTree(pts).query(P, workers=-1, distance_upper_bound=max_distance)
    return d


def sample_surface(V: np.ndarray, F: np.ndarray, n: int, seed: int = 0, normals: str = "vertex",
                   boundary_spacing: float = 0.1, boundary_max: float = np.inf) -> SurfaceSamples:
    """Area-uniform random points on a triangle mesh.

    A face is drawn with probability proportional to its area, then a point uniform in the
    triangle with ``(1 - sqrt(u)) a + sqrt(u) (1 - v) b + sqrt(u) v c``.

    Parameters
    ----------
    V : (nv, 3) float64
    F : (m, 3) int64
    n : int
        Number of samples.
    seed : int
        Seed of ``numpy.random.default_rng``: the same seed gives the same samples.
    normals : {"vertex", "face"}
        ``"vertex"``: area-weighted vertex normals interpolated with the barycentric
        coordinates (a smooth direction across facets); ``"face"``: the facet's normal.
        Normals follow the face orientation; if the area-weighted mean normal points to
        -Z all normals are flipped (the tool comes from +Z) and a warning is logged.
    boundary_spacing : float
        Sampling step (mm) of the boundary polyline for the boundary distance (its error
        is at most half of it).
    boundary_max : float
        Boundary distances above this are stored as ``inf`` (only "farther than" matters
        to the verification; bounding the query makes it fast).

    Returns
    -------
    SurfaceSamples

    Raises
    ------
    MeshError
        No faces, zero total area, bad ``n`` or ``normals``.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if normals not in ("vertex", "face"):
        raise MeshError(f"normals must be 'vertex' or 'face', got {normals!r}")
    if int(n) < 1:
        raise MeshError(f"the number of samples must be >= 1, got {n}")
    if len(F) == 0:
        raise MeshError("the mesh has no faces")
    Fn = _face_normals(V, F)
    area2 = np.linalg.norm(Fn, axis=1)
    total = float(area2.sum()) / 2
    if not total > 0:
        raise MeshError("the mesh has zero area")
    flip = float(Fn[:, 2].sum()) < 0
    if flip:
        log.warning("mesh normals point to -Z on average: flipped so that they face the tool (+Z)")
    rng = np.random.default_rng(seed)
    cdf = np.cumsum(area2)
    face = pick_faces(cdf, rng.random(int(n)) * cdf[-1])
    face = np.minimum(face, len(F) - 1)
    su = np.sqrt(rng.random(int(n)))
    v = rng.random(int(n))
    w0, w1, w2 = 1 - su, su * (1 - v), su * v
    tri = F[face]
    P = w0[:, None] * V[tri[:, 0]] + w1[:, None] * V[tri[:, 1]] + w2[:, None] * V[tri[:, 2]]
    if normals == "vertex":
        VN = vertex_normals(V, F)
        N = w0[:, None] * VN[tri[:, 0]] + w1[:, None] * VN[tri[:, 1]] + w2[:, None] * VN[tri[:, 2]]
        L = np.linalg.norm(N, axis=1)
        bad = L < 1e-12
        N[bad] = Fn[face[bad]]
        N /= np.linalg.norm(N, axis=1, keepdims=True)
    else:
        N = Fn[face] / area2[face, None]
    if flip:
        N = -N
    bd = _boundary_distance(V, F, P, boundary_spacing, boundary_max)
    return SurfaceSamples(P, N, face.astype(np.int64), bd, total)
