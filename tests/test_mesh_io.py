"""read_mesh: formats, vertex order, STL welding, scale, samples and every bad input."""

from __future__ import annotations

import logging
import struct
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_mesh_validate import BAD, grid  # noqa: E402

from conformill.data import SAMPLES, sample_path  # noqa: E402
from conformill.errors import MeshError  # noqa: E402
from conformill.mesh import synthetic, topology  # noqa: E402
from conformill.mesh.io import read_mesh, weld_exact  # noqa: E402
from conformill.mesh.validate import validate_disk  # noqa: E402
from conformill.types import Mesh  # noqa: E402

SHARED = Path("/work/shared/meshes")


# --------------------------------------------------------------------------- writers
def write_obj(path, V, F, extra_v=()):
    lines = ["# test", "o part"] + [f"v {x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in extra_v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F.tolist()]
    Path(path).write_text("\n".join(lines) + "\n")
    return path


def write_off(path, V, F):
    lines = ["OFF", f"{len(V)} {len(F)} 0"] + [f"{x!r} {y!r} {z!r}" for x, y, z in V.tolist()]
    lines += [f"3 {a} {b} {c}" for a, b, c in F.tolist()]
    Path(path).write_text("\n".join(lines) + "\n")
    return path


def write_ply(path, V, F, binary=False, dtype="double"):
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
            f"element vertex {len(V)}", f"property {dtype} x", f"property {dtype} y", f"property {dtype} z",
            f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    head = ("\n".join(head) + "\n").encode()
    if binary:
        vt = "<f8" if dtype == "double" else "<f4"
        rec = np.zeros(len(F), dtype=[("k", "u1"), ("i", "<i4", (3,))])
        rec["k"], rec["i"] = 3, F
        body = np.asarray(V, dtype=vt).tobytes() + rec.tobytes()
    else:
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
        body += "".join(f"3 {a} {b} {c}\n" for a, b, c in F.tolist())
        body = body.encode()
    Path(path).write_bytes(head + body)
    return path


def write_stl(path, V, F, binary=False):
    T = np.asarray(V, dtype=np.float64)[F]
    if binary:
        out = bytearray(b"conformill test".ljust(80, b" ") + struct.pack("<I", len(F)))
        rec = np.zeros(len(F), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("a", "<u2")])
        rec["v"] = T
        Path(path).write_bytes(bytes(out) + rec.tobytes())
    else:
        lines = ["solid test"]
        for t in T.tolist():
            lines += ["facet normal 0 0 0", "outer loop"] + [f"vertex {x!r} {y!r} {z!r}" for x, y, z in t]
            lines += ["endloop", "endfacet"]
        Path(path).write_text("\n".join(lines + ["endsolid test"]) + "\n")
    return path


WRITERS = {
    "obj": lambda p, V, F: write_obj(p, V, F),
    "off": lambda p, V, F: write_off(p, V, F),
    "ply": lambda p, V, F: write_ply(p, V, F),
    "bin.ply": lambda p, V, F: write_ply(p, V, F, binary=True),
    "stl": lambda p, V, F: write_stl(p, V, F),
    "bin.stl": lambda p, V, F: write_stl(p, V, F, binary=True),
}


def bad_files(tmp_path) -> dict:
    """name -> (path, substrings the message must contain); used by the CLI tests too."""
    out = {}
    fmts = ["stl", "obj", "ply", "off", "bin.ply", "bin.stl"]
    for i, (name, (V, F, needles)) in enumerate(sorted(BAD.items())):
        fmt = fmts[i % len(fmts)]
        if name in ("repeated_index", "nan_vertex") and fmt.endswith("stl"):
            fmt = "ply"  # STL ids are facet corners: tested separately
        path = WRITERS[fmt](tmp_path / f"{name}.{fmt}", V, F)
        out[name] = (path, [path.name] + needles)
    out["empty"] = (tmp_path / "empty.stl", ["empty.stl", "empty"])
    out["empty"][0].write_bytes(b"")
    for ext in ("stl", "obj", "ply", "off"):
        p = tmp_path / f"garbage.{ext}"
        p.write_bytes(np.random.default_rng(3).bytes(600))
        out[f"garbage_{ext}"] = (p, [p.name])
    p = tmp_path / "part.step"
    p.write_text("ISO-10303-21;\n")
    out["unknown_ext"] = (p, ["part.step", "unknown mesh format", ".stl", ".obj", ".ply", ".off"])
    out["missing"] = (tmp_path / "nope.ply", ["nope.ply", "no such file"])
    p = tmp_path / "points.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    out["no_faces"] = (p, ["points.obj", "no faces"])
    V, F = grid(2)
    p = write_ply(tmp_path / "oob.ply", V, np.vstack([F, [[0, 1, 42]]]))
    out["index_out_of_range"] = (p, ["oob.ply", "faces 8", "42"])
    return out


def _fan(tmp_path):
    return synthetic.freeform_patch(spacing=4.0)


