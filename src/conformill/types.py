"""Frozen data types that cross pipeline stages.

Arrays follow the house conventions: ``V (n, 3) float64`` in millimetres, ``F (m, 3) int64``,
``uv (n, 2) float64``. Stages never mutate these; they return new objects.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

BoundaryKind = Literal["circle", "rectangle"]
WeightKind = Literal["geodesic", "floater", "mean_value", "cotangent"]
PatternKind = Literal["zigzag", "contour", "spiral"]
#: The pencil stage's searches (:func:`conformill.pencil.pencil_passes`, ``Job.pencil_search``).
PENCIL_SEARCHES = ("samples", "folds")


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Attributes
    ----------
    V : (n, 3) float64
        Vertex positions in mm.
    F : (m, 3) int64
        Triangles, counter-clockwise seen from the side the tool comes from.
    name : str
        Where it came from (file name), for reports.
    """

    V: np.ndarray
    F: np.ndarray
    name: str = ""

    @property
    def n_vertices(self) -> int:
        return int(self.V.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.F.shape[0])


@dataclass(frozen=True, eq=False)
class Quality:
    """Conformal quality of a parameterization (METHOD section 1d).

    Statistics are area-weighted over the 3D faces. ``qc`` is the quasi-conformal
    distortion s1/s2 (1 = conformal); angle errors are in degrees.
    """

    qc_mean: float
    qc_p95: float
    qc_max: float
    angle_mean: float
    angle_p95: float
    angle_max: float
    flipped: int
    sigma_min: float
    sigma_max: float
    sigma: np.ndarray = field(repr=False)  # (n,) per-vertex scale factor, 3D length / 2D length
    qc: np.ndarray = field(repr=False)  # (m,) per-face s1/s2

    def as_dict(self) -> dict:
        """Scalar figures, for JSON reports."""
        return {
            "qc_mean": self.qc_mean,
            "qc_p95": self.qc_p95,
            "qc_max": self.qc_max,
            "angle_error_deg_mean": self.angle_mean,
            "angle_error_deg_p95": self.angle_p95,
            "angle_error_deg_max": self.angle_max,
            "flipped_faces": self.flipped,
            "sigma_min": self.sigma_min,
            "sigma_max": self.sigma_max,
        }


@dataclass(frozen=True, eq=False)
class Parameterization:
    """A bijective planar map of a disk mesh (METHOD section 1).

    Attributes
    ----------
    mesh : Mesh
    uv : (n, 2) float64
        Parameter coordinates of every vertex, input order.
    boundary : (b,) int64
        Vertex ids of the boundary loop in order (interior on the left).
    kind : {"circle", "rectangle"}
        Circle: centred at the origin, radius ``domain[0]``. Rectangle: ``[0, X] x [0, Y]``
        with ``domain = (X, Y)``.
    domain : tuple of float
    weights : str
    corners : tuple of int or None
        Rectangle only: the four corner vertex ids (in boundary order).
    residual : float
        Relative residual ``|A x - b| / |b|`` of the solve.
    fallbacks : int
        Geodesic weights: how many (vertex, spoke) pairs fell back to Floater's rule.
    solver : str
    timings : dict
        Seconds per step.
    """

    mesh: Mesh
    uv: np.ndarray
    boundary: np.ndarray
    kind: str
    domain: tuple
    weights: str
    corners: tuple | None = None
    residual: float = 0.0
    fallbacks: int = 0
    solver: str = ""
    timings: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class SurfaceFrame:
    """Per-vertex differential properties in parameter coordinates (METHOD section 3).

    Every attribute is indexed by vertex. ``n`` is the unit normal towards the tool.
    """

    ru: np.ndarray  # (n, 3)
    rv: np.ndarray  # (n, 3)
    ruu: np.ndarray  # (n, 3)
    ruv: np.ndarray  # (n, 3)
    rvv: np.ndarray  # (n, 3)
    n: np.ndarray  # (n, 3)
    E: np.ndarray  # (n,)
    F: np.ndarray  # (n,)
    G: np.ndarray  # (n,)
    L: np.ndarray  # (n,)
    M: np.ndarray  # (n,)
    N: np.ndarray  # (n,)


