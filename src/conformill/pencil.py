"""Pencil stage: clean-up passes through the best ball positions a pattern's passes miss.

Where the part is tighter than the ball (facet creases and pits of a scan, the rims of
concave regions of radius below ``r``), even the best ball position leaves material at a
surface point ``p``: the *rest* (:mod:`conformill.verify.rest` measures it). A pattern
spaced for the scallop height ``h`` crosses such places at its own passes only, and
between them leaves its scallop on top of the rest: on igea (a face scan, r = 4, h =
0.01 mm) the samples left above 1.05 h are almost all there. CAM's answer is *pencil*
machining: passes along the places where the ball sits wedged against the part.

Two searches find those places. ``search="folds"`` (session 23) visits the folds of
the drop surface where they cross an XY grid (:mod:`conformill.folds`): a
wedged ball's centre lies on such a fold, and its *shadow* (the part between its two
contacts) is what it leaves; fold points whose shadow is deeper than ``low h`` are
centres. Where the part is steeper than 78 deg (sample normal ``n_z < 0.2``) a fold
projects to a short XY segment that the grid crosses too rarely, so the samples there are
searched one by one as below, and their band centres join the fold points. When the
pattern's rest filters the centres (``Job.pencil_left``, as ``plan --scan`` does), each
steep centre is probed at its sample, and the band's lower end no longer applies there:
every searched steep sample (its tangent ball leaves more than ``low h``) whose best ball
leaves at most ``h`` gives a centre, cut where the pattern left more than the filter's
depth at the sample. A best ball that comes within ``low h`` off the tangent one is not one
the pattern or the fill need place (session 61: with the model search below, the shipped
lion's contour left 1.37 h without this, 1.18 h with it; docs/issue5.md). Against the
per-sample search on the eight scans measured, this left a lower verified scallop on
five, the same on two and a higher one on the lion relief (which fails either way), in
18-51 % less time, but for 1-15 points more feed (+16 % against +10 % on igea: twelve
minutes of machine time for 0.9 s of planning), so it is not the default (docs/issue5.md,
"Pencil passes", session 23). The default, ``search="samples"`` (sessions 21-22), finds
the places from the rest itself, sample by sample, everywhere. For area-uniform samples
of the part it
finds the ball centre on the drop surface ``D`` (the lowest centre over each ``(x, y)``,
:class:`conformill.cutter.BallCutter`) that leaves least material along the sample's
normal; the centres of the samples whose rest lies in ``(low h, h]`` (reachable within
``h``, and not already left within ``low h`` by the ball that touches the sample) are
thinned, chained into polylines, settled into the valleys between them, refined
(gouge-safe) and cut as extra passes after the pattern.

The search per sample works on a *working-set model* of ``D``: the drop height over a
few triangles only (``D_W <= D``, cheap to evaluate), starting from the sample's own
triangle and the contact of the tangent ball (the ball touching ``p`` along its normal,
dropped). The best centre of the model is searched on a grid of 7 x 7 centres over
+-0.2 r around the tangent centre, then by a Nelder-Mead simplex from the best of them
(:func:`_simplex`: first sides r/60, ended below 0.0004 r or after 60 evaluations). Sessions
22-60 refined on grids of 7 x 7 over +-r/20 and 5 x 5 over +-r/80, +-r/320 and +-r/1280
(:func:`conformill.verify.rest.rest_material`'s shape): on igea's steep walls the simplex
takes 20 % less time with half the evaluations, and against a much finer grid search its
rest is higher on 2.6 % of the samples where the grids' was on 35 % (session 60). One
true drop at the model's best centre, with the model's height as floor, tells whether a
triangle of the part rises above the model there; if so it joins the working set and the
model is searched again (from the best centre, by the simplex alone), else the centre
is on ``D`` and its value is exact. Since ``D_W <= D`` point by point, a lower ball is not
missed for want of a triangle, only for want of the search's resolution, as in the full
search. A sample whose model search already ends above 1.05 h is given up (no pass for it):
the model only rises as triangles join; a better ball the local search does not reach can
be missed there, as anywhere in such a search. A sample
under an overhang is not searched at all (:func:`_roofed`: one triangle above its normal up
to the give-up distance proves that no ball from above gets that close; session 37, 20863
of igea's 35249 given-up steep-wall samples). On igea (r = 4, h = 0.01) the working set settles after one
or two rounds; with 1M samples the stage found 60331 centres with a rest in (0.15 h, h]
against the 60679 of session 12's search with true drops (9 x 9 grids, about 405 drops
per sample), and the passes through them leave the same 1.024 h, for about 1/30 of that
search's time (10.5 s against 287-367 s; session 21, measured with this search as a
prototype before it moved here; docs/issue5.md "Pencil passes").

The stage is two steps: :func:`pencil_chains` (the search, :func:`pencil_search`, then
the chains and their settling, :func:`chains_of`: it needs only the part and the ball, so
the pipeline runs it in a worker thread beside the pattern stage, :class:`BackgroundChains`)
and :func:`link_chains` (the cutting order from the pattern's last point, the links and the
gouge-safe refinement); :func:`pencil_passes` runs both.

With the fold search, ``Job.pencil_left`` (``--pencil-left F``, session 31) cuts only the
fold points where the pattern's own passes left more than ``F h`` in the shadow (at a
quarter, half or three quarters of the way between the contacts; :func:`where_left`, by the
distance bound of :mod:`conformill.pattern_rest`): elsewhere the pattern already cut most
of what the wedged ball would. The worker then runs only the search, and the chains are made
once the pattern's passes are known. At ``F = 0.5`` on igea zigzag it cut 6 % of the feed
(171.5 to 161.3 m) for the same verified scallop (1.036 / 1.038 h; docs/issue5.md, "Pencil passes").

The samples are drawn per unit area (``density``), with vertex normals interpolated (as
``verify`` judges). The passes need them dense: each centre found is a point of a pass,
and the passes join centres that lie within 3.3 sample spacings of each other. On igea's
default contour (session 21's final code) 20 / 30 samples per mm^2 leave 1.026 / 1.018 h at
p99.9 for 14.7 / 16.6 m more feed (8 / 9 %), the stage taking about 7 s on 2 cores (plan with
it minus plan without, in one run; about 20 us of CPU per sample, 19 % less since session
22's smaller grids, ``benchmarks/bench_pencil.py``); earlier, before lone centres were kept,
43 per mm^2 left 1.010 h. Samples whose rounds ran out (state 3,
:func:`best_centres`) give no pass.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numba import get_num_threads, njit, prange

from conformill.cutter import _drop_point, _drop_scratch, _set_drop, cell_at, xy_barycentric
from conformill.errors import PlanningError
from conformill.passes import feed_length
from conformill.types import PENCIL_SEARCHES

__all__ = ["SEARCHES", "LeftToCut", "PencilChains", "PencilFound", "PencilResult", "SurfaceDraw", "best_centres",
           "chains_of", "draw_samples", "link_chains", "pencil_chains", "pencil_passes", "pencil_search",
           "surface_samples", "where_left"]

log = logging.getLogger(__name__)

#: The model search's coarse grid around the tangent centre: its half-width (units of r)
#: and its points per side.
_COARSE_SPAN = 0.2
_COARSE_GRID = 7
#: Then a Nelder-Mead simplex from the best centre so far: its first side (units of r),
#: the size at which it ends (units of r: about the last refining grid's step of sessions
#: 22-60) and the most evaluations it makes.
_SIMPLEX_SIDE = 1.0 / 60.0
_SIMPLEX_END = 0.0004
_SIMPLEX_EVALS = 60
#: Most triangles in a sample's working set, and most rounds of the search.
_MAX_W = 32
_MAX_ROUNDS = 24
#: A sample whose model rest exceeds this many h after a round is given up on: the model
#: is a lower bound, so its true rest is beyond h too (no pass for it).
_GIVE_UP = 1.05
#: Samples per thread task (consecutive samples lie close: better cache use).
_CHUNK = 256
#: Margin (mm) of the roof test (:func:`_roofed`) over rounding: the triangle must be this
#: much higher than the segment it roofs.
_ROOF_SLACK = 1e-9
#: With the fold search, samples whose normal has ``n_z`` below this (walls steeper than
#: 78 deg) are searched one by one too: the XY grid crosses the folds there too rarely
#: (session 23: on camelhead 61 % of the band centres of such samples lay more than 0.1 mm
#: from a fold point, 3.6 % of the others; such samples are 15-21 % of a scan's).
_STEEP_NZ = 0.2
#: The searches :func:`pencil_passes` knows.
SEARCHES = PENCIL_SEARCHES
#: Where between a fold point's two contacts the pattern's rest is read (``Job.pencil_left``;
#: session 30's ``benchmarks/bench_pencil_filter.py`` read the same three).
_SHADOW_AT = (0.25, 0.5, 0.75)
#: Fold grid edges whose two contacts lie at most this many grid spacings apart are not
#: searched (:func:`fold_jump`): on smooth ground the contact moves ``s rho / (rho - r)``
#: along an edge of length ``s`` where the part is concave with radius ``rho``, within 1.6 s
#: where ``rho >= 2.7 r``. At r = 4, h = 0.01 and 30 points per mm^2 the wedge jump of a
#: 0.15 h shadow (0.22 mm) lies just above s (0.18 mm); on igea the edges with contacts
#: 0.22-0.29 mm apart were 52k of the 167k searched and gave 2884 of the 58838 fold points
#: kept, with shadows of 0.25 h at the median (0.67 h at the 90th percentile). Without them,
#: of the eleven benchmark meshes' 33 ``--scan`` programs the 25 within 1.05 h still are,
#: their verified p99.9 moved by -0.0012 to +0.0020 h (the eight beyond it by -0.003 to
#: +0.003 h), for up to 1.2 CPU-s less per plan (igea 0.3-1.2; session 44, docs/issue5.md).
_JUMP_SPACINGS = 1.6
#: ... but never more than this many spacings above the wedge jump: an edge across a fold
#: whose own contacts jump by ``J`` has its ends' contacts about ``J + m s`` apart, ``m``
#: the contacts' motion per unit of the centre's on the two sides, at least 0.5 where they
#: are convex with a radius of at least r (``rho / (rho + r)``). The floor is then 1.6 s at
#: above about 25 points per mm^2 (r = 4, h = 0.01) and below it on coarser grids, where 1.6 s
#: would pass over real folds (a 3 deg V-groove at 4 per mm^2: 31 of its 35 deep points).
_JUMP_ABOVE_WEDGE = 0.5
#: Most samples the stage draws (about 0.2 kB each while it runs): a larger part gets a
#: lower density, with a warning.
_MAX_SAMPLES = 4_000_000


@njit(cache=True, nogil=True, inline="always")
def _gap(px, py, pz, nx, ny, nz, cx, cy, cz, r2):
    """Distance from ``p`` along ``n`` to the sphere of radius ``r`` at ``c`` (0 inside, inf: no hit)."""
    if not cz > -np.inf:
        return np.inf
    wx = px - cx
    wy = py - cy
    wz = pz - cz
    b = nx * wx + ny * wy + nz * wz
    c = wx * wx + wy * wy + wz * wz - r2
    if c <= 0.0:
        return 0.0
    disc = b * b - c
    if disc < 0.0:
        return np.inf
    t = -b - math.sqrt(disc)
    return t if t >= 0.0 else np.inf


@njit(cache=True, nogil=True, inline="always")
def _roofed(px, py, pz, nx, ny, nz, g, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri):
    """Whether one triangle of the part lies above the segment from ``p`` to ``p + g n``:
    its XY projection holds both ends' (so the whole segment's) and it is higher than both
    ends there (so than the whole segment: the plane's height less the segment's is linear).

    Then no ball on the drop surface leaves ``g`` or less at ``p``, measured along ``n`` as
    :func:`_gap` does: a point ``q`` of a ball whose centre ``c`` is on ``D`` has a free
    vertical ray above it (``q + s Z`` lies on the ball centred at ``c + s Z``, above ``D``,
    which meets no triangle), and the triangle crosses the ray above every point of the
    segment.
    """
    c = cell_at(px, py, gx0, gy0, cell, ncx, ncy)
    if c < 0:
        return False
    qx = px + g * nx
    qy = py + g * ny
    qz = pz + g * nz
    xlo, xhi = min(px, qx), max(px, qx)
    ylo, yhi = min(py, qy), max(py, qy)
    zlo = max(pz, qz) + _ROOF_SLACK
    for e in range(cstart[c], cstart[c + 1]):  # a triangle over the segment is over p: in p's cell
        t = ctri[e]
        if B[t, 4] <= zlo or B[t, 0] > xlo or B[t, 2] < xhi or B[t, 1] > ylo or B[t, 3] < yhi:
            continue
        above = True
        for k in range(2):
            x = px if k == 0 else qx
            y = py if k == 0 else qy
            z = pz if k == 0 else qz
            l0, l1, l2 = xy_barycentric(x, y, T, t)  # NaN (a vertical triangle): no roof
            if not (l0 >= 0.0 and l1 >= 0.0 and l2 >= 0.0
                    and l0 * T[t, 2] + l1 * T[t, 5] + l2 * T[t, 8] > z + _ROOF_SLACK):
                above = False
                break
        if above:
            return True
    return False


@njit(cache=True, nogil=True, inline="always")
def _model_gap(px, py, pz, nx, ny, nz, x, y, r, r2, T, W, nw):
    """``(rest, height)`` of the model's ball centred over ``(x, y)``: :func:`_gap` from ``p``."""
    z = _set_drop(x, y, r, r2, T, W, nw)
    return _gap(px, py, pz, nx, ny, nz, x, y, z, r2), z


