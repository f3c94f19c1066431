"""Families of offset paths in the domain, spaced from the scallop height (METHOD 4-5).

A *family* is a one-parameter set of domain curves ``c(s, tau)``: iso-u lines of the
rectangle domain (``s = u``) or circles of the circle domain (``s = rho``), or, with
adaptive spacing, the curves of constant level ``s`` of a warp of those offsets
(:mod:`conformill.patterns.warp`). Starting from
the first curve, the next curve is at ``s + min_i ds_i`` (the paper's rule: the minimum over
the current path's points), where ``ds_i`` maps the allowed side interval ``l_s`` to the
domain with the actual metric. Then, going past the paper, the true 3D distance between
the two curves is measured and the step is shrunk until no point of either curve is
farther from the other than its allowed ``l_s``: a map that is not conformal, or a
linearisation that is off, cannot open the spacing.
"""

from __future__ import annotations

import logging

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from conformill.errors import PlanningError
from conformill.geometry.closest import segment_d2
from conformill.patterns.filters import running_min
from conformill.planning.steps import allowed_across, side_interval_stock

log = logging.getLogger(__name__)


@njit(cache=True, nogil=True, inline="always")
def _wrap(m, q):
    """``m % q`` for an index at most a few laps off (numba's ``%`` on signed integers
    takes Python's floor semantics and was 40 % of the closed walk's time)."""
    while m < 0:
        m += q
    while m >= q:
        m -= q
    return m


@njit(cache=True, nogil=True)
def _walk_distance(P, Q, closed, window, bounded):
    """Distance from each point of ``P`` to the polyline ``Q`` (:func:`curve_distance`).
    ``bounded``: skip the window's segments that cannot be the nearest (the same bits as
    measuring them all, which ``bounded=False`` does: the tests' reference)."""
    k, q = P.shape[0], Q.shape[0]
    out = np.empty(k)
    # a quarter of each segment's squared length (segment m -> m + 1, cyclic): its lower bound
    quarter = np.empty(q if bounded else 0)
    for m in range(quarter.shape[0]):
        m1 = m + 1 if m + 1 < q else 0
        ux, uy, uz = Q[m1, 0] - Q[m, 0], Q[m1, 1] - Q[m, 1], Q[m1, 2] - Q[m, 2]
        quarter[m] = 0.25 * (ux * ux + uy * uy + uz * uz)
    # the middle point: exhaustive; then walk to the end, and from the middle to the start
    # (two neighbouring revolutions of a spiral meet at their ends, where a walk begun at
    # the first point would follow the wrong one)
    mid = k // 2
    j0 = 0
    best = np.inf
    for m in range(q):
        d = (P[mid, 0] - Q[m, 0]) ** 2 + (P[mid, 1] - Q[m, 1]) ** 2 + (P[mid, 2] - Q[m, 2]) ** 2
        if d < best:
            best, j0 = d, m
    j = j0
    vd = np.empty(2 * window + 2)  # squared distances to the window's vertices (and one more)
    for n in range(k):
        if n == k - mid:
            j = j0
        i = mid + n if n < k - mid else k - 1 - n
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        # walk along Q from the previous nearest vertex, then look a window around it
        best = (px - Q[j, 0]) ** 2 + (py - Q[j, 1]) ** 2 + (pz - Q[j, 2]) ** 2
        moved = True
        while moved:
            moved = False
            for step in (-1, 1):
                m = j + step
                if closed:
                    m = _wrap(m, q)
                elif m < 0 or m >= q:
                    continue
                d = (px - Q[m, 0]) ** 2 + (py - Q[m, 1]) ** 2 + (pz - Q[m, 2]) ** 2
                if d < best:
                    best, j, moved = d, m, True
        c = j
        for off in range(-window, window + 1):
            m = c + off
            if closed:
                m = _wrap(m, q)
            elif m < 0 or m >= q:
                vd[off + window] = np.inf
                continue
            d = (px - Q[m, 0]) ** 2 + (py - Q[m, 1]) ** 2 + (pz - Q[m, 2]) ** 2
            vd[off + window] = d
            if d < best:
                best, j = d, m
        # where the window did not move the nearest vertex, its distances bound the segments
        # around it: a segment of length L whose ends lie at squared distance >= e from the
        # point is at least e - L^2 / 4 from it (where the foot of the perpendicular falls
        # inside, at t along it, the ends are at d^2 + t^2 L^2 and d^2 + (1 - t)^2 L^2, and
        # one of t, 1 - t is at most 1/2; where it falls outside, the nearest point is an
        # end). A segment whose bound is clearly above the distance so far cannot be the
        # nearest and is not measured; the rest are, as before, so the minimum is the same.
        bound = bounded and j == c
        if bound:
            m = c + window + 1
            if closed:
                m = _wrap(m, q)
            if m < q:
                vd[2 * window + 1] = (px - Q[m, 0]) ** 2 + (py - Q[m, 1]) ** 2 + (pz - Q[m, 2]) ** 2
            else:
                vd[2 * window + 1] = np.inf
        # the segments around the window's vertices
        dmin = best
        for off in range(-window, window + 1):
            a = j + off
            b = a + 1
            if closed:
                a = _wrap(a, q)
                b = _wrap(b, q)
            elif a < 0 or b >= q:
                continue
            if bound:
                ea, eb = vd[off + window], vd[off + window + 1]
                # (margins far above the rounding of either side, and needed: a path that
                # doubles back under the point can put a segment's bound above the nearest
                # distance by less than that rounding, tests/test_patterns.py; NaN is never
                # skipped)
                if min(ea, eb) - quarter[a] > dmin * (1.0 + 1e-6) + 1e-9 * max(ea, eb):
                    continue
            d = segment_d2(px, py, pz, Q[a, 0], Q[a, 1], Q[a, 2], Q[b, 0], Q[b, 1], Q[b, 2])
            if d < dmin:
                dmin = d
        out[i] = np.sqrt(dmin)
    return out


