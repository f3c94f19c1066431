"""Pieces -> passes: batching and the worker thread change nothing in the program; errors
raised in the worker reach the caller."""

from __future__ import annotations

import os
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

import conformill.pipeline as pipeline
from conformill.cutter import BallCutter
from conformill.errors import PlanningError
from conformill.mesh import synthetic
from conformill.passes import (BACKGROUND_NICE, PassBuilder, background_priority, feed_length, serial_caller,
                               threads_can_overlap)
from conformill.patterns.pieces import Piece
from conformill.pipeline import Job, plan

R = 4.0


@pytest.fixture(scope="module")
def recorded():
    """A contour plan's pieces and builder settings, recorded from the pipeline.

    The free-form patch with a V-groove cut across it (walls at 30 degrees, narrower than
    the ball), so that the settle check inserts points too."""
    from conformill.types import Mesh

    part = synthetic.freeform_patch(spacing=1.0, jitter=0.3, seed=1)
    V = part.V.copy()
    V[:, 2] -= np.maximum(3.0 - np.abs(V[:, 0] - 5.0), 0.0) * np.tan(np.radians(30.0))
    part = Mesh(V=V, F=part.F, name="grooved")
    return record_plan(part, Job(pattern="contour", tool_radius=R, scallop=0.05, tolerance=0.01))


def record_plan(part, job):
    """``(result, seen)``: ``plan(part, job)`` and what its pass builder was given:
    ``seen["args"]``, ``seen["kw"]``, ``seen["make_cutter"]``, ``seen["pieces"]``."""
    seen = {}

    class Recording(PassBuilder):
        def __init__(self, make_cutter, *args, **kw):
            super().__init__(make_cutter, *args, **kw)
            seen["args"], seen["kw"], seen["pieces"] = args, kw, []
            seen["make_cutter"] = make_cutter

        def add(self, piece):
            seen["pieces"].append(piece)
            super().add(piece)

    mp = pytest.MonkeyPatch()
    mp.setattr(pipeline, "PassBuilder", Recording)
    try:
        res = plan(part, job)
    finally:
        mp.undo()
    return res, seen


def _builder(seen, threaded, batch, link_max=None, make_cutter=None, first_batch=None, hop_lift=0.0):
    """A PassBuilder with the recorded plan's settings (``link_max``, the cutter, the first
    batch and the hop limit replaced where given), no piece handed over yet."""
    args = list(seen["args"])
    if link_max is not None:
        args[4] = link_max
    kw = {} if first_batch is None else {"first_batch": first_batch}
    if hop_lift:
        kw["hop_lift"] = hop_lift
    return PassBuilder(make_cutter or seen["make_cutter"], *args[:5], threaded=threaded, batch=batch,
                       settle_tol=seen["kw"]["settle_tol"], **kw)


def _build(seen, threaded, batch, link_max=None, first_batch=None):
    b = _builder(seen, threaded, batch, link_max, first_batch=first_batch)
    for pc in seen["pieces"]:
        b.add(pc)
    return b.finish(), b


def test_pieces_arrive_in_machining_order(recorded):
    res, seen = recorded
    kinds = [p.kind for p in seen["pieces"]]
    n = len(res.domain_paths.paths)
    assert kinds == ["path", "link"] * (n - 1) + ["path"]
    assert [p.index for p in seen["pieces"] if p.kind == "path"] == list(range(n))


@pytest.mark.parametrize("batch, first", [(1, None), (7, None), (500, None), (500, 3), (10**9, 1)])
@pytest.mark.parametrize("threaded", [False, True])
def test_batches_and_worker_give_the_same_program(recorded, batch, first, threaded):
    # batches of any size (the first ones doubling up from ``first``): the same program
    res, seen = recorded
    if threaded and not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    assert seen["kw"]["settle_tol"] > 0 and res.report["cutter"]["settled_points"] > 0
    (passes, ids, lifts, _), builder = _build(seen, threaded, batch, first_batch=first)
    b_done = builder._done
    assert builder.n_settled == res.report["cutter"]["settled_points"]
    assert ids == res.toolpath.pass_ids
    assert len(passes) == len(res.toolpath.passes)
    for a, b in zip(passes, res.toolpath.passes):
        assert np.array_equal(a, b)
    (_, _, whole_lifts, _), _ = _build(seen, False, 10**9)
    assert np.array_equal(np.concatenate(lifts), np.concatenate(whole_lifts))
    # the hint handed to the next batch is the triangle the last centre rests on
    from conformill.cutter import _tri_drop

    for p in b_done:
        assert p.last_tri >= 0
        assert _tri_drop(p.last[0], p.last[1], R, R * R, builder.cutter._T, p.last_tri) == p.last[2]
    # every path's CC points are cut, and the inner points of every link
    assert len(np.concatenate(lifts)) >= sum(len(c) for c in res.cc_paths)