@dataclass(frozen=True)
class PathParams:
    """Cutting parameters, mm. Ball-end cutter of radius ``tool_radius``; ``stock`` is the
    material left on the part (the paths are spaced for ``scallop`` on the surface offset by
    ``stock``; negative: the ball cuts that far into the part, as for an EDM electrode)."""

    tool_radius: float
    scallop: float
    tolerance: float
    stock: float = 0.0


@dataclass(frozen=True, eq=False)
class ToolPath:
    """A cutter-location program: ordered passes of tool-tip points.

    Attributes
    ----------
    passes : list of (k, 3) float64
        Each pass is a polyline cut at feed (tool tip, mm). Between passes the tool
        retracts to ``safe_z`` with rapids.
    pass_ids : list of int
        For each pass, the index of the planned path(s) it starts with (for colouring);
        -1 for a pencil pass (:mod:`conformill.pencil`) or a fill pass (:mod:`conformill.fill`).
    safe_z : float
    hops : list of (float, float) or None
        For each pass, where the move into it from the pass before is a hop over a lifted
        run (``Job.hop_lift``): the tool-tip heights of the hop's rapid across and of its
        rapid down to above the pass start (then the plunge); ``None`` (or an empty list:
        for all of them) for a retract to ``safe_z``.
    """

    passes: list
    safe_z: float
    pass_ids: list = field(default_factory=list)
    hops: list = field(default_factory=list)


@dataclass(frozen=True, eq=False)
class DomainPath:
    """One planned path in the parameter domain, densely sampled (METHOD section 5).

    Attributes
    ----------
    uv : (k, 2) float64
        Dense domain samples, in cutting order.
    closed : bool
        A ring (contour): the last sample equals the first.
    offset : float
        The family parameter of the path (u for zigzag, rho for contour rings; for a
        spiral revolution, the inner ring's rho).
    side_allowed : (k,) float64
        Allowed side interval l_s (mm) at each sample, from the scallop height the paths
        are spaced for and the curvature across the path.
    side_realised : (k,) float64
        3D distance (mm) from each sample to the next path (NaN on the last path).
    side_predicted : (k,) float64
        The side interval the metric predicts for the domain step actually taken,
        ``|r_a| sin(phi) * ds`` (METHOD section 6's ``l_s'``); NaN on the last path.
    widening : float
        Where the paths are spaced for more than the job's scallop h
        (``Job.pattern_scallop``): how much wider the step to the next path is than a
        step spaced for h would be. The largest factor by which the step taken could be
        scaled and keep ``side_predicted`` within the interval allowed as spaced at every
        sample, over the same within the interval allowed at h. 1.0 otherwise and on the
        last path.
    """

    uv: np.ndarray
    closed: bool
    offset: float
    side_allowed: np.ndarray
    side_realised: np.ndarray
    side_predicted: np.ndarray
    widening: float = 1.0


@dataclass(frozen=True, eq=False)
class DomainPaths:
    """The paths of one pattern in the domain, in machining order."""

    pattern: str
    paths: list  # list[DomainPath]
    shrink_iterations: int = 0


@dataclass(frozen=True, eq=False)
class PlanResult:
    """Everything a plan produced: the program, its geometry and its figures.

    Attributes
    ----------
    toolpath : ToolPath
        Tool-tip passes (what the G-code holds).
    param : Parameterization
    domain_paths : DomainPaths
    cc_paths : list of (k, 3) float64
        Cutter-contact points per planned path (after forward stepping).
    mesh : Mesh
        The mesh as planned (after orientation and scale).
    report : dict
        Figures for the JSON report (counts, lengths, steps, error analysis, timings).
    """

    toolpath: ToolPath
    param: Parameterization
    domain_paths: DomainPaths
    cc_paths: list
    mesh: Mesh
    report: dict
