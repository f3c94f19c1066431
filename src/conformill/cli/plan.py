"""``conformill plan``: a ball-end finishing program for a disk mesh."""

from __future__ import annotations

import argparse
import sys
import time

from conformill.cli.progress import StageProgress, WarnOnce, held_back, printed_through, sample_bar
from conformill.errors import ConformillError, PlanningError


def add_arguments(p) -> None:
    p.add_argument("mesh", help="mesh file (STL, OBJ, PLY, OFF) or sample:NAME")
    p.add_argument("--pattern", choices=["zigzag", "contour", "spiral"], default="spiral")
    p.add_argument("--tool-radius", type=float, required=True, metavar="R", help="ball radius, mm")
    p.add_argument("--scallop", type=float, required=True, metavar="H", help="scallop height, mm")
    p.add_argument("--tolerance", type=float, default=0.01, metavar="E", help="chord deviation, mm (0.01)")
    p.add_argument("--stock", type=float, default=0.0, metavar="S",
                   help="material to leave on the part, mm (default 0): the program finishes the part offset by S "
                        "along its normal (a semi-finish before the finish), with the scallop H on that offset and "
                        "the ball never nearer the part than S less E/2; negative: cut S into the part (an EDM "
                        "electrode's gap), above minus the tool radius. --verify judges it on the offset")
    p.add_argument("--feed", type=float, default=1000.0, metavar="F", help="cutting feed, mm/min (1000)")
    p.add_argument("--plunge-feed", type=float, default=None, metavar="F", help="plunge feed (feed/3)")
    p.add_argument("--spindle", type=float, default=None, metavar="RPM",
                   help="spindle speed: M3 S<RPM> before the first move (default none: the program does not start "
                        "the spindle, and its header and summary say so)")
    p.add_argument("--safe-z", type=float, default=None, metavar="Z", help="rapid height (part top + 5)")
    p.add_argument("--scale", type=float, default=1.0, metavar="S", help="multiply coordinates (to mm)")
    p.add_argument("--orient", choices=["none", "auto"], default="none",
                   help="auto: turn the part so its mean normal is +Z")
    p.add_argument("--weights", default="geodesic", choices=["geodesic", "floater", "mean_value", "cotangent"])
    from conformill.cli.param import corners_arg

    p.add_argument("--corners", type=corners_arg, default=None, metavar="i,j,k,l",
                   help="rectangle corners (zigzag): four boundary vertex ids in boundary order")
    p.add_argument("--concave-steps", choices=["flat", "exact"], default="flat",
                   help="side step where the surface is concave: never wider than on a plane (flat, default) "
                        "or the paper's concave formula (exact)")
    p.add_argument("--spacing", choices=["adaptive", "paper", "local"], default="adaptive",
                   help="paths bend to give each place the side step it needs (adaptive, default), are "
                        "the paper's iso-lines spaced by the smallest step along each (paper), or are adaptive "
                        "and also dent locally at narrow dips of the step (local: zigzag and contour 18-28%% "
                        "shorter on scans, more material at scan creases)")
    p.add_argument("--settle", type=float, default=0.5, metavar="F",
                   help="largest float of a move above the drop surface, as a fraction of the scallop: moves "
                        "that ride over a groove narrower than the ball get a point where the ball sits in it "
                        "(0.5; 0: off)")
    p.add_argument("--fit", choices=["mesh", "split"], default="mesh",
                   help="scale of the curvature fit the paths are spaced from: each vertex's 1-ring (mesh, "
                        "default) or the 1-ring of the mesh split once at its edge midpoints (split: the same "
                        "surface at half the edge length; it reads about twice the curvature at the input's vertices: "
                        "on scans a smaller scallop for a longer program)")
    p.add_argument("--pencil", action="store_true",
                   help="after the pattern, cut pencil passes through the best ball positions where the part is "
                        "tighter than the ball (scan creases, rims of tight concave regions): on scans the "
                        "verified scallop came within 1.05 H on six of the eight scans measured for 2-20 %% more "
                        "feed, at some seconds more (on a deep relief a higher --pencil-density helps)")
    p.add_argument("--pencil-density", type=float, default=30.0, metavar="D",
                   help="surface samples (or, with --pencil-search folds, XY grid points) per mm^2 the pencil "
                        "passes are searched from (30)")
    p.add_argument("--pencil-search", choices=["folds", "samples"], default=None,
                   help="how the pencil stage finds the wedged balls: the best ball of each surface sample "
                        "(samples, default; folds with --scan), or the folds of the drop surface crossing an XY grid (folds: on the "
                        "scans measured an 18-51 %% quicker stage and the same or a lower scallop, for 1-15 points "
                        "more feed)")
    p.add_argument("--pencil-left", type=float, default=None, metavar="F",
                   help="with --pencil-search folds: cut the pencil only through the fold points where the "
                        "pattern's passes leave more than F H in the fold's shadow, and the steep walls' centres "
                        "where they leave more than F H at the centre's sample (estimated from the passes): at 0.5, "
                        "0-7 %% less feed on the eleven meshes measured, the verified scallop within 0.005 H but on "
                        "one relief (+0.013 H, failing either way; session 31, before the steep centres were "
                        "probed). Default: every fold point (0.5 with --scan)")
    p.add_argument("--fill", type=_fill, default=None, metavar="T|off",
                   help="after the pattern (and the pencil), fill passes through the balls that reach the surface "
                        "samples (30 per mm^2) the passes left more than T H, by the planner's estimate; a sample "
                        "no ball reaches within 0.5 H is left to the pencil (default: no fill; 0.7 with --scan, "
                        "where off leaves it out and spaces the pattern for H)")
    p.add_argument("--pattern-scallop", type=float, default=None, metavar="F",
                   help="space the pattern's paths for F H (default 1; with --scan 1.3 for zigzag, 1.7 for contour "
                        "and spiral); above 1 it needs --fill, which cuts what the wider paths leave above T H")
    p.add_argument("--scan", action="store_true",
                   help="settings for a scanned part: --pencil --pencil-search folds --pencil-left 0.5 "
                        "--hop-lifted 3 --pattern-scallop 1.3 (1.7 contour, 1.7 spiral) --fill 0.7, each unless "
                        "given (with --pencil-search samples, no --pencil-left). R4, H 0.01: 27 of 33 benchmark "
                        "programs within 1.05 H (25 without the fill and the wider paths), up to 17 %% shorter on "
                        "the scans (sessions 53-55)")
    p.add_argument("--hop-lifted", type=float, default=None, metavar="L",
                   help="hop over runs of the path where the drop-cutter lifts the ball more than L mm above "
                        "its planned contact (undercuts, pockets tighter than the ball) where the hop is quicker "
                        "than riding the run: a rapid up to 1 mm clear of the part (never above the safe height), "
                        "across, and a plunge. A shorter program (igea, L = 3: 12-16 %% less time at the feeds, "
                        "rapids not counted) and a slightly quicker plan, a little more material at the rims of "
                        "those regions (0: off, default; 3 with --scan; docs/issue5.md, \"Hops over lifted runs\")")
    p.add_argument("--rapid", type=float, default=5000.0, metavar="F",
                   help="the machine's rapid rate, mm/min, for deciding hops (5000)")
    p.add_argument("--blend", type=_blend, default=None, metavar="P|off",
                   help="path control written for the controller: round the corners of the path by at most P mm "
                        "(G64 P<P> Q0: LinuxCNC's G64 without P rounds them by any amount, and Q0 keeps every "
                        "point: no merging of nearly collinear moves); 0: exact path (G61); off: none written, the "
                        "machine's own mode. Default: min(E, H)/4 (the moves cut at most E/2, the rounding E/4 "
                        "more; above the surface within the H/4 the planner allows its chords). Not simulated by "
                        "--verify")
    p.add_argument("--tool-number", type=int, default=None, metavar="N",
                   help="change to tool N and apply its length from the machine's tool table (T N M6, G43 H N); "
                        "default: none, the tool tip is touched off (the program cancels length offsets, G49)")
    p.add_argument("--coolant", choices=["flood", "mist"], default=None,
                   help="turn the coolant on before the first move, after the spindle start when --spindle is given "
                        "(flood: M8, mist: M7), and off at the end (M9); "
                        "default: no coolant words")
    from conformill.cli.verify import add_holder_arguments

    add_holder_arguments(p, "check the written program and report the stick-out (tip to holder face) it needs for the "
                            "holder to clear the part on every move",
                         "a program on which the holder may meet the part is refused (exit 3, nothing written), naming "
                         "the first line and the stick-out that clears")
    p.add_argument("--max-step", type=float, default=10.0, metavar="L", help="longest forward step, mm (10)")
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help="threads for parallel stages (default all; with 1 the cutter runs after the pattern stage, "
                        "and a first run compiles in this process only)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.nc")
    p.add_argument("--report", default=None, metavar="OUT.json")
    p.add_argument("--plot", default=None, metavar="OUT.png")
    p.add_argument("--html", default=None, metavar="OUT.html", help="self-contained 3D viewer")
    p.add_argument("--verify", action="store_true",
                   help="simulate the written program (conformill verify) and add its figures to the report")
    p.add_argument("--verify-samples", type=int, default=400_000, metavar="N",
                   help="surface samples for --verify (400000)")
    p.add_argument("--verify-scallop", type=float, default=None, metavar="H",
                   help="scallop height --verify judges against, mm (default: --scallop); lets a program "
                        "planned with a margin (a smaller --scallop) be checked against the specified height; "
                        "implies --verify")
    p.add_argument("--replan", type=int, default=0, metavar="N",
                   help="when --verify fails on the scallop alone (p99.9 over 1.05 H on the reachable area, nothing "
                        "uncut, no gouge), plan again for a smaller scallop and check again, up to N times: the "
                        "next plan's scallop is the last one times 0.97 x 1.05 H / p99.9, kept between 0.5 and 0.95 "
                        "of it; H stays what was asked (--verify-scallop, else --scallop). The last program is "
                        "written and the report's replan lists every round. Implies --verify. Default 0: none")


