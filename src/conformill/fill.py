"""Fill passes where the program's own passes left more than a depth (issue 5, session 53).

The pattern's paths are spaced by the rule of :mod:`conformill.planning.steps` from the
curvature fitted at each vertex, and a row of a zigzag takes the least step along it. On a
scan most of a row is then far closer to its neighbour than the scallop needs (on igea the
verified scallop's median is 0.16 h where its 99.9th percentile is 1.04 h), while a few
places, which the fit cannot see, need it closer still. This stage measures instead of
predicting: once the passes are cut, it asks at area-uniform surface samples whether the
passes came within the depth (:class:`conformill.pattern_rest.UncutRows`, the bound the
pencil's filter uses: the distance from the sample to the centre moves, less the radius),
and cuts fill passes through balls that reach the samples they left. With it the pattern's
paths can be spaced wider (``Job.pattern_scallop``): ``plan --scan`` spaces them for 1.3 h
and fills where they leave more than 0.7 h.

A sample's ball. Among the balls dropped on an XY grid of the sample spacing (the nodes
around the sample's tangent ball, 4 x 4), the one whose sphere comes nearest the sample;
it is kept when it comes within ``give`` (0.5 h) of it. A sample no grid ball reaches that
close but one comes within :data:`FILL_SEARCH_NEAR` h of, and which the passes left, can be
searched for its best ball from its tangent ball (:func:`conformill.pencil.best_centres`, the
pencil's model search), kept when it comes within the give: the grid's window, +-0.27 mm
around the tangent ball, misses the balls that reach a sample from farther off it. At 2 h
it lowers every mesh's scallop a little for 0.3 s more per plan on igea, so it is off by
default (session 61, docs/issue5.md). A sample no ball
reaches that close lies in a pocket tighter than the ball, under an overhang or on a steep
wall: rest that the pencil passes (``Job.pencil``) are for, not the fill. The kept balls are thinned,
chained, settled, linked and refined as the pencil's centres are
(:func:`conformill.pencil.chains_of`, :func:`conformill.pencil.link_chains`).

Session 53 (``python benchmarks/bench_raster.py --scan``, every mesh, r = 4, h = e = 0.01,
the harness's 400k-sample judge): with the paths spaced for 1.3 h and the fill above 0.7 h,
27 of the 33 ``--scan`` programs pass where 25 did; on the scans they are up to 11 % shorter
(igea 7-9 %), and igea's plans took 1.7-2.7 s longer, 0.8-1.0 s of it this stage's. On
smooth CAD parts the rows leave more than 0.7 h along most of each gap and the fill would
cut it all: :func:`conformill.pipeline.plan` then plans again without the widening
(docs/issue5.md, "Session 53").
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from conformill.errors import PlanningError

__all__ = ["FILL_DENSITY", "FILL_GIVE", "FILL_SEARCH_NEAR", "FILL_SEED", "FillResult", "FillRows", "fill_balls",
           "fill_passes", "fill_samples"]

log = logging.getLogger(__name__)

#: A sample's ball is kept when its sphere comes within this many h of the sample.
FILL_GIVE = 0.5
#: Surface samples per mm^2 and their seed: the defaults of :func:`fill_samples` and
#: :func:`fill_passes`, one constant for both (the pipeline draws the samples in the
#: pencil's worker and hands them to :func:`fill_passes`; they must be the same draw).
FILL_DENSITY = 30.0
FILL_SEED = 0
#: Grid nodes per side around a sample's tangent ball among which its ball is chosen.
_NODES = 4
#: A sample whose nearest grid ball lies beyond the give but within this many h, and
#: which the passes left, is searched for a ball (:func:`conformill.pencil.best_centres`,
#: session 61). Off (the give itself: none searched) by default: at 2 h, on igea's zigzag
#: `--scan` 10753 samples are searched and 281 reached (of the 324 that a search of all
#: 128675 unreached samples reaches in 0.9 s), and every mesh's programs leave as little
#: or less (igea 1.021 / 1.019 / 1.010 h against 1.025 / 1.026 / 1.017 h, the lion relief
#: 1.093-1.129 h against 1.119-1.157 h) for 0.3-1 % more feed; but igea's plans take
#: 0.27-0.29 s longer (4.52 / 4.97 s against 4.23 / 4.70 s, zigzag / spiral, alternating
#: plans), against issue 5's time target (docs/issue5.md, "Session 61").
FILL_SEARCH_NEAR = FILL_GIVE


@dataclass(frozen=True)
class FillResult:
    """The fill stage's passes (ball centres, linked and refined) and figures.

    Attributes
    ----------
    passes : list of (k, 3) float64
        Ball-centre passes, in cutting order.
    stats : dict
        ``samples``, ``reached`` (samples a grid ball comes within the give of),
        ``searched`` (samples the passes left whose nearest grid ball lies beyond the give and
        within :data:`FILL_SEARCH_NEAR` h), ``searched_reached`` (of those, the samples a
        searched ball comes within the give of), ``balls`` (the samples the passes left more
        than the depth that a grid ball or a searched one reaches: one ball each, before
        thinning), ``chains``, ``passes``, ``cl_points``, ``feed_mm``, ``density_per_mm2``,
        ``depth_h``.
    """

    passes: list
    stats: dict = field(default_factory=dict)


def _check(**values):
    """PlanningError unless each value (named by its keyword, ``_`` for a space) is a
    positive number."""
    for name, v in values.items():
        if not (math.isfinite(v) and v > 0):
            raise PlanningError(f"fill: {name.replace('_', ' ')} must be a positive number, got {v}")


@njit(cache=True, nogil=True, parallel=True)
def _nearest_balls(P, N, r, x0, y0, g, nx, ny, z):
    """Per sample: the node among the 4 x 4 around its tangent ball's XY whose ball (centre
    height ``z[node]``, -inf: none) comes nearest the sample, as ``(node, distance of its
    sphere from the sample)``; ``(-1, inf)`` where none of them has a ball."""
    k = P.shape[0]
    node = np.full(k, -1, dtype=np.int64)
    dist = np.full(k, np.inf)
    for s in prange(k):
        tx = P[s, 0] + r * N[s, 0]
        ty = P[s, 1] + r * N[s, 1]
        i0 = int(math.floor((tx - x0) / g)) - (_NODES // 2 - 1)
        j0 = int(math.floor((ty - y0) / g)) - (_NODES // 2 - 1)
        for dj in range(_NODES):
            j = min(max(j0 + dj, 0), ny - 1)
            for di in range(_NODES):
                i = min(max(i0 + di, 0), nx - 1)
                c = j * nx + i
                zc = z[c]
                if not zc > -np.inf:
                    continue
                dx = x0 + g * i - P[s, 0]
                dy = y0 + g * j - P[s, 1]
                dz = zc - P[s, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz) - r
                if d < dist[s]:
                    dist[s] = d
                    node[s] = c
    return node, dist


def _grid_balls(cutter, P, N, density, grid=None):
    """For samples ``P`` (normals ``N``): the ball of the XY grid (spacing ``1 /
    sqrt(density)`` over the cutter's part, :func:`conformill.folds.grid_shape`) nearest each
    sample among the 4 x 4 nodes around its tangent ball's XY (:func:`_nearest_balls`), and
    how far its sphere lies from the sample (mm; inf where no node has a ball). The heights
    are ``grid``'s (this cutter's fold grid, :class:`conformill.folds.DropGrid`) when it has
    that spacing; else the grid is dropped here (:func:`conformill.folds.drop_grid`)."""
    from conformill.folds import drop_grid

    g = 1.0 / math.sqrt(density)
    if grid is None or grid.spacing != g:
        grid = drop_grid(cutter, g)[0]
    z = np.ascontiguousarray(grid.z, dtype=np.float64)
    node, d = _nearest_balls(np.ascontiguousarray(P), np.ascontiguousarray(N), float(cutter.radius), grid.x0,
                             grid.y0, g, grid.nx, grid.ny, z)
    ok = node >= 0
    C = np.full((len(P), 3), np.nan)
    C[ok] = np.column_stack([grid.x0 + g * (node[ok] % grid.nx), grid.y0 + g * (node[ok] // grid.nx), z[node[ok]]])
    return C, d, g


def fill_passes(cutter, V, F, passes, h: float, *, depth: float, tol: float, link_max: float, start_xy,
                density: float = FILL_DENSITY, settle_tol: float = 0.0, seed: int = FILL_SEED, give: float = FILL_GIVE,
                grid=None, samples=None, rows=None, progress=None) -> FillResult:
    """Fill passes through the balls that reach the surface samples ``passes`` left more
    than ``depth * h`` (see the module's text).

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
    V, F : arrays
        The part.
    passes : list of (k, 3) float64
        The tool-tip passes cut so far (the ball is the cutter's: centres ``radius`` above).
    h : float
        The scallop height (mm).
    depth : float
        Fill where the passes left more than ``depth * h`` (by the distance bound).
    tol : float
        The chord tolerance: the fill's moves are refined to cut at most ``tol / 2`` into
        the part.
    link_max : float
        Chains whose ends lie within this (mm) are joined by a straight move.
    start_xy : (2,) float
        Where the tool is when the fill starts (the last pass's end).
    density : float
        Surface samples per mm^2 (the grid's nodes are as far apart as the samples).
    settle_tol : float
        The chains are settled to this float (mm; 0: not).
    seed : int
    give : float
        A ball is kept for a sample when its sphere comes within ``give * h`` of it.
    grid : conformill.folds.DropGrid, optional
        This cutter's fold grid: its heights are used when it has the fill's spacing, with
        the same balls as dropping them anew.
    samples : conformill.pencil.SurfaceDraw, optional
        What :func:`fill_samples` returned for this part, ``density`` and ``seed``, when
        drawn beforehand (the pipeline draws them once, in the pencil's worker where it
        runs, for the pencil's search and the fill).
    rows : FillRows, optional
        The samples' test made beforehand for this cutter, ``h``, ``depth``, ``give`` and
        ``grid`` on ``samples``, with the passes so far handed over: only those of ``passes``
        after them are added (:meth:`FillRows.add`; ``passes`` is then only those). The
        pipeline makes it while the cutter works.
    progress : callable, optional
        ``progress(fraction)``.

    Returns
    -------
    FillResult

    Raises
    ------
    PlanningError
        ``h``, ``depth`` or ``density`` is not a positive number.
    """
    from conformill.pencil import PencilFound, chains_of, link_chains

    _check(scallop=h, fill_depth=depth, fill_density=density)
    say = progress or (lambda f: None)
    drawn = fill_samples(cutter, V, F, density, seed) if samples is None else samples
    say(0.1)
    if rows is None:
        rows = FillRows(cutter, drawn, h, depth=depth, give=give, grid=grid)
    rows.add(passes)
    B, _, counts, g = rows.balls()
    say(0.7)
    found = PencilFound(centres=B, probes=np.full((len(B), 1, 3), np.nan), spacing=g, stats={})
    chains = chains_of(cutter, found, 1, settle_tol)
    out = link_chains(cutter, chains, tol, link_max, start_xy)
    say(1.0)
    stats = {"samples": int(len(drawn.P)), **counts, "balls": int(len(B)),
             "chains": int(chains.stats["chains"]), "passes": int(out.stats["passes"]),
             "cl_points": int(out.stats["cl_points"]), "feed_mm": float(out.stats["feed_mm"]),
             "density_per_mm2": float(drawn.density), "depth_h": float(depth)}
    return FillResult(passes=out.passes, stats=stats)


class FillRows:
    """The fill's samples and the test of what the passes left at them, fed with the passes
    in parts (:meth:`add_grid`; the same balls as :func:`fill_balls` once every pass is in).

    Made, the nearest grid ball of each sample of ``drawn`` is found (:func:`_grid_balls`)
    and the samples one comes near are kept for the passes' test
    (:class:`conformill.pattern_rest.UncutRows`, hinted at the tangent balls' XY). Neither
    needs the passes, so the pipeline makes this, and hands over the pattern's passes cut
    so far, while the cutter works on the rest, sharing the moves' grid with the pencil's
    filter (:class:`conformill.pencil.LeftToCut`).

    Parameters
    ----------
    cutter, drawn, h, depth, give, grid
        As for :func:`fill_balls`.
    """

    def __init__(self, cutter, drawn, h: float, *, depth: float, give: float = FILL_GIVE, grid=None):
        from conformill.pattern_rest import UncutRows

        self._cutter, self._drawn, self._h, self._give = cutter, drawn, float(h), float(give)
        r = cutter.radius
        P, N = drawn.P, drawn.N
        # the samples a grid ball comes within give of, then those the passes left: the same
        # balls as the other way round, with the passes' test on fewer samples; and those a grid
        # ball comes within FILL_SEARCH_NEAR h of, not within give: searched if left
        self._C, d, self.spacing = _grid_balls(cutter, P, N, drawn.density, grid)
        self._near = np.flatnonzero(d <= give * h)
        self._close = np.flatnonzero((d > give * h) & (d <= FILL_SEARCH_NEAR * h))
        both = np.concatenate([self._near, self._close])
        self._rows = UncutRows(P[both], r, depth * h, hints=P[both, :2] + r * N[both, :2])  # the tangent balls' XY

    def add(self, passes) -> None:
        """More tip passes (a list of ``(k, 3)``)."""
        from conformill.pattern_rest import centre_moves

        self._rows.add(*centre_moves(passes, self._cutter.radius))

    def add_grid(self, grid) -> None:
        """More passes, as their centre moves binned (:func:`conformill.pattern_rest.move_grid`
        of :func:`conformill.pattern_rest.centre_moves` with the cutter's radius)."""
        self._rows.add_grid(grid)

    def balls(self):
        """The balls after the passes so far: :func:`fill_balls`' ``(centres, which, counts,
        spacing)``."""
        from conformill.pencil import best_centres

        left = self._rows.uncut()
        near, close = self._near, self._close
        keep = near[left[:near.size]]
        close = close[left[near.size:]]
        d = self._drawn
        Cs, rest, state = best_centres(self._cutter, d.P[close], d.N[close], d.faces[close], low=0.0,
                                       give_up=self._give * self._h)
        # state 0: the tangent ball itself comes within low = 0 (its centre, on the drop surface)
        ok = (state <= 1) & (rest <= self._give * self._h) & np.isfinite(Cs[:, 2])
        counts = {"reached": int(near.size), "searched": int(close.size), "searched_reached": int(ok.sum())}
        return np.vstack([self._C[keep], Cs[ok]]), np.concatenate([keep, close[ok]]), counts, self.spacing


def fill_balls(cutter, drawn, passes, h: float, *, depth: float, give: float = FILL_GIVE, grid=None):
    """The fill's balls: one per sample of ``drawn`` (a :class:`conformill.pencil.SurfaceDraw`)
    that the tip ``passes`` left more than ``depth * h`` (by the distance bound) and that a
    ball reaches within ``give * h``: the nearest grid ball (:func:`_grid_balls`), or, where
    that one lies beyond the give and within :data:`FILL_SEARCH_NEAR` h, the ball the
    pencil's model search finds from the tangent ball (:func:`conformill.pencil.best_centres`).
    :class:`FillRows` with all the passes at once.

    Returns
    -------
    centres : (k, 3) float64
        The grid balls first, then the searched ones; each on the drop surface.
    which : (k,) int64
        Each ball's sample (row of ``drawn``).
    counts : dict
        ``reached`` (samples a grid ball comes within the give of), ``searched``,
        ``searched_reached``.
    spacing : float
        The grid's spacing (mm).
    """
    rows = FillRows(cutter, drawn, h, depth=depth, give=give, grid=grid)
    rows.add(passes)
    return rows.balls()


def fill_samples(cutter, V, F, density: float = FILL_DENSITY, seed: int = FILL_SEED):
    """The fill's area-uniform surface samples facing the tool
    (:func:`conformill.pencil.surface_samples`), a :class:`conformill.pencil.SurfaceDraw`:
    the density lowered, with a warning, where the part would give more samples or grid
    points than the pencil's caps (a huge part: wrong units?)."""
    from conformill.folds import _MAX_GRID, _grid_box
    from conformill.pencil import _MAX_SAMPLES, _face_areas, draw_samples

    _check(fill_density=density)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    areas = _face_areas(V, F)
    lo, hi = _grid_box(cutter)
    most = min(0.9 * _MAX_GRID / float(np.prod(hi - lo)), _MAX_SAMPLES / float(areas.sum()))
    if density > most:  # as the pencil does: a huge part (wrong units?) gets a lower density
        log.warning("fill: %.3g samples per mm^2 over this part would be more than %dM samples or grid points; "
                    "using %.3g per mm^2", density, _MAX_SAMPLES // 10**6, most)
        density = most
    return draw_samples(V, F, density, seed, areas=areas)
