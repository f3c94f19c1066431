"""Step lengths (METHOD section 4): exact circle geometry against closed forms and brute force."""

import math

import numpy as np
import pytest

from conformill.errors import JobValueError, PlanningError
from conformill.planning.steps import (
    BALL_OVER_PART,
    check_ball_size,
    check_params,
    domain_forward_step,
    domain_side_step,
    forward_step,
    polar_forward_step,
    polar_metric,
    polar_side_step,
    scallop_height,
    side_interval,
    side_interval_paper,
)


def brute_cusp(w, r, kappa, nphi=2001):
    """Residual height between two balls on a circle, by ray casting from the centre O.

    Independent of the closed forms: for each ray in the angular sector between the CC
    points, the material left is the part of the ray between the surface circle and the
    first entry into either ball disk; the scallop is its largest length.
    """
    R = 1.0 / abs(kappa)
    convex = kappa < 0
    alpha = math.asin(w / (2 * R))
    D = R + r if convex else R - r
    C = np.array([[D * math.sin(a), D * math.cos(a)] for a in (alpha, -alpha)])
    phi = np.linspace(-alpha, alpha, nphi)
    U = np.column_stack([np.sin(phi), np.cos(phi)])
    b = U @ C.T  # (nphi, 2)
    disc = b * b - ((C * C).sum(1) - r * r)
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    lo, hi = b - sq, b + sq
    if convex:  # stock lies outside the circle; walk outwards from R
        ent = np.nanmin(np.where(hi >= R, lo, np.nan), axis=1)
        res = np.maximum(ent, R) - R
    else:  # stock lies inside the circle; walk inwards from R
        ent = np.nanmax(np.where(lo <= R, hi, np.nan), axis=1)
        res = R - np.minimum(ent, R)
    return float(np.nanmax(res))


class TestSideInterval:
    def test_plane_exact(self):
        r = 4.0
        h = np.array([1e-4, 0.01, 0.1, 1.0, 3.9])
        w, ok = side_interval(h, r, 0.0)
        assert ok.all()
        np.testing.assert_allclose(w, 2 * np.sqrt(h * (2 * r - h)), rtol=0, atol=1e-12)

    def test_paper_approximation_differs_as_expected(self):
        # sqrt(8rh) overestimates: ratio sqrt(8rh) / 2 sqrt(h(2r-h)) = 1 / sqrt(1 - h/(2r))
        r = 4.0
        h = np.array([0.001, 0.01, 0.1, 1.0])
        w, _ = side_interval(h, r, 0.0)
        approx = side_interval_paper(h, r, 0.0)
        np.testing.assert_allclose(approx, np.sqrt(8 * r * h), rtol=1e-15)
        np.testing.assert_allclose(approx / w, 1 / np.sqrt(1 - h / (2 * r)), rtol=1e-12)
        assert approx[-1] / w[-1] > 1.06  # h = r/4: 6.9 % too wide (scallop too high)

    def test_paper_limit_small_h(self):
        r = 4.0
        for kappa in (-0.2, -0.02, 0.02, 0.2):
            w, _ = side_interval(1e-7, r, kappa)
            np.testing.assert_allclose(w, side_interval_paper(1e-7, r, kappa), rtol=1e-6)

    @pytest.mark.parametrize("kappa", [-0.5, -0.2, -0.02, 0.02, 0.1, 0.2, 0.24])
    @pytest.mark.parametrize("h", [0.01, 0.2, 1.0])
    def test_brute_force(self, kappa, h):
        r = 4.0
        w, ok = side_interval(h, r, kappa)
        assert ok
        if kappa > 0 and w >= 2 / kappa * (1 - 1e-12):
            # deep narrow groove (R just above r): even CC points a diameter apart
            # leave less than h; the chord is capped there
            assert brute_cusp(float(w) * (1 - 1e-12), r, kappa) < h
        else:
            assert brute_cusp(float(w), r, kappa) == pytest.approx(h, rel=1e-9)

    def test_inverse_random(self):
        rng = np.random.default_rng(0)
        r = rng.uniform(0.5, 10, 2000)
        h = r * rng.uniform(1e-4, 0.5, 2000)
        # curvature radii from 0.2 r (sharp convex) to 1000 r, both signs, plus flat
        R = r * np.exp(rng.uniform(np.log(0.2), np.log(1000), 2000))
        sign = rng.choice([-1.0, 1.0, 0.0], 2000)
        kappa = sign / R
        conc = kappa * r >= 1
        kappa[conc] = -kappa[conc]  # keep them reachable here
        for i in range(2000):
            w, ok = side_interval(h[i], r[i], kappa[i])
            assert ok
            hh = scallop_height(w, r[i], kappa[i])
            sharp = kappa[i] < 0 and abs(kappa[i]) * h[i] ** 2 > 2 * (r[i] - h[i])
            capped = kappa[i] > 0 and w >= 2 / kappa[i] * (1 - 1e-12)
            valid = not (sharp or capped)
            if valid:
                assert hh == pytest.approx(h[i], rel=1e-9)
            else:  # sharp convex or deep groove: the widest chord still leaves less than h
                assert hh < h[i]

    def test_scallop_then_interval(self):
        r = 3.0
        for kappa in (-0.3, -0.01, 0.0, 0.01, 0.3):
            w = np.linspace(0.01, 2.0, 50)
            h = scallop_height(w, r, kappa)
            w2, ok = side_interval(h, r, kappa)
            assert ok.all()
            np.testing.assert_allclose(w2, w, rtol=1e-9)

    def test_convex_narrower_concave_wider(self):
        r, h = 4.0, 0.1
        flat, _ = side_interval(h, r, 0.0)
        convex, _ = side_interval(h, r, -0.05)
        concave, _ = side_interval(h, r, 0.05)
        assert convex < flat < concave

    def test_concave_unreachable(self):
        r, h = 4.0, 0.1
        kappa = np.array([0.2, 0.25, 0.3, np.inf, np.nan])
        w, ok = side_interval(h, r, kappa)
        np.testing.assert_array_equal(ok, [True, False, False, False, False])
        np.testing.assert_allclose(w[1:], 2 * np.sqrt(h * (2 * r - h)))
        assert np.isnan(scallop_height(1.0, r, 0.3))

    def test_sharp_convex_uses_widest_meeting_chord(self):
        r, h, kappa = 4.0, 1.0, -10.0  # R = 0.1 mm, a sharp edge
        w, ok = side_interval(h, r, kappa)
        assert ok
        assert w == pytest.approx(2 * r / (1 + r * 10.0), rel=1e-12)
        assert brute_cusp(float(w) * (1 - 1e-9), r, kappa) < h
        assert np.isinf(scallop_height(float(w) * 1.001, r, kappa))

    def test_vectorized_shapes(self):
        w, ok = side_interval(0.1, 4.0, np.zeros((3, 4)))
        assert w.shape == (3, 4) and ok.shape == (3, 4)


