"""One continuous spiral on the circle domain (METHOD section 5).

The paper interpolates between consecutive rings of the contour plan,
``rho(theta) = rho_k + theta / (2 pi) (rho_{k+1} - rho_k)``. A revolution then lies
*between* two rings and its gap to the next revolution mixes two ring steps, so it is not
covered by the rings' spacing check; inserting a ring wherever it failed made the spiral
1.6x the length of the contour plan on a face scan (igea, h = 0.01).

Here the revolutions are planned directly, one after the other, like the rings: revolution
``k`` runs from offset ``a_k`` to ``a_{k+1}`` (offsets or warped levels, see
:mod:`conformill.patterns.warp`), so the gap to revolution ``k + 1`` at along-parameter
``tau`` is ``(1 - tau) D + tau E`` with ``D = a_{k+1} - a_k`` already fixed and
``E = a_{k+2} - a_{k+1}`` to choose. ``E`` is the largest value the allowed step at every
sample of revolution ``k`` admits; then the same two-way 3D spacing check as the rings'
shrinks ``E`` (or, where the fault is in the first half of the revolution, which ``E``
cannot mend, shrinks ``D`` and plans revolution ``k`` again). The last revolution reaches
the boundary and is followed by one turn on it.
"""

from __future__ import annotations

import logging

import numpy as np

from conformill.errors import PlanningError
from conformill.patterns.domains import Rings, SpiralTurn
from conformill.patterns.family import halve_then_bisect, pair_distances
from conformill.patterns.pieces import Piece, PieceStream, domain_paths
from conformill.patterns.warp import build_warp

log = logging.getLogger(__name__)

TOL = 1.0 + 1e-9


def _next_gap(g, tau, D: float) -> float:
    """Largest ``E`` with ``(1 - tau) D + tau E`` within the allowed steps ``g`` at ``tau``."""
    ok = np.isfinite(g) & (tau > 0.05)
    if not ok.any():
        return D
    return float(np.min((g[ok] - (1.0 - tau[ok]) * D) / tau[ok]))