def _number_or_off(unit: str):
    """An argparse type: "off" or a number (``unit`` in the message; argparse reports
    anything else, exit 2)."""

    def parse(text: str):
        if text.strip().lower() == "off":
            return "off"
        try:
            if "_" in text:
                raise ValueError
            return float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number ({unit}) or off, got {text!r}") from None

    return parse


_blend = _number_or_off("mm")  # --blend
_fill = _number_or_off("x H")  # --fill


def _scan_defaults(args) -> None:
    """Fill the options ``--scan`` sets (:data:`conformill.pipeline.SCAN_RECIPE`) where the
    command line left them unset; ``--hop-lifted`` unset and no ``--scan`` is 0 (off)."""
    from conformill.pipeline import SCAN_RECIPE, scan_recipe

    if args.scan:
        args.pencil = True
        if args.pencil_search is None:
            args.pencil_search = SCAN_RECIPE["pencil_search"]
        if args.pencil_left is None and args.pencil_search == "folds":
            args.pencil_left = SCAN_RECIPE["pencil_left"]
        if args.hop_lifted is None:
            args.hop_lifted = SCAN_RECIPE["hop_lift"]
        if args.fill is None:
            args.fill = SCAN_RECIPE["fill"]
        if args.pattern_scallop is None and args.fill != "off":  # wider paths only with the fill
            args.pattern_scallop = scan_recipe(args.pattern)["pattern_scallop"]
    if args.hop_lifted is None:
        args.hop_lifted = 0.0
    if args.pattern_scallop is None:
        args.pattern_scallop = 1.0
    if args.fill == "off":
        args.fill = None