@njit(cache=True, nogil=True)
def _simplex(px, py, pz, nx, ny, nz, x0, y0, g0, z0, side, end, evals, r, r2, T, W, nw):
    """Nelder-Mead on the model's rest from ``(x0, y0)`` (rest ``g0``, height ``z0``): a
    triangle with sides ``side`` along x and y, reflected, expanded, contracted or shrunk
    (coefficients 1, 2, 1/2, 1/2) until it is smaller than ``end``, the rest is 0 or
    ``evals`` more evaluations are made. Returns the best vertex ``(x, y, z, rest)``."""
    X = np.empty(3)
    Y = np.empty(3)
    G = np.empty(3)
    Z = np.empty(3)
    X[0], Y[0], G[0], Z[0] = x0, y0, g0, z0
    X[1], Y[1] = x0 + side, y0
    X[2], Y[2] = x0, y0 + side
    for i in range(1, 3):
        G[i], Z[i] = _model_gap(px, py, pz, nx, ny, nz, X[i], Y[i], r, r2, T, W, nw)
    n = 2
    while n < evals:
        for a in range(2):  # sort the vertices by rest (the first one best; ties keep their order)
            for b in range(2 - a):
                if G[b + 1] < G[b]:
                    G[b], G[b + 1] = G[b + 1], G[b]
                    X[b], X[b + 1] = X[b + 1], X[b]
                    Y[b], Y[b + 1] = Y[b + 1], Y[b]
                    Z[b], Z[b + 1] = Z[b + 1], Z[b]
        size = max(math.hypot(X[1] - X[0], Y[1] - Y[0]), math.hypot(X[2] - X[0], Y[2] - Y[0]))
        if size < end or G[0] <= 0.0:
            break
        cx = 0.5 * (X[0] + X[1])
        cy = 0.5 * (Y[0] + Y[1])
        xr = 2.0 * cx - X[2]
        yr = 2.0 * cy - Y[2]
        gr, zr = _model_gap(px, py, pz, nx, ny, nz, xr, yr, r, r2, T, W, nw)
        n += 1
        if gr < G[0]:
            xe = 3.0 * cx - 2.0 * X[2]
            ye = 3.0 * cy - 2.0 * Y[2]
            ge, ze = _model_gap(px, py, pz, nx, ny, nz, xe, ye, r, r2, T, W, nw)
            n += 1
            if ge < gr:
                X[2], Y[2], G[2], Z[2] = xe, ye, ge, ze
            else:
                X[2], Y[2], G[2], Z[2] = xr, yr, gr, zr
        elif gr < G[1]:
            X[2], Y[2], G[2], Z[2] = xr, yr, gr, zr
        else:
            # contract towards the reflection (when it beats the worst) or the worst
            tx = xr if gr < G[2] else X[2]
            ty = yr if gr < G[2] else Y[2]
            xc = cx + 0.5 * (tx - cx)
            yc = cy + 0.5 * (ty - cy)
            gc, zc = _model_gap(px, py, pz, nx, ny, nz, xc, yc, r, r2, T, W, nw)
            n += 1
            if gc < min(gr, G[2]):
                X[2], Y[2], G[2], Z[2] = xc, yc, gc, zc
            else:  # shrink towards the best vertex
                for i in range(1, 3):
                    X[i] = X[0] + 0.5 * (X[i] - X[0])
                    Y[i] = Y[0] + 0.5 * (Y[i] - Y[0])
                    G[i], Z[i] = _model_gap(px, py, pz, nx, ny, nz, X[i], Y[i], r, r2, T, W, nw)
                n += 2
    k = 0
    for i in range(1, 3):
        if G[i] < G[k]:
            k = i
    return X[k], Y[k], Z[k], G[k]


