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

import logging
import queue
import threading
import time

import numpy as np
from numba import njit, prange

from conformill.errors import PlanningError
from conformill.patterns.forward import select_forward

__all__ = ["PassBuilder", "threads_can_overlap"]

log = logging.getLogger(__name__)

#: CC points cut together (large enough that the cutter's threads stay busy).
BATCH = 32768
#: The first batch: the batches double from this up to ``BATCH``, so that the cutter
#: starts early in the pattern stage (igea contour: 0.08 s after its start instead of
#: 0.3 s, when ``BATCH`` CC points are there).
FIRST_BATCH = 4096


def threads_can_overlap() -> bool:
    """Whether numba's threading layer accepts parallel calls from two threads at once.

    ``tbb`` and ``omp`` do; ``workqueue`` aborts the process on concurrent use. False also
    when one thread is asked for (``--threads 1``).
    """
    import numba

    if numba.get_num_threads() < 2:
        return False
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel has run yet: run one, so that numba picks its layer
        _touch(np.zeros(2))
        layer = numba.threading_layer()
    return layer in ("tbb", "omp")


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
                 first_batch: int = FIRST_BATCH):
        self._make_cutter = make_cutter
        self.cutter = None
        self.e, self.e_fwd, self.e_cvx, self.max_step = tolerance, e_fwd, e_cvx, max_step
        self.link_max = link_max
        self.settle_tol = float(settle_tol)
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
        if self._thread is None:
            self._held.append(piece)
            return
        self._raise()
        self._queue.put(piece)

    def wait_cutter(self):
        """The worker's cutter once it is built (threaded builders only; ``None`` when the
        worker failed or was stopped first)."""
        self._cutter_ready.wait()
        return self.cutter

    def end_xy(self):
        """XY of the ball centre the passes will end at, from the last piece handed over,
        before the worker gets there: the centre :meth:`_take` and :meth:`_cut` make of
        that path's last sample (kept by the forward steps, ``settle`` and ``refine``).
        ``None`` when the last piece is no path or the cutter is not built. A prediction
        for work that can start early (the pencil's links); compare it with the passes."""
        pc = self._last_piece
        if pc is None or pc.kind != "path" or self.cutter is None:  # set once built, by either thread
            return None
        S = pc.curve.sample
        if len(S.xyz) == 0:
            return None
        j = 0 if pc.reverse else len(S.xyz) - 1
        try:
            return self.cutter.cl_from_cc(S.xyz[j:j + 1], S.n[j:j + 1])[0][0, :2]
        except PlanningError:  # the worker meets it too, and raises it from finish()
            return None

    def fraction_cut(self) -> float:
        """Share of the pieces handed over so far whose CC points are cut, by their dense
        samples (0 to 1; 1 when nothing was handed over)."""
        return min(self._units_cut / self._units_added, 1.0) if self._units_added else 1.0

    def finish(self, progress=None):
        """Cut what is left; returns ``(passes, pass_ids, lifts)``.

        ``passes`` are tool-tip polylines ``(k, 3)``; ``lifts`` the drop-cutter lifts of
        the CC points (mm). ``progress(fraction)``, if given, is called while the cutter
        works (:meth:`fraction_cut`, non-decreasing, last 1.0). Raises what the worker
        raised.
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
            self._raise()
        say(1.0)
        passes, ids, lifts = [], [], []
        for p in self._done:
            if not p.centres:
                continue
            centres = np.concatenate(p.centres)
            # drop consecutive duplicates (a centre point path, link ends)
            keep = np.ones(len(centres), dtype=bool)
            keep[1:] = np.any(np.abs(np.diff(centres, axis=0)) > 1e-9, axis=1)
            passes.append(self.cutter.tip(centres[keep]))
            ids.append(p.path_id)
            lifts.extend(p.lifts)
        return passes, ids, lifts

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

    def _raise(self):
        if self._error is not None:
            raise self._error

    # -- the work ---------------------------------------------------------------------
    def _loop(self):
        ended = False  # the end marker was taken from the queue
        try:
            import numba

            numba.set_num_threads(self._nthreads)
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

    def _take(self, pc):
        t0 = time.perf_counter()
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
        cur = self._passes[-1]
        if pc.kind == "path":
            self.cc_paths.append(cc)
            if len(cc) > 1:
                self.fwd_steps.append(np.linalg.norm(np.diff(cc, axis=0), axis=1))
            if cur.path_id < 0:
                cur.path_id = pc.index
            cur.cc.append(cc)
            cur.nn.append(nn)
            cur.pending += len(cc)
            cur.units += len(X3)
        else:
            L = float(np.linalg.norm(np.diff(X3, axis=0), axis=1).sum())
            if L <= self.link_max:
                cur.cc.append(cc[1:-1])
                cur.nn.append(nn[1:-1])
                cur.pending += len(cur.cc[-1])
                cur.units += len(X3)
            else:
                self.n_retracts_link += 1
                self._units_cut += len(X3)  # nothing to cut: a retract
                self.timings["forward"] += time.perf_counter() - t0
                self._cut(cur)
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
            self._done.append(p)

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
            # The move from the last batch's end into this batch is checked here.
            if p.last is not None:
                centres = np.vstack([p.last[None], centres])
                tri = np.concatenate([[p.last_tri], tri])
            # no move floats more than settle_tol above the drop surface (the material a
            # chord leaves over a groove the ball cannot enter), then no move cuts more
            # than e / 2 into the part (an exact bound): half of the gouge budget e, the
            # other half left to the mesh facets between samples
            if self.settle_tol > 0:
                centres, n, left, tri = self.cutter.settle(centres, self.settle_tol, contacts=tri)
                self.n_settled += n
                self.n_settle_unresolved += left
            centres = self.cutter.refine(centres, self.e)
            if p.last is not None:
                centres = centres[1:]
            p.centres.append(centres)
            p.last = centres[-1]  # settle and refine keep the ends: tri[-1] is its contact
            p.last_tri = int(tri[-1])
        self._units_cut += units
        self.timings["cutter"] += time.perf_counter() - t0
