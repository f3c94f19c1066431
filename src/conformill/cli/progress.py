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
        """Context in which log lines are written above the bar (``tqdm.write``) instead of
        into it; does nothing when the display is off."""
        if not self.enabled:
            return contextlib.nullcontext()
        from tqdm.contrib.logging import logging_redirect_tqdm

        return logging_redirect_tqdm(loggers=[logging.getLogger()])
