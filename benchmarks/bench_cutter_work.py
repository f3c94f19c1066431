"""Where the cutter stage's work goes in a real plan (issue 5: speed).

Plans ``MESH`` with one pattern in-process, recording every call the pass builder makes to
the ball cutter (``cl_from_cc``, ``settle_pieces``, ``refine_pieces``, batch by batch; before
session 29 it recorded only ``settle`` and ``refine``, which the pass builder no longer
calls, so its settle and refine rows were empty), then replays the recorded calls alone on
one thread, twice, each against its recorded output (a mismatch is an error: the replay
must be the plan's own work). It prints:

* per step, the core seconds (the lower of the two replays), the points in and the points
  it adds, and the time per output point;
* per round of ``settle`` and of ``refine``: the moves tested and the points inserted
  (``refine`` checks every move in one round and inserts all its points there, since
  session 47; a second round checks again, with more room, the moves that needed more
  than eight points; before, round 0 checked every move and later rounds the two halves
  of each split one);
* the CC points by *lift*, how far the drop-cutter raises the ball above the planned
  contact (the ball cannot touch the planned point: an undercut, a wall, a pocket tighter
  than the ball), and the share of the planned moves (between the centres of the CC
  points, before ``settle``) that would cut more than e/2 into the part, by the larger
  lift of their ends: where ``refine``'s insertions come from.

The plan itself runs threaded as usual (its wall time is printed for reference); the
replay runs on one thread, so its figures are core seconds, the currency that counts when
the pattern stage and the cutter share two cores.

Usage::

    python benchmarks/bench_cutter_work.py [MESH] [--scale S] [--pattern contour] [--h 0.01] [--r 4] [--e 0.01]

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea``) or a mesh file,
read as ``conformill plan FILE --scale S`` reads it (the 620k mesh of ``bench_scale.py``:
``/work/shared/meshes/large_igea_face_subdiv1.ply --scale 1400``).
"""

from __future__ import annotations

import argparse
import copy
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

#: the cutter's public entry points (the pass builder calls the first three, the pencil's
#: links ``refine``; the ``_pieces`` forms batch the passes of one call; none of these
#: calls another)
STEPS = ("cl_from_cc", "settle_pieces", "refine_pieces", "settle", "refine")
LIFT_EDGES = (0.0, 1e-3, 1e-2, 0.1, np.inf)


def record(mesh, job):
    """Plan ``job`` on ``mesh`` with the cutter's calls recorded: ``(result, calls)``,
    ``calls`` a list of ``(step, args, kwargs, output)`` in call order."""
    from conformill.cutter import BallCutter
    from conformill.pipeline import plan

    calls = []
    originals = {s: getattr(BallCutter, s) for s in STEPS}

    def wrap(step):
        f = originals[step]

        def g(self, *args, **kwargs):
            # copies: the caller goes on to change its lists of pieces (and the arrays in them)
            a, k = copy.deepcopy(args), copy.deepcopy(kwargs)
            out = f(self, *args, **kwargs)
            calls.append((step, a, k, copy.deepcopy(out)))
            return out
        return g

    try:
        for s in STEPS:
            setattr(BallCutter, s, wrap(s))
        res = plan(mesh, job)
    finally:
        for s, f in originals.items():
            setattr(BallCutter, s, f)
    return res, calls


def _same(a, b) -> bool:
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray):
        return a.shape == np.shape(b) and np.array_equal(a, b)
    return a == b


def _points(x) -> int:
    """Points in an array ``(k, d)`` or in a list of them (the ``_pieces`` forms)."""
    return len(x) if isinstance(x, np.ndarray) else sum(len(p) for p in x)


