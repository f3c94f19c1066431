"""Shared helpers of the benchmark scripts: test meshes in mm, machine description, rs274.

Not part of the package; the scripts put ``benchmarks/`` on ``sys.path`` to import it.
"""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

MESHES = Path(os.environ.get("CONFORMILL_MESHES", "/work/shared/meshes"))

#: Short name -> file in :data:`MESHES` or a shipped sample (``sample:...``, already mm).
MESH_FILES = {
    "igea": "face_igea_cut.ply",
    "choi": "face_choi.ply",
    "nefertiti": "face_nefertiti_cut.ply",
    "spacetime": "face_spacetime_neutral_filled.ply",
    "camelhead": "camelhead.off",
    "beetle": "cad_beetle_roof.ply",
    "fandisk": "cad_fandisk_top_patch.ply",
    "lion": "relief_chinese_lion_choi.ply",
    "sample:face": "sample:face",
    "sample:patch": "sample:patch",
    "sample:lion": "sample:lion",
}


def load_part(name: str, size: float = 130.0):
    """A test mesh as a part in mm, tool side +Z, top at z = 0, centred in XY.

    Shared meshes (metres, unitless, ...) are turned so that their area-weighted mean normal
    is +Z (:func:`conformill.pipeline.orient_mesh` with ``"auto"``: a face scan that looks
    along -Y or -Z then looks along +Z), then scaled so that the larger horizontal extent is
    ``size`` mm. The shipped samples are in mm already and only translated.

    Parameters
    ----------
    name : str
        A key of :data:`MESH_FILES`.
    size : float
        Larger XY extent after scaling (mm).

    Returns
    -------
    mesh : conformill.types.Mesh
    info : dict
        ``file``, ``scale``, ``rotated_deg``, ``extent_mm`` (3,).
    """
    from conformill.mesh.io import read_mesh
    from conformill.pipeline import orient_mesh
    from conformill.types import Mesh

    file = MESH_FILES[name]
    sample = file.startswith("sample:")
    m = read_mesh(file if sample else MESHES / file)
    m, oi = orient_mesh(m, "none" if sample else "auto")
    V = m.V.copy()
    scale = 1.0
    if not sample:
        ext = V.max(0) - V.min(0)
        scale = size / max(ext[0], ext[1])
        V *= scale
    V -= [0.5 * (V[:, 0].min() + V[:, 0].max()), 0.5 * (V[:, 1].min() + V[:, 1].max()), V[:, 2].max()]
    name_ = name.replace("sample:", "sample_")
    mesh = Mesh(V=V, F=m.F, name=name_)
    return mesh, {"file": file, "scale": scale, "rotated_deg": oi["rotated_deg"],
                  "extent_mm": (V.max(0) - V.min(0)).tolist()}


def machine() -> str:
    """One line: CPU model, logical CPUs, RAM, OS and Python."""
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    ram = "?"
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                ram = f"{int(line.split()[1]) / 1024 ** 2:.1f} GiB"
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} logical CPUs (nproc), {ram} RAM, {platform.system()} "
            f"{platform.release()}, Python {platform.python_version()}")


def rs274(path) -> int | None:
    """Exit code of LinuxCNC's stand-alone interpreter on a program (None: not installed)."""
    exe = shutil.which("rs274")
    if exe is None:
        return None
    with tempfile.TemporaryDirectory() as d:
        p = subprocess.run(["env", "-u", "DISPLAY", exe, "-g", str(path), str(Path(d) / "out.canon")],
                           stdin=subprocess.DEVNULL, capture_output=True, timeout=1800)
        return p.returncode


