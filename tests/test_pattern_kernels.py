"""The pattern stage's compiled kernels give the bits of the numpy code they replaced.

Session 42 moved the hot steps of :meth:`Planner.evaluate` and of the curve families into
compiled loops: the surface sample (point location, interpolation and the unit normal in
one pass, and the merge of a refined curve's kept rows), the refinement of the
along-parameters, :meth:`Planner.allowed`, the circle domain's polygon limit, the warp's
offsets and warped rings and spiral turns. The plans are the same bytes only if each step
is the same arithmetic, so each is checked here against a numpy version of the code it
replaced, for exact equality (NaN where NaN), on inputs that reach every branch.
"""

import numpy as np
import pytest

from conformill.geometry.differential import interpolate
from conformill.geometry.surface import DomainSurface, SurfaceSample
from conformill.mesh import synthetic
from conformill.param import parameterize
from conformill.patterns import family
from conformill.patterns.family import Planner, _refined, _refined_sorted
from conformill.planning.steps import side_interval_stock
from conformill.types import PathParams


def _allowed_numpy(planner, S, t):
    """:meth:`Planner.allowed` as it was in numpy (session 41)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return _allowed_numpy_body(planner, S, t)


def _allowed_numpy_body(planner, S, t):
    kappa = S.curvature(S.across(t))
    h = planner.params.scallop
    if planner.rise_tol > 0:
        along = np.maximum(S.curvature(t), 0.0)
        rise = np.minimum(planner.rise_tol, along * planner.max_step ** 2 / 8.0)
        h = h - np.nan_to_num(rise, nan=planner.rise_tol)
    ls, reach = side_interval_stock(h, planner.params.tool_radius, kappa, planner.params.stock,
                                    planner.concave_cap)
    ls = np.asarray(ls, dtype=np.float64)
    down = S.n[:, 2] < family.UNDERCUT_NZ
    if down.any():
        flat, _ = side_interval_stock(planner.params.scallop, planner.params.tool_radius, np.zeros(1),
                                      planner.params.stock, planner.concave_cap)
        ls = np.where(down, np.maximum(ls, flat[0]), ls)
    return ls, np.asarray(reach, dtype=bool)


def _random_sample(k, seed):
    """Samples with random positive and degenerate metrics, curvatures from sharp convex to
    past the ball's concave limit, normals facing up and down, and some NaN entries."""
    rng = np.random.default_rng(seed)
    E = rng.uniform(0.2, 3.0, k)
    G = rng.uniform(0.2, 3.0, k)
    F = rng.uniform(-0.9, 0.9, k) * np.sqrt(E * G)
    F[:20] = np.sqrt(E[:20] * G[:20])  # degenerate: EG - F^2 = 0
    II = rng.normal(0.0, 0.4, (k, 3)) * rng.choice([0.01, 0.1, 1.0, 5.0], (k, 1))
    II[20:30] = np.nan
    II[30:40] = 0.0
    nz = rng.uniform(-1.0, 1.0, k)
    nz[40:45] = family.UNDERCUT_NZ
    n = np.column_stack([np.sqrt(1.0 - nz ** 2), np.zeros(k), nz])
    I = np.column_stack([E, F, G])
    S = SurfaceSample(uv=np.zeros((k, 2)), face=np.zeros(k, np.int64), bary=np.full((k, 3), 1 / 3),
                      xyz=np.zeros((k, 3)), n=n, I=I, II=II)
    t = rng.normal(size=(k, 2))
    t[45:50] = 0.0  # no direction: NaN curvature
    return S, t


@pytest.mark.parametrize("stock", [0.0, 0.4, -0.3])
@pytest.mark.parametrize("cap", [None, 0.3])
@pytest.mark.parametrize("rise_tol, max_step", [(0.0, np.inf), (0.0025, np.inf), (0.0025, 2.0)])
def test_allowed_is_the_numpy_arithmetic_bit_for_bit(stock, cap, rise_tol, max_step):
    params = PathParams(tool_radius=4.0, scallop=0.01, tolerance=0.01, stock=stock)
    planner = Planner(None, params, seg_len=0.2, concave_cap=cap, rise_tol=rise_tol, max_step=max_step)
    S, t = _random_sample(4000, seed=int(100 * abs(stock)) + (cap is None) + int(1e4 * rise_tol))
    ls, reach = planner.allowed(S, t)
    ref_ls, ref_reach = _allowed_numpy(planner, S, t)
    np.testing.assert_array_equal(ls, ref_ls)  # NaN where NaN, else the same bits
    np.testing.assert_array_equal(reach, ref_reach)
    assert reach.dtype == bool and ls.dtype == np.float64
    assert (~reach).any() and reach.any()
    if cap is not None and stock == 0:
        assert np.any(ls == cap)  # the cap binds somewhere


