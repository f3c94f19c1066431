"""The surface seen from its parameter domain: evaluate position, normal and metric at
domain points (METHOD sections 3 and 5: locate the face, interpolate barycentrically).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from conformill.errors import PlanningError
from conformill.geometry.differential import curvature_in, perpendicular_direction, surface_frame
from conformill.geometry.locate import Locator, _locate_one

#: Stand-in for the kept rows of a sample that keeps none (:meth:`DomainSurface.sample`):
#: a C-contiguous ``(1, 3)`` array (never read), typed as the kept rows of a real sample
#: are, so that one compiled kernel serves both calls.
_NONE_KEPT = np.zeros((1, 3))


@njit(cache=True, nogil=True, error_model="numpy")
def _curvature_rows(I, II, d):
    """:func:`conformill.geometry.differential.normal_curvature` of each row of ``I``, ``II``
    (``(k, 3)``) in the direction ``d[i]``: the same arithmetic, without eight column copies
    per call (the forward steps call it once per piece)."""
    out = np.empty(I.shape[0])
    for i in range(I.shape[0]):
        out[i] = curvature_in(I[i, 0], I[i, 1], I[i, 2], II[i, 0], II[i, 1], II[i, 2], d[i, 0], d[i, 1])
    return out


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
        c = np.ascontiguousarray
        d = c(np.broadcast_to(np.asarray(d, dtype=np.float64), (len(self.I), 2)))  # (one direction for all)
        return _curvature_rows(c(self.I, dtype=np.float64), c(self.II, dtype=np.float64), d)

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
    and the point locator once; :meth:`sample` is vectorized over points. Where numba may
    use two or more threads, the locator's grid (one serial kernel that releases the GIL)
    is built in a second thread while the frame is fitted: the same locator, and the
    frame's error first where both would fail (620k faces: 0.21 s of the stage's 0.5-0.8 s).
    """

    def __init__(self, V: np.ndarray, F: np.ndarray, uv: np.ndarray, frame=None):
        import numba

        self.V = V
        self.F = F
        self.uv = uv
        if frame is None and numba.get_num_threads() > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(1, thread_name_prefix="conformill-locator") as pool:
                built = pool.submit(Locator, uv, F)
                self.frame = surface_frame(V, F, uv)
                self.locator = built.result()
        else:
            self.frame = surface_frame(V, F, uv) if frame is None else frame
            self.locator = Locator(uv, F)
        fr = self.frame
        # position, normal, I = (E, F, G), II = (L, M, N) side by side: one gather per evaluation
        self._pack = np.ascontiguousarray(np.column_stack([V, fr.n, fr.E, fr.F, fr.G, fr.L, fr.M, fr.N]),
                                          dtype=np.float64)

    def sample(self, P: np.ndarray, keep: SurfaceSample | None = None, new: np.ndarray | None = None) -> SurfaceSample:
        """The surface at domain points ``P (k, 2)``.

        With ``keep`` and the mask ``new`` (``(k,)`` bool), only the points at the True
        entries are evaluated and ``keep``'s rows, in their order, fill the others: what
        ``self.sample(P[new])`` interleaved with ``keep`` gives, in one pass (the planner
        refining a curve keeps the samples it has).

        Raises
        ------
        PlanningError
            A point lies outside the domain mesh (a planner bug or a hole in the map), or
            ``keep``'s rows do not fill the entries ``new`` leaves.
        """
        P = np.ascontiguousarray(np.asarray(P, dtype=np.float64).reshape(-1, 2))
        loc = self.locator
        args = (loc.uv, loc.F, loc._ptr, loc._items, loc._lo, loc._inv, loc._nx, loc._ny, loc.tol * loc.tol,
                self._pack)
        k = len(P)
        face = np.empty(k, dtype=np.int64)
        bary = np.empty((k, 3))
        # position, normal, I and II each in an array of its own (C-contiguous: the planner's
        # kernels read them without copies)
        xyz, n, I, II = np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3)), np.empty((k, 3))
        uv = np.empty_like(P)
        if keep is None:
            n0 = _NONE_KEPT
            kept = (np.empty((0, 2)), np.empty(0, dtype=np.int64), np.empty((0, 3)), n0, n0, n0, n0)
            new = np.ones(k, dtype=bool)
        else:
            new = np.asarray(new, dtype=bool)
            if new.shape != (k,) or k - np.count_nonzero(new) != len(keep.face):
                raise PlanningError(f"sample: {len(keep.face)} kept rows and {np.count_nonzero(new)} new ones "
                                    f"for {k} points")
            c = np.ascontiguousarray  # (no copy for the samples made here)
            kept = (c(keep.uv), c(keep.face), c(keep.bary), c(keep.xyz), c(keep.n), c(keep.I), c(keep.II))
        # (serial: the planner samples curves of about a thousand points, thousands of
        # times, where waking numba's threads costs more than the work)
        _sample_rows(P, new, *kept, *args, uv, face, bary, xyz, n, I, II)
        bad = np.flatnonzero(face < 0)
        if bad.size:
            raise PlanningError(
                f"{bad.size} domain point(s) fall outside the parameter mesh, e.g. "
                f"{uv[bad[0]].round(6).tolist()}"
            )
        return SurfaceSample(uv=uv, face=face, bary=bary, xyz=xyz, n=n, I=I, II=II)


