"""OBJ writer: v in input order, vt = uv, f a/a b/b c/c; atomic."""

import numpy as np
import pytest

from conformill.errors import OutputError
from conformill.output.obj import format_obj, write_obj


def _parse(text):
    v, vt, f = [], [], []
    for line in text.splitlines():
        t = line.split()
        if not t or t[0] == "#":
            continue
        if t[0] == "v":
            v.append([float(x) for x in t[1:]])
        elif t[0] == "vt":
            vt.append([float(x) for x in t[1:]])
        elif t[0] == "f":
            a = [x.split("/") for x in t[1:]]
            assert all(p[0] == p[1] for p in a)
            f.append([int(p[0]) - 1 for p in a])
    return np.array(v), np.array(vt), np.array(f)


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    V = rng.normal(size=(50, 3)) * [100, 1, 1e-4]
    V[0] = [-0.0000004, 0.0, -123456.5]
    uv = rng.normal(size=(50, 2)) * 40
    F = rng.integers(0, 50, size=(80, 3))
    out = tmp_path / "m.obj"
    write_obj(out, V, F, uv, header="hello\nworld")
    text = out.read_text()
    assert text.startswith("# hello\n# world\n")
    v, vt, f = _parse(text)
    assert np.abs(v - V).max() <= 5e-7 and np.abs(vt - uv).max() <= 5e-7
    assert (f == F).all()
    assert "-0.000000" not in text  # no negative zero
    assert list(tmp_path.iterdir()) == [out]


def test_decimals_and_huge_values():
    V = np.array([[1.25, -2.5, 1e13], [0, 0, 0], [1, 1, 1]], dtype=float)
    uv = np.zeros((3, 2))
    text = format_obj(V, np.array([[0, 1, 2]]), uv, decimals=2).decode()
    assert "v 1.25 -2.50 10000000000000.00\n" in text
    assert text.endswith("f 1/1 2/2 3/3\n")


def test_errors(tmp_path):
    V = np.zeros((3, 3))
    with pytest.raises(OutputError, match="non-finite uv coordinates at vertices \\[1\\]"):
        write_obj(tmp_path / "a.obj", V, np.array([[0, 1, 2]]), np.array([[0, 0], [np.nan, 0], [1, 1]]))
    with pytest.raises(OutputError, match="outside 0..2"):
        write_obj(tmp_path / "a.obj", V, np.array([[0, 1, 3]]), np.zeros((3, 2)))
    with pytest.raises(OutputError, match="does not exist"):
        write_obj(tmp_path / "no" / "a.obj", V, np.array([[0, 1, 2]]), np.zeros((3, 2)))
    assert list(tmp_path.iterdir()) == []
