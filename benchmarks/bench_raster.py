"""conformill's three patterns against OpenCAMLib's raster, on the same mesh and the same h.

For each mesh (turned and scaled to a part in mm by :func:`_common.load_part`) and scallop
height ``h`` (ball radius ``r``, chord tolerance ``e``), in one run:

* conformill: ``pipeline.plan`` + ``write_gcode`` for ``zigzag``, ``contour`` and
  ``spiral`` (wall time of both together, after a warm-up plan that loads numba's caches),
  then each again as ``conformill plan`` in a fresh process (the ``cmd s`` column; with
  ``--cmd-runs N`` the median of N such runs, one after another);
* OpenCAMLib: ``ocl.PathDropCutter`` (ball, ``BallCutter(2 r, ...)``: OCL takes the
  diameter) along a zigzag of straight rows in the XY plane, parallel to the longer
  horizontal extent of the part, written as G-code here (``G21 G90``, ``G0`` to the row
  start at clearance height, ``G1`` plunge and cuts, 4 decimals, ``G0`` retract after each
  row). Where the ball does not touch the part the drop-cutter leaves the tip at the
  minimum Z; those points are dropped and the row is split there (a retract), so the
  program only cuts over the part. The wall time counts building the STLSurf, the
  drop-cutter run, reading the CL points back and formatting the G-code.

  * Stepover: the flat scallop formula ``w = 2 sqrt(h (2r - h))`` (the widest spacing that
    meets ``h`` on a horizontal plane, what a raster CAM uses).
  * Sampling along the rows, "chosen to meet e": the linearised CL path deviates from the
    exact one by the sagitta ``s^2 / (8 rho)`` where ``rho`` is the radius of the CL (ball
    centre) curve, ``rho = R + r`` over convex and ``R - r`` over concave surface of radius
    ``R``, i.e. ``|kappa_CL| = |kappa / (1 - r kappa)|``. Over convex ground, sharp edges
    included, ``rho >= r``, so ``s_r = 2 sqrt(e (2r - e))`` (chord of sagitta ``e`` on a
    circle of radius ``r``) meets ``e`` there whatever the fitted curvature says. Over
    concave ground ``rho`` can be anything down to 0 (a cusp of the CL where the surface is
    concave below ``r``): there the CL curvature per vertex is taken from the most concave
    principal curvature (conformill's quadratic fit, :func:`_common.principal_curvatures`)
    over the vertices the ball can follow (``k1 < 1/r``), and ``rho_q`` is the reciprocal
    of its area-weighted 99th percentile (the maximum of a scan is noise and would make the
    raster absurdly dense). ``s = min(s_r, 2 sqrt(e (2 rho_q - e)))``. The achieved
    deviation is then *measured*: the cutter is dropped (``BatchDropCutter``) at the
    midpoints of up to 20000 random segments of the raster (not the first or last segment
    of a row, which leave the part's edge) and ``dz = z_exact - z_linear`` is reported
    (vertical, so larger than the normal deviation on slopes; > 0: the linear move dips
    below the exact CL, a gouge; < 0: material left); this check is not timed.

Every program is read back with :func:`conformill.verify.gcode.read_gcode` and simulated with
:func:`conformill.verify.simulate.verify` on the same area-uniform samples (seed 0), and given
to LinuxCNC's ``rs274 -g`` when it is installed. Columns:

* ``wall s`` / ``cpu s``: wall-clock and process CPU time (conformill's numba kernels use
  all cores; so does OpenCAMLib's PathDropCutter, whose drops run under OpenMP: its CPU
  time is about twice its wall time on 2 cores);
* ``OCL x``: OpenCAMLib's wall time divided by this program's;
* ``cmd s`` / ``cmd OCL x``: the same program planned by the command line, ``conformill plan``
  in a fresh process on the same part (written as a PLY of doubles) with the same options,
  its whole wall time (Python's start, the imports, numba's cache loads, the read, the plan,
  the G-code and the exit: what a user timing the command sees), and OpenCAMLib's time over
  it; the moves are checked to be the same lines as the in-process program's ("-" and a
  line in the log where they are not);
* ``CL pts``: points written; ``feed m``: length of the cutting moves (feed moves that do
  not start at the clearance height, i.e. without the plunges), metres;
* ``len/floor``: feed length over the floor ``integral dA / s_max(x)`` (the shortest
  total length any set of paths meeting ``h`` everywhere can have,
  :func:`_common.length_floor`; ``s_max`` from the exact side-interval formula of
  :mod:`conformill.planning.steps` with the most concave principal curvature);
* scallop p50/p99/p99.9/max in units of ``h`` over the interior samples (farther than ``r``
  from the boundary), as ``conformill verify`` reports them; ``p99.9 reach``, ``p99 reach``
  and ``uncut reach %``: the same over the interior samples that ``conformill verify``
  counts as reachable by a 3-axis ball (``summary["reachable"]``: tangent ball free, shank
  free, facing up, and some ball position brings the sample within the limit 1.05 h;
  uncut samples excluded from the percentile and counted separately; verify is given the
  limit 1.05 h and the reach depth h); ``excused``: samples the program left above 1.05 h that verify's
  tangent test keeps but for which the rest search finds no ball within the limit 1.05 h
  (a ball within 1.2 h before session 12); ``p99.9 tangent``: the p99.9 with them
  (verify before session 10);
  ``p99.9 ball`` / ``uncut ball %``: this script's own, simpler test
  (:func:`_common.reachable_samples`: facing up, tangent ball penetrating the part by less
  than ``h``, no shank check), uncut samples counted as infinite in the percentile;
  ``>h %``: interior area with more than ``h`` left (or uncut); ``uncut %``;
  ``gouge um``: deepest interior gouge; ``rapid``: least clearance of the rapids (mm);
  ``rs274``: the interpreter's exit code.

Usage::

    python benchmarks/bench_raster.py --quick                 # h = 0.1, two small meshes
    python benchmarks/bench_raster.py --meshes igea choi --h 0.01 --md out.md
    python benchmarks/bench_raster.py --reverify out.json --keep DIR --md out2.md
        # verify the kept programs again (timings and lengths from the JSON)
    python benchmarks/bench_raster.py --meshes igea --patterns zigzag contour --pencil folds
        # conformill's programs with pencil passes (--pencil --pencil-search folds)
    python benchmarks/bench_raster.py --scan --md out.md   # every mesh, plan --scan's recipe

``--pencil SEARCH`` plans every conformill program with ``--pencil --pencil-search SEARCH``
(and ``--pencil-density D``, default 30), so that the table puts the programs that meet
1.05 h on the scans beside the raster, timed in the same run. ``--scan`` plans them with
``conformill plan --scan``'s recipe instead (:func:`conformill.pipeline.scan_recipe`: the
fold pencil at ``--pencil-density``, cut where the pattern left more than 0.5 h, hops over
runs lifted 3 mm; session 38), the settings the README gives for scanned parts.

Needs opencamlib; the shared meshes (/work/shared/meshes or $CONFORMILL_MESHES) for
everything but the shipped samples.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

PATTERNS = ("zigzag", "contour", "spiral")
FULL_MESHES = ("igea", "choi", "camelhead", "beetle", "lion", "sample:face", "sample:patch",
               "nefertiti", "spacetime", "fandisk", "sample:lion")
QUICK_MESHES = ("beetle", "sample:patch")


# ---- OpenCAMLib raster ------------------------------------------------------------------


def raster_sampling(mesh, k1, k2, r: float, e: float, q: float = 99.0):
    """Row sampling (mm) from ``e`` and the CL-path curvature (module notes).

    Returns
    -------
    s : float
    rho : float
        ``rho_q``, the concave CL radius of curvature used (mm).
    """
    ok = np.isfinite(k1) & (k1 * r < 1.0)
    kcl = np.maximum(k1 / (1.0 - r * k1), 0.0)  # concave CL curvature; convex is bounded by 1/r
    A = _common.face_areas(mesh.V, mesh.F)
    va = np.bincount(mesh.F.reshape(-1), weights=np.repeat(A / 3.0, 3), minlength=len(mesh.V))
    x, w = kcl[ok], va[ok]
    o = np.argsort(x)
    c = np.cumsum(w[o])
    kq = float(x[o][min(np.searchsorted(c, q / 100.0 * c[-1]), len(x) - 1)])
    rho = 1.0 / max(kq, 1e-12)
    s_r = 2.0 * math.sqrt(e * (2.0 * r - e))
    s = 2.0 * math.sqrt(e * (2.0 * rho - e)) if 2 * rho > e else e
    return min(s, s_r), rho


def ocl_zigzag(mesh, r: float, h: float, sampling: float, feed: float = 1000.0, clearance: float = 5.0):
    """OpenCAMLib PathDropCutter zigzag raster; returns G-code text and figures (timed)."""
    import opencamlib as ocl

    t0 = time.perf_counter()
    c0 = time.process_time()
    V, F = mesh.V, mesh.F
    surf = ocl.STLSurf()
    for a, b, c in V[F]:
        surf.addTriangle(ocl.Triangle(ocl.Point(*a), ocl.Point(*b), ocl.Point(*c)))
    cutter = ocl.BallCutter(2.0 * r, 10.0 * r)
    w = 2.0 * math.sqrt(h * (2.0 * r - h))
    lo, hi = V.min(0), V.max(0)
    along = 0 if hi[0] - lo[0] >= hi[1] - lo[1] else 1
    across = 1 - along
    n_rows = int(math.ceil((hi[across] - lo[across]) / w)) + 1
    cross = lo[across] + w * np.arange(n_rows) - 0.5 * (w * (n_rows - 1) - (hi[across] - lo[across]))
    zmin = float(lo[2] - 10.0)
    path = ocl.Path()
    for i, c in enumerate(cross):
        a_, b_ = (lo[along], hi[along]) if i % 2 == 0 else (hi[along], lo[along])
        p, q = [0.0, 0.0, zmin], [0.0, 0.0, zmin]
        p[along], p[across], q[along], q[across] = float(a_), float(c), float(b_), float(c)
        path.append(ocl.Line(ocl.Point(*p), ocl.Point(*q)))
    pdc = ocl.PathDropCutter()
    pdc.setSTL(surf)
    pdc.setCutter(cutter)
    pdc.setPath(path)
    pdc.setSampling(float(sampling))
    pdc.setZ(zmin)
    t_setup = time.perf_counter() - t0
    pdc.run()
    t_run = time.perf_counter() - t0 - t_setup
    cl = np.array([(p.x, p.y, p.z) for p in pdc.getCLPoints()])
    n_sampled = len(cl)
    # rows: the across coordinate changes between rows; off-part points split them into runs
    row = np.concatenate([[0], np.cumsum(np.abs(np.diff(cl[:, across])) > 1e-9)])
    on = cl[:, 2] > zmin + 1e-6
    brk = np.ones(len(cl), dtype=bool)
    brk[1:] = (row[1:] != row[:-1]) | ~on[:-1]
    run_id = np.cumsum(brk & on) - 1
    runs = [cl[on & (run_id == k)] for k in range(int(run_id[on].max()) + 1)] if on.any() else []
    safe = float(hi[2] + clearance)
    out = [f"(OpenCAMLib {ocl.version()} PathDropCutter zigzag, ball r = {r:g} mm, stepover {w:.4f} mm, "
           f"sampling {sampling:.4f} mm)", "G21 G90 G17 G94", f"G0 Z{safe:.4f}"]
    fp = f"F{feed / 3:.1f}"
    ff = f"F{feed:.1f}"
    for P in runs:
        out.append(f"G0 X{P[0, 0]:.4f} Y{P[0, 1]:.4f}")
        out.append(f"G1 Z{P[0, 2]:.4f} {fp}")
        first = True
        for x, y, z in P[1:]:
            out.append(f"G1 X{x:.4f} Y{y:.4f} Z{z:.4f}" + (f" {ff}" if first else ""))
            first = False
        out.append(f"G0 Z{safe:.4f}")
    out.append("M30")
    text = "\n".join(out) + "\n"
    wall = time.perf_counter() - t0
    return {"text": text, "wall_s": wall, "cpu_s": time.process_time() - c0, "setup_s": t_setup,
            "run_s": t_run, "stepover": w, "sampling": sampling, "rows": n_rows, "runs": runs,
            "sampled_points": n_sampled, "cl_points": int(sum(len(p) for p in runs)),
            "ms_per_point": 1000 * t_run / max(n_sampled, 1), "safe_z": safe, "surf": surf, "cutter": cutter}


def chord_check(raster, n: int = 20000, seed: int = 0):
    """Drop the cutter at midpoints of random raster segments: ``z_exact - z_linear`` (mm)."""
    import opencamlib as ocl

    A = np.concatenate([p[1:-2] for p in raster["runs"] if len(p) > 3])
    B = np.concatenate([p[2:-1] for p in raster["runs"] if len(p) > 3])
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(A), min(n, len(A)), replace=False)
    M = 0.5 * (A[idx] + B[idx])
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(raster["surf"])
    bdc.setCutter(raster["cutter"])
    zmin = float(min(A[:, 2].min(), B[:, 2].min()) - 10.0)
    for x, y, _ in M:
        bdc.appendPoint(ocl.CLPoint(float(x), float(y), zmin))
    bdc.run()
    z = np.array([p.z for p in bdc.getCLPoints()])
    return z - M[:, 2]


# ---- conformill -------------------------------------------------------------------------


def warm_up():
    """Compile or load numba's kernels before anything is timed: a small synthetic part
    once per pattern, then the shipped sample face, read as the compared meshes are (the
    same array types for the mesh checks' kernels), with the compared recipe (``--scan``'s
    folds and settled chains reach kernels the cap does not). Without the second part a
    fresh cache compiled eight kernels inside the first timed plan (session 66: igea's
    ``--scan`` zigzag 33.4 s wall against 8.9 s warm)."""
    from conformill.mesh import synthetic
    from conformill.output.gcode import format_gcode
    from conformill.pipeline import plan

    m = synthetic.sphere_cap(60.0, 20.0)
    for pat in PATTERNS:
        res = plan(m, _job(pat, 4.0, 0.2, 0.01))
        format_gcode(res.toolpath, feed=1000.0)
    face, _ = _common.load_part("sample:face")
    plan(face, _job(PATTERNS[0], 4.0, 0.05, 0.01))


#: conformill's ``--spacing`` for the compared programs (``--spacing`` of this script)
SPACING = "adaptive"
#: conformill's pencil search for the compared programs (``--pencil`` of this script; None: off)
#: and its density (``--pencil-density``)
PENCIL = None
PENCIL_DENSITY = 30.0
#: plan with ``conformill plan --scan``'s recipe (``--scan`` of this script: the pencil on the
#: folds, cut where the pattern left more than 0.5 h, hops over runs lifted 3 mm)
SCAN = False
#: ``conformill plan`` runs per program from the command line (``--cmd-runs``): their median
CMD_RUNS = 1


def _job(pattern, r, h, e, feed=1000.0):
    from conformill.pipeline import Job, scan_recipe

    pencil = scan_recipe(pattern) if SCAN else {"pencil": PENCIL is not None, "pencil_search": PENCIL or "samples"}
    return Job(pattern=pattern, tool_radius=r, scallop=h, tolerance=e, feed=feed, spacing=SPACING,
               pencil_density=PENCIL_DENSITY, **pencil)


def _label(pattern):
    if SCAN:
        return f"conformill {pattern} --scan"
    return f"conformill {pattern}" + (f" + {PENCIL} pencil" if PENCIL else "")


def write_part(mesh, path: Path) -> Path:
    """The part as a binary PLY with double coordinates (the same floats as ``mesh``, so the
    command line plans the same part)."""
    V = np.ascontiguousarray(mesh.V, dtype="<f8")
    F = np.asarray(mesh.F)
    rec = np.empty(len(F), dtype=[("n", "u1"), ("f", "<i4", (3,))])
    rec["n"] = 3
    rec["f"] = F
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(F)}\n"
            "property list uchar int vertex_indices\nend_header\n")
    path.write_bytes(head.encode("ascii") + V.tobytes() + rec.tobytes())
    return path


def command_program(part: Path, pattern, r, h, e, path: Path, feed: float = 1000.0) -> float:
    """Wall time (s) of ``conformill plan`` on ``part`` in a fresh process (start-up, read and
    exit included: what a user timing the command sees), with the options of
    :func:`conformill_program`'s job; the program is written to ``path``."""
    import subprocess

    cmd = [sys.executable, "-m", "conformill", "plan", str(part), "--pattern", pattern, "--tool-radius", repr(r),
           "--scallop", repr(h), "--tolerance", repr(e), "--feed", repr(feed), "--plunge-feed", repr(feed / 3),
           "--spacing", SPACING, "--quiet", "-o", str(path)]
    if SCAN:
        cmd.append("--scan")
    elif PENCIL is not None:
        cmd += ["--pencil", "--pencil-search", PENCIL, "--pencil-density", repr(PENCIL_DENSITY)]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr.strip()[-500:]}")
    return wall


