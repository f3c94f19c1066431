"""Pieces in machining order -> forward steps (CC points) -> cutter -> tool passes.

The pattern stage hands over each path and link as soon as it is final
(:class:`PassBuilder.add`); the builder picks the forward steps of the piece, groups the
pieces into passes (a link longer than ``link_max`` starts a new pass) and runs the ball
cutter on the CC points in batches. With ``threaded`` this happens in a worker thread
while the pattern stage plans the next paths: the pattern stage is mostly serial and the
cutter is parallel, so the two fill both cores instead of taking turns.

Batching changes nothing in the program: the drop-cutter is exact per point, and
:meth:`conformill.cutter.BallCutter.settle` and :meth:`conformill.cutter.BallCutter.refine`
decide every move on its own (their rounds only ever re-check the two halves of a move
they split), so settling and refining a batch together with the last centre of the batch
before gives, point for point, what one call on the whole pass gives.
"""

from __future__ import annotations

import collections
import functools
import logging
import queue
import threading
import time

import numpy as np
from numba import njit, prange

from conformill.errors import PlanningError
from conformill.patterns.forward import select_forward

__all__ = ["PassBuilder", "feed_length", "threads_can_overlap", "background_priority", "start_worker", "serial_caller"]

log = logging.getLogger(__name__)

#: CC points cut together (large enough that the cutter's threads stay busy).
BATCH = 32768
#: The first batch: the batches double from this up to ``BATCH``, so that the cutter
#: starts early in the pattern stage (igea contour: 0.08 s after its start instead of
#: 0.3 s, when ``BATCH`` CC points are there).
FIRST_BATCH = 4096
#: Least distance (mm) between the ball and the part on a hop's rapids across and down
#: (the rapid up starts at the last cut centre, like any retract; a hop is never above
#: the safe height, which may be lower).
HOP_CLEARANCE = 1.0


def feed_length(passes) -> float:
    """The summed length (mm) of polylines ``passes`` (``(k_i, 3)`` each): the feed of
    their moves, without what joins one to the next."""
    return float(sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in passes))


def hops_into(cutter, start, pieces) -> list:
    """The hop into each of ``pieces`` (ball-centre polylines cut one after another) from
    the end of the one before it, the first from centre ``start``: as the hops over lifted
    runs (:meth:`PassBuilder._cut_centres`), the tip heights ``(across, down)`` of a rapid
    across :data:`HOP_CLEARANCE` clear of the part (by :meth:`conformill.cutter.BallCutter.clear_height`)
    and of a rapid down to where the ball is that clear above the piece's start, then the
    plunge. The G-code writer keeps them below the safe height."""
    if not pieces:
        return []
    A = np.vstack([np.asarray(start, dtype=np.float64).reshape(1, 3)] + [p[-1:] for p in pieces[:-1]])
    B = np.vstack([p[:1] for p in pieces])
    H, Hb = hop_heights(cutter, A, B)
    r = cutter.radius
    return [(float(x - r), float(y - r)) for x, y in zip(H, Hb)]


def hop_heights(cutter, A, B):
    """The centre heights ``(H, Hb)`` of hops from centres ``A`` to centres ``B`` (``(k, 3)``
    each): across at ``H``, where the ball clears the part by :data:`HOP_CLEARANCE` all
    along the XY segment (and no lower than either end), then down by rapid to ``Hb``, where
    the ball is still that clear above ``B`` (between ``B`` and ``H``), then the plunge."""
    H = np.maximum(np.maximum(A[:, 2], B[:, 2]), cutter.clear_height(A[:, :2], B[:, :2], clearance=HOP_CLEARANCE))
    Hb = np.clip(cutter.clear_height(B[:, :2], B[:, :2], clearance=HOP_CLEARANCE), B[:, 2], H)
    return H, Hb


def threads_can_overlap() -> bool:
    """Whether numba's threading layer accepts parallel calls from two threads at once.

    ``tbb`` and ``omp`` do; ``workqueue`` aborts the process on concurrent use. False also
    when one thread is asked for (``--threads 1``). Under ``workqueue`` on more than one
    thread (numba found no ``libgomp.so.1`` for its OpenMP layer) a warning says so, once
    per process: the stages then run one after the other, about a third slower (igea
    ``--scan`` contour, session 66: 11.0-11.9 s against 7.9-8.8 s under ``omp``).
    """
    import numba

    if numba.get_num_threads() < 2:
        return False
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet: run one, so that numba picks its layer
        _touch(np.zeros(2))
        layer = numba.threading_layer()
    if layer in ("tbb", "omp"):
        return True
    _warn_layer(layer)
    return False


