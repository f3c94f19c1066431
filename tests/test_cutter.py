"""Ball-end cutter: drop-cutter against closed forms, OpenCAMLib and a brute-force oracle;
CC -> CL; gouge-safe chord refinement."""

from __future__ import annotations

import math

import numpy as np
import pytest

from numba import njit

from conformill.cutter import _CHUNK, _PRUNE_SLACK, BallCutter, _cell_bound, _contact_slope, _tri_drop
from conformill.errors import MeshError, PlanningError
from conformill.mesh import synthetic as syn

R_BALL = 4.0


def _tilted_plane(a=0.3, b=-0.2, c=5.0, jitter=0.3):
    m = syn.plane(size=100.0, spacing=4.0, jitter=jitter, seed=3)
    V = m.V.copy()
    V[:, 2] = a * V[:, 0] + b * V[:, 1] + c
    return V, m.F


# ----------------------------------------------------------------------------- drop: planes


class TestDropPlane:
    def test_horizontal_plane_is_z_plus_r(self):
        m = syn.plane(size=100.0, spacing=5.0, jitter=0.3, z=3.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        xy = np.random.default_rng(0).uniform(-44, 44, (2000, 2))
        np.testing.assert_allclose(cut.drop(xy), 3.0 + R_BALL, atol=1e-12, rtol=0)

    def test_tilted_plane_closed_form(self):
        # ball on the plane a x + b y + c: centre height plane(p) + r sqrt(1 + a^2 + b^2)
        a, b, c = 0.3, -0.2, 5.0
        V, F = _tilted_plane(a, b, c)
        cut = BallCutter(V, F, R_BALL)
        xy = np.random.default_rng(1).uniform(-40, 40, (2000, 2))
        exact = a * xy[:, 0] + b * xy[:, 1] + c + R_BALL * np.sqrt(1 + a * a + b * b)
        np.testing.assert_allclose(cut.drop(xy), exact, atol=1e-10, rtol=0)

    def test_far_points_touch_nothing(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        z = cut.drop(np.array([[100.0, 0.0], [0.0, -14.01], [0.0, -13.99]]))
        assert z[0] == -np.inf and z[1] == -np.inf
        # 3.99 mm from the edge y = -10: the edge cylinder, height sqrt(r^2 - d^2)
        assert z[2] == pytest.approx(np.sqrt(R_BALL**2 - 3.99**2), abs=1e-12)

    def test_empty_query(self):
        m = syn.plane(size=20.0, spacing=5.0)
        assert BallCutter(m.V, m.F, R_BALL).drop(np.empty((0, 2))).shape == (0,)


# ----------------------------------------------------------------------------- drop: sphere


def test_sphere_cap_to_faceting_error():
    # ball of radius r above a sphere of radius R: centre at sqrt((R + r)^2 - d^2)
    R = 50.0
    m = syn.sphere_cap(R=R, radius_xy=30.0, spacing=0.5, jitter=0.2, seed=2)
    cut = BallCutter(m.V, m.F, R_BALL)
    rng = np.random.default_rng(4)
    xy = rng.uniform(-1, 1, (3000, 2)) * 18.0
    exact = np.sqrt((R + R_BALL) ** 2 - (xy**2).sum(1))
    err = cut.drop(xy) - exact
    # the mesh is inscribed in the sphere: never above; below by at most the sagitta of
    # a facet, (longest edge)^2 / (8 R) * 2 for the facet's centre
    E = np.linalg.norm(m.V[m.F[:, [1, 2, 0]]] - m.V[m.F], axis=2).max()
    assert err.max() <= 1e-9
    assert err.min() >= -(E**2) / (4 * R)
    assert err.min() < -1e-6  # faceting is actually seen (the test is not vacuous)


# ----------------------------------------------------------------------------- drop: one triangle


class TestSingleTriangle:
    """Triangle A(0,0,0) B(10,0,2) C(0,10,1): plane z = 0.2 x + 0.1 y."""

    V = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 2.0], [0.0, 10.0, 1.0]])
    F = np.array([[0, 1, 2]])

    @pytest.fixture
    def cut(self):
        return BallCutter(self.V, self.F, R_BALL)

    def test_facet(self, cut):
        p = np.array([[3.0, 3.0]])
        exact = 0.2 * 3 + 0.1 * 3 + R_BALL * np.sqrt(1 + 0.04 + 0.01)
        assert cut.drop(p)[0] == pytest.approx(exact, abs=1e-12)

    def test_vertex(self, cut):
        # beyond vertex A: edges' contacts fall outside the segments, facet contact outside
        assert cut.drop(np.array([[-2.0, -2.0]]))[0] == pytest.approx(np.sqrt(16 - 8), abs=1e-12)

    def test_edge(self, cut):
        # beside edge AB (y = 0, slope m = 0.2): z_a + m u0 + s sqrt(1 + m^2), s = sqrt(r^2 - d^2)
        s = np.sqrt(R_BALL**2 - 2.0**2)
        exact = 0.2 * 5.0 + s * np.sqrt(1 + 0.04)
        assert cut.drop(np.array([[5.0, -2.0]]))[0] == pytest.approx(exact, abs=1e-12)

    def test_orientation_does_not_matter(self):
        a = BallCutter(self.V, self.F, R_BALL)
        b = BallCutter(self.V, self.F[:, ::-1], R_BALL)
        xy = np.random.default_rng(0).uniform(-5, 15, (500, 2))
        za, zb = a.drop(xy), b.drop(xy)
        assert np.array_equal(np.isfinite(za), np.isfinite(zb))
        np.testing.assert_allclose(za, zb, atol=1e-12, rtol=0)  # edges run the other way

    def test_vertical_triangle_edges_and_vertices_only(self):
        # a wall in the plane y = 0 with top edge from (0,0,5) to (10,0,5)
        V = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 5.0], [0.0, 0.0, 5.0]])
        cut = BallCutter(V, np.array([[0, 1, 2]]), R_BALL)
        z = cut.drop(np.array([[5.0, 1.0], [5.0, 0.0]]))
        np.testing.assert_allclose(z, [5.0 + np.sqrt(R_BALL**2 - 1.0), 5.0 + R_BALL], atol=1e-12)


# ----------------------------------------------------------------------------- drop: oracles


