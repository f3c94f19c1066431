"""`conformill param BAD -o out.obj`: exit code 2, one line on stderr naming the problem,
no traceback, no output file. The bad files are those of tests/test_mesh_io.py."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from test_mesh_io import bad_files  # noqa: E402

from conformill.cli.main import main  # noqa: E402

def _names():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return sorted(bad_files(Path(d)))


@pytest.mark.parametrize("case", _names())
def test_param_rejects_bad_mesh(tmp_path, capsys, case):
    path, needles = bad_files(tmp_path)[case]
    out = tmp_path / "out.obj"
    rc = main(["param", str(path), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for s in needles:
        assert s in lines[0], (s, lines[0])
    assert not out.exists()


def test_param_rejects_unknown_sample(tmp_path, capsys):
    out = tmp_path / "out.obj"
    rc = main(["param", "sample:nose", "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "unknown sample" in err and "face" in err
    assert not out.exists()