@functools.cache
def _warn_layer(layer: str) -> None:
    """:func:`threads_can_overlap`'s warning for a layer that cannot overlap the stages,
    once per process."""
    log.warning("numba runs its %r threading layer (its OpenMP layer needs the system's libgomp.so.1, "
                "e.g. Debian's libgomp1): the cutter cannot work beside the pattern stage, and plans take "
                "about a third longer (the same program)", layer)


#: How much lower (``nice`` steps) the background threads run than the caller's thread.
#: The plan's caller thread runs the serial stages (the map's set-up, the frame, the
#: pattern stage), which the program waits for; the cutter's worker and the pencil's
#: search fill whatever the cores leave and are waited for only at the end. With equal
#: priority the pattern stage got about two thirds of a core (igea contour `--scan`: 3.6 s
#: against 1.8 s alone); measured in session 50, docs/issue5.md.
BACKGROUND_NICE = 5


def background_priority() -> bool:
    """Lower the calling thread's scheduling priority by :data:`BACKGROUND_NICE`.

    Linux only, where ``nice`` is a per-thread attribute (``setpriority`` on the thread's
    id) and threads it starts (numba's OpenMP team) inherit it; elsewhere ``PRIO_PROCESS``
    with a thread id would name a process, so nothing is done. Only under numba's ``omp``
    layer: ``tbb`` shares one pool of workers among all threads, which keep the nice value
    of the thread that made them (the plan's own kernels could then run on lowered
    workers). Raising one's own nice value needs no privilege; a refusal is ignored (only
    the speed depends on it).

    Returns
    -------
    bool
        Whether the priority was lowered.
    """
    import os
    import sys

    if not sys.platform.startswith("linux") or not hasattr(os, "setpriority"):
        return False
    import numba

    try:
        if numba.threading_layer() != "omp":
            return False
    except ValueError:  # no parallel kernel has run: the layer is not chosen yet
        return False
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + BACKGROUND_NICE, 19))
    except OSError:
        return False
    return True


def start_worker(nthreads: int) -> None:
    """What a background worker does first, in its own thread: lower its priority
    (:func:`background_priority`), then take the caller's numba thread count (numba's is per
    thread), so that the team numba makes for this thread inherits the lower priority."""
    import numba

    background_priority()
    numba.set_num_threads(nthreads)


class serial_caller:
    """Context: the calling thread's numba kernels on one thread (numba's count is per thread).

    For a serial stage that runs while the background threads keep the other cores busy:
    each parallel kernel it called woke a thread of its own team onto a core that a
    background thread held, and waited for it. Results do not depend on the thread count.
    ``active=False`` leaves the count as it is (no background threads).
    """

    def __init__(self, active: bool = True):
        self.active = bool(active)
        self._n = None

    def __enter__(self):
        if self.active:
            import numba

            self._n = numba.get_num_threads()
            numba.set_num_threads(1)
        return self

    def __exit__(self, *exc):
        if self._n is not None:
            import numba

            numba.set_num_threads(self._n)
            self._n = None
        return False


@njit(cache=True, parallel=True)
def _touch(x):
    for i in prange(x.shape[0]):
        x[i] += 1.0
    return x


class _Pass:
    """One continuous pass being cut: its pending CC points and the centres so far."""

    def __init__(self, path_id: int):
        self.path_id = path_id
        self.cc, self.nn, self.pending = [], [], 0
        self.units = 0  # dense samples of the pieces whose CC points are pending
        self.centres, self.lifts = [], []
        self.last = None  # last refined centre: the first point of the next batch's moves
        self.last_tri = -1  # the triangle it rests on (a hint for the cutter)
        self.air = None  # with hops: centres and contacts of a lifted run after ``last``, undecided
        self.tips = None  # once finished: its tip polylines and hops (PassBuilder._tips)


