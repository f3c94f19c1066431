"""What it would take to meet 1.05 h on a scan's reachable area: four prototypes, measured.

Not part of the product. On igea the judged p99.9 of a conformill program is 1.52-1.61 h
without the settle check (``plan --settle 0``, session 12) and 1.25-1.41 h with it
(session 13); what is left above 1.05 h sits mostly at the rims of the regions tighter
than the ball, where the least material any ball leaves (the rest) is 0.5-1.05 h.
This script takes a kept program (``bench_raster.py --keep DIR``) and measures, each
judged by ``verify`` on its own samples (400k, seed 0, limit 1.05 h, reach depth h):

``--mode stepover``
    the same pattern planned for smaller scallop heights (``--factors``), i.e. a finer
    stepover everywhere;
``--mode best``
    the program plus extra passes through the best ball centres of the planner-side
    samples (``--samples``, seed 7, *not* the judge's): the tangent ball dropped, then the
    rest search (:func:`conformill.verify.rest.rest_material`, one start) where it leaves more than
    ``--low`` h; the centres of the samples with a rest in (low h, h], thinned to 0.03 mm
    and chained greedily where they lie within ``--link`` mm; each chain refined by the
    drop-cutter (gouge-safe) and cut as its own pass between retracts;
``--mode creases``
    the program plus passes along the creases of the drop surface: drops on a grid of
    ``--grid`` mm, cells where the slope changes by more than ``--kink`` (dimensionless)
    across the cell in one of four directions, chained per connected component, each point moved
    across the chain to where the drop height lies lowest below the chord (the fold).
``--mode kinks``
    the program plus passes along the valleys its own passes cross (session 20): every CL
    point where the program's centre polyline bends by more than ``--kmin`` rad (the 3D
    angle between its two feed moves) and lies below the chord of its neighbours (a fold or
    a tight valley of the drop surface, crossed by a pass), chained greedily in XY where
    they lie within ``--link`` mm (on a scan the passes lie closer than the points along
    them, so the chains mostly run across passes), each chain moved onto the fold as in
    ``creases``; no extra drops to find them, but the program's own kinks are many.

``--settle F`` settles each extra pass (``BallCutter.settle`` with ``F h``) before it is
refined; 0 (default) as in session 12's runs.

Usage::

    python benchmarks/bench_cleanup.py igea DIR/igea_contour_h0.01.nc --mode best --samples 1000000 --low 0.15
    python benchmarks/bench_cleanup.py igea DIR/igea_contour_h0.01.nc --mode creases --grid 0.1 --kink 0.4
    python benchmarks/bench_cleanup.py igea DIR/igea_contour_h0.01.nc --mode stepover --pattern contour
    python benchmarks/bench_cleanup.py igea DIR/igea_contour_h0.01.nc --mode kinks --kmin 0.15 --link 0.5 --settle 0.5
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import load_part  # noqa: E402

from conformill.cutter import BallCutter  # noqa: E402
from conformill.verify.gcode import read_gcode  # noqa: E402
from conformill.verify.simulate import verify  # noqa: E402


def judge(mesh, path, r, h, e):
    res = verify(mesh, read_gcode(path), r, n_samples=400_000, seed=0, scallop=1.05 * h, gouge=e,
                 reach_depth=h, judge="reachable")
    q, s = res.summary["reachable"], res.summary
    return (f"p99.9 {q['scallop']['p999'] / h:.3f} h, p99 {q['scallop']['p99'] / h:.3f} h, above 1.05 h "
            f"{100 * q['above_scallop_fraction']:.3f} %, gouge {1000 * s['gouge_max']:.1f} um, rapid clearance "
            f"{s['rapid_min_clearance']:.2f} mm: {'PASS' if s['pass'] else 'FAIL'}")


def chain(points, link):
    """Greedy nearest-neighbour chains of ``points (k, 2+)`` (XY), links at most ``link`` long."""
    tree = cKDTree(points[:, :2])
    degree = np.array([len(x) for x in tree.query_ball_point(points[:, :2], link)])
    left = np.ones(len(points), dtype=bool)
    out = []
    while left.any():
        free = np.flatnonzero(left)
        k = int(free[np.argmin(degree[free])])  # start at an end
        ch = [k]
        left[k] = False
        for at_end in (True, False):
            while True:
                cur = ch[-1] if at_end else ch[0]
                d, j = tree.query(points[cur, :2], k=min(16, len(points)))
                nxt = next((int(b) for a, b in zip(np.atleast_1d(d), np.atleast_1d(j)) if left[b] and a <= link),
                           None)
                if nxt is None:
                    break
                left[nxt] = False
                if at_end:
                    ch.append(nxt)
                else:
                    ch.insert(0, nxt)
        out.append(points[ch])
    return out


def best_centres(mesh, cut, r, h, n, low, grid=9, levels=4, max_tangent=np.inf, dump=None):
    """Best ball centres of the planner-side samples whose rest is in (low h, h].

    The search is :func:`conformill.verify.rest.rest_material` with one start, a first grid
    of ``grid`` x ``grid`` centres over +-0.2 r and ``levels`` refining grids of the same
    size (session 12: 9 and 4, about 405 drops per sample). Only samples whose tangent ball
    leaves more than ``low`` h and at most ``max_tangent`` h are searched. ``dump``: an
    ``.npz`` with the tangent rest, rest and centre of every searched sample.
    """
    from conformill.verify.rest import _SPANS, rest_material, tangent_rest
    from conformill.verify.samples import sample_surface

    S = sample_surface(mesh.V, mesh.F, n, seed=7)
    P, N = S.points, S.normals
    up = N[:, 2] > 0
    t = np.full(len(P), np.inf)
    t[up] = tangent_rest(cut, P[up], N[up])
    cand = np.flatnonzero(up & (t > low * h) & (t <= max_tangent * h))
    # the planner side may search cheaply (one start): a missed better ball only costs a pass
    rest, C = rest_material(cut, P[cand], N[cand], centres=True, starts=1, coarse=(0.2, grid),
                            refine=(grid, _SPANS[:levels]))
    if dump:
        np.savez_compressed(dump, tangent=t[cand], rest=rest, centre=C)
    B = C[(rest > low * h) & (rest <= h) & np.isfinite(C[:, 2])]
    print(f"  {n} samples, {cand.size} searched ({grid} x {grid} grids, {levels} refining levels, tangent rest "
          f"in ({low}, {max_tangent}] h), {len(B)} with a rest in ({low} h, h]")
    # thin to 0.03 mm
    tree = cKDTree(B[:, :2])
    taken = np.zeros(len(B), dtype=bool)
    keep = []
    for i in np.argsort(B[:, 0], kind="stable"):
        if not taken[i]:
            keep.append(i)
            taken[tree.query_ball_point(B[i, :2], 0.03)] = True
    return B[keep]


def crease_chains(mesh, cut, g, kink):
    lo, hi = mesh.V[:, :2].min(0), mesh.V[:, :2].max(0)
    X, Y = np.meshgrid(np.arange(lo[0], hi[0] + g, g), np.arange(lo[1], hi[1] + g, g))
    D = cut.drop(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
    fin = np.isfinite(D)
    flag = np.zeros_like(fin)
    with np.errstate(invalid="ignore"):
        for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
            a = np.roll(D, (di, dj), axis=(0, 1))
            b = np.roll(D, (-di, -dj), axis=(0, 1))
            f = fin & np.isfinite(a) & np.isfinite(b) & ((a + b - 2 * D) / (g * np.hypot(di, dj)) > kink)
            f[[0, -1], :] = False
            f[:, [0, -1]] = False
            flag |= f
    lab, n = ndimage.label(flag, structure=np.ones((3, 3)))
    print(f"  {X.size} drops on a {g} mm grid, {int(flag.sum())} crease cells in {n} components")
    idx = np.flatnonzero(flag.ravel())
    pts = np.column_stack([X.ravel()[idx], Y.ravel()[idx]])
    comp = lab.ravel()[idx]
    out = []
    for c in range(1, n + 1):
        P = pts[comp == c]
        if len(P) < 4:
            continue
        for ch in chain(P, 2.5 * g):
            if len(ch) < 4:
                continue
            out.append(to_fold(cut, ch, (g, 0.2 * g)))
    return out


def to_fold(cut, ch, spans):
    """Centres of chain ``ch (k, 2+)`` (XY used) moved across the chain onto the fold of the
    drop surface: for each span, the lowest of 11 drops below their chord across the chain."""
    T = np.gradient(ch[:, :2], axis=0)
    T /= np.maximum(np.linalg.norm(T, axis=1, keepdims=True), 1e-12)
    Nn = np.column_stack([-T[:, 1], T[:, 0]])
    best = ch[:, :2]
    z = None
    for span in spans:
        off = np.linspace(-span, span, 11)
        Q = best[:, None, :] + off[None, :, None] * Nn[:, None, :]
        Dq = cut.drop(Q.reshape(-1, 2)).reshape(len(best), -1)
        lin = Dq[:, :1] + (Dq[:, -1:] - Dq[:, :1]) * ((off + span) / (2 * span))[None, :]
        j = np.argmin(np.where(np.isfinite(Dq - lin), Dq - lin, np.inf), axis=1)
        best, z = Q[np.arange(len(best)), j], Dq[np.arange(len(best)), j]
    cen = np.column_stack([best, z])
    return cen[np.isfinite(cen[:, 2])]


def kink_chains(cut, prog, r, kmin, link, spans=(0.1, 0.02)):
    """Chains of the valley kinks of a program's centre polyline, moved onto the fold."""
    P = prog.points + np.array([0.0, 0.0, r])
    m = prog.motion
    i = np.flatnonzero((m[1:-1] == 1) & (m[2:] == 1)) + 1  # points between two feed moves
    a, b = P[i] - P[i - 1], P[i + 1] - P[i]
    la, lb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ok = (la > 1e-6) & (lb > 1e-6)
    i, a, b, la, lb = i[ok], a[ok], b[ok], la[ok], lb[ok]
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", a, b) / (la * lb), -1.0, 1.0))
    below = P[i, 2] < P[i - 1, 2] + la / (la + lb) * (P[i + 1, 2] - P[i - 1, 2]) - 1e-9  # a valley
    K = P[i[below & (turn > kmin)]]
    chains = [c for c in chain(K, link) if len(c) >= 3] if len(K) else []
    print(f"  {len(K)} valley kinks above {kmin} rad of {len(i)} CL points, {len(chains)} chains of 3 or more")
    return [to_fold(cut, c, spans) for c in chains]


