"""``plan(mesh, job) -> PlanResult``: the stages in order, each timed.

orient -> parameterize (rectangle for zigzag, circle otherwise) -> surface frame ->
reachability -> pattern in the domain -> forward steps and CC points -> ball-cutter CL
(drop-cutter, gouge-safe chords) -> tool tips. Writing G-code and figures is the CLI's job.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, replace

import numpy as np

from conformill import __version__
from conformill.errors import JobValueError, PlanningError
from conformill.geometry.surface import DomainSurface
from conformill.output.gcode import coolant_on, path_control, tool_number
from conformill.patterns.family import Planner
from conformill.passes import PassBuilder, feed_length, hops_into, serial_caller, threads_can_overlap
from conformill.planning.steps import check_ball_size, check_meetable, check_params, check_resolution, side_interval
from conformill.types import PENCIL_SEARCHES, DomainPaths, Mesh, PathParams, PlanResult, ToolPath

log = logging.getLogger(__name__)

PATTERNS = ("zigzag", "contour", "spiral")

#: The settings for a scanned part (``plan --scan``): the fold pencil cut where the
#: pattern's passes left more than 0.5 H, and hops over the runs lifted more than 3 mm.
#: On igea zigzag (r = 4, h = e = 0.01) it left 1.039 h at 22.8-24.0x OpenCAMLib's raster
#: (session 35; docs/issue5.md and the README's "Issue 5: scale and the raster").
#: Since session 53 it also fills where the passes left more than 0.7 h
#: (:mod:`conformill.fill`) and spaces the pattern wider, by pattern
#: (:data:`SCAN_PATTERN_SCALLOP`): the whole recipe for a pattern is :func:`scan_recipe`.
SCAN_RECIPE = {"pencil": True, "pencil_search": "folds", "pencil_left": 0.5, "hop_lift": 3.0, "fill": 0.7}
#: ``Job.pattern_scallop`` with ``plan --scan``, by pattern. Session 53 chose 1.3 for all
#: three on the zigzag (igea 1.033 h for 7 % less feed; 1.5 left igea and the shipped face at
#: or above 1.05 h). The contour and spiral rings leave less where they are tight (igea
#: 1.016 / 1.015 h at 1.3): the spiral is spaced for 1.7 h (igea 1.022-1.026 h on four
#: sample sets, 10 % less feed than at 1.3) and, since session 55, the contour too (igea
#: 1.027-1.038 h on four sample sets, 8 % less feed than at 1.3), every other scan within
#: 1.05 h as at 1.3. Session 54 had held the contour at 1.5 because the widening test then
#: assumed a saving of sqrt(F) - 1 and kept the fill on the shipped patch, where the flat
#: cap sets the step at every F; :func:`widening_ratio` reads the saving from the paths
#: (docs/issue5.md, "Session 54" and "Session 55").
SCAN_PATTERN_SCALLOP = {"zigzag": 1.3, "contour": 1.7, "spiral": 1.7}

#: :func:`plan` keeps the fill while its feed is at most this times what the wider paths
#: saved (:func:`widening_ratio`). Above 1: on a scan the fill also cuts what the planner's
#: curvature misreads, which paths spaced for h leave too (session 51, before the fill:
#: choi and the shipped face zigzag ``--scan`` left 1.21 and 1.16 h; with it 0.97 and
#: 0.96 h). There, at 1.3 h, the fill costs 1.00 and 1.09 times the saving; on the beetle
#: roof zigzag 1.56 times (0.83 h without it) and on the shipped patch 2.2-6.4 times:
#: dropped (docs/issue5.md, "Session 55").
FILL_OVER_SAVING = 1.25


def scan_recipe(pattern: str) -> dict:
    """The :class:`Job` fields ``plan --scan`` sets for ``pattern``: :data:`SCAN_RECIPE` and
    the pattern's :data:`SCAN_PATTERN_SCALLOP`."""
    if pattern not in SCAN_PATTERN_SCALLOP:
        raise JobValueError(f"unknown pattern {pattern!r}; expected one of {', '.join(PATTERNS)}")
    return {**SCAN_RECIPE, "pattern_scallop": SCAN_PATTERN_SCALLOP[pattern]}


