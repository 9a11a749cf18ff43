"""How veil writes numbers: in reports and tables (:func:`format_number`,
:func:`format_percent`) and in JSON files (:func:`json_float`, :func:`json_clean`:
non-finite numbers never reach a file, they become null; a result file's are read back by
:func:`veil.fitting.result_fields.read_number`)."""

from __future__ import annotations

import math
from typing import Any


def format_number(x, digits: int = 6, missing: str = "n/a") -> str:
    """``x`` to ``digits`` significant digits; ``missing`` for None or a non-finite number."""
    if x is None:
        return missing
    x = float(x)
    if not math.isfinite(x):
        return missing
    return f"{x:.{digits}g}"


def format_exact(x) -> str:
    """``x`` as the shortest text that reads back as the same float (its repr, "30" for
    30.0): a value echoed in a message, which must not round into another (179.9999 is not
    180)."""
    text = repr(float(x))
    return text[:-2] if text.endswith(".0") else text


def format_percent(x, digits: int = 3, missing: str = "-") -> str:
    """A fraction ``x`` as a percentage, e.g. 0.0123 -> "1.23 %"."""
    if x is None or not math.isfinite(float(x)):
        return missing
    return f"{100 * float(x):.{digits}g} %"


def json_float(x) -> float | None:
    """A number for a JSON file: float, or None (null) when missing or not finite."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def json_clean(obj) -> Any:
    """``obj`` with every non-finite float (also inside dicts, lists, numpy scalars) as None:
    what json.dumps(..., allow_nan=False) accepts."""
    if isinstance(obj, dict):
        return {k: json_clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_clean(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


__all__ = ["format_number", "format_exact", "format_percent", "json_float", "json_clean"]
