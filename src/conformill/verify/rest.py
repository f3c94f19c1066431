"""Rest material: the least material any 3-axis ball position leaves at a surface sample.

A ball of radius ``r`` brought down from above can sit at any centre ``(x, y, z)`` with
``z >= D(x, y)``, the drop height (the ball touches the part and does not cut it). The
material left at a sample ``p`` with unit normal ``n`` by the ball at centre ``c`` is the
distance from ``p`` along ``n`` to the sphere (0 when ``p`` is inside it). Over the centres
on the drop surface around the ball that touches ``p`` (``p + r n``), the least value is the
*rest*: what no finishing program with this ball can remove (a concave crease between
facets, the rim of a pocket tighter than the ball). Only centres on ``D`` are searched, the
lowest the ball can sit over each ``(x, y)``.

The search is a grid of centres around the tangent one (9 x 9 over +-0.2 r), then three
finer grids around the best (+-r/20, +-r/80, +-r/320). The least value found is an upper
bound of the true rest; it is exact up to the last grid where the rest is of the order of
a scallop height (the best ball then lies close to the tangent one), and can be far too
large deep inside a pocket (the best ball beyond the search), where it is far above any
scallop height anyway. ``D`` comes from the planner's drop-cutter
(:class:`conformill.cutter.BallCutter`), which is checked against OpenCAMLib and analytic
cases in its own tests; the material simulation of :mod:`conformill.verify.simulate`
shares no code with the planner.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rest_material", "tangent_rest"]

#: Half-widths of the search grids around the best centre so far, in units of ``r``.
_SPANS = (0.2, 0.05, 0.0125, 0.003125)
_GRID = 9


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


def rest_material(cutter, P, N, chunk: int = 2000, centres: bool = False):
    """Least material (mm) along ``N`` at ``P`` over ball centres on the drop surface near the tangent one.

    Parameters
    ----------
    cutter : conformill.cutter.BallCutter
        Drop-cutter of the part with the ball of the program.
    P, N : (k, 3) float64
        Samples on the part and unit normals towards the tool (``N_z > 0``).
    centres : bool
        Also return the ball centre that gave each value.

    Returns
    -------
    (k,) float64, and with ``centres`` a (k, 3) float64 (``z = -inf`` where the ball
    was off the part)
    """
    P = np.asarray(P, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    r = cutter.radius
    g = np.linspace(-1.0, 1.0, _GRID)
    unit = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    out = np.full(len(P), np.inf)
    where = np.full((len(P), 3), np.nan)
    for a in range(0, len(P), chunk):
        p, n = P[a:a + chunk], N[a:a + chunk]
        centre = (p + r * n)[:, :2]
        cz = cutter.drop(centre)
        best = _ray_gap(p, n, np.column_stack([centre, cz])[:, None, :], r)[:, 0]  # tangent_rest
        for span in _SPANS:
            go = np.flatnonzero(best > 0.0)  # a sample inside the ball is done
            if go.size == 0:
                break
            k = go.size
            rows = np.arange(k)
            Q = (centre[go, None, :] + span * r * unit[None]).reshape(-1, 2)
            z = cutter.drop(Q).reshape(k, -1)
            C = np.concatenate([Q.reshape(k, -1, 2), z[..., None]], axis=2)
            t = _ray_gap(p[go], n[go], C, r)
            j = np.argmin(t, axis=1)
            tj = t[rows, j]
            better = tj < best[go]
            best[go[better]] = tj[better]
            centre[go[better]] = C[rows, j, :2][better]
            cz[go[better]] = C[rows, j, 2][better]
        out[a:a + chunk] = best
        where[a:a + chunk] = np.column_stack([centre, cz])
    return (out, where) if centres else out
