"""Pattern planning in the domain: forward steps, 3D spacing, domain clipping."""

import numpy as np
import pytest

from conformill.patterns.domains import BoundaryPolygon
from conformill.patterns.family import curve_distance, point_polyline_distance
from conformill.patterns.forward import chord_deviation, select_forward


def test_point_polyline_distance_matches_brute_force():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 3, 400)
    Q = np.column_stack([t, np.sin(t), 0.1 * t * t])
    P = Q[::7] + rng.normal(scale=0.05, size=(len(Q[::7]), 3))
    d = point_polyline_distance(P, Q)
    a, b = Q[:-1], Q[1:]
    ab = b - a
    tt = np.clip(np.einsum("pij,ij->pi", P[:, None] - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    brute = np.linalg.norm(P[:, None] - (a + tt[..., None] * ab), axis=2).min(1)
    np.testing.assert_allclose(d, brute, atol=1e-12)


def test_curve_distance_between_spiral_revolutions_is_exact_away_from_the_seam():
    # two consecutive revolutions of an Archimedean spiral meet at their ends; the walk must
    # follow the neighbouring revolution, not the continuation of the curve
    def turn(k, n=3000):
        th = np.linspace(0, 2 * np.pi, n)
        rho = 10.0 + 0.5 * (k + th / (2 * np.pi))
        return np.column_stack([rho * np.cos(th), rho * np.sin(th), 0.01 * rho**2])

    a, b = turn(0), turn(1, 3500)
    for P, Q in ((a, b), (b, a)):
        d = curve_distance(P, Q)
        exact = point_polyline_distance(P, Q)
        assert np.all(d >= exact - 1e-12)  # never shorter than the truth (the check stays strict)
        inner = slice(len(P) // 20, len(P) - len(P) // 20)
        np.testing.assert_allclose(d[inner], exact[inner], atol=1e-9)


@pytest.mark.parametrize("R", [5.0, 20.0, 100.0])
def test_select_forward_on_circle_meets_tolerance_and_sagitta_step(R):
    e = 0.01
    th = np.linspace(0, np.pi / 2, 20001)
    X = np.column_stack([R * np.cos(th), R * np.sin(th), np.zeros_like(th)])
    idx = select_forward(X, np.full(len(X), -1.0 / R), e, max_step=50.0)
    dev, _ = chord_deviation(X, idx)
    assert dev.max() <= e + 1e-12
    steps = np.linalg.norm(np.diff(X[idx], axis=0), axis=1)
    lf = 2 * np.sqrt(e * (2 * R - e))  # exact chord with sagitta e
    assert steps.max() <= lf * (1 + 1e-3)
    # not wastefully short: the equidistributed steps are close to the limit
    assert np.median(steps) > 0.9 * lf


def test_select_forward_convex_and_concave_halves_get_their_own_tolerance():
    # a circle walked half convex (kappa < 0), half concave (kappa > 0): chords on the
    # convex half may deviate up to e_convex, those touching the concave half only e
    R, e, ec = 20.0, 0.0025, 0.005
    th = np.linspace(0, np.pi / 2, 20001)
    X = np.column_stack([R * np.cos(th), R * np.sin(th), np.zeros_like(th)])
    kappa = np.where(th < np.pi / 4, -1.0 / R, 1.0 / R)
    idx = select_forward(X, kappa, e, max_step=50.0, e_convex=ec)
    dev, _ = chord_deviation(X, idx)
    convex = th[idx[1:]] < np.pi / 4  # chords whose both ends (and all samples) are convex
    assert dev[convex].max() <= ec + 1e-12
    assert dev[~convex].max() <= e + 1e-12
    steps = np.linalg.norm(np.diff(X[idx], axis=0), axis=1)
    lf = lambda tol: 2 * np.sqrt(tol * (2 * R - tol))  # noqa: E731
    assert np.median(steps[convex]) > 0.9 * lf(ec) and steps[convex].max() <= lf(ec) * (1 + 1e-3)
    assert steps[~convex].max() <= lf(e) * (1 + 1e-3)


def test_select_forward_catches_a_crease_the_curvature_misses():
    # a sharp V (zero curvature reported everywhere): the chord check must add the apex
    x = np.linspace(-10, 10, 2001)
    X = np.column_stack([x, np.zeros_like(x), -np.abs(x)])
    idx = select_forward(X, np.zeros(len(X)), 0.01, max_step=100.0)
    assert 1000 in idx
    dev, _ = chord_deviation(X, idx)
    assert dev.max() <= 0.01


def test_boundary_polygon_limit_on_regular_polygon():
    n, R = 12, 3.0
    t = 2 * np.pi * np.arange(n) / n
    poly = BoundaryPolygon(R * np.column_stack([np.cos(t), np.sin(t)]))
    np.testing.assert_allclose(poly.limit(t), R, atol=1e-12)  # at the vertices
    mid = t + np.pi / n
    np.testing.assert_allclose(poly.limit(mid), R * np.cos(np.pi / n), atol=1e-12)  # edge midpoints
    P = np.array([[10.0, 0.0], [0.5, 0.5]])
    Q = poly.clip(P)
    np.testing.assert_allclose(Q[0], [R, 0.0], atol=1e-12)
    np.testing.assert_allclose(Q[1], [0.5, 0.5])


def test_curve_distance_matches_kdtree_reference_and_never_underestimates():
    from conformill.patterns.family import curve_distance

    rng = np.random.default_rng(3)
    for closed in (False, True):
        t = np.sort(rng.random(900)) * 2 * np.pi
        Q = np.column_stack([30 * np.cos(t), 30 * np.sin(t), 2 * np.sin(3 * t)])
        t2 = np.sort(rng.random(700)) * 2 * np.pi
        P = np.column_stack([31 * np.cos(t2), 31 * np.sin(t2), 2 * np.sin(3 * t2) + 0.2])
        ref = point_polyline_distance(P, Q, closed)
        got = curve_distance(P, Q, closed)
        assert np.all(got >= ref - 1e-12)
        assert np.allclose(got, ref, atol=1e-9)


@pytest.mark.parametrize("q", [2, 3, 5])
def test_curve_distance_on_a_closed_curve_shorter_than_the_window(q):
    """Closed polylines of 2-5 vertices: the walk's window (3 either side) wraps more than
    once round them, and the distance is the exact one to the nearest segment."""
    rng = np.random.default_rng(q)
    Q = rng.normal(size=(q, 3))
    P = rng.normal(size=(40, 3)) * 2.0
    segs = [(Q[i], Q[(i + 1) % q]) for i in range(q)]

    def seg_dist(p, a, b):
        ab = b - a
        t = np.clip((p - a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
        return np.linalg.norm(p - (a + t * ab))

    want = np.array([min(seg_dist(p, a, b) for a, b in segs) for p in P])
    np.testing.assert_allclose(curve_distance(P, Q, closed=True), want, rtol=0, atol=1e-12)


def test_exact_distance_by_scan_equals_the_kdtree_reference():
    """For a few points, the exact distance scans the curve for the nearest vertex instead
    of building a k-d tree; the result is the reference's bit for bit (open curves, the
    planner's use), and the vertex is the nearest one."""
    from conformill.patterns.family import _around_vertex, _nearest_vertex

    rng = np.random.default_rng(11)
    for _ in range(50):
        q, k = int(rng.integers(1, 300)), int(rng.integers(1, 40))
        t = np.sort(rng.random(q)) * 2 * np.pi
        Q = np.column_stack([30 * np.cos(t), 30 * np.sin(t), 2 * np.sin(3 * t)])
        P = rng.normal(scale=35.0, size=(k, 3))
        j = _nearest_vertex(P, Q)
        d2 = ((P[:, None, :] - Q[None, :, :]) ** 2).sum(-1)
        np.testing.assert_allclose(d2[np.arange(k), j], d2.min(axis=1), rtol=1e-12)
        assert np.array_equal(_around_vertex(P, Q, j, False), point_polyline_distance(P, Q, False))


def test_exact_distance_on_a_closed_curve_measures_both_sides_of_the_seam():
    """A closed curve's first and last samples are the same point up to rounding. Whichever
    of the two the nearest-vertex search picks (scan or k-d tree), the segments on both
    sides of the seam are measured: the distance is the brute-force minimum over all
    segments, and the scan and the tree agree bit for bit."""
    from conformill.patterns.family import _around_vertex, _nearest_vertex

    def seg_dist(p, a, b):
        ab = b - a
        s = np.clip((p - a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
        return np.linalg.norm(p - (a + s * ab))

    rng = np.random.default_rng(5)
    seen = 0
    for _ in range(50):
        q = int(rng.integers(4, 300))
        t = np.sort(rng.random(q - 1)) * 2 * np.pi
        t = np.concatenate([t, [t[0] + 2 * np.pi]])  # the seam: last = first up to rounding
        Q = np.column_stack([30 * np.cos(t), 30 * np.sin(t), 2 * np.sin(3 * t)])
        ang = t[0] + rng.normal(scale=0.05, size=20)  # points near the seam, on both sides
        rad = 30 + rng.normal(size=20)
        P = np.column_stack([rad * np.cos(ang), rad * np.sin(ang), rng.normal(size=20)])
        want = np.array([min(seg_dist(p, Q[m], Q[m + 1]) for m in range(q - 1)) for p in P])
        j = _nearest_vertex(P, Q)
        by_scan = _around_vertex(P, Q, j, True)
        np.testing.assert_allclose(by_scan, want, rtol=0, atol=1e-12)
        assert np.array_equal(by_scan, point_polyline_distance(P, Q, True))
        at_seam = (j == 0) | (j == q - 1)
        seen += int(at_seam.sum())
        for seam in (0, q - 1):  # either copy of the seam point as the nearest vertex
            got = _around_vertex(P[at_seam], Q, np.full(int(at_seam.sum()), seam), True)
            np.testing.assert_allclose(got, want[at_seam], rtol=0, atol=1e-12)
    assert seen > 200


def _two_segments(P, Q, j, closed):
    """Distance from each point of ``P`` to vertex ``j`` of ``Q`` and the segments either
    side, in numpy (``family._two_segments_one``'s reference; session 49 and before)."""
    if len(Q) == 1:
        return np.linalg.norm(P - Q[0], axis=1)
    best = np.linalg.norm(P - Q[j], axis=1)
    q = len(Q)
    for lo in (j - 1, j):
        if closed:
            a, b = Q[lo % q], Q[(lo + 1) % q]
            ok = np.ones(len(P), dtype=bool)
        else:
            ok = (lo >= 0) & (lo + 1 < q)
            a, b = Q[np.clip(lo, 0, q - 1)], Q[np.clip(lo + 1, 0, q - 1)]
        ab = b - a
        t = np.einsum("ij,ij->i", P - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
        t = np.clip(t, 0.0, 1.0)
        d = np.linalg.norm(P - (a + t[:, None] * ab), axis=1)
        best = np.where(ok, np.minimum(best, d), best)
    return best


def _around_numpy(P, Q, j, closed):
    """``family._around_vertex`` as numpy computed it (session 49 and before)."""
    best = _two_segments(P, Q, j, closed)
    q = len(Q)
    if closed and q > 2:
        seam = np.flatnonzero((j == 0) | (j == q - 1))
        if seam.size:
            other = np.where(j[seam] == 0, q - 1, 0)
            best[seam] = np.minimum(best[seam], _two_segments(P[seam], Q, other, closed))
    return best


@pytest.mark.parametrize("closed", [False, True])
def test_the_compiled_exact_distance_is_numpy_s_bit_for_bit(closed):
    """The exact distance around a vertex (compiled) against the numpy arithmetic it
    replaced: random curves of 2 to 300 vertices with repeated vertices (zero-length
    segments), points near and far, every vertex index (the seam's too), NaN rows."""
    from conformill.patterns.family import _around_vertex

    # the kernel follows the order of terms numpy's einsum takes on x86-64 (numpy 2): bit
    # for bit where numpy adds in that order, within rounding where it does not
    A, B = np.random.default_rng(0).normal(size=(2, 10000, 3))
    exact = np.array_equal(np.einsum("ij,ij->i", A, B),
                           (A[:, 0] * B[:, 0] + A[:, 2] * B[:, 2]) + A[:, 1] * B[:, 1])
    rng = np.random.default_rng(21)
    n = 0
    for _ in range(200):
        q, k = int(rng.integers(2, 300)), int(rng.integers(1, 400))
        Q = np.cumsum(rng.normal(scale=0.3, size=(q, 3)), axis=0)
        rep = rng.random(q) < 0.1
        rep[0] = False
        Q[rep] = Q[np.flatnonzero(rep) - 1]
        if closed and q > 2:
            Q[-1] = Q[0] * (1 + 1e-16)
        P = Q[rng.integers(0, q, k)] + rng.normal(scale=rng.choice([1e-9, 0.1, 3.0]), size=(k, 3))
        j = rng.integers(0, q, k)
        j[: min(k, 3)] = [0, q - 1, q // 2][: min(k, 3)]
        if k > 5:
            P[4] = np.nan
        got = _around_vertex(P, Q, j, closed)
        want = _around_numpy(P, Q, j, closed)
        assert np.array_equal(np.isnan(got), np.isnan(want))
        if exact:
            assert np.array_equal(got, want, equal_nan=True)
        else:  # another einsum order: within a few ulps
            np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-300)
        n += k
    assert n > 30000


@pytest.mark.parametrize("max_step", [1.0, 0.1, 0.02])
def test_plan_meets_the_longest_forward_step(max_step):
    # --max-step below the dense samples' spacing (about 0.36 mm here) was not met: the CC
    # steps were chosen among the samples, 0.36 mm apart for a max-step of 0.01 mm; and the
    # equidistribution let a step reach the step plus one sample (1.3 mm for 1.0)
    from conformill.mesh import synthetic
    from conformill.pipeline import Job, plan

    res = plan(synthetic.sphere_cap(), Job(pattern="zigzag", tool_radius=3.0, scallop=0.05, tolerance=0.01,
                                           max_step=max_step))
    steps = np.concatenate([np.linalg.norm(np.diff(c, axis=0), axis=1) for c in res.cc_paths])
    assert steps.max() <= max_step * (1 + 1e-12)
    assert np.median(steps) > 0.5 * max_step  # not a crowd of tiny steps either


def test_select_forward_caps_the_chords():
    # a straight line sampled every 0.3 mm: no chord longer than max_step where samples
    # allow, one sample apart where they do not
    X = np.column_stack([np.arange(0, 30.0, 0.3), np.zeros(100), np.zeros(100)])
    for ms in (5.0, 1.0, 0.3, 0.1):
        idx = select_forward(X, np.zeros(100), 0.01, max_step=ms)
        st = np.diff(X[idx, 0])
        assert idx[0] == 0 and idx[-1] == 99
        assert st.max() <= max(ms, 0.3) + 1e-9


def _walk_unbounded(P, Q, closed, window):
    """The walk measuring every segment of its window, as before session 51: the reference
    for the bound that skips the far ones."""
    from conformill.patterns.family import _walk_distance

    return _walk_distance(P, Q, closed, window, False)


def _walk_cases():
    rng = np.random.default_rng(11)
    for closed in (False, True):
        for q, k in ((900, 700), (400, 400), (60, 900)):
            t = np.sort(rng.random(q)) * 2 * np.pi
            Q = np.column_stack([30 * np.cos(t), 30 * np.sin(t), 2 * np.sin(3 * t)])
            t2 = np.sort(rng.random(k)) * 2 * np.pi
            P = np.column_stack([31 * np.cos(t2), 31 * np.sin(t2), 2 * np.sin(3 * t2) + 0.2])
            yield P, Q, closed
            P2 = Q[rng.integers(0, q, k)]  # points on the vertices (distance 0), in no order
            yield P2, Q, closed
            Q3 = np.repeat(Q, 2, axis=0)  # every vertex twice (zero-length segments)
            yield P, Q3, closed
            P4 = P.copy()
            P4[::50] = np.nan  # NaN samples and vertices
            Q4 = Q.copy()
            Q4[7] = np.nan
            yield P4, Q4, closed
    for q in (2, 3, 5, 8):  # closed curves shorter than the window, and scattered points
        yield rng.normal(size=(40, 3)) * 2.0, rng.normal(size=(q, 3)), True
        yield rng.normal(size=(40, 3)) * 2.0, rng.normal(size=(q, 3)), False
    t = np.linspace(0.0, 6 * np.pi, 3000)  # two revolutions of a spiral, apart by 0.3
    S = np.column_stack([(10 + 0.3 * t / (2 * np.pi)) * np.cos(t), (10 + 0.3 * t / (2 * np.pi)) * np.sin(t), 0 * t])
    yield S[1000:2000], S[:1000], False
    yield S[:1000], S[1000:2000], False


def test_the_walk_s_segment_bound_leaves_every_distance_bit_for_bit():
    """The walk skips a window segment whose lower bound (its ends' distance less a quarter
    of its squared length) is clearly above the nearest so far: the distances are those of
    the walk that measured them all, to the bit (NaN where it gave NaN), on nearly parallel
    curves, points on the vertices, doubled vertices, NaN samples and vertices, curves
    shorter than the window and a spiral's neighbouring revolutions."""
    from conformill.patterns.family import _walk_distance

    n = 0
    for P, Q, closed in _walk_cases():
        for window in (3, 1):
            want = _walk_unbounded(P, Q, closed, window)
            got = _walk_distance(P, Q, closed, window, True)
            assert np.array_equal(got.view(np.int64), want.view(np.int64)), (len(P), len(Q), closed, window)
            n += np.count_nonzero(np.isfinite(got))
    assert n > 20000


def test_the_walk_s_segment_bound_keeps_its_margin_where_a_path_doubles_back():
    """A path that doubles back on itself ((1, y, 0) -> (-1, 0, 0) -> (1, 0, 0)) under a
    point (0, 0, h): the far segment's bound, 1 + h^2 - 1, is above the nearest distance h^2
    by less than the rounding of either side. Without the bound's margin the walk skips the
    segment that is the nearest after rounding and returns another distance (found by a
    review, session 51); with it, the distances are those of the walk that measured every
    segment."""
    from conformill.patterns.family import _walk_distance

    P = np.empty((1, 3))
    n = 0
    for h in np.linspace(1e-5, 2e-5, 201):
        ea = 1.0 + h * h
        gap = ea - 1.0 - h * h
        if gap <= 0.0:
            continue
        for y0 in 2.0 * np.sqrt(0.5 * gap) * np.linspace(0.5, 1.5, 41):
            Q = np.array([[1.0, y0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
            P[0] = (0.0, 0.0, h)
            for window in (1, 2, 3):
                want = _walk_unbounded(P, Q, False, window)
                got = _walk_distance(P, Q, False, window, True)
                assert got.view(np.int64)[0] == want.view(np.int64)[0], (h, y0, window, got[0], want[0])
                n += 1
    assert n > 1000