@pytest.mark.parametrize("stock", [0.0, 0.4])
@pytest.mark.parametrize("cap", [None, 0.3])
def test_allowed_at_another_scallop_is_a_planner_built_for_it(stock, cap):
    # Planner.allowed(S, t, scallop=h) on a planner spaced for 1.7 h (the widening test's
    # Curve.ls_base) gives the bits of a planner built for h, with the same cap, and its
    # own scallop again afterwards (the flat interval is cached per scallop)
    wide = PathParams(tool_radius=4.0, scallop=0.017, tolerance=0.01, stock=stock)
    base = PathParams(tool_radius=4.0, scallop=0.01, tolerance=0.01, stock=stock)
    kw = dict(seg_len=0.2, concave_cap=cap, rise_tol=0.0025, max_step=2.0)
    planner = Planner(None, wide, base_scallop=0.01, **kw)
    S, t = _random_sample(3000, seed=11)
    own = planner.allowed(S, t)[0]
    at_h = planner.allowed(S, t, 0.01)[0]
    np.testing.assert_array_equal(at_h, Planner(None, base, **kw).allowed(S, t)[0])
    np.testing.assert_array_equal(planner.allowed(S, t)[0], own)
    ok = np.isfinite(own)
    assert np.all(own[ok] >= at_h[ok]) and np.any(own[ok] > at_h[ok])
    assert Planner(None, base, base_scallop=0.01, **kw).base_scallop is None  # the same scallop: no second pass


def test_allowed_follows_a_patched_undercut_limit(monkeypatch):
    """The limit is read when the planner is asked (a test patches it)."""
    params = PathParams(tool_radius=4.0, scallop=0.01, tolerance=0.01)
    planner = Planner(None, params, seg_len=0.2)
    S, t = _random_sample(2000, seed=5)
    monkeypatch.setattr(family, "UNDERCUT_NZ", 0.5)
    np.testing.assert_array_equal(planner.allowed(S, t)[0], _allowed_numpy(planner, S, t)[0])


def _curve(k, seed, seg_len):
    rng = np.random.default_rng(seed)
    tau = np.sort(rng.uniform(0.0, 1.0, k))
    tau[0], tau[-1] = 0.0, 1.0
    steps = rng.choice([0.3, 1.0, 2.5, 9.0], k) * seg_len * rng.uniform(0.5, 1.0, k)
    xyz = np.column_stack([np.cumsum(steps), rng.normal(0.0, 0.1 * seg_len, k), np.zeros(k)])
    return tau, xyz


@pytest.mark.parametrize("seed", range(6))
def test_the_refinement_is_the_stable_sort_bit_for_bit(seed):
    seg_len = 0.2
    tau, xyz = _curve(500, seed, seg_len)
    done, tau_new, new = _refined(tau, xyz, seg_len)
    assert not done and tau_new is not None
    ref_tau, ref_new = _refined_sorted(tau, xyz, seg_len)
    np.testing.assert_array_equal(tau_new, ref_tau)
    np.testing.assert_array_equal(new, ref_new)
    assert np.all(np.diff(tau_new) > 0)
    np.testing.assert_array_equal(tau_new[~new], tau)  # the old parameters, all kept


def _round(tau, xyz, seg_len):
    """One refinement round as :meth:`Planner.evaluate` makes it: compiled, or sorted
    where the compiled merge hands over."""
    done, tau_new, new = _refined(tau, xyz, seg_len)
    if done:
        return None, None, False
    if tau_new is None:
        return (*_refined_sorted(tau, xyz, seg_len), True)
    return tau_new, new, False


@pytest.mark.parametrize("ulps", [1, 2, 3, 7])
def test_a_gap_too_narrow_to_split_is_the_sort_bit_for_bit(ulps):
    # a long 3D gap over a few ulps of tau: its new parameters round onto the old ones
    # (dropped) or past the next one (the compiled merge hands the round to the sort)
    tau = np.array([0.0, 0.1, 0.1 + ulps * np.spacing(0.1), 1.0])
    xyz = np.array([[0.0, 0, 0], [0.01, 0, 0], [5.0, 0, 0], [5.01, 0, 0]])
    tau_new, new, sorted_ = _round(tau, xyz, 0.2)
    ref_tau, ref_new = _refined_sorted(tau, xyz, 0.2)
    np.testing.assert_array_equal(tau_new, ref_tau)
    np.testing.assert_array_equal(new, ref_new)
    assert np.all(np.diff(tau_new) > 0)
    assert len(tau_new) <= len(tau) + ulps - 1  # at most one new parameter per ulp inside
    assert sorted_  # 0.1 + k ulp (j / q) rounds up onto the next parameter for some j


def test_a_new_parameter_rounded_onto_the_last_one_is_dropped_by_the_compiled_merge():
    # a gap of one ulp split in two: 0.1 + ulp / 2 rounds to 0.1 (the old parameter), not
    # past the next one, so the compiled merge drops it itself
    tau = np.array([0.0, 0.1, 0.1 + np.spacing(0.1), 1.0])
    xyz = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.31, 0, 0], [0.32, 0, 0]])
    done, tau_new, new = _refined(tau, xyz, 0.2)
    assert not done and tau_new is not None  # no hand-over
    ref_tau, ref_new = _refined_sorted(tau, xyz, 0.2)
    np.testing.assert_array_equal(tau_new, ref_tau)
    np.testing.assert_array_equal(new, ref_new)
    np.testing.assert_array_equal(tau_new, tau)


