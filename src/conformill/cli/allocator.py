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

With the allocator tuned, :class:`HeapPrefault` has the pages of the main thread's heap
written before the plan needs them: the main thread takes blocks from its heap, a helper
thread writes them while the main thread imports the command's modules (which use one core
for about a second), and the blocks are freed before the command runs, to be reused from
the heap's top. The kernel's zeroing of those pages then falls on the idle core instead of
inside the plan. In ``plan`` the main thread takes about 60 % of the command's page faults
(igea contour ``--scan``: 83k of 139k, ``perf record -e page-faults``). The size follows
the part's file (:func:`prefault_size`): the file says little about the plan's memory, so a
guess too large costs memory (the blocks stay in the process), one too small costs time;
the programs are the same bytes either way. Session 62, alternating commands: igea contour
``--scan`` (368 MB ahead) 6.48-6.77 s against 6.70-6.84 s (5 of 5 pairs quicker), the peak
65 MB higher; the 620k zigzag (512 MB) 8.92-9.24 s against 9.05-9.56 s (2 of 3), the peak
the same.
"""

from __future__ import annotations

import os
import sys

__all__ = ["tune_allocator", "HeapPrefault", "prefault_size", "MMAP_THRESHOLD", "MMAP_THRESHOLD_CAPPED", "TRIM_THRESHOLD",
           "TOP_PAD", "OPT_OUT", "PREFAULT_BLOCK", "PREFAULT_PER_BYTE", "PREFAULT_MAX"]

#: Blocks below this (bytes) come from the heap, not from a fresh ``mmap``.
MMAP_THRESHOLD = 256 * 1024 * 1024
#: The mmap threshold tried when glibc refuses :data:`MMAP_THRESHOLD`: glibc releases
#: before 2.35 cap it at half their thread-heap size, 32 MiB on 64-bit systems.
MMAP_THRESHOLD_CAPPED = 32 * 1024 * 1024
#: Free memory at the heap's top kept up to this (bytes) before it is returned.
TRIM_THRESHOLD = 1024 * 1024 * 1024
#: Extra bytes taken from the system whenever the heap grows.
TOP_PAD = 64 * 1024 * 1024

#: Bytes of each block :class:`HeapPrefault` takes: below both mmap thresholds, so from the
#: heap (a block served by ``mmap`` would be unmapped again when freed).
PREFAULT_BLOCK = 16 * 1024 * 1024
#: Bytes written ahead per byte of the part's file, and at most (:func:`prefault_size`).
PREFAULT_PER_BYTE = 100
PREFAULT_MAX = 512 * 1024 * 1024
#: The mesh files :func:`prefault_size` reads the size of (those of
#: ``conformill.mesh.io.FORMATS``, which imports trimesh: not imported here).
_MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off")

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
        return _glibc().mallopt
    except Exception:  # noqa: BLE001 - no ctypes, no such library or symbol: leave it
        return None


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


def prefault_size(argv) -> int:
    """Bytes of heap to write ahead for the command ``argv`` (the words after the program's
    name): for ``plan``, :data:`PREFAULT_PER_BYTE` times the size of the part's file (the
    first word after the command that is ``sample:NAME`` or an existing mesh file), whole
    :data:`PREFAULT_BLOCK` blocks, at most :data:`PREFAULT_MAX`; 0 for any other command,
    ``--help``, or no such file."""
    words = list(argv)
    if not words or words[0] != "plan" or any(a in ("-h", "--help", "--version") for a in words):
        return 0
    size = 0
    for w in words[1:]:
        if w.startswith("-"):
            continue
        try:
            if w.startswith("sample:"):
                from conformill.data import sample_path

                size = sample_path(w[len("sample:"):]).stat().st_size
            elif w.lower().endswith(_MESH_SUFFIXES) and os.path.isfile(w):
                size = os.stat(w).st_size
            else:
                continue
        except Exception:  # noqa: BLE001 - not a part after all: the command reports it
            continue
        break
    n = min(PREFAULT_PER_BYTE * size, PREFAULT_MAX)
    return n - n % PREFAULT_BLOCK


class HeapPrefault:
    """``nbytes`` of the calling thread's heap (whole :data:`PREFAULT_BLOCK` blocks) taken
    now and written by a helper thread; :meth:`release` waits for it and frees the blocks.

    Nothing is taken (``blocks == 0``) for fewer than one block, where glibc's ``malloc``
    cannot be reached through ctypes, or when it refuses a block (those taken are freed).
    ``libc``: an object with ``malloc``, ``free`` and ``memset`` to use instead (tests).
    """

    def __init__(self, nbytes: int, libc=None):
        import threading

        self.blocks = []
        self._thread = None
        n = int(nbytes) // PREFAULT_BLOCK
        if n <= 0:
            return
        try:
            self._libc = libc if libc is not None else _glibc()
            for _ in range(n):
                p = self._libc.malloc(PREFAULT_BLOCK)
                if not p:
                    break
                self.blocks.append(p)
        except Exception:  # noqa: BLE001 - no ctypes or no such library: nothing ahead
            self.blocks = []
            return
        if len(self.blocks) < n:  # refused: give back what was taken
            self.release()
            return
        self._thread = threading.Thread(target=self._write, name="conformill-prefault", daemon=True)
        self._thread.start()

    def _write(self):
        for p in self.blocks:  # ctypes releases the GIL for each call
            self._libc.memset(p, 0, PREFAULT_BLOCK)

    def release(self) -> None:
        """Wait for the writes and free the blocks (last taken first: they join the heap's
        top again); harmless twice."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        while self.blocks:
            self._libc.free(self.blocks.pop())


def _glibc():
    """glibc through ctypes, its ``mallopt``, ``malloc``, ``free`` and ``memset`` typed
    (raises where ctypes, the library or one of them is absent)."""
    import ctypes

    libc = ctypes.CDLL(None)
    libc.gnu_get_libc_version  # glibc's own: musl also has a mallopt, which does nothing
    libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    libc.mallopt.restype = ctypes.c_int
    libc.malloc.argtypes = [ctypes.c_size_t]
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    libc.free.restype = None
    libc.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]
    libc.memset.restype = ctypes.c_void_p
    return libc
