"""Where a ``conformill plan`` command's time goes, against the same plan in a warm process (issue 5).

Issue 5's ratio against OpenCAMLib is judged on what a user times: the command. The
command's process does more than the plan: the interpreter starts, the work modules are
imported (numpy, scipy, numba and the stages), numba loads each kernel from its disk cache
the first time it is called, the mesh is read, the G-code written. This script measures
those parts in one run (the host is shared and noisy: the reference is measured in the
same run, alternating with the commands):

* **command**: ``--runs`` fresh ``conformill plan`` processes (the console script, as the
  README runs it), each with ``--report``: the wall time seen from outside, and the
  report's ``read`` and ``gcode`` timings; the plan is the report's ``total`` (from the
  read to the G-code written) less those two, and *start* the wall time less ``total``
  (the interpreter, the imports, the report's own writing and the exit);
* **in the process**: one process imports the command's work modules, then plans the same
  job ``--plans`` times in a row (the first plan loads numba's cached kernels and touches
  fresh memory; the later ones are what ``bench_raster.py`` calls "in the process");
  the imports' time, the first plan's and the lowest of the later ones.

It prints each part's median, the command over the warm plan, and with ``--raster-s R``
(an OpenCAMLib raster time, ``bench_raster.py``) the ratios R / command and R / warm plan
and the command time that 20x would need.

    python benchmarks/bench_command.py [MESH] [--pattern contour] [--runs 3] [--plans 3]
        [--default] [--raster-s 104.2] [--h 0.01] [--r 4] [--e 0.01]

``MESH`` is a short name of ``_common.MESH_FILES`` (default igea; written oriented, as
``bench_raster.py`` writes the part its commands read) or a mesh file (``--scale``). The
plans use ``plan --scan``'s recipe unless ``--default``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402
from bench_param import run_child  # noqa: E402

#: The child that plans in one process (run as ``python -c``): prints a JSON line.
_IN_PROCESS = r"""
import json, logging, sys, time
t0 = time.perf_counter()
from conformill.cli.allocator import tune_allocator
from conformill.cli.main import _import_work_modules
tune_allocator()
_import_work_modules(["plan"])
t_imp = time.perf_counter() - t0
logging.disable(logging.WARNING)
from conformill.mesh.io import read_mesh
from conformill.pipeline import Job, plan, scan_recipe
a = json.loads(sys.argv[1])
mesh = read_mesh(a["mesh"], scale=a["scale"])
extra = scan_recipe(a["pattern"]) if a["scan"] else {}
job = Job(pattern=a["pattern"], tool_radius=a["r"], scallop=a["h"], tolerance=a["e"], **extra)
plans = []
for _ in range(a["plans"]):
    t, c = time.perf_counter(), time.process_time()
    plan(mesh, job)
    plans.append([time.perf_counter() - t, time.process_time() - c])