def test_parameters_out_of_order_go_to_the_sort():
    tau = np.array([0.0, 0.6, 0.4, 1.0])
    xyz = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.1, 0, 0], [1.2, 0, 0]])
    assert _refined(tau, xyz, 0.2)[1] is None


def test_the_refinement_hands_over_where_a_new_parameter_rounds_onto_the_next():
    tau = np.array([0.0, 0.5, np.nextafter(0.5, 1.0), 1.0])
    xyz = np.array([[0.0, 0, 0], [0.1, 0, 0], [1.0, 0, 0], [1.1, 0, 0]])
    assert _refined(tau, xyz, 0.2)[1] is None  # 0.5 + ulp (j / 5) rounds up to 0.5 + ulp for j >= 3
    tau_new, new, sorted_ = _round(tau, xyz, 0.2)
    assert sorted_
    np.testing.assert_array_equal(tau_new, tau)  # nothing fits inside
    assert not new.any()


def test_the_refinement_is_done_when_every_gap_is_short():
    tau, xyz = _curve(300, 7, 0.2)
    assert _refined(tau, xyz * 1e-3, 0.2)[0]


@pytest.fixture(scope="module")
def surface():
    mesh = synthetic.face_like(seed=3, spacing=2.0, size=80.0)
    p = parameterize(mesh, boundary="circle")
    return DomainSurface(mesh.V, mesh.F, p.uv)


def _sample_numpy(surf, P):
    """:meth:`DomainSurface.sample` as it was (session 41): locate, interpolate, normalise."""
    face, bary = surf.locator.locate(P)
    out = interpolate(surf._pack, surf.F, face, bary)
    n = out[:, 3:6]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return face, bary, out


def _domain_points(surface, k, seed):
    """``k`` points over the whole circle domain: random ones inside, 20 on vertices
    (several faces hold them) and 20 just outside the boundary by less than the locator's
    snapping tolerance (snapped onto the nearest face)."""
    rng = np.random.default_rng(seed)
    R0 = float(np.max(np.linalg.norm(surface.uv, axis=1)))
    rho = 0.97 * R0 * np.sqrt(rng.uniform(0.0, 1.0, k))
    th = rng.uniform(0.0, 2 * np.pi, k)
    P = np.column_stack([rho * np.cos(th), rho * np.sin(th)])
    P[:20] = surface.uv[surface.F[:20, 0]]
    b = surface.uv[np.argsort(-np.linalg.norm(surface.uv, axis=1))[:20]]  # boundary vertices
    P[20:40] = b * (1.0 + 0.5 * surface.locator.tol / np.linalg.norm(b, axis=1, keepdims=True))
    return P


def _brute_location_ok(surface, P, face, bary):
    """Independent of the locator's grid: every point is located in a face whose
    barycentrics are valid and rebuild it (within the snapping tolerance), and a point
    clearly inside one face (every barycentric above 1e-9 by a scan of all faces) is in it."""
    uv, F = surface.uv, surface.F
    assert np.all(face >= 0)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(bary >= -1e-15)
    rebuilt = np.einsum("ij,ijk->ik", bary, uv[F[face]])
    assert np.all(np.linalg.norm(rebuilt - P, axis=1) <= surface.locator.tol + 1e-12)
    A, B, C = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    inside = 0
    for i in range(0, len(P), 7):
        p = P[i]
        w0 = (B[:, 0] - p[0]) * (C[:, 1] - p[1]) - (B[:, 1] - p[1]) * (C[:, 0] - p[0])
        w1 = (C[:, 0] - p[0]) * (A[:, 1] - p[1]) - (C[:, 1] - p[1]) * (A[:, 0] - p[0])
        w2 = (A[:, 0] - p[0]) * (B[:, 1] - p[1]) - (A[:, 1] - p[1]) * (B[:, 0] - p[0])
        sgn = np.sign(w0 + w1 + w2)
        clear = np.flatnonzero((w0 * sgn > 1e-9) & (w1 * sgn > 1e-9) & (w2 * sgn > 1e-9))
        if clear.size == 1:
            assert face[i] == clear[0]
            inside += 1
    return inside


@pytest.mark.parametrize("k", [700, 20000])
def test_the_sample_is_the_numpy_arithmetic_bit_for_bit(surface, k):
    P = _domain_points(surface, k, seed=k)
    S = surface.sample(P)
    assert len(np.unique(S.face)) > 0.1 * min(k, len(surface.F))  # spread over the domain
    assert _brute_location_ok(surface, P, S.face, S.bary) > 50
    snapped = S.bary[20:40]
    assert np.all(snapped.min(axis=1) == 0.0)  # on a boundary edge of their face
    face, bary, out = _sample_numpy(surface, P)
    np.testing.assert_array_equal(S.face, face)
    np.testing.assert_array_equal(S.bary, bary)
    for got, cols in ((S.xyz, slice(0, 3)), (S.n, slice(3, 6)), (S.I, slice(6, 9)), (S.II, slice(9, 12))):
        np.testing.assert_array_equal(got, out[:, cols])
    np.testing.assert_allclose(np.linalg.norm(S.n, axis=1), 1.0, rtol=1e-12)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_a_sample_of_few_points(surface, k):
    P = _domain_points(surface, 700, seed=5)[100:100 + k]
    S = surface.sample(P)
    face, bary, out = _sample_numpy(surface, P)
    np.testing.assert_array_equal(S.face, face)
    np.testing.assert_array_equal(S.bary, bary)
    np.testing.assert_array_equal(np.column_stack([S.xyz, S.n, S.I, S.II]), out)
    np.testing.assert_array_equal(S.uv, P)


