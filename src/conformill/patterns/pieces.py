"""What a pattern hands to mapping: paths and links in machining order."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from conformill.types import DomainPath, DomainPaths


@dataclass(frozen=True, eq=False)
class Piece:
    """A path or a link between paths, cut in order.

    ``kind`` is "path" or "link"; a ``None`` curve with kind "retract" separates passes.
    ``reverse`` walks the curve's samples backwards. ``index`` is the path number.
    """

    kind: str
    curve: object = None
    reverse: bool = False
    index: int = -1


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
            )
        )
    return DomainPaths(pattern=pattern, paths=out, shrink_iterations=int(shrinks))