# --------------------------------------------------------------------------- bad inputs
def test_every_bad_file_raises_meaningful_mesherror(tmp_path):
    for name, (path, needles) in bad_files(tmp_path).items():
        with pytest.raises(MeshError) as exc:
            read_mesh(path)
        msg = str(exc.value)
        assert "\n" not in msg, (name, msg)
        for s in needles:
            assert s in msg, (name, s, msg)


@pytest.mark.parametrize("fmt", ["obj", "off", "ply"])
def test_nan_vertex_is_named_in_file_ids(tmp_path, fmt):
    V, F = grid(2)
    V = V.copy()
    V[4, 2] = np.inf if fmt == "off" else np.nan
    path = WRITERS[fmt](tmp_path / f"bad.{fmt}", V, F)
    with pytest.raises(MeshError, match=r"bad\.\w+: 1 vertex/vertices with NaN or infinite coordinates: vertices 4"):
        read_mesh(path)


@pytest.mark.parametrize("binary", [False, True])
def test_nan_in_stl_names_facets(tmp_path, binary):
    V, F = grid(2)
    V = V.copy()
    V[0, 0] = np.nan  # vertex 0 is used by faces 0 and 1 only
    path = write_stl(tmp_path / "bad.stl", V, F, binary=binary)
    with pytest.raises(MeshError, match=r"bad\.stl: NaN or infinite coordinates in 2 facet\(s\): facets 0, 1"):
        read_mesh(path)


def test_stl_repeated_corner_becomes_degenerate_face(tmp_path):
    V, F = grid(2)
    F = np.vstack([F, [[2, 2, 5]]])
    path = write_stl(tmp_path / "deg.stl", V, F, binary=True)
    with pytest.raises(MeshError, match=r"deg\.stl: 1 degenerate face with a repeated vertex: faces 8"):
        read_mesh(path)


@pytest.mark.parametrize("scale", [0, -1.0, float("nan"), float("inf"), "abc", None])
def test_bad_scale(tmp_path, scale):
    path = write_obj(tmp_path / "ok.obj", *grid(2))
    with pytest.raises(MeshError, match="scale"):
        read_mesh(path, scale=scale)


def test_directory_is_not_a_mesh(tmp_path):
    d = tmp_path / "dir.ply"
    d.mkdir()
    with pytest.raises(MeshError, match="is a directory"):
        read_mesh(d)


def test_bad_obj_records_name_the_line(tmp_path):
    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 x\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"bad\.obj: line 3: bad vertex record"):
        read_mesh(p)
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n")
    with pytest.raises(MeshError, match=r"bad\.obj: line 4: bad face record"):
        read_mesh(p)


def test_unknown_sample():
    with pytest.raises(MeshError, match="sample:nose: unknown sample; available: face, lion, patch"):
        read_mesh("sample:nose")


def test_validate_false_returns_invalid_mesh(tmp_path):
    V, F, _ = BAD["closed"]
    m = read_mesh(write_ply(tmp_path / "sphere.ply", V, F), validate=False)
    assert m.n_faces == len(F)
    with pytest.raises(MeshError, match="closed"):
        validate_disk(m)


# --------------------------------------------------------------------------- good inputs
@pytest.mark.parametrize("fmt", ["obj", "off", "ply", "bin.ply"])
def test_vertex_order_is_file_order(tmp_path, fmt):
    m = synthetic.freeform_patch(spacing=4.0)
    perm = np.random.default_rng(0).permutation(m.n_vertices)  # a scrambled, still valid order
    inv = np.argsort(perm)
    V, F = m.V[perm], inv[m.F]
    r = read_mesh(WRITERS[fmt](tmp_path / f"p.{fmt}", V, F))
    assert r.V.dtype == np.float64 and r.F.dtype == np.int64
    assert np.array_equal(r.V, V)  # repr/double round-trips exactly
    assert np.array_equal(r.F, F)
    assert r.name == f"p.{fmt}"


@pytest.mark.parametrize("binary", [False, True])
def test_stl_welding_gives_the_ply_topology(tmp_path, binary):
    m = synthetic.freeform_patch(spacing=3.0)
    ply = read_mesh(write_ply(tmp_path / "p.ply", m.V, m.F))
    stl = read_mesh(write_stl(tmp_path / "p.stl", m.V, m.F, binary=binary))
    assert stl.n_vertices == ply.n_vertices and stl.n_faces == ply.n_faces
    # same faces in the same order, each corner at the same place (float32 in binary STL)
    np.testing.assert_allclose(stl.V[stl.F], ply.V[ply.F], rtol=0, atol=1e-5 if binary else 0)
    e1, _, _ = topology.undirected_edges(ply.F)
    e2, _, _ = topology.undirected_edges(stl.F)
    assert len(e1) == len(e2)
    l1 = topology.boundary_loops(ply.F, ply.n_vertices)
    l2 = topology.boundary_loops(stl.F, stl.n_vertices)
    assert [len(x) for x in l1] == [len(x) for x in l2]
    # the welded ids are the order of first appearance
    first = np.unique(stl.F.reshape(-1), return_index=True)[1]
    assert np.all(np.diff(first) > 0)


