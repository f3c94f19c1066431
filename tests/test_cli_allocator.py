"""The command's process set-up (:mod:`conformill.cli.allocator`,
:func:`conformill.cli.main.main_exit`): glibc's allocator set to reuse freed blocks, left
alone when the user set malloc parameters, nothing set when glibc refuses the mmap
threshold; the command's modules imported with the cyclic collector off, which is on
again afterwards; :func:`conformill.cli.main.main` (what tests and programs call) changes
none of it. The allocator cases that touch glibc run in their own processes: its settings
are process-wide."""

from __future__ import annotations

import gc
import os
import platform
import subprocess
import sys

import pytest

from conformill.cli import allocator as alloc
from conformill.cli.allocator import (MMAP_THRESHOLD, MMAP_THRESHOLD_CAPPED, PREFAULT_BLOCK, PREFAULT_MAX,
                                      PREFAULT_PER_BYTE, TOP_PAD, TRIM_THRESHOLD, HeapPrefault, _user_set,
                                      prefault_size, tune_allocator)

_GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
needs_glibc = pytest.mark.skipif(not _GLIBC, reason="glibc only")

#: In a child: tune (or not), take a block of argv[2] bytes and print whether the tuning
#: took and how many chunks glibc holds as separate mmaps (mallinfo2's ``hblks``: what the
#: mmap threshold decides, whatever the kernel's huge pages do to page faults), then free
#: it, take a block of argv[3] bytes and print hblks again.
#: A child's start: ctypes, glibc and its ``mallinfo2`` (the heap's figures).
_MALLINFO = """
import ctypes, sys
class Info(ctypes.Structure):
    _fields_ = [(f, ctypes.c_size_t) for f in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks",
                 "keepcost")]
libc = ctypes.CDLL(None)
libc.mallinfo2.restype = Info
"""
_CHILD = _MALLINFO + """
from conformill.cli.allocator import tune_allocator
ok = tune_allocator() if sys.argv[1] == "tune" else None
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
out = [str(ok)]
for n in (int(sys.argv[2]), int(sys.argv[3])):
    base = libc.mallinfo2().hblks
    p = libc.malloc(n)
    ctypes.memset(p, 1, n)
    out.append(str(libc.mallinfo2().hblks - base))
    libc.free(p)
print(" ".join(out))
"""


def _run_child(code: str, *args, **env) -> list:
    """Run ``code`` in a child without the user's malloc settings (and with ``env``); its
    printed words (skips where glibc has no ``mallinfo2``)."""
    e = {k: v for k, v in os.environ.items()
         if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "CONFORMILL_MALLOC", "LD_PRELOAD")}
    e.update(env)
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, timeout=120,
                       env=e)
    if p.returncode != 0 and "mallinfo2" in p.stderr:
        pytest.skip("glibc without mallinfo2 (before 2.33)")
    assert p.returncode == 0, p.stderr
    return p.stdout.split()


def _child(mode: str, first: int, second: int = 0, **env) -> list:
    return _run_child(_CHILD, mode, first, second or first, **env)


MB = 1024 * 1024


def test_the_settings_fit_mallopts_int():
    for v in (MMAP_THRESHOLD, MMAP_THRESHOLD_CAPPED, TRIM_THRESHOLD, TOP_PAD):
        assert 0 < v <= 2**31 - 1
    assert MMAP_THRESHOLD_CAPPED <= 32 * MB < MMAP_THRESHOLD  # what glibc before 2.35 accepts
    assert TOP_PAD < 128 * MB < MMAP_THRESHOLD  # room for the block size the tests below use


@needs_glibc
def test_blocks_below_the_threshold_come_from_the_heap():
    # 128 MB: above glibc's own largest threshold (32 MB) and above the top pad, below ours
    ok, first, again = _child("tune", 128 * MB)
    assert ok == "True"
    assert (first, again) == ("0", "0")
    _, first, again = _child("plain", 128 * MB)
    assert (first, again) == ("1", "1")  # glibc's default maps such a block afresh, every time


