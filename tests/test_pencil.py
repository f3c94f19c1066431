"""Pencil stage: best ball centres against the wedged ball of a V-groove, invariants of the
working-set search, pencil passes along a crease, none on convex parts, and the plan option."""

from __future__ import annotations

import numpy as np
import pytest

from conformill import pencil
from conformill.cutter import BallCutter
from conformill.errors import PlanningError
from conformill.mesh import synthetic as syn
from conformill.pencil import best_centres, chain_points, order_and_link, pencil_passes, surface_samples
from conformill.pipeline import Job, plan

R = 4.0
A = np.radians(8.0)  # groove walls: the wedged ball leaves r (1 / cos a - 1) = 0.039 mm at the crease


def _ray_gap(p, n, c, r):
    """Distance from p along n to the sphere (c, r), by the quadratic (0 inside)."""
    w = p - c
    b = w @ n
    cc = w @ w - r * r
    if cc <= 0:
        return 0.0
    return -b - np.sqrt(b * b - cc)


def _faces_under(V, F, P):
    """The triangle whose XY projection holds each point (brute force)."""
    a, b, c = V[F[:, 0], :2], V[F[:, 1], :2], V[F[:, 2], :2]
    out = []
    for p in P[:, :2]:
        d = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        l1 = ((p[0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (p[1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / d
        l2 = ((b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[0] - a[:, 0])) / d
        inside = (l1 >= -1e-12) & (l2 >= -1e-12) & (1 - l1 - l2 >= -1e-12)
        out.append(int(np.flatnonzero(inside)[0]))
    return np.array(out)


class TestBestCentres:
    def test_v_groove_best_ball_is_the_wedged_one(self):
        # z = |x| tan(a): the ball wedged on the crease has its centre at (0, y, r / cos a).
        # A sample on the crease (normal +Z) or on a wall within r sin(a) of it (the wall's
        # normal) cannot be touched by a ball that stays out of the other wall; the least
        # material is the distance along the normal to the wedged ball. Beyond r sin(a) the
        # tangent ball fits: nothing left, no search.
        m = syn.v_groove(a_deg=8.0, half=12.0, step=0.25)
        cut = BallCutter(m.V, m.F, R)
        rows = []
        for y in (-3.3, 0.1, 2.7):
            rows.append(([0.0, y, 0.0], [0.0, 0.0, 1.0]))
            for s in (0.05, 0.2, 0.4, 0.5):
                for sign in (1.0, -1.0):
                    rows.append(([sign * s, y, s * np.tan(A)], [-sign * np.sin(A), 0.0, np.cos(A)]))
        P = np.array([p for p, _ in rows])
        N = np.array([n for _, n in rows])
        C, rest, state = best_centres(cut, P, N, _faces_under(m.V, m.F, P))
        assert np.all(state == 1)
        # the search's simplex ends smaller than 0.0004 r = 1.6 um: the centre is found to
        # that across the crease (its height to that times tan(a) = 0.14, the slope of D
        # there), and the rest to 0.1 um
        spacing = pencil._SIMPLEX_END * R
        for p, n, c, g in zip(P, N, C, rest):
            wedged = np.array([0.0, p[1], R / np.cos(A)])
            assert g == pytest.approx(_ray_gap(p, n, wedged, R), abs=1e-4)
            assert g >= _ray_gap(p, n, wedged, R) - 1e-12  # and no lower than the best ball
            assert abs(c[0]) < spacing and abs(c[1] - p[1]) < 2e-3
            assert c[2] == pytest.approx(wedged[2], abs=spacing * np.tan(A))  # D rises at tan(a)
        assert rest[0] == pytest.approx(R * (1 / np.cos(A) - 1), abs=1e-4)  # 0.0393 mm on the crease
        # beyond the wedged ball's contacts the tangent ball leaves nothing
        P2 = np.array([[0.8, 1.0, 0.8 * np.tan(A)], [-2.0, -1.0, 2.0 * np.tan(A)]])
        N2 = np.array([[-np.sin(A), 0.0, np.cos(A)], [np.sin(A), 0.0, np.cos(A)]])
        C2, rest2, state2 = best_centres(cut, P2, N2, _faces_under(m.V, m.F, P2), low=1e-9)
        np.testing.assert_array_equal(state2, [0, 0])
        np.testing.assert_allclose(rest2, 0.0, atol=1e-9)
        np.testing.assert_allclose(C2, P2 + R * N2, atol=1e-9)

    def test_centres_lie_on_the_drop_surface_and_beat_the_tangent_ball(self):
        # a bumpy part with pits tighter than the ball: every searched centre is on D, its
        # value is the material it leaves (recomputed), and never more than the tangent ball's
        from conformill.verify.rest import rest_material, tangent_rest

        outline = np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]])
        part = syn.height_field(outline, lambda x, y: 0.6 * np.sin(0.9 * x) * np.sin(0.8 * y) + 0.02 * x * y,
                                0.6, jitter=0.15, seed=2)
        cut = BallCutter(part.V, part.F, R)
        P, N, faces = surface_samples(part.V, part.F, density=4.0, seed=1)
        inner = np.all(np.abs(P[:, :2]) < 15.0 - R, axis=1)
        P, N, faces = P[inner], N[inner], faces[inner]
        C, rest, state = best_centres(cut, P, N, faces)
        s = state == 1
        assert s.sum() > 200  # the pits make work
        np.testing.assert_allclose(cut.drop(C[s, :2]), C[s, 2], atol=1e-9)
        gaps = np.array([_ray_gap(p, n, c, R) for p, n, c in zip(P[s], N[s], C[s])])
        np.testing.assert_allclose(rest[s], gaps, atol=1e-9)
        assert np.all(rest[s] <= tangent_rest(cut, P[s], N[s]) + 1e-9)
        # verify's search (true drops, 8 starts from a 25 x 25 grid: the judge's estimate of
        # the least material) agrees: measured on this part, within 1 um for 95 % of the
        # samples (rests of 10-170 um), median difference 0.03 um
        k = np.flatnonzero(s)[::4]
        ref = rest_material(cut, P[k], N[k])
        fin = np.isfinite(ref)
        d = rest[k][fin] - ref[fin]
        assert np.mean(np.abs(d) < 1e-3) >= 0.9 and abs(np.median(d)) < 1e-4

    def test_samples_under_a_roof_are_not_searched(self):
        # a floor at z = 0 and a roof 2 mm above it over x < 0 (two triangles, their diagonal
        # from (-10, -10) to (0, 10)): no ball on the drop surface reaches under the roof, so
        # a floor sample there keeps more than 2 mm along +Z (the ball's surface crosses the
        # normal above the roof). The roof test says so without a search (state 4), exactly
        # where the roof's triangle lies over the whole normal up to give_up; every other row
        # is the search's own, and the search confirms the roofed rows.
        floor = syn.plane(size=20.0, spacing=1.0)
        roof = np.array([[-10.0, -10.0, 2.0], [0.0, -10.0, 2.0], [0.0, 10.0, 2.0], [-10.0, 10.0, 2.0]])
        V = np.vstack([floor.V, roof])
        k = len(floor.V)
        F = np.vstack([floor.F, [[k, k + 1, k + 2], [k, k + 2, k + 3]]])
        cut = BallCutter(V, F, R)
        g = 0.0105
        tilt = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
        up = np.array([0.0, 0.0, 1.0])
        rows = [((-3.0, -5.0), up, True), ((-0.02, -5.0), tilt, True),  # under the roof
                ((-0.005, -5.0), tilt, False),  # the normal leaves the roof's shadow 5.25 um on
                ((-0.005, -5.0), -tilt * [1, 1, -1], True),  # ... unless it points away from the edge
                ((-7.5 + 0.004, -5.0), tilt * [-1, 1, 1], False),  # crosses the roof's diagonal
                ((5.0, 2.0), up, False), ((6.0, -4.0), tilt, False)]  # in the open
        P = np.array([[x, y, 0.0] for (x, y), _, _ in rows])
        N = np.array([n for _, n, _ in rows])
        faces = _faces_under(floor.V, floor.F, P)  # the floor's triangles come first in F
        C, rest, state = best_centres(cut, P, N, faces, low=0.0015, give_up=g)
        C0, rest0, state0 = best_centres(cut, P, N, faces, low=0.0015, give_up=g, roof=False)
        roofed = np.array([r for _, _, r in rows])
        np.testing.assert_array_equal(state == 4, roofed)
        assert np.isnan(C[roofed]).all() and np.isinf(rest[roofed]).all()
        np.testing.assert_array_equal(C[~roofed], C0[~roofed])
        np.testing.assert_array_equal(rest[~roofed], rest0[~roofed])
        np.testing.assert_array_equal(state[~roofed], state0[~roofed])
        # the search, asked: given up, or a ball that leaves more than 2 mm
        assert np.all((state0[roofed] == 2) | (rest0[roofed] > 2.0))
        assert np.all(state0[roofed] != 4) and state0[-2] == 0  # the open floor: the tangent ball fits
        # without a finite give-up (or with it at or below low) nothing is roofed
        assert not (best_centres(cut, P, N, faces, low=0.0015)[2] == 4).any()
        assert not (best_centres(cut, P, N, faces, low=g, give_up=g)[2] == 4).any()

    def test_rejects_bad_face_index(self):
        m = syn.plane(size=10.0, spacing=2.0)
        cut = BallCutter(m.V, m.F, R)
        with pytest.raises(PlanningError, match="face index"):
            best_centres(cut, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([len(m.F)]))


class TestPencilPasses:
    @pytest.mark.parametrize("search", pencil.SEARCHES)
    @pytest.mark.parametrize("part", [syn.plane(size=40.0, spacing=2.0),
                                      syn.sphere_cap(R=30.0, radius_xy=15.0, spacing=1.0)], ids=["plane", "dome"])
    def test_none_on_convex_parts(self, part, search):
        cut = BallCutter(part.V, part.F, R)
        res = pencil_passes(cut, part.V, part.F, 0.01, 0.01, search=search, density=10.0)
        assert res.passes == [] and res.stats["centres"] == 0 and res.stats["search"] == search
        assert res.stats["samples" if search == "samples" else "grid_points"] > 1000

    @pytest.mark.parametrize("search", pencil.SEARCHES)
    def test_pass_runs_along_the_crease(self, search):
        # rest on the crease 0.039 mm = 0.39 h at h = 0.1: a pass along x = 0 at the wedged
        # height, unbroken over the groove's middle (fold points: one per grid row, 0.18 mm)
        m = syn.v_groove(a_deg=8.0, half=12.0, step=0.25)
        cut = BallCutter(m.V, m.F, R)
        res = pencil_passes(cut, m.V, m.F, 0.1, 0.01, search=search, density=30.0)
        assert res.passes and res.stats["centres"] > (100 if search == "samples" else 80)
        Q = np.vstack(res.passes)
        mid = Q[np.abs(Q[:, 1]) <= 12.0 - R - 1.0]
        assert len(mid) > 0
        np.testing.assert_allclose(mid[:, 0], 0.0, atol=5e-3)
        np.testing.assert_allclose(mid[:, 2], R / np.cos(A), atol=2e-4)  # the centres' ~1 um across, x tan(a)
        y = np.sort(mid[:, 1])
        assert y[0] < -6.5 and y[-1] > 6.5 and np.diff(y).max() < 3.3 / np.sqrt(30.0)
        # every move is on the crease: the drop surface along it is flat, nothing to refine
        np.testing.assert_allclose(cut.drop(mid[:, :2]), mid[:, 2], atol=1e-9)

    def test_the_band_of_the_rest(self):
        # on the groove the best ball is the wedged one, which leaves r (1 / cos a - 1) =
        # 0.393 h at the crease along +Z, and at most 1 / cos(a) of that along the samples'
        # normals (interpolated: between +Z on the crease and the walls' normals), away from
        # the groove's ends (there the ball can also sit past the end)
        m = syn.v_groove(a_deg=8.0, half=12.0, step=0.25)
        cut = BallCutter(m.V, m.F, R)
        top = R * (1 / np.cos(A) - 1)
        P, N, faces = surface_samples(m.V, m.F, 30.0)
        inner = np.abs(P[:, 1]) < 12.0 - R
        C, rest, state = best_centres(cut, P[inner], N[inner], faces[inner], low=0.015, give_up=0.105)
        s = state == 1
        assert s.sum() > 100 and rest[s].max() <= top / np.cos(A) and rest[s].max() > 0.98 * top
        # the band: centres when it holds the crease's rest; starting above it, none but at
        # the groove's ends (a sample or two, where the ball can sit past the end)
        assert pencil_passes(cut, m.V, m.F, 0.1, 0.01, low=0.9 * top / 0.1).stats["centres"] > 0
        assert pencil_passes(cut, m.V, m.F, 0.1, 0.01, low=1.1 * top / 0.1, high=2.0).stats["centres"] <= 2
        # the folds' shadow is the crease's gap: the same band edge, and no ends (the ball past
        # the groove's end touches one wall only)
        assert pencil_passes(cut, m.V, m.F, 0.1, 0.01, search="folds", low=0.9 * top / 0.1).stats["centres"] > 80
        assert pencil_passes(cut, m.V, m.F, 0.1, 0.01, search="folds", low=1.1 * top / 0.1).stats["centres"] == 0

    @pytest.mark.parametrize("search", pencil.SEARCHES)
    def test_same_passes_whatever_the_threads(self, search):
        # every sample's (grid edge's) search is its own: the blocks' order and the thread
        # count change nothing
        import numba

        m = syn.v_groove(a_deg=8.0, half=12.0, step=0.25)
        cut = BallCutter(m.V, m.F, R)
        n = numba.get_num_threads()
        try:
            out = []
            for t in sorted({1, n}):
                numba.set_num_threads(t)
                out.append(pencil_passes(cut, m.V, m.F, 0.1, 0.01, search=search, settle_tol=0.05))
        finally:
            numba.set_num_threads(n)
        assert out[0].stats == out[-1].stats
        for a, b in zip(out[0].passes, out[-1].passes):
            np.testing.assert_array_equal(a, b)

    def test_bad_values(self):
        m = syn.plane(size=10.0, spacing=2.0)
        cut = BallCutter(m.V, m.F, R)
        for kw, word in ((dict(h=0.0), "scallop"), (dict(tol=-1.0), "tolerance"), (dict(density=0.0), "density"),
                         (dict(low=0.5, high=0.5), "band"), (dict(low=-0.1), "band"), (dict(high=np.nan), "band"),
                         (dict(min_chain=0), "min_chain"), (dict(link_max=0.0), "link"),
                         (dict(search="grid"), "search")):
            args = {**dict(h=0.1, tol=0.01, density=1.0), **kw}
            with pytest.raises(PlanningError, match=word):
                pencil_passes(cut, m.V, m.F, args.pop("h"), args.pop("tol"), **args)

    @pytest.mark.parametrize("search, module, cap, count, density, words", [
        # the samples: at most the cap, over the part's 1600 mm^2
        ("samples", "conformill.pencil", ("_MAX_SAMPLES", 5000), ("samples", 5000), 5000 / 1600.0,
         "samples per mm^2"),
        # the fold grid: 90 % of the cap per mm^2 of the grid's plane (the part and r around
        # it, 48 mm square); its edges round up, within the cap itself
        ("folds", "conformill.folds", ("_MAX_GRID", 20000), ("grid_points", 20000), 18000 / 48.0**2,
         "grid points per mm^2"),
    ], ids=["samples", "folds"])
    def test_density_is_capped_on_a_large_part(self, caplog, monkeypatch, search, module, cap, count, density, words):
        import importlib

        monkeypatch.setattr(importlib.import_module(module), *cap)
        m = syn.plane(size=40.0, spacing=4.0)
        cut = BallCutter(m.V, m.F, R)
        with caplog.at_level("WARNING"):
            res = pencil_passes(cut, m.V, m.F, 0.1, 0.01, search=search, density=30.0)
        assert res.stats[count[0]] <= count[1] and res.stats["density_per_mm2"] == pytest.approx(density)
        assert words in caplog.text


class TestChains:
    def test_points_on_two_lines_make_two_chains_in_order(self):
        t = np.linspace(0.0, 5.0, 26)
        xy = np.vstack([np.column_stack([t, np.zeros_like(t)]), np.column_stack([t, np.full_like(t, 3.0)])])
        perm = np.random.default_rng(4).permutation(len(xy))
        chains = chain_points(xy[perm], link=0.5)
        assert sorted(len(c) for c in chains) == [26, 26]
        for c in chains:
            pts = xy[perm][c]
            assert np.ptp(pts[:, 1]) == 0.0
            assert np.allclose(np.abs(np.diff(pts[:, 0])), 0.2)  # consecutive along the line

    def test_order_and_link_joins_near_ends_and_reverses(self):
        a = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
        b = np.array([[5.0, 0.0, 1.0], [2.0, 0.0, 1.0]])  # its near end is its last point
        c = np.array([[50.0, 0.0, 1.0], [51.0, 0.0, 1.0]])
        lone = np.array([[8.0, 0.0, 1.0]])  # a single centre: a point of the linked pass
        passes = order_and_link([c, lone, b, a], start_xy=(-1.0, 0.0), link_max=8.0)
        assert len(passes) == 2
        np.testing.assert_array_equal(passes[0][:, 0], [0.0, 1.0, 2.0, 5.0, 8.0])
        np.testing.assert_array_equal(passes[1][:, 0], [50.0, 51.0])


    def test_order_and_link_is_the_greedy_nearest_end(self):
        # against the plain greedy (numpy's argmin over the (n, 2) end distances: the first
        # of equal ones), on chains with shared and repeated ends (ties)
        rng = np.random.default_rng(3)
        grid = rng.integers(0, 6, (120, 2, 2)).astype(float)  # many equal ends
        chains = [np.column_stack([np.linspace(e[0, 0], e[1, 0], 4), np.linspace(e[0, 1], e[1, 1], 4),
                                   np.arange(4.0) + 10 * i]) for i, e in enumerate(grid)]
        chains += [np.array([[2.0, 2.0, -1.0]]), np.array([[2.0, 2.0, -2.0]])]  # lone centres on a tie
        want, cur, at = [], None, np.array([2.5, 2.5])
        ends = np.array([[c[0, :2], c[-1, :2]] for c in chains])
        left = np.ones(len(chains), dtype=bool)
        for _ in chains:
            d = np.linalg.norm(ends - at, axis=2)
            d[~left] = np.inf
            i, side = np.unravel_index(int(np.argmin(d)), d.shape)
            c = chains[i] if side == 0 else chains[i][::-1]
            left[i] = False
            if cur is not None and d[i, side] <= 1.5:
                cur.append(c)
            else:
                if cur is not None:
                    want.append(np.vstack(cur))
                cur = [c]
            at = c[-1, :2]
        want.append(np.vstack(cur))
        got = order_and_link(chains, start_xy=(2.5, 2.5), link_max=1.5)
        assert 1 < len(got) == len(want)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)

    @pytest.mark.parametrize("spread", [1.0, 1e5])
    def test_samples_are_numpys_to_the_bit(self, spread):
        # the compiled interpolation and the counting sort against the plain numpy they
        # replaced (einsum, norm, lexsort over 1 mm cells); ``spread`` 1e5 stretches the part
        # over a plane too sparse for the counting sort (the stable argsort instead)
        from conformill.geometry.differential import vertex_normals

        m = syn.sphere_cap(R=12.0, radius_xy=11.5, spacing=0.8, jitter=0.1)
        V = m.V * [spread, 1.0, 1.0]
        P, N, f = surface_samples(V, m.F, 20.0 / spread, seed=5)
        a = 0.5 * np.linalg.norm(np.cross(V[m.F[:, 1]] - V[m.F[:, 0]], V[m.F[:, 2]] - V[m.F[:, 0]]), axis=1)
        n = int(round(20.0 / spread * a.sum()))
        rng = np.random.default_rng(5)
        cum = np.cumsum(a)
        fr = np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1], side="right"), len(m.F) - 1)
        u, v = rng.random(n), rng.random(n)
        flip = u + v > 1.0
        u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
        w = np.column_stack([1.0 - u - v, u, v])
        Pr = np.einsum("kj,kjd->kd", w, V[m.F[fr]])
        Nr = np.einsum("kj,kjd->kd", w, vertex_normals(V, m.F)[m.F[fr]])
        ln = np.linalg.norm(Nr, axis=1)
        Nr /= ln[:, None]
        key = np.lexsort((np.floor(Pr[:, 0]), np.floor(Pr[:, 1])))
        keep = key[Nr[key, 2] > 0]
        assert 1000 < len(keep) <= n
        np.testing.assert_array_equal(P, Pr[keep])
        np.testing.assert_array_equal(N, Nr[keep])
        np.testing.assert_array_equal(f, fr[keep])

    def test_steep_samples_are_rows_of_the_full_draw(self):
        from conformill.geometry.differential import vertex_normals

        m = syn.sphere_cap(R=12.0, radius_xy=11.5, spacing=0.8, jitter=0.1)
        P, N, f = surface_samples(m.V, m.F, 20.0, seed=2)
        Ps, Ns, fs = surface_samples(m.V, m.F, 20.0, seed=2, below_nz=0.4)
        steep = N[:, 2] < 0.4
        assert 0 < steep.sum() < len(P)
        # faces whose three vertex normals all have n_z >= 0.4 are skipped before mapping
        assert (vertex_normals(m.V, m.F)[m.F, 2].min(axis=1) >= 0.4).mean() > 0.5
        np.testing.assert_array_equal(Ps, P[steep])
        np.testing.assert_array_equal(Ns, N[steep])
        np.testing.assert_array_equal(fs, f[steep])
        # and SurfaceDraw.rows gives them from one draw
        for x, y in zip(pencil.draw_samples(m.V, m.F, 20.0, seed=2).rows(0.4), (Ps, Ns, fs)):
            np.testing.assert_array_equal(x, y)