@njit(cache=True, nogil=True)
def _model_search(px, py, pz, nx, ny, nz, sx, sy, r, r2, T, W, nw, coarse):
    """Best centre of the model from ``(sx, sy)``: with ``coarse``, first on a grid of
    :data:`_COARSE_GRID` points per side over +-:data:`_COARSE_SPAN` r around it; then a
    Nelder-Mead simplex (:func:`_simplex`) from the best centre so far."""
    bx = sx
    by = sy
    bg, bz = _model_gap(px, py, pz, nx, ny, nz, bx, by, r, r2, T, W, nw)
    if coarse:
        s = _COARSE_SPAN * r
        G = _COARSE_GRID
        mid = (G - 1) // 2  # the grid's centre is the start: known
        for i in range(G):
            x = sx + s * (-1.0 + 2.0 * i / (G - 1))
            for j in range(G):
                if i == mid and j == mid:
                    continue
                y = sy + s * (-1.0 + 2.0 * j / (G - 1))
                g, z = _model_gap(px, py, pz, nx, ny, nz, x, y, r, r2, T, W, nw)
                if g < bg:
                    bg = g
                    bx = x
                    by = y
                    bz = z
    if bg <= 0.0:
        return bx, by, bz, bg
    return _simplex(px, py, pz, nx, ny, nz, bx, by, bg, bz, _SIMPLEX_SIDE * r, _SIMPLEX_END * r, _SIMPLEX_EVALS,
                    r, r2, T, W, nw)


@njit(cache=True, nogil=True, parallel=True)
def _best_many(P, N, face, r, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, maxwin,
               low, give_up, roof, blocks):
    """Per sample: best centre (x, y, z), its rest, and how the search ended.

    ``state``: 0 the tangent ball leaves at most ``low`` (no search), 1 searched (exact
    centre on D), 2 given up (model rest above ``give_up`` after a round), 3 rounds used up or
    working set full (with 24 rounds and room for 32 triangles only the rounds can run out; the
    centre is dropped onto D, its value exact but maybe not the best), 4 roofed (with
    ``roof``: a triangle lies above the sample's normal up to ``give_up``, :func:`_roofed`;
    no ball leaves ``give_up`` or less there; NaN centre, infinite rest).
    """
    k = P.shape[0]
    out = np.empty((k, 4))
    state = np.empty(k, dtype=np.int8)
    r2 = r * r
    for b in prange(len(blocks)):
        ch = blocks[b]
        cid, cbound, seen = _drop_scratch(maxwin)
        W = np.empty(_MAX_W, dtype=np.int64)
        for q in range(ch * _CHUNK, min(k, (ch + 1) * _CHUNK)):
            px, py, pz = P[q, 0], P[q, 1], P[q, 2]
            nx, ny, nz = N[q, 0], N[q, 1], N[q, 2]
            if roof and _roofed(px, py, pz, nx, ny, nz, give_up, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri):
                out[q, 0] = np.nan
                out[q, 1] = np.nan
                out[q, 2] = np.nan
                out[q, 3] = np.inf
                state[q] = 4
                continue
            tx = px + r * nx
            ty = py + r * ny
            z, t0 = _drop_point(tx, ty, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP,
                                face[q], cid, cbound, seen, -np.inf, False)
            x = tx
            y = ty
            g = _gap(px, py, pz, nx, ny, nz, x, y, z, r2)
            st = 0
            if g > low:
                st = 1
                vx, vy, vz, vg = x, y, z, g  # the tangent centre: on D, a fallback
                W[0] = face[q]
                nw = 1
                if t0 >= 0 and t0 != face[q]:
                    W[1] = t0
                    nw = 2
                it = 0
                while it < _MAX_ROUNDS:
                    it += 1
                    # from the tangent centre with the coarse grid, later rounds from the best
                    # centre by the simplex alone (one flag, not two literals: one compiled version)
                    x, y, z, g = _model_search(px, py, pz, nx, ny, nz, x, y, r, r2, T, W, nw, it == 1)
                    if g > give_up:  # the model only rises as triangles join: so does the truth
                        st = 2
                        break
                    # does any triangle rise above the model here? (stops at the first one)
                    hz, tt = _drop_point(x, y, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax,
                                         EB, CP, -1, cid, cbound, seen, z + 1e-9, True)
                    if tt < 0:
                        break
                    if nw == _MAX_W or it == _MAX_ROUNDS:
                        z, tt = _drop_point(x, y, r, r2, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax,
                                            EB, CP, tt, cid, cbound, seen, -np.inf, False)
                        g = _gap(px, py, pz, nx, ny, nz, x, y, z, r2)
                        st = 3
                        break
                    W[nw] = tt
                    nw += 1
                if st != 2 and g > vg:  # a later round, searching near its start only, can end higher
                    x, y, z, g = vx, vy, vz, vg
            out[q, 0] = x
            out[q, 1] = y
            out[q, 2] = z
            out[q, 3] = g
            state[q] = st
    return out, state