def principal_curvatures(mesh):
    """Signed principal curvatures per vertex from conformill's quadratic fit.

    The fit of :func:`conformill.geometry.differential.surface_frame` over a circle-boundary
    parameterization (geodesic weights); with ``H = (EN + GL - 2FM) / (2 (EG - F^2))`` and
    ``K = (LN - M^2) / (EG - F^2)``: ``k1 = H + sqrt(H^2 - K)`` (most concave, towards the
    tool) and ``k2 = H - sqrt(H^2 - K)`` (most convex). Sign as in
    :mod:`conformill.planning.steps`: > 0 concave.

    Returns
    -------
    k1, k2 : (n,) float64
        NaN where the fit failed.
    """
    from conformill.geometry.differential import surface_frame
    from conformill.param import parameterize

    param = parameterize(mesh, boundary="circle")
    fr = surface_frame(mesh.V, mesh.F, param.uv)
    det = np.maximum(fr.E * fr.G - fr.F * fr.F, 1e-300)
    H = (fr.E * fr.N + fr.G * fr.L - 2 * fr.F * fr.M) / (2 * det)
    K = (fr.L * fr.N - fr.M * fr.M) / det
    d = np.sqrt(np.maximum(H * H - K, 0.0))
    return H + d, H - d


def face_areas(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def length_floor(mesh, k1, k2, h: float, r: float) -> dict:
    """Shortest total path length any program meeting ``h`` everywhere can have: ``sum A_f / s_max,f``.

    Paths ``s`` apart cover an area ``s`` per unit length, so a set of paths whose spacing
    nowhere exceeds ``s_max(x)`` is at least ``integral dA / s_max(x)`` long (boundary and
    link effects ignored, so this is a floor, not a target). ``s_max(x)`` is the widest
    side interval that keeps the cusp at ``h`` for a ball of radius ``r`` in the best path
    direction. The normal curvature across a path lies between ``k2`` and ``k1`` (Euler)
    and the exact interval :func:`conformill.planning.steps.side_interval` grows with the
    signed curvature (convex needs closer paths, concave allows wider ones, up to the
    diameter as ``kappa -> 1/r``), so the best paths run along the ``k2`` direction and are
    spaced across the most concave curvature: ``s_max = side_interval(h, r, k1)``. Where
    ``k1 >= 1/r`` the ball cannot touch the point at all (it is concave below the tool
    radius in some direction) and the flat interval is used. Per face, ``1/s`` is the mean
    of its vertices' values.

    Returns
    -------
    dict
        ``floor_mm``, ``flat_floor_mm`` (area / flat interval), ``area_mm2``.
    """
    from conformill.planning.steps import side_interval

    kk = np.where(np.isfinite(k1), k1, 0.0)
    s, _ = side_interval(h, r, kk)
    inv = (1.0 / s)[mesh.F].mean(axis=1)
    A = face_areas(mesh.V, mesh.F)
    flat = float(side_interval(h, r, np.zeros(1))[0][0])
    return {"floor_mm": float((A * inv).sum()), "flat_floor_mm": float(A.sum() / flat), "area_mm2": float(A.sum())}


def reachable_samples(mesh, samples, r: float, tol: float) -> np.ndarray:
    """Samples that a 3-axis ball of radius ``r`` can touch (to within ``tol``).

    A sample ``P`` on face ``f`` with face normal ``n_f`` (towards the tool) counts as
    reachable when ``n_f,z > 0`` (it faces up) and the ball tangent to that facet at ``P``,
    centred at ``C = P + r n_f``, penetrates the part by less than ``tol`` (distance from
    ``C`` to the mesh >= ``r - tol``, libigl's AABB point-mesh distance). This removes
    undercuts and concave regions tighter than the ball. The facet normal (not the
    interpolated vertex normal) is used so that a ball on faceted convex ground does not
    cut the facet it stands on. It does not check that the ball can come down to ``C`` from
    above (shadowing by overhangs), so it may keep a few unreachable samples.

    Returns
    -------
    (n,) bool
    """
    import igl

    V = np.asarray(mesh.V, dtype=np.float64)
    F = np.asarray(mesh.F, dtype=np.int64)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    if (n * face_areas(V, F)[:, None]).sum(0)[2] < 0:  # as the samples: the tool comes from +Z
        n = -n
    P, N = samples.points, n[samples.face]
    C = np.ascontiguousarray(P + r * N)
    d2, _, _ = igl.point_mesh_squared_distance(C, np.ascontiguousarray(mesh.V, dtype=np.float64),
                                               np.ascontiguousarray(mesh.F, dtype=np.int64))
    return (N[:, 2] > 0) & (d2 >= (r - tol) ** 2)


def scan_job_parser(doc: str, patterns):
    """An argument parser with the arguments every one-mesh scan study shares.

    ``mesh`` (a key of :data:`MESH_FILES`, default igea), ``--pattern`` (default contour),
    ``--h``, ``--r``, ``--e`` (0.01, 4, 0.01 mm) and ``--samples`` (400000 verify samples).
    """
    import argparse

    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="igea")
    ap.add_argument("--pattern", default="contour", choices=patterns)
    ap.add_argument("--h", type=float, default=0.01)
    ap.add_argument("--r", type=float, default=4.0)
    ap.add_argument("--e", type=float, default=0.01)
    ap.add_argument("--samples", type=int, default=400_000)
    return ap