@pytest.mark.parametrize("search", pencil.SEARCHES)
def test_plan_with_pencil_adds_passes_after_the_same_program(tmp_path, search):
    # the pattern's passes are those of the plan without the option; the pencil passes
    # come after them (pass id -1), and the material the program leaves on the crease is
    # the wedged ball's, checked by the independent simulation (either search)
    from conformill.output.gcode import write_gcode
    from conformill.verify.gcode import read_gcode
    from conformill.verify.samples import SurfaceSamples
    from conformill.verify.simulate import verify

    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.1, tolerance=0.01)
    base = plan(m, job)
    res = plan(m, Job(**{**job.__dict__, "pencil": True, "pencil_search": search}))
    n = len(base.toolpath.passes)
    assert len(res.toolpath.passes) > n and res.toolpath.pass_ids[n:] == [-1] * (len(res.toolpath.passes) - n)
    for a, b in zip(base.toolpath.passes, res.toolpath.passes[:n]):
        np.testing.assert_array_equal(a, b)
    st = res.report["pencil"]
    assert st["passes"] == len(res.toolpath.passes) - n and st["feed_mm"] > 0 and res.report["timings_s"]["pencil"] > 0
    assert base.report["pencil"] is None
    y = np.linspace(-5.0, 5.0, 41)
    crease = SurfaceSamples.from_arrays(np.column_stack([np.zeros_like(y), y, np.zeros_like(y)]),
                                        np.tile([0.0, 0.0, 1.0], (len(y), 1)))
    left = {}
    for name, r in (("base", base), ("pencil", res)):
        path = tmp_path / f"{name}.nc"
        write_gcode(path, r.toolpath, feed=1000.0)
        left[name] = verify(m, read_gcode(path), R, samples=crease).remaining
    np.testing.assert_allclose(left["pencil"], R * (1 / np.cos(A) - 1), atol=2e-4)  # G-code rounds to 0.1 um
    assert left["base"].max() > left["pencil"].max() + 0.01  # the rows alone leave more between them