def replay(cut, calls, rounds=None):
    """Run the recorded calls again; core seconds per step. With ``rounds`` (a dict), also
    count per round the moves settle tests, and the moves refine checks and splits."""
    t = dict.fromkeys(STEPS, 0.0)
    state = {"round": 0}
    if rounds is not None:
        reaches, moves = cut._reaches, cut._refine_moves

        def count_reaches(xy, *a, **k):
            out = reaches(xy, *a, **k)
            rounds.setdefault(("settle", state["round"]), [0, 0])[0] += len(xy)
            state["round"] += 1
            return out

        def count_moves(P, seg, *a, **k):
            out = moves(P, seg, *a, **k)
            rw = rounds.setdefault(("refine", state["round"]), [0, 0])
            rw[0] += len(seg)
            rw[1] += int((out[3] != 0).sum())
            state["round"] += 1
            return out

        cut._reaches, cut._refine_moves = count_reaches, count_moves
    try:
        for step, a, k, out in calls:
            state["round"] = 0
            t0 = time.process_time()
            got = getattr(cut, step)(*a, **k)
            t[step] += time.process_time() - t0
            if not _same(got, out):
                raise SystemExit(f"replay of {step} differs from the plan's output: the replay is not the plan's work")
    finally:
        if rounds is not None:
            del cut._reaches, cut._refine_moves  # back to the class's methods
    return t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", nargs="?", default="igea",
                    help=f"one of {', '.join(_common.MESH_FILES)}, or a mesh file (read as is, times --scale)")
    ap.add_argument("--scale", type=float, default=1.0, help="for a mesh file: factor to mm (the 620k mesh: 1400)")
    ap.add_argument("--pattern", default="contour", choices=["zigzag", "contour", "spiral"])
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--e", type=float, default=0.01)
    args = ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the plan's reachability warnings

    import numba

    from conformill.cutter import BallCutter
    from conformill.pipeline import Job, plan

    mesh = _common.study_mesh(args.mesh, args.scale)
    job = Job(pattern=args.pattern, tool_radius=args.r, scallop=args.h, tolerance=args.e)
    plan(mesh, job)  # numba's caches
    t0 = time.perf_counter()
    res, calls = record(mesh, job)
    wall = time.perf_counter() - t0
    T = res.report["timings_s"]
    n_cl = sum(len(p) for p in res.toolpath.passes)
    print(f"{_common.machine()}\n{args.mesh} {args.pattern}: {mesh.n_faces} faces, h = {args.h}, r = {args.r}, "
          f"e = {args.e}; plan {wall:.2f} s wall with recording (cutter busy {T['cutter']:.2f} s, the plan "
          f"waited {T['cutter_wait']:.2f} s for it); {len(calls)} cutter calls, {n_cl} CL points")

    m = res.mesh
    cut = BallCutter(m.V, m.F, args.r)
    numba.set_num_threads(1)
    cut.drop(np.zeros((2, 2)))
    rounds = {}
    runs = [replay(cut, calls, rounds)] + [replay(cut, calls)]
    core = {s: min(r[s] for r in runs) for s in STEPS}
    n_in = {s: sum(_points(a[0]) for st, a, k, o in calls if st == s) for s in STEPS}
    n_out = {s: sum(_points(o if s in ("refine", "refine_pieces") else o[0]) for st, a, k, o in calls if st == s)
             for s in STEPS}
    print(f"\nreplay on one thread (the lower of two runs): {sum(core.values()):.2f} core s")
    print(f"  {'step':<13} {'core s':>7} {'points in':>10} {'added':>8} {'us per point out':>17}")
    for s in (s for s in STEPS if any(c[0] == s for c in calls)):
        print(f"  {s:<13} {core[s]:7.2f} {n_in[s]:10d} {n_out[s] - n_in[s]:8d} {1e6 * core[s] / max(n_out[s], 1):17.2f}")
    for step in ("settle", "refine"):
        rs = sorted(k[1] for k in rounds if k[0] == step)
        what = "moves tested" if step == "settle" else "moves checked / split"
        cells = [f"{i}: {rounds[(step, i)][0]}" + (f" / {rounds[(step, i)][1]}" if step == "refine" else "") for i in rs]
        print(f"  {step} rounds, {what}: " + ", ".join(cells))

    # CC points by lift, and where the planned moves cut into the part
    lifts, split_by, moves_by = [], np.zeros(len(LIFT_EDGES) - 1, int), np.zeros(len(LIFT_EDGES) - 1, int)
    thresh = min(0.5 * args.e, args.r)
    for step, a, k, out in calls:
        if step != "cl_from_cc":
            continue
        c, lift = out[0], out[1]
        lifts.append(lift)
        if len(c) < 2:
            continue
        d = np.diff(c, axis=0)
        seg = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) > 1e-9)
        cuts = cut._refine_moves(c, seg, thresh, (args.r - thresh) ** 2, 16, 8)[3] != 0  # a point inserted
        cls = np.digitize(np.maximum(lift[seg], lift[seg + 1]), LIFT_EDGES[1:-1])
        moves_by += np.bincount(cls, minlength=len(moves_by))
        split_by += np.bincount(cls[cuts], minlength=len(split_by))
    lift = np.concatenate(lifts)
    cls = np.digitize(lift, LIFT_EDGES[1:-1])
    print(f"\nCC points by lift (mm), and the planned moves (before settle) that cut more than e/2 = {thresh:g} "
          f"mm, by the larger lift of their ends:")
    for i in range(len(LIFT_EDGES) - 1):
        lo, hi = LIFT_EDGES[i], LIFT_EDGES[i + 1]
        print(f"  [{lo:g}, {hi:g}): {100 * np.mean(cls == i):5.1f} % of {len(lift)} CC points; moves {moves_by[i]:7d}, "
              f"cutting in {split_by[i]:6d} ({100 * split_by[i] / max(moves_by[i], 1):4.1f} %)")
    print(f"  all: moves {moves_by.sum()}, cutting in {split_by.sum()} ({100 * split_by.sum() / max(moves_by.sum(), 1):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