print(json.dumps({"imports": t_imp, "plans": plans}))
"""


def command_run(argv: list, report: Path) -> dict:
    """One ``conformill plan`` process: its wall time and its report's timings (a failed
    command ends the script with its stderr, :func:`bench_param.run_child`)."""
    wall = run_child(argv + ["--report", str(report), "-q"])[0]
    ts = json.loads(report.read_text())["timings_s"]
    # the report's total runs from the read to the G-code written (cli/plan.py)
    return {"wall": wall, "read": ts["read"], "plan": ts["total"] - ts["read"] - ts["gcode"], "gcode": ts["gcode"],
            "start": wall - ts["total"]}


def in_process_run(spec: dict) -> dict:
    """One process: the work modules imported, then ``spec["plans"]`` plans in a row."""
    out = run_child([sys.executable, "-c", _IN_PROCESS, json.dumps(spec)])[2]
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--pattern", default="contour", choices=("zigzag", "contour", "spiral"))
    ap.add_argument("--runs", type=int, default=3, help="fresh command processes")
    ap.add_argument("--plans", type=int, default=3, help="plans in the one warm process (at least 2)")
    ap.add_argument("--default", action="store_true", help="the default plan, not plan --scan's recipe")
    ap.add_argument("--raster-s", type=float, default=None)
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--e", type=float, default=0.01)
    args = ap.parse_args(argv)
    if args.runs < 1 or args.plans < 2:
        ap.error("--runs must be at least 1 and --plans at least 2")
    exe = Path(sys.executable).with_name("conformill")
    if not exe.exists():
        print(f"bench_command: no conformill console script beside {sys.executable}: pip install the package",
              file=sys.stderr)
        return 2
    print(_common.machine())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.mesh in _common.MESH_FILES:
            from bench_raster import write_part

            from conformill.pipeline import orient_mesh

            mesh = orient_mesh(_common.load_part(args.mesh)[0], "none")[0]
            part, scale = write_part(mesh, tmp / f"{args.mesh}.ply"), 1.0
        else:
            part, scale = Path(args.mesh), args.scale
        plan_args = [str(exe), "plan", str(part), "--scale", repr(scale), "--pattern", args.pattern,
                     "--tool-radius", repr(args.r), "--scallop", repr(args.h), "--tolerance", repr(args.e),
                     "-o", str(tmp / "p.nc")] + ([] if args.default else ["--scan"])
        spec = {"mesh": str(part), "scale": scale, "pattern": args.pattern, "r": args.r, "h": args.h, "e": args.e,
                "scan": not args.default, "plans": args.plans}
        print(f"{args.mesh}: {args.pattern}{'' if args.default else ' --scan'}, r = {args.r}, h = {args.h}, "
              f"e = {args.e}; {args.runs} commands and {args.runs} warm processes, alternating")
        run_child(plan_args + ["-q"])  # untimed: caches, disk
        cmds, procs = [], []
        for _ in range(args.runs):
            cmds.append(command_run(plan_args, tmp / "r.json"))
            procs.append(in_process_run(spec))
            c, p = cmds[-1], procs[-1]
            print(f"  command {c['wall']:.2f} s (start {c['start']:.2f}, read {c['read']:.2f}, plan {c['plan']:.2f}, "
                  f"G-code {c['gcode']:.2f});  in a process: imports {p['imports']:.2f}, plans "
                  + ", ".join(f"{w:.2f} ({cpu:.2f} CPU)" for w, cpu in p["plans"]), flush=True)
    med = {k: float(np.median([c[k] for c in cmds])) for k in cmds[0]}
    first = float(np.median([p["plans"][0][0] for p in procs]))
    warm = float(np.median([min(w for w, _ in p["plans"][1:]) for p in procs]))
    imports = float(np.median([p["imports"] for p in procs]))
    print()
    print("| part | median (s) | share of the command |")
    print("|---|---|---|")
    for k, title in (("start", "start: interpreter, imports, report, exit"), ("read", "read the mesh"),
                     ("plan", "plan"), ("gcode", "write the G-code"), ("wall", "the command")):
        print(f"| {title} | {med[k]:.2f} | {100 * med[k] / med['wall']:.0f} % |")
    print(f"| in a process: imports | {imports:.2f} | |")
    print(f"| in a process: first plan | {first:.2f} | |")
    print(f"| in a process: later plans (lowest of each process) | {warm:.2f} | |")
    print()
    print(f"the command is {med['wall'] / warm:.2f}x the warm plan ({med['wall'] - warm:.2f} s more: start "
          f"{med['start']:.2f}, read {med['read']:.2f}, G-code {med['gcode']:.2f}, the command's plan over the warm "
          f"one {med['plan'] - warm:.2f}); the first plan in a process is {first - warm:+.2f} s over the later ones")
    if args.raster_s:
        r = args.raster_s
        print(f"against a {r:.1f} s raster: command {r / med['wall']:.1f}x, warm plan {r / warm:.1f}x; "
              f"20x needs a command of {r / 20:.2f} s ({med['wall'] - r / 20:+.2f} s from this one)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
