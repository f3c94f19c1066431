"""Whole `conformill param` process against libigl's harmonic map, same mesh, same run.

Runs, each in a fresh subprocess (so peak RSS is per process, from ``os.wait4``):

1. ``conformill param MESH --scale S -o OUT.obj`` (read, geodesic weights, circle boundary,
   solve, quality, OBJ write);
2. libigl: read the mesh, ``igl.boundary_loop`` + ``igl.map_vertices_to_circle`` +
   ``igl.harmonic(V, F, bnd, bnd_uv, 1)`` (cotangent weights, circle boundary); the harmonic
   call is timed inside the child as well as the whole child.

Target: conformill's whole process <= igl's harmonic call alone; peak RSS < 4 GB.

The two are interleaved and the best of ``--repeat`` runs of each is compared; the machine's
load average is printed before and after, since other processes on a 2-core machine slow the
multithreaded Pardiso factorization more than igl's single-threaded solve. The stage timings
are the median over the conformill runs.

    python benchmarks/bench_param.py [MESH] [--scale 1400] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

DEFAULT = Path("/work/shared/meshes/large_igea_face_subdiv1.ply")

IGL_CHILD = r"""
import sys, time
import numpy as np, trimesh, igl
m = trimesh.load(sys.argv[1], process=False)
V = np.ascontiguousarray(m.vertices, dtype=np.float64) * float(sys.argv[2])
F = np.ascontiguousarray(m.faces, dtype=np.int64)
t0 = time.perf_counter()
bnd = igl.boundary_loop(F)
bnd_uv = igl.map_vertices_to_circle(np.asfortranarray(V), bnd.astype(np.int32))
uv = igl.harmonic(V, F, bnd.astype(np.int64), np.ascontiguousarray(bnd_uv), 1)
print(f"HARMONIC {time.perf_counter() - t0:.4f} {uv.shape[0]}")
"""


def run_child(cmd, env=None, rusage: bool = False):
    """Wall time (s), peak RSS (MB) and stdout of one subprocess (and, with ``rusage``, its
    whole ``resource.struct_rusage`` as a fourth item: CPU times, page faults).

    The child's pipes are drained while it runs (a child writing more than a pipe holds,
    64 KB, would otherwise wait for a reader for ever); ``os.wait4`` then gives its own
    peak RSS, which ``subprocess``'s wait would throw away. ``env``: the child's
    environment (default this one's). A failed child ends the script with its stderr.
    """
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    got = {}

    def drain(name, f):  # bytes, decoded below: a decoding error cannot lose the output
        with f:
            got[name] = f.read()

    readers = [threading.Thread(target=drain, args=(n, f), daemon=True) for n, f in (("out", p.stdout), ("err", p.stderr))]
    for t in readers:
        t.start()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    for t in readers:
        t.join()
    p.returncode = os.waitstatus_to_exitcode(status)
    out, err = (got.get(n, b"").decode("utf-8", errors="replace") for n in ("out", "err"))
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{err}")
    return (wall, ru.ru_maxrss / 1024.0, out, ru) if rusage else (wall, ru.ru_maxrss / 1024.0, out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default=str(DEFAULT))
    ap.add_argument("--scale", type=float, default=1400.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        obj = str(Path(tmp) / "out.obj")
        rep = str(Path(tmp) / "out.json")
        cm_cmd = [sys.executable, "-m", "conformill", "param", args.mesh, "--scale", str(args.scale),
                  "-o", obj, "--report", rep]
        igl_cmd = [sys.executable, "-c", IGL_CHILD, args.mesh, str(args.scale)]
        run_child(cm_cmd)  # warm numba's cache and the OS file cache
        load0 = os.getloadavg()
        cm, igl_wall, igl_h, stage_runs = [], [], [], []
        import json

        for _ in range(args.repeat):  # interleaved, so background load hits both alike
            w, rss_cm, out = run_child(cm_cmd)
            cm.append((w, rss_cm))
            stage_runs.append(json.loads(Path(rep).read_text())["timings_s"])
            w, rss_igl, out_igl = run_child(igl_cmd)
            h = float(out_igl.split("HARMONIC")[1].split()[0])
            igl_wall.append((w, rss_igl))
            igl_h.append(h)
        load1 = os.getloadavg()
    import statistics

    stages = {k: statistics.median(r[k] for r in stage_runs) for k in stage_runs[0]}
    best_cm = min(cm)
    best_igl = min(igl_wall)
    best_h = min(igl_h)
    print(f"mesh {Path(args.mesh).name} (scale {args.scale}), best of {args.repeat}; load average "
          f"{load0[0]:.2f} before, {load1[0]:.2f} after ({os.cpu_count()} CPUs)")
    print(f"conformill param (whole process)   {best_cm[0]:7.2f} s  peak RSS {max(r for _, r in cm):7.0f} MB"
          f"   all: {', '.join(f'{w:.2f}' for w, _ in cm)}")
    print("  stages (median, s): " + ", ".join(f"{k} {v:.2f}" for k, v in stages.items())
          + f"; outside the stages (start-up, imports, exit): {statistics.median(w for w, _ in cm) - stages['total']:.2f}")
    print(f"igl.harmonic call alone            {best_h:7.2f} s"
          f"   all: {', '.join(f'{h:.2f}' for h in igl_h)}")
    print(f"igl subprocess (read + harmonic)   {best_igl[0]:7.2f} s  peak RSS {max(r for _, r in igl_wall):7.0f} MB")
    print(f"ratio conformill process / igl harmonic alone: {best_cm[0] / best_h:.2f}"
          f"  (/ igl process: {best_cm[0] / best_igl[0]:.2f})")


if __name__ == "__main__":
    main()