def run(args) -> int:
    from conformill.output.atomic import check_writable
    from conformill.pipeline import Job

    check_writable(args.output, args.report, args.plot, args.html, inputs=(args.mesh,))
    if args.threads is not None:
        if args.threads < 1:
            raise ConformillError(f"--threads must be at least 1, got {args.threads}")
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    if args.corners is not None and args.pattern != "zigzag":
        raise ConformillError("--corners needs --pattern zigzag (the rectangle's corners)")
    _scan_defaults(args)
    job = Job(pattern=args.pattern, tool_radius=args.tool_radius, scallop=args.scallop, tolerance=args.tolerance,
              feed=args.feed, plunge_feed=args.plunge_feed, safe_z=args.safe_z, orient=args.orient,
              weights=args.weights, corners=args.corners, max_step=args.max_step, spindle=args.spindle,
              concave_steps=args.concave_steps, spacing=args.spacing, settle=args.settle, fit=args.fit,
              pencil=args.pencil, pencil_density=args.pencil_density, hop_lift=args.hop_lifted,
              rapid=args.rapid, pencil_left=args.pencil_left, blend=args.blend, tool_number=args.tool_number,
              coolant=args.coolant, stock=args.stock, fill=args.fill, pattern_scallop=args.pattern_scallop,
              **({} if args.pencil_search is None else {"pencil_search": args.pencil_search}))
    from conformill.pipeline import check_job

    params = check_job(job, together=False)  # exit 2 first: every single value, then the combinations (exit 3)
    if (args.stick_out is not None or args.holder_step) and args.holder_radius is None:
        raise ConformillError("--stick-out and --holder-step need --holder-radius (the holder's face)")
    from conformill.verify.holder import check_holder, check_steps

    check_holder(args.holder_radius, args.stick_out)
    check_steps(args.holder_step, args.holder_radius)
    if args.replan < 0:
        raise ConformillError(f"--replan must be 0 or more, got {args.replan}")
    if args.verify_scallop is not None or args.replan > 0:  # asking for a judged height is asking for the check
        args.verify = True
    if args.verify and args.verify_samples < 1:
        raise ConformillError(f"--verify-samples must be >= 1, got {args.verify_samples}")
    judge_h = job.scallop if args.verify_scallop is None else float(args.verify_scallop)
    if not (judge_h > 0 and judge_h < float("inf")):
        raise ConformillError(f"--verify-scallop must be a positive number, got {args.verify_scallop}")
    from conformill import warm

    # on a first run a second process compiles the later stages' kernels (not with --threads 1)
    parts = ("cutter",) + (("verify",) if args.verify else ()) + (
        ("holder",) if args.holder_radius is not None else ())
    with warm.beside(parts):
        return _run_job(args, job, params, judge_h)


