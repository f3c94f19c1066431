"""What the scallop limit costs on a scan: plan variants against their verified scallop, one run.

Issue 5 asks, on the 50k-150k-face meshes, for conformill at least 20x faster than
OpenCAMLib's raster *and* a verified scallop within 1.05 h. On the igea scan the default
plan is about 20x but leaves 1.26 h at p99.9 (docs/issue5.md, "Against an OpenCAMLib raster"). This
script measures, on one mesh and one pattern, how the verified scallop moves with the feed
length and the time for the knobs that densify the program:

* ``settle S``: ``Job.settle`` (the largest float of a move above the drop surface, x h);
* ``planned F h``: the paths spaced for ``F h`` (``--scallop``), judged at h;
* ``local``: ``--spacing local`` (sparser paths that dent locally);
* ``fit split``: ``Job.fit = "split"`` (``--fit split``): only the planner's curvature fit
  works on the split mesh below; the cutter stays on the input mesh;
* ``pencil``: ``Job.pencil`` (``--pencil``): pencil passes through the wedged balls after
  the pattern (:mod:`conformill.pencil`), found by the default search (per surface sample)
  at the default 30 or the given samples per mm^2; ``pencil folds`` / ``pencil samples``: by
  the named search (``--pencil-search``; session 23's runs, on f73ad9e, had ``folds`` as
  the default, so their ``pencil`` rows are the fold search); ``pencil folds, settle off`` /
  ``settle 1``: the fold search over a pattern with ``Job.settle`` 0 / 1 (session 24);
* ``hop L`` (with ``, pencil folds`` and ``, density 20``): ``Job.hop_lift`` L (``--hop-lifted``,
  session 27): the runs lifted more than L mm are hopped over where that is quicker;
* ``..., left 0.5``: the same fold pencil cut only through the fold points where the
  pattern's passes left more than 0.5 h (``Job.pencil_left``, ``--pencil-left``; session 31);
* ``scan`` (``, planned F h``): ``plan --scan`` (:func:`conformill.pipeline.scan_recipe`,
  session 35), with the paths spaced for ``F h``; ``scan, no fill``: the recipe of sessions
  35-52, without the fill stage and with the pattern's paths spaced for h; ``scan, paths
  for F h``: the recipe with the pattern's paths spaced for ``F h`` (its own: 1.3 h) and
  the fill (session 53, :mod:`conformill.fill`);
* ``fine``: the same job on the same surface split once more (every triangle into four at its
  edge midpoints, :func:`conformill.mesh.split.split_midpoints`; a planar split, so the surface and the
  drop-cutter's heights are the same): the per-vertex quadratic fit then works at half the
  edge length (both the planner and the cutter run
  on the split mesh, so its time includes a cutter on four times the faces).

Every program is written as G-code, read back and verified on the *original* mesh with the
same 400k area-uniform samples (seed 0), limit 1.05 h and reach depth h, exactly as
``bench_raster.py`` does; so the p99.9 columns of one run compare directly. Time: ``plan`` +
``write_gcode`` in-process after a warm-up (wall and CPU); with ``--ocl`` OpenCAMLib's raster
is run once in the same process and the ratio printed. Its time moves more with the host
than the plan's (106-173 s on igea within one hour in session 38): ``--ocl-runs N`` times it
N times, once before the variants and the rest after them, and the ratios use the median.

    python benchmarks/bench_tradeoff.py [MESH] [--pattern contour] [--h 0.01] [--samples 400000]
        [--variants default "settle 0.25" ...] [--ocl [--ocl-runs N]] [--keep DIR] [--subdivide K]

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea``). ``--subdivide K``
splits every triangle of it into four at its edge midpoints K times first
(:func:`conformill.mesh.split.split_midpoints`: the same surface with 4^K times the faces;
choi's 34144 faces become 136576, inside the 50k-150k faces of issue 5's comparison), and
everything, the raster and the verify included, runs on the split mesh.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
import bench_raster as BR  # noqa: E402

#: name -> (Job overrides, factor on the planned scallop, split the mesh once)
VARIANTS = {
    "default": ({}, 1.0, False),
    "settle 0.25": ({"settle": 0.25}, 1.0, False),
    "settle off": ({"settle": 0.0}, 1.0, False),
    "local": ({"spacing": "local"}, 1.0, False),
    "planned 0.7 h": ({}, 0.7, False),
    "planned 0.5 h": ({}, 0.5, False),
    "planned 0.4 h": ({}, 0.4, False),
    "fine": ({}, 1.0, True),
    "fine, settle 0.25": ({"settle": 0.25}, 1.0, True),
    "fine, settle 0.25, planned 0.8 h": ({"settle": 0.25}, 0.8, True),
    "fit split": ({"fit": "split"}, 1.0, False),
    "fit split, settle 0.25": ({"fit": "split", "settle": 0.25}, 1.0, False),
    "fit split, settle 0.25, planned 0.8 h": ({"fit": "split", "settle": 0.25}, 0.8, False),
    "fit split, settle 0.25, planned 0.7 h": ({"fit": "split", "settle": 0.25}, 0.7, False),
    "pencil": ({"pencil": True}, 1.0, False),
    "pencil, density 20": ({"pencil": True, "pencil_density": 20.0}, 1.0, False),
    "pencil, density 43": ({"pencil": True, "pencil_density": 43.0}, 1.0, False),
    "pencil folds": ({"pencil": True, "pencil_search": "folds"}, 1.0, False),
    "pencil samples": ({"pencil": True, "pencil_search": "samples"}, 1.0, False),
    "pencil folds, settle off": ({"pencil": True, "pencil_search": "folds", "settle": 0.0}, 1.0, False),
    "pencil folds, settle 1": ({"pencil": True, "pencil_search": "folds", "settle": 1.0}, 1.0, False),
    "pencil folds, density 20": ({"pencil": True, "pencil_search": "folds", "pencil_density": 20.0}, 1.0, False),
    "pencil folds, density 15": ({"pencil": True, "pencil_search": "folds", "pencil_density": 15.0}, 1.0, False),
    "pencil folds, density 10": ({"pencil": True, "pencil_search": "folds", "pencil_density": 10.0}, 1.0, False),
    "local, pencil folds": ({"spacing": "local", "pencil": True, "pencil_search": "folds"}, 1.0, False),
    "local, pencil folds, density 20": ({"spacing": "local", "pencil": True, "pencil_search": "folds",
                                         "pencil_density": 20.0}, 1.0, False),
}
for _L in (1.0, 3.0, 6.0):
    VARIANTS[f"hop {_L:g}"] = ({"hop_lift": _L}, 1.0, False)
    VARIANTS[f"hop {_L:g}, pencil folds"] = ({"hop_lift": _L, "pencil": True, "pencil_search": "folds"}, 1.0, False)
    VARIANTS[f"hop {_L:g}, pencil folds, density 20"] = ({"hop_lift": _L, "pencil": True, "pencil_search": "folds",
                                                         "pencil_density": 20.0}, 1.0, False)
# session 35: plan --scan (pipeline.SCAN_RECIPE), and with the paths planned for less than h
from conformill.pipeline import SCAN_RECIPE, scan_recipe  # noqa: E402

for _f in (1.0, 0.9, 0.8):  # (the pattern's own pattern_scallop is added in main: pipeline.scan_recipe)
    VARIANTS["scan" if _f == 1.0 else f"scan, planned {_f:g} h"] = (dict(SCAN_RECIPE), _f, False)
# session 53: the recipe before its fill (the pattern's paths spaced for h, no fill passes:
# sessions 35-52's --scan), and the fill with the paths spaced for F h
VARIANTS["scan, no fill"] = ({**SCAN_RECIPE, "fill": None, "pattern_scallop": 1.0}, 1.0, False)
for _f in (1.0, 1.5):
    VARIANTS[f"scan, paths for {_f:g} h"] = ({**SCAN_RECIPE, "pattern_scallop": _f}, 1.0, False)
# session 31: the fold pencil only where the pattern left more than 0.5 h (Job.pencil_left)
for _name in [n for n in VARIANTS if "pencil folds" in n and "settle" not in n]:
    VARIANTS[f"{_name}, left 0.5"] = ({**VARIANTS[_name][0], "pencil_left": 0.5}, *VARIANTS[_name][1:])


def main(argv=None) -> int:
    ap = _common.scan_job_parser(__doc__, BR.PATTERNS)
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--ocl", action="store_true", help="also time OpenCAMLib's raster once (minutes on igea)")
    ap.add_argument("--ocl-runs", type=int, default=1, metavar="N",
                    help="with --ocl: time the raster N times, the first before the variants and the others "
                         "after them; the ratios use the median (default 1)")
    ap.add_argument("--keep", default=None, help="folder to keep the programs in")
    ap.add_argument("--subdivide", type=int, default=0, metavar="K",
                    help="split every triangle of the part into four K times first (the same surface)")
    args = ap.parse_args(argv)
    import logging

    logging.disable(logging.WARNING)
    from conformill.output.gcode import write_gcode
    from conformill.pipeline import Job, orient_mesh, plan
    from conformill.mesh.split import split_midpoints
    from conformill.types import Mesh

    def split_once(m, tag):  # the same surface, every triangle split into four at its edge midpoints
        Vs, Fs, _ = split_midpoints(m.V, m.F)
        return Mesh(V=Vs, F=Fs, name=m.name + tag)

    h, r, e = args.h, args.r, args.e
    mesh, _ = _common.load_part(args.mesh)
    for _k in range(max(args.subdivide, 0)):
        mesh = split_once(mesh, "_x4")
    mesh, _ = orient_mesh(mesh, "none")  # as plan() sees it: the verify mesh is the planned one
    print(_common.machine())
    print(f"{mesh.name}: {mesh.n_faces} faces; {args.pattern}, r = {r:g}, h = {h:g}, e = {e:g}; "
          f"verify: {args.samples} samples, seed 0, limit 1.05 h, reach depth h", flush=True)
    BR.warm_up()
    ocl_runs = []

    def time_ocl():
        ras = BR.ocl_zigzag(mesh, r, h, sampling)
        ocl_runs.append(ras["wall_s"])
        # its CPU time too: OpenCAMLib's drops run on OpenMP threads (about 1.9x its wall on 2 cores)
        print(f"OpenCAMLib raster: {ras['wall_s']:.1f} s wall, {ras['cpu_s']:.1f} s CPU, {ras['cl_points']} CL points",
              flush=True)

    if args.ocl:
        k1, k2 = _common.principal_curvatures(mesh)
        sampling, _ = BR.raster_sampling(mesh, k1, k2, r, e)
        time_ocl()  # the first run before the variants, the others after them (the host's spells hit both)
    samples = _common.verify_samples(mesh, args.samples, r)
    reach = _common.reachable_samples(mesh, samples, r, tol=h)
    split = None
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in args.variants:
            over, factor, fine = VARIANTS[name]
            if over.get("fill") is not None and "pattern_scallop" not in over:  # the recipe's, for this pattern
                over = {**over, "pattern_scallop": scan_recipe(args.pattern)["pattern_scallop"]}
            if fine and split is None:
                split = split_once(mesh, "_split")
            job = Job(pattern=args.pattern, tool_radius=r, scallop=factor * h, tolerance=e, **over)
            path = folder / f"{mesh.name}_{args.pattern}_{name.replace(' ', '_').replace(',', '')}.nc"
            t0, c0 = time.perf_counter(), time.process_time()
            res = plan(split if fine else mesh, job)
            st = write_gcode(path, res.toolpath, feed=1000.0, plunge_feed=1000.0 / 3)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            m = BR.measure(mesh, path, r, h, e, samples, reach, res.toolpath.safe_z)
            vr = m["verify_reach"]
            row = {"variant": name, "wall": wall, "cpu": cpu, "cl": res.report["paths"]["cl_points"],
                   "feed_m": m["feed_mm"] / 1000, "p999": vr["p999"] / h, "p99": vr["p99"] / h,
                   "excused": vr["beyond_any_ball"], "gouge_um": 1000 * m["gouge_max"], "rs274": m["rs274"],
                   "passes": len(res.toolpath.passes), "minutes": st["machining_time_min"]}
            rows.append(row)
            print(f"  {name}: {wall:.2f} s wall, {cpu:.2f} s cpu, {row['cl']} CL points, {row['feed_m']:.1f} m; "
                  f"reachable p99.9 {row['p999']:.3f} h, p99 {row['p99']:.3f} h", flush=True)
    ocl_s = None
    if args.ocl:
        for _ in range(max(args.ocl_runs, 1) - 1):
            time_ocl()
        ocl_s = float(statistics.median(ocl_runs))
        if len(ocl_runs) > 1:
            print(f"OpenCAMLib raster, {len(ocl_runs)} runs: " + " / ".join(f"{x:.1f}" for x in ocl_runs)
                  + f" s; the ratios use the median, {ocl_s:.1f} s")
    base = next((x for x in rows if x["variant"] == "default"), None)
    print()
    print("| variant | plan + G-code s (cpu s) | " + ("OCL time / this | " if ocl_s else "")
          + "CL points | passes | feed m (x default) | min at feed | reachable p99.9 / h | p99 / h | excused | "
          "gouge um | rs274 |")
    print("|---|---|" + ("---|" if ocl_s else "") + "---|---|---|---|---|---|---|---|---|")
    for x in rows:
        ratio = f"{ocl_s / x['wall']:.1f} | " if ocl_s else ""
        rel = f"{x['feed_m'] / base['feed_m']:.2f}" if base else "-"
        print(f"| {x['variant']} | {x['wall']:.2f} ({x['cpu']:.2f}) | {ratio}{x['cl']} | {x['passes']} | "
              f"{x['feed_m']:.1f} ({rel}) | {x['minutes']:.1f} | {x['p999']:.3f} | {x['p99']:.3f} | "
              f"{x['excused']} | {x['gouge_um']:.1f} | {x['rs274']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