@pytest.mark.parametrize("link_max", [None, 1e-6])
@pytest.mark.parametrize("threaded", [False, True])
def test_progress_of_the_cutter(recorded, threaded, link_max):
    """finish(progress) reports the share cut: in [0, 1], non-decreasing, last 1.0, with
    every piece counted once (retracted links too); the program is the same without it."""
    if threaded and not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    _, seen = recorded
    b = _builder(seen, threaded, 500, link_max)
    assert b.fraction_cut() == 1.0  # nothing handed over yet
    for pc in seen["pieces"]:
        b.add(pc)
    got = []
    passes, ids, _, _ = b.finish(progress=got.append)
    f = np.array(got)
    assert f[-1] == 1.0
    if not threaded:  # one report per piece (the worker may be done before finish() looks)
        assert f.size == len(seen["pieces"]) + 1 and f[0] < 1.0
    assert np.all((f >= 0.0) & (f <= 1.0)) and np.all(np.diff(f) >= 0.0)
    assert b._units_cut == b._units_added == sum(len(pc.curve.sample.xyz) for pc in seen["pieces"])
    (plain, ids_plain, _, _), _ = _build(seen, False, 500, link_max=link_max)
    assert ids == ids_plain and len(passes) == len(plain)
    assert all(np.array_equal(a, c) for a, c in zip(passes, plain))


class _Gated:
    """A cutter whose first CC batch waits for ``gate`` (at most 10 s)."""

    def __init__(self, cutter, gate):
        self._cutter, self._gate = cutter, gate

    def __getattr__(self, name):
        return getattr(self._cutter, name)

    def cl_from_cc(self, *args, **kw):
        self._gate.wait(10.0)
        return self._cutter.cl_from_cc(*args, **kw)


def test_progress_reported_while_the_worker_cuts(recorded):
    """In the worker, finish() reports before the cutting is done: the worker's first batch
    waits until the first report has been made, so a finish() that only joined the worker
    would report nothing but the final 1.0 (after a 10 s wait)."""
    if not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    import threading

    _, seen = recorded
    gate = threading.Event()
    b = _builder(seen, True, 500, make_cutter=lambda: _Gated(seen["make_cutter"](), gate))
    for pc in seen["pieces"]:
        b.add(pc)
    got = []

    def report(f):
        got.append(f)
        gate.set()

    passes, ids, _, _ = b.finish(progress=report)
    assert len(got) >= 2 and got[0] < 1.0 and got[-1] == 1.0
    (plain, ids_plain, _, _), _ = _build(seen, False, 500)
    assert ids == ids_plain and all(np.array_equal(a, c) for a, c in zip(passes, plain))