def _run_job(args, job, params, judge_h: float) -> int:
    """Read, plan, write and check: :func:`run` once the arguments are checked one by one.
    The mesh is read and checked (exit 2) before the values are checked together (exit 3),
    so that any malformed input is named first. With ``--replan N``, plan, write and verify
    again for a smaller scallop (:func:`replan_scallop`) while the check fails on the
    scallop alone, at most N more times."""
    from conformill.mesh.io import read_mesh
    from conformill.output.atomic import all_or_nothing
    from conformill.output.gcode import write_gcode
    from conformill.output.report import write_json
    from conformill.pipeline import check_job_on, plan, with_overrides
    from conformill.verify.holder import check_holder_fits

    t0 = time.perf_counter()
    with held_back():  # the read's warnings are printed once the checks pass
        t = time.perf_counter()
        mesh = read_mesh(args.mesh, scale=args.scale)
        t_read = time.perf_counter() - t
        check_job_on(job, params, mesh)  # exit 2 against the mesh, then the values together (exit 3)
        check_holder_fits(args.holder_radius, job.tool_radius)
    rounds = []  # --replan: one entry per plan
    once = WarnOnce() if args.replan else None  # the same mesh warns the same on every plan: once is enough
    with all_or_nothing(args.output, args.report, args.plot, args.html):
        while True:
            t_round = time.perf_counter()
            progress = StageProgress(enabled=not args.quiet)
            try:
                with progress.logging(), printed_through(once):
                    result = plan(mesh, job, progress=progress)
            finally:
                progress.close()
            report = result.report
            report["timings_s"]["read"] = t_read
            header = _header(args, job, result)
            if rounds:  # only then: a program planned once keeps its bytes
                header["replanned"] = (f"plan {len(rounds) + 1} of at most {args.replan + 1} (--replan): scallop "
                                       f"{job.scallop:.6g} planned so that --verify passes at {judge_h:g}")
            t = time.perf_counter()
            stats = write_gcode(args.output, result.toolpath, feed=job.feed, plunge_feed=job.plunge_rate,
                                spindle=job.spindle, header=header, blend=job.blend_tolerance,
                                tool=job.tool_number, coolant=job.coolant)
            report["timings_s"]["gcode"] = time.perf_counter() - t
            report["program"] = stats
            program = None
            if args.verify or args.html or args.holder_radius is not None:
                from conformill.verify.gcode import read_gcode

                # the checks and the viewer use the program as written: what the machine will run
                program = read_gcode(args.output)
            if not args.verify:
                break
            t = time.perf_counter()
            report["verify"] = v = _verify(result.mesh, program, job, args.verify_samples, args.quiet, judge_h)
            report["timings_s"]["verify"] = time.perf_counter() - t
            if args.replan:
                rounds.append({"scallop": job.scallop,
                               "reachable_p999_over_h": v["reachable"]["scallop_over_h"]["p999"],
                               "feed_m": stats["feed_length_mm"] / 1000.0, "cl_points": report["paths"]["cl_points"],
                               "pass": v["pass"], "seconds": time.perf_counter() - t_round})
            nxt = (replan_scallop(v, job.scallop, judge_h, job.tolerance)
                   if args.replan and len(rounds) <= args.replan else None)
            if nxt is None:
                break
            if not args.quiet:
                print(f"conformill plan: reachable scallop p99.9 {v['reachable']['scallop_over_h']['p999']:.3f} H "
                      f"over {SCALLOP_SLACK:g} H; planning again for scallop {nxt:.6g} (--replan)", file=sys.stderr)
            job = with_overrides(job, scallop=nxt)
            del result, program, report  # the next plan's peak memory is its own
        if args.replan:
            report["replan"] = rounds
        if args.plot:
            from conformill.output.plot_plan import plot_plan

            t = time.perf_counter()
            plot_plan(args.plot, result)
            report["timings_s"]["plot"] = time.perf_counter() - t
        if args.holder_radius is not None:
            t = time.perf_counter()
            report["holder"] = _holder(result.mesh, program, args.holder_radius, args.stick_out, args.holder_step)
            report["timings_s"]["holder"] = time.perf_counter() - t
        if args.html:
            from conformill.cli.view import vertex_heat
            from conformill.output.viewer import split_program, write_viewer

            t = time.perf_counter()
            passes, rapids = split_program(program.points, program.motion, program.start)
            info = {"pattern": job.pattern, "tool": f"ball R{job.tool_radius:g}", "scallop H": job.scallop,
                    "tolerance E": job.tolerance}
            if "holder" in report:
                from conformill.cli.verify import holder_name

                h = report["holder"]
                info[f"holder {holder_name(h)}"] = (f"stick-out {h['needed_stick_out']:.3f} mm needed "
                                                    f"(line {h['worst_line']})")
            heat = None
            if args.verify:
                heat, figures = vertex_heat(result.mesh, program, job.tool_radius, stock=job.stock)
                info.update(figures)
                info["verify"] = "PASS" if report["verify"]["pass"] else "FAIL"
            write_viewer(args.html, result.mesh.V, result.mesh.F, passes, rapids=rapids, heat=heat,
                         title=f"conformill {job.pattern}: {mesh.name}", info=info)
            report["timings_s"]["html"] = time.perf_counter() - t
        report["timings_s"]["total"] = time.perf_counter() - t0
        report["peak_rss_mb"] = peak_rss_mb()
        if args.report:
            write_json(args.report, report)
    if not args.quiet:
        _summary(report, args.output)
    if args.verify and not report["verify"]["pass"]:
        return 1  # the files are kept for inspection; the check failed
    return 0