class TestForwardStep:
    def test_sagitta(self):
        R, e = 50.0, 0.01
        w = forward_step(e, -1 / R, 100.0)
        # the chord w on a circle of radius R has sagitta exactly e
        assert R - math.sqrt(R * R - (w / 2) ** 2) == pytest.approx(e, rel=1e-10)
        assert w == pytest.approx(2 * math.sqrt(e * (2 * R - e)), rel=1e-14)
        assert w == pytest.approx(math.sqrt(8 * e * R - 4 * e * e), rel=1e-14)

    def test_sign_irrelevant_and_caps(self):
        e = 0.01
        k = np.array([-0.1, 0.1, 0.0, 1e-12, 500.0, np.nan])
        w = forward_step(e, k, 5.0)
        assert w[0] == w[1] < 5.0
        np.testing.assert_array_equal(w[2:], 5.0)


class TestDomainSteps:
    def test_conformal(self):
        sigma = 2.5
        E = G = np.full(3, sigma**2)
        F = np.zeros(3)
        np.testing.assert_allclose(domain_side_step(1.0, E, F, G, "u"), 1 / sigma)
        np.testing.assert_allclose(domain_side_step(1.0, E, F, G, "v"), 1 / sigma)
        np.testing.assert_allclose(domain_forward_step(1.0, E, F, G, "v"), 1 / sigma)
        np.testing.assert_allclose(domain_forward_step(1.0, E, F, G, "u"), 1 / sigma)

    def test_sheared_plane(self):
        # r(u, v) = (u + a v, b v, 0): lines u = const are (a, b) direction; the distance
        # between u and u + du, measured perpendicular to them, is du * b / sqrt(a^2 + b^2)
        a, b = 0.7, 1.3
        ru, rv = np.array([1.0, 0, 0]), np.array([a, b, 0])
        E, F, G = ru @ ru, ru @ rv, rv @ rv
        du = domain_side_step(1.0, E, F, G, "u")
        assert du * b / math.hypot(a, b) == pytest.approx(1.0, rel=1e-14)
        # METHOD section 2 form
        sinphi = math.sqrt(E * G - F * F) / math.sqrt(E * G)
        assert du == pytest.approx(1 / (math.sqrt(E) * sinphi), rel=1e-14)
        dv = domain_forward_step(1.0, E, F, G, "v")
        assert np.linalg.norm(rv * dv) == pytest.approx(1.0, rel=1e-14)
        # across v: lines v = const are along x; distance between them is b dv
        assert domain_side_step(1.0, E, F, G, "v") * b == pytest.approx(1.0, rel=1e-14)

    def test_degenerate_metric_nan(self):
        assert np.isnan(domain_side_step(1.0, 1.0, 1.0, 1.0))
        assert np.isnan(domain_forward_step(1.0, 1.0, 1.0, 1.0))

    def test_bad_axis(self):
        with pytest.raises(PlanningError, match="across"):
            domain_side_step(1.0, 1.0, 0.0, 1.0, across="x")
        with pytest.raises(PlanningError, match="along"):
            domain_forward_step(1.0, 1.0, 0.0, 1.0, along="w")

    def test_polar_on_affine_map(self):
        # r(u, v) = A (u, v) for a random A: ring rho in the domain is an ellipse on the
        # surface; compare with brute-force geometry
        rng = np.random.default_rng(3)
        A = rng.normal(size=(3, 2))
        ru, rv = A[:, 0], A[:, 1]
        E, F, G = ru @ ru, ru @ rv, rv @ rv
        for theta in np.linspace(0, 2 * np.pi, 7):
            rho = 2.0
            c, s = math.cos(theta), math.sin(theta)
            Er, Frt, Gt = polar_metric(E, F, G, theta, rho)
            assert Er * Gt - Frt**2 == pytest.approx(rho**2 * (E * G - F * F), rel=1e-12)
            # ring tangent on the surface and the distance to the next ring
            t = A @ np.array([-s, c])
            t /= np.linalg.norm(t)
            drho = polar_side_step(1.0, E, F, G, theta)
            step = A @ np.array([c, s]) * drho
            assert np.linalg.norm(step - (step @ t) * t) == pytest.approx(1.0, rel=1e-12)
            dth = polar_forward_step(0.5, E, F, G, theta, rho)
            speed = np.linalg.norm(A @ np.array([-s, c])) * rho
            assert dth * speed == pytest.approx(0.5, rel=1e-12)
        assert polar_forward_step(0.5, E, F, G, 0.3, 0.0) == pytest.approx(2 * np.pi)
        assert polar_forward_step(1e3, E, F, G, 0.3, 1.0) == pytest.approx(2 * np.pi)