@pytest.mark.parametrize("search, left, fill", [("samples", None, None), ("folds", None, None), ("folds", 0.5, None),
                                               ("folds", 0.5, 0.7), ("samples", None, 0.7)])
def test_plan_searches_beside_the_pattern_for_the_same_program(search, left, fill):
    # with two numba threads the plan runs the pencil's search beside the pattern stage
    # (pencil.BackgroundChains), and the fill's samples after it, with one in line after
    # it: the same passes, point for point
    import numba

    from conformill.passes import threads_can_overlap

    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.1, tolerance=0.01, pencil=True, pencil_search=search,
              pencil_left=left, fill=fill)
    n = numba.get_num_threads()
    if n < 2:
        pytest.skip("one numba thread: nothing runs beside")
    try:
        numba.set_num_threads(1)
        one = plan(m, job)
    finally:
        numba.set_num_threads(n)
    two = plan(m, job)
    assert "pencil_busy" not in one.report["timings_s"]
    assert ("pencil_busy" in two.report["timings_s"]) == threads_can_overlap()
    assert len(one.toolpath.passes) == len(two.toolpath.passes) and one.toolpath.pass_ids == two.toolpath.pass_ids
    for a, b in zip(one.toolpath.passes, two.toolpath.passes):
        np.testing.assert_array_equal(a, b)
    assert one.report["pencil"] == two.report["pencil"]
    assert one.report["fill"] == two.report["fill"] and (fill is None) == (two.report["fill"] is None)