@njit(cache=True, nogil=True, inline="always")
def _sample_one(q, P, uv, F, ptr, items, lo, inv_cell, nx, ny, tol2, pack, face, bary, xyz, n, I, II):
    """Point ``q`` of :meth:`DomainSurface.sample`: located (:func:`conformill.geometry.locate._locate_one`),
    the packed per-vertex values (position, normal, I, II: three columns each) interpolated
    barycentrically and the normal made unit (NaN rows outside the domain). The same
    arithmetic as ``Locator.locate``, :func:`conformill.geometry.differential.interpolate`
    and numpy's norm."""
    f, b0, b1, b2 = _locate_one(P[q, 0], P[q, 1], uv, F, ptr, items, lo, inv_cell, nx, ny, tol2)
    face[q] = f
    bary[q, 0] = b0
    bary[q, 1] = b1
    bary[q, 2] = b2
    if f < 0:
        for c in range(3):
            xyz[q, c] = np.nan
            n[q, c] = np.nan
            I[q, c] = np.nan
            II[q, c] = np.nan
        return
    a, b, d = F[f, 0], F[f, 1], F[f, 2]
    for c in range(3):
        xyz[q, c] = b0 * pack[a, c] + b1 * pack[b, c] + b2 * pack[d, c]
        n[q, c] = b0 * pack[a, 3 + c] + b1 * pack[b, 3 + c] + b2 * pack[d, 3 + c]
        I[q, c] = b0 * pack[a, 6 + c] + b1 * pack[b, 6 + c] + b2 * pack[d, 6 + c]
        II[q, c] = b0 * pack[a, 9 + c] + b1 * pack[b, 9 + c] + b2 * pack[d, 9 + c]
    nn = np.sqrt(n[q, 0] * n[q, 0] + n[q, 1] * n[q, 1] + n[q, 2] * n[q, 2])
    if nn < 1e-300:  # (np.maximum: NaN stays NaN)
        nn = 1e-300
    n[q, 0] /= nn
    n[q, 1] /= nn
    n[q, 2] /= nn


@njit(cache=True, nogil=True)
def _sample_rows(P, new, kuv, kface, kbary, kxyz, kn, kI, kII, uv, F, ptr, items, lo, inv_cell, nx, ny, tol2,
                 pack, uv_out, face, bary, xyz, n, I, II):
    """:meth:`DomainSurface.sample`: the rows at ``new`` evaluated (:func:`_sample_one`),
    the kept rows copied in order."""
    j = 0
    for q in range(P.shape[0]):
        if new[q]:
            uv_out[q, 0] = P[q, 0]
            uv_out[q, 1] = P[q, 1]
            _sample_one(q, P, uv, F, ptr, items, lo, inv_cell, nx, ny, tol2, pack, face, bary, xyz, n, I, II)
            continue
        uv_out[q, 0] = kuv[j, 0]
        uv_out[q, 1] = kuv[j, 1]
        face[q] = kface[j]
        for c in range(3):
            bary[q, c] = kbary[j, c]
            xyz[q, c] = kxyz[j, c]
            n[q, c] = kn[j, c]
            I[q, c] = kI[j, c]
            II[q, c] = kII[j, c]
        j += 1
