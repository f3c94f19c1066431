"""The planner's estimate of the pattern's rest (conformill.pattern_rest): the distance
bound against a plane's exact rest, against brute force, and its edge cases."""

from __future__ import annotations

import numpy as np
import pytest

import conformill.pattern_rest as pr
from conformill.pattern_rest import centre_moves, uncut_beyond

R = 4.0


def _brute(Q, A, B):
    """Distance from each point to the nearest segment A -> B (numpy, all pairs)."""
    v = B - A
    L2 = (v * v).sum(1)
    out = []
    for q in Q:
        w = q - A
        t = np.clip((w * v).sum(1) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        d = w - t[:, None] * v
        out.append(np.sqrt((d * d).sum(1)).min())
    return np.array(out)


def _scattered(seed, passes, per_pass, n):
    """Centre moves ``A, B`` of ``passes`` random tip passes of ``per_pass`` points over
    16 x 12 mm, and ``n`` random points around them (seeded)."""
    rng = np.random.default_rng(seed)
    tips = [np.column_stack([rng.uniform(-8, 8, per_pass), rng.uniform(-6, 6, per_pass),
                             rng.uniform(-1, 1, per_pass)]) for _ in range(passes)]
    A, B = centre_moves(tips, R)
    P = np.column_stack([rng.uniform(-10, 10, n), rng.uniform(-8, 8, n), rng.uniform(-2, 6, n)])
    return A, B, P


def test_a_pass_over_a_plane_leaves_the_circle_s_rest():
    # one pass along X over the plane z = 0, tip on the plane: at lateral distance y the
    # ball leaves sqrt(y^2 + r^2) - r, the exact rest (the bound is exact on a plane)
    tips = [np.column_stack([np.linspace(-10, 10, 41), np.zeros(41), np.zeros(41)])]
    A, B = centre_moves(tips, R)
    np.testing.assert_array_equal(A[:, 2], R)
    y = np.linspace(0.0, 3.0, 301)
    Q = np.column_stack([np.zeros_like(y), y, np.zeros_like(y)])
    rest = np.sqrt(y * y + R * R) - R
    for depth in (0.0, 0.01, 0.1, 0.5):
        away = np.abs(rest - depth) > 1e-9
        got = uncut_beyond(Q, A, B, R, depth)
        np.testing.assert_array_equal(got[away], rest[away] > depth)
    # past the pass's ends the distance is to its end point
    Q2 = np.array([[10.0 + 2.0, 0.0, 0.0], [10.0 + 0.2, 0.0, 0.0]])
    np.testing.assert_array_equal(uncut_beyond(Q2, A, B, R, 0.01), np.hypot([2.0, 0.2], R) - R > 0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_agrees_with_brute_force(seed):
    # zigzag rows over a wavy part (moves of mixed length and slope, some long ones across
    # many cells), points near and far: the grid's pruning loses no move
    rng = np.random.default_rng(seed)
    tips = []
    for k, y in enumerate(np.arange(-8.0, 8.0, 0.7)):
        x = np.sort(rng.uniform(-10, 10, rng.integers(3, 40)))
        x = x if k % 2 else x[::-1]
        tips.append(np.column_stack([x, y + 0.05 * rng.standard_normal(len(x)), np.sin(0.3 * x) + 0.2 * y]))
    A, B = centre_moves(tips, R)
    Q = np.column_stack([rng.uniform(-14, 14, 3000), rng.uniform(-12, 12, 3000), rng.uniform(-3, 6, 3000)])
    d = _brute(Q, A, B)
    for depth in (0.0, 0.02, 1.5):
        away = np.abs(d - R - depth) > 1e-9
        got = uncut_beyond(Q, A, B, R, depth)
        assert 0 < got.sum() < len(Q)
        np.testing.assert_array_equal(got[away], (d > R + depth)[away])


def test_rows_nan_and_empty():
    tips = [np.column_stack([np.linspace(-5, 5, 11), np.zeros(11), np.zeros(11)])]
    A, B = centre_moves(tips + [np.zeros((1, 3))], R)  # a one-point pass has no move
    assert len(A) == 10
    near, far = [0.0, 0.1, 0.0], [0.0, 3.0, 0.0]
    Q = np.array([[near, near], [near, far], [far, near], [near, [np.nan, 0.0, 0.0]]])
    np.testing.assert_array_equal(uncut_beyond(Q, A, B, R, 0.01), [False, True, True, True])
    np.testing.assert_array_equal(uncut_beyond(np.array([near, far]), A, B, R, 0.01), [False, True])
    # no moves at all: everything is uncut; no points: nothing
    np.testing.assert_array_equal(uncut_beyond(np.array([near]), *centre_moves([], R), R, 0.01), [True])
    assert uncut_beyond(np.zeros((0, 3)), A, B, R, 0.01).shape == (0,)


@pytest.mark.parametrize("cap", [1, 50])
def test_a_coarser_grid_gives_the_same_answers(monkeypatch, cap):
    # the cells grow to keep about _MAX_CELLS of them (large parts): the same answers
    A, B, P = _scattered(5, 6, 30, 2000)
    want = uncut_beyond(P, A, B, R, 0.05)
    assert 0 < want.sum() < len(P)
    monkeypatch.setattr(pr, "_MAX_CELLS", cap)
    np.testing.assert_array_equal(uncut_beyond(P, A, B, R, 0.05), want)


def test_a_long_diagonal_move_fills_only_the_cells_it_crosses():
    # a move is walked a cell at a time: a 700 mm diagonal enters about 3 x 1400 cells, not
    # the 1400^2 of its box; its far end still counts
    A, B = np.array([[0.0, 0.0, R]]), np.array([[500.0, 500.0, R]])
    start, item, zlo, zhi = pr._bin(A, B, 0.0, 0.0, 0.5, 1001, 1001)
    assert len(item) < 4 * 1414 and start[-1] == len(item)
    Q = np.array([[500.0, 500.0, 0.0], [250.0, 250.0, 0.0], [250.0, 251.0, 0.0]])
    np.testing.assert_array_equal(uncut_beyond(Q, A, B, R, 0.01), [False, False, True])


@pytest.mark.parametrize("radius, depth", [(0.0, 0.01), (-1.0, 0.01), (R, -0.01), (R, np.nan), (np.inf, 0.0)])
def test_bad_values(radius, depth):
    A, B = centre_moves([np.zeros((2, 3)) + [[0, 0, 0], [1, 0, 0]]], 1.0)
    with pytest.raises(ValueError, match="radius must be finite and positive"):
        uncut_beyond(np.zeros((1, 3)), A, B, radius, depth)


def test_moves_that_are_not_finite_are_named():
    A, B = centre_moves([np.array([[0.0, 0, 0], [1, 0, 0], [np.nan, 0, 0], [3, 0, 0]])], 1.0)
    with pytest.raises(ValueError, match=r"move ends A must be finite; not at rows \[2\]"):
        uncut_beyond(np.zeros((1, 3)), A, B, 1.0, 0.01)


@pytest.mark.parametrize("parts", [2, 3, 7])
def test_moves_handed_over_in_parts_give_the_same_answers(parts):
    # UncutRows: the moves in parts (a pass split anywhere, as the pipeline hands over the
    # passes cut so far), rows of three points some of them NaN: the same rows as one call,
    # and as brute force
    rng = np.random.default_rng(parts)
    tips = [np.column_stack([rng.uniform(-8, 8, 40), rng.uniform(-6, 6, 40), rng.uniform(-1, 1, 40)])
            for _ in range(5)]
    A, B = centre_moves(tips, R)
    Q = np.column_stack([rng.uniform(-10, 10, 3000), rng.uniform(-8, 8, 3000),
                         rng.uniform(-2, 6, 3000)]).reshape(1000, 3, 3)
    Q[rng.random(1000) < 0.05, 2] = np.nan
    want = uncut_beyond(Q, A, B, R, 0.05)
    d = _brute(np.nan_to_num(Q.reshape(-1, 3), nan=1e6), A, B).reshape(1000, 3)
    np.testing.assert_array_equal(want, (d > R + 0.05).any(axis=1))
    assert 0 < want.sum() < len(Q)
    cuts = np.sort(rng.choice(np.arange(1, len(A)), parts - 1, replace=False))
    rows = pr.UncutRows(Q, R, 0.05)
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(A)]):
        rows.add(A[a:b], B[a:b])
        rows.add(A[:0], B[:0])  # nothing: no change
    np.testing.assert_array_equal(rows.uncut(), want)