def test_background_search_stops_and_reports_errors():
    # cancelled before the cutter is there: no search, and result() says so; an error in
    # the search reaches the caller's thread
    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    import threading

    gate = threading.Event()
    bg = pencil.BackgroundChains(lambda: (gate.wait(), BallCutter(m.V, m.F, R))[1], m.V, m.F, 0.1)
    bg._stop.set()
    gate.set()
    bg.cancel()
    with pytest.raises(RuntimeError, match="cancelled"):
        bg.result()
    bg = pencil.BackgroundChains(lambda: BallCutter(m.V, m.F, R), m.V, m.F, -1.0)
    with pytest.raises(PlanningError, match="scallop must be a positive number"):
        bg.result()
    with pencil.BackgroundChains(lambda: BallCutter(m.V, m.F, R), m.V, m.F, 0.1) as bg:
        found = bg.result()
    assert found.chains and found.stats["chains"] == len(found.chains)


def test_background_links_only_from_the_end_asked_for():
    # link_from() lets the worker link the chains; linked() hands them over only for the
    # same start, tolerance and link length, and they are link_chains' passes in line
    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    cut = BallCutter(m.V, m.F, R)
    start = np.array([-9.0, 3.0])
    with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1) as bg:
        bg.link_from(start, 0.01, 8.0)
        got = bg.linked(start.copy(), 0.01, 8.0)
        found = bg.result()
    want = pencil.link_chains(cut, found, 0.01, 8.0, start)
    assert got is not None and got.stats == want.stats and len(got.passes) == len(want.passes) > 0
    for a, b in zip(got.passes, want.passes):
        np.testing.assert_array_equal(a, b)
    for other in ((start + [1e-9, 0.0], 0.01, 8.0), (start, 0.02, 8.0), (start, 0.01, 9.0)):
        with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1) as bg:
            bg.link_from(start, 0.01, 8.0)
            assert bg.linked(*other) is None
    with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1) as bg:  # never asked: nothing linked
        assert bg.linked(start, 0.01, 8.0) is None
        assert not bg._thread.is_alive()
    # links that fail in the worker: the error for the start asked for, None for another
    for other, raises in ((start, True), (start + 1.0, False)):
        with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1) as bg:
            bg.link_from(start, -1.0, 8.0)
            if raises:
                with pytest.raises(PlanningError):
                    bg.linked(other, -1.0, 8.0)
            else:
                assert bg.linked(other, -1.0, 8.0) is None