@dataclass(frozen=True)
class Job:
    """What to plan. Lengths in mm, feeds in mm/min.

    Attributes
    ----------
    pattern : {"zigzag", "contour", "spiral"}
    tool_radius, scallop, tolerance : float
        Ball radius r, scallop height h, chord deviation e.
    feed, plunge_feed : float
    safe_z : float or None
        Clearance height of the tool tip for rapids; default: part top + ``clearance``.
    clearance : float
    orient : {"none", "auto"}
        "auto" turns the part so its area-weighted mean normal is +Z.
    weights : str
        Parameterization weights (see :func:`conformill.param.parameterize`).
    corners : tuple of int or None
        Rectangle corners (zigzag), vertex ids in boundary order.
    max_step : float
        Longest forward step on flat ground.
    link_max : float or None
        Longest on-surface link between paths; longer links retract. Default
        ``max(2 r, 4 * flat side interval)``.
    concave_steps : {"flat", "exact"}
        Side interval where the surface is concave across the path. "exact" uses the
        concave circle formula (METHOD section 4, the paper); it assumes the curvature holds
        across the whole step and leaves up to 1.25 H at narrow creases and fillets (measured
        on the face sample). "flat" (default) never spaces concave regions wider than a
        plane would be.
    spindle : float or None
    spacing : {"adaptive", "paper", "local"}
        "paper": each path is an iso-line spaced from the last by the minimum allowed step
        over it (METHOD 5). "adaptive" (default): the paths bend so that each place gets
        the step it needs (:mod:`conformill.patterns.warp`); the same 3D spacing check
        applies to both. "local": adaptive, and zigzag rows and contour rings also dent
        locally where a narrow dip of the allowed step would otherwise set the whole
        path's step (:meth:`conformill.patterns.family.Planner.run_local`): 18-28 % shorter
        on scans, but more material at scan creases (igea contour: 1.39 h above the rest
        against 1.06 h); the spiral plans as with "adaptive".
    settle : float
        Largest float of a centre move above the drop surface, as a fraction of the
        scallop height (:meth:`conformill.cutter.BallCutter.settle`): where the ball rides
        over a groove narrower than itself, a move between two centres on either side
        passes above the wedged position and leaves the groove's rims uncut. Met at
        creases with straight sides; curved valleys get four rounds of insertion, and the
        moves still untested after them are counted in the report
        (``cutter.settle_unresolved_moves``). 0 turns the check off.
    fit : {"mesh", "split"}
        Scale of the per-vertex quadratic fit the planner spaces the paths from. "mesh"
        (default): each vertex's 1-ring of the input. "split": the 1-ring of the input split
        once at its edge midpoints (:func:`conformill.mesh.split.split_midpoints`, the same
        surface), i.e. half the edge length (the paths are sampled at the split mesh's edge
        length where that is below a third of the flat step; on igea it is not). On a scan
        the planner then spaces the paths for sharper curvature at facet creases
        and rims (igea contour, h = 0.01: reachable p99.9 1.256 h -> 1.086 h for 1.38x the
        feed; docs/issue5.md, "What 1.05 H costs on a scan"). The midpoints lie on chords, so on a smooth tessellated surface
        the fit reads twice the curvature at the input's vertices and 0.7x at the midpoints
        (measured on a sphere): with the min rule the paths come out denser than needed, and
        the reachability report flags concave regions of radius up to about 2 r. The cutter
        works on the input mesh either way; the report's concave-region face counts and
        the frame's warnings then refer to the split mesh.
    pencil : bool
        After the pattern, cut pencil passes through the best ball positions where the
        part is tighter than the ball (:mod:`conformill.pencil`): the centres of surface
        samples whose least possible material lies in (0.15 h, h], chained, settled and
        refined. On igea (contour, h = 0.01) it takes the reachable p99.9 from 1.256 h to
        1.018 h for 9 % more feed, and six of the eight scans measured within 1.05 h for
        2-20 % (see docs/issue5.md, "Pencil passes"), at a cost growing with the area and
        ``pencil_density`` (3.7 s more on igea contour at 30 per mm^2 on a 2-CPU AMD EPYC
        host, session 24, its search running beside the pattern stage; 7-8 s on session
        21's Intel Xeon host).
    pencil_density : float
        Samples per mm^2 the pencil stage searches (30: 0.18 mm apart); with
        ``pencil_search = "folds"``, grid points per mm^2 of the XY plane.
    pencil_search : str
        How the pencil stage finds the wedged balls (:func:`conformill.pencil.pencil_passes`):
        ``"samples"`` (the best ball of each surface sample) or ``"folds"`` (the folds of
        the drop surface crossing an XY grid, :mod:`conformill.folds`, with the samples on
        steep walls searched one by one): on the scans the latter's stage took 18-51 %
        less time (igea 2.1 against 3.7 s more than the default since session 24) and
        left the same or a lower scallop on seven of eight, for 1-15 points more feed
        (docs/issue5.md, "Pencil passes", sessions 23-24).
    pencil_left : float or None
        With the fold search: cut the pencil only through the fold points where the
        pattern's passes leave more than this many ``h`` in the fold's shadow, by the
        planner's estimate (:func:`conformill.pencil.where_left`,
        :mod:`conformill.pattern_rest`), and through the steep walls' centres where they
        leave more than that at the centre's sample (every searched steep sample whose best
        ball leaves at most ``h`` then gives a centre: :func:`conformill.pencil.steep_centres`,
        session 61). None (default): every fold point and the steep centres whose rest lies
        in the band. Session 31 measured 0.5 on the scans (docs/issue5.md, "Pencil passes").
    hop_lift : float
        Hop over the runs of a path whose CC points the drop-cutter lifts more than this
        (mm) above their planned contact, where the hop (rapids clear of the part by 1 mm,
        then the plunge) is quicker than riding the run at the feed
        (:meth:`conformill.passes.PassBuilder._cut_centres`); 0 (default): off. On igea
        (h = 0.01) 3 mm gave 12-16 % less machining time and about 20 % less feed, the
        reachable p99.9 up by 0.03-0.06 h, or by 0.003-0.007 h with the fold pencil
        (docs/issue5.md, "Hops over lifted runs", session 27).
    rapid : float
        The machine's rapid rate (mm/min) the hops are timed at.
    fill : float or None
        After the pattern (and the pencil), cut fill passes through the balls that reach
        the surface samples (30 per mm^2) the passes so far left more than this many ``h``,
        by the planner's estimate (:mod:`conformill.fill`); None (default): no fill.
    pattern_scallop : float
        The pattern's paths are spaced for this many ``h`` (default 1); above 1 only with
        ``fill``, which brings what the wider paths leave back under ``h``. ``plan --scan``
        spaces them for 1.3 / 1.7 / 1.7 h (zigzag / contour / spiral;
        :data:`SCAN_PATTERN_SCALLOP`) and fills above 0.7 h (sessions 53-55: 27 of the 33
        benchmark programs within 1.05 h where 25 were, up to 17 % shorter on the scans;
        docs/issue5.md, "Session 53" to "Session 55").
    blend : float, "off" or None
        The path control the program asks of the controller
        (:func:`conformill.output.gcode.path_control`): stay within this many mm of the
        programmed path when rounding its corners (``G64 P<blend> Q0``); 0: exact path
        (``G61``); "off": no path-control block, the machine's own mode (LinuxCNC's ``G64``
        without ``P`` rounds corners by any amount). None (default): :attr:`blend_tolerance`'s
        ``min(e, h) / 4``: the moves cut at most e/2 into the part, the rounding e/4 more,
        and e/4 is left to the mesh's facets (e in all); above the surface the rounding
        stays within the h/4 the planner allows its own chords on concave ground. A
        default below the 1e-6 mm that can be written gives exact path (``G61``); more
        than the tool radius is refused.
    tool_number : int or None
        The program changes to this tool (``T N M6``) and applies its length from the
        machine's tool table (``G43 H N``); None (default): the tool tip is touched off and
        the program keeps any length offset cancelled (``G49``).
    coolant : {"flood", "mist"} or None
        Coolant on before the first move, after the spindle start when ``spindle`` is given
        (``M8`` / ``M7``), and off at the end (``M9``);
        None (default): the program leaves the coolant to the operator.
    stock : float
        Material left on the part (mm, default 0): the program finishes the part's offset
        by ``stock`` along its normal, for a semi-finishing pass; negative values cut into
        the part (an EDM electrode's spark gap), down to above ``-tool_radius``. The
        cutter places the centres of a ball of radius ``tool_radius + stock`` on the part
        (so the ball stays ``stock`` from it, less the gouge budget), the tips are written
        ``tool_radius`` below them, and the paths are spaced for the scallop on the
        offset (:func:`conformill.planning.steps.side_interval_stock`).
    """

    pattern: str = "spiral"
    tool_radius: float = 4.0
    scallop: float = 0.1
    tolerance: float = 0.01
    feed: float = 1000.0
    plunge_feed: float | None = None
    safe_z: float | None = None
    clearance: float = 5.0
    orient: str = "none"
    weights: str = "geodesic"
    corners: tuple | None = None
    max_step: float = 10.0
    link_max: float | None = None
    spindle: float | None = None
    concave_steps: str = "flat"
    spacing: str = "adaptive"
    settle: float = 0.5
    fit: str = "mesh"
    pencil: bool = False
    pencil_density: float = 30.0
    pencil_search: str = "samples"
    pencil_left: float | None = None
    hop_lift: float = 0.0
    rapid: float = 5000.0
    fill: float | None = None
    pattern_scallop: float = 1.0
    blend: float | str | None = None
    tool_number: int | None = None
    coolant: str | None = None
    stock: float = 0.0

    @property
    def plunge_rate(self) -> float:
        """The plunge feed (mm/min): ``plunge_feed``, or a third of ``feed`` when unset."""
        return self.plunge_feed or self.feed / 3

    @property
    def blend_tolerance(self) -> float | None:
        """The path-control tolerance written (mm): ``blend``; when unset ``min(e, h) / 4``,
        or 0 (exact path) where that is below the 1e-6 mm that can be written; None for
        "off" (no path-control block)."""
        if isinstance(self.blend, str) and self.blend == "off":
            return None
        if self.blend is None:
            b = 0.25 * min(self.tolerance, self.scallop)
            return b if b >= 1e-6 else 0.0
        if isinstance(self.blend, (bool, str)):
            return self.blend  # refused by check_job
        return float(self.blend) + 0.0  # -0.0 -> 0.0