def _brute_force(V, F, r, xy, n=60):
    """Max over dense samples q of each triangle of q_z + sqrt(r^2 - |q - p|^2)."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    w1, w2 = i[keep] / n, j[keep] / n
    w0 = 1 - w1 - w2
    P = V[F]
    Q = (w0[None, :, None] * P[:, None, 0] + w1[None, :, None] * P[:, None, 1]
         + w2[None, :, None] * P[:, None, 2]).reshape(-1, 3)
    out = np.full(len(xy), -np.inf)
    for k, p in enumerate(xy):
        d2 = ((Q[:, :2] - p) ** 2).sum(1)
        ok = d2 <= r * r
        if ok.any():
            out[k] = (Q[ok, 2] + np.sqrt(r * r - d2[ok])).max()
    return out


def test_against_dense_sampling_oracle():
    m = syn.freeform_patch(spacing=6.0, jitter=0.3)
    cut = BallCutter(m.V, m.F, 3.0)
    xy = np.random.default_rng(5).uniform([-50, -30], [50, 30], (40, 2))
    z = cut.drop(xy)
    zb = _brute_force(m.V, m.F, 3.0, xy)
    assert np.array_equal(np.isfinite(z), np.isfinite(zb))
    f = np.isfinite(z)
    d = z[f] - zb[f]
    assert d.min() >= -1e-9  # exact drop is the supremum over the mesh: never below samples
    assert d.max() < 2e-2  # and close to it (sampling at 0.1 mm)


def _step_with_wall():
    """Two horizontal squares joined by a vertical wall (XY-degenerate triangles)."""
    V = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0],
                  [10, 0, 5], [10, 10, 5], [20, 0, 5], [20, 10, 5]])
    F = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2], [4, 6, 7], [4, 7, 5]])
    return V, F


def test_vertical_wall_against_dense_sampling():
    V, F = _step_with_wall()
    xy = np.random.default_rng(9).uniform([-3, -3], [23, 13], (60, 2))
    z = BallCutter(V, F, 2.0).drop(xy)
    zb = _brute_force(V, F, 2.0, xy, n=200)
    assert np.array_equal(np.isfinite(z), np.isfinite(zb))
    f = np.isfinite(z)
    assert (z[f] - zb[f]).min() >= -1e-9 and (z[f] - zb[f]).max() < 1e-2


@pytest.mark.parametrize("case", ["freeform", "steep_cylinder", "wall"])
def test_against_opencamlib(case):
    ocl_mod = pytest.importorskip("opencamlib")
    ocl = ocl_mod.ocl
    r = 3.0
    rng = np.random.default_rng(0)
    if case == "freeform":
        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        V, F = m.V, m.F
        xy = rng.uniform([-70, -50], [70, 50], (3000, 2))
    elif case == "steep_cylinder":  # facets down to n_z ~ 0.02
        m = syn.cylinder_patch(R=20.0, length=40.0, half_angle=1.55, spacing=1.5, jitter=0.2)
        V, F = m.V, m.F
        xy = rng.uniform([-25, -25], [25, 25], (3000, 2))
    else:
        V, F = _step_with_wall()
        xy = rng.uniform([-4, -4], [24, 14], (3000, 2))
    surf = ocl.STLSurf()
    for t in V[F].tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*t[0]), ocl.Point(*t[1]), ocl.Point(*t[2])))
    cutter = ocl.BallCutter(2 * r, 50.0)  # keep a reference: ocl does not own it
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(surf)
    bdc.setCutter(cutter)
    zmin = -1000.0
    for x, y in xy.tolist():
        bdc.appendPoint(ocl.CLPoint(x, y, zmin))
    bdc.run()
    tip = np.array([p.z for p in bdc.getCLPoints()])
    ref = np.where(tip > zmin, tip + r, -np.inf)  # ocl gives the tool tip
    z = BallCutter(V, F, r).drop(xy)
    assert np.array_equal(np.isfinite(z), np.isfinite(ref))
    f = np.isfinite(z)
    assert f.sum() > 1500
    np.testing.assert_allclose(z[f], ref[f], atol=1e-9, rtol=0)


def test_result_does_not_depend_on_order_or_grid():
    m = syn.freeform_patch(spacing=2.0, jitter=0.3)
    xy = np.random.default_rng(7).uniform([-65, -45], [65, 45], (5000, 2))
    a = BallCutter(m.V, m.F, 3.0)
    z = a.drop(xy)
    perm = np.random.default_rng(8).permutation(len(xy))
    np.testing.assert_array_equal(a.drop(xy[perm]), z[perm])
    np.testing.assert_array_equal(BallCutter(m.V, m.F, 3.0, cell=4.0).drop(xy), z)


def _max_over_all_triangles(cut, xy):
    """The drop as the plain maximum of :func:`_tri_drop` over every triangle whose XY box
    lies within the ball's reach (no other can touch it)."""
    T, r = cut._T, cut.radius
    X, Y = T[:, [0, 3, 6]], T[:, [1, 4, 7]]
    lo, hi = np.column_stack([X.min(1), Y.min(1)]), np.column_stack([X.max(1), Y.max(1)])
    out = []
    for p in xy:
        d = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        near = np.flatnonzero((d * d).sum(1) <= r * r)
        out.append(max((_tri_drop(p[0], p[1], r, r * r, T, t) for t in near.tolist()), default=-np.inf))
    return np.array(out)


@pytest.mark.parametrize("spacing, cell", [(6.0, 0.5), (0.4, None)])
def test_drop_tests_a_triangle_once_and_finds_the_maximum(spacing, cell):
    # each drop skips the triangles it has tested already from another cell (a
    # direct-mapped table stamped per drop, reused by the points of a chunk): the result
    # must stay the maximum over all triangles, bit for bit, with its contact triangle.
    # Large triangles in small cells: every triangle is an entry of 100+ cells; a fine
    # mesh: 700 triangles in reach, about a hundred tested per drop, sharing table slots
    m = syn.freeform_patch(spacing=spacing, jitter=0.3)
    cut = BallCutter(m.V, m.F, 3.0, cell=cell)
    rng = np.random.default_rng(11)
    xy = rng.uniform([-50, -30], [50, 30], (600, 2))
    xy = xy[np.argsort(xy[:, 0] + 0.01 * xy[:, 1])]  # path-like order: warm starts
    z, tri = cut._drop(xy, np.full(len(xy), -np.inf))
    ref = _max_over_all_triangles(cut, xy)
    np.testing.assert_array_equal(z, ref)
    hit = tri >= 0
    np.testing.assert_array_equal(hit, np.isfinite(ref))
    assert hit.sum() > 0.9 * len(xy)
    at = np.array([_tri_drop(x, y, 3.0, 9.0, cut._T, t) for (x, y), t in zip(xy[hit].tolist(), tri[hit])])
    np.testing.assert_array_equal(at, z[hit])
    # with a floor just below the answer (as cl_from_cc drops) a triangle still rises, the
    # same height (its contact may be another of tied triangles: the cells go in grid
    # order from the first point on)
    zf, tf = cut._drop(xy, np.where(np.isfinite(ref), ref - 1e-6, -np.inf))
    np.testing.assert_array_equal(zf[hit], z[hit])
    assert (tf[hit] >= 0).all()
    at = np.array([_tri_drop(x, y, 3.0, 9.0, cut._T, t) for (x, y), t in zip(xy[hit].tolist(), tf[hit])])
    np.testing.assert_array_equal(at, z[hit])


def test_drop_refuses_working_arrays_of_another_size():
    # the kernels index without checks: a table without the batch's room (an older
    # _drop_scratch) would be written past its end
    from conformill.cutter import _SEEN_MASK, _drop_point, _drop_scratch

    m = syn.freeform_patch(spacing=6.0, jitter=0.3)
    cut = BallCutter(m.V, m.F, 3.0)
    T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, maxwin = cut._kernel_args()
    cid, cbound, seen = _drop_scratch(maxwin)
    args = (0.0, 0.0, 3.0, 9.0, T, B, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, EB, CP, -1, cid, cbound)
    z, t = _drop_point(*args, seen, -np.inf, False)
    assert t >= 0 and z == cut.drop(np.zeros((1, 2)))[0]
    with pytest.raises(ValueError, match="_drop_scratch"):
        _drop_point(*args, np.zeros(_SEEN_MASK + 2, dtype=np.int64), -np.inf, False)


@njit(cache=True)
def _single_pass_drops(xy, floor, r, T, gx0, gy0, cell, ncx, ncy, cstart, ctri, czmax, CP, chunk):
    """The drop of session 58 in its plainest form, as the oracle of which triangle a drop
    reports where several give the same height: cells in grid order, each skipped by the
    same cell tests, each cell's entries in order until the first whose top is too low,
    every one of them tested in full (a test the real drop prunes cannot raise the best),
    the previous point's contact first (a new start every ``chunk`` points)."""
    n = xy.shape[0]
    out = np.empty(n)
    tri = np.full(n, -1, dtype=np.int64)
    r2 = r * r
    warm = -1
    for p in range(n):
        if p % chunk == 0:
            warm = -1
        px, py = xy[p, 0], xy[p, 1]
        best = floor[p]
        besttri = -1
        if warm >= 0:
            h = _tri_drop(px, py, r, r2, T, warm)
            if h > best:
                best, besttri = h, warm
        i0 = max(int(math.floor((px - r - gx0) / cell)), 0)
        i1 = min(int(math.floor((px + r - gx0) / cell)), ncx - 1)
        j0 = max(int(math.floor((py - r - gy0) / cell)), 0)
        j1 = min(int(math.floor((py + r - gy0) / cell)), ncy - 1)
        for j in range(j0, j1 + 1):
            y0 = gy0 + j * cell
            dy = py - y0 - cell if py > y0 + cell else (y0 - py if py < y0 else 0.0)
            for i in range(i0, i1 + 1):
                c = j * ncx + i
                if cstart[c] == cstart[c + 1]:
                    continue
                x0 = gx0 + i * cell
                dx = px - x0 - cell if px > x0 + cell else (x0 - px if px < x0 else 0.0)
                q = dx * dx + dy * dy
                g = max(best - _PRUNE_SLACK - czmax[c], 0.0)
                if g * g > r2 - q or _cell_bound(px, py, r2, x0, y0, cell, CP, c) + _PRUNE_SLACK < best:
                    continue
                hc = math.sqrt(r2 - q)
                for e in range(cstart[c], cstart[c + 1]):
                    t = ctri[e]
                    if best - _PRUNE_SLACK - max(T[t, 2], T[t, 5], T[t, 8]) > hc:
                        break
                    h = _tri_drop(px, py, r, r2, T, t)
                    if h > best:
                        best, besttri = h, t
        out[p] = best
        tri[p] = besttri
        if besttri >= 0:
            warm = besttri
    return out, tri