@pytest.mark.parametrize("search", pencil.SEARCHES)
@pytest.mark.parametrize("chain", [False, True])
def test_background_draw_runs_before_the_search_which_uses_it(chain, search):
    # draw(cutter) runs in the worker before the search, which takes its samples from it
    # (the same centres as its own draw); drawn() hands over its value or its error (the
    # search then draws its own); None when it never ran (stopped before the cutter)
    import threading

    m = syn.v_groove(a_deg=80.0, half=6.0, step=0.5)  # walls steeper than 78 deg: steep samples
    cut = BallCutter(m.V, m.F, R)
    seen, drawn = [], pencil.draw_samples(m.V, m.F, 30.0)
    calls = []
    real = pencil.surface_samples

    def counted(*a, **k):
        calls.append(k.get("below_nz"))
        return real(*a, **k)

    def draw(cutter):
        seen.append((cutter, "draw", threading.current_thread().name))
        return drawn

    def searched(fn):
        def run(*a, **k):
            seen.append("search")
            return fn(*a, **k)
        return run

    kw = dict(chain=chain, search=search)
    alone = pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1, **kw)
    own = alone.result()
    alone.cancel()
    assert own.stats["centres"] > 0
    if search == "folds":
        assert own.stats["steep_samples"] > 0 and own.stats["steep_centres"] > 0
    start = np.array([-9.0, 3.0])
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pencil, "surface_samples", counted)
        for name in ("pencil_search", "pencil_chains"):
            mp.setattr(pencil, name, searched(getattr(pencil, name)))
        with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1, draw=draw, **kw) as bg:
            if chain:
                bg.link_from(start, 0.01, 8.0)
            assert bg.drawn() is drawn
            got = bg.result()
            if chain:
                assert bg.linked(start, 0.01, 8.0) is not None
    assert seen[:2] == [(cut, "draw", "conformill-pencil"), "search"]
    assert calls == []  # every sample the search needed came from the draw
    assert got.stats == own.stats
    if chain:
        for a, b in zip(got.chains, own.chains):
            np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_array_equal(got.centres, own.centres)

    def fails(cutter):
        raise PlanningError("draw failed (test)")

    with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1, draw=fails, **kw) as bg:
        with pytest.raises(PlanningError, match="draw failed"):
            bg.drawn()
        assert bg.result().stats == own.stats  # the search itself is unharmed
    gate = threading.Event()
    bg = pencil.BackgroundChains(lambda: (gate.wait(), cut)[1], m.V, m.F, 0.1, draw=draw, **kw)
    bg._stop.set()
    gate.set()
    assert bg.drawn() is None
    bg.cancel()
    assert sum(isinstance(x, tuple) for x in seen) == 1
    with pencil.BackgroundChains(lambda: cut, m.V, m.F, 0.1, **kw) as bg:  # no draw
        assert bg.drawn() is None