def same_moves(a: Path, b: Path) -> bool:
    """Whether two programs hold the same ``G0`` / ``G1`` lines (the header's comments and
    modes may differ: the command line writes its path control ``G64``)."""
    def moves(p):
        return [ln for ln in p.read_text().splitlines() if ln.startswith(("G0 ", "G1 "))]

    return moves(a) == moves(b)


def conformill_program(mesh, pattern, r, h, e, path: Path, feed: float = 1000.0):
    from conformill.output.gcode import write_gcode
    from conformill.pipeline import plan

    job = _job(pattern, r, h, e, feed)
    t0 = time.perf_counter()
    c0 = time.process_time()
    res = plan(mesh, job)
    st = write_gcode(path, res.toolpath, feed=feed, plunge_feed=feed / 3)
    return res, st, time.perf_counter() - t0, time.process_time() - c0


# ---- figures ----------------------------------------------------------------------------


def cut_length(prog, safe_z: float) -> float:
    """Length of the feed moves that do not start at the clearance height (no plunges)."""
    from conformill.verify.gcode import FEED

    A, B = prog.segments(FEED)
    keep = A[:, 2] < safe_z - 1e-6
    return float(np.linalg.norm(B[keep] - A[keep], axis=1).sum())


def upper_quantile(x, q):
    """Quantile by rank (``inf`` entries allowed)."""
    x = np.sort(np.asarray(x))
    if x.size == 0:
        return math.nan
    return float(x[min(int(math.ceil(q * x.size)) - 1, x.size - 1)])


