"""``conformill`` entry point: dispatches to one module per subcommand.

Each subcommand module defines ``add_arguments(parser)`` and ``run(args) -> int``.
Errors of type :class:`conformill.errors.ConformillError` become one line on stderr and
their exit code (2 bad input, 3 plan that cannot be met); no traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import re
import sys
import warnings

from conformill import __version__
from conformill.errors import ConformillError

#: subcommand -> (module, one-line help, the modules its work imports: numpy, scipy, numba,
#: trimesh and the stages, imported first by :func:`_import_work_modules`)
SUBCOMMANDS = {
    "param": ("conformill.cli.param", "conformal parameterization of a disk mesh",
              ("conformill.param", "conformill.mesh.io")),
    "plan": ("conformill.cli.plan", "plan a ball-end finishing program (G-code)",
             ("conformill.pipeline", "conformill.mesh.io", "conformill.output.gcode")),
    "verify": ("conformill.cli.verify", "simulate a G-code program on a mesh and check it",
               ("conformill.verify.simulate", "conformill.verify.gcode", "conformill.mesh.io")),
    "view": ("conformill.cli.view", "write a self-contained HTML 3D view of a mesh and program",
             ("conformill.output.viewer", "conformill.mesh.io")),
}


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors with exit code 2 (its default) on one line.

    argparse reads a word that starts with '-' as an option unless it is a plain negative
    number, so ``--corners -1,1,2,3`` or ``--stock -1e-3`` leave the option without its
    value: the error then says to write ``--corners=-1,1,2,3``.
    """

    def parse_known_args(self, args=None, namespace=None):
        self._words = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message):
        # argparse prints its usage lines first; one line says it, and where the options are
        hint = _dash_hint(message, getattr(self, "_words", []), self._option_string_actions)
        self.exit(2, f"{self.prog}: error: {message}{hint} (see {self.prog} --help)\n")