@njit(cache=True, nogil=True, parallel=True)
def _walk_both(Pa, Pb, closed, window):
    """:func:`_walk_distance` both ways between two curves, one way per thread."""
    fwd = np.empty(Pa.shape[0])
    bwd = np.empty(Pb.shape[0])
    for w in prange(2):
        if w == 0:
            d = _walk_distance(Pa, Pb, closed, window, True)
            for i in range(d.shape[0]):
                fwd[i] = d[i]
        else:
            d = _walk_distance(Pb, Pa, closed, window, True)
            for i in range(d.shape[0]):
                bwd[i] = d[i]
    return fwd, bwd


def point_polyline_distance(P: np.ndarray, Q: np.ndarray, closed: bool = False, tree=None) -> np.ndarray:
    """Distance from each point of ``P (k, 3)`` to the polyline ``Q (q, 3)`` (kd-tree).

    Reference implementation; the planner uses :func:`curve_distance` and this only where
    that walk says a sample is too far. ``tree`` may pass a ``cKDTree`` of ``Q`` built
    before.

    The nearest vertex of ``Q`` is found with a k-d tree; the two segments around it are
    then measured exactly (exact whenever the nearest segment touches the nearest vertex,
    which holds for the densely sampled, nearly parallel curves used here).
    """
    Q = np.asarray(Q)
    _, j = (cKDTree(Q) if tree is None else tree).query(P)
    return _around_vertex(P, Q, j, closed)


def _around_vertex(P, Q, j, closed):
    """Distance from each point of ``P`` to the two segments of ``Q`` at its vertex ``j``
    (the vertex itself included). On a closed curve the first and the last sample are
    the same point (up to rounding): at either, the segments on both sides of that
    point are measured. Compiled (:func:`_around_kernel`), with the arithmetic of the numpy
    form it replaced (``tests/test_patterns.py`` holds the two to the same bits)."""
    if len(Q) == 1:
        return np.linalg.norm(P - Q[0], axis=1)
    j = np.asarray(j)
    if j.size and (j.min() < 0 or j.max() >= len(Q)):  # (the kernel does not check its indices)
        raise IndexError(f"vertex index out of range [0, {len(Q)}): {j.min()} .. {j.max()}")
    return _around_kernel(np.ascontiguousarray(P, dtype=np.float64), np.ascontiguousarray(Q, dtype=np.float64),
                          np.ascontiguousarray(j, dtype=np.int64), bool(closed))


@njit(cache=True, nogil=True, inline="always")
def _nan_min(a, b):
    """``np.minimum``: NaN if either is."""
    if a != a or b != b:
        return np.nan
    return a if a <= b else b


@njit(cache=True, nogil=True, inline="always")
def _two_segments_one(px, py, pz, Q, jj, closed):
    """One point's distance to vertex ``jj`` of ``Q`` and to the segments either side, each
    as numpy computes it (``einsum``, ``maximum``, ``clip``, ``norm``; the
    einsum's order of terms is the one numpy 2 takes on x86-64, so that the plans keep their
    bits there; the test holds the two within rounding elsewhere)."""
    q = Q.shape[0]
    dx, dy, dz = px - Q[jj, 0], py - Q[jj, 1], pz - Q[jj, 2]
    best = np.sqrt(dx * dx + dy * dy + dz * dz)
    for lo in (jj - 1, jj):
        if closed:
            a = lo % q
            b = (lo + 1) % q
        else:
            if lo < 0 or lo + 1 >= q:
                continue
            a = lo
            b = lo + 1
        abx, aby, abz = Q[b, 0] - Q[a, 0], Q[b, 1] - Q[a, 1], Q[b, 2] - Q[a, 2]
        # (numpy's einsum over three terms adds the first and the third, then the second)
        num = ((px - Q[a, 0]) * abx + (pz - Q[a, 2]) * abz) + (py - Q[a, 1]) * aby
        den = (abx * abx + abz * abz) + aby * aby
        if not (den != den or den >= 1e-300):
            den = 1e-300
        t = num / den
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
        ex = px - (Q[a, 0] + t * abx)
        ey = py - (Q[a, 1] + t * aby)
        ez = pz - (Q[a, 2] + t * abz)
        best = _nan_min(best, np.sqrt(ex * ex + ey * ey + ez * ez))
    return best


