"""The HTML viewer: self-contained page, embedded data round trip, determinism, atomicity,
bad inputs, program splitting and the ``conformill view`` command."""

from __future__ import annotations

import base64
import re
from importlib import resources

import numpy as np
import pytest

from conformill.cli.main import main
from conformill.errors import OutputError
from conformill.mesh import synthetic
from conformill.output import viewer
from conformill.output.viewer import render_viewer, split_program, write_viewer

BLOB = re.compile(
    r'<script type="application/x-conformill" id="cm-(\w+)" data-dtype="(\w+)" data-shape="([\d,]*)">([A-Za-z0-9+/=]*)</script>'
)


def decode(page: str) -> dict:
    """The embedded arrays, decoded independently of the writer."""
    out = {}
    for key, dtype, shape, b64 in BLOB.findall(page):
        dt = {"float32": "<f4", "uint32": "<u4"}[dtype]
        arr = np.frombuffer(base64.b64decode(b64), dtype=dt)
        out[key] = arr.reshape(tuple(int(s) for s in shape.split(",")))
    return out


@pytest.fixture(scope="module")
def scene():
    mesh = synthetic.sphere_cap(R=50.0, radius_xy=30.0, spacing=4.0)
    V, F = mesh.V, mesh.F
    t = np.linspace(-25, 25, 40)
    passes = []
    for j, y in enumerate(np.linspace(-20, 20, 6)):
        x = t if j % 2 == 0 else t[::-1]
        p = np.column_stack([x, np.full_like(x, y), np.sqrt(50.0**2 - x**2 - y**2) - 50.0 + 0.01])
        passes.append(p)
    rapids = np.array([[[25, -20, 1], [25, -20, 20]], [[25, -20, 20], [-25, 20, 20]]], float)
    heat = np.abs(V[:, 0]) / 100.0
    heat[3] = np.nan
    return V, F, passes, rapids, heat


def test_page_is_self_contained(scene):
    V, F, passes, rapids, heat = scene
    page = render_viewer(V, F, passes, rapids, heat, title="cap", info={"tool": "ball R3"})
    assert page.startswith("<!DOCTYPE html>")
    # nothing is fetched: no external scripts, styles, images or module imports
    assert not re.search(r"""<(script|link|img|iframe)[^>]*\s(src|href)\s*=""", page, re.I)
    assert not re.search(r"""\b(src|href)\s*=\s*["']?(https?:)?//""", page, re.I)
    assert not re.search(r"""import[^;]*from\s*["'](https?:)?//""", page)
    assert not re.search(r"""import\s*\(\s*["'](https?:)?//""", page)
    assert "url(http" not in page
    # the vendored three.js bundle is inlined, its licence ships beside it
    three = resources.files("conformill.output").joinpath("assets", viewer.THREE_ASSET).read_text("utf-8")
    assert three in page
    assert "var THREE=" in three
    lic = resources.files("conformill.output").joinpath("assets", viewer.THREE_LICENSE).read_text("utf-8")
    assert "MIT License" in lic and "three.js authors" in lic
    # exactly one </script> per <script>: no data or library text closes an element early
    assert page.count("<script") == page.count("</script>")


def test_embedded_data_round_trip(scene):
    V, F, passes, rapids, heat = scene
    data = decode(render_viewer(V, F, passes, rapids, heat))
    assert set(data) == {"V", "F", "P", "PO", "R", "H"}
    np.testing.assert_array_equal(data["V"], V.astype(np.float32))
    np.testing.assert_array_equal(data["F"], F)
    P = np.concatenate(passes)
    np.testing.assert_array_equal(data["P"], P.astype(np.float32))
    np.testing.assert_array_equal(data["PO"], np.cumsum([0] + [len(p) for p in passes]))
    for i, p in enumerate(passes):  # each pass comes back whole and in order
        np.testing.assert_array_equal(data["P"][data["PO"][i]:data["PO"][i + 1]], p.astype(np.float32))
    np.testing.assert_array_equal(data["R"], rapids.astype(np.float32))
    np.testing.assert_array_equal(np.isnan(data["H"]), np.isnan(heat))
    ok = ~np.isnan(heat)
    np.testing.assert_array_equal(data["H"][ok], heat[ok].astype(np.float32))


def test_rapid_polylines_become_segments(scene):
    V, F, passes, _, _ = scene
    poly = np.array([[0, 0, 1], [0, 0, 10], [5, 5, 10], [5, 5, 2]], float)
    data = decode(render_viewer(V, F, passes, rapids=[poly]))
    np.testing.assert_array_equal(data["R"], np.stack([poly[:-1], poly[1:]], axis=1).astype(np.float32))
    np.testing.assert_array_equal(decode(render_viewer(V, F, passes, rapids=poly))["R"], data["R"])
    assert "H" not in decode(render_viewer(V, F, passes))
    empty = decode(render_viewer(V, F, []))
    assert empty["P"].shape == (0, 3) and empty["PO"].tolist() == [0] and empty["R"].shape == (0, 2, 3)


