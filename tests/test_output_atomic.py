"""Atomic outputs: a failed command leaves the files as they were, and bad output names are refused first."""

import os

import pytest

from conformill.errors import OutputError
from conformill.output.atomic import all_or_nothing, check_writable, write_text


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_failure_puts_back_the_old_files_and_removes_the_new(tmp_path):
    old, new, same = tmp_path / "old.nc", tmp_path / "new.json", tmp_path / "same.png"
    old.write_text("the old program\n")
    same.write_text("untouched\n")
    with pytest.raises(RuntimeError), all_or_nothing(old, new, same, None):
        write_text(old, "half of a new program\n")
        write_text(new, "{}\n")
        raise RuntimeError("a later output failed")
    assert old.read_text() == "the old program\n" and not new.exists() and same.read_text() == "untouched\n"
    assert _hidden(tmp_path) == []  # no kept copy or temporary file left


def test_success_keeps_the_new_files_and_no_copy(tmp_path):
    old = tmp_path / "old.nc"
    old.write_text("the old program\n")
    with all_or_nothing(old, tmp_path / "new.json"):
        write_text(old, "the new program\n")
        write_text(tmp_path / "new.json", "{}\n")
    assert old.read_text() == "the new program\n" and (tmp_path / "new.json").exists()
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("copy_fails", [False, True])
def test_where_links_fail_a_copy_keeps_the_old_file_and_without_one_nothing_is_deleted(tmp_path, monkeypatch,
                                                                                      copy_fails):
    import shutil

    old = tmp_path / "old.nc"
    old.write_text("the old program\n")

    def refuse(*a, **k):
        raise OSError("no")

    monkeypatch.setattr(os, "link", refuse)
    if copy_fails:
        monkeypatch.setattr(shutil, "copyfile", refuse)
    with pytest.raises(RuntimeError), all_or_nothing(old):
        with open(old, "w") as fh:  # in place, not by a rename: only a copy keeps the old contents
            fh.write("the new program\n")
        raise RuntimeError("failed")
    # with a copy the old file is put back; without one the new stays (deleting it would lose both)
    assert old.read_text() == ("the new program\n" if copy_fails else "the old program\n")
    assert _hidden(tmp_path) == []


def test_check_writable_refuses_folders_twins_and_inputs(tmp_path):
    mesh = tmp_path / "part.ply"
    mesh.write_text("ply\n")
    (tmp_path / "d").mkdir()
    (tmp_path / "sub").mkdir()
    check_writable(tmp_path / "a.nc", None, tmp_path / "r.json", inputs=(mesh, "sample:face", None))
    with pytest.raises(OutputError, match="it is a folder"):
        check_writable(tmp_path / "d")
    with pytest.raises(OutputError, match="missing does not exist"):
        check_writable(tmp_path / "missing" / "a.nc")
    with pytest.raises(OutputError, match="given for two outputs"):
        check_writable(tmp_path / "a.nc", tmp_path / "r.json", tmp_path / "sub" / ".." / "a.nc")
    with pytest.raises(OutputError, match="it is the input"):
        check_writable(tmp_path / "a.nc", mesh, inputs=(mesh,))
    link = tmp_path / "alias.ply"
    os.symlink(mesh, link)
    with pytest.raises(OutputError, match="it is the input"):  # another name of the same file
        check_writable(link, inputs=(mesh,))
    assert mesh.read_text() == "ply\n"


def test_a_long_name_is_kept_and_put_back(tmp_path):
    # the hidden name takes only the start of the file's: it fits wherever the file's own does
    old = tmp_path / ("a" * 238 + ".nc")
    old.write_text("the old program\n")
    with pytest.raises(RuntimeError), all_or_nothing(old):
        write_text(old, "the new program\n")
        raise RuntimeError("failed")
    assert old.read_text() == "the old program\n" and _hidden(tmp_path) == []


def test_sigterm_during_a_command_puts_back_the_old_file(tmp_path):
    # the command line's handler undoes the outputs at once and ends the process (nothing is
    # unwound: worker threads may still read the arrays); run in a process of its own
    import signal
    import subprocess
    import sys

    old = tmp_path / "old.nc"
    old.write_text("the old program\n")
    code = f"""
import os, signal, types
from conformill.cli.main import _run
from conformill.output.atomic import all_or_nothing, atomic_path, write_text

def run(args):
    with all_or_nothing({str(old)!r}, {str(tmp_path / "new.json")!r}):
        write_text({str(old)!r}, "half of a new program\\n")
        write_text({str(tmp_path / "new.json")!r}, "{{}}\\n")
        with atomic_path({str(tmp_path / "plot.png")!r}) as tmp:
            open(tmp, "w").write("a temporary file")
            os.kill(os.getpid(), signal.SIGTERM)
            raise AssertionError("not reached")

# as from a terminal (a background job of a script inherits SIGINT ignored, and stays so)
signal.signal(signal.SIGINT, signal.default_int_handler)
signal.signal(signal.SIGTERM, signal.SIG_DFL)
_run(types.SimpleNamespace(command="plan", _module=types.SimpleNamespace(run=run)))
"""
    for sig, word in (("SIGTERM", "terminated"), ("SIGINT", "interrupted")):
        r = subprocess.run([sys.executable, "-c", code.replace("signal.SIGTERM", f"signal.{sig}")],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 128 + getattr(signal, sig) and f"conformill: {word}" in r.stderr, r.stderr
        assert old.read_text() == "the old program\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["old.nc"]  # no new, temporary or kept file


def test_a_signal_told_to_be_ignored_stays_ignored():
    # nohup ignores SIGHUP: the command must not end on a hangup then
    import signal

    from conformill.cli.main import _undo_on_termination

    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with _undo_on_termination():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, before)
