"""Typed errors of conformill.

Every error raised on purpose by the library derives from :class:`ConformillError`.
Messages say *what* is wrong and *where* (vertex ids, boundary loops, line numbers), so
that the CLI can print them on one line. The CLI maps them to exit codes:
``exit_code`` 2 for bad input, 3 for a plan that cannot be met.

Which job checks give which code:

- 2 (:class:`JobValueError`): a value that is not a number, not finite, out of its own
  range (a radius, scallop, tolerance, feed or density <= 0, a settle or lift below 0, a
  stock at or below minus the tool radius, i.e. a ball of no size, a radius, scallop,
  chord tolerance or max-step below the program's 1e-4 mm resolution, a safe height beyond
  1e6 mm), an unknown word, a feed written ``F0``, a spindle below 1 rpm, options that need
  another (``pencil-left`` without the fold pencil), a tool radius (plus a stock) more than
  100 times the part's size (a mistake of units), a holder step no wider than the part of
  the holder below it (the holder described wrongly). The same mistake gets 2 from every
  command.
- 3 (:class:`PlanningError`): well-formed values that cannot be met together or on this
  part: a scallop at or above the tool radius, a blend larger than the tool radius, a
  safe height below the part, a program too large for the memory, a parameterization with
  flipped faces, a side step that collapses or too many paths, a holder not wider than
  the tool or one that meets the part at the stick-out given.

When an input holds mistakes of both kinds, exit code 2 wins for every mistake found
before planning: ``plan`` and ``verify`` check each value on its own, then read and check
the mesh and the program (the ball's size against the part's, the corner ids against the
mesh, a program that cuts nothing), and only then the values against each other (exit
code 3); the reads' warnings are printed once those checks pass. What only the work finds
(rectangle corners off the boundary, a safe height below the part, a program too large
for the memory, a side step that collapses) is found in the order the stages meet it.
"""

from __future__ import annotations


class ConformillError(Exception):
    """Base class of every error conformill raises on purpose."""

    exit_code = 2


class MeshError(ConformillError, ValueError):
    """The mesh cannot be read or is not a valid disk (what is wrong and where)."""


class ParameterizationError(ConformillError):
    """The parameterization failed (singular system, large residual, bad corners)."""


class PlanningError(ConformillError, ValueError):
    """The requested plan cannot be met (tool, tolerances, geometry)."""

    exit_code = 3


class JobValueError(PlanningError):
    """A job value is malformed: not a number, not finite, out of its own range, or an
    unknown word (exit code 2, bad input, as the same mistake gets from every command).

    A :class:`PlanningError`, so that callers catching that keep working; a job whose
    values are well formed but cannot be met raises :class:`PlanningError` itself (exit
    code 3).
    """

    exit_code = 2


class OutputError(ConformillError):
    """An output file could not be written."""


class GCodeError(ConformillError, ValueError):
    """A G-code program cannot be read (names the line)."""