class _Timer:
    def __init__(self):
        self.t = {}

    @contextmanager
    def __call__(self, name):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.t[name] = self.t.get(name, 0.0) + time.perf_counter() - t0


#: The least feed (mm/min) the G-code carries: F words have 3 decimals (below 0.0005: F0).
_LEAST_FEED = 0.001


#: Largest safe height (mm) taken: the writer counts coordinates in 1e-4 mm ticks (int64),
#: and a safe height of 1e15 mm overflowed them into a wrong "above the clearance" refusal.
_MOST_SAFE_Z = 1e6


def check_job(job: Job, together: bool = True) -> PathParams:
    """Refuse a job before any work; return its checked cutting parameters
    (:func:`conformill.planning.steps.check_params`).

    Every value is checked on its own first, then (with ``together``) the values against
    each other (:func:`check_job_together`), so that a job with a malformed value and a
    combination that cannot be met is refused for the malformed value (exit code 2). A
    caller with more single values of its own (the command line) passes ``together=False``
    and calls :func:`check_job_together` after checking them.

    Raises
    ------
    JobValueError
        A malformed value (exit code 2): not a number, not finite, out of its own range, an
        unknown word, a feed written ``F0``, a spindle below 1 rpm, ``pencil_left``
        without the fold pencil.
    PlanningError
        Well-formed values that cannot be met together (exit code 3): a scallop at or
        above the tool radius, a blend larger than the tool radius.
    """
    if job.pattern not in PATTERNS:
        raise JobValueError(f"unknown pattern {job.pattern!r}; choose one of {', '.join(PATTERNS)}")
    params = check_params(job.tool_radius, job.scallop, job.tolerance, job.stock, together=False)
    for name in ("feed", "max_step", "clearance", "rapid"):
        v = getattr(job, name)
        if not np.isfinite(v) or v <= 0:
            raise JobValueError(f"{name.replace('_', '-')} must be a positive number, got {v}")
    check_resolution("max-step", job.max_step)
    if job.plunge_feed is not None and (not np.isfinite(job.plunge_feed) or job.plunge_feed <= 0):
        raise JobValueError(f"plunge-feed must be a positive number, got {job.plunge_feed}")
    for name, v in (("feed", job.feed), ("plunge-feed", job.plunge_rate)):
        if float(f"{v:.3f}") == 0.0:  # F is written with 3 decimals (output.gcode)
            raise JobValueError(f"{name} {v:g} mm/min would be written F0; it must be at least {_LEAST_FEED:g}")
    if job.spindle is not None and not (np.isfinite(job.spindle) and job.spindle >= 1.0):
        raise JobValueError(f"spindle must be a speed of at least 1 rpm, got {job.spindle}")
    if job.safe_z is not None and not (np.isfinite(job.safe_z) and abs(job.safe_z) <= _MOST_SAFE_Z):
        raise JobValueError(f"safe-z must be a finite height within +-{_MOST_SAFE_Z:g} mm, got {job.safe_z}")
    if not (np.isfinite(job.settle) and job.settle >= 0):
        raise JobValueError(f"settle must be a non-negative number, got {job.settle}")
    if job.orient not in ("none", "auto"):
        raise JobValueError(f"orient must be 'none' or 'auto', got {job.orient!r}")
    if job.concave_steps not in ("flat", "exact"):
        raise JobValueError(f"concave_steps must be 'flat' or 'exact', got {job.concave_steps!r}")
    if job.spacing not in ("adaptive", "paper", "local"):
        raise JobValueError(f"spacing must be 'adaptive', 'paper' or 'local', got {job.spacing!r}")
    if job.fit not in ("mesh", "split"):
        raise JobValueError(f"fit must be 'mesh' or 'split', got {job.fit!r}")
    if not (np.isfinite(job.pencil_density) and job.pencil_density > 0):
        raise JobValueError(f"pencil-density must be a positive number, got {job.pencil_density}")
    if job.pencil_search not in PENCIL_SEARCHES:
        raise JobValueError(f"pencil-search must be {' or '.join(map(repr, sorted(PENCIL_SEARCHES)))}, "
                            f"got {job.pencil_search!r}")
    if job.pencil_left is not None:
        if not (np.isfinite(job.pencil_left) and job.pencil_left >= 0):
            raise JobValueError(f"pencil-left must be a number >= 0 (x h), got {job.pencil_left}")
        if not (job.pencil and job.pencil_search == "folds"):
            raise JobValueError("pencil-left keeps fold points: it needs the fold pencil (--pencil --pencil-search "
                                "folds)")
    if job.fill is not None and not (np.isfinite(job.fill) and job.fill > 0):
        raise JobValueError(f"fill must be a positive number (x h), got {job.fill}")
    if not (np.isfinite(job.pattern_scallop) and job.pattern_scallop > 0):
        raise JobValueError(f"pattern-scallop must be a positive number (x h), got {job.pattern_scallop}")
    if job.pattern_scallop > 1.0 and job.fill is None:
        raise JobValueError(f"pattern-scallop {job.pattern_scallop:g} spaces the paths for more than the scallop: it "
                            f"needs --fill, which cuts what they leave above it")
    if not (np.isfinite(job.hop_lift) and job.hop_lift >= 0):
        raise JobValueError(f"hop-lifted must be a number >= 0 (mm; 0: off), got {job.hop_lift}")
    if isinstance(job.blend, str) and job.blend != "off":
        raise JobValueError(f"blend must be a number >= 0 (mm) or 'off', got {job.blend!r}")
    try:  # the writer's own checks, refused before any work
        path_control(job.blend_tolerance)
        tool_number(job.tool_number)
        coolant_on(job.coolant)
    except PlanningError as exc:  # JobValueError: the same type, without the writer's prefix
        raise type(exc)(str(exc).replace("G-code: ", "", 1)) from None
    if together:
        check_job_together(job, params)
    return params


