"""``conformill param``: parameterize a disk mesh and write an OBJ with texture coordinates.

    conformill param MESH [--boundary circle|rectangle]
                          [--weights geodesic|floater|mean_value|cotangent]
                          [--corners i,j,k,l] [--scale S] -o OUT.obj
                          [--report OUT.json] [--plot OUT.png]

Every output folder is checked before the work starts, and the outputs are written to
temporary files that are renamed only once all of them are complete: an error leaves no
partial output.
"""

from __future__ import annotations

import argparse
import contextlib
import time

from conformill.errors import OutputError, ParameterizationError

BOUNDARIES = ("circle", "rectangle")
WEIGHTS = ("geodesic", "floater", "mean_value", "cotangent")


def corners_arg(text: str) -> tuple:
    """``--corners i,j,k,l`` (param and plan): four integers (argparse reports anything else,
    exit 2); whether they are boundary vertices in order is the parameterization's check."""
    try:
        vals = tuple(int(x) for x in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"corners must be four vertex ids i,j,k,l, got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"corners must be four vertex ids i,j,k,l, got {text!r}")
    return vals


def add_arguments(parser) -> None:
    parser.add_argument("mesh", metavar="MESH", help="disk-topology triangle mesh (STL, OBJ, PLY, OFF)")
    parser.add_argument("--boundary", choices=BOUNDARIES, default="circle",
                        help="domain: circle (contour/spiral paths) or rectangle (zigzag paths); default circle")
    parser.add_argument("--weights", choices=WEIGHTS, default="geodesic",
                        help="interior weights; default geodesic (the paper's); cotangent may flip faces")
    parser.add_argument("--corners", type=corners_arg, default=None, metavar="i,j,k,l",
                        help="rectangle corners: four boundary vertex ids in boundary order (default: automatic)")
    parser.add_argument("--scale", type=float, default=1.0, metavar="S",
                        help="multiply the mesh coordinates by S to get mm (e.g. 1000 for metres)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.obj",
                        help="OBJ with v (mesh, mm), vt (uv) and f a/a b/b c/c")
    parser.add_argument("--report", metavar="OUT.json", help="JSON report: counts, timings, solver, quality")
    parser.add_argument("--plot", metavar="OUT.png", help="checkerboard figure (surface and domain)")
    parser.add_argument("--solver", choices=("pardiso", "superlu", "gmres_ilu"), default=None,
                        help=argparse.SUPPRESS)


def run(args) -> int:
    from conformill.output.atomic import check_writable

    check_writable(args.output, args.report, args.plot, inputs=(args.mesh,))
    if args.corners is not None and args.boundary != "rectangle":
        raise ParameterizationError("--corners needs --boundary rectangle")

    from conformill.mesh.io import read_mesh
    from conformill.param import parameterize, parameterization_quality

    t_start = time.perf_counter()
    mesh = read_mesh(args.mesh, scale=args.scale)
    t_read = time.perf_counter() - t_start
    param = parameterize(mesh, boundary=args.boundary, weights=args.weights, corners=args.corners,
                         solver=args.solver)
    t0 = time.perf_counter()
    q = parameterization_quality(param)
    timings = {"read": t_read, **param.timings, "quality": time.perf_counter() - t0}

    from conformill.output.atomic import atomic_path
    from conformill.output.obj import format_obj

    t0 = time.perf_counter()
    header = (f"conformill param {mesh.name}: {args.boundary} boundary, {args.weights} weights\n"
              f"v = mesh vertices (mm, input order), vt = parameter coordinates")
    data = format_obj(mesh.V, mesh.F, param.uv, header=header)
    from conformill.output.atomic import all_or_nothing

    # rename every output only when all are complete (and undo the renames if one fails)
    with all_or_nothing(args.output, args.report, args.plot), contextlib.ExitStack() as stack:
        tmp = stack.enter_context(atomic_path(args.output))
        _write_bytes(tmp, data, args.output)
        del data
        timings["write_obj"] = time.perf_counter() - t0
        if args.plot:
            from conformill.output.plot_param import plot_param

            t0 = time.perf_counter()
            tmp_png = stack.enter_context(atomic_path(args.plot))
            plot_param(tmp_png, mesh.V, mesh.F, param.uv, boundary=param.boundary, corners=param.corners,
                       title=f"{mesh.name}: {args.boundary}, {args.weights} weights, QC mean {q.qc_mean:.3f}")
            timings["plot"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_start
        if args.report:
            from conformill.output.report import dumps

            tmp_json = stack.enter_context(atomic_path(args.report))
            _write_bytes(tmp_json, dumps(report(args, param, q, timings)).encode(), args.report)
    if not args.quiet:
        print(summary(param, q, timings["total"]))
    return 0


def _write_bytes(tmp, data: bytes, shown) -> None:
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
    except OSError as exc:
        raise OutputError(f"cannot write {shown}: {exc.strerror}") from None


def report(args, param, q, timings) -> dict:
    """The JSON report of one run."""
    mesh = param.mesh
    dom = ({"kind": "circle", "center": [0.0, 0.0], "radius": param.domain[0]} if param.kind == "circle"
           else {"kind": "rectangle", "x": param.domain[0], "y": param.domain[1]})
    return {
        "command": "param",
        "mesh": {"file": str(args.mesh), "name": mesh.name, "scale": args.scale,
                 "vertices": mesh.n_vertices, "faces": mesh.n_faces,
                 "boundary_vertices": int(len(param.boundary))},
        "boundary": param.kind,
        "weights": param.weights,
        "domain": dom,
        "corners": list(param.corners) if param.corners is not None else None,
        "solver": param.solver,
        "residual": param.residual,
        "fallbacks": param.fallbacks,
        "quality": q.as_dict(),
        "timings_s": timings,
        "outputs": {"obj": str(args.output), "plot": args.plot},
    }


def summary(param, q, seconds: float) -> str:
    """A few human-readable lines."""
    m = param.mesh
    dom = (f"circle R {param.domain[0]:.4g} mm" if param.kind == "circle"
           else f"rectangle {param.domain[0]:.4g} x {param.domain[1]:.4g} mm, corners {param.corners}")
    fb = f" ({param.fallbacks} fallbacks to Floater)" if param.weights == "geodesic" else ""
    return (
        f"{m.name}: {m.n_vertices} vertices, {m.n_faces} faces; {dom}; {param.weights} weights{fb}\n"
        f"solver {param.solver}, residual {param.residual:.2g}; QC mean {q.qc_mean:.4g} p95 {q.qc_p95:.4g} "
        f"max {q.qc_max:.4g}; angle error mean {q.angle_mean:.3g} deg; flipped {q.flipped}; {seconds:.2f} s"
    )