def measure(mesh, path: Path, r, h, e, samples, reach, safe_z):
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    prog = read_gcode(path)
    t0 = time.perf_counter()
    v = verify(mesh, prog, r, samples=samples, scallop=1.05 * h, reach_depth=h, gouge=e, judge="reachable")
    t_ver = time.perf_counter() - t0
    s = v.summary
    sel = v.interior & reach
    rem = v.remaining[sel]
    return {
        "verify_s": t_ver,
        "feed_mm": cut_length(prog, safe_z),
        "feed_all_mm": prog.feed_length(),
        "scallop": {k: float(s["scallop"][k]) for k in ("p50", "p99", "p999", "max")},
        "p999_reach": upper_quantile(np.where(np.isfinite(rem), rem, np.inf), 0.999),
        "uncut_reach": float((~np.isfinite(rem)).mean()) if rem.size else math.nan,
        # conformill verify's own reachable set (ball, shank and undercut), when it has one
        "verify_reach": ({"p999": float(s["reachable"]["scallop"]["p999"]),
                          "p99": float(s["reachable"]["scallop"]["p99"]),
                          "uncut": float(s["reachable"]["uncut_fraction"]),
                          "unreachable": float(s["reachable"].get("unreachable_fraction", math.nan)),
                          # excused by the rest search (no ball position brings them within h)
                          "beyond_any_ball": int(s["reachable"].get("beyond_any_ball", 0)),
                          "p999_tangent": float(s["reachable"]["tangent_test"]["scallop"]["p999"])
                          if "tangent_test" in s["reachable"] else math.nan}
                         if "reachable" in s else None),
        "above_h": float(s["interior"].get("above_scallop_fraction", math.nan)),
        "uncut": float(s["uncut_fraction"]),
        "gouge_max": float(s["gouge_max"]),
        "rapid": float(s["rapid_min_clearance"]),
        "rs274": _common.rs274(path),
    }