def test_a_point_outside_the_domain_is_named(surface):
    from conformill.errors import PlanningError

    with pytest.raises(PlanningError, match=r"1 domain point\(s\) fall outside the parameter mesh, e.g. \[1000.0, 0.0\]"):
        surface.sample(np.array([[0.0, 0.0], [1000.0, 0.0]]))


def test_the_sample_keeps_its_rows_and_evaluates_the_new_ones_only(surface):
    rng = np.random.default_rng(11)
    k = 900
    P = _domain_points(surface, k, seed=11)
    new = rng.uniform(size=k) < 0.3
    kept = surface.sample(P[~new])
    S = surface.sample(P, keep=kept, new=new)
    full = surface.sample(P)
    for f in ("uv", "face", "bary", "xyz", "n", "I", "II"):
        np.testing.assert_array_equal(getattr(S, f), getattr(full, f))
        np.testing.assert_array_equal(getattr(S, f)[~new], getattr(kept, f))
    # the kept rows are copied, not evaluated again: a marked row keeps its value
    marked = SurfaceSample(**{f: getattr(kept, f).copy() for f in ("uv", "face", "bary", "xyz", "n", "I", "II")})
    marked.xyz[:, 2] = -7.0
    assert np.all(surface.sample(P, keep=marked, new=new).xyz[~new, 2] == -7.0)


def test_one_kernel_serves_a_plain_sample_and_a_refined_one(surface):
    """A fresh install compiles the sample's kernel once: the stand-ins for no kept rows
    are typed as a real sample's kept rows."""
    from conformill.geometry.surface import _sample_rows

    P = _domain_points(surface, 700, seed=9)
    S = surface.sample(P[:300])
    compiled = len(_sample_rows.signatures)
    new = np.zeros(700, dtype=bool)
    new[300:] = True
    surface.sample(P, keep=S, new=new)
    assert len(_sample_rows.signatures) == compiled  # no second version for the refined one


def test_kept_rows_must_match_the_mask(surface):
    from conformill.errors import PlanningError

    P = np.zeros((5, 2))
    kept = surface.sample(P[:3])
    with pytest.raises(PlanningError, match="3 kept rows and 1 new ones for 5 points"):
        surface.sample(P, keep=kept, new=np.array([True, False, False, False, False]))


# -- the curve families' compiled steps (the polygon's limit, the warp, rings and turns) --

from conformill.patterns import domains  # noqa: E402
from conformill.patterns.warp import Warp  # noqa: E402


def _limit_numpy(poly, theta):
    """:meth:`BoundaryPolygon.limit` as it was (session 41)."""
    th = np.mod(theta, domains.TWO_PI)
    b = len(poly.ang)
    j = (np.searchsorted(poly.ang, th, side="right") - 1) % b
    cs = np.cos(th - poly._phi[j])
    with np.errstate(divide="ignore", over="ignore"):
        t = poly._p[j] / np.where(cs > 1e-300, cs, 1e-300)
    return np.where(poly._ok[j] & (cs > 1e-300) & (t > 0) & np.isfinite(t), t, poly.R0)


def _polygon(seed, b=300):
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0.0, 2 * np.pi, b))
    rad = 1.0 - 0.1 * rng.uniform(size=b)
    uvb = np.column_stack([rad * np.cos(ang), rad * np.sin(ang)])
    uvb[5] = uvb[4]  # a degenerate edge
    return domains.BoundaryPolygon(uvb)


def test_the_polygon_limit_is_the_numpy_arithmetic_bit_for_bit():
    poly = _polygon(0)
    rng = np.random.default_rng(1)
    theta = np.concatenate([rng.uniform(-40.0, 40.0, 50000), poly.ang, poly.ang + 1e-15, [0.0, -0.0, 2 * np.pi,
                                                                                          -2 * np.pi, np.nan]])
    np.testing.assert_array_equal(poly.limit(theta), _limit_numpy(poly, theta))
    np.testing.assert_array_equal(poly.limit(theta[:50600].reshape(-1, 8)), _limit_numpy(poly, theta[:50600]).reshape(-1, 8))


def test_the_polygon_limit_s_buckets_keep_the_binary_search_s_edge():
    # vertex angles bunched in a narrow arc (many to a bucket, most buckets empty) and
    # directions on every bucket edge and one ulp either side, where rounding may put a
    # direction in the next bucket
    rng = np.random.default_rng(3)
    ang = np.sort(np.concatenate([rng.uniform(1.0, 1.001, 250), rng.uniform(0.0, 2 * np.pi, 50), [0.0]]))
    uvb = np.column_stack([np.cos(ang), np.sin(ang)])
    for poly in (domains.BoundaryPolygon(uvb), _polygon(4, b=7)):
        edges = np.arange(len(poly.ang) + 1) * (domains.TWO_PI / len(poly.ang))
        theta = np.concatenate([edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf), poly.ang,
                                np.nextafter(poly.ang, np.inf), np.nextafter(poly.ang, -np.inf),
                                rng.uniform(-10.0, 10.0, 20000), rng.uniform(0.999, 1.002, 20000)])
        np.testing.assert_array_equal(poly.limit(theta), _limit_numpy(poly, theta))