def test_summary_figures_and_escaping(scene):
    V, F, passes, rapids, _ = scene
    page = render_viewer(V, F, passes, rapids, title="<b>cap & co</b>", info={"<i>k</i>": "v<script>"})
    assert "<b>cap" not in page and "&lt;b&gt;cap &amp; co&lt;/b&gt;" in page
    assert "v<script>" not in page and "v&lt;script&gt;" in page
    feed = sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in passes)
    assert f"<th>feed length</th><td>{feed:.4g} mm</td>" in page
    rap = np.linalg.norm(rapids[:, 1] - rapids[:, 0], axis=1).sum()
    assert f"{rap:.4g} mm" in page
    assert f"<th>passes</th><td>{len(passes)} " in page


def test_deterministic_bytes(scene, tmp_path):
    V, F, passes, rapids, heat = scene
    a, b = tmp_path / "a.html", tmp_path / "b.html"
    write_viewer(a, V, F, passes, rapids, heat, title="t", info={"tool": "ball R3", "scallop": 0.01})
    write_viewer(b, V.copy(), F.astype(np.int32), [p.copy() for p in passes], list(rapids), heat.copy(),
                 title="t", info={"tool": "ball R3", "scallop": 0.01})
    assert a.read_bytes() == b.read_bytes()
    assert a.read_text("utf-8") == render_viewer(V, F, passes, rapids, heat, title="t",
                                                 info={"tool": "ball R3", "scallop": 0.01})


def test_inputs_not_mutated(scene):
    V, F, passes, rapids, heat = scene
    copies = [V.copy(), F.copy(), [p.copy() for p in passes], rapids.copy(), heat.copy()]
    render_viewer(V, F, passes, rapids, heat)
    np.testing.assert_array_equal(V, copies[0])
    np.testing.assert_array_equal(F, copies[1])
    for p, q in zip(passes, copies[2]):
        np.testing.assert_array_equal(p, q)
    np.testing.assert_array_equal(rapids, copies[3])
    np.testing.assert_array_equal(heat, copies[4])


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_no_file_on_bad_input(scene, tmp_path):
    V, F, passes, _, _ = scene
    out = tmp_path / "view.html"
    with pytest.raises(OutputError, match=r"passes\[1\] has shape \(5, 2\)"):
        write_viewer(out, V, F, [passes[0], np.zeros((5, 2))])
    assert _listing(tmp_path) == []


def test_no_partial_file_when_writing_fails(scene, tmp_path, monkeypatch):
    V, F, passes, _, _ = scene
    out = tmp_path / "view.html"
    out.write_text("old")

    import conformill.output.atomic as atomic

    real_open = open

    def failing_open(path, mode="r", *a, **k):
        fh = real_open(path, mode, *a, **k)
        if "w" in mode:
            fh.write("partial")
            fh.close()
            raise OSError(28, "No space left on device")
        return fh

    monkeypatch.setattr(atomic, "open", failing_open, raising=False)
    with pytest.raises(OutputError, match="No space left"):
        write_viewer(out, V, F, passes)
    assert out.read_text() == "old"  # the old file stands, no partial page, no temp file
    assert _listing(tmp_path) == ["view.html"]


def test_missing_folder(scene, tmp_path):
    V, F, passes, _, _ = scene
    with pytest.raises(OutputError, match="does not exist"):
        write_viewer(tmp_path / "nope" / "view.html", V, F, passes)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(V=np.zeros((4, 2))), r"V has shape \(4, 2\)"),
        (dict(V=np.zeros((2, 3))), "V has 2 points, expected at least 3"),
        (dict(V="abc"), "V is not numeric"),
        (dict(F=np.zeros((0, 3), int)), r"F has shape \(0, 3\)"),
        (dict(F=np.array([[0, 1, 99]])), r"F row 0 = \[0, 1, 99\] indexes outside"),
        (dict(F=np.array([[0, 1, -1]])), "indexes outside"),
        (dict(F=np.array([[0, 1, 2.5]])), "F has dtype float64, expected integers"),
        (dict(passes=[np.array([[0, 0, np.nan], [1, 1, 1]])]), r"passes\[0\] has non-finite coordinates at row 0"),
        (dict(passes=[np.zeros((0, 3))]), r"passes\[0\] has 0 points"),
        (dict(rapids=np.zeros((3, 3, 3))), r"rapids has shape \(3, 3, 3\)"),
        (dict(rapids=[np.zeros((1, 3))]), r"rapids\[0\] has 1 points, expected at least 2"),
        (dict(rapids=np.full((1, 2, 3), np.inf)), "rapids has non-finite"),
        (dict(heat=np.zeros(5)), "heat has 5 values for 4 vertices"),
        (dict(heat=np.full(4, np.nan)), "heat has no finite value"),
    ],
)
def test_bad_inputs(change, message):
    args = dict(V=np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]], float),
                F=np.array([[0, 1, 2], [1, 3, 2]]), passes=[np.zeros((2, 3))], rapids=None, heat=None)
    args.update(change)
    with pytest.raises(OutputError, match=message):
        render_viewer(args["V"], args["F"], args["passes"], rapids=args["rapids"], heat=args["heat"])


