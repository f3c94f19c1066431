"""Folds of the drop surface: the wedged ball of a V-groove and of a conical pit, none on
smooth convex parts, every fold point on the drop surface with a contact on each side,
the shadow against the rest of the per-sample search, and bad values."""

from __future__ import annotations

import numpy as np
import pytest

from conformill.cutter import BallCutter
from conformill.errors import PlanningError
from conformill.folds import fold_points, wedge_jump
from conformill.mesh import synthetic as syn

R = 4.0
A = np.radians(8.0)


def _bumpy():
    outline = np.array([[-15.0, -15.0], [15.0, -15.0], [15.0, 15.0], [-15.0, 15.0]])
    return syn.height_field(outline, lambda x, y: 0.6 * np.sin(0.9 * x) * np.sin(0.8 * y) + 0.02 * x * y,
                            0.6, jitter=0.15, seed=2)


def test_wedge_jump_is_the_chord_of_the_wedged_ball():
    # a V of half-angle pi/2 - a: the ball touches both planes 2 r sin(a) apart and its
    # underside is r (1 / cos a - 1) above the crease
    for a in np.radians([1.0, 8.0, 30.0, 60.0]):
        assert wedge_jump(R, R * (1 / np.cos(a) - 1)) == pytest.approx(2 * R * np.sin(a), rel=1e-12)
    assert wedge_jump(R, 0.0) == 0.0


def test_v_groove_folds_lie_on_the_crease_with_the_wedged_ball():
    # z = |x| tan(a): D = |x| tan(a) + r / cos(a) folds along x = 0. Away from the groove's
    # ends every grid row crosses it once: the centre (0, y, r / cos a), the contacts on the
    # walls at x = -+ r sin(a), and the shadow is the gap at the crease, r (1 / cos a - 1)
    m = syn.v_groove(a_deg=8.0, half=12.0, step=0.25)
    cut = BallCutter(m.V, m.F, R)
    s = 0.2
    fp = fold_points(cut, s, jump=0.3)
    C = fp.centres
    inner = np.abs(C[:, 1]) < 12.0 - R - 0.5
    assert inner.sum() >= int(2 * (12.0 - R - 0.5) / s) - 1
    np.testing.assert_allclose(C[inner, 0], 0.0, atol=1e-3 * s + 1e-9)
    np.testing.assert_allclose(C[inner, 2], R / np.cos(A), atol=1e-3 * s * np.tan(A) + 1e-9)
    qa, qb = fp.contact_a[inner], fp.contact_b[inner]
    np.testing.assert_allclose(np.sort(np.column_stack([qa[:, 0], qb[:, 0]]), axis=1),
                               np.tile([-R * np.sin(A), R * np.sin(A)], (inner.sum(), 1)), atol=2e-3 * s)
    np.testing.assert_allclose(fp.shadow[inner], R * (1 / np.cos(A) - 1), atol=2e-5)
    # nothing but the crease folds there (the walls are planes; the groove's ends aside)
    assert np.all(np.abs(C[np.abs(C[:, 1]) < 12.0 - R - 0.5, 0]) < 1e-3)


def test_conical_pit_folds_ring_the_apex():
    # a cone pit z = k rho (slope k = tan 8 deg) tighter than the ball: the ball sits on a
    # circle of contacts at the apex; off the axis D is again a cone, folded along no line,
    # so the fold points found lie near the apex, and the deepest shadow is the apex's gap
    k = np.tan(A)
    outline = syn.regular_polygon(64, 10.0)
    m = syn.height_field(outline, lambda x, y: k * np.hypot(x, y), 0.2, name="pit")
    cut = BallCutter(m.V, m.F, R)
    fp = fold_points(cut, 0.1, jump=0.3)
    deep = fp.shadow > 0.5 * R * (1 / np.cos(A) - 1)
    assert deep.any()
    assert np.hypot(fp.centres[deep, 0], fp.centres[deep, 1]).max() < 0.2
    assert fp.shadow.max() <= R * (1 / np.cos(A) - 1) + 1e-4  # the facets lie below the cone: not deeper


@pytest.mark.parametrize("part", [syn.plane(size=40.0, spacing=2.0),
                                  syn.sphere_cap(R=30.0, radius_xy=15.0, spacing=1.0)], ids=["plane", "dome"])
def test_none_on_smooth_convex_parts(part):
    cut = BallCutter(part.V, part.F, R)
    fp = fold_points(cut, 0.2, jump=wedge_jump(R, 0.0015))
    inner = np.all(np.abs(fp.centres[:, :2]) < 15.0 - R - 1.0, axis=1) if len(fp.centres) else np.zeros(0, bool)
    assert not inner.any() and fp.stats["grid_points"] > 1000


def test_fold_points_lie_on_the_drop_surface_between_two_contacts():
    # a bumpy part with pits tighter than the ball: each fold point is a true drop height,
    # and the ball there touches the part on both sides: each contact is r from the centre,
    # up to the crossing's resolution (1e-3 of the edge: 0.15 um, times D's slope there)
    part = _bumpy()
    cut = BallCutter(part.V, part.F, R)
    fp = fold_points(cut, 0.15, jump=0.2)
    assert len(fp.centres) > 100
    C = fp.centres
    np.testing.assert_allclose(cut.drop(C[:, :2]), C[:, 2], atol=1e-9)
    for q in (fp.contact_a, fp.contact_b):
        d = np.linalg.norm(q - C, axis=1)
        assert d.min() >= R - 1e-9 and d.max() <= R + 1e-4
    assert np.all(fp.shadow >= 0)
    # the same points whatever the thread count
    import numba

    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = fold_points(cut, 0.15, jump=0.2)
    finally:
        numba.set_num_threads(n)
    np.testing.assert_array_equal(one.centres, C)
    np.testing.assert_array_equal(one.shadow, fp.shadow)


def test_shadow_bounds_the_best_ball_of_the_per_sample_search():
    # on the bumpy part, the band centres of the per-sample search (best balls leaving 0.15-1
    # of h = 0.01) lie on folds: most within 0.1 mm of a fold point whose shadow is deeper
    # than 0.15 h (the per-sample search's centres lie on folds between the grid's crossings)
    from scipy.spatial import cKDTree

    from conformill.pencil import best_centres, surface_samples

    part = _bumpy()
    cut = BallCutter(part.V, part.F, R)
    h = 0.01
    P, N, faces = surface_samples(part.V, part.F, density=10.0, seed=1)
    inner = np.all(np.abs(P[:, :2]) < 15.0 - R, axis=1)
    C, rest, state = best_centres(cut, P[inner], N[inner], faces[inner], low=0.15 * h, give_up=1.05 * h)
    band = (state == 1) & (rest > 0.15 * h) & (rest <= h)
    assert band.sum() > 20
    fp = fold_points(cut, 1 / np.sqrt(30.0), jump=wedge_jump(R, 0.15 * h))
    d, _ = cKDTree(fp.centres[fp.shadow > 0.15 * h, :2]).query(C[band, :2])
    assert np.mean(d < 0.1) >= 0.8


def test_bad_values():
    m = syn.plane(size=10.0, spacing=2.0)
    cut = BallCutter(m.V, m.F, R)
    for kw, word in ((dict(spacing=0.0, jump=0.2), "spacing"), (dict(spacing=np.nan, jump=0.2), "spacing"),
                     (dict(spacing=0.2, jump=-1.0), "jump")):
        with pytest.raises(PlanningError, match=word):
            fold_points(cut, **kw)
    with pytest.raises(PlanningError, match="grid"):
        fold_points(cut, 1e-4, jump=0.2)