def _polygon_at(ang):
    ang = np.asarray(ang, dtype=np.float64)
    return domains.BoundaryPolygon(np.column_stack([np.cos(ang), np.sin(ang)]))


def test_the_polygon_edge_search_is_searchsorted_with_vertices_on_bucket_edges():
    # vertex angles on the buckets' edges and an ulp or two either side, and one of exactly
    # 2 pi (np.mod of a tiny negative angle), for vertex counts where nb * (2 pi / nb)
    # rounds below 2 pi (75, 150, 300): the edge found is numpy's for every direction
    rng = np.random.default_rng(8)
    for b in (1, 2, 3, 7, 75, 150, 300):
        for trial in range(20):
            edges = np.arange(b) * (domains.TWO_PI / b)
            ang = edges.copy()
            for k in range(b):
                for _ in range(int(rng.integers(0, 3))):
                    ang[k] = np.nextafter(ang[k], np.inf if rng.random() < 0.5 else -np.inf)
            ang = np.mod(ang, domains.TWO_PI)
            poly = _polygon_at(ang)
            if trial % 2:  # one vertex at exactly 2 pi
                poly.ang[-1] = domains.TWO_PI
            cuts = np.arange(b + 1) * (domains.TWO_PI / b)
            theta = np.concatenate([cuts, np.nextafter(cuts, -np.inf), np.nextafter(cuts, np.inf), poly.ang,
                                    np.nextafter(poly.ang, np.inf), np.nextafter(poly.ang, -np.inf),
                                    [-1e-17, -5e-324, -0.0, 0.0, domains.TWO_PI], rng.uniform(-20.0, 20.0, 500)])
            j, _ = domains._edge_angles(theta, poly.ang, poly._phi, poly._start)
            want = (np.searchsorted(poly.ang, np.mod(theta, domains.TWO_PI), side="right") - 1) % len(poly.ang)
            np.testing.assert_array_equal(j, want)


def test_the_edge_angle_is_numpy_s_mod_bit_for_bit_at_the_borders_of_its_short_cut():
    # within one turn either side of [0, 2 pi) the kernel takes x or x + 2 pi instead of
    # fmod: the same bits as np.mod, signed zeros and the turn's ends one ulp either side
    # included, and beyond them (fmod) as before
    poly = _polygon(5, b=150)
    T = domains.TWO_PI
    ends = np.array([0.0, T, -T, 2 * T, -2 * T, 3 * T])
    rng = np.random.default_rng(9)
    odd = [-0.0, 5e-324, -5e-324, -1e-17, np.inf, -np.inf, np.nan, 1e300, -1e300]
    theta = np.concatenate([ends, np.nextafter(ends, np.inf), np.nextafter(ends, -np.inf), odd,
                            rng.uniform(-3 * T, 3 * T, 20000)])
    j, arg = domains._edge_angles(theta, poly.ang, poly._phi, poly._start)
    with np.errstate(invalid="ignore"):  # (np.mod of inf and NaN)
        th = np.mod(theta, T)
    want_j = (np.searchsorted(poly.ang, th, side="right") - 1) % len(poly.ang)
    ok = np.isfinite(theta)  # (for inf and NaN numpy's searchsorted and the kernel's search differ; the arg is NaN)
    np.testing.assert_array_equal(j[ok], want_j[ok])
    want = th - poly._phi[j]
    assert np.array_equal(arg.view(np.int64)[ok], want.view(np.int64)[ok])
    assert np.all(np.isnan(arg[~ok]))


def _warp(closed, seed=2, m=65, n=33, top=1.0):
    """A random warp table; ``top > 1`` lets the middle levels reach past the far side."""
    rng = np.random.default_rng(seed)
    G = np.sort(rng.uniform(0.0, top, size=(m, n)), axis=0)
    G[0], G[-1] = 0.0, 1.0
    tau = np.arange(n) / n if closed else np.linspace(0.0, 1.0, n)
    return Warp(tau, G, 0.05, lambda t: 0.9 + 0.05 * np.cos(7 * np.asarray(t)), closed)


def _bilinear_numpy(G, s, tau, closed):
    """The warp's bilinear table lookup in numpy (as ``Warp.fraction`` was, session 41)."""
    m, n = G.shape
    fs = np.clip(s, 0.0, 1.0) * (m - 1)
    j0 = np.minimum(np.floor(fs).astype(np.int64), m - 2)
    ws = fs - j0
    if closed:
        f = (tau - np.floor(tau)) * n
        i0 = np.floor(f).astype(np.int64) % n
        i1 = (i0 + 1) % n
        wt = f - np.floor(f)
    else:
        f = np.clip(tau, 0.0, 1.0) * (n - 1)
        i0 = np.minimum(np.floor(f).astype(np.int64), n - 2)
        i1 = i0 + 1
        wt = f - i0
    lo = G[j0, i0] + wt * (G[j0, i1] - G[j0, i0])
    hi = G[j0 + 1, i0] + wt * (G[j0 + 1, i1] - G[j0 + 1, i0])
    return lo + ws * (hi - lo), (hi - lo) * (m - 1)