@pytest.mark.parametrize("link_max, hop_lift", [(None, 0.0), (1e-6, 0.0), (None, 0.01)])
def test_passes_so_far_are_the_first_passes(recorded, link_max, hop_lift):
    # what the pencil's filter reads while the cutter works: the first passes finish()
    # returns, the last one possibly only its first points (the pass being cut); with
    # retracts (a pass per path) and with hops (a pass split into runs)
    _, seen = recorded
    pieces = seen["pieces"]
    partial = 0
    for k in (0, 1, len(pieces) // 3, len(pieces) // 2, len(pieces) - 1, len(pieces)):
        b = _builder(seen, False, 7, link_max=link_max, hop_lift=hop_lift)
        for pc in pieces[:k]:
            b._take(pc)  # as the worker does
        early = b.passes_so_far()
        for pc in pieces[k:]:
            b.add(pc)
        passes = b.finish()[0]
        assert len(early) <= len(passes) and (early == [] if k == 0 else k < len(pieces) // 3 or early)
        for i, e in enumerate(early):
            full = passes[i]
            assert np.array_equal(e, full if i < len(early) - 1 else full[:len(e)])
        partial += bool(early) and len(early[-1]) < len(passes[len(early) - 1])
        if hop_lift:
            assert b.n_hops > 0
    if link_max is None:  # one long pass: read in part (with a retract after each path, whole)
        assert partial >= 2


def test_the_cutter_s_error_wins_over_the_wait_for_the_pencil(monkeypatch):
    # with --pencil-left the plan waits for the pencil's search while the cutter works: a
    # cutter that fails after the pattern stage (here: building its index) is the error
    # reported, not the search's "no cutter" RuntimeError (a traceback from the CLI)
    if not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    import threading

    import conformill.cutter as cutter_mod
    import conformill.patterns.zigzag as zigzag

    done = threading.Event()
    real_plan, real_cutter = zigzag.plan_zigzag, cutter_mod.BallCutter

    def plan_then_say(*a, **kw):
        out = real_plan(*a, **kw)
        done.set()
        return out

    def cutter(*a, **kw):
        if threading.current_thread().name == "conformill-cutter":
            done.wait(60)
            raise PlanningError("cutter index: a failure made on purpose")
        return real_cutter(*a, **kw)

    monkeypatch.setattr(zigzag, "plan_zigzag", plan_then_say)
    monkeypatch.setattr(cutter_mod, "BallCutter", cutter)
    part = synthetic.freeform_patch(spacing=2.0, jitter=0.3, seed=2)
    with pytest.raises(PlanningError, match="a failure made on purpose"):
        plan(part, Job(pattern="zigzag", tool_radius=R, scallop=0.05, tolerance=0.01, pencil=True,
                       pencil_search="folds", pencil_left=0.5))


def test_retracts_split_passes_the_same_way_in_batches(recorded):
    _, seen = recorded
    (whole, ids_w, _, _), bw = _build(seen, False, 10**9, link_max=1e-6)
    (parts, ids_p, _, _), bp = _build(seen, threads_can_overlap(), 5, link_max=1e-6)
    assert bw.n_retracts_link == bp.n_retracts_link > 0
    assert len(whole) == bw.n_retracts_link + 1 and ids_w == ids_p
    for a, b in zip(whole, parts):
        assert np.array_equal(a, b)


def test_whole_plan_same_with_and_without_the_worker(monkeypatch):
    part = synthetic.freeform_patch(spacing=2.0, jitter=0.3, seed=2)
    job = Job(pattern="zigzag", tool_radius=R, scallop=0.05, tolerance=0.01)
    a = plan(part, job)
    monkeypatch.setattr(pipeline, "threads_can_overlap", lambda: False)
    b = plan(part, job)
    assert "cutter_wait" not in b.report["timings_s"]
    assert len(a.toolpath.passes) == len(b.toolpath.passes)
    for p, q in zip(a.toolpath.passes, b.toolpath.passes):
        assert np.array_equal(p, q)


def _nice(tid=None):
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id() if tid is None else tid)


def _omp_or_skip():
    import numba

    threads_can_overlap()  # runs a parallel kernel if none has: numba picks its layer
    if numba.threading_layer() != "omp":
        pytest.skip("the workers are lowered under numba's omp layer only")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")
def test_background_priority_lowers_only_the_calling_thread():
    _omp_or_skip()
    seen = {}

    def work():
        before = _nice()
        seen["lowered"] = background_priority()
        seen["step"] = _nice() - before
        seen["again"] = background_priority()  # never past 19, never an error
        seen["capped"] = _nice() <= 19

    main = _nice()
    t = threading.Thread(target=work)
    t.start()
    t.join()
    assert seen["lowered"] and seen["again"] and seen["capped"]
    assert seen["step"] == min(BACKGROUND_NICE, 19 - main)
    assert _nice() == main  # the caller's thread, and so the process's later threads, keep theirs


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice values are Linux's")
def test_plan_runs_its_workers_lower_and_leaves_the_caller_as_it_was(monkeypatch):
    if not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    _omp_or_skip()
    import numba

    import conformill.passes as passes

    seen = []
    real = passes.background_priority

    def spy():
        out = real()
        seen.append((threading.current_thread().name, _nice()))
        return out

    monkeypatch.setattr(passes, "background_priority", spy)
    main, nthreads = _nice(), numba.get_num_threads()
    part = synthetic.freeform_patch(spacing=2.0, jitter=0.3, seed=2)
    plan(part, Job(pattern="zigzag", tool_radius=R, scallop=0.05, tolerance=0.01, pencil=True))
    names = sorted(n for n, _ in seen)
    assert names == ["conformill-cutter", "conformill-pencil"], seen
    assert all(v == min(main + BACKGROUND_NICE, 19) for _, v in seen), seen
    assert BACKGROUND_NICE > 0 and (main == 19 or all(v > main for _, v in seen))
    assert _nice() == main and numba.get_num_threads() == nthreads


def test_serial_caller_sets_one_thread_and_restores_it():
    import numba

    n = numba.get_num_threads()
    with serial_caller():
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == n
    with pytest.raises(RuntimeError):
        with serial_caller():
            raise RuntimeError("a stage failed")
    assert numba.get_num_threads() == n
    with serial_caller(active=False):
        assert numba.get_num_threads() == n


def _far_piece():
    """A path whose CC points lie 50 mm beside the mesh: the cutter refuses it."""
    xyz = np.column_stack([np.linspace(100, 110, 20), np.zeros(20), np.zeros(20)])
    S = SimpleNamespace(xyz=xyz, n=np.tile([0.0, 0.0, 1.0], (20, 1)), curvature=lambda t: np.zeros(20))
    return Piece("path", SimpleNamespace(sample=S, t=None), False, 0)


@pytest.mark.parametrize("threaded", [False, True])
def test_cutter_error_in_the_worker_reaches_the_caller(threaded):
    if threaded and not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    m = synthetic.plane(size=20.0, spacing=2.0)
    b = PassBuilder(lambda: BallCutter(m.V, m.F, R), 0.01, 0.0025, 0.005, 10.0, 8.0, threaded=threaded, batch=5)
    with pytest.raises(PlanningError, match="not within the ball's reach"):
        for _ in range(50):  # more pieces after the failure: add() raises early or finish() does
            b.add(_far_piece())
        b.finish()
    b.abort()  # returns at once: the worker has stopped
    assert b._thread is None


def test_abort_drops_the_queued_pieces(recorded):
    """A failure in the caller's thread stops the worker without cutting the backlog."""
    _, seen = recorded
    if not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    started, holder = [], []

    def late_cutter():  # the worker starts only once the caller has aborted
        started.append(1)
        for _ in range(1000):
            if holder and holder[0]._cancel:
                break
            time.sleep(0.01)
        return seen["make_cutter"]()

    args = list(seen["args"])[:5]
    with pytest.raises(RuntimeError, match="pattern failed"):
        with PassBuilder(late_cutter, *args, threaded=True, batch=1) as b:
            holder.append(b)
            for pc in seen["pieces"]:
                b.add(pc)
            for _ in range(1000):  # the worker is building the cutter (until the abort)
                if started:
                    break
                time.sleep(0.01)
            raise RuntimeError("pattern failed")
    assert b._thread is None and started
    assert b.cc_paths == []  # nothing of the backlog was cut


@pytest.mark.parametrize("threaded", [False, True])
def test_cutter_error_at_the_last_batch_reaches_the_caller(threaded):
    """With the default batch the whole (small) pass is cut after the last piece, in
    finish(): its error must be raised there, not leave finish() waiting."""
    if threaded and not threads_can_overlap():
        pytest.skip("numba's threading layer here does not allow two threads")
    import threading

    m = synthetic.plane(size=20.0, spacing=2.0)
    b = PassBuilder(lambda: BallCutter(m.V, m.F, R), 0.01, 0.0025, 0.005, 10.0, 8.0, threaded=threaded)
    b.add(_far_piece())
    caught = []

    def run():
        try:
            b.finish()
        except PlanningError as exc:
            caught.append(exc)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(60)
    assert not t.is_alive(), "finish() did not return"
    assert caught and "not within the ball's reach" in str(caught[0])
    b.abort()



def test_feed_length_sums_the_moves_of_each_pass_not_the_joins():
    a = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [3.0, 4.0, 12.0]])  # 5 + 12
    b = np.array([[100.0, 0.0, 0.0], [100.0, 0.0, -2.0]])  # 2, far from a's end
    lone = np.array([[7.0, 7.0, 7.0]])  # one point: no move
    assert feed_length([a, b, lone]) == pytest.approx(19.0, abs=1e-12)
    assert feed_length([]) == 0.0 and isinstance(feed_length([]), float)


@pytest.mark.parametrize("layer, threads, overlap, warns", [("omp", 2, True, False), ("tbb", 2, True, False),
                                                            ("workqueue", 2, False, True),
                                                            ("workqueue", 1, False, False)])
def test_threading_layer_decides_the_overlap_and_workqueue_is_named(monkeypatch, caplog, layer, threads, overlap,
                                                                    warns):
    """Only ``omp`` and ``tbb`` let the cutter's worker run beside the pattern stage; under
    ``workqueue`` on several threads the plan says why it is slower, once per process."""
    import numba

    import conformill.passes as passes

    monkeypatch.setattr(numba, "threading_layer", lambda: layer)
    monkeypatch.setattr(numba, "get_num_threads", lambda: threads)
    passes._warn_layer.cache_clear()  # as in a new process
    with caplog.at_level("WARNING", logger="conformill.passes"):
        assert threads_can_overlap() is overlap
        assert threads_can_overlap() is overlap
    said = [r.getMessage() for r in caplog.records if "threading layer" in r.getMessage()]
    assert len(said) == (1 if warns else 0)
    if warns:
        assert "'workqueue'" in said[0] and "libgomp.so.1" in said[0]
