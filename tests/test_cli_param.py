"""`conformill param` end to end on generated meshes."""

import json

import numpy as np
import pytest
import trimesh

from conformill.cli.main import main
from conformill.mesh import synthetic as syn


@pytest.fixture()
def mesh_file(tmp_path):
    m = syn.freeform_patch(spacing=4.0)
    path = tmp_path / "patch.ply"
    trimesh.Trimesh(m.V / 1000.0, m.F, process=False).export(path)  # in metres
    return m, path


def _read_obj(path):
    v, vt, f = [], [], []
    for line in path.read_text().splitlines():
        t = line.split()
        if t and t[0] == "v":
            v.append([float(x) for x in t[1:]])
        elif t and t[0] == "vt":
            vt.append([float(x) for x in t[1:]])
        elif t and t[0] == "f":
            f.append([int(x.split("/")[0]) - 1 for x in t[1:]])
    return np.array(v), np.array(vt), np.array(f)


def test_param_writes_obj_report_plot(mesh_file, tmp_path, capsys):
    m, path = mesh_file
    out, rep, png = tmp_path / "o.obj", tmp_path / "r.json", tmp_path / "p.png"
    rc = main(["param", str(path), "--scale", "1000", "--boundary", "rectangle", "-o", str(out),
               "--report", str(rep), "--plot", str(png)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "vertices" in text and "QC mean" in text and "flipped 0" in text
    v, vt, f = _read_obj(out)
    assert np.abs(v - m.V).max() < 1e-5  # input order, times the scale
    assert (f == m.F).all() and vt.shape == (m.n_vertices, 2)
    r = json.loads(rep.read_text())
    assert r["mesh"]["vertices"] == m.n_vertices and r["mesh"]["faces"] == m.n_faces
    assert r["domain"]["kind"] == "rectangle" and len(r["corners"]) == 4
    assert r["quality"]["flipped_faces"] == 0 and r["residual"] < 1e-8
    assert {"read", "weights", "solve", "write_obj", "total"} <= set(r["timings_s"])
    assert r["solver"] and r["fallbacks"] >= 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_param_quiet_and_user_corners(mesh_file, tmp_path, capsys):
    _, path = mesh_file
    from conformill.mesh.io import read_mesh
    from conformill.mesh.topology import boundary_loops

    mm = read_mesh(path, scale=1000)
    loop = boundary_loops(mm.F, mm.n_vertices)[0]
    c = loop[[0, 10, 30, 50]]
    rep = tmp_path / "r.json"
    rc = main(["param", str(path), "-q", "--boundary", "rectangle", "--corners", ",".join(map(str, c)),
               "-o", str(tmp_path / "o.obj"), "--report", str(rep)])
    assert rc == 0 and capsys.readouterr().out == ""
    assert json.loads(rep.read_text())["corners"] == [int(x) for x in c]


def test_errors_leave_no_output(mesh_file, tmp_path, capsys):
    _, path = mesh_file
    out = tmp_path / "o.obj"
    # missing output folder: checked before the work
    rc = main(["param", str(path), "-o", str(out), "--report", str(tmp_path / "nope" / "r.json")])
    assert rc == 2 and "does not exist" in capsys.readouterr().err
    # corners not on the boundary: the message names them
    rc = main(["param", str(path), "--boundary", "rectangle", "--corners", "0,1,2,400", "-o", str(out),
               "--report", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "are not on the boundary loop" in err and err.count("\n") == 1
    # a negative id: given with "=" (without, argparse reads it as an option and says so)
    rc = main(["param", str(path), "--boundary", "rectangle", "--corners=-1,1,2,3", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "corner vertex id -1 is not in the mesh (ids 0.." in err and err.count("\n") == 1
    assert main(["param", str(path), "--boundary", "rectangle", "--corners", "-1,1,2,3", "-o", str(out)]) == 2
    assert "write --corners=-1,1,2,3" in capsys.readouterr().err
    # corners with the circle boundary
    rc = main(["param", str(path), "--corners", "0,1,2,3", "-o", str(out)])
    assert rc == 2 and "--corners needs --boundary rectangle" in capsys.readouterr().err
    # usage errors
    assert main(["param", str(path), "--weights", "tutte", "-o", str(out)]) == 2
    capsys.readouterr()
    assert main(["param", str(path), "--corners", "1,2", "-o", str(out)]) == 2
    err = capsys.readouterr().err  # one line, without argparse's usage lines
    assert err.splitlines() == ["conformill param: error: argument --corners: corners must be four vertex ids "
                                "i,j,k,l, got '1,2' (see conformill param --help)"]
    assert main(["param", str(path)]) == 2
    # same file twice
    rc = main(["param", str(path), "-o", str(out), "--report", str(out)])
    assert rc == 2 and "given for two outputs" in capsys.readouterr().err
    # a missing mesh
    assert main(["param", str(tmp_path / "none.ply"), "-o", str(out)]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["patch.ply"]