def _offset_numpy(w, s, tau, end=None):
    """:meth:`Warp.offset` as it was (session 41)."""
    tau = np.asarray(tau, dtype=np.float64)
    s = np.broadcast_to(np.asarray(s, dtype=np.float64), tau.shape)
    x, dx = _bilinear_numpy(w.G, s.reshape(-1), tau.reshape(-1), w.closed)
    x, dx = x.reshape(tau.shape), dx.reshape(tau.shape)
    if end is None:
        end = w.end(np.asarray(tau, dtype=np.float64))
    span = np.asarray(end, dtype=np.float64) - w.start
    return w.start + x * span, dx * span


@pytest.mark.parametrize("closed", [False, True])
def test_the_warp_offset_is_the_numpy_arithmetic_bit_for_bit(closed):
    w = _warp(closed)
    rng = np.random.default_rng(3)
    tau = np.concatenate([rng.uniform(-0.2, 1.2, 5000), [0.0, 1.0]])
    for s in (0.37, rng.uniform(-0.1, 1.1, tau.size)):
        for got, ref in zip(w.offset(s, tau), _offset_numpy(w, s, tau)):
            np.testing.assert_array_equal(got, ref)
        end = rng.uniform(0.5, 1.0, tau.size)
        for got, ref in zip(w.offset(s, tau, end=end), _offset_numpy(w, s, tau, end=end)):
            np.testing.assert_array_equal(got, ref)
    g = w.offset(0.5, tau.reshape(-1, 2))[0]
    assert g.shape == (tau.size // 2, 2)


def _ring_numpy(fam, s, tau):
    """``Rings.along`` / ``SpiralTurn.along`` with a warp, as they were (session 41)."""
    th = fam.theta0 + domains.TWO_PI * tau
    c, s_ = np.cos(th), np.sin(th)
    lim = _limit_numpy(fam.poly, th)
    rho, dg = _offset_numpy(fam.warp, s, tau, end=lim)
    rho = np.minimum(rho, lim)
    P = rho[:, None] * np.column_stack([c, s_])
    return P, domains._unit_tangent(P, tau, np.column_stack([-s_, c])), dg


def test_warped_rings_and_turns_are_the_numpy_arithmetic_bit_for_bit():
    poly = _polygon(4)
    rings = domains.Rings(poly, 0.01, theta0=0.3, warp=_warp(True))
    turn = domains.SpiralTurn(poly, 0.2, 0.35, 0.01, theta0=0.3, warp=_warp(True))
    past = domains.Rings(poly, 0.01, theta0=0.3, warp=_warp(True, top=1.4))  # held at the polygon
    tau = np.linspace(0.0, 1.0, 3001)
    for fam, lev in ((rings, 0.37), (rings, 1.0), (rings, np.linspace(0.3, 0.4, tau.size)),
                     (turn, turn.r0 + tau * (turn.r1 - turn.r0)), (past, 0.95)):
        P, t = fam.along(lev, tau)
        assert fam._last[0] is tau and len(fam._last) == 4  # what rate reuses
        ref_P, ref_t, ref_dg = _ring_numpy(fam, lev, tau)
        np.testing.assert_array_equal(P, ref_P)
        np.testing.assert_array_equal(t, ref_t)
        # the rate reuses the ray and dg/ds of this call: the same as computing them again
        rate = fam.rate(lev, tau, P, t)
        th = fam.theta0 + domains.TWO_PI * tau
        a = np.column_stack([np.cos(th), np.sin(th)])
        det = np.abs(a[:, 0] * t[:, 1] - a[:, 1] * t[:, 0])
        np.testing.assert_array_equal(rate, np.maximum(det, domains.MIN_CROSSING) * ref_dg)
    lim = poly.limit(past.theta0 + domains.TWO_PI * tau)
    raw, _ = past.warp.offset(0.95, tau, end=lim)
    assert np.any(raw > lim)  # the branch that holds the ring at the polygon is reached
    P, _ = past.along(0.95, tau)
    np.testing.assert_array_equal(np.hypot(P[:, 0], P[:, 1])[raw > lim] <= lim[raw > lim] * (1 + 1e-15), True)


def test_the_rise_follows_nan_to_num_where_it_is_infinite():
    params = PathParams(tool_radius=4.0, scallop=0.01, tolerance=0.01)
    planner = Planner(None, params, seg_len=0.2, rise_tol=np.inf)
    S, t = _random_sample(2000, seed=1)
    ls, reach = planner.allowed(S, t)
    ref_ls, ref_reach = _allowed_numpy(planner, S, t)
    np.testing.assert_array_equal(ls, ref_ls)
    np.testing.assert_array_equal(reach, ref_reach)


def test_a_huge_longest_step_does_not_overflow_where_there_is_no_rise():
    params = PathParams(tool_radius=4.0, scallop=0.01, tolerance=0.01)
    S, t = _random_sample(500, seed=2)
    ls, _ = Planner(None, params, seg_len=0.2, max_step=1e200).allowed(S, t)
    np.testing.assert_array_equal(ls, _allowed_numpy(Planner(None, params, seg_len=0.2), S, t)[0])


def _forward_step_numpy(e, kappa, max_step):
    """:func:`conformill.planning.steps.forward_step` as it was in numpy (session 47)."""
    e = np.asarray(e, dtype=np.float64)
    ak = np.abs(np.asarray(kappa, dtype=np.float64))
    cap = np.asarray(max_step, dtype=np.float64)
    ok = np.isfinite(ak) & (ak > 0) & (e * ak < 2.0)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        w = 2.0 * np.sqrt(e * (2.0 - e * ak) / np.where(ok, ak, 1.0))
    return np.where(ok, np.minimum(w, cap), cap * np.ones_like(w))


def test_the_forward_step_is_the_numpy_arithmetic_bit_for_bit():
    """:func:`forward_step` (compiled per sample since session 48): curvatures of both signs
    from subnormal to past ``2 / e``, zero, infinite and NaN; arrays, scalars and their
    broadcasts."""
    from conformill.planning.steps import forward_step

    rng = np.random.default_rng(4)
    kappa = rng.normal(0.0, 1.0, 5000) * 10.0 ** rng.uniform(-6, 3, 5000)
    kappa[:8] = [0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -1e-310, 2.0 / 0.01]
    e = rng.choice([0.001, 0.01, 0.1], 5000)
    cap = rng.choice([0.05, 1.0, 10.0], 5000)
    cases = ((e, kappa, cap), (0.01, kappa, 10.0), (e, 0.5, cap), (0.01, -0.5, 10.0), (e[:, None], kappa[:7], 1.0),
             (0.01, kappa[:50], np.nan), (0.0, 1.0, -0.0), (-0.0, 1.0, 0.0), (-1.0, kappa[:50], 1.0))
    for args in cases:
        got, want = forward_step(*args), _forward_step_numpy(*args)
        assert got.shape == want.shape and got.dtype == np.float64
        np.testing.assert_array_equal(got, want)  # (NaN where NaN)
        np.testing.assert_array_equal(np.signbit(got), np.signbit(want))  # (and -0.0 where -0.0)


def _select_forward_numpy(X, kappa, e, max_step, max_rounds=30, e_convex=None):
    """:func:`conformill.patterns.forward.select_forward` as it was in numpy (session 47)."""
    from conformill.patterns.forward import _add_farthest, _cap_steps

    forward_step = _forward_step_numpy
    k = len(X)
    if k <= 2:
        return np.arange(k, dtype=np.int64)
    tol = np.full(k, float(e))
    if e_convex is not None:
        tol[np.asarray(kappa) < 0] = float(e_convex)
    lf = forward_step(tol, kappa, max_step)
    seg = np.linalg.norm(np.diff(X, axis=0), axis=1)
    lf_mid = np.minimum(lf[:-1], lf[1:])
    N = np.concatenate([[0.0], np.cumsum(seg / lf_mid)])
    m = max(1, int(np.ceil(N[-1] - 1e-9)))
    targets = np.linspace(0.0, N[-1], m + 1)
    idx = np.searchsorted(N, targets, side="right") - 1
    idx[-1] = k - 1
    idx = np.unique(np.clip(idx, 0, k - 1))
    X = np.ascontiguousarray(X, dtype=np.float64)
    idx = _cap_steps(X, idx.astype(np.int64), float(max_step))
    return _add_farthest(X, tol, idx, max_rounds)


@pytest.mark.parametrize("seed", range(6))
def test_the_forward_steps_are_the_numpy_arithmetic_bit_for_bit(seed):
    """The compiled forward steps keep the samples the numpy steps kept: paths from a few
    samples to thousands, evenly and unevenly spaced, flat, wavy and jittered, curvatures
    from nearly flat to far past the tolerance's circle (2 R <= e), zero and NaN, with and
    without a convex tolerance, and longest steps from below a sample's spacing to above the
    path's length."""
    from conformill.patterns.forward import select_forward

    rng = np.random.default_rng(seed)
    for trial in range(150):
        k = int(rng.integers(1, 2500))
        t = np.sort(rng.uniform(0.0, 1.0, k)) if trial % 2 else np.linspace(0.0, 1.0, k)
        L = rng.uniform(0.5, 200.0)
        X = np.column_stack([t * L, np.sin(t * rng.uniform(0.0, 40.0)) * rng.uniform(0.0, 5.0),
                             rng.normal(0.0, 0.01, k).cumsum() * (trial % 3 == 0)])
        kappa = rng.normal(0.0, rng.choice([1e-3, 0.1, 1.0, 300.0]), k)
        kappa[rng.random(k) < 0.1] = 0.0
        kappa[rng.random(k) < 0.02] = np.nan
        e = float(rng.choice([0.001, 0.01, 0.1]))
        max_step = float(rng.choice([0.05, 1.0, 10.0, 1000.0]))
        e_convex = None if trial % 4 else e * float(rng.choice([1.0, 2.0, 4.0]))
        got = select_forward(X, kappa, e, max_step, e_convex=e_convex)
        want = _select_forward_numpy(X, kappa, e, max_step, e_convex=e_convex)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want)