def test_contact_ties_go_to_the_triangle_a_single_pass_finds_first():
    # where triangles give the same height (a shared edge or vertex), the drop reports the
    # one a single pass over the cells and their entries reaches first, whatever the
    # drop skips or reads in batches: the settle and the pencil take the contacts as
    # hints, so another tie-break changes programs (a batch read ahead of the cell's end,
    # a mutant of session 59, changed 2 of these 20000 contacts)
    m = syn.freeform_patch(spacing=0.5, jitter=0.3)
    cut = BallCutter(m.V, m.F, 4.0)
    rng = np.random.default_rng(3)
    xy = rng.uniform([-50, -30], [50, 30], (20000, 2))
    xy = xy[np.lexsort((xy[:, 0], np.round(xy[:, 1])))]  # rows: warm starts
    floor = np.full(len(xy), -1e3)  # finite: cells in grid order from the first point on
    z, tri = cut._drop(xy, floor)
    gx0, gy0, cell, ncx, ncy = cut._grid
    zr, tr = _single_pass_drops(xy, floor, cut.radius, cut._T, gx0, gy0, cell, ncx, ncy, cut._cstart, cut._ctri,
                                cut._czmax, cut._CP, _CHUNK)
    np.testing.assert_array_equal(z, zr)
    np.testing.assert_array_equal(tri, tr)


def _tri_drop_all_features(p, tri, r):
    """Closed-form drop onto one triangle by every feature (facet, 3 edges, 3 vertices)."""
    x, y = p
    best = -np.inf
    a, b, c = tri
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n)
    n = -n if n[2] < 0 else n
    if n[2] > 1e-12:
        q = np.array([x, y]) - r * n[:2]
        M = np.column_stack([b[:2] - a[:2], c[:2] - a[:2]])
        l1, l2 = np.linalg.solve(M, q - a[:2])
        if l1 >= 0 and l2 >= 0 and l1 + l2 <= 1:
            return a[2] + l1 * (b[2] - a[2]) + l2 * (c[2] - a[2]) + r * n[2]  # plane at the contact
    for v in tri:
        d2 = (x - v[0]) ** 2 + (y - v[1]) ** 2
        if d2 <= r * r:
            best = max(best, v[2] + np.sqrt(r * r - d2))
    for u, v in ((a, b), (b, c), (c, a)):
        e = v[:2] - u[:2]
        L = np.linalg.norm(e)
        if L < 1e-12:
            continue
        e = e / L
        w = np.array([x, y]) - u[:2]
        d = w[0] * e[1] - w[1] * e[0]
        if d * d > r * r:
            continue
        s = np.sqrt(r * r - d * d)
        u0 = w @ e
        m = (v[2] - u[2]) / L
        ucc = u0 + s * m / np.sqrt(1 + m * m)
        if 0 <= ucc <= L:
            best = max(best, u[2] + m * u0 + s * np.sqrt(1 + m * m))
    return best


def test_triangle_drop_tests_only_the_facing_edges():
    # _tri_drop tests the facet, then only the edges facing the facet contact (the height
    # is concave over the triangle): the same value as testing every feature
    from conformill.cutter import _tables, _tri_drop

    rng = np.random.default_rng(11)
    r = 3.0
    n_fin = 0
    for _ in range(400):
        tri = rng.uniform([-4, -4, -2], [4, 4, 2], (3, 3))
        if rng.random() < 0.2:  # steep ones too
            tri[:, 2] *= 20
        if rng.random() < 0.1:  # a vertical edge (and facet): the edge table's flag
            tri[1, :2] = tri[0, :2]
        T, _ = _tables(tri, np.array([[0, 1, 2]]), r)  # the cutter's own table, edges too
        for p in rng.uniform(-8, 8, (20, 2)):
            got = _tri_drop(p[0], p[1], r, r * r, T, 0)
            ref = _tri_drop_all_features(p, tri, r)
            assert np.isfinite(got) == np.isfinite(ref)
            if np.isfinite(ref):
                n_fin += 1
                assert got == pytest.approx(ref, abs=1e-9)
    assert n_fin > 2000


def _seg_drop_per_call(px, py, r2, a, b):
    """The edge test as the cutter computed it before the edge table (session 57): length,
    direction and slope computed at the call, then ``_arc_max``."""
    from conformill.cutter import _arc_max

    ex, ey = b[0] - a[0], b[1] - a[1]
    L2 = ex * ex + ey * ey
    if L2 <= 1e-24:
        dx, dy = px - a[0], py - a[1]
        q = dx * dx + dy * dy
        return -np.inf if q > r2 else max(a[2], b[2]) + math.sqrt(r2 - q)
    L = math.sqrt(L2)
    ux, uy = ex / L, ey / L
    wx, wy = px - a[0], py - a[1]
    d = wx * uy - wy * ux
    m = (b[2] - a[2]) / L
    return _arc_max(r2 - d * d, wx * ux + wy * uy, 0.0, L, m, math.sqrt(1.0 + m * m), a[2])


def _tri_drop_per_call(px, py, r, T, tri):
    """``_tri_drop`` with the edges computed at each call (the code before the edge table)."""
    x0, y0, z0 = T[0, 0:3]
    nx, ny, nz, idet = T[0, 9:13]
    a, b, c = tri
    if nz > 1e-12:
        cx, cy = px - r * nx, py - r * ny
        l1 = ((cx - x0) * (T[0, 7] - y0) - (cy - y0) * (T[0, 6] - x0)) * idet
        l2 = ((T[0, 3] - x0) * (cy - y0) - (T[0, 4] - y0) * (cx - x0)) * idet
        l0 = 1.0 - l1 - l2
        if l1 >= 0.0 and l2 >= 0.0 and l0 >= 0.0:
            return z0 - (nx * (cx - x0) + ny * (cy - y0)) / nz + r * nz
        best = -np.inf
        for lk, (u, v) in ((l0, (b, c)), (l1, (c, a)), (l2, (a, b))):
            if lk < 0.0:
                best = max(best, _seg_drop_per_call(px, py, r * r, u, v))
        return best
    best = _seg_drop_per_call(px, py, r * r, a, b)
    best = max(best, _seg_drop_per_call(px, py, r * r, b, c))
    return max(best, _seg_drop_per_call(px, py, r * r, c, a))


def test_edge_table_is_the_per_call_arithmetic_bit_for_bit():
    # the edge columns of _tables (session 58) hold what each edge test computed at the
    # call: the same operations, so the same bits, and the flag exactly where the old test
    # took the vertical branch (L^2 <= 1e-24), whichever edge is vertical or nearly so
    from conformill.cutter import _E0, _EW, _tables, _tri_drop

    rng = np.random.default_rng(58)
    r = 2.5
    n_edge = n_flag = 0
    for k in range(600):
        tri = rng.uniform([-3, -3, -2], [3, 3, 2], (3, 3))
        if k % 3 == 0:
            tri[:, 2] *= 30  # steep
        e = k % 4  # 0-2: edge e made vertical or nearly so (just either side of the flag)
        if e < 3 and k % 2 == 0:
            i, j = [(1, 2), (2, 0), (0, 1)][e]
            tri[j, :2] = tri[i, :2] + rng.choice([0.0, 0.99e-12, 1.01e-12]) * np.array([1.0, 0.0])
        T, _ = _tables(tri, np.array([[0, 1, 2]]), r)
        for kk, (i, j) in enumerate([(1, 2), (2, 0), (0, 1)]):
            ex, ey = tri[j, 0] - tri[i, 0], tri[j, 1] - tri[i, 1]
            L2 = ex * ex + ey * ey
            col = T[0, _E0 + _EW * kk:_E0 + _EW * (kk + 1)]
            if L2 <= 1e-24:
                n_flag += 1
                assert col[0] == -1.0
                continue
            L = math.sqrt(L2)
            m = (tri[j, 2] - tri[i, 2]) / L
            assert col.tolist() == [L, ex / L, ey / L, m, math.sqrt(1.0 + m * m)]
        for p in rng.uniform(-6, 6, (12, 2)):
            got = _tri_drop(p[0], p[1], r, r * r, T, 0)
            want = _tri_drop_per_call(p[0], p[1], r, T, tri)
            assert got == want or (np.isinf(got) and np.isinf(want))
            n_edge += np.isfinite(want)
    assert n_flag > 50 and n_edge > 1500


def test_triangle_table_of_another_width_is_refused():
    # the kernels cannot see a table's width: a 13-column table (the layout before the edge
    # columns) would read its edges from the next row; _tri_drop refuses it
    from conformill.cutter import _tables, _tri_drop

    tri = np.array([[0.0, 0, 0], [1, 0, 0.2], [0, 1, 0.1]])
    T, _ = _tables(tri, np.array([[0, 1, 2]]), 1.0)
    with pytest.raises(ValueError, match="columns"):
        _tri_drop(0.2, 0.2, 1.0, 1.0, np.ascontiguousarray(T[:, :13]), 0)
    assert np.isfinite(_tri_drop(0.2, 0.2, 1.0, 1.0, T, 0))