def plan_spiral(planner, poly, delta: float, progress=None, adaptive: bool = True, max_turns: int = 200000,
                emit=None):
    """Plan a single spiral pass from the centre to the boundary.

    Returns
    -------
    domain : conformill.types.DomainPaths

    ``emit(piece)``, if given, is called with each revolution as soon as it is final (once
    the next one is planned: only the last revolution is ever planned again): one path per
    revolution, with no links, as each revolution starts where the last ended.
    """
    rings = Rings(poly, delta)
    warp, s_end = None, poly.R0
    if adaptive:
        warp, s_end = build_warp(planner, rings, 0.0, rings.end), 1.0
        rings = Rings(poly, delta, warp=warp)
    min_gap = s_end * 1e-7

    def turn(a, b):
        return planner.evaluate(SpiralTurn(poly, a, b, delta, warp=warp), a)

    def replan(a0, D):
        """Plan the last revolution again, from ``a0`` to ``a0 + D`` (its gap to the one
        before only narrows; that gap's figures are refreshed)."""
        levels[-1] = a0 + D
        turns[-1] = turn(a0, a0 + D)
        if realised:
            realised[-1], _ = pair_distances(turns[-2], turns[-1])
        return a0 + D, turns[-1]

    stream = PieceStream(emit)
    centre = planner.evaluate(rings, 0.0)
    D = min(float(np.min(planner.domain_steps(centre))), s_end)
    levels = [0.0, D]
    turns = [turn(0.0, D)]
    realised, predicted = [], []
    shrinks = 0
    done = False
    trust = 1.0  # share of the linear step the 3D check lets through, carried from turn to turn
    while not done:
        if len(turns) > max_turns:
            raise PlanningError(f"more than {max_turns} revolutions: the scallop height is too small for this part")
        cur = turns[-1]
        a0, a1 = levels[-2], levels[-1]
        D = a1 - a0
        if a1 >= s_end:  # the last revolution reached the boundary: one turn on it
            nxt = planner.evaluate(rings, s_end)
            E = 0.0
        else:
            g = trust * planner.domain_steps(cur)
            E = _next_gap(g, cur.tau, D)
            if E < 0.5 * D:
                # the allowed step drops early in this revolution: a gap that starts at D
                # cannot be mended by E, so this revolution ends closer (the gap to the
                # previous one only narrows) and the next may be at least half its pitch
                ok = np.isfinite(g)
                D_new = float(np.min(g[ok] / (1.0 - 0.5 * cur.tau[ok]))) if ok.any() else D
                if min_gap < D_new < D:
                    D = D_new
                    a1, cur = replan(a0, D)
                    E = _next_gap(trust * planner.domain_steps(cur), cur.tau, D)
            E = min(max(E, 0.0), s_end - a1)
            nxt = None
        first = True
        for it in range(24):
            if nxt is None:
                if E <= min_gap:
                    break
                nxt = turn(a1, a1 + E)
            d_fwd, ratio = pair_distances(cur, nxt)
            if ratio <= TOL:
                if first:  # let the trust recover where the linear step holds
                    trust = min(1.0, trust * 0.995 / max(ratio, 0.5))
                break
            first = False
            shrinks += 1
            k = int(np.argmax(d_fwd / cur.ls))
            tw = float(cur.tau[k])
            # the gap at the worst sample, brought within bounds by E alone if it can be
            gap = (1.0 - tw) * D + tw * E
            E_new = (gap * min(0.995 / ratio, 0.999) - (1.0 - tw) * D) / tw if tw > 0.05 else -1.0
            if it < 12 and (E_new > 0.1 * D or (E > min_gap and E_new > min_gap)):
                trust *= min(0.995 / ratio, 0.999)
                E = min(E_new, E * 0.999)
            else:
                # the first part of this revolution is too far out: plan it again, closer,
                # and trust the linear step less for the next one
                trust *= min(0.995 / ratio, 0.9)
                D = D * min(0.995 / ratio, 0.9)
                if D <= min_gap:
                    raise PlanningError(f"spiral step collapsed at offset {a0:.6g}: degenerate surface frame")
                a1, cur = replan(a0, D)
                E = min(max(_next_gap(trust * planner.domain_steps(cur), cur.tau, D), 0.0), s_end - a1)
            nxt = None
        else:
            # the last try left an untested E (and cur planned again closer): halved until the
            # check passes, then bisected to the largest that passes (as in the other
            # patterns' Planner._bisect_step); where none above min_gap passes, the fault is
            # in the part of cur that E cannot mend: the least bad revolution tried (of equal
            # ratios the smaller E), with the warning
            def attempt(g, cur=cur, a1=a1, E=E):
                nxt = turn(a1, a1 + g * E)
                d_fwd, ratio = pair_distances(cur, nxt)
                return ratio, (nxt, g * E, d_fwd, ratio)

            best, failed = halve_then_bisect(attempt, 1.0, g_min=min_gap / E if E > 0 else np.inf)
            if best is None and failed:
                best = min(failed, key=lambda f: (f[0], f[1]))[2]
            if best is not None:
                nxt, E, d_fwd, ratio = best
            if best is None or ratio > TOL:
                log.warning("spiral spacing check did not converge at offset %.6g (ratio %.3f)", a1, ratio)
        if nxt is None:  # E collapsed: step at least a little
            E = max(E, min_gap)
            nxt = turn(a1, min(a1 + E, s_end))
            d_fwd, _ = pair_distances(cur, nxt)
        realised.append(d_fwd)
        step = (1.0 - cur.tau) * D + cur.tau * E
        predicted.append(cur.sample.area_factor() / cur.sample.length(cur.t) * cur.rate * step)
        turns.append(nxt)
        stream.add(Piece("path", turns[-2], False, len(turns) - 2))
        if a1 >= s_end:
            done = True
        else:
            levels.append(min(a1 + E, s_end))
        if progress is not None:
            progress(min(levels[-1] / s_end, 1.0))
    stream.add(Piece("path", turns[-1], False, len(turns) - 1))
    return domain_paths("spiral", turns, realised, predicted, shrinks, closed=False)
