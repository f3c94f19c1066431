"""Read triangle meshes (STL, OBJ, PLY, OFF) into :class:`conformill.types.Mesh`.

PLY files of triangles are parsed here with ``numpy.frombuffer`` (binary, either byte order,
any extra scalar properties) or one ``split`` (ASCII), which is tens of times faster than
trimesh's reader; PLY files this parser does not handle (polygons, other list properties before
the faces) go to trimesh, as do OFF and STL (``process=False``: no merging, no reordering).
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
        parsed = _parse_ply(data, name) if fmt == "PLY" else None
        V, F = parsed if parsed is not None else _load_trimesh(data, fmt, name)

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


#: PLY scalar type names -> numpy type codes (without byte order)
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_FACE_LISTS = ("vertex_indices", "vertex_index")


class _PlyFallback(Exception):
    """A valid PLY feature the fast parser leaves to trimesh (polygons, other list properties)."""


def _ply_header(data: bytes, name: str):
    """Parse a PLY header: ``(format, elements, body offset)``.

    ``elements`` is a list of ``(name, count, props)``, ``props`` a list of ``(name, type)``
    for scalars or ``(name, (count type, item type))`` for lists.
    """
    if not data.startswith(b"ply"):
        raise MeshError(f"{name}: cannot read as PLY: the file does not start with 'ply'")
    end = data.find(b"end_header", 0, 1 << 20)
    if end < 0:
        raise MeshError(f"{name}: cannot read as PLY: no 'end_header' line in the header")
    nl = data.find(b"\n", end)
    body = len(data) if nl < 0 else nl + 1
    try:
        lines = data[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise MeshError(f"{name}: cannot read as PLY: non-ASCII bytes in the header") from None
    fmt, elements = None, []
    for no, line in enumerate(lines[1:], start=2):
        t = line.split()
        if not t or t[0] in ("comment", "obj_info"):
            continue
        bad = MeshError(f"{name}: cannot read as PLY: header line {no}: bad record {_one_line(line, 60)!r}")
        if t[0] == "format":
            if len(t) < 2 or t[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise bad
            fmt = t[1]
        elif t[0] == "element":
            if len(t) != 3 or not t[2].isdigit():
                raise bad
            elements.append((t[1], int(t[2]), []))
        elif t[0] == "property":
            if not elements:
                raise bad
            if len(t) == 5 and t[1] == "list" and t[2] in _PLY_TYPES and t[3] in _PLY_TYPES:
                elements[-1][2].append((t[4], (_PLY_TYPES[t[2]], _PLY_TYPES[t[3]])))
            elif len(t) == 3 and t[1] in _PLY_TYPES:
                elements[-1][2].append((t[2], _PLY_TYPES[t[1]]))
            else:
                raise bad
        else:
            raise bad
    if fmt is None:
        raise MeshError(f"{name}: cannot read as PLY: no 'format' line in the header")
    return fmt, elements, body


def _ply_face_layout(props, name: str):
    """Index of the face list among the face element's properties; other lists -> fallback."""
    lists = [i for i, (_, t) in enumerate(props) if isinstance(t, tuple)]
    if len(lists) != 1 or props[lists[0]][0] not in _PLY_FACE_LISTS:
        raise _PlyFallback
    return lists[0]


def _parse_ply(data: bytes, name: str):
    """Vertices and triangles of a PLY file, or ``None`` when trimesh must read it.

    Handles ASCII and binary (little/big endian) files whose ``vertex`` element has scalar
    ``x, y, z`` (plus any other scalar properties) and whose ``face`` element holds triangles in
    a ``vertex_indices`` (or ``vertex_index``) list (plus any other scalar properties); other
    elements are skipped. Polygons, and list properties anywhere else before the faces are
    read, fall back to trimesh (``None``).

    Returns
    -------
    V : (n, 3) float64
    F : (m, 3) int64

    Raises
    ------
    MeshError
        A malformed header, a file shorter than its header says (truncated), or an ASCII
        body that is not numbers.
    """
    fmt, elements, body = _ply_header(data, name)
    try:
        if fmt == "ascii":
            return _ply_ascii(data, body, elements, name)
        return _ply_binary(data, body, elements, "<" if fmt == "binary_little_endian" else ">", name)
    except _PlyFallback:
        return None