@pytest.mark.parametrize("parts", [1, 4])
def test_a_point_repeated_in_its_row_is_answered_as_one(parts):
    # a steep centre's sample fills every slot of its row (conformill.pencil): the row is
    # uncut exactly when the point is, whether the moves come at once or in parts, and
    # mixed with rows of distinct points
    A, B, P = _scattered(7, 5, 40, 2000)
    one = uncut_beyond(P, A, B, R, 0.05)
    assert 0 < one.sum() < len(P)
    Q = np.repeat(P[:, None], 3, axis=1)
    Q[1::2, 2] = P[::-1][1::2]  # every other row ends with another point
    d = _brute(Q.reshape(-1, 3), A, B).reshape(-1, 3)
    want = (d > R + 0.05).any(axis=1)
    np.testing.assert_array_equal(want[::2], one[::2])
    rows = pr.UncutRows(Q, R, 0.05)
    cuts = np.linspace(0, len(A), parts + 1).astype(int)
    for a, b in zip(cuts[:-1], cuts[1:]):
        rows.add(A[a:b], B[a:b])
    np.testing.assert_array_equal(rows.uncut(), want)


def test_rows_before_any_moves_are_uncut():
    rows = pr.UncutRows(np.zeros((4, 2, 3)), R, 0.01)
    np.testing.assert_array_equal(rows.uncut(), [True] * 4)
    with pytest.raises(ValueError, match="as many move starts as ends"):
        rows.add(np.zeros((2, 3)), np.zeros((1, 3)))