def run_mesh(name, h, r, e, n_samples, folder: Path, log):
    mesh, info = _common.load_part(name)
    ext = info["extent_mm"]
    log(f"\n== {mesh.name}: {mesh.n_faces} faces, {ext[0]:.1f} x {ext[1]:.1f} x {ext[2]:.1f} mm "
        f"(scale {info['scale']:.4g}, turned {info['rotated_deg']:.1f} deg); r = {r}, h = {h}, e = {e}")
    rows = []
    # conformill first (it also gives the oriented mesh everything else uses)
    progs = {}
    for pat in PATTERNS:
        tag = "_scan" if SCAN else (f"_pencil_{PENCIL}{PENCIL_DENSITY:g}" if PENCIL else "")
        p = folder / f"{mesh.name}_{pat}_h{h:g}{tag}.nc"
        try:
            res, st, wall, cpu = conformill_program(mesh, pat, r, h, e, p)
        except Exception as exc:  # a failing pattern is a row of the table, not the end of the run
            log(f"   {pat}: FAILED {type(exc).__name__}: {exc}")
            rows.append({"program": _label(pat), "error": f"{type(exc).__name__}: {exc}"})
            continue
        mesh = res.mesh
        progs[pat] = (p, res, st, wall, cpu)
        log(f"   {_label(pat)}: {wall:.2f} s wall, {cpu:.2f} s cpu, {st['passes']} passes, "
            f"{st['cut_points']} CL points")
    # the same programs from the command line, each in a fresh process (after all the
    # in-process plans: their mesh is the oriented one the pipeline returned)
    part = write_part(mesh, folder / f"{mesh.name}.ply")
    for pat, (p, res, st, wall, cpu) in progs.items():
        q = p.with_name(p.stem + "_cmd.nc")
        try:
            # CMD_RUNS fresh processes one after another: their median (this host's other
            # tenants move a single run by up to 2 s)
            walls = [command_program(part, pat, r, h, e, q) for _ in range(CMD_RUNS)]
            cmd_wall = float(np.median(walls))
        except RuntimeError as exc:
            log(f"   {_label(pat)} from the command line: FAILED {exc}")
            continue
        if not same_moves(p, q):
            log(f"   {_label(pat)} from the command line: NOT the same moves ({q.name})")
            continue
        progs[pat] = (p, res, st, wall, cpu, cmd_wall)
        runs = f" (median of {', '.join(f'{w:.2f}' for w in walls)})" if len(walls) > 1 else ""
        log(f"   {_label(pat)} from the command line: {cmd_wall:.2f} s wall{runs} (the same moves)")
    k1, k2 = _common.principal_curvatures(mesh)
    floor = _common.length_floor(mesh, k1, k2, h, r)
    s, rho = raster_sampling(mesh, k1, k2, r, e)
    log(f"   floor {floor['floor_mm'] / 1000:.2f} m (area / flat interval: {floor['flat_floor_mm'] / 1000:.2f} m); "
        f"raster sampling {s:.4f} mm (concave CL radius p99 {rho:.3f} mm)")
    ras = ocl_zigzag(mesh, r, h, s)
    p_ocl = folder / f"{mesh.name}_ocl_h{h:g}.nc"
    p_ocl.write_text(ras["text"])
    dz = chord_check(ras)
    log(f"   OpenCAMLib: {ras['wall_s']:.1f} s wall ({ras['run_s']:.1f} s drop-cutter, "
        f"{ras['ms_per_point']:.2f} ms per sampled point, {ras['sampled_points']} sampled, {ras['cl_points']} on "
        f"the part), {ras['rows']} rows at {ras['stepover']:.4f} mm; chord check |dz| p99 "
        f"{np.percentile(np.abs(dz), 99):.4f} p99.9 {np.percentile(np.abs(dz), 99.9):.4f} max {np.abs(dz).max():.4f} mm (gouge side max {max(dz.max(), 0):.4f})")

    samples = _common.verify_samples(mesh, n_samples, r)
    reach = _common.reachable_samples(mesh, samples, r, tol=h)
    interior = samples.boundary_distance > r
    reach_share = float((reach & interior).sum() / max(interior.sum(), 1))
    log(f"   {n_samples} samples, {interior.sum()} interior, of which {100 * reach_share:.2f} % reachable")

    m_ocl = measure(mesh, p_ocl, r, h, e, samples, reach, ras["safe_z"])
    for pat, (p, res, st, wall, cpu, *cmd) in progs.items():
        m = measure(mesh, p, r, h, e, samples, reach, res.toolpath.safe_z)
        cmd_wall = cmd[0] if cmd else math.nan
        rows.append({"program": _label(pat), "file": p.name, "wall_s": wall, "cpu_s": cpu,
                     "cl_points": st["cut_points"], "passes": st["passes"], "ocl_ratio": ras["wall_s"] / wall,
                     "cmd_s": cmd_wall, "cmd_ocl_ratio": ras["wall_s"] / cmd_wall, **m})
        log("   " + fmt_row(rows[-1], h, floor["floor_mm"]))
    rows.append({"program": "OpenCAMLib raster", "file": p_ocl.name, "wall_s": ras["wall_s"], "cpu_s": ras["cpu_s"],
                 "cl_points": ras["cl_points"], "passes": len(ras["runs"]), "ocl_ratio": 1.0, "cmd_s": math.nan,
                 "cmd_ocl_ratio": math.nan, **m_ocl})
    log("   " + fmt_row(rows[-1], h, floor["floor_mm"]))
    return {"mesh": mesh.name, "faces": int(mesh.n_faces), "extent_mm": ext, "scale": info["scale"],
            "rotated_deg": info["rotated_deg"], "h": h, "r": r, "e": e, "samples": n_samples,
            "interior": int(interior.sum()), "reachable_share": reach_share, "floor": floor,
            "raster": {k: ras[k] for k in ("stepover", "sampling", "rows", "sampled_points", "cl_points",
                                           "ms_per_point", "run_s", "setup_s", "wall_s")},
            "raster_cl_radius_p99": rho, "chord_dz": {"p99_abs": float(np.percentile(np.abs(dz), 99)),
                                                      "p999_abs": float(np.percentile(np.abs(dz), 99.9)),
                                                      "max_abs": float(np.abs(dz).max()),
                                                      "gouge_side_max": float(max(dz.max(), 0.0))},
            "rows": rows}


