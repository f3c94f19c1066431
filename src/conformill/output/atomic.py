"""Atomic file output: write to a temporary file beside the target, then rename.

A failed run therefore never leaves a partial output file. A run ended by a signal unwinds
no Python frames (worker threads may still be using their arrays), so what the active
blocks would undo on failure is also registered here, for :func:`undo_now` to do at once
(the command line's SIGTERM and SIGHUP handlers, ``conformill.cli.main``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from conformill.errors import OutputError

#: What the active blocks would undo on failure, innermost last (:func:`undo_now`).
_UNDO: list = []


def undo_now() -> None:
    """Undo at once what every active :func:`atomic_path` and :func:`all_or_nothing` would
    undo on failure (their temporary files, the files they replaced); for a process about
    to end without unwinding."""
    while _UNDO:
        with contextlib.suppress(Exception):
            _UNDO.pop()()


@contextlib.contextmanager
def _undo_on_signal(undo):
    _UNDO.append(undo)
    try:
        yield
    finally:
        with contextlib.suppress(ValueError):
            _UNDO.remove(undo)


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

    def drop_tmp():
        with contextlib.suppress(OSError):
            os.unlink(tmp)

    try:
        with _undo_on_signal(drop_tmp):
            yield Path(tmp)
        # mkstemp makes the file 0600; give it the permissions an ordinary open() would.
        umask = os.umask(0)
        os.umask(umask)
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        drop_tmp()
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
    a file that existed before is put back as it was. Until the block ends it is kept under
    a hidden name beside it: a hard link where the file system allows (it keeps the old
    contents because every writer replaces its file by a rename, :func:`atomic_path`), a
    copy otherwise; one that could be neither stays as the block left it.
    """
    before, kept = {}, {}

    def undo():
        for p, st in before.items():
            if _stamp(p) == st:
                continue
            old = kept.pop(p, None)
            with contextlib.suppress(OSError):
                if old is not None:
                    os.replace(old, p)
                elif st is None:  # new: removed
                    os.unlink(p)
                # (an old file that could not be kept stays replaced: removing it would lose both)
        _drop(kept)

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
        with _undo_on_signal(undo):
            yield
    except BaseException:
        undo()
        raise
    finally:
        _drop(kept)


def _keep(path: Path) -> str | None:
    """A hidden second name (or copy) of the existing file ``path`` beside it; ``None``
    when none can be made (the new file then stays on failure)."""
    folder = path.parent if str(path.parent) else Path(".")
    try:  # (the name's start only: the hidden name must fit where the file's own did)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:64]}.", suffix=".kept", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError:
        return None
    try:
        os.link(path, tmp)
    except OSError:
        try:
            shutil.copyfile(path, tmp)  # (the contents: a copy of the permissions may fail)
        except OSError:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            return None
    return tmp


def _drop(kept: dict) -> None:
    while kept:
        old = kept.popitem()[1]
        if old is not None:
            with contextlib.suppress(OSError):
                os.unlink(old)


def _stamp(p):
    try:
        s = os.stat(p)
        return (s.st_ino, s.st_mtime_ns, s.st_size)
    except OSError:
        return None