def append_passes(src: Path, dst: Path, centres, r, safe):
    lines = src.read_text().rstrip().split("\n")
    end = [ln for ln in lines if ln.strip().upper() in ("M2", "M30", "%")]
    out = [ln for ln in lines if ln not in end]
    for cen in centres:
        tip = cen - [0.0, 0.0, r]
        out += [f"G0 Z{safe:.4f}", f"G0 X{tip[0, 0]:.4f} Y{tip[0, 1]:.4f}", f"G1 Z{tip[0, 2]:.4f} F1000"]
        out += [f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f}" for x, y, z in tip[1:]]
        out.append(f"G0 Z{safe:.4f}")
    dst.write_text("\n".join(out + end) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("program")
    ap.add_argument("--mode", choices=("stepover", "best", "creases", "kinks"), required=True)
    ap.add_argument("--pattern", default="contour", help="stepover mode: the pattern to plan")
    ap.add_argument("--factors", type=float, nargs="*", default=[0.7, 0.5, 0.35])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--low", type=float, default=0.15)
    ap.add_argument("--grid-n", type=int, default=9, help="best mode: size of the search grids")
    ap.add_argument("--levels", type=int, default=4, help="best mode: refining levels (at most 4)")
    ap.add_argument("--max-tangent", type=float, default=np.inf,
                    help="best mode: search only samples whose tangent ball leaves at most this (x h)")
    ap.add_argument("--dump", default=None, help="best mode: .npz of the searched samples")
    ap.add_argument("--link", type=float, default=0.3)
    ap.add_argument("--grid", type=float, default=0.1)
    ap.add_argument("--kink", type=float, default=0.4)
    ap.add_argument("--kmin", type=float, default=0.08, help="kinks mode: least bend (rad) of the centre polyline at a point below its neighbours' chord")
    ap.add_argument("--settle", type=float, default=0.0, help="settle the extra passes to F h (0: off)")
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--e", type=float, default=0.01)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)
    mesh, _ = load_part(args.mesh)
    r, h, e = args.r, args.h, args.e
    src = Path(args.program)
    print(f"{args.mesh}: {src.name} as kept: {judge(mesh, src, r, h, e)}", flush=True)
    tmp = Path(tempfile.mkdtemp(prefix="cm_cleanup_"))
    if args.mode == "stepover":
        from conformill.output.gcode import write_gcode
        from conformill.pipeline import Job, plan

        for f in args.factors:
            t = time.perf_counter()
            res = plan(mesh, Job(pattern=args.pattern, tool_radius=r, scallop=f * h, tolerance=e))
            wall = time.perf_counter() - t
            p = tmp / f"{args.pattern}_{f:g}h.nc"
            write_gcode(p, res.toolpath, feed=1000.0)
            feed = sum(float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum()) for q in res.toolpath.passes)
            print(f"planned for {f:g} h: {wall:.1f} s, feed {feed / 1000:.2f} m: {judge(mesh, p, r, h, e)}", flush=True)
        return 0
    cut = BallCutter(mesh.V, mesh.F, r)
    t = time.perf_counter()
    if args.mode == "best":
        chains = chain(best_centres(mesh, cut, r, h, args.samples, args.low, args.grid_n, args.levels,
                                    args.max_tangent, args.dump), args.link)
    elif args.mode == "kinks":
        chains = kink_chains(cut, read_gcode(src), r, args.kmin, args.link)
    else:
        chains = crease_chains(mesh, cut, args.grid, args.kink)
    chains = [c for c in chains if len(c) >= 2]
    if args.settle > 0:
        chains = [cut.settle(c, args.settle * h)[0] for c in chains]
    passes = [cut.refine(c, e) for c in chains]
    wall = time.perf_counter() - t
    extra = sum(float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) for c in passes)
    print(f"  {len(passes)} extra passes, {sum(len(c) for c in passes)} CL points, {extra / 1000:.2f} m of feed, "
          f"{wall:.1f} s", flush=True)
    dst = tmp / f"{src.stem}_{args.mode}.nc"
    append_passes(src, dst, passes, r, float(mesh.V[:, 2].max()) + 5.0)
    print(f"with them ({dst}): {judge(mesh, dst, r, h, e)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
