"""The 3D spacing check where its shrinks stall (patterns.family.Planner._bisect_step, and
the spiral's twin in patterns.spiral).

A shrink scales the step by the ratio the check measured. Where the next path's own allowed
interval shrinks as the path moves back, twelve shrinks could leave it still too far (the
620k igea mesh, zigzag: ratio 1.016). Here the check is made to stall on purpose: for the
first path, any step beyond a set fraction of the first try is reported 2 % too far, which
the shrinks (at most 2.5 % each) cannot clear in twelve tries. The spiral tries 24 times
before its fallback: the first twelve shrink the next revolution's span where the worst
sample lies late enough in the revolution for that to mend it (its own span otherwise),
the last twelve shrink its own span.
"""

import logging

import numpy as np
import pytest

from conformill.mesh import synthetic
from conformill.patterns import family
from conformill.pipeline import Job, plan


@pytest.fixture(scope="module")
def cap():
    return synthetic.sphere_cap(R=50.0, radius_xy=20.0, spacing=2.0)


def _stall(monkeypatch, limit):
    """Make the check of the first path report every sample 2 % too far for any step
    beyond ``limit`` times its first try (the step keyed on the new curve's lowest level);
    returns the list of ``(a.s, b.s, ratio)`` the check gave. Both planners' checks go
    through :func:`family.pair_distances_both`."""
    real = family.pair_distances_both
    calls = []

    def stalled(a, b, closed=False):
        d_fwd, d_bwd = real(a, b, closed)
        s0, base = (calls[0][0], calls[0][1] - calls[0][0]) if calls else (a.s, b.s - a.s)
        if a.s == s0 and b.s - a.s > limit * base * (1 + 1e-12):
            d_fwd = np.maximum(d_fwd, 1.02 * a.ls)
        calls.append((a.s, b.s, max(np.max(d_fwd / a.ls), np.max(d_bwd / b.ls))))
        return d_fwd, d_bwd

    monkeypatch.setattr(family, "pair_distances_both", stalled)
    return calls


def _second_step(calls):
    """The first path's first try and the step to where the second path lies."""
    s0, base = calls[0][0], calls[0][1] - calls[0][0]
    return s0, base, next(c[0] for c in calls if c[0] != s0) - s0


@pytest.mark.parametrize("pattern", ["zigzag", "contour"])
def test_a_stalled_check_is_bisected_to_the_largest_passing_step(cap, pattern, monkeypatch, caplog):
    calls = _stall(monkeypatch, 0.6)
    with caplog.at_level(logging.WARNING, logger="conformill"):
        res = plan(cap, Job(pattern=pattern, tool_radius=4.0, scallop=0.01, tolerance=0.01))
    assert "did not converge" not in caplog.text
    s0, base, step = _second_step(calls)
    assert sum(c[0] == s0 for c in calls) > 12  # the twelve shrinks did not clear it
    # the largest passing step, to the bisection's precision (8 halvings of the last try)
    assert 0.6 * base * (1 - 2.0 ** -7) <= step <= 0.6 * base * (1 + 1e-9)
    assert any(c[:2] == (s0, s0 + step) and c[2] <= 1.0 + 1e-9 for c in calls)
    assert res.report["paths"]["cl_points"] > 0


def test_a_step_failing_down_to_a_small_fraction_is_halved_then_bisected(cap, monkeypatch):
    calls = _stall(monkeypatch, 0.05)
    plan(cap, Job(pattern="zigzag", tool_radius=4.0, scallop=0.01, tolerance=0.01))
    _, base, step = _second_step(calls)
    assert 0.05 * base * (1 - 2.0 ** -7) <= step <= 0.05 * base * (1 + 1e-9)


def test_without_a_stall_the_bisection_is_not_entered(cap, monkeypatch):
    """Where twelve shrinks suffice (every benchmark part at h = 0.01), the rows are the
    same as before the bisection existed."""
    entered = []
    real = family.Planner._bisect_step
    monkeypatch.setattr(family.Planner, "_bisect_step", lambda *a, **k: entered.append(1) or real(*a, **k))
    plan(cap, Job(pattern="zigzag", tool_radius=4.0, scallop=0.01, tolerance=0.01))
    assert not entered


def test_local_spacing_bisects_a_stalled_check_too(cap, monkeypatch, caplog):
    """``--spacing local`` (:meth:`Planner.run_local`): its curves are profiles, so the
    stall is keyed on the lowest level."""
    calls = _stall(monkeypatch, 0.6)
    with caplog.at_level(logging.WARNING, logger="conformill"):
        plan(cap, Job(pattern="zigzag", tool_radius=4.0, scallop=0.01, tolerance=0.01, spacing="local"))
    assert "did not converge" not in caplog.text
    s0, base, step = _second_step(calls)
    assert sum(c[0] == s0 for c in calls) > 12
    assert 0.5 * base <= step <= 0.6 * base * (1 + 1e-9)


