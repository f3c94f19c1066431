"""Read triangle meshes (STL, OBJ, PLY, OFF) into :class:`conformill.types.Mesh`.

PLY, OFF and STL are parsed by trimesh (``process=False``: no merging, no reordering).
OBJ is parsed here, geometry only (``v`` and ``f`` records): trimesh's OBJ loader splits
vertices along texture seams, reorders them and drops unreferenced ones silently, and a
parameterization needs the file's own vertex ids and topology.

STL stores each facet's three corners separately, so exactly coincident corners are
welded (bit-identical coordinates, ``-0.0 == 0.0``); the welded vertices are numbered in
order of first appearance. For the other formats vertices stay in file order; vertices no
face uses are dropped with a logging warning (ids of the survivors keep their order).

Paths of the form ``sample:NAME`` read a sample mesh shipped with the package
(:data:`conformill.data.SAMPLES`).
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
from pathlib import Path

import numpy as np

from conformill.errors import MeshError
from conformill.mesh.validate import fmt_ids, validate_disk
from conformill.types import Mesh

log = logging.getLogger(__name__)

#: file extension -> format name
FORMATS = {".stl": "STL", ".obj": "OBJ", ".ply": "PLY", ".off": "OFF"}

SAMPLE_PREFIX = "sample:"


def read_mesh(path, scale: float = 1.0, validate: bool = True) -> Mesh:
    """Read a triangle mesh file, scale it to mm and (by default) check it is a disk.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.stl`` (ASCII or binary), ``.obj``, ``.ply`` or ``.off`` file, or
        ``"sample:NAME"`` for a sample shipped with the package (see
        :data:`conformill.data.SAMPLES`).
    scale : float
        Factor applied to the coordinates (e.g. 1000 for a file in metres). Finite, > 0.
    validate : bool
        Run :func:`conformill.mesh.validate.validate_disk` on the result.

    Returns
    -------
    Mesh
        ``V (n, 3) float64`` = file coordinates times ``scale``; ``F (m, 3) int64``;
        ``name`` = the file name (or ``sample:NAME``). Vertices in file order (STL: welded,
        in order of first appearance), unreferenced vertices dropped.

    Raises
    ------
    MeshError
        Bad scale; file missing, empty, unreadable or of an unknown extension; face indices
        out of range; NaN/inf coordinates (names the vertices); no faces; and, with
        ``validate``, every defect :func:`validate_disk` reports.
    """
    try:
        scale_f = float(scale)
    except (TypeError, ValueError):
        raise MeshError(f"scale must be a positive number, got {scale!r}") from None
    if not math.isfinite(scale_f) or scale_f <= 0.0:
        raise MeshError(f"scale must be a positive finite number, got {scale!r}")

    path_s = os.fspath(path)
    if isinstance(path_s, bytes):
        path_s = os.fsdecode(path_s)
    if path_s.startswith(SAMPLE_PREFIX):
        from conformill.data import sample_path

        name = path_s
        file = sample_path(path_s[len(SAMPLE_PREFIX):])
    else:
        file = Path(path_s)
        name = file.name or path_s

    ext = file.suffix.lower()
    if ext not in FORMATS:
        supported = ", ".join(FORMATS)
        raise MeshError(
            f"{path_s}: unknown mesh format {ext or '(no extension)'!r}; supported: {supported}"
        )
    data = _read_bytes(file, path_s)
    fmt = FORMATS[ext]
    if fmt == "OBJ":
        V, F = _parse_obj(data, name)
    else:
        V, F = _load_trimesh(data, fmt, name)

    if len(F) == 0:
        raise MeshError(
            f"{name}: no faces found ({len(V)} vertices): not a {fmt} triangle mesh, or a point cloud"
        )
    _check_indices(V, F, name)
    _check_finite(V, F, name, fmt)
    if fmt == "STL":
        V, F = weld_exact(V, F)
    V, F = drop_unreferenced(V, F, name)
    mesh = Mesh(V=np.ascontiguousarray(V * scale_f, dtype=np.float64),
                F=np.ascontiguousarray(F, dtype=np.int64), name=name)
    if validate:
        validate_disk(mesh)
    return mesh


def _read_bytes(file: Path, shown: str) -> bytes:
    if not file.exists():
        raise MeshError(f"{shown}: no such file")
    if file.is_dir():
        raise MeshError(f"{shown}: is a directory, not a mesh file")
    try:
        data = file.read_bytes()
    except OSError as exc:
        raise MeshError(f"{shown}: cannot read the file: {exc.strerror or exc}") from None
    if len(data) == 0:
        raise MeshError(f"{shown}: the file is empty (0 bytes)")
    return data


def _one_line(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _load_trimesh(data: bytes, fmt: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces as stored, via trimesh with ``process=False``."""
    import trimesh

    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt.lower(), process=False)
    except Exception as exc:  # trimesh raises anything from ValueError to struct.error
        raise MeshError(
            f"{name}: cannot read as {fmt}: {type(exc).__name__}: {_one_line(exc)}"
        ) from None
    if isinstance(loaded, trimesh.Scene):
        parts = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
    elif isinstance(loaded, trimesh.Trimesh):
        parts = [loaded]
    else:  # a point cloud, a path
        n = len(getattr(loaded, "vertices", []))
        return np.zeros((n, 3)), np.zeros((0, 3), dtype=np.int64)
    Vs, Fs, offset = [], [], 0
    for g in parts:
        v = np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        Vs.append(v)
        Fs.append(f + offset)
        offset += len(v)
    if not Vs:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.vstack(Vs), np.vstack(Fs)