# ---- tables -----------------------------------------------------------------------------

COLS = ("program", "wall s", "cpu s", "OCL x", "cmd s", "cmd OCL x", "CL pts", "feed m", "len/floor", "p50/h", "p99/h", "p99.9/h",
        "max/h", "p99.9 reach/h", "p99 reach/h", "excused", "p99.9 tangent/h", "uncut reach %", "p99.9 ball/h", "uncut ball %", ">h %", "uncut %", "gouge um",
        "rapid mm", "rs274")


def _cells(row, h, floor_mm):
    if "error" in row:
        return [row["program"], "failed: " + row["error"][:80]] + [""] * (len(COLS) - 2)
    sc = row["scallop"]
    vr = row.get("verify_reach")

    def f(x, fmt):
        return "inf" if x == math.inf else ("-" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt % x)

    return [row["program"], f(row["wall_s"], "%.2f"), f(row["cpu_s"], "%.2f"), f(row["ocl_ratio"], "%.1f"),
            f(row.get("cmd_s"), "%.2f"), f(row.get("cmd_ocl_ratio"), "%.1f"), str(row["cl_points"]), f(row["feed_mm"] / 1000, "%.2f"), f(row["feed_mm"] / floor_mm, "%.2f"),
            f(sc["p50"] / h, "%.3f"), f(sc["p99"] / h, "%.3f"), f(sc["p999"] / h, "%.3f"), f(sc["max"] / h, "%.1f"),
            f(vr["p999"] / h if vr else None, "%.3f"), f(vr["p99"] / h if vr and "p99" in vr else None, "%.3f"),
            str(vr.get("beyond_any_ball", "-")) if vr else "-",
            f(vr["p999_tangent"] / h if vr and "p999_tangent" in vr else None, "%.3f"),
            f(100 * vr["uncut"] if vr else None, "%.3f"),
            f(row["p999_reach"] / h, "%.3f"), f(100 * row["uncut_reach"], "%.3f"), f(100 * row["above_h"], "%.2f"),
            f(100 * row["uncut"], "%.3f"), f(1000 * row["gouge_max"], "%.1f"), f(min(row["rapid"], 99), "%.2f"),
            str(row["rs274"])]


