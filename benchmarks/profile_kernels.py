"""Where a plan's CPU goes, kernel by kernel: ``perf`` samples attributed to numba's kernels.

py-spy sees only Python frames (a numba kernel is one opaque call, and its worker threads
none at all), and numba's cached kernels carry no symbols that ``perf`` could name. This
script plans the part once in a child process (numba's caches loaded), then a second time
with ``perf record`` enabled (``cpu-clock``, every thread: the pipeline's workers and
numba's), and names each sample by the kernel whose machine code holds it: the child
writes the entry address of every compiled conformill kernel it loaded, and a sample is
given to the nearest entry below it (each cached kernel is one block of code). Samples in
other libraries (numpy, MKL, the kernel's page clearing) keep their own symbols.

Read the shares with these caveats. A kernel that numba inlined counts for its caller
(``_scan_cell`` in ``_drop_point``, ``_set_top`` in its callers). A kernel called from
other kernels is linked into each caller's compiled code as a weak copy, and the process
runs the copy it loaded first: ``_drop_point`` and ``_tri_drop`` (explicit signatures,
loaded at import) get the samples of every caller, but a helper without a signature that
is not inlined (``_refine_move``, ``_holding``, ``pencil._model_search`` and about twenty
more) has no entry of its own, and its samples go to the caller whose code was loaded
first, which may not be the one that ran it. Session 58 on igea contour ``--scan``:
``_drop_point`` 26 %, ``_tri_drop`` 16 %, ``folds._crossings`` 12 %, then nothing above 3 %.

    python benchmarks/profile_kernels.py [MESH] [--pattern contour] [--scale S] [--default]
        [--freq 1999] [--top 30]

``MESH`` is a short name of ``_common.MESH_FILES`` (default igea) or a mesh file (with
``--scale``, as ``bench_scale.py`` reads the 620k mesh). The plan uses ``plan --scan``'s
recipe unless ``--default``. Needs Linux ``perf`` with the ``cpu-clock`` event allowed
(``kernel.perf_event_paranoid`` <= 2 for one's own processes); exits 2 with a message
otherwise.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402

#: The first argument that makes this script the recorded child (not a user's option).
_CHILD = "--recorded-child"


def _child(argv) -> int:
    """Plan twice (in a process set up as the command's); perf records the second plan;
    write the kernels' entry addresses."""
    import logging

    logging.disable(logging.WARNING)
    from numba.core.registry import CPUDispatcher

    from conformill.cli.allocator import tune_allocator

    tune_allocator()  # glibc's allocator as ``conformill plan`` sets it

    from conformill.pipeline import Job, plan, scan_recipe

    mesh_arg, pattern, scale, default, ctl, ack, out = argv

    def say(word):  # to perf's control fifo, then wait for its acknowledgement
        with open(ctl, "w") as f:
            f.write(word + "\n")
        with open(ack) as f:
            f.readline()

    mesh = _common.study_mesh(mesh_arg, float(scale))
    job = Job(pattern=pattern, tool_radius=4.0, scallop=0.01, tolerance=0.01,
              **({} if default == "1" else scan_recipe(pattern)))
    plan(mesh, job)  # numba's caches loaded, first-call costs paid
    say("enable")
    t = time.perf_counter()
    plan(mesh, job)
    t = time.perf_counter() - t
    say("disable")
    rows = set()
    for name, mod in list(sys.modules.items()):
        if not name.startswith("conformill"):
            continue
        for attr, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher):
                for cres in obj.overloads.values():
                    try:
                        a = cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)
                        if a:
                            rows.add((a, f"{obj.py_func.__module__}.{obj.py_func.__name__}"))
                    except Exception:  # a kernel without a loaded library: nothing to name
                        pass
    with open(out, "w") as f:
        f.write(f"# the recorded plan {t:.2f} s\n")
        for a, n in sorted(rows):
            f.write(f"{a:x} {n}\n")
    return 0


def main(argv=None) -> int:
    if len(sys.argv) > 1 and sys.argv[1] == _CHILD:
        return _child(sys.argv[2:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--pattern", default="contour", choices=["zigzag", "contour", "spiral"])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--default", action="store_true", help="the default plan, not plan --scan's recipe")
    ap.add_argument("--freq", type=int, default=1999, help="samples per second and thread (default 1999)")
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args(argv)
    if shutil.which("perf") is None:
        print("profile_kernels: `perf` not found (Linux perf tools)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        ctl, ack, data, addrs = (os.path.join(tmp, n) for n in ("ctl", "ack", "perf.data", "addrs.txt"))
        os.mkfifo(ctl)
        os.mkfifo(ack)
        cmd = ["perf", "record", "-q", "-D", "-1", "--control", f"fifo:{ctl},{ack}", "-e", "cpu-clock", "-F",
               str(args.freq), "-o", data, sys.executable, __file__, _CHILD, args.mesh, args.pattern,
               repr(args.scale), "1" if args.default else "0", ctl, ack, addrs]
        print(f"profile_kernels: planning {args.mesh} twice under perf ...", file=sys.stderr, flush=True)
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0 or not os.path.exists(addrs):
            print(f"profile_kernels: perf record failed ({p.returncode}): {p.stderr.strip()[-600:]}", file=sys.stderr)
            return 2
        entries, head = [], ""
        for line in open(addrs):
            if line.startswith("#"):
                head = line[1:].strip()
                continue
            a, n = line.split(" ", 1)
            entries.append((int(a, 16), n.strip()))
        entries.sort()
        keys = [a for a, _ in entries]
        script = subprocess.run(["perf", "script", "-i", data, "-F", "ip,sym"], capture_output=True, text=True)
        if script.returncode != 0:
            print(f"profile_kernels: perf script failed ({script.returncode}): {script.stderr.strip()[-600:]}",
                  file=sys.stderr)
            return 2
    count = collections.Counter()
    total = 0
    for line in script.stdout.splitlines():
        parts = line.split(None, 1)
        if not parts:
            continue
        total += 1
        sym = parts[1].strip() if len(parts) > 1 else "[unknown]"
        if sym != "[unknown]":
            count[f"(lib) {sym}"] += 1
            continue
        ip = int(parts[0], 16)
        i = bisect.bisect_right(keys, ip) - 1
        # a cached kernel's code lies within a few hundred kB of its entry
        count[entries[i][1] if i >= 0 and ip - keys[i] < (1 << 20) else "(unnamed code)"] += 1
    if total == 0:
        print("profile_kernels: perf recorded no samples (is the cpu-clock event allowed?)", file=sys.stderr)
        return 2
    print(f"{args.mesh} {args.pattern}{'' if args.default else ' --scan'}: {head}, {total} samples "
          f"({args.freq} per s per thread), {_common.machine()}")
    print("| share | kernel or symbol |\n|---|---|")
    for name, n in count.most_common(args.top):
        print(f"| {100.0 * n / max(total, 1):5.1f} % | {name} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