def scan_study(args):
    """What every one-mesh scan study does first (``args`` from :func:`scan_job_parser`).

    Warnings off, the part loaded (:func:`study_mesh`, with ``args.scale`` where the
    parser has it) and oriented as ``plan`` sees it (the verify mesh is the
    planned one), the machine printed. Returns ``(mesh, samples)``: the verify samples as
    ``bench_raster.py`` draws them (``args.samples``, seed 0).
    """
    import logging

    from conformill.pipeline import orient_mesh

    logging.disable(logging.WARNING)
    mesh, _ = orient_mesh(study_mesh(args.mesh, getattr(args, "scale", 1.0)), "none")
    print(machine())
    return mesh, verify_samples(mesh, args.samples, args.r)


def study_mesh(name: str, scale: float = 1.0):
    """A short name of :data:`MESH_FILES` (:func:`load_part`), or a mesh file read as
    ``conformill plan FILE --scale S`` reads it (the 620k mesh of ``bench_scale.py``:
    ``/work/shared/meshes/large_igea_face_subdiv1.ply`` with ``scale`` 1400)."""
    if name in MESH_FILES:
        return load_part(name)[0]
    from conformill.mesh.io import read_mesh

    return read_mesh(name, scale=scale)


def print_table(columns, rows) -> None:
    """Print a Markdown table: ``columns`` is a list of ``(title, format)`` pairs (a format
    spec such as ``".2f"``, or ``""``), ``rows`` a list of tuples in the same order."""
    print("| " + " | ".join(t for t, _ in columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        print("| " + " | ".join(format(v, f) for v, (_, f) in zip(row, columns)) + " |")


def verify_samples(mesh, n: int, r: float):
    """The area-uniform samples every program of a run is verified on: ``n`` of them, seed 0,
    their boundary distances measured as ``verify`` measures them (the rim sampled every
    ``min(0.1, r / 20)`` mm, distances beyond ``2 r`` stored as inf), so that the figures of
    one run compare sample for sample."""
    from conformill.verify.samples import sample_surface

    return sample_surface(mesh.V, mesh.F, n, seed=0, boundary_spacing=min(0.1, r / 20), boundary_max=2 * r)


def program_of(res):
    """The program of plan result ``res`` as ``conformill verify`` reads it: written as G-code
    (feed 1000, plunge 1000 / 3) and read back."""
    return written(res.toolpath)[0]


def written(toolpath):
    """``(Program, write_gcode's statistics)`` of ``toolpath`` written as :func:`program_of`
    writes it and read back."""
    from conformill.output.gcode import write_gcode
    from conformill.verify.gcode import read_gcode

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.nc"
        stats = write_gcode(path, toolpath, feed=1000.0, plunge_feed=1000.0 / 3)
        return read_gcode(path), stats


def verify_program(mesh, prog, samples, h: float, r: float, e: float):
    """Verify ``prog`` as the raster run does: limit 1.05 h, reach depth h, gouge e, the
    reachable judge."""
    from conformill.verify.simulate import verify

    return verify(mesh, prog, r, samples=samples, scallop=1.05 * h, reach_depth=h, gouge=e, judge="reachable")
