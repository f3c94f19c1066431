"""The holder check's speed and agreement, against checking every move exactly, one run.

:func:`conformill.verify.holder.holder_clearance` bounds every move's need from a raster of
the part's tops and resolves exactly only the moves whose bound can hold the program's
largest need (or straddle a given stick-out). The reference, measured in the same run, is
the exact pass on *every* move (whole moves, then the moves that matter in pieces of small
climb: the first version of the check, session 33), with the same kernels. The script
plans each part's default program at r = 4, h = e = 0.01 (in-process, written as G-code and
read back, as ``conformill verify`` reads it), then for each holder radius prints: the
check's time with no stick-out, with a stick-out 1 mm longer than needed (clear) and with one
5 mm shorter (refused), the reference's time and the ratio, the needed stick-out by both
(they must agree within the 0.01 mm climb: the reference shares the check's geometry
kernels, so this checks the passes' pruning; ``tests/test_holder.py`` checks the geometry
against analytic needs and sampled points), the moves the short stick-out may hit, and the
gap between the check's two bounds.

    python benchmarks/bench_holder.py [MESH ...] [--pattern zigzag] [--radii 8 16 25] [--large]

``MESH`` is a short name of :data:`_common.MESH_FILES` (default ``igea sample:face``). With
``--large``, the 620k-face mesh's contour program (scale 1400, planned here, about 15 s) is
checked too, without the reference (which takes 37-135 s there).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common  # noqa: E402


def exhaustive(V, F, program, radius: float, climb: float = 0.01) -> float:
    """The reference: every move's bounds exactly (whole moves, then the moves whose upper
    bound exceeds the largest lower bound in pieces); returns the largest upper bound."""
    from conformill.verify import holder as H

    A, B = program.segments(None)
    A, B = np.ascontiguousarray(A), np.ascontiguousarray(B)
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    edge = float(np.linalg.norm(V[F[:, 1], :2] - V[F[:, 0], :2], axis=1).mean())
    cell = max(radius / 4.0, 2.0 * edge, 1e-6)
    g0, gn, ttop, cstart, ctri, ctop = H._grid(V, F, cell)
    grid = (float(g0[0]), float(g0[1]), float(cell), int(gn[0]), int(gn[1]), cstart, ctri, ctop)
    out = np.zeros((len(A), 5))
    H._all(np.arange(len(A)), A, B, V, F, ttop, float(radius), np.inf, 0.0, np.inf, *grid, out)
    again = np.flatnonzero(out[:, 1] > out[:, 0].max())
    out2 = np.zeros((len(A), 5))
    H._all(again, A, B, V, F, ttop, float(radius), float(climb), 0.0, np.inf, *grid, out2)
    out[again, :2] = out2[again, :2]
    return float(out[:, 1].max())


def _time(f, *a, **k):
    t = time.perf_counter()
    r = f(*a, **k)
    return r, time.perf_counter() - t


def check(label, mesh, program, radii, reference: bool):
    from conformill.verify.holder import holder_clearance

    holder_clearance(mesh.V, mesh.F, program, radii[0])  # compile / load the kernels
    rows = []
    for R in radii:
        h, t0 = _time(holder_clearance, mesh.V, mesh.F, program, R)
        need = h.needed
        hc, t_clear = _time(holder_clearance, mesh.V, mesh.F, program, R, stick_out=need + 1.0)
        hs, t_short = _time(holder_clearance, mesh.V, mesh.F, program, R, stick_out=max(need - 5.0, 0.5))
        short = hs.hits(max(need - 5.0, 0.5))
        ref, t_ref = (_time(exhaustive, mesh.V, mesh.F, program, R) if reference else (float("nan"), float("nan")))
        rows.append((label, len(program), R, t0, t_clear, t_short, t_ref, t_ref / t0, need, ref,
                     short["moves_may_hit"], need - h.needed_lower, hc.hits(need + 1.0)["clear"]))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("meshes", nargs="*", default=["igea", "sample:face"])
    ap.add_argument("--pattern", default="zigzag", choices=["zigzag", "contour", "spiral"])
    ap.add_argument("--radii", type=float, nargs="+", default=[8.0, 16.0, 25.0])
    ap.add_argument("--large", action="store_true", help="also the 620k-face mesh's contour program")
    args = ap.parse_args(argv)
    from conformill.pipeline import Job, plan

    print(_common.machine())
    rows = []
    for name in args.meshes:
        mesh, _ = _common.load_part(name)
        res = plan(mesh, Job(pattern=args.pattern, tool_radius=4.0, scallop=0.01, tolerance=0.01))
        rows += check(f"{name} {args.pattern}", res.mesh, _common.program_of(res), args.radii, reference=True)
    if args.large:
        from conformill.mesh.io import read_mesh

        big = read_mesh(_common.MESHES / "large_igea_face_subdiv1.ply", scale=1400.0)
        res = plan(big, Job(pattern="contour", tool_radius=4.0, scallop=0.01, tolerance=0.01))
        rows += check("620k contour", res.mesh, _common.program_of(res), args.radii, reference=False)
    _common.print_table([("program", ""), ("moves", "d"), ("R mm", "g"), ("check s", ".2f"),
                         ("clear L s", ".2f"), ("short L s", ".2f"), ("every move s", ".2f"), ("ratio", ".0f"),
                         ("needed mm", ".3f"), ("every move: needed", ".3f"), ("short L: moves", "d"),
                         ("bounds gap mm", ".4f"), ("L + 1 clear", "")], rows)
    bad = [r for r in rows if np.isfinite(r[9]) and abs(r[8] - r[9]) > 0.01 + 1e-9]
    if bad:
        print("DISAGREE:", bad)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
