"""Atomic file output: write to a temporary file beside the target, then rename.

A failed run therefore never leaves a partial output file.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from conformill.errors import OutputError


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; rename it to ``path`` on success.

    Parameters
    ----------
    path : str or Path
        Final file name.
    suffix : str, optional
        Suffix for the temporary file (some writers pick the format from it);
        defaults to the target's suffix.

    Raises
    ------
    OutputError
        The folder does not exist or cannot be written.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"cannot write {path}: folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=folder)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp makes the file 0600; give it the permissions an ordinary open() would.
        umask = os.umask(0)
        os.umask(umask)
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8, ``\\n`` line ends)."""
    with atomic_path(path) as tmp:
        try:
            with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
                fh.write(text)
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None


def check_writable(*paths) -> None:
    """Fail early, before any work, when an output folder does not exist.

    Raises
    ------
    OutputError
    """
    for p in paths:
        if p is None:
            continue
        folder = Path(p).parent if str(Path(p).parent) else Path(".")
        if not folder.is_dir():
            raise OutputError(f"cannot write {p}: folder {folder} does not exist")


@contextlib.contextmanager
def all_or_nothing(*paths):
    """Remove every file in ``paths`` written inside the block if the block fails.

    A command that writes several outputs (program, report, plot, viewer) leaves none of
    them behind when a later one cannot be made. Files that existed before are left alone
    only if they were not replaced inside the block.
    """
    before = {str(p): _stamp(p) for p in paths if p is not None}
    try:
        yield
    except BaseException:
        for p, st in before.items():
            if _stamp(p) != st:
                with contextlib.suppress(OSError):
                    os.unlink(p)
        raise


def _stamp(p):
    try:
        s = os.stat(p)
        return (s.st_ino, s.st_mtime_ns, s.st_size)
    except OSError:
        return None