class TestCheckParams:
    def test_ok(self):
        p = check_params(4, 0.5, 0.01)
        assert (p.tool_radius, p.scallop, p.tolerance) == (4.0, 0.5, 0.01)

    @pytest.mark.parametrize(
        "args, match, code",
        [
            ((4.0, 4.0, 0.01), "scallop height 4 mm must be smaller than the tool radius 4", 3),
            ((4.0, 5.0, 0.01), "smaller than the tool radius", 3),
            ((4.0, 0.0, 0.01), "scallop height must be finite and > 0", 2),
            ((4.0, -1.0, 0.01), "scallop height", 2),
            ((4.0, 0.1, 0.0), "chord tolerance must be finite and > 0", 2),
            ((4.0, 0.1, -0.01), "chord tolerance", 2),
            ((0.0, 0.1, 0.01), "tool radius must be finite and > 0", 2),
            ((float("nan"), 0.1, 0.01), "tool radius", 2),
            ((4.0, float("nan"), 0.01), "scallop height", 2),
            ((4.0, 0.1, float("inf")), "chord tolerance", 2),
            ((4.0, "abc", 0.01), "scallop height must be a number", 2),
            ((None, 0.1, 0.01), "tool radius must be a number", 2),
        ],
    )
    def test_rejects(self, args, match, code):
        # 2: a malformed value (JobValueError, still a PlanningError); 3: h >= r, a plan
        # that cannot be met
        with pytest.raises(PlanningError, match=match) as ei:
            check_params(*args)
        assert ei.value.exit_code == code
        assert isinstance(ei.value, JobValueError) == (code == 2)


class TestCheckBallSize:
    """A ball more than BALL_OVER_PART times the part's largest extent is refused (exit 2)."""

    V = np.array([[0.0, 0.0, 0.0], [12.0, 0.0, 0.0], [0.0, 5.0, 2.0]])  # 12 x 5 x 2 mm

    def test_bound(self):
        check_ball_size(BALL_OVER_PART * 12.0, self.V)  # at the bound: kept
        check_ball_size(4.0, self.V)
        check_ball_size(1e300, np.zeros((0, 3)))  # no part, nothing to compare
        with pytest.raises(JobValueError, match=r"^tool radius 1200.01 mm is more than 100 times the part's size "
                                                r"\(12 x 5 x 2 mm\).*--scale") as ei:
            check_ball_size(1200.01, self.V)
        assert ei.value.exit_code == 2

    def test_error_and_name(self):
        from conformill.errors import ConformillError

        with pytest.raises(ConformillError, match=r"^--tool-radius 1e\+300 mm is more than") as ei:
            check_ball_size(1e300, self.V, ConformillError, "--tool-radius")
        assert type(ei.value) is ConformillError