def test_cell_plane_bound_is_the_maximum_over_the_cell():
    # _cell_bound: the highest ball resting on the plane z = g.q + c at a contact q inside
    # the cell; against a dense grid of contacts in the cell: never below, and close
    from conformill.cutter import _cell_bound

    rng = np.random.default_rng(12)
    r = 4.0
    u = np.linspace(0.0, 1.0, 401)
    checked = 0
    for _ in range(300):
        x0, y0 = rng.uniform(-3, 3, 2)
        cell = rng.uniform(0.3, 2.0)
        gx, gy = rng.normal(scale=1.5, size=2)
        gc = rng.uniform(-1, 1)
        k = np.sqrt(1 + gx * gx + gy * gy)
        CP = np.array([[gx, gy, gc, r * gx / k, r * gy / k, r * k]])
        px, py = np.array([x0, y0]) + 0.5 * cell + rng.uniform(-5, 5, 2)
        if rng.random() < 0.3:  # the free maximum inside the cell
            px, py = np.array([x0, y0]) + cell * rng.random(2) - r * np.array([gx, gy]) / k
        b = _cell_bound(px, py, r * r, x0, y0, cell, CP, 0)
        qx, qy = np.meshgrid(x0 + cell * u, y0 + cell * u)
        d2 = (qx - px) ** 2 + (qy - py) ** 2
        ok = d2 <= r * r
        if not ok.any():
            assert b == -np.inf or b < gx * px + gy * py + gc + r * k + 1e-12
            continue
        dense = (gx * qx + gy * qy + gc + np.sqrt(np.where(ok, r * r - d2, 0.0)))[ok].max()
        assert b >= dense - 1e-9
        assert b <= dense + 1e-3  # the grid step is cell / 400
        checked += 1
    assert checked > 150


# ----------------------------------------------------------------------------- CC -> CL


