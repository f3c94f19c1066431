"""Rest material: the least material any 3-axis ball position leaves at a surface sample.

A ball of radius ``r`` brought down from above can sit at any centre ``(x, y, z)`` with
``z >= D(x, y)``, the drop height (the ball touches the part and does not cut it). The
material left at a sample ``p`` with unit normal ``n`` by the ball at centre ``c`` is the
distance from ``p`` along ``n`` to the sphere (0 when ``p`` is inside it). Over the centres
on the drop surface around the ball that touches ``p`` (``p + r n``), the least value is the
*rest*: what no finishing program with this ball can remove (a concave crease between
facets, the rim of a pocket tighter than the ball). Only centres on ``D`` are searched, the
lowest the ball can sit over each ``(x, y)``.

The search starts from a grid of 25 x 25 centres over +-0.4 r around the tangent one
and the tangent centre itself, keeps the ``_STARTS`` best (distinct) centres, and refines
each on 9 x 9 grids over +-r/20, +-r/80, +-r/320 and +-r/1280 around it; the best value over
all of them is the answer. Refining several starts matters: the material left at a
sample is not a convex function of the centre near creases and steep walls, and refining
only the best coarse centre missed a better ball for 15 % of the samples it found beyond
reach on igea (a search still wider and finer, 41 x 41 centres over +-0.6 r and 8 starts
on 11 x 11 grids, found one for 29 of the 823 that this one and the single-start search
both put above h; ``verify`` therefore searches again, with the still wider and deeper
:data:`CONFIRM`, before it excuses a sample). The least value found is an upper bound of the true rest; it is exact up
to the last grid where the rest is of the order of a scallop height (the best ball then
lies close to the tangent one), and can be far too large deep inside a pocket (the best
ball beyond the search), where it is far above any scallop height anyway. ``D`` comes from the planner's drop-cutter
(:class:`conformill.cutter.BallCutter`), which is checked against OpenCAMLib and analytic
cases in its own tests; the material simulation of :mod:`conformill.verify.simulate`
shares no code with the planner.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CONFIRM", "rest_material", "tangent_rest"]

#: Half-width (units of ``r``) and size of the first grid of centres around the tangent one.
_COARSE_SPAN, _COARSE_GRID = 0.4, 25
#: How many of the best centres of the first grid are refined.
_STARTS = 8
#: Half-widths of the refining grids around each start, in units of ``r``, and their size.
_SPANS = (0.05, 0.0125, 0.003125, 0.00078125)
_GRID = 9
#: Margin (mm) of :func:`_drop_within`'s tests over rounding.
_WITHIN_SLACK = 1e-7
#: The second, wider and deeper search that ``verify`` runs where the first finds no ball
#: within the limit, before it excuses a sample: 61 x 61 centres over +-0.8 r, the 16 best
#: refined on 13 x 13 grids over +-0.06 r down to +-0.06 r / 1024. On igea (contour,
#: h = 0.01 mm, limit 1.05 h) it finds a ball within the limit for 15 of the 582 samples
#: the first search excuses; 81 x 81 centres over +-r with 32 starts finds one for 4 more.
CONFIRM = {"starts": 16, "coarse": (0.8, 61), "refine": (13, tuple(0.06 / 4 ** k for k in range(6)))}


def _ray_gap(p, n, C, r):
    """Distance from ``p`` along ``n`` to the spheres of radius ``r`` at ``C (k, m, 3)``."""
    with np.errstate(invalid="ignore"):  # centres at -inf (the ball off the part): no hit
        w = p[:, None, :] - C
        b = np.einsum("kj,kmj->km", n, w)
        c = np.einsum("kmj,kmj->km", w, w) - r * r
        disc = b * b - c
        t = np.where(disc >= 0.0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        t = np.where(c <= 0.0, 0.0, t)
        return np.where(np.isfinite(C[..., 2]) & (t >= 0.0), t, np.inf)


def tangent_rest(cutter, P, N) -> np.ndarray:
    """Material left at ``P`` by the ball over the tangent centre ``P + r N``, dropped onto the part.

    An upper bound of :func:`rest_material` (one of the centres it searches), for one drop
    per sample.
    """
    r = cutter.radius
    c = P + r * N
    z = cutter.drop(c[:, :2])
    C = np.column_stack([c[:, :2], z])[:, None, :]
    return _ray_gap(P, N, C, r)[:, 0]


def _drop_within(cutter, Q, p, bound):
    """Drop heights at ``Q (k, 2)`` where the ball there could leave less than ``bound[i]`` at
    ``p[i]``, ``+inf`` where it cannot.

    A ball centred at ``c`` leaves at least ``|c - p| - r`` at ``p`` (along any direction),
    so a centre whose drop height lies at or above ``p_z + sqrt((r + bound)^2 - d^2)`` (``d``
    its XY distance from ``p``) cannot do better than ``bound``; nor can any centre with
    ``d`` beyond ``r + bound``. The first test is a drop that stops at the first triangle
    rising above that height (:meth:`conformill.cutter.BallCutter._reaches`, whose 2e-9 mm
    tie allowance the margin ``_WITHIN_SLACK`` covers): over a pocket or an undercut, where
    the drop surface lies far above the sample, that is one triangle instead of the whole
    search. The others get a full drop.
    """
    r = cutter.radius
    z = np.full(len(Q), np.inf)
    reach = r + bound
    d2 = ((Q - p[:, :2]) ** 2).sum(axis=1)
    open_ = ~np.isfinite(bound)
    near = open_ | (d2 < (reach + _WITHIN_SLACK) ** 2)
    test = np.flatnonzero(near & ~open_)
    if test.size:
        floor = p[test, 2] + np.sqrt(np.maximum(reach[test] ** 2 - d2[test], 0.0)) + _WITHIN_SLACK
        near[test[cutter._reaches(Q[test], floor)]] = False
    todo = np.flatnonzero(near)
    if todo.size:
        z[todo] = cutter.drop(Q[todo])
    return z


def rest_material(cutter, P, N, chunk: int = 1000, centres: bool = False, starts: int = _STARTS,
                  coarse: tuple = (_COARSE_SPAN, _COARSE_GRID), refine: tuple = (_GRID, _SPANS),
                  prune: bool = True):
    """Least material (mm) along ``N`` at ``P`` over ball centres on the drop surface near the tangent one.

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
        Drop-cutter of the part with the ball of the program.
    P, N : (k, 3) float64
        Samples on the part and unit normals towards the tool (``N_z > 0``).
    chunk : int
        Samples searched at once (memory: about ``chunk * 1300`` centres).
    centres : bool
        Also return the ball centre that gave each value.
    starts, coarse
        How many centres of the first grid are refined, and that grid's half-width (units
        of ``r``) and size: a cheaper search (e.g. ``1, (0.2, 9)``) misses more.
    refine
        Size of the refining grids and their half-widths (units of ``r``), coarsest first.
    prune
        Drop only the centres that can change the answer (:func:`_drop_within`): on the
        refining grids those that can beat their start's best so far; on the first grid,
        once a sub-grid (about 9 x 9 and the tangent centre) is dropped, those that can beat
        its ``starts``-th best value, which bounds the starts of the whole grid. The values
        and centres are the same as without (tests compare them), for about half the time
        where the part keeps the ball far from the sample (igea, the 490 samples ``verify``
        excuses under a zigzag: the second search 26-28 -> 13-14 s, the first 5.5 -> 2.5-2.8 s).

    Returns
    -------
    (k,) float64, and with ``centres`` a (k, 3) float64 (``z = -inf`` where the ball
    was off the part)
    """
    P = np.asarray(P, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    r = cutter.radius

    def grid(n):
        g = np.linspace(-1.0, 1.0, n)
        return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)

    coarse, fine, spans = coarse[0] * r * grid(int(coarse[1])), grid(int(refine[0])), tuple(refine[1])
    # the coarse grid's sub-grid searched first with prune (index 0 is the tangent centre)
    side = int(coarse.shape[0] ** 0.5 + 0.5)
    every = np.arange(0, side, max(1, (side - 1) // 8))
    sub = np.concatenate([[0], 1 + (every[:, None] * side + every[None, :]).ravel()])
    others = np.setdiff1d(np.arange(coarse.shape[0] + 1), sub)
    out = np.full(len(P), np.inf)
    where = np.full((len(P), 3), np.nan)
    for a in range(0, len(P), chunk):
        p, n = P[a:a + chunk], N[a:a + chunk]
        k = len(p)
        rows = np.arange(k)[:, None]
        tangent = (p + r * n)[:, :2]
        # the tangent centre and the coarse grid; keep the best few as starts
        Q = np.concatenate([tangent[:, None, :], tangent[:, None, :] + coarse[None]], axis=1)
        m = max(1, min(int(starts), Q.shape[1]))
        if prune and len(sub) > m:
            # a sub-grid first: its m-th best value bounds the m best of the whole grid, and
            # a centre that cannot come within that bound is not among them
            z = np.empty(Q.shape[:2])
            z[:, sub] = cutter.drop(Q[:, sub].reshape(-1, 2)).reshape(k, -1)
            bound = np.sort(_ray_gap(p, n, np.concatenate([Q[:, sub], z[:, sub, None]], axis=2), r), axis=1)[:, m - 1]
            z[:, others] = _drop_within(cutter, Q[:, others].reshape(-1, 2), np.repeat(p, len(others), axis=0),
                                        np.repeat(bound, len(others))).reshape(k, -1)
        else:
            z = cutter.drop(Q.reshape(-1, 2)).reshape(k, -1)
        C = np.concatenate([Q, z[..., None]], axis=2)
        t = _ray_gap(p, n, C, r)
        start = np.argsort(t, axis=1, kind="stable")[:, :m]
        S, St = C[rows, start], t[rows, start]  # (k, m, 3), (k, m)
        for span in spans:
            live = np.flatnonzero(St.min(axis=1) > 0.0)  # a sample inside a ball is done
            if live.size == 0:
                break
            kk = live.size
            Q = (S[live, :, None, :2] + span * r * fine[None, None]).reshape(-1, 2)
            if prune:  # only a centre that can beat its start's best so far needs its height
                g = fine.shape[0]
                zq = _drop_within(cutter, Q, np.repeat(p[live], m * g, axis=0), np.repeat(St[live].reshape(-1), g))
            else:
                zq = cutter.drop(Q)
            Cq = np.concatenate([Q.reshape(kk, m, -1, 2), zq.reshape(kk, m, -1)[..., None]], axis=3)
            tq = _ray_gap(p[live], n[live], Cq.reshape(kk, -1, 3), r).reshape(kk, m, -1)
            j = np.argmin(tq, axis=2)
            r2 = np.arange(kk)[:, None]
            tj = tq[r2, np.arange(m)[None], j]
            better = tj < St[live]
            St[live] = np.where(better, tj, St[live])
            S[live] = np.where(better[..., None], Cq[r2, np.arange(m)[None], j], S[live])
        b = np.argmin(St, axis=1)
        out[a:a + chunk] = St[np.arange(k), b]
        where[a:a + chunk] = S[np.arange(k), b]
    return (out, where) if centres else out
