"""The surface seen from its parameter domain: evaluate position, normal and metric at
domain points (METHOD sections 3 and 5: locate the face, interpolate barycentrically).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from conformill.errors import PlanningError
from conformill.geometry.differential import interpolate, normal_curvature, perpendicular_direction, surface_frame
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

    def merged(self, other: "SurfaceSample", new: np.ndarray) -> "SurfaceSample":
        """This sample and ``other`` interleaved: ``other``'s points at the True entries of
        the mask ``new``, this one's at the others, each in its own order."""
        at_old, at_new = np.flatnonzero(~new), np.flatnonzero(new)  # once for the seven fields

        def mix(a, b):
            out = np.empty((len(new),) + a.shape[1:], dtype=a.dtype)
            out[at_old] = a
            out[at_new] = b
            return out
        return SurfaceSample(*(mix(getattr(self, f), getattr(other, f))
                               for f in ("uv", "face", "bary", "xyz", "n", "I", "II")))

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
        # position, normal, I = (E, F, G), II = (L, M, N) side by side: one gather per evaluation
        self._pack = np.ascontiguousarray(np.column_stack([V, fr.n, fr.E, fr.F, fr.G, fr.L, fr.M, fr.N]),
                                          dtype=np.float64)

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
        out = interpolate(self._pack, self.F, face, bary)
        xyz, n, I, II = out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9:12]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return SurfaceSample(uv=P, face=face, bary=bary, xyz=xyz, n=n, I=I, II=II)