def best_centres(cutter, P, N, faces, low: float = 0.0, give_up: float = np.inf, roof: bool = True):
    """Best ball centres on the drop surface for surface samples (the working-set search).

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
    P, N : (k, 3) float64
        Samples on the part and their unit normals towards the tool (``N_z > 0``).
    faces : (k,) int64
        The triangle of each sample (index into the cutter's faces).
    low : float
        Samples whose tangent ball leaves at most this (mm) are not searched: their row is
        the tangent centre.
    give_up : float
        Samples whose model rest exceeds this (mm) after a round are not searched further
        (their true rest exceeds it too; the row's z is then the model's).
    roof : bool
        With a finite ``give_up`` above ``low``: samples under a triangle of the part that
        lies above their normal up to ``give_up`` (an overhang, the far side of a wall;
        :func:`_roofed`) are not searched, since no ball on the drop surface leaves
        ``give_up`` or less there. The other rows are the same either way. On igea's steep
        walls (r = 4, h = 0.01, give-up 1.05 h) 20863 of the 35249 samples the search gave up
        on are roofed (choi: 11463 of 15381), and none of the others.

    Returns
    -------
    centres : (k, 3) float64
        Best centre found (``z = -inf`` where the ball touches nothing).
    rest : (k,) float64
        Material it leaves at the sample along the normal (mm).
    state : (k,) int8
        0 not searched (tangent ball within ``low``), 1 searched, 2 given up, 3 rounds used up
        (the centre dropped onto D: its value exact, maybe not the best), 4 roofed (NaN
        centre, infinite rest).
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    N = np.ascontiguousarray(N, dtype=np.float64)
    tri = cutter._tri_index(np.asarray(faces, dtype=np.int64))
    if len(P) == 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, dtype=np.int8)
    # the blocks of samples in a shuffled order: prange hands each thread one contiguous
    # range, and the work gathers where the part is tight (a fixed seed: the rows do not
    # depend on the order anyway)
    blocks = np.random.default_rng(0).permutation((len(P) + _CHUNK - 1) // _CHUNK)
    out, state = _best_many(P, N, tri, cutter.radius, *cutter._kernel_args(), float(low), float(give_up),
                            bool(roof and math.isfinite(give_up) and give_up > low), blocks)
    return out[:, :3], out[:, 3], state


def _face_areas(V, F) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def surface_samples(V, F, density: float, seed: int = 0, areas=None, below_nz: float | None = None):
    """Area-uniform samples with vertex normals interpolated, facing the tool (``n_z > 0``).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    density : float
        Samples per mm^2 (``round(density * area)`` are drawn; those facing down are dropped).
    seed : int
    areas : (m,) float64, optional
        The faces' areas, when the caller has them.
    below_nz : float, optional
        Keep only the samples whose normal has ``n_z`` below this (the same samples, in the
        same order, as those rows of the full output).

    Returns
    -------
    P, N : (k, 3) float64
    faces : (k,) int64
    """
    from conformill.geometry.differential import vertex_normals
    from conformill.geometry.locate import pick_faces

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    a = _face_areas(V, F) if areas is None else np.asarray(areas, dtype=np.float64)
    n = int(round(density * float(a.sum())))
    rng = np.random.default_rng(seed)
    cum = np.cumsum(a)
    f = np.minimum(pick_faces(cum, rng.random(n) * cum[-1]), len(F) - 1)
    u, v = rng.random(n), rng.random(n)
    vn = vertex_normals(V, F)
    if below_nz is not None:
        # a sample's normal is a unit vector's convex blend renormalised: where all three
        # vertex normals have n_z >= b, so has the sample's; those faces' samples are not
        # mapped (the same draws, so the same samples as the rows of the full output)
        maybe = ~(vn[F, 2].min(axis=1) >= below_nz + 1e-9)
        sel = np.flatnonzero(maybe[f])
        f, u, v = f[sel], u[sel], v[sel]
    P, N = _sample_points(V, F, vn, f, u, v)  # N: NaN where the normals cancel (not kept)
    up = N[:, 2] > 0
    if below_nz is not None:
        up &= N[:, 2] < below_nz
    # in cell order (1 mm, row by row): consecutive samples touch the same triangles (cache);
    # a subset keeps its order in the whole (the cells are whole millimetres)
    keep = np.flatnonzero(up)
    keep = keep[_cell_order(P[keep])] if len(keep) else keep
    return P[keep], N[keep], f[keep]


@njit(cache=True, nogil=True)
def _sample_points(V, F, vn, f, u, v):
    """The points of faces ``f`` at ``(u, v)`` folded into the triangle (``u + v > 1``: ``1 -
    u``, ``1 - v``), barycentric ``(1 - u - v, u, v)``, and the vertex normals interpolated
    there, renormalised (NaN where they cancel): the arithmetic of
    :func:`conformill.geometry.locate.map_points` and ``map_normals``, in one pass."""
    k = f.shape[0]
    P = np.empty((k, 3))
    N = np.empty((k, 3))
    for p in range(k):
        uu, vv = u[p], v[p]
        if uu + vv > 1.0:
            uu, vv = 1.0 - uu, 1.0 - vv
        w0 = 1.0 - uu - vv
        a, b, c = F[f[p], 0], F[f[p], 1], F[f[p], 2]
        for j in range(3):
            P[p, j] = w0 * V[a, j] + uu * V[b, j] + vv * V[c, j]
        n0 = w0 * vn[a, 0] + uu * vn[b, 0] + vv * vn[c, 0]
        n1 = w0 * vn[a, 1] + uu * vn[b, 1] + vv * vn[c, 1]
        n2 = w0 * vn[a, 2] + uu * vn[b, 2] + vv * vn[c, 2]
        ln = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if ln > 0:
            N[p, 0], N[p, 1], N[p, 2] = n0 / ln, n1 / ln, n2 / ln
        else:
            N[p, 0] = N[p, 1] = N[p, 2] = np.nan
    return P, N


@dataclass(frozen=True, eq=False)
class SurfaceDraw:
    """One draw of :func:`surface_samples` over the whole part, kept to be used again.

    The fill stage draws its samples over the whole part; the pencil's searches draw the
    same samples (all of them, or the steep walls' rows) when their density and seed are
    the same. :func:`draw_samples` draws once, and :func:`pencil_search` takes the rows it
    would have drawn from here (:meth:`matches`).

    Attributes
    ----------
    P, N : (k, 3) float64
        The samples and their interpolated normals, facing the tool, in cell order.
    faces : (k,) int64
    density : float
        Samples per mm^2 drawn.
    seed : int
    """

    P: np.ndarray
    N: np.ndarray
    faces: np.ndarray
    density: float
    seed: int

    def matches(self, density: float, seed: int) -> bool:
        """Whether :func:`surface_samples` with ``density`` and ``seed`` draws these (on the
        part they were drawn on: the part itself is not compared; the callers pass the
        draw of the part they search)."""
        return float(density) == self.density and int(seed) == self.seed

    def rows(self, below_nz: float | None = None) -> tuple:
        """``(P, N, faces)``: all the samples, or those whose normal has ``n_z`` below
        ``below_nz``, as :func:`surface_samples` returns them with that argument."""
        if below_nz is None:
            return self.P, self.N, self.faces
        keep = self.N[:, 2] < below_nz
        return self.P[keep], self.N[keep], self.faces[keep]


def draw_samples(V, F, density: float, seed: int = 0, areas=None) -> SurfaceDraw:
    """:func:`surface_samples` over the whole part, as a :class:`SurfaceDraw`."""
    P, N, faces = surface_samples(V, F, density, seed, areas=areas)
    return SurfaceDraw(P=P, N=N, faces=faces, density=float(density), seed=int(seed))


def _drawn_or_new(drawn, V, F, density, seed, areas, below_nz=None):
    """The rows of ``drawn`` when it is the draw asked for, else a new draw."""
    if drawn is not None and drawn.matches(density, seed):
        return drawn.rows(below_nz)
    return surface_samples(V, F, density, seed, areas=areas, below_nz=below_nz)


def _cell_order(P) -> np.ndarray:
    """Indices of ``P`` sorted by 1 mm cell, row by row (``floor(y)``, then ``floor(x)``), ties
    in index order: ``np.lexsort((floor(x), floor(y)))``, by a counting sort."""
    fx, fy = np.floor(P[:, 0]), np.floor(P[:, 1])
    ix = (fx - fx.min()).astype(np.int64)
    iy = (fy - fy.min()).astype(np.int64)
    nx = int(ix.max()) + 1
    ncell = nx * (int(iy.max()) + 1)
    if ncell > 4 * len(P) + 1_000_000:  # a sparse spread (a huge part): a stable sort
        return np.argsort(iy * nx + ix, kind="stable")
    return _counting_order(iy * nx + ix, ncell)


@njit(cache=True, nogil=True)
def _counting_order(key, ncell):
    cnt = np.zeros(ncell + 1, dtype=np.int64)
    for k in key:
        cnt[k + 1] += 1
    for i in range(ncell):
        cnt[i + 1] += cnt[i]
    out = np.empty(len(key), dtype=np.int64)
    for i in range(len(key)):
        out[cnt[key[i]]] = i
        cnt[key[i]] += 1
    return out


@njit(cache=True)
def _thin(xy, order, radius):
    """Greedy thinning in ``order`` (by increasing x): keep a point unless a kept one lies within ``radius``."""
    kept = np.empty(len(order), dtype=np.int64)
    nk = 0
    r2 = radius * radius
    lo = 0
    for i in order:
        x, y = xy[i, 0], xy[i, 1]
        while lo < nk and xy[kept[lo], 0] < x - radius:
            lo += 1
        ok = True
        for m in range(lo, nk):
            j = kept[m]
            dx = xy[j, 0] - x
            dy = xy[j, 1] - y
            if dx * dx + dy * dy <= r2:
                ok = False
                break
        if ok:
            kept[nk] = i
            nk += 1
    return kept[:nk]


@njit(cache=True)
def _chains(nbr, dist, starts, link):
    """Greedy chains: from each free point in ``starts`` order, extend both ends by the
    nearest free neighbour (``nbr``, ``dist``: k nearest, sorted) within ``link``.

    Returns the points in chain order and the chain start offsets.
    """
    n = nbr.shape[0]
    free = np.ones(n, dtype=np.bool_)
    seq = np.empty(n, dtype=np.int64)
    offs = [0]
    buf = np.empty(2 * n + 1, dtype=np.int64)
    pos = 0
    for s in starts:
        if not free[s]:
            continue
        free[s] = False
        head = n  # buf[head:tail] holds the chain
        tail = n + 1
        buf[head] = s
        for end in range(2):
            while True:
                cur = buf[tail - 1] if end == 0 else buf[head]
                nxt = -1
                for m in range(nbr.shape[1]):
                    j = nbr[cur, m]
                    if j < n and dist[cur, m] <= link and free[j]:
                        nxt = j
                        break
                if nxt < 0:
                    break
                free[nxt] = False
                if end == 0:
                    buf[tail] = nxt
                    tail += 1
                else:
                    head -= 1
                    buf[head] = nxt
        for m in range(head, tail):
            seq[pos] = buf[m]
            pos += 1
        offs.append(pos)
    return seq, np.array(offs, dtype=np.int64)


def chain_points(xy, link: float, k: int = 16):
    """Greedy nearest-neighbour chains of points with links at most ``link``.

    Each chain starts at the free point with the fewest neighbours within ``link`` (an end,
    as far as one can tell) and grows at both ends by the nearest free point within
    ``link`` among its ``k`` nearest (a chain can end early in a dense blob; the passes
    join such pieces again, :func:`order_and_link`).

    Parameters
    ----------
    xy : (n, 2) float64
    link : float
    k : int

    Returns
    -------
    list of (k_i,) int64
        Indices into ``xy``, in chain order; every point in exactly one chain.
    """
    from scipy.spatial import cKDTree

    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 2:
        return [np.arange(len(xy))] if len(xy) else []
    tree = cKDTree(xy)
    workers = get_num_threads()  # the plan's --threads
    dist, nbr = tree.query(xy, k=min(k + 1, len(xy)), workers=workers)
    dist, nbr = dist[:, 1:], nbr[:, 1:]  # without the point itself
    degree = tree.query_ball_point(xy, link, return_length=True, workers=workers)
    starts = np.argsort(degree, kind="stable")
    seq, offs = _chains(np.ascontiguousarray(nbr, dtype=np.int64), np.ascontiguousarray(dist), starts, float(link))
    return [seq[offs[i]:offs[i + 1]] for i in range(len(offs) - 1)]


def order_and_link(chains, start_xy, link_max: float):
    """Order centre polylines for cutting and join those whose ends lie within ``link_max``.

    Greedy: from ``start_xy`` (the tool's last position), the nearest end of a chain not yet
    cut (the chain reversed when that is its last point); quadratic in the number of chains.

    Parameters
    ----------
    chains : list of (k_i, 3) float64
    start_xy : (2,) float
    link_max : float
        XY distance up to which the next chain is joined by a straight move (refined later)
        instead of starting a new pass.

    Returns
    -------
    list of (k, 3) float64
        The passes, each a concatenation of chains.
    """
    if not chains:
        return []
    ends = np.ascontiguousarray([[c[0, :2], c[-1, :2]] for c in chains], dtype=np.float64)  # (n, 2, 2)
    order, side, join = _order_ends(ends, np.asarray(start_xy, dtype=np.float64)[:2].copy(), float(link_max))
    passes, cur = [], []
    for i, sd, j in zip(order.tolist(), side.tolist(), join.tolist()):
        if cur and not j:
            passes.append(np.vstack(cur))
            cur = []
        cur.append(chains[i] if sd == 0 else chains[i][::-1])
    passes.append(np.vstack(cur))
    return passes


@njit(cache=True)
def _order_ends(ends, at, link_max):
    """The greedy order of :func:`order_and_link`: per step the chain, its side (1: reversed)
    and whether it joins the previous one; the nearest end first, ties to the lower index
    (``np.argmin`` over the ``(n, 2)`` distances, which this replaced: 0.4 s of Python on
    igea's 2800 chains)."""
    n = ends.shape[0]
    left = np.ones(n, dtype=np.bool_)
    order = np.empty(n, dtype=np.int64)
    side = np.empty(n, dtype=np.int64)
    join = np.zeros(n, dtype=np.bool_)
    ax, ay = at[0], at[1]
    for k in range(n):
        best = np.inf
        bi = -1
        bs = 0
        for i in range(n):
            if not left[i]:
                continue
            for sd in range(2):
                dx = ends[i, sd, 0] - ax
                dy = ends[i, sd, 1] - ay
                d = math.sqrt(dx * dx + dy * dy)
                if d < best or bi < 0:
                    best = d
                    bi = i
                    bs = sd
        left[bi] = False
        order[k] = bi
        side[k] = bs
        join[k] = k > 0 and best <= link_max
        ax = ends[bi, 1 - bs, 0]
        ay = ends[bi, 1 - bs, 1]
    return order, side, join


@dataclass(frozen=True, eq=False)
class PencilResult:
    """Extra passes of the pencil stage.

    Attributes
    ----------
    passes : list of (k, 3) float64
        Ball centres of each pass, on the drop surface and gouge-safe, in cutting order.
    stats : dict
        ``samples`` (facing the tool), ``searched``, ``centres`` (rest in the band),
        ``thinned``, ``chains``, ``passes``, ``cl_points``, ``feed_mm`` (cut length of the
        passes, links included), ``given_up``, ``roofed`` (a triangle above the sample: not
        searched, :func:`best_centres`), ``rounds_used_up`` (no pass for them),
        ``settled_points``, ``density_per_mm2`` (as used), ``low``, ``high``. The fold
        search: ``centres`` are its fold points (shadow deeper than ``low h``), with
        ``grid_points``, ``fold_points``, ``steep_samples`` and ``steep_centres``
        (:func:`steep_centres`); filtered by the pattern's rest (``Job.pencil_left``) also
        ``left_h``, ``fold_points_cut`` and ``steep_centres_cut``.
    """

    passes: list
    stats: dict = field(default_factory=dict)


def pencil_passes(cutter, V, F, h: float, tol: float, *, search: str = "samples", density: float = 30.0,
                  low: float = 0.15, high: float = 1.0, min_chain: int = 1, settle_tol: float = 0.0,
                  link_max: float = 8.0, start_xy=(0.0, 0.0), seed: int = 0, progress=None) -> PencilResult:
    """Pencil passes through the best ball centres whose rest lies in ``(low h, h]``.

    Two searches give the centres. ``"samples"``: the best centre of each of area-uniform
    surface samples (:func:`best_centres`), kept where its rest lies in ``(low h, high h]``.
    ``"folds"``: the points where the folds of the drop surface cross an XY grid
    (:func:`conformill.folds.fold_points`), kept where the fold's shadow (the part between
    the wedged ball's two contacts) is deeper than ``low h``; ``high`` does not apply (the
    rims of a deep shadow are in the band even where its bottom is not).

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
        Drop-cutter of the part (the program's ball).
    V, F : arrays
        The part (the cutter's mesh).
    h : float
        Scallop height (the unit of ``low`` and ``high``).
    tol : float
        Chord tolerance ``e``: no centre move cuts more than ``e / 2`` into the part
        (:meth:`conformill.cutter.BallCutter.refine`).
    search : {"samples", "folds"}
        Where the centres come from (above).
    density : float
        Samples per mm^2 of surface (default 30: 0.18 mm apart, 695k on igea); with
        ``"folds"``, grid points per mm^2 of the XY plane (30: a grid of 0.18 mm).
    low, high : float
        The band of the rest (x h) whose centres make passes: samples whose tangent ball
        leaves at most ``low h`` need no pass, those whose best ball leaves more than
        ``high h`` get none.
    min_chain : int
        Fewest centres a chain needs to be cut (1: a lone centre too, as a point of the
        pass that links it to its neighbours).
    settle_tol : float
        Each chain is settled into the drop surface's valleys to this float (mm; 0: not).
    link_max : float
        Chains whose ends lie within this (mm, XY) are joined by a straight move on the
        surface instead of a retract.
    start_xy : (2,) float
        Where the tool is when the passes begin.
    seed : int
        Of the samples (the output is a deterministic function of the inputs).
    progress : callable, optional
        ``progress(fraction)``.

    Returns
    -------
    PencilResult

    Raises
    ------
    PlanningError
        Non-positive ``h``, ``tol``, ``density`` or ``link_max``; not ``0 <= low < high``;
        ``min_chain`` below 1; an unknown ``search``.

    Notes
    -----
    At most 4M samples are drawn (and, with ``"folds"``, a grid of at most 14.4M points):
    on a larger part the density is lowered to fit, with a warning.
    """
    for name, v in (("tolerance", tol), ("link length", link_max)):
        if not (np.isfinite(v) and v > 0):
            raise PlanningError(f"pencil: {name} must be a positive number, got {v}")
    say = progress or (lambda f: None)
    found = pencil_chains(cutter, V, F, h, search=search, density=density, low=low, high=high, min_chain=min_chain,
                          settle_tol=settle_tol, seed=seed, progress=lambda f: say(0.9 * f))
    res = link_chains(cutter, found, tol, link_max, start_xy)
    say(1.0)
    return res


@dataclass(frozen=True, eq=False)
class PencilChains:
    """The chains of centres of the pencil stage, before they are ordered and linked.

    Attributes
    ----------
    chains : list of (k, 3) float64
        Ball centres on the drop surface, each chain settled, in no cutting order.
    stats : dict
        As :attr:`PencilResult.stats`, without the figures of the passes.
    """

    chains: list
    stats: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class PencilFound:
    """The centres the pencil stage's search found, before they are thinned and chained.

    Attributes
    ----------
    centres : (k, 3) float64
        Ball centres on the drop surface: with the fold search, the fold points first, then
        the steep walls' centres.
    probes : (k, p, 3) float64
        For each centre, points of the part where the pattern's rest tells whether its pass
        is needed (``Job.pencil_left``): a fold point's shadow at a quarter, half and three
        quarters of the way between its contacts; a steep centre's sample, in each slot.
        NaN rows: always cut (the centres of a search without probes, and every centre of
        the per-sample search).
    spacing : float
        The search's spacing (mm): the thinning and chaining lengths scale with it.
    stats : dict
        As :attr:`PencilChains.stats`, without the chains' figures.
    grid : conformill.folds.DropGrid or None
        With the fold search, its grid's drop heights (the fill stage reuses them).
    """

    centres: np.ndarray
    probes: np.ndarray
    spacing: float
    stats: dict = field(default_factory=dict)
    grid: object = None

    @property
    def probed(self) -> np.ndarray:
        """``(k,)`` bool: the centres with probes (the others are always cut)."""
        return np.isfinite(self.probes).all(axis=2).all(axis=1)


def _check_search(h, density, low, high, search):
    for name, v in (("scallop", h), ("pencil density", density)):
        if not (np.isfinite(v) and v > 0):
            raise PlanningError(f"pencil: {name} must be a positive number, got {v}")
    if not (np.isfinite(low) and np.isfinite(high) and 0 <= low < high):
        raise PlanningError(f"pencil: the band of the rest needs 0 <= low < high, got {low}, {high}")
    if search not in SEARCHES:
        raise PlanningError(f"pencil: search must be one of {', '.join(SEARCHES)}, got {search!r}")


def pencil_chains(cutter, V, F, h: float, *, search: str = "samples", density: float = 30.0, low: float = 0.15,
                  high: float = 1.0, min_chain: int = 1, settle_tol: float = 0.0, seed: int = 0, progress=None,
                  cancelled=None, drawn: SurfaceDraw | None = None) -> PencilChains | None:
    """The search of :func:`pencil_passes` and its chains: everything but the order.

    It needs neither the pattern's passes nor the tool's last position, so the pipeline
    runs it beside the pattern stage where numba's threads allow
    (:func:`conformill.passes.threads_can_overlap`). Parameters as for
    :func:`pencil_passes`; ``cancelled``, a callable, is asked between the steps of the
    search, and ``None`` is returned once it says true; ``drawn`` as for
    :func:`pencil_search`. It is :func:`pencil_search`, then :func:`chains_of`.

    Returns
    -------
    PencilChains or None
    """
    if int(min_chain) < 1:
        raise PlanningError(f"pencil: min_chain must be at least 1, got {min_chain}")
    found = pencil_search(cutter, V, F, h, search=search, density=density, low=low, high=high, seed=seed,
                          progress=progress, cancelled=cancelled, probes=False, drawn=drawn)
    if found is None or (cancelled is not None and cancelled()):
        return None
    return chains_of(cutter, found, min_chain, settle_tol)


def pencil_search(cutter, V, F, h: float, *, search: str = "samples", density: float = 30.0, low: float = 0.15,
                  high: float = 1.0, seed: int = 0, progress=None, cancelled=None,
                  probes: bool = True, drawn: SurfaceDraw | None = None) -> PencilFound | None:
    """The search of :func:`pencil_passes`: the centres, not yet chained (parameters and
    ``cancelled`` as for :func:`pencil_chains`; ``probes=False``: the fold points' shadow
    probes are not read and the steep centres have none, all NaN, as when they will not be
    filtered; with probes the steep centres are those :func:`steep_centres` gives for a
    filter, more than without; ``drawn``: samples
    already drawn over the part, used where they are the draw the search would make, the
    same density and seed: the fill's, :func:`conformill.fill.fill_samples`).

    Returns
    -------
    PencilFound or None
    """
    _check_search(h, density, low, high, search)
    say = progress or (lambda f: None)
    stop = cancelled or (lambda: False)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    areas = _face_areas(V, F)
    area = float(areas.sum())
    if search == "folds":
        from conformill.folds import _MAX_GRID, _grid_box, shadow_probes

        lo, hi = _grid_box(cutter)
        plane = float(np.prod(hi - lo))
        if density * plane > 0.9 * _MAX_GRID:
            log.warning("pencil: %.0f mm^2 of XY at %.3g grid points per mm^2 would be %.3gM points; using %.3g "
                        "per mm^2", plane, density, density * plane / 1e6, 0.9 * _MAX_GRID / plane)
            density = 0.9 * _MAX_GRID / plane
        spacing = 1.0 / math.sqrt(density)
        fp, kept = fold_centres(cutter, spacing, h, low)
        say(0.5)
        if stop():
            return None
        n_steep, steep, steep_at = steep_centres(cutter, V, F, h, min(density, _MAX_SAMPLES / area), low, high, seed,
                                                 areas, drawn=drawn, probed=probes)
        stats = {"search": "folds", **fp.stats, "fold_points": int(len(fp.centres)), "centres": int(kept.sum()),
                 "steep_samples": n_steep, "steep_centres": int(len(steep)),
                 "density_per_mm2": float(density), "low": float(low), "high": float(high)}
        shadows = shadow_probes(cutter, fp.contact_a[kept], fp.contact_b[kept], _SHADOW_AT) if probes \
            else np.full((int(kept.sum()), len(_SHADOW_AT), 3), np.nan)
        # a steep centre's probe is its sample (the same point in each of the probe slots)
        at = np.repeat(steep_at[:, None, :], len(_SHADOW_AT), axis=1) if probes \
            else np.full((len(steep), len(_SHADOW_AT), 3), np.nan)
        shadows = np.concatenate([shadows, at])
        say(0.8)
        if stop():
            return None
        return PencilFound(centres=np.vstack([fp.centres[kept], steep]), probes=shadows, spacing=spacing,
                           stats=stats, grid=fp.grid)
    if density * area > _MAX_SAMPLES:
        log.warning("pencil: %.0f mm^2 at %.3g samples per mm^2 would be %.3gM samples; using %.3g per mm^2 "
                    "(at most %dM)", area, density, density * area / 1e6, _MAX_SAMPLES / area, _MAX_SAMPLES // 10**6)
        density = _MAX_SAMPLES / area
    P, N, faces = _drawn_or_new(drawn, V, F, density, seed, areas)
    say(0.02)
    k = len(P)
    C = np.empty((k, 3))
    rest = np.empty(k)
    state = np.empty(k, dtype=np.int8)
    step = max(1, -(-k // 20))
    for a in range(0, k, step):
        if stop():
            return None
        C[a:a + step], rest[a:a + step], state[a:a + step] = best_centres(
            cutter, P[a:a + step], N[a:a + step], faces[a:a + step], low=low * h, give_up=max(_GIVE_UP, high) * h)
        say(0.02 + 0.9 * min(a + step, k) / max(k, 1))
    useful = (state == 1) & (rest > low * h) & (rest <= high * h) & np.isfinite(C[:, 2])
    stats = {"search": "samples", "samples": int(k), "searched": int(np.count_nonzero((state > 0) & (state < 4))),
             "centres": int(useful.sum()), "given_up": int(np.count_nonzero(state == 2)),
             "roofed": int(np.count_nonzero(state == 4)),
             "rounds_used_up": int(np.count_nonzero(state == 3)), "density_per_mm2": float(density),
             "low": float(low), "high": float(high)}
    n = int(useful.sum())
    return PencilFound(centres=C[useful], probes=np.full((n, 1, 3), np.nan), spacing=1.0 / math.sqrt(density),
                       stats=stats)


def where_left(found: PencilFound, passes, radius: float, depth: float) -> np.ndarray:
    """Which of ``found``'s centres to cut after the pattern's tip ``passes``: those with a
    probe where the passes leave more than ``depth`` (:func:`conformill.pattern_rest.uncut_beyond`),
    and those without probes. Returns ``(k,)`` bool."""
    left = LeftToCut(found, radius, depth)
    left.add(passes)
    return left.keep()


class LeftToCut:
    """:func:`where_left` for the pattern's passes handed over in parts, the same answer
    once all are in (:class:`conformill.pattern_rest.UncutRows`): the pipeline hands over
    the passes cut so far while the cutter works on the rest."""

    def __init__(self, found: PencilFound, radius: float, depth: float):
        from conformill.pattern_rest import UncutRows

        self._probed = found.probed
        self._radius = float(radius)
        # the hint: the wedged ball's XY, over its shadow
        self._rows = UncutRows(found.probes[self._probed], radius, depth, hints=found.centres[self._probed, :2])

    def add(self, passes) -> None:
        """More tip passes (a list of ``(k, 3)``)."""
        from conformill.pattern_rest import centre_moves

        self._rows.add(*centre_moves(passes, self._radius))

    def add_grid(self, grid) -> None:
        """More passes, as their centre moves binned (:func:`conformill.pattern_rest.move_grid`
        of :func:`conformill.pattern_rest.centre_moves` with this radius): the same as :meth:`add`."""
        self._rows.add_grid(grid)

    def keep(self) -> np.ndarray:
        """``(k,)`` bool: the centres to cut after the passes so far."""
        keep = ~self._probed
        keep[self._probed] = self._rows.uncut()
        return keep


def fold_jump(r: float, h: float, spacing: float, low: float = 0.15) -> float:
    """Least distance (mm) between a fold grid edge's two contacts for the edge to be searched:
    the wedge jump of a ``low * h`` shadow (:func:`conformill.folds.wedge_jump`), at least
    ``min(`` :data:`_JUMP_SPACINGS` ``s, wedge +`` :data:`_JUMP_ABOVE_WEDGE` ``s)``."""
    from conformill.folds import wedge_jump

    w = wedge_jump(r, low * h)
    return max(w, min(_JUMP_SPACINGS * spacing, w + _JUMP_ABOVE_WEDGE * spacing))


def fold_centres(cutter, spacing: float, h: float, low: float = 0.15):
    """The fold search's first step: fold points on an XY grid of ``spacing`` (mm), on the
    edges whose contacts lie farther apart than :func:`fold_jump`. Returns the :class:`conformill.folds.FoldPoints` and
    which of them (``(k,)`` bool) have a shadow deeper than ``low * h``."""
    from conformill.folds import fold_points

    fp = fold_points(cutter, spacing, fold_jump(cutter.radius, h, spacing, low))
    return fp, fp.shadow > low * h


def steep_centres(cutter, V, F, h: float, density: float, low: float = 0.15, high: float = 1.0, seed: int = 0,
                  areas=None, drawn: SurfaceDraw | None = None, probed: bool = False):
    """The fold search's second step: on walls steeper than 78 deg a fold running down the
    wall projects to a short XY segment that few grid edges cross, so there the samples
    (``density`` per mm^2) are searched one by one. ``drawn``: the samples over the whole
    part, whose steep rows are these samples when it has this density and seed
    (:meth:`SurfaceDraw.rows`).

    Without ``probed`` the centres are those whose rest lies in ``(low * h, high * h]``.
    With it (the pattern's rest will be read at each centre's sample, ``Job.pencil_left``)
    they are those of every sample whose tangent ball leaves more than ``low * h`` and whose
    best ball leaves at most ``high * h``: where a ball off the tangent one reaches the
    sample within ``low * h``, neither the fill's balls (:mod:`conformill.fill`) nor the
    pattern's need reach it, and only the pattern's rest tells whether a pass is needed
    (session 61, docs/issue5.md).

    Returns
    -------
    n : int
        The steep samples.
    centres : (k, 3) float64
    samples : (k, 3) float64
        The sample of each centre.
    """
    P, N, faces = _drawn_or_new(drawn, V, F, density, seed, areas, below_nz=_STEEP_NZ)
    C, rest, state = best_centres(cutter, P, N, faces, low=low * h, give_up=max(_GIVE_UP, high) * h)
    useful = (state == 1) & (rest <= high * h) & np.isfinite(C[:, 2])
    if not probed:
        useful &= rest > low * h
    return int(len(P)), C[useful], P[useful]


def chains_of(cutter, found: PencilFound, min_chain: int = 1, settle_tol: float = 0.0, keep=None) -> PencilChains:
    """Thin ``found``'s centres (those ``keep`` says, a ``(k,)`` bool; default all), chain
    them and settle the chains (``min_chain`` and ``settle_tol`` as for :func:`pencil_passes`)."""
    B = found.centres if keep is None else found.centres[np.asarray(keep, dtype=bool)]
    spacing = found.spacing
    # thin to a fifth of the sample spacing, chain within 3.3 spacings (0.03 / 0.5 mm on
    # igea's 43 per mm^2, the values measured there)
    kept = _thin(np.ascontiguousarray(B[:, :2]), np.argsort(B[:, 0], kind="stable"), 0.2 * spacing) \
        if len(B) else np.zeros(0, dtype=np.int64)
    B = B[kept]
    chains = [B[c] for c in chain_points(B[:, :2], 3.3 * spacing) if len(c) >= min_chain]
    n_settled = 0
    if settle_tol > 0:
        chains, n_settled, _ = cutter.settle_pieces(chains, settle_tol)
    return PencilChains(chains=chains, stats={**found.stats, "thinned": int(len(B)), "chains": len(chains),
                                              "settled_points": int(n_settled)})


def link_chains(cutter, found: PencilChains, tol: float, link_max: float, start_xy) -> PencilResult:
    """Order the chains of :func:`pencil_chains` from ``start_xy``, link and refine them
    (:func:`order_and_link`, :meth:`conformill.cutter.BallCutter.refine`); parameters as
    for :func:`pencil_passes`."""
    # a lone centre (min_chain 1) joins its neighbours through the links; alone it is no move.
    # One batch for all passes: the same points as one refine per pass (the checks are per
    # move), without a round of kernel calls per pass (igea zigzag --scan: 0.51 -> 0.43 s)
    passes = cutter.refine_pieces([p for p in order_and_link(found.chains, start_xy, link_max) if len(p) >= 2], tol)
    feed = feed_length(passes)
    stats = {**found.stats, "passes": len(passes), "cl_points": int(sum(len(p) for p in passes)), "feed_mm": feed}
    return PencilResult(passes=passes, stats=stats)


class BackgroundChains:
    """:func:`pencil_chains` in a worker thread, beside the pattern stage, then
    :func:`link_chains` beside the cutter's last batches.

    The search needs only the part and the ball, so it can run while the pattern stage
    and the cutter work; on two cores it takes the CPU they leave idle. The links need the
    point the pattern's passes end at: the caller hands over where it expects them to end
    (:meth:`link_from`) as soon as the pattern stage is done, and the worker links from
    there while the cutter finishes; :meth:`linked` gives the passes only if the passes
    did end there, so the program is the same as when everything runs in the caller's
    thread (the search and the links are deterministic functions of their inputs).

    Parameters
    ----------
    get_cutter : callable
        Waits for and returns the :class:`conformill.cutter.BallCutter` (``None``: the
        search is not run).
    args, kwargs
        For :func:`pencil_chains` after the cutter.
    chain : bool
        False: run only :func:`pencil_search` (``kwargs`` for it), whose centres the caller
        chains itself once it knows which to keep (``Job.pencil_left``); :meth:`result`
        then gives the :class:`PencilFound`, and nothing is linked.
    draw : callable, optional
        ``draw(cutter)``, run in the worker before the search: the fill's samples
        (:func:`conformill.fill.fill_samples`, a :class:`SurfaceDraw`), which the search
        uses where they are the samples it would draw (``drawn``). :meth:`drawn` gives
        what it returned.
    """

    def __init__(self, get_cutter, *args, chain: bool = True, draw=None, **kwargs):
        import threading

        import numba

        self._nthreads = numba.get_num_threads()  # thread-local in numba: hand it over
        self._get_cutter, self._args, self._kwargs = get_cutter, args, kwargs
        self._search = pencil_chains if chain else pencil_search
        self._stop = threading.Event()
        self._searched = threading.Event()  # the search ended (found, failed or stopped)
        self._go_link = threading.Event()  # link_from() or the end: the worker may go on
        self._link_args = None
        self._found, self._linked, self._error = None, None, None
        self._draw, self._drawn, self._draw_error = draw, None, None
        self._draw_done = threading.Event()  # draw() ended, or will not run
        self._link_error = None  # raised by linked() only for the start it was asked for
        self.busy_s = 0.0  # the search's time
        self.draw_s = 0.0  # draw()'s time
        self.link_s = 0.0  # the links' time
        self.fraction = 0.0  # the search's progress, 0 to 1
        self._thread = threading.Thread(target=self._run, name="conformill-pencil", daemon=True)
        self._thread.start()

    def _run(self):
        import time

        try:
            from conformill.passes import start_worker

            start_worker(self._nthreads)  # the caller's serial stages first (passes.BACKGROUND_NICE)
            cutter = self._get_cutter()
            if cutter is None or self._stop.is_set():
                return
            if self._draw is not None:
                t0 = time.perf_counter()
                try:
                    self._drawn = self._draw(cutter)
                except BaseException as exc:  # drawn() raises it; the search draws its own
                    self._draw_error = exc
                self.draw_s = time.perf_counter() - t0
                self._draw_done.set()
            t0 = time.perf_counter()
            self._found = self._search(cutter, *self._args, cancelled=self._stop.is_set,
                                       progress=lambda f: setattr(self, "fraction", f), drawn=self._drawn,
                                       **self._kwargs)
            self.busy_s = time.perf_counter() - t0
            self._searched.set()
            self._go_link.wait()
            if (isinstance(self._found, PencilChains) and self._link_args is not None
                    and not self._stop.is_set()):
                t0 = time.perf_counter()
                try:
                    self._linked = link_chains(cutter, self._found, *self._link_args)
                except BaseException as exc:  # linked() raises it only if these were the links wanted
                    self._link_error = exc
                self.link_s = time.perf_counter() - t0
        except BaseException as exc:  # handed to the caller by result() / linked()
            self._error = exc
        finally:
            self._searched.set()
            self._draw_done.set()

    def drawn(self):
        """What ``draw(cutter)`` returned, once it ran (``None`` when it did not: no
        ``draw``, no cutter, the worker was stopped first or failed before it, which
        :meth:`result` and :meth:`linked` raise); raises what ``draw`` raised."""
        if self._draw is None:
            return None
        self._draw_done.wait()
        if self._draw_error is not None:
            raise self._draw_error
        return self._drawn

    def link_from(self, start_xy, tol: float, link_max: float) -> None:
        """Link the chains from ``start_xy`` in the worker once they are found
        (:func:`link_chains`' arguments); at most once, before :meth:`linked`."""
        if self._link_args is None and not self._go_link.is_set():
            self._link_args = (float(tol), float(link_max), np.array(start_xy, dtype=np.float64).reshape(2))
            self._go_link.set()

    def result(self, wait=None) -> PencilChains | PencilFound:
        """The chains (or, with ``chain=False``, the centres), once the search is done
        (``wait(fraction)`` is called every 0.2 s until then); raises what the search raised."""
        while not self._searched.wait(timeout=0.2):
            if wait is not None:
                wait(self.fraction)
        if self._error is not None:
            raise self._error
        if self._found is None:
            raise RuntimeError("pencil: the background search was cancelled or had no cutter")
        return self._found

    def linked(self, start_xy, tol: float, link_max: float, wait=None) -> PencilResult | None:
        """The worker's pencil passes if :meth:`link_from` asked for exactly these arguments,
        else ``None`` (then link :meth:`result` yourself); waits for the worker to end and
        raises what it raised. ``wait`` as for :meth:`result` (1.0 while the links run)."""
        self.result(wait)
        self._go_link.set()  # no link_from(): let the worker end
        while self._thread.is_alive():
            if wait is not None:
                wait(1.0)
            self._thread.join(timeout=0.2)
        if self._error is not None:
            raise self._error
        start = np.array(start_xy, dtype=np.float64).reshape(2)
        args = self._link_args
        if args is None or args[:2] != (float(tol), float(link_max)) or not np.array_equal(args[2], start):
            return None
        if self._link_error is not None:
            raise self._link_error
        return self._linked

    def cancel(self) -> None:
        """Stop the worker at its next step and wait for the thread (harmless when done)."""
        self._stop.set()
        self._go_link.set()
        self._thread.join()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.cancel()
        return False