def _dash_hint(message: str, words: list, options=()) -> str:
    """For "argument --opt: expected one argument" where the word after the option starts
    with '-' and is not one of the parser's ``options`` (then the value is just missing):
    how to give it as the value (else "")."""
    m = re.fullmatch(r"argument (\S+): expected one argument", message)
    if not m:
        return ""
    names = m.group(1).split("/")
    for opt, nxt in zip(words, words[1:]):
        value_like = len(nxt) > 1 and nxt.startswith("-") and nxt.split("=")[0] not in options
        if opt in names and value_like:
            return f" ({nxt!r} starts with '-' and is read as an option: write {opt}={nxt})"
    return ""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="conformill", description="CNC finishing tool paths for triangle meshes from a conformal parameterization.")
    parser.add_argument("--version", action="version", version=f"conformill {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (modname, help_, _) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        p.add_argument("-q", "--quiet", action="store_true", help="no progress bars or summary")
        p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
        mod = importlib.import_module(modname)
        mod.add_arguments(p)
        p.set_defaults(_module=mod, _parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (never calls ``sys.exit``)."""
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # said by the command's own parser, which names its --help
            args._parser.error(f"unrecognized arguments: {' '.join(extra)}")
    except SystemExit as exc:  # argparse usage error or --help/--version
        return int(exc.code or 0)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="conformill: %(levelname)s: %(message)s",
    )
    with warnings.catch_warnings():
        # library warnings (RuntimeWarning from a fit, ...) become one log line each, without
        # the Python source line that warnings.showwarning would print
        warnings.simplefilter("default")
        warnings.showwarning = _show_warning
        return _run(args)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    logging.getLogger("conformill").warning("%s", message)


def _run(args) -> int:
    with _undo_on_termination():
        return _run_command(args)


@contextlib.contextmanager
def _undo_on_termination():
    """While the command runs, SIGTERM, SIGHUP and SIGINT (Ctrl-C) first undo its outputs as a
    failure would (:func:`conformill.output.atomic.undo_now`: the files it replaced are put
    back, its new and temporary files removed) and stop the warm-up helper, then end the
    process with 128 + the signal. Nothing is unwound: an exception raised in the main thread
    while a library's worker threads still read its arrays (scipy's k-d tree queries) crashed
    the process. A signal the process was told to ignore (``nohup``, a background job) stays
    ignored. The handlers are put back afterwards."""
    import signal

    old = {}
    try:
        for name in ("SIGTERM", "SIGHUP", "SIGINT"):
            sig = getattr(signal, name, None)
            if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
                old[sig] = signal.signal(sig, _terminate)
    except ValueError:  # not the main thread: signals cannot be handled here
        pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _terminate(signum, frame):
    import os

    from conformill import warm
    from conformill.output.atomic import undo_now

    undo_now()
    warm.stop()
    with contextlib.suppress(Exception):
        print("conformill: interrupted" if signum == 2 else "conformill: terminated", file=sys.stderr)
        sys.stderr.flush()
        sys.stdout.flush()
    os._exit(128 + signum)


def _run_command(args) -> int:
    try:
        return int(args._module.run(args))
    except ConformillError as exc:
        print(f"conformill {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("conformill: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        print(f"conformill {args.command}: error: out of memory", file=sys.stderr)
        return 2


def _import_work_modules(argv) -> None:
    """Import the modules the command named in ``argv`` works with, the cyclic garbage
    collector off meanwhile, then freeze what they made out of later collections.

    The imports make about 195k objects (numba's type system, scipy's functions), and
    with the collector on they spent 0.05-0.15 s of their 0.6-0.7 s in collections
    (session 57: ``import conformill.pipeline`` and the plan's modules, 0.71 / 0.72 / 0.73
    / 0.70 / 0.66 s against 0.60 / 0.56 / 0.59 / 0.54 / 0.53 s, alternating). The
    collector is on again for the work itself: a cold numba cache compiles with millions
    of objects in cycles, which it must free (a first plan of ``sample:face`` peaked at
    737 MB with the collector off throughout, 414 MB with it on: the session's review). A
    failed import is left to the command, which meets it again and reports it; Ctrl-C ends
    the process with 130, as during the command; ``--help``, ``--version`` and unknown
    commands import nothing here.
    """
    import gc

    words = [a for a in argv if not a.startswith("-")]
    asks_help = any(a in ("-h", "--help", "--version") for a in argv)
    modules = SUBCOMMANDS[words[0]][2] if words and words[0] in SUBCOMMANDS and not asks_help else ()
    if not modules:
        return
    gc.disable()
    try:
        for name in modules:
            importlib.import_module(name)
    except KeyboardInterrupt:  # Ctrl-C before the command started: as :func:`_run_command` says it
        print("conformill: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except Exception:  # noqa: BLE001 - the command imports it again and reports the error
        pass
    finally:
        gc.freeze()
        gc.enable()


def main_exit() -> None:  # console-script entry (and ``python -m conformill``)
    """Run :func:`main` and end the process with its exit code, without the interpreter's teardown.

    Python's teardown collects every object left (numba's type system, scipy's and the
    plan's): 0.2-0.35 s after a plan of the igea scan, where starting the command costs
    about 1 s. By then the command has closed every file it wrote (atomically), so the
    ``atexit`` handlers run (logging's flush, the warm-up helper's stop), stdout and
    stderr are flushed and the process ends with ``os._exit``. Where a thread other than the
    main one still runs, under a profiler or a tracer, or where a flush fails, the usual
    ``sys.exit`` ends it instead.

    The process is the command's, so before :func:`main` the C allocator is set to reuse
    freed memory (:func:`conformill.cli.allocator.tune_allocator`), part of its heap is
    written ahead by a helper thread (:class:`conformill.cli.allocator.HeapPrefault`) while
    the command's own heavy modules are imported with Python's cyclic garbage collector off
    (:func:`_import_work_modules`).
    """
    from conformill.cli.allocator import HeapPrefault, prefault_size, tune_allocator

    ahead = None
    if tune_allocator():  # reuse freed memory (cli/allocator.py), written ahead while importing
        ahead = HeapPrefault(prefault_size(sys.argv[1:]))
    _import_work_modules(sys.argv[1:])
    if ahead is not None:
        ahead.release()
    code = main()
    _exit_now(code)


def _exit_now(code: int) -> None:
    """``os._exit(code)`` after the ``atexit`` handlers and a flush of stdout and stderr
    (:func:`main_exit`); ``sys.exit(code)`` where another non-daemon thread runs, a profiler or
    a tracer is set, or a flush fails."""
    import atexit
    import os
    import threading

    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)  # (CPython's; elsewhere the usual exit)
    # under a profiler or a tracer (``python -m cProfile``, pyinstrument, coverage, a
    # debugger) the usual exit: they write their results after the code returns
    watched = sys.getprofile() is not None or sys.gettrace() is not None
    if others or run_exitfuncs is None or watched:
        sys.exit(code)
    run_exitfuncs()
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
    except (OSError, ValueError):  # a closed pipe or stream: let the interpreter report it
        sys.exit(code)
    os._exit(code)


if __name__ == "__main__":
    main_exit()