@njit(cache=True, nogil=True)
def _around_kernel(P, Q, j, closed):
    """:func:`_around_vertex` for a ``Q`` of two or more vertices."""
    q = Q.shape[0]
    out = np.empty(P.shape[0])
    for i in range(P.shape[0]):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        jj = j[i]
        best = _two_segments_one(px, py, pz, Q, jj, closed)
        if closed and q > 2 and (jj == 0 or jj == q - 1):
            best = _nan_min(best, _two_segments_one(px, py, pz, Q, q - 1 if jj == 0 else 0, closed))
        out[i] = best
    return out


def curve_distance(P: np.ndarray, Q: np.ndarray, closed: bool = False, window: int = 3) -> np.ndarray:
    """Distance from each point of curve ``P (k, 3)`` to the polyline ``Q (q, 3)``.

    For two neighbouring curves of a family, sampled in the same direction: the nearest
    vertex of ``Q`` is followed along ``P`` by a local walk plus a window of ``window``
    vertices either side, then the segments around it are measured exactly. A local
    minimum can only make a distance *larger* than the true one, which makes the 3D
    spacing check stricter, never looser. Compiled; about 5x faster than building and
    querying a k-d tree per curve pair (4000-point rings).
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    Q = np.ascontiguousarray(Q, dtype=np.float64)
    if len(Q) == 1:
        return np.linalg.norm(P - Q[0], axis=1)
    return _walk_distance(P, Q, bool(closed), int(window), True)


@njit(cache=True, nogil=True)
def _nearest_vertex(P, Q):
    """Index of the vertex of ``Q`` nearest to each point of ``P`` (the first of equals):
    a full scan, for a few points, where building a k-d tree costs more."""
    k, q = P.shape[0], Q.shape[0]
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        j = 0
        bd = np.inf
        for m in range(q):
            dx, dy, dz = px - Q[m, 0], py - Q[m, 1], pz - Q[m, 2]
            dd = dx * dx + dy * dy + dz * dz
            if dd < bd:
                bd, j = dd, m
        out[i] = j
    return out


#: Below this many point-vertex pairs the exact distance scans the curve instead of
#: building a k-d tree of it (about 0.6 ms of scanning, what a tree of a 4000-point ring costs
#: to build and query for 400 points).
_SCAN_PAIRS = 500_000

#: Samples whose unit normal (towards the tool) has ``n_z`` below this face down so far
#: that no ball of a 3-axis tool touches them (the ball's upper half is hidden by its shank,
#: so a contact needs ``n_z >= 0``): their own curvature does not set the side step, which is
#: the flat one there (:meth:`Planner.allowed`). Between this and 0 they keep their own: the
#: balls that ride the rim above an overhang are placed from those samples.
UNDERCUT_NZ = -0.3


def _exact_where_over(d: np.ndarray, limit: np.ndarray, P: np.ndarray, b, closed: bool) -> np.ndarray:
    """``d`` with the entries above ``limit`` recomputed exactly against curve ``b``
    (k-d tree of its samples, built once per curve: a curve is measured against its
    neighbours on both sides and again after every shrink of the step; for a few
    entries, a scan of the curve)."""
    over = np.flatnonzero(d > limit * (1.0 + 1e-9))
    if over.size == 0:
        return d
    d = d.copy()
    Q = b.sample.xyz
    Po = P[over]
    if b.tree is None and over.size * len(Q) <= _SCAN_PAIRS:
        j = _nearest_vertex(np.ascontiguousarray(Po, dtype=np.float64), np.ascontiguousarray(Q, dtype=np.float64))
    else:
        if b.tree is None:
            b.tree = cKDTree(Q)
        j = b.tree.query(Po)[1]
    d[over] = _around_vertex(Po, Q, j, closed)
    return d


def pair_distances_both(a, b, closed: bool = False):
    """3D distances between neighbouring curves ``a`` and ``b`` (:class:`Curve`), both ways.

    Returns ``(d_fwd, d_bwd)``: the distance from each sample of ``a`` to the polyline of
    ``b``, and from each sample of ``b`` to that of ``a``. The fast walk
    (:func:`curve_distance`) may overestimate, so where it says a sample is farther than
    its allowed interval ``ls`` the distance is recomputed exactly before anything is
    decided.
    """
    Pa, Pb = a.sample.xyz, b.sample.xyz
    if len(Pa) > 1 and len(Pb) > 1:  # the two walks at once (the pattern stage is serial otherwise)
        d_fwd, d_bwd = _walk_both(np.ascontiguousarray(Pa, dtype=np.float64),
                                  np.ascontiguousarray(Pb, dtype=np.float64), bool(closed), 3)
    else:
        d_fwd = curve_distance(Pa, Pb, closed)
        d_bwd = curve_distance(Pb, Pa, closed)
    d_fwd = _exact_where_over(d_fwd, a.ls, Pa, b, closed)
    d_bwd = _exact_where_over(d_bwd, b.ls, Pb, a, closed)
    return d_fwd, d_bwd


def pair_distances(a, b, closed: bool = False):
    """``(d_fwd, ratio)``: :func:`pair_distances_both`'s ``d_fwd`` and the largest
    ``d / l_s`` over both directions (samples of ``a`` to ``b`` and of ``b`` to ``a``)."""
    d_fwd, d_bwd = pair_distances_both(a, b, closed)
    return d_fwd, max(np.max(d_fwd / a.ls), np.max(d_bwd / b.ls))


def halve_then_bisect(attempt, g: float, failing: float | None = None, g_min: float = 0.0,
                      halvings: int = 40, rounds: int = 8):
    """The largest fraction of a step that passes the 3D spacing check, where its shrinks stalled.

    ``attempt(g)`` evaluates the step's fraction ``g`` and returns ``(ratio, result)``; the
    check passes at ``ratio <= 1 + 1e-9``. ``g`` is halved from the value given until a
    fraction passes (at most ``halvings`` tries, none at or below ``g_min``), then bisected
    ``rounds`` times between the largest passing fraction and the smallest known to fail
    (``failing``, a fraction that failed before the call, or the halvings' last failure;
    none when the first fraction tried passes and nothing is known to fail).

    Returns
    -------
    best : object or None
        The ``result`` of the largest passing fraction; None when none passed.
    failed : list of (ratio, g, result)
        The halvings that failed, in order.
    """
    lo, hi, best, failed = 0.0, failing, None, []
    for _ in range(halvings):
        if g <= g_min:
            break
        ratio, res = attempt(g)
        if ratio <= 1.0 + 1e-9:
            lo, best = g, res
            break
        failed.append((ratio, g, res))
        hi, g = g, 0.5 * g
    if best is not None and hi is not None:
        for _ in range(rounds):
            g = 0.5 * (lo + hi)
            ratio, res = attempt(g)
            if ratio <= 1.0 + 1e-9:
                lo, best = g, res
            else:
                hi = g
    return best, failed


@njit(cache=True, nogil=True)
def _sweep(E, seg, k, closed, reverse):
    """One pass of :func:`_envelope` along the gaps (backwards with ``reverse``), in place."""
    m = seg.shape[0]
    for q in range(m):
        g = m - 1 - q if reverse else q
        i, j = (g + 1, g) if reverse else (g, g + 1)
        v = E[i] + k[g] * seg[g]
        if v < E[j]:
            E[j] = v
    if closed:
        v = min(E[0], E[m])
        E[0] = v
        E[m] = v


@njit(cache=True, nogil=True)
def _envelope(A, seg, k, closed):
    """Largest function below ``A`` whose slope between samples is at most ``k``.

    ``E_i = min_j (A_j + sum of k * seg over the samples between i and j)``: a distance
    transform along the curve (``seg`` the 3D length of each gap, ``k`` the allowed rise
    per unit length at each gap). For a closed curve the first and the last sample are
    the same point and the passes go round twice.
    """
    E = A.copy()
    laps = 2 if closed else 1
    for reverse in (False, True):
        for _ in range(laps):
            _sweep(E, seg, k, closed, reverse)
    return E


@njit(cache=True, nogil=True, inline="always")
def _gap_length(xyz, i):
    """3D length of the gap after sample ``i`` (as numpy's norm of the difference)."""
    dx = xyz[i + 1, 0] - xyz[i, 0]
    dy = xyz[i + 1, 1] - xyz[i, 1]
    dz = xyz[i + 1, 2] - xyz[i, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True)
def _split_gaps(tau, xyz, seg_len):
    """:meth:`Planner.evaluate`'s refinement of the along-parameters, compiled: every gap
    whose 3D length exceeds ``seg_len`` gets ``ceil(length / seg_len) - 1`` new parameters
    evenly inside. Returns ``(n_long, tau_new, new, ok)``: the number of long gaps, the
    parameters in order with their new-or-not mask, and whether that order is the stable
    sort's: the old parameters increasing and every new one strictly before the next old
    one (else the caller sorts, :func:`_refined_sorted`)."""
    k = tau.shape[0]
    n_long = 0
    total = k
    for i in range(k - 1):
        d = _gap_length(xyz, i)
        if d > seg_len:
            n_long += 1
            total += int(np.ceil(d / seg_len)) - 1
    out = np.empty(total)
    new = np.zeros(total, dtype=np.bool_)
    if n_long == 0:
        return 0, out, new, True
    m = 0
    last = -np.inf
    ok = True
    for i in range(k):
        t0 = tau[i]
        if t0 > last:  # (equal parameters: the second is dropped, as np.diff(...) > 0 does)
            out[m] = t0
            m += 1
            last = t0
        if i == k - 1:
            break
        if tau[i + 1] < t0:  # (not increasing: the sort's order is not this one)
            ok = False
        d = _gap_length(xyz, i)
        if d > seg_len:
            q = int(np.ceil(d / seg_len))
            w = tau[i + 1] - t0
            for j in range(1, q):
                e = t0 + w * (j / q)
                if e >= tau[i + 1]:
                    ok = False
                if e > last:
                    out[m] = e
                    new[m] = True
                    m += 1
                    last = e
    return n_long, out[:m], new[:m], ok


def _refined(tau, xyz, seg_len):
    """``(done, tau_new, new)`` of one refinement round (:func:`_split_gaps`); ``tau_new``
    is None where the caller must sort (:func:`_refined_sorted`)."""
    n_long, tau_new, new, ok = _split_gaps(np.ascontiguousarray(tau, dtype=np.float64), xyz, float(seg_len))
    if n_long == 0:
        return True, None, None
    return False, (tau_new if ok else None), new


def _refined_sorted(tau, xyz, seg_len):
    """The refinement of :func:`_split_gaps` by a stable sort of all the parameters (the
    reference; for the rare curve where rounding puts a new parameter at or past the next
    old one)."""
    seg = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    long_ = np.flatnonzero(seg > seg_len)
    k = np.ceil(seg[long_] / seg_len).astype(np.int64)
    owner = np.repeat(long_, k - 1)  # m - 1 new parameters inside each long gap
    m = np.repeat(k, k - 1)
    j = np.arange(owner.size) - np.repeat(np.cumsum(k - 1) - (k - 1), k - 1) + 1
    extra = tau[owner] + (tau[owner + 1] - tau[owner]) * (j / m)
    both = np.concatenate([tau, extra])
    order = np.argsort(both, kind="stable")
    tau_new = both[order]
    # a gap too narrow to split in floating point adds nothing (the stable sort puts
    # the existing parameter first, so only a new one is dropped)
    keep = np.concatenate([[True], np.diff(tau_new) > 0])
    return tau_new[keep], (order >= len(tau))[keep]


class Levels:
    """A level per along-parameter: ``s(tau)``, linear between the knots ``tau_k``.

    A curve of a family need not be a level set: with local steps (:meth:`Planner.run_local`)
    it dents back where its neighbour allows only a small step. ``tau_k`` must be
    increasing in [0, 1] and cover it.
    """

    __slots__ = ("tau", "s")

    def __init__(self, tau, s):
        self.tau = np.asarray(tau, dtype=np.float64)
        self.s = np.asarray(s, dtype=np.float64)

    def __call__(self, tau):
        return np.interp(tau, self.tau, self.s)


def _levels_at(s, tau):
    return s(tau) if isinstance(s, Levels) else s


class Curve:
    """One evaluated domain curve: dense samples and the surface there."""

    __slots__ = ("s", "tau", "sample", "t", "ls", "reach", "rate", "tree", "levels", "ls_base")

    def __init__(self, s, tau, sample, t, ls, reach, rate=None, levels=None, ls_base=None):
        self.s = s
        # the level of each sample: ``s`` everywhere for a level set, less in a dent
        # (:meth:`Planner.run_local`)
        self.levels = np.full(len(tau), float(s)) if levels is None else levels
        self.tau = tau
        self.sample = sample
        self.t = t
        self.ls = ls
        self.reach = reach
        # how fast the curve moves across itself per unit of ``s``, in units of the base
        # domain direction (1 for the paper's iso-lines; see conformill.patterns.warp)
        self.rate = np.ones(len(tau)) if rate is None else rate
        self.tree = None  # k-d tree of sample.xyz, built on first need (pair_distances)
        # the allowed side interval at the job's own scallop where the paths are spaced
        # wider (Planner's base_scallop); ``ls`` itself otherwise
        self.ls_base = ls if ls_base is None else ls_base


class Family:
    """Base class of an offset family; subclasses define the domain geometry.

    Subclasses implement ``along(s, tau) -> (P, t)``: domain points ``(k, 2)`` and unit
    domain tangents ``(k, 2)`` at along-parameters ``tau`` in [0, 1]. A warped family
    (:mod:`conformill.patterns.warp`) also implements ``rate(s, tau, P, t)``: the domain
    distance a point moves across the curve per unit of ``s``; for the paper's iso-lines it
    is 1 and the method returns ``None``.
    """

    closed = False

    def rate(self, s, tau, P, t):
        return None

    def along(self, s, tau):  # pragma: no cover - abstract
        raise NotImplementedError

    def initial_tau(self, s) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class Planner:
    """Plans one family of offset curves over a :class:`DomainSurface`.

    Parameters
    ----------
    surface : conformill.geometry.surface.DomainSurface
    params : conformill.types.PathParams
    seg_len : float
        Target 3D length (mm) between dense samples of a curve.
    concave_cap : float, optional
        Upper bound of the side interval (mm), e.g. the flat one; ``None`` for none.
    rise_tol, max_step : float
        Forward chord tolerance and longest forward step (mm): the chord rise over concave
        stretches is taken off the scallop height before the side step is computed.
    base_scallop : float, optional
        The job's scallop height (mm) when ``params.scallop`` spaces the paths wider
        (``Job.pattern_scallop`` above 1; :func:`conformill.pipeline.plan` passes it only
        then): each curve then also holds the side interval allowed at it
        (``Curve.ls_base``), with the same cap, which is what the wider spacing saves
        against (:func:`conformill.pipeline.plan`'s test of the widening). Ignored when it
        equals ``params.scallop``.
    """

    def __init__(self, surface, params, seg_len: float, concave_cap: float | None = None,
                 rise_tol: float = 0.0, max_step: float = np.inf, base_scallop: float | None = None):
        self.surface = surface
        self.params = params
        self.seg_len = float(seg_len)
        self.concave_cap = concave_cap
        self.rise_tol = float(rise_tol)
        self.max_step = float(max_step)
        self.base_scallop = None if base_scallop is None or base_scallop == params.scallop else float(base_scallop)
        self._flat = {}  # the flat side interval with the stock and the cap, by scallop (allowed)

    # -- evaluation ---------------------------------------------------------------
    def evaluate(self, family: Family, s: float, max_rounds: int = 6, tau: np.ndarray | None = None) -> Curve:
        """Sample curve ``s`` densely enough that 3D gaps are below ``seg_len``.

        ``tau`` may give the along-parameters to start from (those of a neighbouring
        curve of the same family, which usually need no refinement). ``s`` is a level or
        a :class:`Levels` profile; the curve's ``s`` is then its lowest level.
        """
        prof = s if isinstance(s, Levels) else None
        s_low = float(np.min(prof.s)) if prof is not None else s
        tau = family.initial_tau(float(np.max(prof.s)) if prof is not None else s) if tau is None else tau
        S, new = None, None
        for rnd in range(max_rounds + 1):
            P, t = family.along(_levels_at(s, tau), tau)
            if S is None:
                S = self.surface.sample(P)
            else:
                # a domain point depends on its own along-parameter only: the surface is
                # evaluated at the new ones and the old samples are kept
                S = self.surface.sample(P, keep=S, new=new)
            if rnd == max_rounds:
                break
            done, tau_new, new = _refined(tau, np.ascontiguousarray(S.xyz), self.seg_len)
            if done:
                break
            if tau_new is None:  # (rounding put a new parameter out of order: sort them)
                tau_new, new = _refined_sorted(tau, S.xyz, self.seg_len)
            tau = tau_new
        ls, reach = self.allowed(S, t)
        ls_base = None if self.base_scallop is None else self.allowed(S, t, self.base_scallop)[0]
        lv = _levels_at(s, tau)
        return Curve(s_low, tau, S, t, ls, reach, family.rate(lv, tau, P, t),
                     levels=None if prof is None else lv, ls_base=ls_base)

    def allowed(self, S, t, scallop: float | None = None):
        """Allowed side interval ``l_s`` (mm) across domain tangents ``t`` at samples ``S``.

        Returns ``(ls, reach)``; ``reach`` is False where the ball cannot follow the
        concave curvature across the path. Samples facing down past :data:`UNDERCUT_NZ`
        get at least the flat interval: no ball touches them, so the scallop there is not
        the program's (``verify`` leaves them out as unreachable). ``scallop`` (mm), if
        given, replaces ``params.scallop`` (the cap stays).
        """
        # (one compiled pass: planning.steps.allowed_across, the same arithmetic as
        # S.curvature(S.across(t)), the rise and side_interval_stock in numpy)
        # Where the path is concave along its direction, its straight moves ride above the
        # surface by up to the forward chord tolerance (or kappa L_max^2 / 8 when the
        # longest step binds): that material adds to the scallop, so the side step there
        # is planned for what is left of h. Zero on planes and on convex ground. With
        # stock, the ball rolls on the offset surface (the cap holds there).
        p = self.params
        h = float(p.scallop if scallop is None else scallop)
        cap = np.inf if self.concave_cap is None else float(self.concave_cap)
        if h not in self._flat:
            self._flat[h] = float(side_interval_stock(h, p.tool_radius, np.zeros(1), p.stock, self.concave_cap)[0][0])
        c = np.ascontiguousarray
        return allowed_across(c(S.I, dtype=np.float64), c(S.II, dtype=np.float64), c(S.n, dtype=np.float64),
                              c(t, dtype=np.float64), h, float(p.tool_radius), float(p.stock), cap,
                              self.rise_tol, self.max_step * self.max_step if self.rise_tol > 0 else 0.0,
                              UNDERCUT_NZ, self._flat[h])

    def domain_steps(self, c: Curve) -> np.ndarray:
        """Step in ``s`` allowed at each sample: ``l_s |r_t| / (sqrt(EG - F^2) rate)``."""
        S = c.sample
        return c.ls * S.length(c.t) / (S.area_factor() * c.rate)

    # -- the family ---------------------------------------------------------------
    def _checked_steps(self, cur: Curve, n_paths: int, max_paths: int, min_step: float) -> np.ndarray:
        """:meth:`domain_steps` of ``cur``; PlanningError for too many paths or a collapsed step."""
        if n_paths > max_paths:
            raise PlanningError(f"more than {max_paths} paths: the scallop height is too small for this part")
        steps = self.domain_steps(cur)
        low = float(np.min(steps))
        if not np.isfinite(low) or low <= min_step:
            raise PlanningError(
                f"side step collapsed to {low:.3g} at offset {cur.s:.6g}: "
                "degenerate surface frame (check the mesh for slivers)"
            )
        return steps

    def _bisect_step(self, family: Family, cur: Curve, level, hint, halvings: int = 40, rounds: int = 8):
        """The next curve where the shrinks of the 3D check stalled.

        A shrink scales the step by what the check measured, as if the allowed interval
        stayed put; where the new curve's own interval shrinks as it moves back (it moves
        into more curved ground), twelve shrinks can leave it still too far (620k igea
        mesh, zigzag: 1.016 after twelve). Here the step's fraction ``g`` of the last try
        (``level(g)``: the level or profile to evaluate) is halved until the check passes,
        then bisected ``rounds`` times between that and the smallest fraction known to
        fail; the largest passing fraction is taken. As ``g`` tends to 0 the new curve
        tends to the current one and the check passes.

        Returns ``(level, curve, d_fwd, ratio)`` with ``level = level(g)`` as evaluated; the
        check's warning is logged only if no fraction passed.
        """
        def attempt(g):
            lev = level(g)
            nxt = self.evaluate(family, lev, tau=hint)
            d_fwd, ratio = pair_distances(cur, nxt, family.closed)
            return ratio, (lev, nxt, d_fwd, ratio)

        best, failed = halve_then_bisect(attempt, 0.5, failing=1.0, halvings=halvings, rounds=rounds)
        if best is None:  # (the last fraction tried is returned)
            log.warning("3D spacing check did not converge at offset %.6g (ratio %.3f)", cur.s, failed[-1][0])
            return failed[-1][2]
        return best

    def run(self, family: Family, s0: float, s_max: float, max_paths: int = 200000, progress=None,
            on_curve=None):
        """Plan curves from ``s0`` to ``s_max`` (both included).

        ``on_curve(curve)``, if given, is called with each curve as soon as it is planned
        (curves are never changed afterwards).

        Returns
        -------
        curves : list of Curve
        realised : list of (k,) float64
            3D distance from each sample of curve i to curve i+1.
        predicted : list of (k,) float64
            ``sqrt(EG - F^2) / |r_t| * ds`` for the step ``ds`` taken.
        shrinks : int
            How often the 3D check shrank a step.
        """
        span = s_max - s0
        min_step = span * 1e-7
        cur = self.evaluate(family, s0)
        curves, realised, predicted = [cur], [], []
        if on_curve is not None:
            on_curve(cur)
        shrinks = 0
        while cur.s < s_max:
            steps = self._checked_steps(cur, len(curves), max_paths, min_step)
            base = float(np.min(steps))
            step = base
            hint = None
            for _ in range(12):
                s_next = min(cur.s + step, s_max)
                nxt = self.evaluate(family, s_next, tau=hint)
                d_fwd, ratio = pair_distances(cur, nxt, family.closed)
                hint = nxt.tau
                if ratio <= 1.0 + 1e-9:
                    break
                shrinks += 1
                step = (s_next - cur.s) * min(0.995 / ratio, 0.999)
            else:
                last = s_next - cur.s
                s_next, nxt, d_fwd, ratio = self._bisect_step(family, cur, lambda g: min(cur.s + g * last, s_max),
                                                              hint)
            realised.append(d_fwd)
            predicted.append(cur.sample.area_factor() / cur.sample.length(cur.t) * cur.rate * (s_next - cur.s))
            curves.append(nxt)
            if on_curve is not None:
                on_curve(nxt)
            cur = nxt
            if progress is not None:
                progress((cur.s - s0) / span if span > 0 else 1.0)
        return curves, realised, predicted, shrinks

    def run_local(self, family: Family, s0: float, s_max: float, quantile: float = 2.0, slope: float = 0.25,
                  spread_mm: float = 0.5, margin: float = 0.99, max_paths: int = 200000, progress=None,
                  on_curve=None):
        """Plan curves from level ``s0`` to ``s_max`` with local steps (adaptive spacing).

        Going past the paper's rule (:meth:`run`: every curve a level set, stepped by the
        minimum allowed step over the current one), the next curve's level is a function
        of ``tau``:

            s_next(tau) = E[ min(ceiling, s(tau) + ds(tau)) ]

        with ``ds`` the allowed level step at each sample of the current curve,
        ``ceiling`` the last ceiling plus the ``quantile`` percentile of ``ds``, and
        ``E`` the largest function below its argument that rises by at most ``slope``
        mm across per mm along the curve (:func:`_envelope`, the rise converted to
        levels with each sample's own scale). So a narrow dip of the allowed step (a
        facet crease on a scan crossing the path) dents the next curve back there,
        gently, instead of moving the whole curve closer; the dent heals on the
        following curves wherever the step allows. Curves stay whole (rings closed,
        rows from side to side) and the last one is level ``s_max`` everywhere.

        The 3D spacing check is the same as in :meth:`run` (every sample of either
        curve within its allowed interval of the other), but a failure shrinks the step
        where it fails, over ``spread_mm`` either side, to ``margin`` of what the check
        measured (then the envelope again); after 6 local rounds the whole step shrinks
        as in :meth:`run`.

        Measured on the igea scan (h = 0.01, r = 4): contour 429 -> 354 rings, 178 ->
        146 m; zigzag 668 -> 543 rows, 141 -> 114 m. What is left of the gap to the
        length floor is mostly rays that need more steps than their neighbours all the
        way across (a narrow radial crease): their dents never heal, and the last curves
        catch up there while lying on the boundary elsewhere (63 of 354 rings on igea).
        Only partial paths would avoid that. The worst case is a narrow ridge through the
        centre of the rings (radial for every ring): there contour came out 1.08x the
        paper's length, against 0.97x with the min rule on the same warp; holding the
        ceiling within a few steps of the lowest level helped there (1.04x) but made
        igea longer (146 -> 150 m), so it is not done.

        Returns the same as :meth:`run` (and calls ``on_curve`` the same way); a curve's
        ``s`` is its lowest level and ``levels`` holds each sample's.
        """
        span = s_max - s0
        min_step = span * 1e-7
        done = s_max - 1e-12 * max(abs(s_max), 1.0)
        cur = self.evaluate(family, s0)
        ceiling = float(s0)
        curves, realised, predicted = [cur], [], []
        if on_curve is not None:
            on_curve(cur)
        shrinks = 0
        closed = family.closed
        while np.min(cur.levels) < done:
            steps = self._checked_steps(cur, len(curves), max_paths, min_step)
            ceiling = min(ceiling + float(np.percentile(steps, quantile)), s_max)
            lv = cur.levels
            seg = np.linalg.norm(np.diff(cur.sample.xyz, axis=0), axis=1)
            # levels per mm across at each sample, then the slope limit per gap in levels/mm
            per_mm = steps / np.maximum(cur.ls, 1e-300)
            k = slope * np.minimum(per_mm[1:], per_mm[:-1])

            def profile(cap):
                T = _envelope(np.ascontiguousarray(np.minimum(cap, s_max)), seg, k, closed)
                return np.clip(np.maximum(T, lv + min_step), None, s_max)

            T = profile(np.minimum(lv + steps, ceiling))
            # start the next curve from this one's parameters, thinned to about 0.9 seg_len
            # of arc (dense where this curve needed it, and no growth from curve to curve)
            arc = np.concatenate([[0.0], np.cumsum(seg)])
            bucket = np.floor(arc / (0.9 * self.seg_len))
            pick = np.concatenate([[True], np.diff(bucket) > 0])
            pick[-1] = True
            hint = np.union1d(cur.tau[pick], np.linspace(0.0, 1.0, 33))
            pos = seg[seg > 0]
            spread = max(1, min(len(lv) // 2, int(round(spread_mm / float(np.median(pos)))))) if pos.size else 1
            for rnd in range(12):
                nxt = self.evaluate(family, Levels(cur.tau, T), tau=hint)
                d_fwd, d_bwd = pair_distances_both(cur, nxt, closed)
                r_fwd, r_bwd = d_fwd / cur.ls, d_bwd / nxt.ls
                ratio = max(np.max(r_fwd), np.max(r_bwd))
                hint = nxt.tau
                if ratio <= 1.0 + 1e-9:
                    break
                shrinks += 1
                if rnd < 6:
                    # where either curve's sample is too far, shrink the step around that tau
                    # (over +-spread_mm along: a shrink at one knot alone barely moves the curve
                    # between knots, and the nearest point of the other curve is not
                    # always at the same tau)
                    f = np.minimum(margin / np.maximum(r_fwd, 1e-300), 1.0)
                    fb = np.minimum(margin / np.maximum(r_bwd, 1e-300), 1.0)
                    f = np.minimum(f, np.interp(cur.tau, nxt.tau, fb))
                    f = running_min(f, spread, closed)  # scipy.ndimage.minimum_filter1d's
                else:
                    f = np.full(len(lv), min(0.995 / ratio, 0.999))
                T = profile(lv + (T - lv) * f)
            else:
                T_last = T
                lev, nxt, d_fwd, ratio = self._bisect_step(
                    family, cur, lambda g: Levels(cur.tau, profile(lv + (T_last - lv) * g)), hint)
                T = lev.s
            realised.append(d_fwd)
            predicted.append(cur.sample.area_factor() / cur.sample.length(cur.t) * cur.rate * (T - lv))
            curves.append(nxt)
            if on_curve is not None:
                on_curve(nxt)
            cur = nxt
            if progress is not None:
                progress((ceiling - s0) / span if span > 0 else 1.0)
        return curves, realised, predicted, shrinks