class TestClFromCC:
    def test_plane_centre_is_cc_plus_rn(self):
        a, b, c = 0.3, -0.2, 5.0
        V, F = _tilted_plane(a, b, c)
        cut = BallCutter(V, F, R_BALL)
        xy = np.random.default_rng(2).uniform(-35, 35, (500, 2))
        cc = np.column_stack([xy, a * xy[:, 0] + b * xy[:, 1] + c])
        n = np.tile(np.array([-a, -b, 1.0]) / np.sqrt(1 + a * a + b * b), (len(xy), 1))
        centre, lift = cut.cl_from_cc(cc, n)
        np.testing.assert_allclose(centre, cc + R_BALL * n, atol=1e-10, rtol=0)
        np.testing.assert_allclose(lift, 0.0, atol=1e-10)
        np.testing.assert_allclose(np.linalg.norm(centre - cc, axis=1), R_BALL, atol=1e-10)

    def test_contacts_are_the_triangles_the_centres_rest_on(self):
        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        cut = BallCutter(m.V, m.F, 3.0)
        xy = np.random.default_rng(3).uniform(-30, 30, (300, 2))
        D = cut.drop(xy)
        xy, D = xy[np.isfinite(D)], D[np.isfinite(D)]  # the outline is notched
        cc = np.column_stack([xy, D - 3.0])  # tip under the centre: a CC point with n = Z
        n = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        centre, lift, tri = cut.cl_from_cc(cc, n, contacts=True)
        c2, l2 = cut.cl_from_cc(cc, n)
        np.testing.assert_array_equal(centre, c2)
        np.testing.assert_array_equal(lift, l2)
        assert tri.dtype == np.int64 and (tri >= 0).all()
        h = np.array([_tri_drop(x, y, 3.0, 9.0, cut._T, t) for (x, y, _), t in zip(centre, tri)])
        np.testing.assert_array_equal(h, centre[:, 2])  # the contact triangle gives the drop height

    def test_sphere_lift_is_faceting_error(self):
        R = 50.0
        m = syn.sphere_cap(R=R, radius_xy=30.0, spacing=0.5)
        cut = BallCutter(m.V, m.F, R_BALL)
        rng = np.random.default_rng(3)
        xy = rng.uniform(-14, 14, (300, 2))
        cc = np.column_stack([xy, np.sqrt(R * R - (xy**2).sum(1))])  # on the analytic sphere
        n = cc / R  # its true normals
        centre, lift = cut.cl_from_cc(cc, n)
        assert lift.min() > -1e-2 and lift.max() < 1e-2
        np.testing.assert_allclose(np.linalg.norm(centre, axis=1), R + R_BALL, atol=1e-2)

    def test_lift_is_never_negative_and_reports_bad_normals(self):
        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        cut = BallCutter(m.V, m.F, 3.0)
        rng = np.random.default_rng(4)
        f = rng.integers(0, len(m.F), 400)
        w = rng.dirichlet([1, 1, 1], 400)
        cc = np.einsum("ij,ijk->ik", w, m.V[m.F[f]])
        n = rng.normal(size=(400, 3))
        n[:, 2] = np.abs(n[:, 2])
        centre, lift = cut.cl_from_cc(cc, n)
        assert lift.min() >= -1e-9
        # the ball never intersects the mesh: centre on the drop surface
        np.testing.assert_array_equal(centre[:, 2], cut.drop(centre[:, :2]))
        # a normal pointing down gives a large lift
        _, lift_down = cut.cl_from_cc(cc[:1], -np.array([[0.0, 0.0, 1.0]]))
        assert lift_down[0] > 5.0

    def test_horizontal_normal_at_the_rim_of_reach(self):
        # A CC point at a convex corner of the outline with a horizontal outward normal puts
        # the ideal centre exactly r from the corner in XY, the only point it can touch;
        # rounding made some of these touch nothing and aborted the plan (seen on a 2.5M-face
        # scan). Now the centre is pulled towards cc by a relative 1e-6 and dropped there.
        a, b, z0 = 10.3, 7.1, 2.5
        V = np.array([[-a, -b, z0], [a, -b, z0], [a, b, z0], [-a, b, z0]])
        F = np.array([[0, 1, 2], [0, 2, 3]])
        cut = BallCutter(V, F, R_BALL)
        th = np.random.default_rng(5).uniform(0.0, 0.5 * np.pi, 400)
        n = np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
        cc = np.tile(V[2], (len(th), 1))
        ideal = cc + R_BALL * (n / np.linalg.norm(n, axis=1)[:, None])  # as cl_from_cc forms it
        missed = np.array([not np.isfinite(cut.drop(p[None, :2])[0]) for p in ideal])
        assert missed.any()  # the case exists: without the pull these points raised
        centre, lift = cut.cl_from_cc(cc, n)
        assert np.isfinite(centre).all()
        # each centre touches the square (its corner) and does not cut into it
        dx = np.maximum(np.abs(centre[:, 0]) - a, 0.0)
        dy = np.maximum(np.abs(centre[:, 1]) - b, 0.0)
        dist = np.sqrt(dx * dx + dy * dy + (centre[:, 2] - z0) ** 2)
        assert dist.min() >= R_BALL - 1e-9 and dist.max() <= R_BALL + 1e-9
        # a centre keeps its ideal XY, or is pulled by 1e-6 and rests on the corner just
        # below the ball's equator, lifted by about r sqrt(2e-6)
        pulled = np.any(centre[:, :2] != ideal[:, :2], axis=1)
        assert pulled.any()
        d = np.linalg.norm(centre[pulled, :2] - cc[pulled, :2], axis=1)
        np.testing.assert_allclose(d, R_BALL * (1 - 1e-6), rtol=1e-12)
        np.testing.assert_allclose(lift[pulled], np.sqrt(R_BALL**2 - d**2), rtol=1e-6)
        assert lift.min() >= 0.0 and lift.max() < 0.01

    def test_bad_inputs(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        cc = np.zeros((2, 3))
        n = np.tile([0.0, 0.0, 1.0], (2, 1))
        with pytest.raises(PlanningError, match="same shape"):
            cut.cl_from_cc(cc, n[:1])
        with pytest.raises(PlanningError, match="zero length.*point 1"):
            cut.cl_from_cc(cc, np.array([[0, 0, 1.0], [0, 0, 0]]))
        with pytest.raises(PlanningError, match="not within the ball's reach.*point 0"):
            cut.cl_from_cc(np.array([[100.0, 0, 0]]), n[:1])
        with pytest.raises(PlanningError, match="non-finite rows.*row 1"):
            cut.cl_from_cc(np.array([[0, 0, 0], [np.nan, 0, 0]]), n)


# ----------------------------------------------------------------------------- refine


def _max_dip(cut, P, spacing=0.01):
    """Largest ``drop - chord`` over dense samples of every segment of ``P``."""
    worst = -np.inf
    for a, b in zip(P[:-1], P[1:]):
        k = max(2, int(np.ceil(np.hypot(*(b[:2] - a[:2])) / spacing)) + 1)
        t = np.linspace(0, 1, k)[:, None]
        S = a + t * (b - a)
        d = cut.drop(S[:, :2]) - S[:, 2]
        worst = max(worst, np.max(d[np.isfinite(d)], initial=-np.inf))
    return worst


def _split_whole(cut, P, seg, thresh, track, max_levels=60):
    """The halving of ``BallCutter._split_safe`` as it was up to session 63: each level over
    the whole polyline (the reference its move-by-move form must match)."""
    from conformill.cutter import _insert

    l_safe = cut._l_safe(thresh)
    check = np.zeros(len(P) - 1, dtype=bool)
    check[seg] = True
    for _ in range(max_levels):
        d = np.diff(P, axis=0)
        long_ = check & (np.linalg.norm(d, axis=1) > l_safe) & (np.hypot(d[:, 0], d[:, 1]) > 1e-9)
        if not long_.any():
            break
        s = np.flatnonzero(long_)
        mid = 0.5 * (P[s] + P[s + 1])
        mid[:, 2] = np.maximum(cut.drop(mid[:, :2]), mid[:, 2])
        P, check, track = _insert(P, s, mid, track)
    return P, track


def _is_subsequence(P, Q):
    """Every row of P appears in Q, in order."""
    j = 0
    for q in Q:
        if j < len(P) and np.array_equal(q, P[j]):
            j += 1
    return j == len(P)


class TestRefine:
    @pytest.mark.parametrize("tol", [0.05, 0.005])
    def test_dome_chords(self, tol):
        m = syn.sphere_cap(R=30.0, radius_xy=25.0, spacing=1.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.linspace(-18, 18, 7)  # 6 mm steps over a dome: chords dip well below
        xy = np.column_stack([x, 0.3 * x])
        P = np.column_stack([xy, cut.drop(xy)])
        assert _max_dip(cut, P) > 4 * tol  # the input does gouge
        Q = cut.refine(P, tol)
        assert len(Q) > len(P)
        assert _is_subsequence(P, Q)
        assert _max_dip(cut, Q) <= tol
        # inserted points lie on the drop surface
        np.testing.assert_array_equal(Q[:, 2] >= cut.drop(Q[:, :2]) - 1e-12, True)

    def test_undecided_moves_are_cut_into_safe_pieces(self, caplog):
        # no insertion rounds at all: every move is left undecided and must be cut into
        # pieces no longer than L_safe with dropped ends, which the bound proves safe
        m = syn.sphere_cap(R=30.0, radius_xy=25.0, spacing=1.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.linspace(-18, 18, 7)
        xy = np.column_stack([x, 0.3 * x])
        P = np.column_stack([xy, cut.drop(xy)])
        tol = 0.01
        assert _max_dip(cut, P) > 4 * tol
        with caplog.at_level("WARNING", logger="conformill.cutter"):
            Q = cut.refine(P, tol, max_points=0)
        assert "still unchecked" in caplog.text
        assert _is_subsequence(P, Q)
        l_safe = 2 * np.sqrt(tol / 2 * (2 * R_BALL - tol / 2))
        assert np.linalg.norm(np.diff(Q, axis=0), axis=1).max() <= l_safe
        assert np.all(Q[:, 2] >= cut.drop(Q[:, :2]) - 1e-12)
        assert _max_dip(cut, Q) <= tol

    def test_safe_pieces_move_by_move(self, caplog):
        # a plateau 10 mm above a floor, 20 mm wide: the drop surface jumps by 6 mm where
        # the ball leaves the plateau's rim (4 mm beyond its edge). A move from a point
        # just off the rim, on the floor's side (as the pencil's fold crossings sit), onto
        # the plateau keeps a 6 mm piece until its XY extent vanishes (about 30 levels).
        # Halving each move on its own points gives the points, and the tracked rows, of
        # halving the whole polyline level by level
        lo = syn.plane(size=60.0, spacing=2.0, z=0.0)
        hi = syn.plane(size=20.0, spacing=2.0, z=10.0)
        cut = BallCutter(np.vstack([lo.V, hi.V]), np.vstack([lo.F, hi.F + len(lo.V)]), R_BALL)
        xy = np.array([[-25, -3], [-14 - 1e-10, 0.5], [2, 1], [18, 2.5], [22, 3], [6, 5], [-20, 6], [-20, 6],
                       [-24, 9]])
        P = np.column_stack([xy, cut.drop(xy)])
        thresh = 0.005
        track = np.array([0, 2, 3, 6, 7, 8, 9], dtype=np.int64)
        same, same_track = cut._split_safe(P, np.zeros(0, dtype=np.int64), thresh, track)  # no moves: nothing
        np.testing.assert_array_equal(same, P)
        np.testing.assert_array_equal(same_track, track)
        for seg in (np.arange(len(P) - 1), np.array([0, 2, 3]), np.array([3]), np.array([6, 7])):
            got, got_track = cut._split_safe(P, seg, thresh, track)
            want, want_track = _split_whole(cut, P, seg, thresh, track)
            np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(got_track, want_track)
            np.testing.assert_array_equal(got[got_track[:-1]], P[track[:-1]])
            assert _is_subsequence(P, got)
            if 1 in seg:  # the rim's move needed the levels: a piece under a micron in XY
                step = np.hypot(*np.diff(got[:, :2], axis=0).T)
                assert 0 < step[step > 0].min() < 1e-6
        # and through refine: every move undecided, every piece safe
        with caplog.at_level("WARNING", logger="conformill.cutter"):
            Q = cut.refine(P, 0.01, max_points=0)
        assert "still unchecked" in caplog.text and "after" not in caplog.text
        want, _ = _split_whole(cut, P, np.flatnonzero(np.hypot(*np.diff(P, axis=0)[:, :2].T) > 1e-9), thresh,
                               np.zeros(0, dtype=np.int64))
        np.testing.assert_array_equal(Q, want)

    @pytest.mark.parametrize("max_points", [1, 3, 8, 9, 256])
    def test_room_per_move(self, max_points, caplog):
        # long moves over a dome need many points each: with little room they are halved
        # into L_safe pieces instead (with a warning), with more room (past the first
        # eight) they are refined again with it; every way, the moves are proved safe
        m = syn.sphere_cap(R=30.0, radius_xy=25.0, spacing=1.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.linspace(-18, 18, 4)  # 12 mm moves
        xy = np.column_stack([x, 0.3 * x])
        P = np.column_stack([xy, cut.drop(xy)])
        tol = 0.01
        with caplog.at_level("WARNING", logger="conformill.cutter"):
            Q = cut.refine(P, tol, max_points=max_points)
        assert _is_subsequence(P, Q)
        assert _max_dip(cut, Q) <= tol
        assert np.all(Q[:, 2] >= cut.drop(Q[:, :2]) - 1e-12)
        full = cut.refine(P, tol)
        # 12 mm chords 0.6 mm below a 34 mm dome: more than 8 points each, fewer than 256
        assert 3 * 8 < len(full) - len(P) < 3 * 256
        if max_points >= len(full) - len(P):
            np.testing.assert_array_equal(Q, full)
            assert "still unchecked" not in caplog.text
        if max_points <= 8:
            assert "still unchecked" in caplog.text
            l_safe = 2 * np.sqrt(tol / 2 * (2 * R_BALL - tol / 2))
            assert np.linalg.norm(np.diff(Q, axis=0), axis=1).max() <= l_safe + 1e-12

    def test_inserted_points_follow_the_sphere(self):
        # over a sphere cap the drop surface is a sphere of radius R + r: the chords of the
        # refined move lie at most tol/2 below it (the sagitta of each chord), and no move
        # needs a point where a chord no longer than L_safe would do
        R = 30.0
        m = syn.sphere_cap(R=R, radius_xy=25.0, spacing=0.5)
        cut = BallCutter(m.V, m.F, R_BALL)
        xy = np.array([[-15.0, 2.0], [15.0, -1.0]])
        P = np.column_stack([xy, cut.drop(xy)])
        tol = 0.01
        Q = cut.refine(P, tol)
        L = np.linalg.norm(np.diff(Q, axis=0), axis=1)
        assert _max_dip(cut, Q) <= tol / 2 + 1e-9
        # a chord of length L under a sphere of radius R + r sags L^2 / 8(R + r): each
        # inserted point was needed, so the moves are not much shorter than the sag allows
        sag_l = np.sqrt(8 * (R + R_BALL) * tol / 2)
        assert L.max() <= sag_l * 1.05 + 1e-9
        assert np.median(L) >= 0.3 * sag_l

    def test_ridge_crease(self):
        # a roof: two planes meeting at the ridge x = 0; the drop surface rounds it with r
        P2, F = syn.polygon_disk(syn.regular_polygon(40, 40.0), 3.0)
        V = np.column_stack([P2, 10.0 - 0.6 * np.abs(P2[:, 0])])
        cut = BallCutter(V, F, R_BALL)
        xy = np.array([[-12.0, 1.0], [12.0, -1.0]])
        P = np.column_stack([xy, cut.drop(xy)])
        Q = cut.refine(P, 0.01)
        assert _is_subsequence(P, Q)
        assert _max_dip(cut, Q) <= 0.01

    def test_freeform_zigzag(self):
        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        cut = BallCutter(m.V, m.F, 3.0)
        x = np.arange(-50, 51, 5.0)
        xy = np.vstack([np.column_stack([x if k % 2 == 0 else x[::-1], np.full_like(x, y)])
                        for k, y in enumerate(np.arange(-30, 31, 15.0))])
        z = cut.drop(xy)
        P = np.column_stack([xy, z])[np.isfinite(z)]  # not in the notch
        assert _max_dip(cut, P, spacing=0.02) > 0.05
        Q = cut.refine(P, 0.01)
        assert _is_subsequence(P, Q)
        assert _max_dip(cut, Q, spacing=0.02) <= 0.01

    @pytest.mark.parametrize("tol", [0.01, 0.002])
    def test_moves_keep_clear_of_the_mesh(self, tol):
        # The exact bound: every centre move stays at least r - tol / 2 from every triangle
        # (segment-triangle distance from conformill.verify, which shares no code with the
        # cutter). Zigzag rows over a jittered free-form patch with a notch.
        from scipy.spatial import cKDTree

        from conformill.verify.simulate import segment_triangle_distance

        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        r = 3.0
        cut = BallCutter(m.V, m.F, r)
        x = np.arange(-50, 51, 2.5)
        xy = np.vstack([np.column_stack([x if k % 2 == 0 else x[::-1], np.full_like(x, y)])
                        for k, y in enumerate(np.arange(-30, 31, 7.5))])
        z = cut.drop(xy)
        P = np.column_stack([xy, z])[np.isfinite(z)]
        Q = cut.refine(P, tol)
        assert len(Q) > len(P)
        A, B = Q[:-1], Q[1:]
        cen = m.V[m.F].mean(axis=1)
        rad = np.linalg.norm(m.V[m.F] - cen[:, None], axis=2).max()
        half = 0.5 * np.linalg.norm(B - A, axis=1)
        near = cKDTree(cen).query_ball_point(0.5 * (A + B), r + half + rad)
        seg = np.repeat(np.arange(len(A)), [len(n) for n in near])
        tri = np.concatenate([np.asarray(n, dtype=np.int64) for n in near])
        d = segment_triangle_distance(A, B, m.V, m.F, seg, tri)
        assert d.min() >= r - tol / 2 - 1e-9
        # without the inserted points the moves do cut deeper
        near0 = cKDTree(cen).query_ball_point(0.5 * (P[:-1] + P[1:]), r + 3.0 + rad)
        seg0 = np.repeat(np.arange(len(P) - 1), [len(n) for n in near0])
        tri0 = np.concatenate([np.asarray(n, dtype=np.int64) for n in near0])
        assert segment_triangle_distance(P[:-1], P[1:], m.V, m.F, seg0, tri0).min() < r - tol

    @pytest.mark.parametrize("below, inserted", [(0.00499, False), (0.0051, True)])
    def test_long_move_just_below_the_drop_surface(self, below, inserted):
        # A 40 mm move on a plane, `below` under the drop surface everywhere: within tol/2 =
        # 0.005 it is safe but the bound only proves it on pieces of ~0.015 mm (thousands of
        # pieces: the bisection's buffers grow), beyond it the deepest point is lifted.
        m = syn.plane(size=60.0, spacing=2.0, jitter=0.0, z=0.0)
        r = 3.0
        cut = BallCutter(m.V, m.F, r)
        P = np.array([[-20.0, 0.3, r - below], [20.0, 0.7, r - below]])
        Q = cut.refine(P, 0.01)
        if inserted:
            assert len(Q) > 2
            np.testing.assert_allclose(Q[1:-1, 2], r, atol=1e-9)  # lifted onto D
        else:
            np.testing.assert_array_equal(Q, P)

    def test_nearly_flat_dome_long_move(self):
        # a 32 mm move over a very flat sphere cap, both ends on the drop surface: 93 first
        # pieces (more than the 64 the buffers start with)
        m = syn.sphere_cap(R=30000.0, radius_xy=25.0, spacing=1.0)
        cut = BallCutter(m.V, m.F, 3.0)
        xy = np.array([[-16.0, 0.37], [16.0, 0.41]])
        P = np.column_stack([xy, cut.drop(xy)])
        Q = cut.refine(P, 0.01)
        assert np.isfinite(Q).all() and _is_subsequence(P, Q)
        assert _max_dip(cut, Q) <= 0.005

    def test_piece_bound_is_the_minimum_over_the_piece(self):
        # f(t) = (1-t)(r-d0)^2 + t(r-d1)^2 - t(1-t) l^2 >= (r - tol/2)^2 for all t in [0, 1]
        from conformill.cutter import _piece_ok

        rng = np.random.default_rng(3)
        r, thr = 3.0, 0.005
        floor2 = (r - thr) ** 2
        t = np.linspace(0.0, 1.0, 20001)
        for _ in range(400):
            d0, d1 = rng.uniform(0.0, thr, 2) * rng.choice([0.0, 1.0], 2)
            ln = rng.uniform(0.0, 0.5)
            f = (1 - t) * (r - d0) ** 2 + t * (r - d1) ** 2 - t * (1 - t) * ln * ln
            brute = f.min() >= floor2
            if abs(f.min() - floor2) > 1e-9:  # away from the tie
                assert _piece_ok(r, d0, d1, ln * ln, floor2) == brute

    def test_flat_needs_nothing_and_short_inputs(self):
        m = syn.plane(size=50.0, spacing=5.0, jitter=0.2, z=1.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        P = np.array([[-20.0, -20, 5], [20, 20, 5], [20, -20, 5]])
        np.testing.assert_array_equal(cut.refine(P, 0.01), P)
        np.testing.assert_array_equal(cut.refine(P[:1], 0.01), P[:1])

    def test_bad_tolerance(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        with pytest.raises(PlanningError, match="tolerance must be positive"):
            cut.refine(np.zeros((2, 3)), 0.0)

    @pytest.mark.parametrize("kw, match", [(dict(max_depth=41), "max_depth"), (dict(max_depth=-1), "max_depth"),
                                           (dict(max_depth=2.5), "max_depth"), (dict(max_points=-1), "max_points"),
                                           (dict(max_points=1.5), "max_points")])
    def test_bad_limits(self, kw, match):
        # beyond 40 levels the halved pieces' ends stop being distinct floats
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        P = np.array([[-5.0, 0.0, R_BALL], [5.0, 0.0, R_BALL]])
        with pytest.raises(PlanningError, match=match):
            cut.refine(P, 0.01, **kw)
        with pytest.raises(PlanningError, match=match):
            cut.refine_pieces([P], 0.01, **kw)

    def test_deepest_limit_is_accepted(self):
        # max_depth 40 (the limit): a move 1e-7 mm inside tol/2 below a plane needs about
        # eight levels below L_safe, so the deepest limit proves it as the default does
        m = syn.plane(size=60.0, spacing=2.0, jitter=0.0, z=0.0)
        cut = BallCutter(m.V, m.F, 3.0)
        P = np.array([[-5.0, 0.3, 3.0 - 0.0049999], [5.0, 0.7, 3.0 - 0.0049999]])
        np.testing.assert_array_equal(cut.refine(P, 0.01, max_depth=40), P)
        np.testing.assert_array_equal(cut.refine(P, 0.01), P)


# ----------------------------------------------------------------------------- settle (float above D)


def _max_float(cut, P, n=64):
    """Largest height of the moves of ``P`` above the drop surface (``n`` points per move)."""
    t = np.arange(1, n) / n
    Q = P[:-1, None, :] + t[None, :, None] * np.diff(P, axis=0)[:, None, :]
    D = cut.drop(Q[:, :, :2].reshape(-1, 2)).reshape(Q.shape[:2])
    return float(np.max(Q[:, :, 2] - D))


class TestSettle:
    def test_v_groove_crease_in_one_point(self):
        # The ball rests on one wall of z = |x| tan(a): D(x) = |x| tan(a) + r / cos(a), a V
        # with its crease at x = 0 where the ball sits wedged. A move from x = -1 to 1.5
        # floats 1.2 tan(a) above it there; the crease is found exactly (the tangent lines
        # of D at the ends, the walls' offsets, meet on it), one point, and nothing floats
        # any more.
        a = np.radians(30.0)
        m = syn.v_groove()
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.array([-1.0, 1.5])
        P = np.column_stack([x, [2.0, 2.0], np.abs(x) * np.tan(a) + R_BALL / np.cos(a)])
        np.testing.assert_allclose(cut.drop(P[:, :2]), P[:, 2], atol=1e-12)
        assert _max_float(cut, P, n=65) == pytest.approx(1.2 * np.tan(a), rel=1e-9)  # x = 0 is the 26th point
        Q, n, left = cut.settle(P, 0.005)
        assert n == 1 and len(Q) == 3 and left == 0
        np.testing.assert_array_equal(Q[[0, 2]], P)
        np.testing.assert_allclose(Q[1], [0.0, 2.0, R_BALL / np.cos(a)], atol=1e-9)
        assert _max_float(cut, Q) <= 1e-9

    @pytest.mark.parametrize("x0, x1", [(-0.9, 2.1), (-2.1, 0.9), (-0.3, 2.7), (-2.7, 0.3), (-0.05, 2.95)])
    def test_v_groove_crease_off_the_middle(self, x0, x1):
        # the tangent lines of D at the ends (the two walls' planes) meet on the crease
        # wherever it lies on the move (t = 0.3, 0.7, 0.1, 0.9, 0.017): one drop, one point
        a = np.radians(30.0)
        m = syn.v_groove()
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.array([x0, x1])
        P = np.column_stack([x, [-3.0, -3.0], np.abs(x) * np.tan(a) + R_BALL / np.cos(a)])
        Q, n, left = cut.settle(P, 0.005, steps=1)
        assert n == 1 == len(Q) - 2 and left == 0
        np.testing.assert_allclose(Q[1], [0.0, -3.0, R_BALL / np.cos(a)], atol=1e-9)
        assert _max_float(cut, Q) <= 1e-9

    def test_move_over_a_gap_is_left_alone(self):
        # a move from one plate to another across a gap wider than the ball: D is -inf in
        # the gap, nothing to lower the move onto
        m1 = syn.plane(size=20.0, spacing=2.0)
        V2 = m1.V + [30.0, 0.0, 0.0]
        V = np.vstack([m1.V, V2])
        F = np.vstack([m1.F, m1.F + len(m1.V)])
        cut = BallCutter(V, F, R_BALL)
        P = np.array([[5.0, 0.0, R_BALL], [25.0, 0.0, R_BALL]])
        assert not np.isfinite(cut.drop(np.array([[15.0, 0.0]])))[0]
        Q, n, left = cut.settle(P, 0.01)
        assert n == 0 and left == 0
        np.testing.assert_array_equal(Q, P)

    @pytest.mark.parametrize("tol", [0.01, 0.002])
    def test_trough_floats_at_most_tol(self, tol):
        # a trough of radius 12 (wider than the ball): D is a circle of radius 8, and a chord
        # of length l floats l^2 / 64 above it; zigzag rows across it with 3 mm steps
        m = syn.cylinder_patch(R=12.0, length=30.0, half_angle=0.8, spacing=0.5, concave=True)
        cut = BallCutter(m.V, m.F, R_BALL)
        y = np.arange(-4.5, 4.51, 3.0)
        xy = np.vstack([np.column_stack([np.full_like(y, x), y if k % 2 == 0 else y[::-1]])
                        for k, x in enumerate((-6.0, -2.0, 2.0))])
        P = np.column_stack([xy, cut.drop(xy)])
        assert _max_float(cut, P) > 0.1
        Q, n, left = cut.settle(P, tol, max_iter=20)
        assert n == len(Q) - len(P) > 0 and _is_subsequence(P, Q) and left == 0
        np.testing.assert_allclose(cut.drop(Q[:, :2]), Q[:, 2], atol=1e-9)  # inserted points on D
        assert _max_float(cut, Q) <= tol
        # one round halves every floating move (a quarter of the float on a circle) and
        # reports the new moves it did not test again
        Q1, n1, left1 = cut.settle(P, tol, max_iter=1)
        assert left1 == 2 * n1 > 0
        assert _max_float(cut, Q1) < 0.3 * _max_float(cut, P)

    def test_plane_and_dome_need_nothing(self):
        # on a plane no move floats; over a dome every chord lies below D (refine's side)
        for m in (syn.plane(size=50.0, spacing=5.0, jitter=0.2, z=1.0), syn.sphere_cap(R=30.0, radius_xy=20.0)):
            cut = BallCutter(m.V, m.F, R_BALL)
            xy = np.array([[-12.0, -11], [13, 12], [12, -13], [-1, 0.5]])
            P = np.column_stack([xy, cut.drop(xy)])
            Q, n, left = cut.settle(P, 0.001)
            assert n == 0 and left == 0
            np.testing.assert_array_equal(Q, P)

    def test_short_inputs_and_bad_arguments(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        Q, n, left = cut.settle(np.array([[0.0, 0.0, 4.0]]), 0.01)
        assert n == 0 and left == 0 and Q.shape == (1, 3)
        with pytest.raises(PlanningError, match="settle tolerance must be positive"):
            cut.settle(np.zeros((2, 3)), 0.0)
        with pytest.raises(PlanningError, match="at least one step"):
            cut.settle(np.zeros((2, 3)), 0.01, steps=0)
        with pytest.raises(PlanningError, match="non-finite"):
            cut.settle(np.array([[0.0, 0.0, np.nan], [1.0, 0.0, 4.0]]), 0.01)

    @pytest.mark.parametrize("steps", [3, 2, 1])
    def test_contact_hints_change_nothing(self, steps):
        # hints are checked before their slopes are used: the right triangles (from
        # cl_from_cc), nearby wrong ones (the next centre's), far ones and none give the
        # same points, point for point (279 centres: more than one chunk of the kernels)
        m = syn.v_groove()
        cut = BallCutter(m.V, m.F, R_BALL)
        x = np.arange(-6.3, 6.0, 0.4)  # the crease x = 0 inside a move
        y = np.linspace(-8.0, 8.0, 9)
        xy = np.vstack([np.column_stack([x if k % 2 == 0 else x[::-1], np.full_like(x, yk)])
                        for k, yk in enumerate(y)])
        cc = np.column_stack([xy, np.zeros(len(xy))])
        n = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
        P, _, tri = cut.cl_from_cc(cc, n, contacts=True)
        assert len(P) > 256
        ref = cut.settle(P, 0.005, steps=steps)
        assert ref[1] > 0
        far = np.random.default_rng(4).integers(0, len(cut._T), len(P))
        for hint in (tri, np.roll(tri, 1), far, np.full(len(P), -1)):
            Q, k, left, qtri = cut.settle(P, 0.005, steps=steps, contacts=hint)
            np.testing.assert_array_equal(Q, ref[0])
            assert (k, left) == ref[1:]
            assert len(qtri) == len(Q)
        # with the right hints every output point carries the triangle it rests on
        Q, _, _, qtri = cut.settle(P, 0.005, steps=steps, contacts=tri)
        h = np.array([_tri_drop(x, yy, R_BALL, R_BALL ** 2, cut._T, t) for (x, yy, _), t in zip(Q, qtri)])
        np.testing.assert_allclose(h, Q[:, 2], atol=1e-12)

    def test_slopes_from_contacts_match_the_drop_surface(self):
        # D's slope along a move, from the contact point alone, against central differences
        # of the drop: facet, edge and vertex contacts on a jittered dome and a V-groove
        rng = np.random.default_rng(11)
        for m in (syn.sphere_cap(R=12.0, radius_xy=10.0, spacing=1.5, jitter=0.3), syn.v_groove()):
            cut = BallCutter(m.V, m.F, R_BALL)
            xy = rng.uniform(-5.0, 5.0, (400, 2))
            z, tri = cut._drop(xy, np.full(len(xy), -np.inf))
            v = rng.normal(size=(len(xy), 2))
            v /= np.linalg.norm(v, axis=1)[:, None]
            dt = 1e-6
            fd_r, fd_l = (cut.drop(xy + dt * v) - z) / dt, (z - cut.drop(xy - dt * v)) / dt
            smooth = np.abs(fd_r - fd_l) < 1e-4  # away from D's creases
            assert smooth.sum() > 300
            s = np.array([_contact_slope(x, y, zz, t, cut._T, a, b) for (x, y), zz, t, (a, b) in zip(xy, z, tri, v)])
            np.testing.assert_allclose(s[smooth], 0.5 * (fd_r + fd_l)[smooth], atol=1e-4)

    @pytest.mark.parametrize("max_iter", [4, 1])
    def test_settle_pieces_is_settle_per_piece(self, max_iter):
        # one batch gives the same points as one call per piece: rows across the V-groove's
        # crease of several lengths, a lone point, a piece without XY extent, and pieces
        # whose ends meet (the step between pieces is no move and is not settled)
        a = np.radians(30.0)
        m = syn.v_groove()
        cut = BallCutter(m.V, m.F, R_BALL)
        rng = np.random.default_rng(7)
        pieces = []
        for k in range(40):
            x = np.sort(rng.uniform(-6.0, 6.0, rng.integers(2, 12)))
            y = np.full_like(x, rng.uniform(-8.0, 8.0))
            pieces.append(np.column_stack([x, y, np.abs(x) * np.tan(a) + R_BALL / np.cos(a)]))
        pieces.insert(3, np.array([[0.5, 1.0, 9.0]]))
        pieces.insert(7, np.array([[-2.0, 0.0, 9.0], [-2.0, 0.0, 9.5]]))
        pieces.insert(9, pieces[8][::-1].copy())  # starts where the previous one ends
        pieces.insert(12, np.column_stack([[-3.0, 3.0], [-9.0, 9.0], [9.0, 9.0]]))  # ends across the crease
        pieces.insert(0, np.empty((0, 3)))  # empty pieces, first and last
        pieces.append(np.empty((0, 3)))
        got, n, left = cut.settle_pieces(pieces, 0.005, max_iter=max_iter)
        ref = [cut.settle(p, 0.005, max_iter=max_iter) for p in pieces]
        assert len(got) == len(pieces)
        for g, (q, _, _) in zip(got, ref):
            np.testing.assert_array_equal(g, q)
        assert n == sum(x[1] for x in ref) > 0 and left == sum(x[2] for x in ref)
        assert max_iter > 1 or left > 0
        assert cut.settle_pieces([], 0.005) == ([], 0, 0)
        with pytest.raises(PlanningError, match="settle tolerance must be positive"):
            cut.settle_pieces(pieces, -1.0)

    @pytest.mark.parametrize("method", ["settle_pieces", "refine_pieces"])
    def test_pieces_checked_as_one_polyline_is(self, method):
        # the batch checks its pieces stacked; a bad piece gets the message one call on it gets
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        run = getattr(cut, method)
        good = np.array([[0.0, 0.0, 4.0], [1.0, 0.0, 4.0]])
        nan = np.array([[0.0, 0.0, 4.0], [1.0, np.nan, 4.0], [2.0, 0.0, np.inf]])
        with pytest.raises(PlanningError, match=r"centers has 2 non-finite rows \(first: row 1\)"):
            run([good, good, nan, good], 0.01)
        with pytest.raises(PlanningError, match=r"centers must be \(k, 3\), got shape \(3,\)"):
            run([good, good[0], nan], 0.01)
        with pytest.raises(PlanningError, match=r"centers must be \(k, 3\), got shape \(2, 2\)"):
            run([good, good[:, :2]], 0.01)
        # integers are points too, as for one polyline
        out = run([good.astype(int), good], 0.01)
        np.testing.assert_array_equal((out[0] if method == "settle_pieces" else out)[0], good)

    def test_contacts_of_short_inputs(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        Q, n, left, tri = cut.settle(np.array([[0.0, 0.0, 4.0]]), 0.01, contacts=[3])
        assert Q.shape == (1, 3) and tri.tolist() == [3] and n == left == 0
        Q, n, left, tri = cut.settle(np.empty((0, 3)), 0.01, contacts=[])
        assert Q.shape == (0, 3) and tri.shape == (0,)
        hint = np.array([2, 5])
        _, _, _, tri = cut.settle(np.array([[0.0, 0.0, 4.0], [1.0, 0.0, 4.0]]), 0.01, contacts=hint)
        tri[0] = 7
        assert hint[0] == 2  # a copy, not the caller's array

    def test_bad_contacts_are_refused(self):
        m = syn.plane(size=20.0, spacing=5.0)
        cut = BallCutter(m.V, m.F, R_BALL)
        P = np.array([[0.0, 0.0, 4.0], [1.0, 0.0, 4.0]])
        with pytest.raises(PlanningError, match="one per centre"):
            cut.settle(P, 0.01, contacts=[0])
        with pytest.raises(PlanningError, match="one per centre"):
            cut.settle(P, 0.01, contacts=[0.5, 1.0])
        with pytest.raises(PlanningError, match="not triangles of this cutter.*centre 1"):
            cut.settle(P, 0.01, contacts=[0, len(cut._T)])
        with pytest.raises(PlanningError, match="not triangles of this cutter.*centre 0"):
            cut.settle(P, 0.01, contacts=[-2, 0])

    def test_reaches_agrees_with_the_drop(self):
        m = syn.freeform_patch(spacing=2.0, jitter=0.3)
        cut = BallCutter(m.V, m.F, 3.0)
        xy = np.random.default_rng(5).uniform(-45, 45, (4000, 2))
        D = cut.drop(xy)
        z = D + np.random.default_rng(6).uniform(-0.01, 0.01, len(xy))
        z[~np.isfinite(D)] = 0.0
        far = np.abs(z - D) > 1e-6  # away from the tie
        np.testing.assert_array_equal(cut._reaches(xy, z)[far], (D >= z)[far])
        # hints: the contacts themselves, the next point's (near, wrong), random ones
        _, tri = cut._drop(xy, np.full(len(xy), -np.inf))
        plain = cut._reaches(xy, z)
        for wa, wb in ((tri, tri), (np.roll(tri, 1), np.roll(tri, -1)),
                       np.random.default_rng(7).integers(-1, len(cut._T), (2, len(xy)))):
            np.testing.assert_array_equal(cut._reaches(xy, z, wa, wb), plain)
            # and the drop heights themselves (the second hint raises the floor)
            np.testing.assert_array_equal(cut._drop(xy, np.full(len(xy), -np.inf), wa, wb)[0], D)


def test_tip_is_centre_minus_r():
    m = syn.plane(size=20.0, spacing=5.0)
    cut = BallCutter(m.V, m.F, 2.5)
    C = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.testing.assert_array_equal(cut.tip(C), C - [0, 0, 2.5])
    np.testing.assert_array_equal(C, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])  # not mutated


# ----------------------------------------------------------------------------- bad inputs


class TestBadInputs:
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    F = np.array([[0, 1, 2]])

    def test_vertices_shape(self):
        with pytest.raises(MeshError, match=r"vertices must be \(n, 3\)"):
            BallCutter(self.V[:, :2], self.F, 1.0)

    def test_faces_shape_and_empty(self):
        with pytest.raises(MeshError, match=r"faces must be \(m, 3\)"):
            BallCutter(self.V, np.zeros((0, 3), dtype=np.int64), 1.0)

    def test_faces_not_integer(self):
        with pytest.raises(MeshError, match="integers"):
            BallCutter(self.V, self.F.astype(float), 1.0)

    def test_index_out_of_range(self):
        with pytest.raises(MeshError, match=r"face 1 .*out of range"):
            BallCutter(self.V, np.array([[0, 1, 2], [0, 1, 3]]), 1.0)

    def test_nonfinite_vertex(self):
        V = self.V.copy()
        V[2, 1] = np.nan
        with pytest.raises(MeshError, match="vertex 2"):
            BallCutter(V, self.F, 1.0)

    @pytest.mark.parametrize("r", [0.0, -1.0, np.inf, np.nan])
    def test_radius(self, r):
        with pytest.raises(PlanningError, match="radius must be positive"):
            BallCutter(self.V, self.F, r)

    def test_query_shape(self):
        cut = BallCutter(self.V, self.F, 1.0)
        with pytest.raises(PlanningError, match=r"xy must be \(k, 2\)"):
            cut.drop(np.zeros((3, 3)))
        with pytest.raises(PlanningError, match="non-finite"):
            cut.drop(np.array([[0.0, np.inf]]))
