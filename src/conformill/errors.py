"""Typed errors of conformill.

Every error raised on purpose by the library derives from :class:`ConformillError`.
Messages say *what* is wrong and *where* (vertex ids, boundary loops, line numbers), so
that the CLI can print them on one line. The CLI maps them to exit codes:
``exit_code`` 2 for bad input, 3 for a plan that cannot be met.
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


class OutputError(ConformillError):
    """An output file could not be written."""


class GCodeError(ConformillError, ValueError):
    """A G-code program cannot be read (names the line)."""
