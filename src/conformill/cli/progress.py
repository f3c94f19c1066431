"""Progress display for long stages: a tqdm bar on a terminal, nothing otherwise."""

from __future__ import annotations

import contextlib
import logging
import sys


class StageProgress:
    """``progress(stage, fraction)`` callable drawing one tqdm bar per stage.

    Quiet when ``enabled`` is false or stderr is not a terminal.
    """

    def __init__(self, enabled: bool = True):
        self.enabled = enabled and sys.stderr.isatty()
        self.bar = None
        self.stage = None

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        if stage == "done":  # the end of the plan, not a stage to draw
            self.close()
            self.stage = None
            return
        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.stage = stage
            self.bar = tqdm(total=1000, desc=f"{stage:>12}", unit="", leave=False, file=sys.stderr,
                            bar_format="{desc} {percentage:3.0f}%|{bar}| {elapsed}")
        n = int(1000 * min(max(fraction, 0.0), 1.0))
        if self.bar is not None and n > self.bar.n:
            self.bar.update(n - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def logging(self):
        """Context in which log lines are written above the bar instead of into it
        (:func:`log_above_bars`); does nothing when the display is off."""
        return log_above_bars(self.enabled)


def log_above_bars(enabled: bool = True):
    """Context in which the root logger's console lines go through ``tqdm.write`` (above
    any bar, which is drawn again below them) instead of into a bar's line.

    Nothing changes when ``enabled`` is false or when no root handler writes to the
    console (stdout or stderr): tqdm's redirect would then add a console handler of its own.
    """
    root = logging.getLogger()
    console = any(isinstance(h, logging.StreamHandler) and h.stream in (sys.stdout, sys.stderr)
                  for h in root.handlers)
    if not (enabled and console):
        return contextlib.nullcontext()
    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm(loggers=[root])


class WarnOnce(logging.Filter):
    """Lets each warning (logger and text) through once: ``--replan``'s later plans of the
    same part repeat the first one's."""

    def __init__(self):
        super().__init__()
        self.seen = set()

    def filter(self, record) -> bool:
        if record.levelno < logging.WARNING:
            return True
        # decided once per record: every handler it passes through gets the same answer
        verdict = getattr(record, "_conformill_first", None)
        if verdict is None:
            key = (record.name, record.getMessage())
            verdict = key not in self.seen
            self.seen.add(key)
            record._conformill_first = verdict
        return verdict


@contextlib.contextmanager
def printed_through(flt):
    """Context in which ``flt`` (a :class:`logging.Filter`; None: nothing) filters what the
    root logger's handlers print, those in place on entry: inside :meth:`StageProgress.logging`
    that is the stand-in writing above the bar."""
    handlers = list(logging.getLogger().handlers) if flt is not None else []
    for hd in handlers:
        hd.addFilter(flt)
    try:
        yield
    finally:
        for hd in handlers:
            hd.removeFilter(flt)


@contextlib.contextmanager
def held_back():
    """Context in which the root logger's handlers print nothing: what they would have
    printed is printed on leaving normally, and dropped when the block raises, so that a
    refusal after a read that warned stays the one line it is."""
    held = []

    class _Hold(logging.Filter):
        def filter(self, record) -> bool:
            if not held or held[-1] is not record:  # once per record, whatever the handlers
                held.append(record)
            return False

    handlers = list(logging.getLogger().handlers)  # those printed_through filters
    with printed_through(_Hold()):
        yield
    for record in held:  # not reached when the block raised
        for hd in handlers:
            if record.levelno >= hd.level:
                hd.handle(record)


@contextlib.contextmanager
def sample_bar(total: int, desc: str, enabled: bool = True):
    """A bar of ``total`` samples on a terminal, log lines written above it; yields its
    ``update`` callable, or ``None`` when quiet or off a terminal."""
    if not (enabled and sys.stderr.isatty()):
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="samples", unit_scale=True, leave=False, file=sys.stderr)
    try:
        with log_above_bars():
            yield bar.update
    finally:
        bar.close()