def _ply_binary(data: bytes, pos: int, elements, endian: str, name: str):
    V = F = None
    for el, count, props in elements:
        if V is not None and F is not None:
            break
        is_face = el == "face"
        if is_face:
            li = _ply_face_layout(props, name)
            ct, it = props[li][1]
            fields = [(p if i != li else "_n", t if i != li else ct) for i, (p, t) in enumerate(props)]
            fields.insert(li + 1, ("_i", it, (3,)))
        else:
            if any(isinstance(t, tuple) for _, t in props):
                raise _PlyFallback
            fields = [(p, t) for p, t in props]
        dt = np.dtype([(f[0], endian + f[1]) + tuple(f[2:]) for f in fields])
        size = dt.itemsize * count
        if pos + size > len(data):
            have = max(len(data) - pos, 0) // dt.itemsize if dt.itemsize else 0
            if is_face:  # polygons make the face records longer: trimesh may read it
                n = np.frombuffer(data, dtype=dt, count=have, offset=pos)["_n"] if have else []
                if np.any(np.asarray(n) != 3):
                    raise _PlyFallback
            raise MeshError(
                f"{name}: truncated PLY: the header declares {count} {el} records of "
                f"{dt.itemsize} bytes ({size} bytes from byte {pos}), the file has {len(data) - pos}"
            )
        rec = np.frombuffer(data, dtype=dt, count=count, offset=pos)
        pos += size
        if el == "vertex":
            V = _ply_xyz(rec, props, name)
        elif is_face:
            if count and not np.all(rec["_n"] == 3):
                raise _PlyFallback
            F = rec["_i"].astype(np.int64)
    return _ply_result(V, F, name)


def _ply_ascii(data: bytes, pos: int, elements, name: str):
    tokens = data[pos:].split()
    V = F = None
    t = 0
    for el, count, props in elements:
        if V is not None and F is not None:
            break
        if el == "face":
            li = _ply_face_layout(props, name)
            width = len(props) + 3
        elif any(isinstance(tp, tuple) for _, tp in props):
            raise _PlyFallback
        else:
            width = len(props)
        chunk = tokens[t:t + width * count]
        if len(chunk) < width * count:
            if el == "face" and len(chunk) >= width and chunk[li] != b"3":
                raise _PlyFallback
            raise MeshError(
                f"{name}: truncated PLY: the header declares {count} {el} records of {width} numbers, "
                f"the file has {len(chunk)} numbers for them"
            )
        t += width * count
        if el not in ("vertex", "face"):
            continue
        try:
            arr = np.array(chunk, dtype=np.float64).reshape(count, width)
        except ValueError:
            bad = next(x for x in chunk if not _is_number(x))
            raise MeshError(f"{name}: cannot read as PLY: {el} data: not a number: {_one_line(bad.decode('latin-1'), 40)!r}") from None
        if el == "vertex":  # values rounded to the declared type, as a binary file would be
            rec = {p: arr[:, i].astype(tp).astype(np.float64) for i, (p, tp) in enumerate(props)}
            V = _ply_xyz(rec, props, name)
        else:
            if count and not np.all(arr[:, li] == 3):
                raise _PlyFallback
            idx = arr[:, li + 1:li + 4]
            if not np.all(idx == np.round(idx)):
                raise MeshError(f"{name}: cannot read as PLY: face indices are not integers")
            F = idx.astype(np.int64)
    return _ply_result(V, F, name)


def _is_number(tok: bytes) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _ply_xyz(rec, props, name: str) -> np.ndarray:
    names = [p for p, _ in props]
    if not all(c in names for c in "xyz"):
        raise MeshError(f"{name}: cannot read as PLY: the vertex element has no x, y, z properties")
    V = np.empty((len(rec["x"]), 3), dtype=np.float64)
    for j, c in enumerate("xyz"):
        V[:, j] = rec[c]
    return V


def _ply_result(V, F, name: str):
    if V is None:
        raise MeshError(f"{name}: cannot read as PLY: no 'vertex' element")
    if F is None:
        F = np.zeros((0, 3), dtype=np.int64)
    return V, F


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
