"""``conformill verify MESH PROGRAM.nc --tool-radius R``: simulate a program on the part.

Prints a table of remaining material (scallop), gouge, uncut area and rapid clearance;
optionally writes a JSON report and a PNG heat map. Exit 0 when the limits given are met
(or none is given), 1 when a limit is exceeded (scallop p99.9 > H or any uncut area with
``--scallop``; gouge max > G with ``--gouge``), 2 on bad input.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from conformill.cli.progress import held_back, sample_bar
from conformill.errors import ConformillError


def add_arguments(parser) -> None:
    parser.add_argument("mesh", help="part surface (STL, OBJ, PLY, OFF), faces towards the tool (+Z)")
    parser.add_argument("program", help="3-axis G-code program (tool-tip positions)")
    parser.add_argument("--tool-radius", "-r", type=float, required=True, metavar="R", help="ball radius, mm")
    parser.add_argument("--scallop", type=float, default=None, metavar="H",
                        help="scallop limit, mm: fail when p99.9 > H or any area is uncut")
    parser.add_argument("--gouge", type=float, default=None, metavar="G", help="gouge limit, mm: fail when deeper")
    parser.add_argument("--stock", type=float, default=0.0, metavar="S",
                        help="material the program leaves on the part, mm (plan --stock; default 0): every figure "
                             "is measured from the part offset by S along its normal (the scallop above it, a "
                             "gouge into the stock); negative: cut into the part, above minus the tool radius")
    parser.add_argument("--samples", type=int, default=200_000, metavar="N", help="surface samples (default 200000)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the samples (default 0)")
    parser.add_argument("--scale", type=float, default=1.0, metavar="S",
                        help="factor applied to the mesh coordinates (e.g. 1000 for metres)")
    parser.add_argument("--normals", choices=("vertex", "face"), default="vertex",
                        help="sample normals: interpolated vertex normals (default) or face normals")
    parser.add_argument("--chord-tol", type=float, default=0.001, metavar="E",
                        help="chord tolerance for linearising arcs, mm (default 0.001)")
    parser.add_argument("--judge", choices=("interior", "reachable"), default="interior",
                        help="check the scallop limit on all interior samples (default) or only where a "
                             "3-axis ball can reach (undercuts, pockets tighter than the ball and creases "
                             "where no ball position comes within H excluded)")
    parser.add_argument("--reach-depth", type=float, default=None, metavar="D",
                        help="material depth, mm, that makes a sample unreachable: the ball touching it along "
                             "its normal, or its shank, would run deeper than D into the part (undercut, pocket "
                             "tighter than the ball). It shapes the 'reachable interior' column and what "
                             "--judge reachable judges (default: H; without --scallop 0.01 R). The raster and "
                             "trade-off benchmarks judge 1.05 H with a depth of H: --scallop 1.05H --reach-depth H")
    parser.add_argument("--rest", action="store_true",
                        help="with --scallop: search the ball positions at every reachable sample left above H "
                             "and report the program's own share above the least material any ball leaves; "
                             "pass/fail does not change")
    add_holder_arguments(parser, "report the stick-out (tip to holder face) the program needs for the holder to clear "
                                 "the part on every move, and where it comes closest",
                         "fail when the holder may meet the part on any move")
    parser.add_argument("--report", default=None, metavar="OUT.json", help="write a JSON report")
    parser.add_argument("--plot", default=None, metavar="OUT.png", help="write a PNG heat map")


def _positive(name, v, allow_zero=False):
    if v is None:
        return
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ConformillError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {v!r}")


def _fmt(x, unit=" mm"):
    if x is None:
        return "-"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else "nan"
    return f"{x:.4g}{unit}"


def table(summary: dict) -> str:
    """The summary as a plain-text table (interior samples and all samples)."""
    i, a, q = summary["interior"], summary["all"], summary["reachable"]
    sets = (i, q, a)

    def pct(key):
        return tuple(f"{100 * x[key]:.4g} %" for x in sets)

    rows = [
        ("samples", *(f"{x['samples']}" for x in sets)),
        ("scallop p50", *(_fmt(x["scallop"]["p50"]) for x in sets)),
        ("scallop p99", *(_fmt(x["scallop"]["p99"]) for x in sets)),
        ("scallop p99.9", *(_fmt(x["scallop"]["p999"]) for x in sets)),
        ("scallop max", *(_fmt(x["scallop"]["max"]) for x in sets)),
    ]
    if "above_scallop_fraction" in i:
        rows.append(("area above H", *pct("above_scallop_fraction")))
    rows += [
        ("uncut area", *pct("uncut_fraction")),
        ("gouge max", *(_fmt(x["gouge_max"]) for x in sets)),
        ("gouged area (>1 um)", *pct("gouged_fraction")),
    ]
    w0 = max(len(r[0]) for r in rows) + 2
    out = [f"{'':<{w0}}{'interior (> r from boundary)':>30}{'reachable interior':>20}{'all samples':>16}"]
    out += [f"{r[0]:<{w0}}{r[1]:>30}{r[2]:>20}{r[3]:>16}" for r in rows]
    t = q["tangent_test"]
    out.append(f"unreachable by a 3-axis ball (undercut, tighter than the ball, or beyond any ball position): "
               f"{100 * q['unreachable_fraction']:.3g} % of the interior (reach depth "
               f"{_fmt(summary['thresholds']['reach_depth'])}); limits judged on: {summary['judged_on']}")
    if not q.get("searched", True):
        out.append("  (crease material no ball position removes is left out only with --judge reachable or --rest)")
    else:
        out.append(f"  of the samples the tangent ball reaches, {q['beyond_any_ball']} "
                   f"({q['beyond_any_ball_per_mille']:.3g} per mille) are left above the limit by every "
                   f"ball position searched (no program can meet it there); with them the reachable p99.9 would be "
                   f"{_fmt(t['scallop']['p999'])}"
                   + (f"; {q['unconfirmed']} not excused: the best ball found does not touch the part"
                      if q["unconfirmed"] else ""))
    rest = q.get("rest")
    if rest is not None:
        out.append(f"rest material: above the least material any ball leaves, the program's own share is "
                   f"p99.9 {_fmt(rest['p999_over_rest'])} ({rest['above_limit']} reachable samples above H; of them "
                   f"{' / '.join(str(k) for k in rest['above_limit_by_rest'])} where the best ball found leaves "
                   f"below H/2 / H/2 to 0.9 H / above 0.9 H)")
    g = summary
    if g["gouge_where"] is not None:
        x, y, z = g["gouge_where"]
        out.append(f"deepest interior gouge at ({x:.3f}, {y:.3f}, {z:.3f}) by the move on line {g['gouge_line']}")
    cl = g["rapid_min_clearance"]
    rc = f"{_fmt(cl)}" + (f" (line {g['rapid_min_line']})" if g["rapid_min_line"] is not None else "")
    out.append(f"rapid clearance min {rc} over {g['n_rapids']} rapids; "
               f"vertical retracts ({g['n_retracts']}): min {_fmt(g['retract_min_clearance'])}")
    out.append(f"feed moves {g['feed_moves']}, feed length {g['feed_length_mm']:.1f} mm, tool radius {g['tool_radius']:g} mm"
               + (f", stock {g['stock']:g} mm (the figures are measured from the part offset by it)"
                  if g.get("stock") else ""))
    modes = g.get("path_control")
    if modes:
        out.append(f"path control of the feed moves: {', '.join(modes)} (the controller's corner rounding is not "
                   f"simulated)")
        from conformill.verify.gcode import unbounded_mode

        loose = [m for m in modes if unbounded_mode(m)]
        if loose:
            out.append(f"  {', '.join(loose)}: G64 without a positive P, the controller may round their corners by "
                       f"any amount")
        if "unset" in modes:
            out.append("  unset: the machine's own mode applies (LinuxCNC's G64 without P may round corners by any "
                       "amount)")
    sp = g.get("spindle")
    if sp and sp["feed_blocks_stopped"]:
        out.append(f"spindle: {sp['feed_blocks_stopped']} feed block(s) run with the spindle stopped (no M3/M4 before "
                   f"them, or after an M5 or a tool change), the first on line {sp['first_line']}: start it by hand before running "
                   f"the program")
    if g.get("holder") is not None:
        out.append(holder_text(g["holder"]))
    if (g["thresholds"]["scallop"] is not None or g["thresholds"]["gouge"] is not None
            or (g.get("holder") or {}).get("stick_out") is not None):
        out.append("PASS" if g["pass"] else "FAIL: " + "; ".join(g["failures"]))
    return "\n".join(out)


def spindle_summary(program) -> dict:
    """The report's ``spindle`` entry of a program read by :func:`conformill.verify.gcode.read_gcode`:
    how many feed blocks run with the spindle stopped, and the line of the first (``None``: none)."""
    return {"feed_blocks_stopped": int(program.spindle_off_feeds),
            "first_line": int(program.spindle_off_line) if program.spindle_off_feeds else None}


def _xyz(p) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in p) + ")"


def add_holder_arguments(parser, does: str, short: str) -> None:
    """``--holder-radius``, ``--holder-step`` and ``--stick-out`` (plan and verify): ``does``
    says what the check gives, ``short`` what a stick-out the holder may not clear does."""
    parser.add_argument("--holder-radius", type=float, default=None, metavar="R",
                        help=f"radius of the tool holder at its face, mm: {does}")
    parser.add_argument("--holder-step", type=holder_step, action="append", default=[], metavar="R@H",
                        help="with --holder-radius: a wider part of the holder, radius R from H mm above its face "
                             "(repeat for each step; e.g. a collet nut, then the body)")
    parser.add_argument("--stick-out", type=float, default=None, metavar="L",
                        help=f"with --holder-radius: the tool's stick-out, mm; {short}")


def holder_step(text: str) -> tuple[float, float]:
    """``--holder-step R@H``: a radius and a height (argparse reports anything else, exit 2)."""
    import argparse

    try:
        r, at = text.split("@")
        return float(r), float(at)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R@H (radius @ height above the holder's face, mm), "
                                         f"got {text!r}") from None


def holder_name(h: dict) -> str:
    """``R10`` or, for a stepped holder, ``R10, R17 from 25 mm``."""
    return ", ".join([f"R{h['radius']:g}"] + [f"R{r:g} from {at:g} mm" for r, at in h.get("steps", [])])


def ring_name(h: dict) -> str:
    """The cylinder that sets the need: ``R16`` or ``R25 (15 mm above the face)``."""
    r, at = h.get("worst_ring") or (h["radius"], 0.0)
    return f"R{r:g}" + (f" ({at:g} mm above the face)" if at else "")


def holder_text(h: dict) -> str:
    """The holder check's figures (:meth:`conformill.verify.holder.HolderCheck.summary`) in a
    line or two of text."""
    text = f"holder {holder_name(h)}: needs a stick-out of {h['needed_stick_out']:.3f} mm"
    if h["worst_line"] is not None and h["worst_part"] is not None:
        text += (f" (the part at {_xyz(h['worst_part'])} within {ring_name(h)} of the move on line "
                 f"{h['worst_line']}, tip {_xyz(h['worst_tip'])})")
    if h.get("stick_out") is not None:
        if h["clear"]:
            text += f"\n  stick-out {h['stick_out']:g} mm: clears the part by {h['clearance']:.3f} mm"
        else:
            text += (f"\n  stick-out {h['stick_out']:g} mm: {holder_failure(h)}")
    return text


def holder_failure(h: dict) -> str:
    """Why a stick-out fails: how many moves, from which line, and what would clear."""
    sure = (f"{h['moves_hit']} of them certainly" if h["moves_hit"] else "none certainly: within the "
            f"{h['needed_stick_out'] - h['needed_lower']:.3f} mm the bounds leave")
    return (f"the holder may meet the part on {h['moves_may_hit']} moves ({sure}), the first on line "
            f"{h['first_line']}; a stick-out of at least {h['needed_stick_out']:.3f} mm clears it")


def run(args) -> int:
    from conformill.output.atomic import check_writable
    from conformill.verify.holder import check_holder, check_steps

    _positive("--tool-radius", args.tool_radius)
    _positive("--scallop", args.scallop, allow_zero=True)
    _positive("--gouge", args.gouge, allow_zero=True)
    _positive("--reach-depth", args.reach_depth)
    from conformill.planning.steps import check_stock  # numba: not at the CLI's import

    check_stock(args.stock, args.tool_radius, ConformillError, "--stock")
    _positive("--scale", args.scale)
    _positive("--chord-tol", args.chord_tol)
    if args.samples < 1:
        raise ConformillError(f"--samples must be >= 1, got {args.samples}")
    if (args.stick_out is not None or args.holder_step) and args.holder_radius is None:
        raise ConformillError("--stick-out and --holder-step need --holder-radius (the holder's face)")
    check_holder(args.holder_radius, args.stick_out)
    check_steps(args.holder_step, args.holder_radius)
    if args.rest and args.scallop is None:
        raise ConformillError("--rest needs --scallop (the rest is searched where more than H is left)")
    check_writable(args.report, args.plot, inputs=(args.mesh, None if args.program == "-" else args.program))
    if args.program != "-" and (not Path(args.program).exists() or Path(args.program).is_dir()):
        raise ConformillError(f"G-code file {args.program} does not exist (or is a folder)")
    from conformill import warm

    # on a first run a second process compiles the kernels of the cutter (the reachable judge's
    # and the rest's search drop the ball) and of the holder check
    parts = (("cutter",) if args.judge == "reachable" or args.rest else ()) + (
        ("holder",) if args.holder_radius is not None else ())
    with warm.beside(parts):
        return _check(args)


def _check(args) -> int:
    """Read, simulate, report: :func:`run` once the arguments are checked."""
    from conformill.mesh.io import read_mesh
    from conformill.planning.steps import check_ball_size
    from conformill.verify.gcode import read_gcode
    from conformill.verify.holder import check_holder_fits
    from conformill.verify.simulate import check_cuts, verify

    t0 = time.perf_counter()
    with held_back():  # the reads' warnings are printed once the checks pass
        mesh = read_mesh(args.mesh, scale=args.scale, validate=False)
        check_ball_size(args.tool_radius, mesh.V, ConformillError, "--tool-radius", stock=args.stock)  # before reading
        if args.program == "-":
            from conformill.verify.gcode import program_text

            source = program_text(sys.stdin.buffer.read(), "standard input")  # refused if binary, as a file is
        else:
            source = Path(args.program)
        program = read_gcode(source, chord_tol=args.chord_tol)
        check_cuts(program)
        check_holder_fits(args.holder_radius, args.tool_radius)  # exit 3: after every check of input (exit 2)
    quiet = getattr(args, "quiet", False)
    with sample_bar(args.samples, "simulating", enabled=not quiet) as update:
        res = verify(mesh, program, args.tool_radius, n_samples=args.samples, seed=args.seed,
                     scallop=args.scallop, gouge=args.gouge, normals=args.normals, judge=args.judge,
                     progress=update, rest=args.rest, reach_depth=args.reach_depth, stock=args.stock)
    summary = dict(res.summary)
    if args.holder_radius is not None:
        from conformill.verify.holder import holder_clearance

        h = holder_clearance(mesh.V, mesh.F, program, args.holder_radius, stick_out=args.stick_out,
                             steps=args.holder_step)
        summary["holder"] = h.summary(args.stick_out)
        if args.stick_out is not None and not summary["holder"]["clear"]:
            summary["failures"] = [*summary["failures"], f"holder {holder_name(summary['holder'])} at stick-out "
                                   f"{args.stick_out:g} mm: {holder_failure(summary['holder'])}"]
            summary["pass"] = False
    seconds = time.perf_counter() - t0
    summary.update(mesh=mesh.name, program=program.source, faces=mesh.n_faces, scale=args.scale, seconds=seconds,
                   path_control=list(program.path_modes), spindle=spindle_summary(program))
    from conformill.output.atomic import all_or_nothing

    with all_or_nothing(args.report, args.plot):  # both or neither
        if args.report:
            from conformill.output.report import write_json

            write_json(args.report, summary)
        if args.plot:
            from conformill.output.plot_verify import plot_verify

            plot_verify(args.plot, res, title=f"{mesh.name} / {program.source}")
    if not quiet:
        print(table(summary))
        print(f"({seconds:.1f} s)")
    return 0 if summary["pass"] else 1
