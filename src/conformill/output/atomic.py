"""Atomic file output: write to a temporary file beside the target, then rename.

A failed run therefore never leaves a partial output file.
"""

from __future__ import annotations

import contextlib
import os
import shutil
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


def check_writable(*paths, inputs=()) -> None:
    """Fail early, before any work, when an output cannot be written: its folder does not
    exist, it is a folder, two outputs are the same file, or an output is one of the
    command's ``inputs`` (which it would overwrite). ``None`` entries are skipped.

    Raises
    ------
    OutputError
    """
    seen = {}
    for p in paths:
        if p is None:
            continue
        path = Path(p)
        folder = path.parent if str(path.parent) else Path(".")
        if not folder.is_dir():
            raise OutputError(f"cannot write {p}: folder {folder} does not exist")
        if path.is_dir():
            raise OutputError(f"cannot write {p}: it is a folder; give a file name")
        key = _same_file_key(path)
        if key in seen:
            raise OutputError(f"cannot write {p}: it is given for two outputs ({seen[key]} and {p}); give each its "
                              f"own file")
        seen[key] = p
    for q in inputs:
        if q is None or not Path(q).is_file():
            continue
        key = _same_file_key(Path(q))
        if key in seen:
            raise OutputError(f"cannot write {seen[key]}: it is the input {q}, which it would overwrite")


def _same_file_key(path: Path):
    """A key equal for two names of the same file: (device, inode) when it exists, else the
    absolute path with symbolic links resolved."""
    try:
        st = os.stat(path)
        return ("inode", st.st_dev, st.st_ino)
    except OSError:
        return ("path", str(path.resolve()))


@contextlib.contextmanager
def all_or_nothing(*paths):
    """Undo every file in ``paths`` written inside the block if the block fails.

    A command that writes several outputs (program, report, plot, viewer) leaves none of
    them behind when a later one cannot be made: a file that did not exist is removed, and
    a file that existed before is put back as it was (it is kept under a hidden name beside
    it, a hard link where the file system allows, a copy otherwise, until the block ends;
    a hard link keeps the old contents because every writer replaces its file by a rename,
    :func:`atomic_path`).
    """
    before, kept = {}, {}
    try:
        for p in paths:
            if p is None:
                continue
            before[str(p)] = _stamp(p)
            if before[str(p)] is not None:
                kept[str(p)] = _keep(Path(p))
    except BaseException:
        _drop(kept)
        raise
    try:
        yield
    except BaseException:
        for p, st in before.items():
            if _stamp(p) == st:
                continue
            old = kept.pop(p, None)
            with contextlib.suppress(OSError):
                if old is not None:
                    os.replace(old, p)
                else:
                    os.unlink(p)
        raise
    finally:
        _drop(kept)


def _keep(path: Path) -> str | None:
    """A hidden second name (or copy) of the existing file ``path`` beside it; ``None``
    when none can be made (the file is then removed on failure, as a new one is)."""
    folder = path.parent if str(path.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".kept", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError:
        return None
    try:
        os.link(path, tmp)
    except OSError:
        try:
            shutil.copy2(path, tmp)
        except OSError:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            return None
    return tmp


def _drop(kept: dict) -> None:
    for old in kept.values():
        if old is not None:
            with contextlib.suppress(OSError):
                os.unlink(old)


def _stamp(p):
    try:
        s = os.stat(p)
        return (s.st_ino, s.st_mtime_ns, s.st_size)
    except OSError:
        return None