def _header(args, job, result) -> dict:
    """The program header's fields: the job as planned."""
    header = {
        "mesh": args.mesh, "pattern": job.pattern, "tool": f"ball R{job.tool_radius:g} (D{2 * job.tool_radius:g})",
        "scallop": job.scallop, "tolerance": job.tolerance, "feed": job.feed,
        "plunge_feed": job.plunge_rate, "safe_z": round(result.toolpath.safe_z, 4),
        "scale": args.scale, "orient": job.orient, "weights": job.weights, "concave steps": job.concave_steps,
        "spacing": job.spacing, "settle": job.settle, "fit": job.fit,
        "programmed point": "tool tip", "units": "mm",
        "path control": _control(job.blend_tolerance)[1],
        "tool length": ("G49: the work offset holds it [tool tip touched off]" if job.tool_number is None
                        else f"T{job.tool_number} M6 G43 H{job.tool_number}: from the tool table"),
        "spindle": _spindle_text(job.spindle),
    }
    if job.coolant is not None:  # only then: the programs without it keep their bytes
        header["coolant"] = job.coolant
    if job.stock:  # likewise
        header["stock"] = (f"{job.stock:g} mm left on the part (the ball R{job.tool_radius:g} finishes its offset)"
                           if job.stock > 0 else f"{-job.stock:g} mm cut into the part (negative stock)")
    if job.pencil:  # only then: the default program's bytes stay as they were
        header["pencil"] = (f"samples per mm2 {job.pencil_density:g}" if job.pencil_search == "samples"
                            else f"folds, grid points per mm2 {job.pencil_density:g}")
        if job.pencil_left is not None:
            header["pencil"] += f", where the pattern leaves above {job.pencil_left:g} H"
    if job.fill is not None:  # likewise
        header["fill"] = (f"where the passes leave above {job.fill:g} H"
                          + (f", the pattern's paths spaced for {job.pattern_scallop:g} H"
                             if job.pattern_scallop != 1.0 else ""))
        fill = result.report.get("fill") or {}
        if fill.get("dropped"):  # the wider paths did not pay: planned again
            times = _fill_times(fill)
            cost = f"{times} times what the spacing saved" if times else "longer than the spacing saved"
            header["fill"] = (f"none: the fill above {job.fill:g} H of paths spaced for {job.pattern_scallop:g} H was "
                              f"{cost}; paths spaced for H")
    elif job.pattern_scallop != 1.0:
        header["pattern scallop"] = f"{job.pattern_scallop:g} H"
    if job.hop_lift > 0:  # likewise
        header["hop lifted"] = f"runs lifted more than {job.hop_lift:g} mm, rapid {job.rapid:g}"
    if args.holder_radius is not None:  # likewise
        header["holder"] = f"radius {args.holder_radius:g}" + "".join(
            f", radius {r:g} from {at:g} mm above its face" for r, at in args.holder_step) + (
            "" if args.stick_out is None else f", stick-out {args.stick_out:g}: checked to clear the part")
    return header


