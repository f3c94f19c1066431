"""Checkerboard figure of a parameterization (Zhao et al. 2015, Fig. 6 a-b).

Left: the mesh in 3D, each face coloured by the checker square of its uv centroid and shaded by
its normal; a conformal map keeps the squares square on the surface. Right: the same checker in
the parameter domain. The 3D view is drawn with the painter's algorithm into a 2D
``PolyCollection`` (much faster than ``Poly3DCollection`` on large meshes). Written atomically.
"""

from __future__ import annotations

import numpy as np

from conformill.errors import OutputError
from conformill.output.atomic import atomic_path

LIGHT = np.array([0.93, 0.62, 0.22])
DARK = np.array([0.16, 0.30, 0.55])


def checker_colors(uv_centroids: np.ndarray, cell: float) -> np.ndarray:
    """Checker parity of each point, ``(m,)`` bool (True = light square)."""
    ij = np.floor(uv_centroids / cell).astype(np.int64)
    return ((ij[:, 0] + ij[:, 1]) % 2) == 0


def _view_frame(V: np.ndarray, F: np.ndarray, elev_deg: float = 35.0, azim_deg: float = -60.0):
    """Orthonormal view frame: ``d`` towards the viewer, tilted from the mean face normal."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    N = np.cross(b - a, c - a)
    up = N.sum(0)
    up = up / (np.linalg.norm(up) or 1.0)
    # any vector not parallel to up, to build a frame (x, y, up)
    t = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(t, up)
    x /= np.linalg.norm(x)
    y = np.cross(up, x)
    el, az = np.radians(elev_deg), np.radians(azim_deg)
    d = np.sin(el) * up + np.cos(el) * (np.cos(az) * x + np.sin(az) * y)
    r = np.cross(up, d)
    r = r / (np.linalg.norm(r) or 1.0)
    s = np.cross(d, r)
    return d, r, s, N


def plot_param(path, V: np.ndarray, F: np.ndarray, uv: np.ndarray, *, boundary=None, corners=None,
               cells: int = 16, title: str = "", dpi: int = 150) -> None:
    """Write the checkerboard figure as a PNG.

    Parameters
    ----------
    path : str or Path
    V : (n, 3) float64
    F : (m, 3) int64
    uv : (n, 2) float64
    boundary : (b,) int64, optional
        Boundary loop, drawn in both views.
    corners : sequence of int, optional
        Rectangle corners, marked in both views.
    cells : int
        Checker squares across the longer side of the domain.
    title : str

    Raises
    ------
    OutputError
        The file cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    uv = np.asarray(uv, dtype=np.float64)
    span = np.ptp(uv, axis=0).max()
    cell = span / max(int(cells), 1)
    light = checker_colors(uv[F].mean(axis=1), cell)
    base = np.where(light[:, None], LIGHT, DARK)

    d, r, s, N = _view_frame(V, F)
    nn = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
    lam = np.abs(nn @ d)  # two-sided Lambert towards the viewer
    col3 = np.clip(base * (0.35 + 0.65 * lam[:, None]), 0, 1)
    P2 = np.column_stack([V @ r, V @ s])
    depth = (V @ d)[F].mean(axis=1)
    order = np.argsort(depth)  # far first

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 6.2))
    ax1.add_collection(PolyCollection(P2[F[order]], facecolors=col3[order], edgecolors="none",
                                      antialiased=False))
    ax1.set_xlim(P2[:, 0].min(), P2[:, 0].max())
    ax1.set_ylim(P2[:, 1].min(), P2[:, 1].max())
    ax1.set_aspect("equal")
    ax1.set_axis_off()
    ax1.set_title("checkerboard on the surface (3D view)")

    ax2.add_collection(PolyCollection(uv[F], facecolors=base, edgecolors="none", antialiased=False))
    if boundary is not None:
        bl = np.append(np.asarray(boundary), boundary[0])
        ax2.plot(uv[bl, 0], uv[bl, 1], "k-", lw=0.8)
    if corners is not None:
        c = np.asarray(corners)
        ax2.plot(uv[c, 0], uv[c, 1], "o", color="crimson", ms=6, label="corners")
        ax1.plot(P2[c, 0], P2[c, 1], "o", color="crimson", ms=6)
        ax2.legend(loc="upper right", fontsize=8)
    pad = 0.03 * span
    ax2.set_xlim(uv[:, 0].min() - pad, uv[:, 0].max() + pad)
    ax2.set_ylim(uv[:, 1].min() - pad, uv[:, 1].max() + pad)
    ax2.set_aspect("equal")
    ax2.set_xlabel("u (mm)")
    ax2.set_ylabel("v (mm)")
    ax2.set_title(f"parameter domain (checker {cell:.3g} mm)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        with atomic_path(path, suffix=".png") as tmp:
            fig.savefig(tmp, dpi=dpi, format="png")
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror}") from None
    finally:
        plt.close(fig)
