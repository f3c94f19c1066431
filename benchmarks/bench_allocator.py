"""`conformill plan` with the command's allocator settings against glibc's defaults, same run.

The command line sets glibc's mmap threshold, trim threshold and top pad so that freed
blocks are reused (:mod:`conformill.cli.allocator`). This runs the same ``conformill plan``
with them and with glibc's defaults (``CONFORMILL_MALLOC=default``, which tells the command
to leave the allocator alone; a ``MALLOC_*`` variable would do so too, but setting
``MALLOC_TOP_PAD_``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_MMAP_THRESHOLD_`` or
``MALLOC_MMAP_MAX_`` turns off glibc's rising mmap threshold), alternating, in fresh processes, and
prints per run the wall time, the user and system CPU time, the minor page faults and the
peak RSS (``os.wait4``), then per setting the median and the ratio tuned / default. The
programs must be the same bytes (their md5 is compared).

    python benchmarks/bench_allocator.py [PART] [--pattern zigzag] [--rounds 4] [--plan-args "--scan"]

``PART``: a key of ``_common.MESH_FILES`` (scaled to mm as every benchmark does), or a mesh
file with ``--scale``; default the 620k-face mesh at x1400. One untimed plan comes first.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shlex
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import _common  # noqa: E402
from bench_param import run_child  # noqa: E402

DEFAULT = _common.MESHES / "large_igea_face_subdiv1.ply"
#: the command leaves the allocator as glibc has it
GLIBC_DEFAULT = {"CONFORMILL_MALLOC": "default"}


def run(cmd, env) -> dict:
    """Wall time, CPU times, minor faults and peak RSS of one child (which must succeed)."""
    wall, rss, _, ru = run_child(cmd, env=env, rusage=True)
    return {"wall": wall, "user": ru.ru_utime, "sys": ru.ru_stime, "minflt": ru.ru_minflt, "rss_mb": rss}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", nargs="?", default=str(DEFAULT))
    ap.add_argument("--scale", type=float, default=None, help="for a mesh file (default 1400 for the 620k mesh)")
    ap.add_argument("--pattern", default="zigzag", choices=["zigzag", "contour", "spiral"])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--plan-args", default="", metavar="ARGS", help="more options for every plan, one string")
    args = ap.parse_args(argv)
    print(_common.machine())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.part in _common.MESH_FILES:
            from bench_raster import write_part

            mesh, _ = _common.load_part(args.part)
            part, scale = write_part(mesh, tmp / f"{mesh.name}.ply"), None
        else:
            if not Path(args.part).exists():
                print(f"no mesh at {args.part}: skipped")
                return 0
            part = Path(args.part)
            scale = args.scale if args.scale is not None else (1400.0 if part == DEFAULT else None)
        base = [sys.executable, "-m", "conformill", "plan", str(part), "--pattern", args.pattern,
                "--tool-radius", "4", "--scallop", "0.01", "--tolerance", "0.01", "-q",
                *(["--scale", str(scale)] if scale else []), *shlex.split(args.plan_args)]
        clean = {k: v for k, v in os.environ.items()
                 if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "CONFORMILL_MALLOC")}
        settings = {"tuned": clean, "glibc default": {**clean, **GLIBC_DEFAULT}}
        run(base + ["-o", str(tmp / "warm.nc")], clean)  # untimed: caches, files
        rows = {k: [] for k in settings}
        md5 = {}
        print(f"{' ':14s} {'wall s':>7s} {'user s':>7s} {'sys s':>6s} {'minflt':>8s} {'peak MB':>8s}")
        for i in range(args.rounds):
            order = list(settings) if i % 2 == 0 else list(settings)[::-1]
            for name in order:
                out = tmp / f"{name.replace(' ', '_')}.nc"
                r = run(base + ["-o", str(out)], settings[name])
                rows[name].append(r)
                md5.setdefault(name, hashlib.md5(out.read_bytes()).hexdigest())
                print(f"{name:14s} {r['wall']:7.2f} {r['user']:7.2f} {r['sys']:6.2f} {r['minflt']:8d} "
                      f"{r['rss_mb']:8.0f}", flush=True)
        med = {k: {f: statistics.median(r[f] for r in v) for f in v[0]} for k, v in rows.items()}
        print("\nmedians:")
        for k, m in med.items():
            print(f"{k:14s} {m['wall']:7.2f} {m['user']:7.2f} {m['sys']:6.2f} {m['minflt']:8.0f} {m['rss_mb']:8.0f}")
        t, d = med["tuned"], med["glibc default"]
        pairs = [a["wall"] < b["wall"] for a, b in zip(rows["tuned"], rows["glibc default"])]
        print(f"tuned / default: wall {t['wall'] / d['wall']:.3f} ({sum(pairs)} of {len(pairs)} rounds quicker), "
              f"system time {t['sys'] / d['sys']:.2f}, minor faults {t['minflt'] / d['minflt']:.2f}, "
              f"peak {t['rss_mb'] / d['rss_mb']:.2f}")
        same = len(set(md5.values())) == 1
        print("programs:", "the same bytes" if same else f"DIFFER {md5}")
        return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
