"""The PLY fast path of read_mesh against trimesh's reader, and its failures.

ASCII and binary (both byte orders) files with extra vertex and face properties, other
elements, float and double coordinates, signed and unsigned indices: the arrays must be
exactly trimesh's. Polygons go to trimesh; truncated or malformed files fail with a
MeshError that names the file.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from conformill.errors import MeshError
from conformill.mesh import synthetic
from conformill.mesh.io import _parse_ply, read_mesh

NP = {"float": "f4", "double": "f8", "uchar": "u1", "char": "i1", "short": "i2", "ushort": "u2",
      "int": "i4", "uint": "u4"}


def make_ply(V, F, fmt="binary_little_endian", vtype="float", itype="int", ctype="uchar",
             vextra=(), fextra=(), other=None, index_name="vertex_indices", face_first=False):
    """PLY bytes. ``vextra``/``fextra``: (name, type) scalar properties with values 7, 8, ...;
    ``other``: an extra element ``(name, count)`` of two uchar properties, written first."""
    nv, nf = len(V), len(F)
    vprops = [("x", vtype), ("y", vtype), ("z", vtype)] + list(vextra)
    el_v = [f"element vertex {nv}"] + [f"property {t} {n}" for n, t in vprops]
    el_f = [f"element face {nf}", f"property list {ctype} {itype} {index_name}"] + \
        [f"property {t} {n}" for n, t in fextra]
    el_o = [f"element {other[0]} {other[1]}", "property uchar a", "property uchar b"] if other else []
    order = ([el_o] if other else []) + ([el_f, el_v] if face_first else [el_v, el_f])
    head = ["ply", f"format {fmt} 1.0", "comment made by conformill tests"] + sum(order, []) + ["end_header"]
    head = ("\n".join(head) + "\n").encode()
    e = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    vcols = [V[:, 0], V[:, 1], V[:, 2]] + [np.full(nv, 7 + i) for i in range(len(vextra))]
    fcols = [np.full(nf, 3), F[:, 0], F[:, 1], F[:, 2]] + [np.full(nf, 7 + i) for i in range(len(fextra))]
    ftypes = [ctype, itype, itype, itype] + [t for _, t in fextra]
    vtypes = [t for _, t in vprops]
    ocols = [np.full(other[1], 1), np.full(other[1], 2)] if other else []
    if e is None:
        def rows(cols, types):
            return "".join(" ".join(repr(float(c[i])) if NP[t][0] == "f" else str(int(c[i]))
                                    for c, t in zip(cols, types)) + "\n" for i in range(len(cols[0])))
        parts = {"v": rows(vcols, vtypes), "f": rows(fcols, ftypes),
                 "o": rows(ocols, ["uchar", "uchar"]) if other else ""}
        parts = {k: p.encode() for k, p in parts.items()}
    else:
        def rec(cols, types):
            dt = np.dtype([(f"c{i}", e + NP[t]) for i, t in enumerate(types)])
            r = np.zeros(len(cols[0]), dtype=dt)
            for i, c in enumerate(cols):
                r[f"c{i}"] = c
            return r.tobytes()
        parts = {"v": rec(vcols, vtypes), "f": rec(fcols, ftypes),
                 "o": rec(ocols, ["uchar", "uchar"]) if other else b""}
    body = parts["o"] + (parts["f"] + parts["v"] if face_first else parts["v"] + parts["f"])
    return head + body


def trimesh_arrays(data):
    m = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


MESH = synthetic.sphere_cap(R=40, radius_xy=20, spacing=4.0, jitter=0.3)

CASES = {
    "ascii": dict(fmt="ascii", vtype="double"),
    "ascii_float_extras": dict(fmt="ascii", vextra=[("nx", "float"), ("red", "uchar")], fextra=[("flags", "int")]),
    "le_float": dict(),
    "le_double_uint": dict(vtype="double", itype="uint"),
    "be_float": dict(fmt="binary_big_endian"),
    "be_double_extras": dict(fmt="binary_big_endian", vtype="double", vextra=[("nx", "float"), ("q", "short")],
                             fextra=[("red", "uchar"), ("w", "double")]),
    "le_vertex_index_ushort_count": dict(index_name="vertex_index", ctype="ushort"),
    "le_other_element_first": dict(other=("material", 3)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_fast_reader_gives_trimeshs_arrays(case):
    data = make_ply(MESH.V, MESH.F, **CASES[case])
    parsed = _parse_ply(data, "t.ply")
    assert parsed is not None, "the fast path should handle this file"
    V, F = parsed
    Vt, Ft = trimesh_arrays(data)
    assert V.dtype == np.float64 and F.dtype == np.int64
    assert np.array_equal(V, Vt) and np.array_equal(F, Ft)


def test_face_element_before_vertices(tmp_path):
    data = make_ply(MESH.V, MESH.F, face_first=True)
    V, F = _parse_ply(data, "t.ply")
    assert np.array_equal(V, MESH.V.astype(np.float32)) and np.array_equal(F, MESH.F)
    p = tmp_path / "ff.ply"
    p.write_bytes(data)
    assert read_mesh(p).n_faces == MESH.n_faces


def test_read_mesh_uses_the_fast_path_and_scales(tmp_path):
    p = tmp_path / "m.ply"
    p.write_bytes(make_ply(MESH.V, MESH.F, vtype="double"))
    m = read_mesh(p, scale=2.0)
    assert np.array_equal(m.V, MESH.V * 2.0) and np.array_equal(m.F, MESH.F)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_polygons_fall_back_to_trimesh(tmp_path, fmt):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]])
    head = f"ply\nformat {fmt} 1.0\nelement vertex 5\nproperty double x\nproperty double y\nproperty double z\n" \
           "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
    quads = [[0, 1, 2, 3], [1, 4, 2, 3]]
    if fmt == "ascii":  # a triangle and a quad
        body = "".join(f"{x} {y} {z}\n" for x, y, z in V) + "3 1 4 2\n4 0 1 2 3\n"
        data = head.encode() + body.encode()
    else:  # two quads (trimesh reads binary polygons only when they all have the same size)
        body = V.astype("<f8").tobytes() + b"".join(bytes([4]) + np.array(q, "<i4").tobytes() for q in quads)
        data = head.encode() + body
    assert _parse_ply(data, "q.ply") is None
    p = tmp_path / "q.ply"
    p.write_bytes(data)
    m = read_mesh(p, validate=False)
    Vt, Ft = trimesh_arrays(data)
    assert np.array_equal(m.F, Ft) and m.n_faces == (3 if fmt == "ascii" else 4)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("cut", [0.3, 0.7, 0.999])
def test_truncated_files_fail_cleanly(tmp_path, fmt, cut):
    data = make_ply(MESH.V, MESH.F, fmt=fmt)
    body_start = data.index(b"end_header\n") + len(b"end_header\n")
    n = body_start + int((len(data) - body_start) * cut)
    if fmt == "ascii":  # cut at a line end: a short file, not a bad number
        n = data.rindex(b"\n", 0, n) + 1
    p = tmp_path / "cut.ply"
    p.write_bytes(data[:n])
    with pytest.raises(MeshError, match=r"cut\.ply: truncated PLY"):
        read_mesh(p)


@pytest.mark.parametrize("header, needle", [
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n", "no 'end_header'"),
    (b"ply\nformat weird 1.0\nend_header\n", "header line 2"),
    (b"ply\nelement vertex 1\nproperty float x\nend_header\n", "no 'format'"),
    (b"ply\nformat ascii 1.0\nproperty float x\nend_header\n", "header line 3"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
     "no x, y, z"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n1 2 abc\n", "not a number: 'abc'"),
])
def test_malformed_files_fail_with_what_and_where(tmp_path, header, needle):
    p = tmp_path / "bad.ply"
    p.write_bytes(header)
    with pytest.raises(MeshError) as ei:
        read_mesh(p)
    assert "bad.ply" in str(ei.value) and needle in str(ei.value)


def test_vertices_without_faces_is_no_faces(tmp_path):
    p = tmp_path / "pts.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                  b"property float z\nend_header\n0 0 0\n1 1 1\n")
    with pytest.raises(MeshError, match="no faces"):
        read_mesh(p)
