"""The C allocator's settings for a command's process (glibc only).

A plan allocates and frees arrays of a few MB to a few hundred MB all along (the map's
matrices, the pattern stage's samples, the cutter's batches). glibc serves every block
above its *mmap threshold* (128 kB at first, raised as blocks are freed, to 32 MB at
most) with a fresh ``mmap``, and returns freed memory to the system when more than the
*trim threshold* lies free at the top of its heap. Each block taken anew is zeroed page
by page by the kernel on first touch: at 620k faces (zigzag) that was 1.0-1.3 s of system
time and about 345k minor page faults in a 9 s command, while the process never held
more than about 1 GB.

:func:`tune_allocator` raises the mmap threshold to :data:`MMAP_THRESHOLD` and the trim
threshold to :data:`TRIM_THRESHOLD`, and grows the heap by :data:`TOP_PAD` at a time, so
that freed blocks are reused instead. The peak memory rises a little (the heap keeps
what it took); the programs are the same bytes. Session 57, ``benchmarks/bench_allocator.py``
(medians, alternating fresh processes): the 620k zigzag 8.55 s against 9.03 s (4 of 4
rounds quicker), system time 0.72 against 1.12 s, 213k against 343k faults, peak 1056
against 987 MB; igea zigzag ``--scan`` 6.29 against 6.38 s (6 of 6), peak 727 against
688 MB.

Freed memory is kept for reuse in the heaps of the worker threads too (the cutter's,
the pencil's, numba's), which glibc would otherwise give back when a thread's heap
empties: the peak above is measured with it.

Only the command line calls it (:func:`conformill.cli.main.main_exit`, which owns its
process); a program that imports conformill keeps its own settings. It does nothing where
the C library is not glibc, and nothing when the user set any of glibc's malloc settings
(``MALLOC_*`` variables or ``glibc.malloc`` tunables: those are left as given) or set
``CONFORMILL_MALLOC=default`` (glibc's own behaviour; ``benchmarks/bench_allocator.py``
compares the two).
"""

from __future__ import annotations

import os
import sys

__all__ = ["tune_allocator", "MMAP_THRESHOLD", "MMAP_THRESHOLD_CAPPED", "TRIM_THRESHOLD", "TOP_PAD", "OPT_OUT"]

#: Blocks below this (bytes) come from the heap, not from a fresh ``mmap``.
MMAP_THRESHOLD = 256 * 1024 * 1024
#: The mmap threshold tried when glibc refuses :data:`MMAP_THRESHOLD`: glibc releases
#: before 2.35 cap it at half their thread-heap size, 32 MiB on 64-bit systems.
MMAP_THRESHOLD_CAPPED = 32 * 1024 * 1024
#: Free memory at the heap's top kept up to this (bytes) before it is returned.
TRIM_THRESHOLD = 1024 * 1024 * 1024
#: Extra bytes taken from the system whenever the heap grows.
TOP_PAD = 64 * 1024 * 1024

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3

#: The environment variable that, set to ``default``, leaves the allocator as glibc has it.
OPT_OUT = "CONFORMILL_MALLOC"


def _user_set(environ) -> bool:
    """Whether the environment sets one of glibc's malloc parameters, or opts out."""
    if environ.get(OPT_OUT, "").strip().lower() == "default":
        return True
    if any(k.startswith("MALLOC_") for k in environ):
        return True
    return "glibc.malloc." in environ.get("GLIBC_TUNABLES", "")


def _glibc_mallopt():
    """glibc's ``mallopt(param, value) -> int`` through ctypes, or None (not glibc, no
    ctypes)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.gnu_get_libc_version  # glibc's own: musl also has a mallopt, which does nothing
        mallopt = libc.mallopt
        mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        mallopt.restype = ctypes.c_int
    except Exception:  # noqa: BLE001 - no ctypes, no such library or symbol: leave it
        return None
    return mallopt


def tune_allocator(environ=None, mallopt=None) -> bool:
    """Set glibc's mmap threshold, trim threshold and top pad for this process.

    The mmap threshold is set first: :data:`MMAP_THRESHOLD`, else
    :data:`MMAP_THRESHOLD_CAPPED`. When glibc refuses both, nothing is set (setting only
    the other two would turn off glibc's own rising threshold and leave it at 128 kB).

    Parameters
    ----------
    environ : mapping, optional
        The environment to read (default ``os.environ``).
    mallopt : callable, optional
        ``mallopt(param, value) -> int`` (1: accepted) to call instead of glibc's (tests).

    Returns
    -------
    bool
        Whether all three were set: False off Linux, without glibc, when the user set any
        malloc parameter or :data:`OPT_OUT`, or when glibc refused the mmap threshold
        (nothing is changed in these cases). Under an allocator loaded in glibc's place
        (``LD_PRELOAD`` of jemalloc, tcmalloc) the calls reach glibc's unused allocator:
        True, and nothing changes.
    """
    environ = os.environ if environ is None else environ
    if _user_set(environ):
        return False
    if mallopt is None:
        if not sys.platform.startswith("linux"):
            return False
        mallopt = _glibc_mallopt()
        if mallopt is None:
            return False
    if not any(mallopt(_M_MMAP_THRESHOLD, v) == 1 for v in (MMAP_THRESHOLD, MMAP_THRESHOLD_CAPPED)):
        return False
    ok = mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
    return mallopt(_M_TOP_PAD, TOP_PAD) == 1 and ok