def test_the_sample_curvature_is_normal_curvature_bit_for_bit():
    """:meth:`SurfaceSample.curvature` (compiled, row by row) against
    :func:`normal_curvature` on the columns, as it was: degenerate metrics, NaN rows and zero
    directions included."""
    from conformill.geometry.differential import normal_curvature

    S, t = _random_sample(3000, seed=3)
    d = np.array(t)
    d[:10] = 0.0
    want = normal_curvature(*S.I.T, *S.II.T, d[:, 0], d[:, 1])
    got = S.curvature(d)
    assert np.isnan(want).any() and np.isfinite(want).any()
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("repeat", [1, 2, 5])
def test_the_forward_steps_keep_a_path_start_that_is_repeated(repeat):
    """Both ends are kept when the path starts (or ends) with repeated points: the numpy
    steps (up to session 47) lost the first point there."""
    from conformill.patterns.forward import select_forward

    X = np.vstack([np.zeros((repeat, 3)), np.column_stack([np.linspace(0.1, 30.0, 300), np.zeros((300, 2))]),
                   np.full((repeat, 3), [30.0, 0.0, 0.0])])
    idx = select_forward(X, np.zeros(len(X)), 0.01, 10.0)
    assert idx[0] == 0 and idx[-1] == len(X) - 1
    assert np.all(np.diff(idx) > 0)
    assert np.linalg.norm(np.diff(X[idx], axis=0), axis=1).max() <= 10.0
    same = select_forward(np.zeros((4, 3)), np.zeros(4), 0.01, 10.0)  # one point, four times
    np.testing.assert_array_equal(same, [0, 3])