def _move_dist(Q, passes):
    """Distance from each point of ``Q`` to the ball-centre moves of tip ``passes`` (by brute
    force over the moves, as ``tests/test_pattern_rest.py``'s ``_brute``)."""
    from conformill.pattern_rest import centre_moves

    A, B = centre_moves(passes, R)
    v = B - A
    L2 = (v * v).sum(1)
    out = np.empty(len(Q))
    for i, q in enumerate(Q):
        w = q - A
        t = np.clip((w * v).sum(1) / np.where(L2 > 0, L2, 1.0), 0, 1)
        out[i] = np.linalg.norm(w - t[:, None] * v, axis=1).min()
    return out


def test_steep_centres_for_the_filter_are_every_searched_sample_within_h():
    # on steep walls a ball off the tangent one can reach a sample the tangent ball leaves
    # material on; with the pattern's rest to filter them (probed) such samples keep their
    # centre, probed at the sample, where without a filter the band (low h, h] drops them
    from conformill.verify.rest import tangent_rest

    m = syn.v_groove(a_deg=80.0, half=6.0, step=0.5)
    cut = BallCutter(m.V, m.F, R)
    h, low = 0.1, 0.15
    n0, c0, s0 = pencil.steep_centres(cut, m.V, m.F, h, 30.0, low)
    n1, c1, s1 = pencil.steep_centres(cut, m.V, m.F, h, 30.0, low, probed=True)
    assert n0 == n1 > 0 and len(c1) > len(c0) > 0
    # the same draw: the centres without the filter are rows of those with it
    at = {tuple(p): i for i, p in enumerate(s1)}
    rows = np.array([at[tuple(p)] for p in s0])
    np.testing.assert_array_equal(c1[rows], c0)
    P, N, _ = surface_samples(m.V, m.F, 30.0, below_nz=pencil._STEEP_NZ)
    at = {tuple(p): i for i, p in enumerate(P)}
    N1 = N[[at[tuple(p)] for p in s1]]
    gap = np.array([_ray_gap(p, n, c, R) for p, n, c in zip(s1, N1, c1)])
    np.testing.assert_allclose(cut.drop(c1[:, :2]), c1[:, 2], atol=1e-9)  # on the drop surface
    assert np.all(gap <= h + 1e-12) and np.all(tangent_rest(cut, s1, N1) > low * h)
    extra = np.ones(len(c1), dtype=bool)
    extra[rows] = False
    assert np.all(gap[extra] <= low * h + 1e-12) and np.all(gap[~extra] > low * h)
    # the search gives them their samples as probes (fold points first, then the steep
    # centres), and the filter cuts a steep centre where the moves pass r + depth from its sample
    found = pencil.pencil_search(cut, m.V, m.F, h, search="folds")
    n_fold = found.stats["centres"]
    assert found.stats["steep_centres"] == len(c1) and found.probed.all()
    np.testing.assert_array_equal(found.centres[n_fold:], c1)
    np.testing.assert_array_equal(found.probes[n_fold:], np.repeat(s1[:, None], len(pencil._SHADOW_AT), axis=1))
    assert np.isnan(pencil.pencil_search(cut, m.V, m.F, h, search="folds", probes=False).probes[n_fold:]).all()
    # a pass along the groove's first half (tip 0.05 mm below the steep centres there)
    first = c1[c1[:, 1] < np.median(c1[:, 1])]
    tip = [first[np.argsort(first[:, 1])] - [0.0, 0.0, R + 0.05]]
    depth = 0.5 * h
    keep = pencil.where_left(found, tip, R, depth)[n_fold:]
    d = _move_dist(s1, tip)
    assert 0 < keep.sum() < len(keep)
    assert np.all(keep[d > R + depth + 1e-9]) and not np.any(keep[d < R + depth - 1e-9])


