"""The command's allocator settings (:mod:`conformill.cli.allocator`): set on glibc, left
alone when the user set malloc parameters, and they make a freed block reused (no new page
faults) where glibc would map a fresh one. Each case runs in its own process: the settings
are process-wide."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from conformill.cli.allocator import MMAP_THRESHOLD, _user_set

_GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
needs_glibc = pytest.mark.skipif(not _GLIBC, reason="glibc only")

#: In a child: tune (or not), then take a block, touch it, free it, take and touch one of the
#: same size again; prints whether the tuning took and the minor page faults of the second round.
_CHILD = """
import ctypes, resource, sys
from conformill.cli.allocator import tune_allocator
ok = tune_allocator() if sys.argv[1] == "tune" else None
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
n = int(sys.argv[2])
def touch():
    p = libc.malloc(n)
    ctypes.memset(p, 1, n)
    return p
libc.free(touch())
f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
p = touch()
f1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
libc.free(p)
print(ok, f1 - f0)
"""


def _child(mode: str, nbytes: int, **env) -> tuple[str, int]:
    e = {k: v for k, v in os.environ.items()
         if not k.startswith("MALLOC_") and k not in ("GLIBC_TUNABLES", "CONFORMILL_MALLOC")}
    e.update(env)
    p = subprocess.run([sys.executable, "-c", _CHILD, mode, str(nbytes)], capture_output=True, text=True,
                       timeout=120, env=e)
    assert p.returncode == 0, p.stderr
    ok, faults = p.stdout.split()
    return ok, int(faults)


@needs_glibc
def test_a_freed_block_is_reused_instead_of_mapped_again():
    n = 64 * 1024 * 1024  # above glibc's largest dynamic mmap threshold (32 MB), below ours
    assert n < MMAP_THRESHOLD
    pages = n // os.sysconf("SC_PAGE_SIZE")
    ok, faults_tuned = _child("tune", n)
    assert ok == "True"
    _, faults_plain = _child("plain", n)
    # glibc's default maps the second block afresh: every page faults again when touched
    assert faults_plain > 0.9 * pages
    # tuned, the freed block is taken again from the heap: already touched
    assert faults_tuned < 0.01 * pages


@needs_glibc
@pytest.mark.parametrize("env", [{"MALLOC_ARENA_MAX": "8"}, {"MALLOC_TOP_PAD_": "131072"},
                                 {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=65536"},
                                 {"MALLOC_MMAP_THRESHOLD_": "65536"}, {"CONFORMILL_MALLOC": "default"}])
def test_the_users_malloc_settings_are_left_as_given(env):
    n = 64 * 1024 * 1024
    ok, faults = _child("tune", n, **env)
    assert ok == "False"
    assert faults > 0.9 * n // os.sysconf("SC_PAGE_SIZE")  # glibc's (or the user's) behaviour


def test_which_environments_count_as_set_by_the_user():
    assert not _user_set({})
    assert not _user_set({"MALLOC": "1", "GLIBC_TUNABLES": "glibc.rtld.optional_static_tls=1000", "PATH": "/bin"})
    assert _user_set({"MALLOC_TRIM_THRESHOLD_": "0"})
    assert _user_set({"MALLOC_CHECK_": "3"})
    assert _user_set({"MALLOC_ARENA_MAX": "2"})
    assert _user_set({"CONFORMILL_MALLOC": "default"})
    assert not _user_set({"CONFORMILL_MALLOC": "tuned"})
    assert _user_set({"GLIBC_TUNABLES": "glibc.rtld.nns=2:glibc.malloc.hugetlb=1"})


def test_the_command_line_sets_up_its_process_before_main(monkeypatch):
    import gc

    import conformill.cli.allocator as alloc
    import conformill.cli.main as cli

    calls = []
    monkeypatch.setattr(alloc, "tune_allocator", lambda: calls.append("tuned") or True)
    monkeypatch.setattr(cli, "main", lambda: calls.append("main") or 0)
    monkeypatch.setattr(cli, "_exit_now", lambda code: calls.append(("exit", code)))
    monkeypatch.setattr(gc, "disable", lambda: calls.append("no gc"))
    cli.main_exit()
    assert calls == ["no gc", "tuned", "main", ("exit", 0)]
