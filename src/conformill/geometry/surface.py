"""The surface seen from its parameter domain: evaluate position, normal and metric at
domain points (METHOD sections 3 and 5: locate the face, interpolate barycentrically).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from conformill.errors import PlanningError
from conformill.geometry.differential import normal_curvature, perpendicular_direction, surface_frame
from conformill.geometry.locate import Locator


@dataclass(frozen=True, eq=False)
class SurfaceSample:
    """The surface at ``k`` domain points.

    ``xyz`` are points on the mesh (CC points), ``n`` unit normals towards the tool
    interpolated from the per-vertex fit, ``I`` the first fundamental form
    ``(E, F, G)`` and ``II`` the second ``(L, M, N)``, each ``(k, 3)``.
    """

    uv: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    xyz: np.ndarray
    n: np.ndarray
    I: np.ndarray
    II: np.ndarray

    def length(self, d: np.ndarray) -> np.ndarray:
        """3D length per unit domain length in domain direction ``d (k, 2)``: sqrt(d^T I d)."""
        E, F, G = self.I.T
        return np.sqrt(np.maximum(E * d[:, 0] ** 2 + 2 * F * d[:, 0] * d[:, 1] + G * d[:, 1] ** 2, 0.0))

    def curvature(self, d: np.ndarray) -> np.ndarray:
        """Normal curvature in domain direction ``d (k, 2)`` (METHOD section 3).

        Positive: the surface curves towards the tool (concave); negative: convex.
        """
        return normal_curvature(*self.I.T, *self.II.T, d[:, 0], d[:, 1])

    def area_factor(self) -> np.ndarray:
        """sqrt(EG - F^2): surface area per unit domain area."""
        E, F, G = self.I.T
        return np.sqrt(np.maximum(E * G - F * F, 1e-300))

    def across(self, t: np.ndarray) -> np.ndarray:
        """Domain direction whose surface image is perpendicular to the path ``t (k, 2)``."""
        du, dv = perpendicular_direction(*self.I.T, t[:, 0], t[:, 1])
        return np.column_stack([du, dv])


class DomainSurface:
    """Evaluate a parameterized mesh at arbitrary domain points.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    uv : (n, 2) float64
        A bijective parameterization (no flipped faces).

    Notes
    -----
    Builds the per-vertex frame (:func:`conformill.geometry.differential.surface_frame`)
    and the point locator once; :meth:`sample` is vectorized over points.
    """

    def __init__(self, V: np.ndarray, F: np.ndarray, uv: np.ndarray, frame=None):
        self.V = V
        self.F = F
        self.uv = uv
        self.frame = surface_frame(V, F, uv) if frame is None else frame
        self.locator = Locator(uv, F)
        fr = self.frame
        self._I = np.column_stack([fr.E, fr.F, fr.G])
        self._II = np.column_stack([fr.L, fr.M, fr.N])
        # position, normal, I, II side by side: one gather per evaluation
        self._pack = np.ascontiguousarray(np.hstack([V, fr.n, self._I, self._II]), dtype=np.float64)
        self._F = np.ascontiguousarray(F, dtype=np.int64)

    def sample(self, P: np.ndarray) -> SurfaceSample:
        """The surface at domain points ``P (k, 2)``.

        Raises
        ------
        PlanningError
            A point lies outside the domain mesh (a planner bug or a hole in the map).
        """
        P = np.asarray(P, dtype=np.float64).reshape(-1, 2)
        face, bary = self.locator.locate(P)
        bad = np.flatnonzero(face < 0)
        if bad.size:
            raise PlanningError(
                f"{bad.size} domain point(s) fall outside the parameter mesh, e.g. "
                f"{P[bad[0]].round(6).tolist()}"
            )
        out = _interp_rows(self._pack, self._F, face, np.ascontiguousarray(bary, dtype=np.float64))
        xyz, n, I, II = out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return SurfaceSample(uv=P, face=face, bary=bary, xyz=xyz, n=n, I=I, II=II)


@njit(cache=True)
def _interp_rows(values, F, face, bary):
    """``out[p] = sum_k bary[p, k] values[F[face[p], k]]`` for all columns (faces >= 0)."""
    k, c = face.shape[0], values.shape[1]
    out = np.empty((k, c))
    for p in range(k):
        f = face[p]
        a, b, d = F[f, 0], F[f, 1], F[f, 2]
        w0, w1, w2 = bary[p, 0], bary[p, 1], bary[p, 2]
        for j in range(c):
            out[p, j] = w0 * values[a, j] + w1 * values[b, j] + w2 * values[d, j]
    return out