def test_a_draw_of_another_density_or_seed_is_not_used():
    m = syn.v_groove(a_deg=80.0, half=6.0, step=0.5)  # steep walls: the fold search's steep rows
    cut = BallCutter(m.V, m.F, R)
    for search in pencil.SEARCHES:
        own = pencil.pencil_search(cut, m.V, m.F, 0.1, search=search)
        assert own.stats["centres"] > 0 and (search == "samples" or own.stats["steep_centres"] > 0)
        for other in (pencil.draw_samples(m.V, m.F, 20.0), pencil.draw_samples(m.V, m.F, 30.0, seed=1)):
            assert not other.matches(30.0, 0)
            got = pencil.pencil_search(cut, m.V, m.F, 0.1, search=search, drawn=other)
            assert got.stats == own.stats
            np.testing.assert_array_equal(got.centres, own.centres)


@pytest.mark.parametrize("pattern", ["zigzag", "contour", "spiral"])
def test_plan_links_the_pencil_beside_the_cutter(monkeypatch, pattern):
    # the builder's prediction of where the passes end is where they end, so the pencil
    # thread's links are used (and give the program of the in-line plan, test above)
    from conformill.passes import PassBuilder, threads_can_overlap

    if not threads_can_overlap():
        pytest.skip("nothing runs beside the pattern stage")
    ends, used = [], []
    end_xy, linked = PassBuilder.end_xy, pencil.BackgroundChains.linked
    monkeypatch.setattr(PassBuilder, "end_xy", lambda self: (ends.append(end_xy(self)), ends[-1])[1])
    monkeypatch.setattr(pencil.BackgroundChains, "linked",
                        lambda self, *a, **k: (used.append(linked(self, *a, **k)), used[-1])[1])
    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    res = plan(m, Job(pattern=pattern, tool_radius=R, scallop=0.1, tolerance=0.01, pencil=True,
                      pencil_search="folds"))
    last = [p for p, i in zip(res.toolpath.passes, res.toolpath.pass_ids) if i >= 0][-1]
    assert len(ends) == 1 and np.array_equal(ends[0], last[-1, :2])
    assert len(used) == 1 and used[0] is not None and used[0].stats == res.report["pencil"]


@pytest.mark.parametrize("left", [None, 0.5])
def test_a_failing_stage_stops_the_background_search(monkeypatch, left):
    # the pattern stage fails while the pencil's search runs beside it: plan() raises the
    # stage's error, and no search thread outlives it
    import threading

    import conformill.patterns.zigzag as zz

    def fail(*a, **k):
        raise PlanningError("side step collapses (test)")

    monkeypatch.setattr(zz, "plan_zigzag", fail)
    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.1, tolerance=0.01, pencil=True, pencil_search="folds",
              pencil_left=left)
    with pytest.raises(PlanningError, match="collapses"):
        plan(m, job)
    assert not [t for t in threading.enumerate() if t.name in ("conformill-pencil", "conformill-cutter")]



def test_fold_search_skips_the_contact_motion_of_smooth_concave_ground():
    # a bowl of radius 5 r (no fold: D is smooth there): the contact moves 1.25 grid
    # spacings along an edge, beyond the wedge jump of a 0.15 h shadow (0.22 mm against the
    # 0.18 mm spacing), so that jump alone searches thousands of edges and finds no shadow;
    # the floor of 1.6 spacings searches none. A V-groove's fold (contacts 1.1 mm apart) is
    # still found on every grid row
    from conformill.folds import fold_points, wedge_jump

    h, s = 0.01, 1 / np.sqrt(30.0)
    bowl = syn.sphere_cap(R=5 * R, radius_xy=8.0, spacing=0.2, concave=True)
    cut = BallCutter(bowl.V, bowl.F, R)
    alone = fold_points(cut, s, wedge_jump(R, 0.15 * h))
    assert alone.stats["edges"] > 1000 and not (alone.shadow > 0.15 * h).any()
    fp, deep = pencil.fold_centres(cut, s, h)
    assert fp.stats["jump_mm"] == pytest.approx(1.6 * s) and fp.stats["edges"] == 0 and not deep.any()
    groove = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    cut = BallCutter(groove.V, groove.F, R)
    fp, deep = pencil.fold_centres(cut, s, h)
    rows = np.unique(np.round(fp.centres[deep, 1] / s))
    inner = np.abs(rows * s) < 10.0 - R
    assert inner.sum() >= int(2 * (10.0 - R) / s) - 1
    # on coarser grids the floor stays within half a spacing of the wedge jump: a shallow
    # V-groove (3 deg, a 0.55 h crease) keeps every deep fold point the wedge jump finds
    # (1.6 spacings alone lost 4 of 35 at 4 per mm^2)
    groove = syn.v_groove(a_deg=3.0, half=10.0, step=0.5)
    cut = BallCutter(groove.V, groove.F, R)
    for density in (4.0, 10.0, 30.0):
        s = 1 / np.sqrt(density)
        alone = fold_points(cut, s, wedge_jump(R, 0.15 * h))
        fp, deep = pencil.fold_centres(cut, s, h)
        assert deep.sum() == (alone.shadow > 0.15 * h).sum() > 30
        assert fp.stats["jump_mm"] == pytest.approx(min(1.6 * s, wedge_jump(R, 0.15 * h) + 0.5 * s))