@needs_glibc
@pytest.mark.parametrize("env", [{"MALLOC_ARENA_MAX": "8"}, {"MALLOC_TOP_PAD_": "131072"},
                                 {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=65536"},
                                 {"MALLOC_MMAP_THRESHOLD_": "65536"}, {"CONFORMILL_MALLOC": "default"},
                                 {"CONFORMILL_MALLOC": " Default "}])
def test_the_users_malloc_settings_are_left_as_given(env):
    ok, first, _ = _child("tune", 128 * MB, **env)
    assert ok == "False"
    assert first == "1"  # glibc's (or the user's) threshold: the block is mapped


class _FakeMallopt:
    """glibc's mallopt as a recorder: accepts what ``accept(param, value)`` says."""

    def __init__(self, accept):
        self.accept, self.calls = accept, []

    def __call__(self, param, value):
        self.calls.append((param, value))
        return 1 if self.accept(param, value) else 0


def test_all_three_are_set_mmap_threshold_first():
    f = _FakeMallopt(lambda p, v: True)
    assert tune_allocator({}, mallopt=f)
    assert f.calls == [(-3, MMAP_THRESHOLD), (-1, TRIM_THRESHOLD), (-2, TOP_PAD)]


def test_a_capped_glibc_gets_the_capped_threshold():
    f = _FakeMallopt(lambda p, v: not (p == -3 and v > 32 * MB))
    assert tune_allocator({}, mallopt=f)
    assert f.calls == [(-3, MMAP_THRESHOLD), (-3, MMAP_THRESHOLD_CAPPED), (-1, TRIM_THRESHOLD), (-2, TOP_PAD)]


def test_nothing_else_is_set_when_the_mmap_threshold_is_refused():
    # the trim threshold or the top pad alone would stop glibc's own threshold from rising
    f = _FakeMallopt(lambda p, v: p != -3)
    assert not tune_allocator({}, mallopt=f)
    assert all(p == -3 for p, _ in f.calls)


def test_no_glibc_no_ctypes_or_another_system_changes_nothing(monkeypatch):
    monkeypatch.setattr(alloc, "_glibc_mallopt", lambda: None)
    assert not tune_allocator({})
    monkeypatch.setattr(alloc.sys, "platform", "darwin")
    monkeypatch.setattr(alloc, "_glibc_mallopt", lambda: pytest.fail("looked for glibc off Linux"))
    assert not tune_allocator({})
    monkeypatch.undo()
    monkeypatch.setitem(sys.modules, "ctypes", None)  # a Python built without ctypes
    assert alloc._glibc_mallopt() is None


def test_which_environments_count_as_set_by_the_user():
    assert not _user_set({})
    assert not _user_set({"MALLOC": "1", "GLIBC_TUNABLES": "glibc.rtld.optional_static_tls=1000", "PATH": "/bin"})
    assert _user_set({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert _user_set({"MALLOC_CHECK_": "3"})
    assert _user_set({"MALLOC_ARENA_MAX": "2"})
    assert _user_set({"GLIBC_TUNABLES": "glibc.rtld.nns=2:glibc.malloc.hugetlb=1"})
    assert _user_set({"CONFORMILL_MALLOC": "default"}) and _user_set({"CONFORMILL_MALLOC": "DEFAULT\n"})
    assert not _user_set({"CONFORMILL_MALLOC": "tuned"})


def test_the_command_line_sets_up_its_process_before_main(monkeypatch):
    import conformill.cli.main as cli

    calls = []
    monkeypatch.setattr(alloc, "tune_allocator", lambda: calls.append("tuned") or True)
    monkeypatch.setattr(cli, "_import_work_modules", lambda argv: calls.append(("imports", argv)))
    monkeypatch.setattr(cli, "main", lambda: calls.append("main") or 0)
    monkeypatch.setattr(cli, "_exit_now", lambda code: calls.append(("exit", code)))
    monkeypatch.setattr(sys, "argv", ["conformill", "plan", "part.ply"])
    cli.main_exit()
    assert calls == ["tuned", ("imports", ["plan", "part.ply"]), "main", ("exit", 0)]


@pytest.mark.parametrize("tuned", [True, False])
def test_the_heap_is_written_ahead_while_the_modules_import(monkeypatch, tuned):
    import conformill.cli.main as cli

    calls = []

    class Ahead:
        def __init__(self, n):
            calls.append(("ahead", n))

        def release(self):
            calls.append("released")

    monkeypatch.setattr(alloc, "tune_allocator", lambda: calls.append("tuned") or tuned)
    monkeypatch.setattr(alloc, "prefault_size", lambda argv: 7 * len(argv))
    monkeypatch.setattr(alloc, "HeapPrefault", Ahead)
    monkeypatch.setattr(cli, "_import_work_modules", lambda argv: calls.append("imports"))
    monkeypatch.setattr(cli, "main", lambda: calls.append("main") or 0)
    monkeypatch.setattr(cli, "_exit_now", lambda code: calls.append(("exit", code)))
    monkeypatch.setattr(sys, "argv", ["conformill", "plan", "part.ply"])
    cli.main_exit()
    # only on a tuned allocator (else freed blocks may go back to the system at once)
    want = ["tuned", ("ahead", 14), "imports", "released"] if tuned else ["tuned", "imports"]
    assert calls == want + ["main", ("exit", 0)]


def test_the_size_written_ahead_follows_the_parts_file(tmp_path):
    from conformill.data import sample_path

    def part(name, nbytes):
        f = tmp_path / name
        f.write_bytes(b"\0" * nbytes)
        return str(f)

    mid = part("mid.ply", 3_000_000)
    want = PREFAULT_PER_BYTE * 3_000_000
    want -= want % PREFAULT_BLOCK
    assert 0 < want < PREFAULT_MAX and want % PREFAULT_BLOCK == 0
    assert prefault_size(["plan", mid, "--scan"]) == want
    # options before the part, an existing output file (not a mesh) before it
    out = part("old.nc", 9_000_000)
    assert prefault_size(["plan", "--scan", "-o", out, "--tool-radius", "4", mid]) == want
    assert prefault_size(["plan", part("big.STL", 50_000_000)]) == PREFAULT_MAX
    assert prefault_size(["plan", part("tiny.obj", 1000)]) == 0  # less than a block
    face = PREFAULT_PER_BYTE * sample_path("face").stat().st_size
    assert prefault_size(["plan", "sample:face"]) == face - face % PREFAULT_BLOCK
    for argv in (["plan", str(tmp_path / "absent.ply")], ["plan", "sample:nope"], ["verify", mid, out],
                 ["plan", mid, "--help"], ["plan"], []):
        assert prefault_size(argv) == 0, argv


class _FakeLibc:
    def __init__(self, refuse_at=None):
        self.calls, self.next, self.refuse_at = [], 0, refuse_at

    def malloc(self, n):
        self.next += 1
        self.calls.append(("malloc", n))
        return 0 if self.next == self.refuse_at else 1000 * self.next

    def memset(self, p, v, n):
        self.calls.append(("memset", p, v, n))

    def free(self, p):
        self.calls.append(("free", p))


def test_heap_prefault_takes_writes_and_frees_whole_blocks():
    libc = _FakeLibc()
    ahead = HeapPrefault(3 * PREFAULT_BLOCK + 5, libc=libc)
    assert len(ahead.blocks) == 3
    ahead.release()
    ahead.release()  # harmless twice
    B = PREFAULT_BLOCK
    assert libc.calls == ([("malloc", B)] * 3 + [("memset", p, 0, B) for p in (1000, 2000, 3000)]
                          + [("free", p) for p in (3000, 2000, 1000)])  # the last taken first
    assert HeapPrefault(B - 1, libc=libc).blocks == []


def test_heap_prefault_gives_back_what_it_took_when_refused():
    libc = _FakeLibc(refuse_at=3)
    ahead = HeapPrefault(4 * PREFAULT_BLOCK, libc=libc)
    assert ahead.blocks == [] and ahead._thread is None
    assert libc.calls == [("malloc", PREFAULT_BLOCK)] * 3 + [("free", 2000), ("free", 1000)]
    ahead.release()


@needs_glibc
def test_the_blocks_written_ahead_stay_in_the_heap_for_reuse():
    # in a child (glibc's settings are process-wide): tuned, 64 MB written ahead and freed
    # stay in the heap as free memory (fordblks), none of it in separate mmaps (hblks)
    code = _MALLINFO + """
from conformill.cli.allocator import HeapPrefault, tune_allocator
assert tune_allocator()
before = libc.mallinfo2()
ahead = HeapPrefault(64 << 20)
n = len(ahead.blocks)
ahead.release()
after = libc.mallinfo2()
print(n, after.hblks - before.hblks, (after.fordblks - before.fordblks) >> 20)
"""
    n, hblks, free_mb = (int(v) for v in _run_child(code))
    assert n == (64 << 20) // PREFAULT_BLOCK and hblks <= 0 and free_mb >= 64  # (another chunk may be unmapped)


def test_main_itself_changes_neither(monkeypatch, capsys):
    import conformill.cli.main as cli

    monkeypatch.setattr(alloc, "tune_allocator", lambda *a, **k: pytest.fail("main tuned the allocator"))
    monkeypatch.setattr(gc, "disable", lambda: pytest.fail("main turned the collector off"))
    monkeypatch.setattr(gc, "freeze", lambda: pytest.fail("main froze objects"))
    assert cli.main(["--version"]) == 0
    assert "conformill" in capsys.readouterr().out


@pytest.mark.parametrize(("argv", "wanted"), [(["plan", "part.ply", "--scan"], "conformill.pipeline"),
                                              (["verify", "part.ply", "p.nc"], "conformill.verify.simulate"),
                                              (["plan", "--help"], None), (["--version"], None), ([], None),
                                              (["bogus", "x"], None)])
def test_the_commands_modules_are_imported_with_the_collector_off(monkeypatch, argv, wanted):
    import conformill.cli.main as cli

    seen = []
    monkeypatch.setattr(cli.importlib, "import_module", lambda name: seen.append((name, gc.isenabled())))
    froze = []
    monkeypatch.setattr(gc, "freeze", lambda: froze.append(gc.isenabled()))
    assert gc.isenabled()
    cli._import_work_modules(argv)
    assert gc.isenabled()  # on again for the work (a cold cache compiles with millions of cycles)
    if wanted is None:
        assert seen == [] and froze == []
    else:
        assert (wanted, False) in seen and all(not on for _, on in seen)
        assert froze == [False]


def test_a_failing_import_is_left_to_the_command(monkeypatch):
    import conformill.cli.main as cli

    def boom(name):
        raise ImportError(f"no module {name}")

    monkeypatch.setattr(cli.importlib, "import_module", boom)
    monkeypatch.setattr(gc, "freeze", lambda: None)
    cli._import_work_modules(["plan", "part.ply"])
    assert gc.isenabled()


def test_ctrl_c_during_the_imports_ends_with_130_and_no_traceback(monkeypatch, capsys):
    import conformill.cli.main as cli

    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    monkeypatch.setattr(gc, "freeze", lambda: None)
    with pytest.raises(SystemExit) as exc:
        cli._import_work_modules(["plan", "part.ply"])
    assert exc.value.code == 130
    assert gc.isenabled()
    assert capsys.readouterr().err.strip() == "conformill: interrupted"


def test_every_commands_work_modules_exist():
    # a misspelt name would be skipped without a word (the command reports its own imports)
    import importlib

    import conformill.cli.main as cli

    for name, (_, _, modules) in cli.SUBCOMMANDS.items():
        assert modules, name
        for m in modules:
            importlib.import_module(m)
