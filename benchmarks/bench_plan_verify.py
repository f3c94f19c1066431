"""Plan, then check independently: every pattern on face-like and CAD-like parts.

For each mesh, pattern and scallop height the program is planned (``pipeline.plan`` +
``write_gcode``, timed together: "plan s"), read back from the written file, simulated by
``conformill.verify`` (area-uniform samples, ball swept along every feed move) and given to
LinuxCNC's ``rs274 -g`` when it is installed. Printed per row: the plan time, passes, the
scallop p50 / p99.9 / max as a multiple of H over the samples farther than r from the
boundary, uncut share; the share of those samples no 3-axis ball can reach (undercuts,
pockets tighter than the ball: ``verify.simulate.unreachable_samples``) and the scallop
p99.9 / uncut share over the reachable ones ("R"); gouge max, rapid clearance, rs274 exit
code and PASS/FAIL against issue 3's criteria (p99.9 <= 1.05 H and no uncut on the
reachable samples, gouge <= E, rapid clearance >= 0.5 mm, spiral = 1 pass, rs274 = 0,
plan < 10 s).

Meshes: seeded ``synthetic.face_like`` / ``synthetic.cad_like`` (about 120-130 mm, 22-28 mm
relief, slopes up to 55 deg, 17k-22k irregular faces, non-convex outlines) and the shipped
samples.

Usage: ``python benchmarks/bench_plan_verify.py [--seeds 0 1] [--h 1 0.1]
[--patterns zigzag contour spiral] [--samples 400000] [--samples-meshes]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _common import rs274  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    ap.add_argument("--h", type=float, nargs="*", default=[1.0, 0.1])
    ap.add_argument("--patterns", nargs="*", default=["zigzag", "contour", "spiral"])
    ap.add_argument("--samples", type=int, default=400_000)
    ap.add_argument("--samples-meshes", action="store_true", help="also the shipped sample parts")
    ap.add_argument("--only", default=None, help="substring of mesh names to run")
    ap.add_argument("--keep", default=None, help="folder to keep the programs in")
    args = ap.parse_args()

    from conformill.mesh import synthetic
    from conformill.mesh.io import read_mesh
    from conformill.output.gcode import write_gcode
    from conformill.pipeline import Job, plan
    from conformill.verify.gcode import read_gcode
    from conformill.verify.simulate import verify

    r, e = 4.0, 0.01
    meshes = []
    for s in args.seeds:
        meshes += [synthetic.face_like(s), synthetic.cad_like(s)]
    if args.samples_meshes:
        meshes += [read_mesh("sample:face"), read_mesh("sample:patch")]
    if args.only:
        meshes = [m for m in meshes if args.only in m.name]
    out = Path(args.keep or tempfile.mkdtemp(prefix="cm_bench_"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"r = {r} mm, e = {e} mm, {args.samples} verify samples; programs in {out}")
    hdr = (f"{'mesh':16s} {'faces':>6s} {'pattern':8s} {'H':>5s} {'plan s':>6s} {'pass':>4s} {'CL pts':>8s} "
           f"{'feed m':>7s} {'p50/H':>6s} {'p999/H':>7s} {'max/H':>7s} {'uncut%':>7s} {'unrch%':>6s} {'R p999/H':>8s} "
           f"{'R uncut%':>8s} {'gouge':>7s} "
           f"{'rapid':>6s} {'rs274':>5s}  verdict")
    print(hdr)
    print("-" * len(hdr))
    n_fail = 0
    for m in meshes:
        for h in args.h:
            for pat in args.patterns:
                job = Job(pattern=pat, tool_radius=r, scallop=h, tolerance=e)
                path = out / f"{m.name}_{pat}_h{h:g}.nc"
                t = time.perf_counter()
                res = plan(m, job)
                st = write_gcode(path, res.toolpath, feed=job.feed, plunge_feed=job.feed / 3)
                dt = time.perf_counter() - t
                prog = read_gcode(path)
                v = verify(res.mesh, prog, r, n_samples=args.samples, scallop=1.05 * h, gouge=e, judge="reachable").summary
                q = v["reachable"]
                rc = rs274(path)
                sc = v["scallop"]
                fails = list(v["failures"])
                if v["rapid_min_clearance"] < 0.5:
                    fails.append(f"rapid clearance {v['rapid_min_clearance']:.3f}")
                if pat == "spiral" and st["passes"] != 1:
                    fails.append(f"{st['passes']} passes")
                if rc not in (0, None):
                    fails.append(f"rs274 {rc}")
                if dt > 10:
                    fails.append(f"{dt:.1f} s")
                n_fail += bool(fails)
                print(f"{m.name:16s} {len(m.F):6d} {pat:8s} {h:5g} {dt:6.2f} {st['passes']:4d} {st['cut_points']:8d} "
                      f"{st['feed_length_mm'] / 1000:7.2f} {sc['p50'] / h:6.3f} {sc['p999'] / h:7.3f} "
                      f"{sc['max'] / h:7.3f} {100 * v['uncut_fraction']:7.3f} {100 * q['unreachable_fraction']:6.2f} "
                      f"{q['scallop']['p999'] / h:8.3f} {100 * q['uncut_fraction']:8.3f} {v['gouge_max']:7.4f} "
                      f"{min(v['rapid_min_clearance'], 99):6.2f} {str(rc):>5s}  "
                      + ("PASS" if not fails else "FAIL: " + "; ".join(fails)), flush=True)
    print(f"{n_fail} failing rows")
    return 1 if n_fail else 0


if __name__ == "__main__":
    sys.exit(main())