def check_job_on(job: Job, params: PathParams, mesh: Mesh) -> None:
    """The checks of a job (its values each checked, :func:`check_job` with
    ``together=False``) that need the mesh, then :func:`check_job_together`.

    Raises
    ------
    JobValueError
        A ball far larger than the part (:func:`conformill.planning.steps.check_ball_size`;
        exit code 2).
    ParameterizationError
        Corners that are not four distinct vertex ids of the mesh (exit code 2; their place
        on the boundary is checked with the map).
    PlanningError
        :func:`check_job_together` (exit code 3).
    """
    check_ball_size(params.tool_radius, mesh.V, stock=params.stock)
    if job.corners is not None:
        from conformill.param.boundary import check_corner_ids

        check_corner_ids(job.corners, mesh.n_vertices)
    check_job_together(job, params)


def check_job_together(job: Job, params: PathParams) -> None:
    """Refuse a job whose values, each well formed (:func:`check_job` with
    ``together=False``), cannot be met together.

    Raises
    ------
    PlanningError
        Exit code 3: a scallop at or above the tool radius
        (:func:`conformill.planning.steps.check_meetable`), a blend larger than the tool
        radius.
    """
    check_meetable(params)
    b = job.blend_tolerance  # None, or a number path_control took
    if b is not None and b > job.tool_radius:
        raise PlanningError(f"blend {b:g} mm is larger than the tool radius {job.tool_radius:g} mm: the controller "
                            f"could round the path's corners by more than the ball")


def face_normals(V: np.ndarray, F: np.ndarray):
    """Unit face normals and face areas."""
    c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a = np.linalg.norm(c, axis=1)
    return c / np.maximum(a, 1e-300)[:, None], 0.5 * a


def orient_mesh(mesh: Mesh, mode: str, normals: bool = False):
    """Make the tool side +Z.

    Faces wound so that the mean normal points down are re-wound (the tool always comes
    from +Z on a 3-axis machine); with ``mode == "auto"`` the part is also rotated about
    its bounding-box centre so that the area-weighted mean normal is +Z.

    Returns
    -------
    mesh : Mesh
    info : dict
    n, a : (m, 3), (m,) float64
        Only with ``normals``: :func:`face_normals` of the returned mesh.
    """
    V, F = mesh.V, mesh.F
    info = {"rewound": False, "rotated_deg": 0.0}
    n, a = face_normals(V, F)
    m = (n * a[:, None]).sum(0)
    if m[2] < 0:
        F = F[:, [0, 2, 1]]
        n = -n  # exactly what face_normals gives for the re-wound faces
        m = -m
        info["rewound"] = True
        log.warning("faces were wound with normals pointing down; re-wound so the tool side is +Z")
    if mode == "auto":
        z = np.array([0.0, 0.0, 1.0])
        mu = m / np.linalg.norm(m)
        axis = np.cross(mu, z)
        s, c = np.linalg.norm(axis), float(mu @ z)
        if s > 1e-12:
            k = axis / s
            K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            Rm = np.eye(3) + s * K + (1 - c) * K @ K
            ctr = 0.5 * (V.min(0) + V.max(0))
            V = (V - ctr) @ Rm.T + ctr
            info["rotated_deg"] = float(np.degrees(np.arctan2(s, c)))
            if normals:
                n, a = face_normals(V, F)
    out = Mesh(V=V, F=F, name=mesh.name)
    return (out, info, n, a) if normals else (out, info)


def principal_concave(sample_I: np.ndarray, sample_II: np.ndarray) -> np.ndarray:
    """Largest principal curvature (positive = concave, towards the tool) from I and II."""
    E, Fm, G = sample_I.T
    L, M, N = sample_II.T
    det = np.maximum(E * G - Fm * Fm, 1e-300)
    H = (E * N + G * L - 2 * Fm * M) / (2 * det)
    K = (L * N - M * M) / det
    return H + np.sqrt(np.maximum(H * H - K, 0.0))


def _regions(mask_f: np.ndarray, mesh: Mesh, areas: np.ndarray, top: int = 5):
    """The ``top`` largest connected regions of the faces in ``mask_f``: area, centre, faces."""
    from conformill.mesh.topology import face_components

    idx = np.flatnonzero(mask_f)
    if idx.size == 0:
        return []
    sub = mesh.F[idx]
    count, lab = face_components(sub, mesh.n_vertices)
    w = areas[idx]
    cen = mesh.V[sub].mean(axis=1)
    area = np.bincount(lab, weights=w, minlength=count)
    faces = np.bincount(lab, minlength=count)
    centre = np.column_stack([np.bincount(lab, weights=w * cen[:, k], minlength=count) for k in range(3)])
    centre /= np.maximum(area, 1e-300)[:, None]
    # largest first; ties keep the component order (a stable sort, as before)
    order = np.argsort(-area, kind="stable")[:top]
    return [{"area_mm2": float(area[c]), "centre": centre[c], "faces": int(faces[c])} for c in order]


def _stats(x):
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"mean": None, "min": None, "max": None}
    return {"mean": float(x.mean()), "min": float(x.min()), "max": float(x.max())}


#: Memory a plan needs per metre of the feed estimate ``area / flat side step`` (bytes): at
#: least this. The peak RSS was 16 MB per metre of it on igea and 21 MB on the 620k mesh
#: (their feed 4.4x and 6.0x the estimate; h = 0.01, r = 4), so a plan refused by
#: :func:`_check_size` is more than ten times too large to finish.
_BYTES_PER_FEED_M = 1.0e6
#: Memory per dense sample of the paths (bytes): at least this. The planner samples the
#: paths every ``min(median edge, flat side step / 3, max-step)``, and the samples are kept until the
#: program is written, so at a tiny scallop they decide the memory: a 40 mm dome at h = 1e-5
#: (r = 2, a 4 um sample spacing, 26.6M samples over 112 m of feed) peaked at 10.6 GB, 400
#: bytes each (session 43; at h = 1e-9 the same dome was killed by the OS with 24 GB).
_BYTES_PER_SAMPLE = 300.0


