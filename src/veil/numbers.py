"""How veil writes numbers: in reports and tables (:func:`format_number`,
:func:`format_percent`) and in JSON files (:func:`json_float`, :func:`from_json_float`:
non-finite numbers never reach a file, they become null)."""

from __future__ import annotations

import math
from typing import Any

from .errors import InputError


def format_number(x, digits: int = 6, missing: str = "n/a") -> str:
    """``x`` to ``digits`` significant digits; ``missing`` for None or a non-finite number."""
    if x is None:
        return missing
    x = float(x)
    if not math.isfinite(x):
        return missing
    return f"{x:.{digits}g}"


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


def from_json_float(x, where: str = "a fit result") -> float | None:
    """A number read from a file: float or None; anything else is an InputError."""
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise InputError(f"expected a number or null in {where}, got {x!r}")
    return float(x)


__all__ = ["format_number", "format_percent", "json_float", "json_clean", "from_json_float"]
