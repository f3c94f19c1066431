"""How much of the fold pencil the pattern makes unnecessary (issue 5, session 30: a lead).

``plan --pencil --pencil-search folds`` cuts a pencil pass through every fold point whose
shadow is deeper than 0.15 h, and through the steep centres, whatever the pattern left
there. This script asks which of them the pattern had already cut. It plans one mesh and
pattern without the pencil, then measures the pattern's own program with verify's
``remaining_material``. For each fold point it reads three points: the part's top a quarter,
half and three quarters of the way between the two contacts, with the material measured
towards the wedged centre. For each steep centre it reads its surface sample, along the
sample's normal. It prints:

* at the shadows' middles, the share the pattern leaves above h, and how many of those the
  wedged ball itself would bring within h (where a pencil pass changes the verdict);
* per threshold ``FOLD[,STEEP]`` (units of h; FOLD alone keeps every steep centre; ``all``:
  the stage as it is): the pencil built the stage's way (chains, settling, links, refine)
  through only the fold points (and steep centres) where the pattern left more than the
  threshold at one of their points, appended to the pattern's program, written, and
  verified as ``bench_raster.py`` does (400k samples, seed 0, limit 1.05 h, reach depth h,
  the reachable judge).

This was the prototype (session 30) of ``plan --pencil-left`` (session 31), which reads the
same three shadow points but with the planner's own estimate of the pattern's rest
(:mod:`conformill.pattern_rest`; verify's simulation is independent of the planner by
design): on igea zigzag both give 161.3 m at 1.036-1.038 h for fold points above 0.5 h.

    python benchmarks/bench_pencil_filter.py [MESH] [--pattern zigzag] [--density 30] [--hop 0]
        [--thresholds all 0.5 0.5,0 0.3]

Session 30 (igea zigzag, density 30, no hops): ``all`` 171.5 m, 1.036 h; fold points above
0.5 h only 161.3 m, 1.036 h; both at 0.5 h 158.4 m, 1.042 h (docs/issue5.md, "What stands in the way").
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402

#: Where between the two contacts of a fold point the pattern's rest is read.
SHADOW_AT = (0.25, 0.5, 0.75)


def _threshold(text):
    if text == "all":
        return None
    v = [float(x) for x in text.split(",")]
    if len(v) == 1:
        v.append(-np.inf)  # the steep centres all kept
    if len(v) != 2:
        raise ValueError(f"a threshold is FOLD[,STEEP] in units of h, or 'all', got {text!r}")
    return tuple(v)


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.set_defaults(pattern="zigzag")
    ap.add_argument("--density", type=float, default=30.0, help="the fold pencil's density (default 30)")
    ap.add_argument("--hop", type=float, default=0.0, help="--hop-lifted of the pattern (default 0: off)")
    ap.add_argument("--thresholds", nargs="*", default=["all", "0.5", "0.5,0.5", "0.3,0.3"])
    args = ap.parse_args(argv)
    try:
        thresholds = [(t, _threshold(t)) for t in args.thresholds]
    except ValueError as exc:
        ap.error(str(exc))
    from conformill import pencil
    from conformill.cutter import BallCutter
    from conformill.folds import part_tops
    from conformill.pipeline import Job, plan
    from conformill.types import ToolPath
    from conformill.verify.samples import SurfaceSamples
    from conformill.verify.simulate import remaining_material

    h, r, e, D = args.h, args.r, args.e, args.density
    mesh, samples = _common.scan_study(args)
    job = Job(pattern=args.pattern, tool_radius=r, scallop=h, tolerance=e, hop_lift=args.hop)
    res = plan(mesh, job)
    tp0 = res.toolpath
    prog0, st0 = _common.written(tp0)
    m = res.mesh
    cut = BallCutter(m.V, m.F, r)
    spacing = 1.0 / math.sqrt(D)
    fp, keep = pencil.fold_centres(cut, spacing, h)
    C, qa, qb = fp.centres[keep], fp.contact_a[keep], fp.contact_b[keep]
    areas = pencil._face_areas(m.V, m.F)
    P, N, faces = pencil.surface_samples(m.V, m.F, min(D, pencil._MAX_SAMPLES / float(areas.sum())), 0, areas=areas,
                                         below_nz=pencil._STEEP_NZ)
    Cs, rest_s, state = pencil.best_centres(cut, P, N, faces, low=0.15 * h, give_up=max(pencil._GIVE_UP, 1.0) * h)
    useful = (state == 1) & (rest_s > 0.15 * h) & (rest_s <= h) & np.isfinite(Cs[:, 2])
    steep, Ps, Ns = Cs[useful], P[useful], N[useful]
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern}, hop {args.hop:g}, r = {r:g}, h = {h:g}, e = {e:g}; "
          f"the pattern alone {st0['feed_length_mm'] / 1000:.1f} m; fold density {D:g}: {len(C)} fold points kept, "
          f"{len(steep)} steep centres", flush=True)

    # the pattern's rest: at each fold point's shadow points (towards the wedged centre) and at
    # each steep centre's sample (along its normal), in one cast
    k = len(C)
    M = np.vstack([qa + f * (qb - qa) for f in SHADOW_AT])
    z = part_tops(cut, M[:, :2])
    pts, nrm, ok = [], [], []
    for i in range(len(SHADOW_AT)):
        zi, Mi = z[i * k:(i + 1) * k], M[i * k:(i + 1) * k]
        good = np.isfinite(zi)
        Q = np.column_stack([Mi[:, :2], np.where(good, zi, Mi[:, 2])])
        d = C - Q
        pts.append(Q)
        nrm.append(d / np.linalg.norm(d, axis=1, keepdims=True))
        ok.append(good)
    pts.append(Ps)
    nrm.append(Ns)
    Q, Nq = np.vstack(pts), np.vstack(nrm)
    t0 = time.perf_counter()
    rest = remaining_material(SurfaceSamples.from_arrays(Q + 1e-6 * Nq, Nq), prog0, r)[0]
    t_cast = time.perf_counter() - t0
    fold_rest = np.zeros(k)
    for i, good in enumerate(ok):
        fold_rest = np.maximum(fold_rest, np.where(good, rest[i * k:(i + 1) * k], 0.0))
    steep_rest = rest[len(SHADOW_AT) * k:]
    mid = SHADOW_AT.index(0.5)
    mid_rest = np.where(ok[mid], rest[mid * k:(mid + 1) * k], 0.0)
    wedged = np.linalg.norm(C - pts[mid], axis=1) - r  # what the wedged ball leaves there
    above = mid_rest > h
    print(f"the pattern's rest at {len(Q)} points: {t_cast:.2f} s wall; at the shadows' middles above h: "
          f"{100 * above.mean():.1f} %, of which the wedged ball brings {int((above & (wedged <= h)).sum())} "
          f"({100 * (above & (wedged <= h)).mean():.1f} % of the fold points) within h", flush=True)

    start = tp0.passes[-1][-1, :2] if tp0.passes else m.V[:, :2].mean(axis=0)
    link_max = res.report["job"]["link_max"]
    rows = []
    for name, thr in thresholds:
        sel = np.ones(k, bool) if thr is None else fold_rest > thr[0] * h
        ssel = np.ones(len(steep), bool) if thr is None else steep_rest > thr[1] * h
        c0 = time.process_time()
        B = np.vstack([C[sel], steep[ssel]])
        found = pencil.chains_of(cut, pencil.PencilFound(centres=B, probes=np.full((len(B), 1, 3), np.nan),
                                                         spacing=spacing), 1, job.settle * h)
        pen = pencil.link_chains(cut, found, e, link_max, start)
        cpu = time.process_time() - c0
        tp = ToolPath(passes=list(tp0.passes) + [cut.tip(p) for p in pen.passes], safe_z=tp0.safe_z,
                      pass_ids=list(tp0.pass_ids) + [-1] * len(pen.passes),
                      hops=(list(tp0.hops) + [None] * len(pen.passes)) if tp0.hops else [])
        prog, st = _common.written(tp)
        s = _common.verify_program(m, prog, samples, h, r, e).summary["reachable"]["scallop"]
        rows.append((name, int(sel.sum()), int(ssel.sum()), cpu, pen.stats["feed_mm"] / 1000,
                     st["feed_length_mm"] / 1000, st["machining_time_min"], s["p999"] / h, s["p99"] / h))
        print(f"  {name}: {rows[-1][1]} fold points, {rows[-1][2]} steep; chains and links {cpu:.2f} CPU-s; "
              f"pencil {rows[-1][4]:.1f} m; program {rows[-1][5]:.1f} m, {rows[-1][6]:.1f} min; "
              f"reachable p99.9 {rows[-1][7]:.4f} h, p99 {rows[-1][8]:.3f} h", flush=True)
    print()
    _common.print_table([("kept above (x h): fold, steep", ""), ("fold points", "d"), ("steep centres", "d"),
                         ("chains + links cpu s", ".2f"), ("pencil feed m", ".1f"), ("feed m", ".1f"),
                         ("min at feed", ".1f"), ("reachable p99.9 / h", ".4f"), ("p99 / h", ".3f")], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