def replan_scallop(v: dict, planned: float, judge_h: float, tolerance: float) -> float | None:
    """The scallop to plan next under ``--replan``, or None when planning again cannot help.

    Parameters
    ----------
    v : dict
        :func:`_verify`'s figures for the program planned for ``planned``.
    planned, judge_h, tolerance : float
        The scallop the program was planned for, the height it is judged against (H) and
        the chord tolerance (the gouge limit).

    Returns
    -------
    float or None
        ``planned * clip(0.97 * 1.05 H / p99.9, 0.5, 0.95)``, to 4 significant digits, when
        the check failed on the reachable scallop alone (p99.9 over ``1.05 H``, no reachable
        sample uncut, no gouge beyond ``tolerance``); None when it passed or failed on
        anything a smaller scallop does not mend. On the scans the verified p99.9 grows in proportion to the planned
        scallop (choi zigzag ``--scan``: 1.190 / 1.073 / 0.969 H planned for 1 / 0.9 / 0.8 H),
        so one more plan usually passes; the 0.97 is its margin.
    """
    limit = SCALLOP_SLACK * judge_h
    p999 = v["reachable"]["scallop"]["p999"]
    if v["pass"] or not p999 > limit or v["reachable"]["uncut_fraction"] > 0 or v["gouge_max"] > tolerance:
        return None
    return float(f"{planned * min(max(0.97 * limit / p999, 0.5), 0.95):.4g}")  # 4 digits: a readable header


def _holder(mesh, program, radius: float, stick_out: float | None, steps=()) -> dict:
    """The holder check on the program as written (:mod:`conformill.verify.holder`): its
    figures, or :class:`PlanningError` when the holder may meet the part at ``stick_out``."""
    from conformill.cli.verify import holder_failure, holder_name, ring_name
    from conformill.verify.holder import holder_clearance

    h = holder_clearance(mesh.V, mesh.F, program, radius, stick_out=stick_out, steps=steps).summary(stick_out)
    if stick_out is not None and not h["clear"]:
        where = "" if h["worst_part"] is None else (
            f" (the part at ({', '.join(f'{x:.3f}' for x in h['worst_part'])}) within {ring_name(h)} of the move "
            f"on line {h['worst_line']})")
        raise PlanningError(f"holder {holder_name(h)} at stick-out {stick_out:g} mm: {holder_failure(h)}{where}; "
                            f"nothing written")
    return h


SCALLOP_SLACK = 1.05
"""--verify passes when scallop p99.9 <= SCALLOP_SLACK * H (and gouge max <= E)."""