class PassBuilder:
    """Forward steps and the cutter for pieces handed over in machining order.

    Parameters
    ----------
    make_cutter : callable
        Returns the :class:`conformill.cutter.BallCutter` (built in the worker, so that
        building its index overlaps the pattern stage too).
    tolerance : float
        ``e``: no centre move cuts more than ``e / 2`` into the part.
    e_fwd, e_cvx, max_step : float
        Forward chord tolerances (concave / convex along the path) and longest step.
    link_max : float
        Longest link cut on the surface; a longer one ends the pass (a retract).
    settle_tol : float
        No centre move floats more than this above the drop surface
        (:meth:`conformill.cutter.BallCutter.settle`); 0: not checked.
    hop_lift : float
        Runs of centres lifted more than this above their planned contact (mm) are hopped
        over where that is quicker (:meth:`_cut_centres`); 0: off.
    rates : (float, float, float)
        Feed, plunge feed and rapid rate (mm/min) the hops are timed at.
    threaded : bool
        Work in a worker thread (see :func:`threads_can_overlap`).
    batch : int
        CC points cut together (the first batches fewer: ``first_batch``, then doubling).
    first_batch : int
        CC points of the first batch.

    Notes
    -----
    ``timings`` holds the busy time of the forward and cutter work (in the worker when
    threaded, so they overlap the pattern stage's wall time).
    """

    def __init__(self, make_cutter, tolerance: float, e_fwd: float, e_cvx: float, max_step: float,
                 link_max: float, threaded: bool, batch: int = BATCH, settle_tol: float = 0.0,
                 first_batch: int = FIRST_BATCH, hop_lift: float = 0.0, rates=(1000.0, 1000.0 / 3, 5000.0)):
        self._make_cutter = make_cutter
        self.cutter = None
        self.e, self.e_fwd, self.e_cvx, self.max_step = tolerance, e_fwd, e_cvx, max_step
        self.link_max = link_max
        self.settle_tol = float(settle_tol)
        self.hop_lift = float(hop_lift)
        self.feed, self.plunge, self.rapid = (float(v) for v in rates)
        self.n_hops = 0  # lifted runs hopped over
        self.n_hopped = 0  # CC points not cut: in those runs, or lifted at a pass's ends
        self.hop_saved = 0.0  # minutes: the runs hopped over at feed, less the hops
        self.n_settled = 0  # points inserted by the settle check
        self.n_settle_unresolved = 0  # moves its rounds did not test again
        self.batch = int(batch)
        self._next_batch = max(1, min(int(first_batch), self.batch))
        self.timings = {"forward": 0.0, "cutter": 0.0}
        self.cc_paths, self.fwd_steps = [], []
        self.n_retracts_link = 0
        self._passes = [_Pass(-1)]
        self._done = []  # finished passes
        self._error = None
        self._cancel = False
        self._thread = None
        self._cutter_ready = threading.Event()  # set once the worker built the cutter (or failed)
        self._held = []  # pieces handed over, when not threaded (cut in finish())
        self._last_piece = None
        self._recent = collections.deque(maxlen=16)  # the last pieces handed over (end_xy)
        # progress of the cutter in dense samples of the pieces: handed over (caller's
        # thread) and cut (the worker's, counted when a pass's batch is done)
        self._units_added = 0
        self._units_cut = 0
        self.threaded = bool(threaded)
        if threaded:
            import numba

            self._nthreads = numba.get_num_threads()  # thread-local in numba: hand it over
            self._queue = queue.Queue()
            self._thread = threading.Thread(target=self._loop, name="conformill-cutter", daemon=True)
            self._thread.start()

    # -- the caller's side ----------------------------------------------------------
    def add(self, piece) -> None:
        """Hand over the next piece (a :class:`conformill.patterns.pieces.Piece`)."""
        self._units_added += len(piece.curve.sample.xyz)
        self._last_piece = piece
        self._recent.append(piece)
        if self._thread is None:
            self._held.append(piece)
            return
        self.check()
        self._queue.put(piece)

    def wait_cutter(self):
        """The worker's cutter once it is built (threaded builders only; ``None`` when the
        worker failed or was stopped first)."""
        self._cutter_ready.wait()
        return self.cutter

    def end_xy(self):
        """XY of the ball centre the passes will end at, from the last piece handed over,
        before the worker gets there: the centre :meth:`_take` and :meth:`_cut` make of
        that path's last sample (kept by the forward steps, ``settle`` and ``refine``); with
        ``hop_lift``, of the last CC point not lifted above it among the last 16 pieces
        (the runs after it are not cut). ``None`` when the last piece is no path, the
        cutter is not built or (with hops) no such point is found. A prediction for work
        that can start early (the pencil's links); compare it with the passes."""
        pc = self._last_piece
        if pc is None or pc.kind != "path" or self.cutter is None:  # set once built, by either thread
            return None
        S = pc.curve.sample
        if len(S.xyz) == 0:
            return None
        try:
            if self.hop_lift > 0:  # the last CC point cut: not lifted above the limit
                for q in reversed(self._recent):  # (the runs after it are not cut)
                    _, cc, nn = self._forward(q)
                    if cc is not None and len(cc):  # (a retract cuts nothing)
                        c, lift = self.cutter.cl_from_cc(cc, nn)
                        ok = np.flatnonzero(lift <= self.hop_lift)
                        if ok.size:
                            return c[ok[-1], :2]
                return None
            j = 0 if pc.reverse else len(S.xyz) - 1
            return self.cutter.cl_from_cc(S.xyz[j:j + 1], S.n[j:j + 1])[0][0, :2]
        except PlanningError:  # the worker meets it too, and raises it from finish()
            return None

    def check(self) -> None:
        """Raise what the worker raised, if it failed (call it while waiting on other work,
        so that the cutter's own error is the one reported)."""
        if self._error is not None:
            raise self._error

    def fraction_cut(self) -> float:
        """Share of the pieces handed over so far whose CC points are cut, by their dense
        samples (0 to 1; 1 when nothing was handed over)."""
        return min(self._units_cut / self._units_added, 1.0) if self._units_added else 1.0

    def finish(self, progress=None):
        """Cut what is left; returns ``(passes, pass_ids, lifts, hops)``.

        ``passes`` are tool-tip polylines ``(k, 3)``; ``lifts`` the drop-cutter lifts of
        the CC points (mm); ``hops`` per pass the hop into it from the pass before, as
        the tool-tip heights of its rapid across and of its rapid down to above the pass
        start (``None``: a retract to the safe height; see ``hop_lift``).
        ``progress(fraction)``, if given, is called while the cutter works
        (:meth:`fraction_cut`, non-decreasing, last 1.0). Raises what the worker raised.
        """
        say = progress or (lambda f: None)
        if self._thread is None:
            for piece in self._held:
                self._take(piece)
                say(self.fraction_cut())
            self._held = []
            self._close()
        else:
            self._queue.put(None)
            while self._thread.is_alive():
                say(self.fraction_cut())
                self._thread.join(timeout=0.2)
            self._thread = None
            self.check()
        say(1.0)
        passes, ids, lifts, hops = [], [], [], []
        for p in self._done:
            lifts.extend(p.lifts)
            pp, hh = self._tips(p)
            passes.extend(pp)
            ids.extend([p.path_id] * len(pp))
            hops.extend(hh)
        return passes, ids, lifts, hops

    def passes_so_far(self) -> list:
        """The tool-tip polylines cut so far, while the worker cuts the rest (call it from
        the caller's thread, as :meth:`finish`): the first passes :meth:`finish` returns,
        the same values, the last of them possibly only the first points of its pass (the
        pass being cut)."""
        done = list(self._done)  # (the worker appends to these lists)
        out = [q for p in done for q in self._tips(p)[0]]
        if len(self._passes) > len(done):
            out.extend(self._runs(list(self._passes[len(done)].centres))[0])
        return out

    def _tips(self, p: _Pass):
        """A finished pass's tip polylines and the hop into each (``finish``'s ``passes``
        and ``hops``), made once (a finished pass does not change)."""
        if p.tips is None:
            p.tips = self._runs(p.centres)
        return p.tips

    def _runs(self, items):
        """Tip polylines and hops of a pass's ``centres`` items (arrays of centres, and a
        pair of centre heights for each hop between runs)."""
        passes, hops = [], []
        run, hop = [], None  # a pair in p.centres: a hop (centre heights across and down to)
        for c in items + [None]:
            if isinstance(c, np.ndarray):
                run.append(c)
                continue
            if run:
                centres = np.concatenate(run)
                # drop consecutive duplicates (a centre point path, link ends): decided pair by
                # pair, so the runs of a pass being cut are the first points of its runs
                keep = np.ones(len(centres), dtype=bool)
                keep[1:] = np.any(np.abs(np.diff(centres, axis=0)) > 1e-9, axis=1)
                passes.append(self.cutter.tip(centres[keep]))
                hops.append(None if hop is None else tuple(z - self.cutter.radius for z in hop))
            run, hop = [], c
        return passes, hops

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.abort()
        return False

    def abort(self) -> None:
        """Stop the worker (after an error in the caller's thread); harmless after :meth:`finish`."""
        if self._thread is not None:
            self._cancel = True  # the pieces still queued are dropped, not cut
            self._queue.put(None)
            self._thread.join()
            self._thread = None

    # -- the work ---------------------------------------------------------------------
    def _loop(self):
        ended = False  # the end marker was taken from the queue
        try:
            start_worker(self._nthreads)
            if not self._cancel:
                t0 = time.perf_counter()
                self.cutter = self._make_cutter()  # its index, while the map is solved
                self.timings["cutter"] += time.perf_counter() - t0
            self._cutter_ready.set()
            while True:
                piece = self._queue.get()
                if piece is None:
                    ended = True
                    break
                if not self._cancel:
                    self._take(piece)
            if not self._cancel:
                self._close()
        except BaseException as exc:  # handed to the caller's thread by finish() / add()
            self._error = exc
            self._cutter_ready.set()
            while not ended:  # let finish() / abort() return: take the end marker
                ended = self._queue.get() is None

    def _forward(self, pc):
        """The piece's dense samples in cutting order and the CC points and normals it
        adds to the pass: all of a path's, the inner ones of a link cut on the surface;
        ``None`` for both where the link is longer than ``link_max`` (a retract)."""
        c = pc.curve
        S = c.sample
        order = slice(None, None, -1) if pc.reverse else slice(None)
        X3 = S.xyz[order]
        kap = S.curvature(c.t)[order]
        idx = select_forward(X3, kap, self.e_fwd, self.max_step, e_convex=self.e_cvx)
        # the fitted (smooth) normal: with the facet's the contact would sit exactly on
        # the CC point, but the centre path would jitter at every edge; measured, it
        # changes the scallop by less than 1 % (cad_like_0, h = 0.01)
        cc, nn = X3[idx], S.n[order][idx]
        if pc.kind == "path":
            return X3, cc, nn
        if float(np.linalg.norm(np.diff(X3, axis=0), axis=1).sum()) <= self.link_max:
            return X3, cc[1:-1], nn[1:-1]
        return X3, None, None

    def _take(self, pc):
        t0 = time.perf_counter()
        X3, cc, nn = self._forward(pc)
        cur = self._passes[-1]
        if pc.kind == "path":
            self.cc_paths.append(cc)
            if len(cc) > 1:
                self.fwd_steps.append(np.linalg.norm(np.diff(cc, axis=0), axis=1))
            if cur.path_id < 0:
                cur.path_id = pc.index
        if cc is not None:
            cur.cc.append(cc)
            cur.nn.append(nn)
            cur.pending += len(cc)
            cur.units += len(X3)
        else:
            self.n_retracts_link += 1
            self._units_cut += len(X3)  # nothing to cut: a retract
            self.timings["forward"] += time.perf_counter() - t0
            self._cut(cur)
            self._end(cur)
            self._done.append(cur)
            self._passes.append(_Pass(-1))
            return
        self.timings["forward"] += time.perf_counter() - t0
        if cur.pending >= self._next_batch:
            self._next_batch = min(2 * self._next_batch, self.batch)
            self._cut(cur)

    def _close(self):
        for p in self._passes[len(self._done):]:
            self._cut(p)
            self._end(p)
            self._done.append(p)

    def _end(self, p: _Pass):
        """The pass ends: a lifted run after its last cut centre is not cut."""
        if p.air is not None:
            self.n_hopped += len(p.air[0])
            p.air = None

    def _cut(self, p: _Pass):
        """Drop-cutter and gouge-safe moves for the pending CC points of pass ``p``."""
        if not p.cc:
            return
        t0 = time.perf_counter()
        if self.cutter is None:
            self.cutter = self._make_cutter()
        cc = np.concatenate(p.cc)
        nn = np.concatenate(p.nn)
        p.cc, p.nn, p.pending = [], [], 0
        units, p.units = p.units, 0  # counted as cut once this batch is done
        if len(cc):
            centres, lift, tri = self.cutter.cl_from_cc(cc, nn, contacts=True)  # finite, or it raises
            p.lifts.append(lift)
            self._cut_centres(p, centres, lift, tri)
        self._units_cut += units
        self.timings["cutter"] += time.perf_counter() - t0

    def _cut_centres(self, p: _Pass, centres, lift, tri):
        """Gouge-safe moves through one batch's centres of pass ``p``, joined to the last
        batch's end (the move into the batch is checked here).

        No move floats more than ``settle_tol`` above the drop surface (the material a
        chord leaves over a groove the ball cannot enter), then no move cuts more than
        ``e / 2`` into the part (an exact bound): half of the gouge budget e; of the
        other half, the controller's corner rounding gets a quarter by default
        (``Job.blend``, ``G64 P``) and the mesh facets between samples the rest.

        With ``hop_lift``, runs of centres lifted more than it are hopped over. Such a run
        is where the ball cannot reach its planned contact (an undercut, a pocket tighter
        than the ball): it rides on material that other passes mostly cut. Where a hop is
        quicker than riding the run at the feed, the run is not cut and the pass is split
        there. The hop (written by :func:`conformill.output.gcode.write_gcode`): a rapid
        straight up from the last cut centre A to a height at which the ball clears the
        part by :data:`HOP_CLEARANCE` all along the XY segment to the next cut centre B
        (:meth:`conformill.cutter.BallCutter.clear_height`), across, a rapid down to where
        the ball is still that clear above B, and the plunge to B at the plunge feed;
        gouge-free by construction, timed at ``rates``. Only the cut stretches are
        settled and refined (together: the same points as one call each). A lifted run at
        a pass's start or end is not cut either. A run still lifted at the end of the
        batch waits for the next batch (or the pass's end), so the program does not
        depend on the batches.
        """
        air = lift > self.hop_lift if self.hop_lift > 0 else np.zeros(len(lift), dtype=bool)
        if p.air is not None:  # the undecided run from the last batch
            centres = np.vstack([p.air[0], centres])
            tri = np.concatenate([p.air[1], tri])
            air = np.concatenate([np.ones(len(p.air[0]), dtype=bool), air])
            p.air = None
        joined = p.last is not None
        if joined:
            centres = np.vstack([p.last[None], centres])
            tri = np.concatenate([[p.last_tri], tri])
            air = np.concatenate([[False], air])
        n = len(centres)
        d = np.diff(np.concatenate([[0], air.astype(np.int8), [0]]))
        ra, rb = np.flatnonzero(d == 1), np.flatnonzero(d == -1)  # lifted runs [ra, rb)
        end = n
        if len(ra) and rb[-1] == n:  # lifted up to the batch's end: undecided
            end = ra[-1]
            p.air = (centres[end:], tri[end:])
            ra, rb = ra[:-1], rb[:-1]
        lead = 0
        if len(ra) and ra[0] == 0:  # lifted from the pass's start (no centre before)
            lead = rb[0]
            self.n_hopped += int(lead)
            ra, rb = ra[1:], rb[1:]
        if lead >= end:
            return
        H = Hb = np.zeros(0)
        if len(ra):
            A, B = centres[ra - 1], centres[rb]
            step = np.linalg.norm(np.diff(centres, axis=0), axis=1)
            # summed per run (not as a difference of running sums): the same figure
            # whichever batch the run is decided in
            ride = np.array([step[a - 1:b].sum() for a, b in zip(ra, rb)]) / self.feed
            H, Hb = hop_heights(self.cutter, A, B)
            hop = ((H - A[:, 2]) + np.hypot(*(B[:, :2] - A[:, :2]).T) + (H - Hb)) / self.rapid \
                + (Hb - B[:, 2]) / self.plunge
            go = hop < ride
            self.n_hops += int(go.sum())
            self.n_hopped += int((rb - ra)[go].sum())
            self.hop_saved += float((ride - hop)[go].sum())
            ra, rb, H, Hb = ra[go], rb[go], H[go], Hb[go]
        starts = np.concatenate([[lead], rb])
        stops = np.concatenate([ra, [end]])
        pcs = [centres[a:b] for a, b in zip(starts, stops)]
        tris = [tri[a:b] for a, b in zip(starts, stops)]
        if self.settle_tol > 0:
            pcs, k, left, tris = self.cutter.settle_pieces(pcs, self.settle_tol, contacts=tris)
            self.n_settled += k
            self.n_settle_unresolved += left
        pcs = self.cutter.refine_pieces(pcs, self.e)  # a hop's moves are not checked: above D
        if joined:  # settle and refine keep the ends: the last batch's end is already there
            pcs[0] = pcs[0][1:]
        for k, c in enumerate(pcs):
            if k > 0:  # a hop from the last piece's end to this piece's start: its centre heights
                p.centres.append((float(H[k - 1]), float(Hb[k - 1])))
            if len(c):
                p.centres.append(c)
        p.last, p.last_tri = centres[end - 1], int(tris[-1][-1])