# --------------------------------------------------------------------------- split_program

def test_split_program_runs_and_rapids():
    start = np.array([0.0, 0.0, 50.0])
    pts = np.array([
        [0, 0, 5],    # 0 rapid down
        [0, 0, 0],    # 1 feed plunge
        [10, 0, 0],   # 2 feed
        [10, 0, 5],   # 3 rapid up
        [20, 0, 5],   # 4 rapid over
        [20, 0, 0],   # 5 feed
        [30, 0, 0],   # 6 feed
        [30, 5, 0],   # 7 feed
        [30, 5, 0],   # 8 rapid of zero length (dropped)
    ], float)
    motion = np.array([0, 1, 1, 0, 0, 1, 1, 1, 0], np.int8)
    passes, rapids = split_program(pts, motion, start)
    assert len(passes) == 2
    np.testing.assert_array_equal(passes[0], pts[[0, 1, 2]])  # starts where the run starts
    np.testing.assert_array_equal(passes[1], pts[[4, 5, 6, 7]])
    np.testing.assert_array_equal(rapids, np.stack([[start, pts[0]], [pts[2], pts[3]], [pts[3], pts[4]]]))
    # every feed move is in exactly one pass, every moving rapid in the segments
    assert sum(len(p) - 1 for p in passes) == int((motion == 1).sum())


def test_split_program_edges():
    pts = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    passes, rapids = split_program(pts, np.array([1, 1, 1]))  # no start: first move has no length
    assert len(passes) == 1 and rapids.shape == (0, 2, 3)
    np.testing.assert_array_equal(passes[0], pts[[0, 0, 1, 2]])
    passes, rapids = split_program(np.zeros((0, 3)), np.zeros(0))
    assert passes == [] and rapids.shape == (0, 2, 3)
    with pytest.raises(OutputError, match="3 points but 2 motion codes"):
        split_program(pts, [1, 1])


# --------------------------------------------------------------------------- CLI

GCODE = """%
G21 G90 G17
G0 X-20 Y-10 Z30
G0 Z1
G1 Z0 F1000
G1 X20
Y0
X-20
G0 Z30
G0 X0 Y10
G1 Z0
G1 X20
G0 Z30
M30
%
"""


@pytest.fixture()
def files(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh = synthetic.plane(size=60.0, spacing=5.0)
    stl = tmp_path / "plane.stl"
    trimesh.Trimesh(mesh.V, mesh.F, process=False).export(stl)
    nc = tmp_path / "prog.nc"
    nc.write_text(GCODE)
    return stl, nc


def test_cli_view(files, tmp_path):
    pytest.importorskip("conformill.verify.gcode")
    stl, nc = files
    out = tmp_path / "view.html"
    assert main(["view", str(stl), str(nc), "-o", str(out), "-q"]) == 0
    data = decode(out.read_text("utf-8"))
    # two feed runs: plunge + 3 moves, then plunge + 1 move
    assert data["PO"].tolist() == [0, 5, 8]
    np.testing.assert_array_equal(data["P"][:5], [[-20, -10, 1], [-20, -10, 0], [20, -10, 0], [20, 0, 0], [-20, 0, 0]])
    assert data["R"].shape == (4, 2, 3)  # Z1, Z30, X0Y10, Z30 (the first G0 defines the start)
    assert "H" not in data


def test_cli_view_heat(files, tmp_path):
    pytest.importorskip("conformill.verify.simulate")
    stl, nc = files
    out = tmp_path / "view.html"
    assert main(["view", str(stl), str(nc), "--tool-radius", "3", "-o", str(out), "-q"]) == 0
    data = decode(out.read_text("utf-8"))
    H = data["H"]
    assert H.shape == (len(data["V"]),)
    # plane z = 0, ball tip on it along y = -10 and y = 0 (x in [-20, 20]) and y = 10 (x in
    # [0, 20]): a vertex at distance d < r from the nearest line keeps r - sqrt(r^2 - d^2)
    V = data["V"].astype(float)
    r = 3.0
    d = np.minimum(np.abs(V[:, 1] + 10), np.abs(V[:, 1]))
    d = np.where(V[:, 0] >= 0, np.minimum(d, np.abs(V[:, 1] - 10)), d)
    inner = (np.abs(V[:, 0]) <= 17) & (d < r - 0.01) & ~((np.abs(V[:, 0]) < 3) & (V[:, 1] > 5))
    assert inner.sum() > 20
    np.testing.assert_allclose(H[inner], r - np.sqrt(r * r - d[inner] ** 2), atol=1e-5)
    assert np.isnan(H).any()  # far corners are not cut


def test_cli_view_errors(files, tmp_path, capsys):
    stl, nc = files
    assert main(["view", str(stl), str(nc), "-o", str(tmp_path / "no" / "v.html")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["view", str(stl), str(nc), "--tool-radius", "-1", "-o", str(tmp_path / "v.html")]) == 2
    assert "--tool-radius must be > 0" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "missing.stl"), "-o", str(tmp_path / "v.html")]) == 2
    assert not (tmp_path / "v.html").exists()