def test_plan_cuts_the_fold_pencil_where_the_pattern_left_material():
    # Job.pencil_left: the fold points cut are exactly those with a shadow point farther
    # than r + F h from every centre move of the pattern (brute force here); the pattern's
    # passes are the same; F = 0 keeps the most, a large F none (the groove has no steep
    # walls, so then no pencil pass is cut at all)
    from conformill.folds import shadow_probes

    m = syn.v_groove(a_deg=8.0, half=10.0, step=0.5)
    h = 0.1
    job = Job(pattern="zigzag", tool_radius=R, scallop=h, tolerance=0.01, pencil=True, pencil_search="folds")
    full = plan(m, job)
    cut = BallCutter(m.V, m.F, R)
    fp, deep = pencil.fold_centres(cut, 1 / np.sqrt(30.0), h)
    probes = shadow_probes(cut, fp.contact_a[deep], fp.contact_b[deep])
    pattern = [p for p, i in zip(full.toolpath.passes, full.toolpath.pass_ids) if i >= 0]
    dist = _move_dist(probes.reshape(-1, 3), pattern).reshape(probes.shape[:2])
    cuts = {}
    for left in (0.0, 0.5, 1.0, 50.0):
        res = plan(m, Job(**{**job.__dict__, "pencil_left": left}))
        st = res.report["pencil"]
        assert st["left_h"] == left and st["centres"] == int(deep.sum())
        # a probe within 1e-9 mm of the reach may fall either way (other arithmetic)
        reach = R + left * h
        assert int((dist > reach + 1e-9).any(axis=1).sum()) <= st["fold_points_cut"] \
            <= int((dist > reach - 1e-9).any(axis=1).sum())
        cuts[left] = st["fold_points_cut"]
        n = len(pattern)
        for a, b in zip(pattern, res.toolpath.passes[:n]):
            np.testing.assert_array_equal(a, b)
        if cuts[left] == 0:
            assert len(res.toolpath.passes) == n and st["passes"] == 0
    assert deep.sum() >= cuts[0.0] > cuts[0.5] > cuts[50.0] == 0 and cuts[0.5] >= cuts[1.0]
    assert full.report["pencil"]["thinned"] > plan(m, Job(**{**job.__dict__, "pencil_left": 0.5})).report[
        "pencil"]["thinned"]


def test_where_left_keeps_what_has_no_probes():
    # the steep walls' centres (and the per-sample search's) carry no probes: always cut
    found = pencil.PencilFound(centres=np.zeros((3, 3)), probes=np.array(
        [[[0.0, 0.0, 0.0]], [[np.nan] * 3], [[0.0, 50.0, 0.0]]]), spacing=0.2)
    tips = [np.array([[-5.0, 0.0, 0.0], [5.0, 0.0, 0.0]])]
    np.testing.assert_array_equal(pencil.where_left(found, tips, R, 0.01), [False, True, True])


def test_where_left_from_passes_in_parts():
    # LeftToCut: the passes handed over as the pipeline does (those cut so far, the last of
    # them in part; then the rest of it and the passes after), the same centres kept
    rng = np.random.default_rng(3)
    probes = np.column_stack([rng.uniform(-10, 10, 600), rng.uniform(-10, 10, 600),
                              rng.uniform(-1, 1, 600)]).reshape(200, 3, 3)
    probes[::7] = np.nan  # no probes: always cut
    found = pencil.PencilFound(centres=np.zeros((200, 3)), probes=probes, spacing=0.2)
    y = np.arange(-9.0, 9.5, 1.5)
    tips = [np.column_stack([np.linspace(-9, 9, 25), np.full(25, v), rng.uniform(-0.5, 0.5, 25)]) for v in y]
    want = pencil.where_left(found, tips, R, 0.05)
    assert 0 < want.sum() < 200 and want[::7].all()
    for n, k in ((0, 0), (3, 10), (5, 25), (len(tips), 25)):
        early = tips[:n - 1] + [tips[n - 1][:k]] if n else []
        left = pencil.LeftToCut(found, R, 0.05)
        left.add(early)
        rest = [tips[n - 1][k - 1:]] if n else []
        left.add(rest + tips[n:])
        np.testing.assert_array_equal(left.keep(), want)


@pytest.mark.parametrize("over, words", [
    ({"pencil_left": -0.5}, "pencil-left must be a number >= 0"),
    ({"pencil_left": float("nan")}, "pencil-left must be a number >= 0"),
    ({"pencil_search": "samples"}, "it needs the fold pencil"),
    ({"pencil": False}, "it needs the fold pencil"),
])
def test_pencil_left_bad_jobs(over, words):
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.1, tolerance=0.01, pencil=True, pencil_search="folds",
              pencil_left=0.5)
    with pytest.raises(PlanningError, match=words):
        plan(syn.v_groove(a_deg=8.0, half=10.0, step=0.5), Job(**{**job.__dict__, **over}))


def test_roof_test_on_a_scan_changes_no_searched_row():
    # face_choi (x1000 to mm, as SOURCES.md says, read as it is), r = 4, h = 0.01: on its
    # steep walls the roof test spares the search of many samples (11463 of 38259 on the part
    # as the pipeline orients it), every one a sample the search gives up on; every other
    # row is the same.
    from pathlib import Path

    path = Path("/work/shared/meshes/face_choi.ply")
    if not path.exists():
        pytest.skip(f"{path} is absent")
    from conformill.mesh.io import read_mesh

    m = read_mesh(path, scale=1000.0)
    cut = BallCutter(m.V, m.F, R)
    h = 0.01
    P, N, faces = surface_samples(m.V, m.F, 30.0, 0, below_nz=pencil._STEEP_NZ)
    C, rest, state = best_centres(cut, P, N, faces, low=0.15 * h, give_up=1.05 * h)
    C0, rest0, state0 = best_centres(cut, P, N, faces, low=0.15 * h, give_up=1.05 * h, roof=False)
    roofed = state == 4
    assert roofed.sum() > 0.1 * len(P)
    assert np.all(state0[roofed] == 2)  # given up by the search itself
    np.testing.assert_array_equal(state[~roofed], state0[~roofed])
    np.testing.assert_array_equal(C[~roofed], C0[~roofed])
    np.testing.assert_array_equal(rest[~roofed], rest0[~roofed])