@pytest.mark.parametrize("kwargs, match", [
    ({"e": 0.0}, "tolerance must be a positive number"),
    ({"e": np.nan}, "tolerance must be a positive number"),
    ({"e_convex": np.nan}, "convex tolerance must be a positive number"),
    ({"e_convex": -0.01}, "convex tolerance must be a positive number"),
    ({"max_step": 0.0}, "longest step must be a positive number"),
    ({"max_step": np.inf}, "longest step must be a positive number"),
    ({"kappa": np.zeros(1)}, "k curvatures are needed"),
    ({"kappa": np.zeros(11)}, "k curvatures are needed"),
    ({"X": np.zeros((10, 2))}, r"shape \(k, 3\)"),
    ({"X": np.where(np.arange(30).reshape(10, 3) == 13, np.nan, np.arange(30.0).reshape(10, 3))}, "must be finite"),
])
def test_the_forward_steps_refuse_what_they_cannot_step(kwargs, match):
    from conformill.errors import PlanningError
    from conformill.patterns.forward import select_forward

    args = {"X": np.arange(30.0).reshape(10, 3), "kappa": np.full(10, 0.5), "e": 0.01, "max_step": 1.0,
            "e_convex": None}
    args.update(kwargs)
    with pytest.raises(PlanningError, match=match):
        select_forward(args["X"], args["kappa"], args["e"], args["max_step"], e_convex=args["e_convex"])


def test_the_sample_curvature_broadcasts_one_direction():
    """One direction for every sample, as :func:`normal_curvature` broadcast it."""
    from conformill.geometry.differential import normal_curvature

    S, _ = _random_sample(500, seed=5)
    d = np.array([[0.3, -1.2]])
    np.testing.assert_array_equal(S.curvature(d), normal_curvature(*S.I.T, *S.II.T, d[:, 0], d[:, 1]))
    with pytest.raises(ValueError):
        S.curvature(np.ones((3, 2)))


def test_the_surface_builds_the_same_with_the_locator_beside_the_frame(surface):
    # two numba threads: the locator's grid in a second thread while the frame is fitted;
    # one thread: one after the other. The same frame and the same locator, bit for bit.
    import numba

    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = DomainSurface(surface.V, surface.F, surface.uv)
        numba.set_num_threads(2)
        two = DomainSurface(surface.V, surface.F, surface.uv)
    finally:
        numba.set_num_threads(before)
    for name in ("_ptr", "_items", "_lo", "_inv", "_nx", "_ny", "tol"):
        np.testing.assert_array_equal(getattr(one.locator, name), getattr(two.locator, name))
    np.testing.assert_array_equal(one._pack, two._pack)


@pytest.mark.parametrize("threads", [1, 2])
def test_the_frame_error_comes_first_where_the_locator_would_fail_too(surface, threads):
    import numba

    from conformill.errors import ConformillError

    uv = surface.uv.copy()
    uv[7] = np.nan  # both the frame and the locator refuse this
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(threads)
        with pytest.raises(ConformillError, match="surface_frame: 1 vertices with non-finite V or uv"):
            DomainSurface(surface.V, surface.F, uv)
    finally:
        numba.set_num_threads(before)