def fmt_row(row, h, floor_mm):
    return "  ".join(f"{c}={v}" for c, v in zip(COLS, _cells(row, h, floor_mm)))


def markdown(results, machine: str) -> str:
    out = []
    for R in results:
        ext = R["extent_mm"]
        ras = R["raster"]
        vr = next((row["verify_reach"] for row in R["rows"] if row.get("verify_reach")), None)
        out.append(f"### {R['mesh']}, h = {R['h']:g} mm (r = {R['r']:g} mm, e = {R['e']:g} mm)\n")
        out.append(f"{R['faces']} faces, {ext[0]:.1f} x {ext[1]:.1f} x {ext[2]:.1f} mm (scale {R['scale']:.4g}, "
                   f"turned {R['rotated_deg']:.1f} deg). Length floor {R['floor']['floor_mm'] / 1000:.2f} m "
                   f"(area {R['floor']['area_mm2']:.0f} mm^2 / flat interval: {R['floor']['flat_floor_mm'] / 1000:.2f} m). "
                   f"Raster: {ras['rows']} rows at {ras['stepover']:.4f} mm, sampling {ras['sampling']:.4f} mm "
                   f"(concave CL radius p99 {R['raster_cl_radius_p99']:.2f} mm), {ras['sampled_points']} points dropped "
                   f"({ras['ms_per_point']:.2f} ms each, {ras['run_s']:.1f} s), chord check |dz| p99 "
                   f"{1000 * R['chord_dz']['p99_abs']:.1f} um, p99.9 {1000 * R['chord_dz']['p999_abs']:.1f} um, max {1000 * R['chord_dz']['max_abs']:.1f} um. "
                   f"Verify: {R['samples']} samples, {R['interior']} interior, "
                   f"{100 * R['reachable_share']:.2f} % of them reachable by this script's ball test"
                   + ("" if not vr else f", {100 * (1 - vr['unreachable']):.2f} % by conformill verify's") + ".\n")
        out.append("| " + " | ".join(COLS) + " |")
        out.append("|" + "---|" * len(COLS))
        for row in R["rows"]:
            out.append("| " + " | ".join(_cells(row, R["h"], R["floor"]["floor_mm"])) + " |")
        out.append("")
    return "\n".join(out)


