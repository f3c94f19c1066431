"""``conformill view MESH [PROGRAM.nc] -o OUT.html``: a self-contained HTML 3D view.

Reads the mesh (:func:`conformill.mesh.io.read_mesh`) and the program
(:func:`conformill.verify.gcode.read_gcode`), splits the program into feed passes and rapid
moves (:func:`conformill.output.viewer.split_program`) and writes the page
(:func:`conformill.output.viewer.write_viewer`). With ``--tool-radius`` the remaining material
left by a ball of that radius is computed at every mesh vertex (the same simulation as
``conformill verify``) and shown as a heat map; gouges appear as negative values.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from conformill.errors import ConformillError
from conformill.output.atomic import check_writable

log = logging.getLogger(__name__)


def add_arguments(parser):
    parser.add_argument("mesh", help="part surface: .stl, .obj, .ply, .off (or sample:NAME)")
    parser.add_argument("program", nargs="?", help="G-code program (tool-tip positions); omit to view the mesh alone")
    parser.add_argument("-o", "--output", required=True, help="HTML file to write")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="factor applied to the mesh coordinates, e.g. 1000 for metres (default 1)")
    parser.add_argument("--tool-radius", type=float, default=None, metavar="R",
                        help="ball radius (mm): also show the remaining material left at the mesh vertices")
    parser.add_argument("--stock", type=float, default=0.0, metavar="S",
                        help="with --tool-radius: the material the program leaves on the part (plan --stock, mm); "
                             "the map shows what is left above the part offset by S")
    parser.add_argument("--title", default=None, help="page title (default: the file names)")


def vertex_heat(mesh, program, tool_radius: float, gouge_tol: float = 1e-3,
                stock: float = 0.0) -> tuple[np.ndarray, dict]:
    """Remaining material (mm) at the mesh vertices after the program's feed moves.

    Casts from each vertex along its (area-weighted) normal against the swept ball (see
    :func:`conformill.verify.simulate.remaining_material`); with ``stock``, from the vertex
    moved that far along its normal (the material above the part's offset, as ``verify``
    measures it).

    Returns
    -------
    heat : (n,) float64
        Remaining material, ``-gouge`` where the tool cut more than ``gouge_tol`` (mm) below
        the surface (smaller gouges are facet noise and count as 0), NaN where the vertex is
        not cut at all (more than ``2 r`` left).
    figures : dict
        ``uncut vertices`` and ``max gouge`` for the info panel.
    """
    from conformill.verify.samples import SurfaceSamples, vertex_normals
    from conformill.verify.simulate import remaining_material

    samples = SurfaceSamples.from_arrays(mesh.V, vertex_normals(mesh.V, mesh.F)).offset(stock)
    rem, gouge, _, _ = remaining_material(samples, program, tool_radius)
    gouged = gouge > gouge_tol
    heat = np.where(gouged, -gouge, np.where(gouge > 0, 0.0, rem))
    heat[~np.isfinite(rem) & ~(gouge > 0)] = np.nan
    figures = {"uncut vertices (grey)": int(np.isnan(heat).sum()), "max gouge (mm)": float(gouge.max(initial=0.0))}
    return heat, figures


def run(args) -> int:
    from conformill.mesh.io import read_mesh
    from conformill.output.viewer import split_program, write_viewer

    if args.tool_radius is not None and not (math.isfinite(args.tool_radius) and args.tool_radius > 0):
        raise ConformillError(f"--tool-radius must be > 0 mm, got {args.tool_radius!r}")
    from conformill.planning.steps import check_stock  # numba: not at the CLI's import

    check_stock(args.stock, args.tool_radius, ConformillError, "--stock")
    check_writable(args.output, inputs=(args.mesh, args.program))
    mesh = read_mesh(args.mesh, scale=args.scale)
    if args.tool_radius is not None:
        from conformill.planning.steps import check_ball_size

        check_ball_size(args.tool_radius, mesh.V, ConformillError, "--tool-radius", stock=args.stock)
    info: dict = {"mesh file": Path(args.mesh).name}
    if args.scale != 1.0:
        info["scale"] = args.scale
    passes: list = []
    rapids = None
    heat = None
    if args.program is not None:
        from conformill.verify.gcode import read_gcode

        program = read_gcode(Path(args.program))
        info["program"] = Path(args.program).name
        info["moves"] = len(program)
        passes, rapids = split_program(program.points, program.motion, program.start)
        if args.tool_radius is not None:
            info["tool"] = f"ball, R {args.tool_radius:g} mm" + (f", stock {args.stock:g} mm" if args.stock else "")
            if np.any(program.motion != 0):
                heat, figures = vertex_heat(mesh, program, args.tool_radius, stock=args.stock)
                info.update(figures)
            else:
                log.warning("%s has no feed moves: no remaining-material map", args.program)
    elif args.tool_radius is not None:
        log.warning("--tool-radius needs a program: no remaining-material map")
    title = args.title or " + ".join(Path(p).name for p in (args.mesh, args.program) if p)
    write_viewer(args.output, mesh.V, mesh.F, passes, rapids=rapids, heat=heat, title=title, info=info)
    if not args.quiet:
        print(f"wrote {args.output} ({Path(args.output).stat().st_size / 1e6:.1f} MB, "
              f"{len(passes)} passes, {0 if rapids is None else len(rapids)} rapids)")
    return 0