_SLASH_TAIL = re.compile(r"/\S*")


def _parse_obj(data: bytes, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Geometry of a Wavefront OBJ: ``v x y z [w]`` and ``f i[/t[/n]] ...`` records.

    Indices are 1-based or negative (relative to the vertices read so far); polygons are
    split into fans ``(0, k, k + 1)``. Other records are ignored.
    """
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        try:
            text = data.decode("latin-1")
        except UnicodeDecodeError:  # pragma: no cover - latin-1 decodes any byte
            raise MeshError(f"{name}: not a text OBJ file") from None
    if "\x00" in text:
        raise MeshError(f"{name}: cannot read as OBJ: the file contains binary data (NUL bytes)")
    text = text.replace("\\\r\n", " ").replace("\\\n", " ")
    lines = text.splitlines()
    v_lines, f_lines, f_nv = [], [], []
    for no, line in enumerate(lines, start=1):
        s = line.lstrip()
        if s.startswith("v ") or s.startswith("v\t"):
            v_lines.append((no, s))
        elif s.startswith("f ") or s.startswith("f\t"):
            f_lines.append((no, s))
            f_nv.append(len(v_lines))
    V = _obj_vertices(v_lines, name)
    F = _obj_faces(f_lines, np.asarray(f_nv, dtype=np.int64), len(V), name)
    return V, F


def _obj_vertices(v_lines, name: str) -> np.ndarray:
    if not v_lines:
        return np.zeros((0, 3))
    toks = [s.split() for _, s in v_lines]
    if all(len(t) >= 4 for t in toks):  # the common case, parsed in one call
        try:
            return np.array([t[1:4] for t in toks], dtype=np.float64)
        except ValueError:
            pass  # find and report the bad line below
    V = np.empty((len(toks), 3))
    for i, ((no, s), t) in enumerate(zip(v_lines, toks)):
        try:
            if len(t) < 4:
                raise ValueError
            V[i] = [float(x) for x in t[1:4]]
        except ValueError:
            raise MeshError(
                f"{name}: line {no}: bad vertex record {_one_line(s, 60)!r} (expected 'v x y z')"
            ) from None
    return V


def _obj_faces(f_lines, nv_before: np.ndarray, n_vertices: int, name: str) -> np.ndarray:
    if not f_lines:
        return np.zeros((0, 3), dtype=np.int64)
    toks = [_SLASH_TAIL.sub("", s).split()[1:] for _, s in f_lines]
    if all(len(t) == 3 for t in toks):
        try:
            idx = np.array(toks, dtype=np.int64)
        except ValueError:
            idx = None
        if idx is not None and (idx != 0).all():
            # OBJ is 1-based; negative indices count back from the last vertex read so far
            return np.where(idx > 0, idx - 1, nv_before[:, None] + idx)
    out = []
    for (no, s), t, nvb in zip(f_lines, toks, nv_before):
        try:
            ids = [int(x) for x in t]
        except ValueError:
            ids = []
        if len(ids) < 3 or 0 in ids:
            raise MeshError(
                f"{name}: line {no}: bad face record {_one_line(s, 60)!r} (expected 'f i j k', "
                f"1-based vertex indices)"
            )
        ids = [i - 1 if i > 0 else int(nvb) + i for i in ids]
        for k in range(1, len(ids) - 1):
            out.append((ids[0], ids[k], ids[k + 1]))
    return np.asarray(out, dtype=np.int64).reshape(-1, 3)


def _check_indices(V: np.ndarray, F: np.ndarray, name: str) -> None:
    n = len(V)
    bad = np.flatnonzero(((F < 0) | (F >= n)).any(axis=1))
    if len(bad):
        f = int(bad[0])
        raise MeshError(
            f"{name}: {len(bad)} face(s) reference vertices outside the {n} in the file: "
            f"faces {fmt_ids(bad)} (face {f} = {F[f].tolist()}, 0-based)"
        )


def _check_finite(V: np.ndarray, F: np.ndarray, name: str, fmt: str) -> None:
    bad = np.flatnonzero(~np.isfinite(V).all(axis=1))
    if not len(bad):
        return
    if fmt == "STL":  # STL corners are numbered by facet
        facets = np.unique(np.flatnonzero(np.isin(F, bad).any(axis=1)))
        raise MeshError(
            f"{name}: NaN or infinite coordinates in {len(facets)} facet(s): facets "
            f"{fmt_ids(facets)} (0-based)"
        )
    raise MeshError(
        f"{name}: {len(bad)} vertex/vertices with NaN or infinite coordinates: vertices "
        f"{fmt_ids(bad)} (0-based, file order; vertex {int(bad[0])} = {V[bad[0]].tolist()})"
    )


def weld_exact(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical coordinates (``-0.0`` and ``0.0`` are equal).

    Parameters
    ----------
    V : (k, 3) float64
    F : (m, 3) int64

    Returns
    -------
    V : (n, 3) float64
        Unique positions in order of first appearance in ``V``.
    F : (m, 3) int64
        Faces re-indexed, same order.
    """
    Vc = np.ascontiguousarray(np.asarray(V, dtype=np.float64) + 0.0)  # -0.0 + 0.0 == +0.0
    rows = Vc.view(np.dtype((np.void, Vc.dtype.itemsize * 3))).reshape(-1)
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    new_of_old = rank[inverse.reshape(-1)]
    Vw = Vc[np.sort(first)]
    return Vw, new_of_old[np.asarray(F, dtype=np.int64)]


def drop_unreferenced(V: np.ndarray, F: np.ndarray, name: str = "mesh") -> tuple[np.ndarray, np.ndarray]:
    """Remove vertices no face uses, keeping the order of the others; logs a warning.

    Returns
    -------
    V : (n', 3) float64
    F : (m, 3) int64
    """
    used = np.bincount(F.reshape(-1), minlength=len(V)) > 0
    if used.all():
        return V, F
    unused = np.flatnonzero(~used)
    log.warning("%s: dropped %d unreferenced vertices (file ids %s)", name, len(unused), fmt_ids(unused))
    new_id = np.cumsum(used) - 1
    return V[used], new_id[F]