def _physical_memory() -> float | None:
    """Bytes of RAM of this machine (None where the OS does not say)."""
    import os

    try:
        return float(os.sysconf("SC_PAGE_SIZE")) * float(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return None


def _sample_spacing(mesh: Mesh, flat_ls: float, max_step: float = np.inf) -> float:
    """The planner's dense sample spacing on ``mesh``: about one edge (the fitted fields are
    linear inside a face), never coarser than a third of the flat side step, nor than the
    longest forward step (the forward steps are chosen among the samples: a ``--max-step``
    below their spacing was not met, steps of 0.36 mm for a max-step of 0.01 mm)."""
    edges = np.linalg.norm(mesh.V[mesh.F[:, 1]] - mesh.V[mesh.F[:, 0]], axis=1)
    return min(float(np.median(edges)), flat_ls / 3.0, float(max_step))


def _check_size(mesh: Mesh, area: float, flat_ls: float, memory: float | None = None,
                spacing: float | None = None) -> None:
    """Refuse, before any work, a plan that cannot fit in memory (PlanningError, exit 3).

    Where the part faces the tool the paths are never wider apart than the flat side
    step, so the feed is about ``area / flat_ls`` or more (4.4x that on igea; only where
    the part faces down can the paths lie wider apart). A part in the wrong units (a
    millimetre mesh given ``--scale 1000``) otherwise plans for minutes and ends out of
    memory, or is killed by the OS without a word. So does a tiny scallop, whose paths are
    sampled densely (:data:`_BYTES_PER_SAMPLE`): both bounds are lower bounds.
    """
    memory = _physical_memory() if memory is None else memory
    if memory is None:
        return
    feed_m = area / flat_ls / 1000.0
    # the planner's dense samples (spacing: _sample_spacing, given or found) per metre of that feed
    spacing = _sample_spacing(mesh, flat_ls) if spacing is None else spacing
    per_m = max(_BYTES_PER_FEED_M, 1000.0 / spacing * _BYTES_PER_SAMPLE)
    if feed_m * per_m > memory:
        ext = mesh.V.max(0) - mesh.V.min(0)
        raise PlanningError(
            f"the part is {ext[0]:.4g} x {ext[1]:.4g} x {ext[2]:.4g} mm with {area / 1e6:.4g} m^2 of surface: at a "
            f"flat side step of {flat_ls:.3g} mm its program would be at least {feed_m / 1000:.4g} km of feed, "
            f"needing at least {feed_m * per_m / 2**30:.3g} GB to plan, more than the {memory / 2**30:.1f} GB of "
            f"memory here; check the units (--scale), the scallop and the max-step")


def _after(cutter, passes, pass_ids, hops, centres, hop: bool):
    """The program's passes, ids and hops with the ball-centre passes ``centres`` (the
    pencil's or the fill's) cut after them: entered by a hop from the pass before
    (:func:`conformill.passes.hops_into`) when ``hop`` (``Job.hop_lift``), else by a retract
    to the safe height."""
    if hop and centres and passes:
        into = hops_into(cutter, passes[-1][-1] + np.array([0.0, 0.0, cutter.radius]), centres)
    else:
        into = [None] * len(centres)
    return (passes + [cutter.tip(p) for p in centres], pass_ids + [-1] * len(centres), hops + into)


def plan(mesh: Mesh, job: Job, progress=None) -> PlanResult:
    """Plan a ball-end finishing program for ``mesh``.

    The fill's test of its own widening: with ``job.pattern_scallop`` F above 1 and the
    fill, when the fill's feed is more than :data:`FILL_OVER_SAVING` times what the wider
    paths saved, the part is planned again with the pattern spaced for h and no fill. The
    saving is read from the pattern's own paths (:func:`widening_ratio`): how much wider
    each path's step is than a step spaced for h, near ``sqrt(F)`` where the curvature
    sets the step and 1 where the flat cap (``Job.concave_steps``) holds it at both. The
    fill is dropped on a smooth part, where the wider rows leave more than the fill's depth
    along most of each gap and the fill would cut it all, and where the cap leaves little
    to save. The report's ``fill`` then holds the first plan's figures with ``"dropped":
    True``, and its ``timings_s`` the two plans' sum. Either way the report's ``fill``
    holds the test's figures: ``pattern_scallop`` (F), ``pattern_feed_mm``, ``saved_mm``
    and ``widening_ratio``.

    Parameters
    ----------
    mesh : Mesh
        A valid disk mesh in mm (see :func:`conformill.mesh.io.read_mesh`).
    job : Job
    progress : callable, optional
        ``progress(stage, fraction)`` for a progress display.

    Returns
    -------
    PlanResult

    Raises
    ------
    JobValueError
        Malformed job values (:func:`check_job`), a ball far larger than the part
        (:func:`conformill.planning.steps.check_ball_size`); exit code 2.
    ParameterizationError
        Corners that are not four distinct vertex ids of the mesh
        (:func:`conformill.param.boundary.check_corner_ids`), or not on its boundary in
        order; exit code 2.
    PlanningError
        A job that cannot be met (exit code 3), refused after the checks above: a scallop
        at or above the tool radius, a blend larger than it, a side step that collapses, a
        safe height below the part, a part whose program could not fit in this machine's
        memory (wrong units).
    """
    res = _plan_once(mesh, job, progress)
    fill = res.report["fill"]
    if fill is None or job.pattern_scallop <= 1.0:
        return res
    pattern = [q for q, i in zip(res.toolpath.passes, res.toolpath.pass_ids) if i >= 0]
    pattern_feed = feed_length(pattern)
    ratio = widening_ratio(res.domain_paths)
    saved = (ratio - 1.0) * pattern_feed
    widening = {"pattern_scallop": job.pattern_scallop, "pattern_feed_mm": pattern_feed, "saved_mm": saved,
                "widening_ratio": ratio}
    if fill["feed_mm"] <= FILL_OVER_SAVING * saved:
        return replace(res, report={**res.report, "fill": {**fill, **widening}})
    log.info("fill: %.1f m of fill passes against %.1f m saved by the wider paths: planning again with the "
             "pattern spaced for the scallop and no fill", fill["feed_mm"] / 1000, saved / 1000)
    again = _plan_once(mesh, replace(job, fill=None, pattern_scallop=1.0), progress)
    t = dict(again.report["timings_s"])
    for k_, v in res.report["timings_s"].items():
        t[k_] = t.get(k_, 0.0) + v
    report = {**again.report, "timings_s": t,
              "fill": {**fill, **widening, "dropped": True}}
    return replace(again, report=report)


def widening_ratio(domain: DomainPaths) -> float:
    """How much longer the pattern would be spaced for the job's scallop h than as spaced.

    The paths' ``DomainPath.widening`` (how much wider each path's step to the next is,
    spaced for ``Job.pattern_scallop`` F times h, than a step spaced for h), averaged over
    every path but the last with the weight of its samples (about one dense spacing apart
    in 3D: its length). Near ``sqrt(F)`` where the curvature sets the steps, 1 where the
    flat cap sets both; 1.0 for paths spaced for h.

    It is an estimate: a path's widening is that of its tightest sample (relative to the
    step taken), so where the adaptive or local spacing follows the allowed interval along
    a path that crosses capped and curved ground, one curved sample can give the whole
    path its ratio. Session 55 checked it against plans spaced for h on 11 meshes, three
    patterns and F = 1.3, 1.5 and 1.7: it put the pattern's feed at h within 5 % of the
    plan's on every mesh but camelhead (2.8-10.2 % short there, where it finds 27-69 % of
    the saving).

    Parameters
    ----------
    domain : DomainPaths
        A plan's paths (``PlanResult.domain_paths``).

    Returns
    -------
    float
        The pattern's feed spaced for h over its feed as spaced, estimated (1.0 or more
        for ``Job.pattern_scallop`` above 1).
    """
    w = np.array([len(p.uv) for p in domain.paths[:-1]], dtype=np.float64)
    if not w.sum():
        return 1.0
    return float(np.dot(w, [p.widening for p in domain.paths[:-1]]) / w.sum())


def _plan_once(mesh: Mesh, job: Job, progress=None) -> PlanResult:
    """:func:`plan` without the fill's test of its own widening."""
    from conformill.cutter import BallCutter
    from conformill.param import parameterize
    from conformill.param.quality import quality
    from conformill.patterns.contour import plan_contour
    from conformill.patterns.domains import BoundaryPolygon
    from conformill.patterns.spiral import plan_spiral
    from conformill.patterns.zigzag import plan_zigzag

    params = check_job(job, together=False)
    check_job_on(job, params, mesh)
    timer = _Timer()
    r, h, e, stock = params.tool_radius, params.scallop, params.tolerance, params.stock
    # the cutter places the centres of a ball of radius r + stock on the part: the ball of
    # radius r then rolls on the part's offset by the stock; tips are written r below them
    r_cut = r + stock
    say = progress or (lambda stage, frac: None)

    with timer("orient"):
        mesh, orient_info, fn, fa = orient_mesh(mesh, job.orient, normals=True)
        total_area = float(fa.sum())
        under = fn[:, 2] < 0.0
        undercut_share = float(fa[under].sum() / total_area)
        if undercut_share > 0:
            log.warning("%.2f%% of the surface faces below the horizontal: not reachable in 3 axes",
                        100 * undercut_share)
        ext = mesh.V.max(0) - mesh.V.min(0)
        if max(ext[0], ext[1]) < 2.0 * r:  # a part in metres or inches reads as a speck
            log.warning("the part is %.3g x %.3g mm across, smaller than the ball (diameter %.3g mm): if its units "
                        "are not millimetres, scale it (--scale 1000 for metres, 25.4 for inches)", ext[0], ext[1],
                        2.0 * r)

    zmax = float(mesh.V[:, 2].max())
    top = zmax + max(stock, 0.0)  # the part as it stands before this program: with its stock
    safe_z = top + job.clearance if job.safe_z is None else float(job.safe_z)
    if safe_z < top + 0.5:
        raise PlanningError(f"safe-z {safe_z:.4f} is not above the part top {top:.4f} by 0.5 mm"
                            + (f" (with its {stock:g} mm of stock)" if stock > 0 else ""))

    flat_ls = float(side_interval(h, r, np.zeros(1))[0][0])
    spacing = _sample_spacing(mesh, flat_ls, job.max_step)
    _check_size(mesh, total_area, flat_ls, spacing=spacing)
    # Forward chord tolerance. Over a concave stretch the straight move rides above the
    # surface by up to the chord deviation, and that material adds to the scallop: with
    # e close to h the scallop reached about 1.4 h (measured, zigzag, h = e = 0.01). So the
    # chords keep within h / 4 (still "at most e"), and the planner takes the possible rise
    # off h where the path is concave along its direction (face sample, h = 0.1: reachable
    # p99.9 1.06 H -> see README).
    e_fwd = min(e, 0.25 * h)
    # Where the path is convex along its direction the chord dips into the part instead:
    # only the gouge budget bounds it, and the cutter stage checks every move against e/2.
    e_cvx = max(e_fwd, 0.5 * e)
    link_max = job.link_max if job.link_max is not None else max(2.0 * r, 4.0 * flat_ls)
    # forward steps and the cutter run on each piece as the pattern stage finishes it,
    # in a worker thread where numba allows (passes.py; it builds the cutter's index while
    # the map is solved); the program is the same either way
    builder = PassBuilder(lambda: BallCutter(mesh.V, mesh.F, r_cut), e, e_fwd, e_cvx, job.max_step, link_max,
                          threaded=threads_can_overlap(), settle_tol=job.settle * h,
                          hop_lift=job.hop_lift, rates=(job.feed, job.plunge_rate, job.rapid))
    background = None
    search_args = (mesh.V, mesh.F, h)
    search_kw = {"search": job.pencil_search, "density": job.pencil_density}
    # with pencil_left the centres are chained only once the pattern's passes tell which
    # to keep; else the search chains them at once
    filtered = job.pencil_left is not None
    chain_kw = {} if filtered else {"settle_tol": job.settle * h}
    draw = None  # the fill's samples: one draw for the pencil's search and the fill
    if job.fill is not None:
        from conformill.fill import FILL_DENSITY, FILL_SEED, fill_passes, fill_samples

        draw = (lambda cutter: fill_samples(cutter, mesh.V, mesh.F, FILL_DENSITY, FILL_SEED))
    if job.pencil and builder.threaded:
        from conformill.pencil import BackgroundChains

        # the pencil's search needs only the part and the ball: it runs beside the map and
        # the pattern stage, on the cutter the worker builds (the same chains either way);
        # the worker draws the fill's samples before its search, which uses them
        background = BackgroundChains(builder.wait_cutter, *search_args, chain=not filtered, draw=draw,
                                      **search_kw, **chain_kw)
    with builder, (background or nullcontext()):  # stop the workers if a stage fails
        say("parameterize", 0.0)
        with timer("parameterize"):
            boundary = "rectangle" if job.pattern == "zigzag" else "circle"
            param = parameterize(mesh, boundary=boundary, weights=job.weights, corners=job.corners)
        with timer("quality"):
            q = quality(mesh.V, mesh.F, param.uv)
        if q.flipped:
            raise PlanningError(f"the parameterization has {q.flipped} flipped faces; try --weights mean_value")
        say("parameterize", 1.0)

        say("frame", 0.0)
        with timer("frame"):
            # the mesh the planner sees: the input, or the same surface split at its edge
            # midpoints (Job.fit); the cutter works on the input either way
            fmesh, ffa, fuv = mesh, fa, param.uv
            if job.fit == "split":
                from conformill.mesh.split import split_midpoints

                Vs, Fs, fuv = split_midpoints(mesh.V, mesh.F, param.uv)
                fmesh = Mesh(V=Vs, F=Fs, name=mesh.name)
                ffa = face_normals(Vs, Fs)[1]
            surface = DomainSurface(fmesh.V, fmesh.F, fuv)

        with timer("reachability"):
            fr = surface.frame
            kmax_v = principal_concave(np.column_stack([fr.E, fr.F, fr.G]), np.column_stack([fr.L, fr.M, fr.N]))
            unreach_v = kmax_v >= 1.0 / r_cut  # the ball on the offset: r_cut on the part
            unreach_f = unreach_v[fmesh.F].sum(1) >= 2
            unreach_share = float(ffa[unreach_f].sum() / total_area)
            regions = _regions(unreach_f, fmesh, ffa)
            if unreach_share > 0:
                log.warning("%.2f%% of the surface is concave with a radius at or below the tool radius%s %.3g mm: "
                            "the ball cannot follow it there (largest region near %s)%s", 100 * unreach_share,
                            " plus the stock" if stock else "", r_cut,
                            np.round(regions[0]["centre"], 2).tolist() if regions else "?",
                            "" if job.pencil else "; --pencil adds passes where the ball wedges against them "
                            "(--scan: the settings for a scanned part, the pencil among them)")

        # dense sampling: about one edge of the mesh the planner sees (the input's unless split)
        seg_len = spacing if fmesh is mesh else _sample_spacing(fmesh, flat_ls, job.max_step)
        sigma = np.median(q.sigma[np.isfinite(q.sigma) & (q.sigma > 0)])
        delta = seg_len / sigma
        # the pattern's paths: spaced for pattern_scallop h (wider only with the fill stage)
        pparams = params if job.pattern_scallop == 1.0 else replace(params, scallop=job.pattern_scallop * h)
        check_meetable(pparams)
        planner = Planner(surface, pparams, seg_len, concave_cap=flat_ls if job.concave_steps == "flat" else None,
                          rise_tol=e_fwd, max_step=job.max_step,
                          base_scallop=h if job.pattern_scallop > 1.0 else None)

        say("frame", 1.0)
        # the pattern stage is serial: its kernels on this thread alone while the workers
        # hold the other cores (passes.serial_caller; the same program either way)
        with timer("pattern"), serial_caller(builder.threaded):
            prog = (lambda f: say("pattern", f))
            adaptive = job.spacing in ("adaptive", "local")
            local = job.spacing == "local"
            if job.pattern == "zigzag":
                X, Y = param.domain
                domain = plan_zigzag(planner, X, Y, delta, progress=prog, adaptive=adaptive, local=local,
                                     emit=builder.add)
            else:
                uvb = param.uv[param.boundary]
                poly = BoundaryPolygon(uvb)
                if job.pattern == "contour":
                    domain = plan_contour(planner, poly, delta, progress=prog, adaptive=adaptive,
                                          local=local, emit=builder.add)
                else:
                    domain = plan_spiral(planner, poly, delta, progress=prog, adaptive=adaptive,
                                         emit=builder.add)
        if background is not None and not filtered:
            # the pencil's links start from where the passes end: the worker links while
            # the cutter finishes, and the result is used only if the passes end there
            end = builder.end_xy()
            if end is not None:
                background.link_from(end, e, link_max)
        say("cutter", builder.fraction_cut())
        left, early = None, []  # the pencil's filter and the passes it read while the cutter worked
        fill_rows = None  # the fill's samples' test, fed with the same passes meanwhile
        shown = ["cutter"]  # the stage the progress shows while the search is waited for
        if background is not None and filtered:
            from conformill.pattern_rest import centre_moves, move_grid
            from conformill.pencil import LeftToCut

            # the pencil's filter reads the passes cut so far while the cutter works on
            # the rest, then only the rest (the same centres kept as from all at once)
            def waiting(f):  # the cutter's own error first, as soon as it fails
                builder.check()
                cut = builder.fraction_cut()
                if cut < 1.0:
                    say("cutter", cut)
                else:  # all cut: the search is what the plan waits for
                    shown[0] = "pencil"
                    say("pencil", 0.8 * f)

            with timer("pencil"):
                try:
                    found = background.result(wait=waiting)
                except BaseException:
                    builder.check()  # a worker that failed left the search without a cutter
                    raise
                timer.t["pencil_busy"] = background.busy_s
                with timer("pencil_left"):
                    left = LeftToCut(found, r_cut, job.pencil_left * h)
                    early = builder.passes_so_far()
                    # the moves binned once for the pencil's filter and the fill
                    early_moves = move_grid(*centre_moves(early, r_cut))
                    left.add_grid(early_moves)
                if draw is not None:
                    from conformill.fill import FillRows

                    with timer("fill"):  # its samples' grid balls and their test of the passes so far
                        fill_rows = FillRows(builder.cutter, background.drawn(), h, depth=job.fill, grid=found.grid)
                        fill_rows.add_grid(early_moves)
        t_wait = time.perf_counter()
        passes, pass_ids, lifts, hops = builder.finish(
            progress=(lambda f: say("cutter", f)) if shown[0] == "cutter" else None)
        t_wait = time.perf_counter() - t_wait
        # forward and cutter: busy time (beside the pattern stage when threaded; then
        # cutter_wait is how long the plan waited for the cutter after the last path)
        timer.t.update(builder.timings)
        if builder.threaded:
            timer.t["cutter_wait"] = t_wait
        cc_paths, fwd_steps, n_retracts_link = builder.cc_paths, builder.fwd_steps, builder.n_retracts_link
        n_settled, n_unsettled = builder.n_settled, builder.n_settle_unresolved
        hop_stats = {"lift_mm": job.hop_lift, "hops": builder.n_hops, "cc_points_not_cut": builder.n_hopped,
                     "minutes_saved": builder.hop_saved}
        pencil = None
        fold_grid = None  # the fold search's grid of drops (conformill.folds.DropGrid)
        drawn = None  # the fill's samples, drawn once for the pencil's search and the fill
        if job.pencil or job.fill is not None:  # their cutter: the worker's, or built once here (nothing cut)
            cutter = builder.cutter if builder.cutter is not None else BallCutter(mesh.V, mesh.F, r_cut)
            if draw is not None:
                with timer("fill"):  # the worker's draw, or drawn here
                    drawn = background.drawn() if background is not None else draw(cutter)
                if background is not None:  # the worker's time for it, before its search
                    timer.t["fill_draw"] = background.draw_s
        if job.pencil:
            from conformill.pattern_rest import centre_moves, move_grid
            from conformill.pencil import LeftToCut, chains_of, link_chains, pencil_chains, pencil_search

            say("pencil", 0.0)
            with timer("pencil"):  # beside the other stages: the wait for the search and links
                start = passes[-1][-1, :2] if passes else mesh.V[:, :2].mean(axis=0)
                if filtered:  # the centres where the pattern left more than pencil_left h
                    if left is None:
                        found = pencil_search(cutter, *search_args, **search_kw, drawn=drawn,
                                              progress=lambda f: say("pencil", 0.8 * f))
                        left = LeftToCut(found, r_cut, job.pencil_left * h)
                    with timer("pencil_left"):
                        # the moves after those already read: the rest of the last pass
                        # read in part, then the passes after it
                        rest = [passes[len(early) - 1][len(early[-1]) - 1:]] if early else []
                        rest_moves = move_grid(*centre_moves(rest + passes[len(early):], r_cut))
                        left.add_grid(rest_moves)
                        keep = left.keep()
                    if fill_rows is not None:
                        with timer("fill"):
                            fill_rows.add_grid(rest_moves)
                    cut = keep & found.probed
                    n_fold = found.stats["centres"]  # the fold points, then the steep centres
                    found = replace(found, stats={**found.stats, "left_h": float(job.pencil_left),
                                                  "fold_points_cut": int(np.count_nonzero(cut[:n_fold])),
                                                  "steep_centres_cut": int(np.count_nonzero(cut[n_fold:]))})
                    fold_grid = found.grid  # the fill stage's balls, when it runs
                    found = chains_of(cutter, found, 1, job.settle * h, keep)
                    pencil = link_chains(cutter, found, e, link_max, start)
                elif background is not None:
                    pencil = background.linked(start, e, link_max, wait=lambda f: say("pencil", 0.9 * f))
                    timer.t["pencil_busy"] = background.busy_s + background.link_s
                    if pencil is None:  # the passes did not end where the builder expected
                        pencil = link_chains(cutter, background.result(), e, link_max, start)
                else:
                    found = pencil_chains(cutter, *search_args, **search_kw, **chain_kw, drawn=drawn,
                                          progress=lambda f: say("pencil", 0.9 * f))
                    pencil = link_chains(cutter, found, e, link_max, start)
                n_pattern = len(passes)
                passes, pass_ids, hops = _after(cutter, passes, pass_ids, hops, pencil.passes, job.hop_lift > 0)
        fill = None
        if job.fill is not None:
            say("fill", 0.0)
            with timer("fill"):
                start = passes[-1][-1, :2] if passes else mesh.V[:, :2].mean(axis=0)
                # with the samples' test made while the cutter worked: only the pencil's passes are new to it
                fill = fill_passes(cutter, mesh.V, mesh.F, passes if fill_rows is None else passes[n_pattern:], h,
                                   depth=job.fill, tol=e, link_max=link_max, start_xy=start, density=FILL_DENSITY,
                                   seed=FILL_SEED, settle_tol=job.settle * h, grid=fold_grid, samples=drawn,
                                   rows=fill_rows, progress=lambda f: say("fill", f))
                passes, pass_ids, hops = _after(cutter, passes, pass_ids, hops, fill.passes, job.hop_lift > 0)
    if stock:  # the tips so far are those of the ball of radius r_cut: the ball of radius r is stock higher
        lift = np.array([0.0, 0.0, stock])
        passes = [p + lift for p in passes]
        hops = [None if hp is None else tuple(z + stock for z in hp) for hp in hops]
    toolpath = ToolPath(passes=passes, safe_z=safe_z, pass_ids=pass_ids, hops=hops)

    # -- figures -----------------------------------------------------------------
    lift_all = np.concatenate(lifts) if lifts else np.zeros(0)
    fwd_all = np.concatenate(fwd_steps) if fwd_steps else np.zeros(0)
    allowed = np.concatenate([p.side_allowed for p in domain.paths[:-1]]) if len(domain.paths) > 1 else np.zeros(0)
    realised = np.concatenate([p.side_realised for p in domain.paths[:-1]]) if len(domain.paths) > 1 else np.zeros(0)
    predicted = np.concatenate([p.side_predicted for p in domain.paths[:-1]]) if len(domain.paths) > 1 else np.zeros(0)
    ok = np.isfinite(realised) & np.isfinite(predicted) & (predicted > 0)
    lin_err = 100 * np.abs(predicted[ok] - realised[ok]) / predicted[ok]
    util = 100 * realised[np.isfinite(realised)] / allowed[np.isfinite(realised)]
    report = {
        "conformill_version": __version__,
        "mesh": {"name": mesh.name, "vertices": mesh.n_vertices, "faces": mesh.n_faces,
                 "bbox_min": mesh.V.min(0), "bbox_max": mesh.V.max(0), "area_mm2": total_area},
        "job": {"pattern": job.pattern, "tool_radius": r, "scallop": h, "tolerance": e, "feed": job.feed,
                "plunge_feed": job.plunge_rate, "safe_z": safe_z, "orient": job.orient,
                "weights": job.weights, "max_step": job.max_step, "link_max": link_max,
                "forward_chord_tolerance": e_fwd, "forward_chord_tolerance_convex": e_cvx,
                "concave_steps": job.concave_steps, "spacing": job.spacing, "settle": job.settle,
                "fit": job.fit, "pencil": job.pencil, "pencil_density": job.pencil_density,
                "pencil_search": job.pencil_search, "pencil_left": job.pencil_left, "fill": job.fill,
                "pattern_scallop": job.pattern_scallop,
                "blend": "off" if job.blend_tolerance is None else job.blend_tolerance,
                "tool_number": job.tool_number, "coolant": job.coolant, "spindle": job.spindle, "stock": stock},
        "orientation": orient_info,
        "parameterization": {"boundary": param.kind, "domain": param.domain, "corners": param.corners,
                             "solver": param.solver, "residual": param.residual, "fallbacks": param.fallbacks,
                             "quality": q.as_dict()},
        "paths": {"planned_paths": len(domain.paths), "passes": len(passes),
                  "retracts_for_long_links": n_retracts_link,
                  "cc_points": int(sum(len(c) for c in cc_paths)),
                  "cl_points": int(sum(len(p) for p in passes)),
                  "step_shrinks_3d_check": domain.shrink_iterations,
                  "dense_sample_spacing_mm": seg_len},
        "side_step": {"flat_interval_mm": flat_ls, "allowed_mm": _stats(allowed), "realised_mm": _stats(realised),
                      "utilisation_pct": _stats(util)},
        "forward_step": {"mm": _stats(fwd_all)},
        "error_analysis": {
            "linearisation_pct": _stats(lin_err),
            "note": "METHOD section 6: |l_s' - d| / l_s' with l_s' = sqrt(EG-F^2)/|r_t| * step, the side interval "
                    "the metric predicts for the domain step taken, and d the true 3D distance to the next path; "
                    "utilisation = d / allowed l_s (the paper's min rule leaves it below 100% away from the "
                    "point that sets the step)",
        },
        "cutter": {"lift_mm": _stats(lift_all), "settled_points": n_settled,
                   "settle_unresolved_moves": n_unsettled, "hops": hop_stats,
                   "lift_over_tolerance_share": float(np.mean(lift_all > e)) if lift_all.size else 0.0},
        "pencil": pencil.stats if pencil is not None else None,
        "fill": fill.stats if fill is not None else None,
        "reachability": {"undercut_share": undercut_share,
                         "concave_below_tool_radius_share": unreach_share, "concave_regions": regions},
        "timings_s": timer.t,
    }
    say("done", 1.0)
    result = PlanResult(toolpath=toolpath, param=param, domain_paths=domain, cc_paths=cc_paths,
                        mesh=mesh, report=report)
    return result


def with_overrides(job: Job, **kw) -> Job:
    """A copy of ``job`` with fields replaced (None values ignored)."""
    return replace(job, **{k: v for k, v in kw.items() if v is not None})