def reverify(old: dict, folder: Path, log) -> dict:
    """Measure the kept programs of one mesh again (e.g. after ``verify`` changed)."""
    from conformill.pipeline import orient_mesh

    name = next(k for k in _common.MESH_FILES if k.replace("sample:", "sample_") == old["mesh"])
    mesh, _ = _common.load_part(name)
    mesh, _ = orient_mesh(mesh, "none")  # as plan() did: re-wound if the normals point down
    r, h, e = old["r"], old["h"], old["e"]
    samples = _common.verify_samples(mesh, old["samples"], r)
    reach = _common.reachable_samples(mesh, samples, r, tol=h)
    new = dict(old, rows=[])
    for row in old["rows"]:
        if "error" in row:
            new["rows"].append(row)
            continue
        if "file" in row:
            p = folder / row["file"]
        else:  # written before the rows named their files
            tag = "ocl" if row["program"].startswith("OpenCAMLib") else row["program"].split()[-1]
            p = folder / f"{old['mesh']}_{tag}_h{h:g}.nc"
        safe = float(mesh.V[:, 2].max()) + 5.0
        m = measure(mesh, p, r, h, e, samples, reach, safe)
        new["rows"].append({**row, **{k: v for k, v in m.items() if k != "rs274"}})
        log(f"   {old['mesh']}: " + fmt_row(new["rows"][-1], h, old["floor"]["floor_mm"]))
    return new