def _verify(mesh, program, job, n_samples: int, quiet: bool, judge_h: float) -> dict:
    """Run the independent simulation on the program as written to disk.

    ``program`` is read back from the G-code file (not taken from the planner's arrays), so
    the check covers the writer too. Thresholds: scallop ``1.05 H`` at p99.9 and no uncut
    sample over the reachable interior samples (farther than ``R`` from the boundary, see
    ``verify(judge="reachable")``), gouge at most ``E`` over all interior samples. ``H`` is
    ``judge_h`` (``--verify-scallop``, by default the planned scallop).
    """
    from conformill.verify.simulate import verify

    with sample_bar(n_samples, "verify", enabled=not quiet) as update:
        res = verify(mesh, program, job.tool_radius, n_samples=n_samples, scallop=SCALLOP_SLACK * judge_h,
                     gouge=job.tolerance, progress=update, judge="reachable", stock=job.stock)
    s = res.summary
    keep = ("samples", "interior_samples", "scallop", "scallop_mean", "uncut_fraction", "above_scallop_fraction",
            "gouge_max", "gouge_where", "gouge_line", "rapid_min_clearance", "rapid_min_line",
            "retract_min_clearance", "n_rapids", "n_retracts", "thresholds", "judged_on", "failures", "pass")
    out = {k: s[k] if k in s else s["interior"].get(k) for k in keep}
    out["judged_h"] = judge_h
    out["stock"] = job.stock
    out["scallop_over_h"] = {k: v / judge_h for k, v in s["scallop"].items()}
    q = s["reachable"]
    out["reachable"] = {"unreachable_fraction": q["unreachable_fraction"], "scallop": q["scallop"],
                        "scallop_over_h": {k: v / judge_h for k, v in q["scallop"].items()},
                        "uncut_fraction": q["uncut_fraction"], "gouge_max": q["gouge_max"],
                        "beyond_any_ball": q["beyond_any_ball"], "unconfirmed": q["unconfirmed"],
                        "tangent_test_scallop": q["tangent_test"]["scallop"]}
    return out


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    try:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    except ImportError:  # pragma: no cover - Windows
        import psutil

        return psutil.Process().memory_info().peak_wset / 2**20


def _pencil_source(st: dict) -> str:
    if st.get("search") == "folds":
        found = (f"{st['centres']} fold points ({st['grid_points']} grid points) and {st['steep_centres']} "
                 f"steep-wall centres")
        if "left_h" not in st:
            return found
        return (f"{found}, {st['fold_points_cut']} and {st['steep_centres_cut']} of them where the pattern left above "
                f"{st['left_h']:g} H")
    return f"{st['centres']} best ball centres ({st['samples']} samples)"


def _control(blend) -> tuple[str, str]:
    """The path-control block for the resolved ``blend`` (``Job.blend_tolerance``; None:
    none written) and the header's account of it."""
    from conformill.output.gcode import path_control

    if blend is None:
        return "no path control", "none written: the machine's own mode"
    block = path_control(blend)
    if blend == 0:
        return block, f"{block}: exact path"
    return block, f"{block}: corners rounded by at most {blend:g} mm, moves not merged"


def _spindle_text(rpm) -> str:
    """The header's and the summary's account of the spindle: started by the program
    (``--spindle``), or to be started by hand."""
    if rpm is None:
        return "not started by this program [no --spindle]: start it by hand before running it"
    return f"M3 S{rpm:g}: started before the first move"


def _fill_times(fill: dict) -> str | None:
    """The fill's feed over what the wider paths saved (the report's ``fill``), as the
    header and the summary print it; ``None`` when they saved nothing."""
    saved = fill.get("saved_mm")
    return f"{fill['feed_mm'] / saved:.1f}" if saved is not None and saved > 0 else None


def _fill_text(fill: dict) -> str:
    """The summary's account of the fill stage (the report's ``fill``): its passes, or why
    it was dropped, and what the wider paths saved (:func:`conformill.pipeline.plan`)."""
    saved = fill.get("saved_mm")
    wider = (f"about {saved / 1000:.2f} m saved by the paths spaced for {fill['pattern_scallop']:g} H"
             if saved is not None else "")
    if fill.get("dropped"):
        times = _fill_times(fill)
        times = f" ({times} times)" if times else ""
        return (f"none: {fill['feed_mm'] / 1000:.2f} m of fill against {wider}{times}; planned again with the "
                f"paths spaced for H")
    return (f"{fill['passes']} pass(es), {fill['cl_points']} CL points, {fill['feed_mm'] / 1000:.2f} m through "
            f"{fill['balls']} balls where the passes left above {fill['depth_h']:g} H"
            + (f"; {wider}" if wider else ""))


