"""The progress display: quiet off a terminal, one bar per stage on one, log lines above it."""

from __future__ import annotations

import io
import logging

from conformill.cli import progress as progress_mod
from conformill.cli.progress import StageProgress, held_back, log_above_bars


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _tty(monkeypatch):
    """stderr as a terminal. Set in the test itself: pytest's capture puts its own stderr
    back between a fixture's setup and the test."""
    out = _Tty()
    monkeypatch.setattr(progress_mod.sys, "stderr", out)
    return out


def test_quiet_off_a_terminal(monkeypatch):
    out = io.StringIO()
    monkeypatch.setattr(progress_mod.sys, "stderr", out)
    p = StageProgress()
    assert not p.enabled
    p("pattern", 0.5)
    with p.logging():
        logging.getLogger("conformill").warning("not redirected")
    p.close()
    assert out.getvalue() == ""


def test_quiet_when_asked(monkeypatch):
    tty = _tty(monkeypatch)
    p = StageProgress(enabled=False)
    p("pattern", 0.5)
    p.close()
    assert tty.getvalue() == ""


def test_a_bar_per_stage_and_none_for_done(monkeypatch):
    tty = _tty(monkeypatch)
    p = StageProgress()
    assert p.enabled
    p("pattern", 0.25)
    p("pattern", 0.75)
    first = p.bar
    p("cutter", 0.5)
    assert p.bar is not first and p.stage == "cutter" and p.bar.n == 500
    p("done", 1.0)  # the end of the plan: the bar goes, no new one
    assert p.bar is None and p.stage is None
    text = tty.getvalue()
    assert "pattern" in text and "cutter" in text and "done" not in text


def test_log_lines_are_written_above_the_bar(monkeypatch):
    tty = _tty(monkeypatch)
    root = logging.getLogger()
    handler = logging.StreamHandler(tty)  # what logging.basicConfig gives the CLI
    handler.setFormatter(logging.Formatter("conformill: %(levelname)s: %(message)s"))
    root.addHandler(handler)
    try:
        p = StageProgress()
        p("pattern", 0.5)
        with p.logging():
            assert handler not in root.handlers  # swapped for tqdm.write while the bar is up
            logging.getLogger("conformill").warning("a region the ball cannot reach")
        assert handler in root.handlers
        p.close()
    finally:
        root.removeHandler(handler)
    lines = tty.getvalue().replace("\r", "\n").split("\n")
    warn = [ln for ln in lines if "a region the ball cannot reach" in ln]
    assert warn == ["conformill: WARNING: a region the ball cannot reach"]


def test_the_plan_reports_its_stages_in_order():
    """plan(progress=...) names each stage once, in pipeline order, with fractions in
    [0, 1] that do not fall within a stage; the cutter's reaches 1 before 'done'."""
    from conformill.mesh import synthetic
    from conformill.pipeline import Job, plan

    seen = []
    part = synthetic.freeform_patch(spacing=2.0, jitter=0.3, seed=2)
    plan(part, Job(pattern="contour", tool_radius=4.0, scallop=0.05, tolerance=0.01),
         progress=lambda stage, f: seen.append((stage, f)))
    stages = [s for i, (s, _) in enumerate(seen) if i == 0 or seen[i - 1][0] != s]
    assert stages == ["parameterize", "frame", "pattern", "cutter", "done"]
    for stage in stages:
        f = [v for s, v in seen if s == stage]
        assert all(0.0 <= v <= 1.0 for v in f) and all(b >= a for a, b in zip(f, f[1:]))
    assert [v for s, v in seen if s == "cutter"][-1] == 1.0


def test_no_redirect_without_a_console_handler(monkeypatch):
    """A root logger that writes only to a file keeps its handlers: tqdm's redirect would
    add a console handler of its own."""
    tty = _tty(monkeypatch)
    root = logging.getLogger()
    saved = root.handlers[:]
    to_file = logging.StreamHandler(io.StringIO())  # not stdout or stderr
    root.handlers = [to_file]
    try:
        with log_above_bars(True):
            assert root.handlers == [to_file]
            logging.getLogger("conformill").warning("only to the file")
    finally:
        root.handlers = saved
    assert "only to the file" in to_file.stream.getvalue() and tty.getvalue() == ""


def test_held_back_prints_after_the_block_or_not_at_all():
    out = io.StringIO()
    hd = logging.StreamHandler(out)
    hd.setLevel(logging.WARNING)
    root = logging.getLogger()
    root.addHandler(hd)
    log = logging.getLogger("conformill.test_held")
    try:
        with held_back():
            log.warning("first")
            log.info("below the handler's level")
            assert out.getvalue() == ""  # held while the block runs
            log.warning("second")
        assert out.getvalue() == "first\nsecond\n"  # then printed once each, in order
        out.truncate(0)
        out.seek(0)
        try:
            with held_back():
                log.warning("dropped")
                raise ValueError("refused")
        except ValueError:
            pass
        log.warning("after")
        assert out.getvalue() == "after\n"  # the refusal's block printed nothing; the filter is gone
        assert not hd.filters
    finally:
        root.removeHandler(hd)