def test_weld_exact_merges_signed_zeros_only_exact():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-0.0, 0, 0], [0, 1, 0], [1, 1e-12, 0]])
    F = np.array([[0, 1, 2], [3, 2, 5]])
    Vw, Fw = weld_exact(V, F)
    assert len(Vw) == 4
    assert Fw.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_obj_polygons_negative_indices_and_slashes(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text(
        "mtllib none.mtl\nv 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\nvt 0 0\nvn 0 0 1\n"
        "usemtl a\nf 1/1/1 2/1/1 3/1/1 4/1/1\n"
        "v 20 0 0 1.0\nv 20 10 0\nf -5//1 -2//1 -1//1 -4//1\n"
    )
    m = read_mesh(p)
    assert m.F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]
    assert m.n_vertices == 6


def test_unreferenced_vertices_are_dropped_with_a_warning(tmp_path, caplog):
    V, F = grid(2)
    V = np.vstack([[[50.0, 50.0, 50.0]], V, [[60.0, 60.0, 60.0]]])  # ids 0 and 10 unused
    p = write_ply(tmp_path / "loose.ply", V, F + 1)
    with caplog.at_level(logging.WARNING, logger="conformill.mesh.io"):
        m = read_mesh(p)
    assert "loose.ply: dropped 2 unreferenced vertices (file ids 0, 10)" in caplog.text
    assert np.array_equal(m.V, V[1:-1]) and np.array_equal(m.F, F)


def test_scale_multiplies_coordinates(tmp_path):
    V, F = grid(2)
    m = read_mesh(write_off(tmp_path / "g.off", V, F), scale=1000)
    assert np.array_equal(m.V, V * 1000.0)


def test_quads_in_off_and_float32_ply(tmp_path):
    p = tmp_path / "q.off"
    p.write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    assert read_mesh(p).n_faces == 2
    V, F = grid(3)
    m = read_mesh(write_ply(tmp_path / "f.ply", V, F, binary=True, dtype="float"))
    assert m.V.dtype == np.float64 and np.array_equal(m.V, V.astype(np.float32).astype(np.float64))


# --------------------------------------------------------------------------- samples
@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_samples_are_valid_disks_facing_z(name):
    path = sample_path(name)
    assert path.stat().st_size <= 400_000
    m = read_mesh(f"sample:{name}")
    assert m.name == f"sample:{name}"
    validate_disk(m)
    assert 5_000 <= m.n_faces <= 40_000
    assert m.V[:, 2].min() == 0.0
    lo, hi = m.V.min(axis=0), m.V.max(axis=0)
    np.testing.assert_allclose((lo + hi)[:2] / 2, 0.0, atol=1e-4)
    assert 100.0 <= hi[0] - lo[0] <= 140.0  # mm
    P = m.V[m.F]
    N = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    if name == "patch":  # a height field over XY as designed: every normal points up
        assert (N[:, 2] > 0).all()
    else:  # scans are turned so that the area-weighted mean normal is +Z
        n = N.sum(axis=0)
        np.testing.assert_allclose(n / np.linalg.norm(n), [0, 0, 1], atol=1e-5)
    assert isinstance(SAMPLES[name], str) and "\n" not in SAMPLES[name]


def test_sample_licence_files_ship():
    d = sample_path("face").parent
    assert (d / "SAMPLES.md").is_file()
    assert "Apache License" in (d / "LICENSE-choi-disk-conformal-map-Apache-2.0.txt").read_text()


# --------------------------------------------------------------------------- shared meshes
SHARED_FILES = sorted(p.name for p in SHARED.glob("*") if p.suffix in (".ply", ".off", ".obj", ".stl")) \
    if SHARED.is_dir() else []


@pytest.mark.parametrize("fname", SHARED_FILES or ["(none)"])
def test_shared_meshes_read_as_disks(fname):
    if not SHARED.is_dir() or fname == "(none)":
        pytest.skip("/work/shared/meshes is not available")
    t = time.perf_counter()
    m = read_mesh(SHARED / fname)
    logging.getLogger(__name__).info("%s: %.3f s", fname, time.perf_counter() - t)
    assert m.n_faces > 0 and len(topology.boundary_loops(m.F, m.n_vertices)) == 1


@pytest.mark.parametrize("fmt", ["stl", "off"])
def test_a_text_mesh_in_latin1_is_read(tmp_path, fmt):
    # trimesh decodes text that is not UTF-8 with charset-normalizer (a dependency for this)
    import trimesh

    m = synthetic.plane(size=10.0, spacing=2.0)
    tm = trimesh.Trimesh(m.V, m.F, process=False)
    text = trimesh.exchange.stl.export_stl_ascii(tm) if fmt == "stl" else tm.export(file_type="off")
    text = text.replace("solid", "solid pi\xe8ce", 1) if fmt == "stl" else text.replace("OFF", "OFF\n# pi\xe8ce", 1)
    p = tmp_path / f"latin1.{fmt}"
    p.write_bytes(text.encode("latin-1"))
    with pytest.raises(UnicodeDecodeError):
        p.read_bytes().decode("utf-8")
    got = read_mesh(p)
    assert got.n_faces == m.n_faces and np.allclose(np.sort(got.V, axis=0), np.sort(m.V, axis=0))