def _stall_spiral(monkeypatch, limit):
    """The spiral's twin of :func:`_stall`: the check of the first revolution pair it
    tries reports every sample 2 % too far for any ``E`` (the next revolution's span of
    levels) beyond ``limit`` times the first ``E`` tried, whatever that revolution's own
    replanned span. The excess grows a little along the revolution, so the worst sample
    lies at its end, where a smaller ``E`` can mend it: the first twelve tries shrink ``E``.
    Returns the list of ``(a0, D, E, ratio)`` the check gave (``D``: the span of the
    revolution checked, ``E``: that of the next)."""
    from conformill.patterns import spiral
    from conformill.patterns.domains import SpiralTurn

    spans = {}  # id of an evaluated revolution -> (the curve, kept alive, r0, r1)
    real_eval = family.Planner.evaluate

    def evaluate(self, fam, s, *a, **k):
        c = real_eval(self, fam, s, *a, **k)
        if isinstance(fam, SpiralTurn):
            spans[id(c)] = (c, fam.r0, fam.r1)
        return c

    real = spiral.pair_distances
    calls = []

    def stalled(a, b, closed=False):
        d_fwd, ratio = real(a, b, closed)
        if id(a) not in spans or id(b) not in spans:  # the centre or the boundary turn
            return d_fwd, ratio
        (_, a0, a1), (_, b0, b1) = spans[id(a)], spans[id(b)]
        E = b1 - b0
        if calls and a0 == calls[0][0] and E > limit * calls[0][2] * (1 + 1e-12):
            d_fwd = np.maximum(d_fwd, 1.02 * a.ls * (1.0 + 1e-6 * a.tau))
            ratio = max(ratio, float(np.max(d_fwd / a.ls)))
        calls.append((a0, a1 - a0, E, ratio))
        return d_fwd, ratio

    monkeypatch.setattr(family.Planner, "evaluate", evaluate)
    monkeypatch.setattr(spiral, "pair_distances", stalled)
    return calls


def test_a_stalled_spiral_check_is_bisected_to_the_largest_passing_gap(cap, monkeypatch, caplog):
    """24 failures (twelve shrinks of ``E``, then twelve of ``D``) leave an untested ``E``;
    it is halved, then bisected, to the largest that passes, and that revolution is the
    one taken. Before, the spiral warned and took the untested ``E`` (here 2 % too far by
    construction)."""
    calls = _stall_spiral(monkeypatch, 0.05)
    with caplog.at_level(logging.WARNING, logger="conformill"):
        res = plan(cap, Job(pattern="spiral", tool_radius=4.0, scallop=0.01, tolerance=0.01))
    assert "did not converge" not in caplog.text
    a0, D0, E0 = calls[0][:3]
    first = [c for c in calls if c[0] == a0]
    assert len(first) > 25  # 24 failed tries, then at least two of the fallback
    assert all(c[3] > 1.0 + 1e-9 for c in first[:24])
    # both kinds of shrink ran: E alone (D kept), then D (the revolution planned closer)
    e_only = sum(b[1] == a[1] and b[2] < a[2] for a, b in zip(first[:23], first[1:24]))
    assert e_only >= 11 and first[23][1] < D0
    passing = [c[2] for c in first if c[3] <= 1.0 + 1e-9]
    E = max(passing)
    assert 0.05 * E0 * (1 - 2.0 ** -8) <= E <= 0.05 * E0 * (1 + 1e-9)
    taken = next(c for c in calls if c[0] != a0)  # the next pair starts from the revolution taken
    assert taken[1] == E
    assert res.report["paths"]["cl_points"] > 0


def test_a_spiral_gap_that_never_passes_takes_the_best_tried_and_warns(cap, monkeypatch, caplog):
    """Where no ``E`` passes (here every one is reported 2 % too far), the fault lies where
    ``E`` cannot mend it: the spiral warns and takes the revolution tried with the lowest
    ratio, of equal ratios the smallest ``E``, not the untested ``E`` of the last try."""
    calls = _stall_spiral(monkeypatch, 0.0)
    with caplog.at_level(logging.WARNING, logger="conformill"):
        plan(cap, Job(pattern="spiral", tool_radius=4.0, scallop=0.01, tolerance=0.01))
    assert "spiral spacing check did not converge" in caplog.text
    a0 = calls[0][0]
    first = [c for c in calls if c[0] == a0]
    fallback = first[24:]
    assert len(fallback) > 10 and all(c[3] > 1.0 + 1e-9 for c in fallback)
    taken = next(c for c in calls if c[0] != a0)
    assert taken[1] == min(c[2] for c in fallback) < fallback[0][2]