@pytest.mark.parametrize("kind", ["row", "point", "nan", "far"])
def test_hints_change_the_order_not_the_answer(kind):
    # the hint only says which cells a point reads first: per row, per point, NaN (none) or
    # far off the part, the same rows as brute force, in parts as in one call
    rng = np.random.default_rng(7)
    tips = [np.column_stack([rng.uniform(-8, 8, 60), rng.uniform(-6, 6, 60), rng.uniform(-1, 1, 60)])
            for _ in range(6)]
    A, B = centre_moves(tips, R)
    Q = np.column_stack([rng.uniform(-10, 10, 1500), rng.uniform(-8, 8, 1500),
                         rng.uniform(-2, 3, 1500)]).reshape(500, 3, 3)
    d = _brute(Q.reshape(-1, 3), A, B).reshape(500, 3)
    want = (d > R + 0.05).any(axis=1)
    assert 0 < want.sum() < len(Q)
    H = {"row": Q[:, 0, :2] + rng.normal(0, 2, (500, 2)),
         "point": Q[:, :, :2] + rng.normal(0, 2, (500, 3, 2)),
         "nan": np.full((500, 2), np.nan),
         "far": np.full((500, 3, 2), 1e6)}[kind]
    np.testing.assert_array_equal(uncut_beyond(Q, A, B, R, 0.05, hints=H), want)
    rows = pr.UncutRows(Q, R, 0.05, hints=H)
    rows.add(A[:100], B[:100])
    rows.add(A[100:], B[100:])
    np.testing.assert_array_equal(rows.uncut(), want)


def test_hints_of_the_wrong_shape_are_refused():
    with pytest.raises(ValueError, match=r"hints must be \(4, 2\) or \(4, 2, 2\)"):
        pr.UncutRows(np.zeros((4, 2, 3)), R, 0.01, hints=np.zeros((3, 2)))


@pytest.mark.parametrize("parts", [1, 3])
def test_moves_binned_once_serve_rows_of_one_and_of_three_points(parts):
    # the pipeline bins the pattern's moves once (move_grid) and hands the grid to the
    # pencil's filter (rows of three probes) and to the fill (one sample a row): each gives
    # what its own add() of the same moves gives, and brute force
    A, B, P = _scattered(11, 6, 40, 3000)
    Q3 = P.reshape(1000, 3, 3)
    cuts = np.linspace(0, len(A), parts + 1).astype(int)
    one, three = pr.UncutRows(P, R, 0.05), pr.UncutRows(Q3, R, 0.05)
    for a, b in zip(cuts[:-1], cuts[1:]):
        g = pr.move_grid(A[a:b], B[a:b])
        one.add_grid(g)
        three.add_grid(g)
    d = _brute(P, A, B)
    np.testing.assert_array_equal(one.uncut(), d > R + 0.05)
    np.testing.assert_array_equal(three.uncut(), (d.reshape(1000, 3) > R + 0.05).any(axis=1))
    assert 0 < one.uncut().sum() < len(P)
    empty = pr.move_grid(A[:0], B[:0])  # nothing: no change
    one.add_grid(empty)
    np.testing.assert_array_equal(one.uncut(), d > R + 0.05)


def test_move_grid_refuses_what_add_refuses():
    A, B, _ = _scattered(2, 2, 5, 1)
    with pytest.raises(ValueError, match="as many move starts as ends"):
        pr.move_grid(A, B[:-1])
    B[3, 1] = np.inf
    with pytest.raises(ValueError, match=r"move ends B must be finite; not at rows \[3\]"):
        pr.move_grid(A, B)