def _summary(rep: dict, out: str) -> None:
    pr, pa, q = rep["program"], rep["paths"], rep["parameterization"]["quality"]
    lines = [
        f"conformill plan: {rep['mesh']['name']} ({rep['mesh']['faces']} faces), {rep['job']['pattern']}, "
        f"ball R{rep['job']['tool_radius']:g}, scallop {rep['job']['scallop']:g}, tolerance {rep['job']['tolerance']:g}"
        + (f", stock {rep['job']['stock']:g}" if rep["job"].get("stock") else ""),
        f"  parameterization  {rep['parameterization']['boundary']}, QC mean {q['qc_mean']:.3f}, flipped {q['flipped_faces']}",
        f"  paths             {pa['planned_paths']} planned, {pa['passes']} feed pass(es), {pa['cl_points']} CL points",
        f"  side step         flat {rep['side_step']['flat_interval_mm']:.3f} mm, realised mean "
        f"{(rep['side_step']['realised_mm']['mean'] or 0):.3f} mm",
        f"  program           feed {pr['feed_length_mm'] / 1000:.2f} m, rapid {pr['rapid_length_mm'] / 1000:.2f} m, "
        f"{pr['machining_time_min']:.1f} min at feed, {pr['n_lines']} lines, "
        f"{_control(None if rep['job']['blend'] == 'off' else rep['job']['blend'])[0]}"
        + ("" if rep["job"].get("spindle") is not None else "; spindle not started by the program (--spindle RPM)"),
        *([f"  pencil            {rep['pencil']['passes']} pass(es), {rep['pencil']['cl_points']} CL points, "
           f"{rep['pencil']['feed_mm'] / 1000:.2f} m from {_pencil_source(rep['pencil'])}"] if rep.get("pencil") else []),
        *([f"  fill              {_fill_text(rep['fill'])}"] if rep.get("fill") else []),
        f"  reachability      undercut {100 * rep['reachability']['undercut_share']:.2f}%, concave below R "
        f"{100 * rep['reachability']['concave_below_tool_radius_share']:.2f}%",
    ]
    if "holder" in rep:
        from conformill.cli.verify import holder_name

        h = rep["holder"]
        lines.append(f"  holder            {holder_name(h)} needs a stick-out of {h['needed_stick_out']:.3f} mm "
                     f"(line {h['worst_line']})" + ("" if h.get("stick_out") is None else
                                                    f"; {h['stick_out']:g} mm clears it by {h['clearance']:.3f} mm"))
    if "verify" in rep:
        v = rep["verify"]
        s = v.get("scallop", {})
        q = v["reachable"]
        lines.append(f"  verify            {'on the part offset by the stock: ' if v.get('stock') else ''}interior: scallop p50 {s['p50']:.4f} / p99.9 {s['p999']:.4f} / max "
                     f"{s['max']:.4f} mm, uncut {100 * v['uncut_fraction']:.3f}%, gouge max {v['gouge_max']:.4f} mm")
        share = (f"{100 * (1 - q['unreachable_fraction']):.2f}% of it" if v.get("interior_samples", 1)
                 else "no interior sample")
        lines.append(f"                    reachable ({share}): scallop "
                     f"p99.9 {q['scallop']['p999']:.4f} mm = {q['scallop_over_h']['p999']:.3f} H"
                     + ("" if v["judged_h"] == rep["job"]["scallop"] else f" (H = {v['judged_h']:g})") + ", uncut "
                     f"{100 * q['uncut_fraction']:.3f}%; rapid clearance {v['rapid_min_clearance']:.2f} mm: "
                     + ("PASS" if v["pass"] else "FAIL (" + "; ".join(v["failures"]) + ")"))
    if rep.get("replan"):
        r = rep["replan"]
        lines.append(f"  replan            {len(r)} plan(s): scallop " + " -> ".join(f"{x['scallop']:.4g}" for x in r)
                     + " mm, reachable p99.9 " + " -> ".join(f"{x['reachable_p999_over_h']:.3f}" for x in r) + " H")
    lines.append(f"  time              {rep['timings_s']['total']:.2f} s -> {out}")
    print("\n".join(lines), file=sys.stdout)