def main(argv=None) -> int:
    global SPACING, PATTERNS, PENCIL, PENCIL_DENSITY, SCAN, CMD_RUNS
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="h = 0.1 on two small meshes, 100k samples")
    ap.add_argument("--meshes", nargs="*", default=None, help=f"of {', '.join(_common.MESH_FILES)}")
    ap.add_argument("--h", type=float, default=None, help="scallop height (default 0.01; --quick 0.1)")
    ap.add_argument("--r", type=float, default=4.0, help="ball radius (default 4)")
    ap.add_argument("--e", type=float, default=0.01, help="chord tolerance (default 0.01)")
    ap.add_argument("--samples", type=int, default=None, help="verify samples (default 400000; --quick 100000)")
    ap.add_argument("--keep", default=None, help="folder for the programs (default: a temporary one)")
    ap.add_argument("--spacing", default="adaptive", choices=["adaptive", "paper", "local"],
                    help="conformill's --spacing (default adaptive)")
    ap.add_argument("--patterns", nargs="*", default=list(PATTERNS), choices=list(PATTERNS),
                    help="conformill's patterns to run (default all three)")
    ap.add_argument("--pencil", default=None, choices=["samples", "folds"],
                    help="plan conformill's programs with --pencil --pencil-search SEARCH (default: no pencil)")
    ap.add_argument("--pencil-density", type=float, default=30.0, help="conformill's --pencil-density (default 30)")
    ap.add_argument("--scan", action="store_true",
                    help="plan conformill's programs with conformill plan --scan's recipe (pencil on the folds, "
                         "--pencil-left 0.5, --hop-lifted 3)")
    ap.add_argument("--cmd-runs", type=int, default=1, metavar="N",
                    help="run each program's command N times in fresh processes and take the median (default 1)")
    ap.add_argument("--md", default=None, help="write the tables as Markdown here")
    ap.add_argument("--json", default=None, help="write all figures as JSON here")
    ap.add_argument("--reverify", default=None, metavar="OLD.json",
                    help="only verify the programs kept in --keep again (figures of a previous run)")
    args = ap.parse_args(argv)
    SPACING = args.spacing
    PATTERNS = tuple(args.patterns)
    PENCIL, PENCIL_DENSITY = args.pencil, float(args.pencil_density)
    SCAN = bool(args.scan)
    CMD_RUNS = max(1, int(args.cmd_runs))
    if SCAN and PENCIL:
        ap.error("--scan sets the pencil search (folds): leave out --pencil")
    if args.reverify and not args.keep:
        ap.error("--reverify needs --keep DIR: the folder the programs were kept in")
    if args.reverify:
        old = json.loads(Path(args.reverify).read_text())
        res = [reverify(R, Path(args.keep), print) for R in old["results"]]
        md = markdown(res, old["machine"])
        if args.md:
            Path(args.md).write_text(f"Machine: {old['machine']}\n\n" + md)
        if args.json:
            Path(args.json).write_text(json.dumps({"machine": old["machine"], "results": res}, indent=1, default=str))
        print(md)
        return 0
    meshes = args.meshes or (QUICK_MESHES if args.quick else FULL_MESHES)
    h = args.h if args.h is not None else (0.1 if args.quick else 0.01)
    n = args.samples or (100_000 if args.quick else 400_000)
    need = [m for m in meshes if not _common.MESH_FILES[m].startswith("sample:")]
    if need and not _common.MESHES.is_dir():
        print(f"no meshes at {_common.MESHES}; use --meshes sample:face sample:patch", file=sys.stderr)
        return 1
    folder = Path(args.keep or tempfile.mkdtemp(prefix="cm_raster_"))
    folder.mkdir(parents=True, exist_ok=True)
    machine = _common.machine()

    def log(msg):
        print(msg, flush=True)

    log(f"machine: {machine}\nprograms in {folder}")
    t0 = time.perf_counter()
    warm_up()
    log(f"warm-up (numba caches) {time.perf_counter() - t0:.1f} s")
    results = []
    for name in meshes:
        results.append(run_mesh(name, h, args.r, args.e, n, folder, log))
        md = markdown(results, machine)
        if args.md:
            Path(args.md).write_text(f"Machine: {machine}\n\n" + md)
        if args.json:
            Path(args.json).write_text(json.dumps({"machine": machine, "results": results}, indent=1, default=str))
    log("\n" + markdown(results, machine))
    return 0


if __name__ == "__main__":
    sys.exit(main())
