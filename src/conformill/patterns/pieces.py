"""What a pattern hands to mapping: paths and links in machining order."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from conformill.types import DomainPath, DomainPaths


@dataclass(frozen=True, eq=False)
class Piece:
    """A path or a link between paths, cut in order.

    ``kind`` is "path" or "link". ``reverse`` walks the curve's samples backwards.
    ``index`` is the path number (for a link, the path it leaves).
    """

    kind: str
    curve: object = None
    reverse: bool = False
    index: int = -1


class PieceStream:
    """Pieces in machining order, each handed to ``emit`` (if given) as soon as it is final.

    For a family of paths linked one to the next (rings, rows), :meth:`on_curve` takes each
    curve as the planner finishes it: path ``i`` is final once path ``i + 1`` exists, so it
    is added then, with the link ``link(i, a, b)`` between them; :meth:`close` adds the
    last path. ``reverse(i)`` says whether path ``i`` is walked backwards.
    """

    def __init__(self, emit=None, link=None, reverse=None):
        self._emit = emit
        self._link = link
        self._reverse = reverse or (lambda i: False)
        self._curves = []

    def add(self, piece: Piece) -> None:
        if self._emit is not None:
            self._emit(piece)

    def _path(self, i: int) -> None:
        self.add(Piece("path", self._curves[i], self._reverse(i), i))

    def on_curve(self, curve) -> None:
        self._curves.append(curve)
        i = len(self._curves) - 2
        if i >= 0:
            self._path(i)
            self.add(Piece("link", self._link(i, self._curves[i], curve), False, i))

    def close(self) -> None:
        """Add the last path."""
        self._path(len(self._curves) - 1)


def _widening(c, predicted) -> float:
    """``DomainPath.widening`` of curve ``c`` with the side intervals ``predicted`` for the
    step taken to the next curve: the largest factor that step could be scaled by and stay
    within the interval allowed as spaced (``c.ls``) everywhere, over the same within the
    one allowed at the job's scallop (``c.ls_base``). 1.0 where they are the same."""
    if c.ls_base is c.ls:
        return 1.0
    ok = np.isfinite(predicted) & (predicted > 0) & (c.ls > 0) & (c.ls_base > 0)
    if not ok.any():
        return 1.0
    return float(np.min(c.ls[ok] / predicted[ok]) / np.min(c.ls_base[ok] / predicted[ok]))


def domain_paths(pattern: str, curves, realised, predicted, shrinks: int, closed: bool) -> DomainPaths:
    """Package planned curves with their side-interval figures for the report."""
    out = []
    for i, c in enumerate(curves):
        k = len(c.tau)
        out.append(
            DomainPath(
                uv=c.sample.uv,
                closed=closed,
                offset=float(c.s),
                side_allowed=c.ls,
                side_realised=realised[i] if i < len(realised) else np.full(k, np.nan),
                side_predicted=predicted[i] if i < len(predicted) else np.full(k, np.nan),
                widening=_widening(c, predicted[i]) if i < len(predicted) else 1.0,
            )
        )
    return DomainPaths(pattern=pattern, paths=out, shrink_iterations=int(shrinks))
