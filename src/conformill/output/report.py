"""JSON reports: deterministic (sorted keys, fixed float rounding), written atomically."""

from __future__ import annotations

import json
import math

import numpy as np

from conformill.output.atomic import write_text


def to_jsonable(obj, digits: int = 6):
    """Convert numpy scalars/arrays, tuples and non-finite floats to plain JSON values.

    Floats are rounded to ``digits`` significant digits so that reports are stable
    across runs; NaN and inf become ``None``.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, digits) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), digits)
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        if not math.isfinite(x):
            return None
        return float(f"{x:.{digits}g}")
    return obj


def dumps(report: dict) -> str:
    """The report as indented JSON text with sorted keys."""
    return json.dumps(to_jsonable(report), indent=2, sort_keys=True) + "\n"


def write_json(path, report: dict) -> None:
    """Write ``report`` to ``path`` atomically (see :func:`dumps`)."""
    write_text(path, dumps(report))
