"""Internal coordinates u of fitted parameters (docs/fitting.md): parameters declared
``log_scale`` are fitted as logarithms, an open finite interval such as g in (-1, 1) through
atanh, the rest as they are ("plain") inside their bounds."""

from __future__ import annotations

import math

from ..models import Param

#: Internal search range (natural-log units) of log-scale parameters without a finite bound.
LOG_RANGE = 40.0
#: Open bounds are kept this fraction of the interval's width away.
OPEN_MARGIN = 1e-6
#: A solution within this fraction of its search interval's width of an end is at the edge.
EDGE = 1e-6


def coordinate(p: Param) -> str:
    """The coordinate a parameter is fitted in: "log", "atanh" or "plain"."""
    if p.log_scale:
        return "log"
    if p.lower_open and p.upper_open and math.isfinite(p.lower) and math.isfinite(p.upper):
        return "atanh"
    return "plain"


def to_u(p: Param, x: float, kind: str | None = None) -> float:
    """Internal coordinate of the natural value ``x`` (``kind``: :func:`coordinate`)."""
    kind = kind or coordinate(p)
    if kind == "log":
        return math.log(x)
    if kind == "atanh":
        mid, half = (p.upper + p.lower) / 2, (p.upper - p.lower) / 2
        return math.atanh(min(max((x - mid) / half, -1 + OPEN_MARGIN), 1 - OPEN_MARGIN))
    return float(x)


def to_x(p: Param, u: float, kind: str | None = None) -> tuple[float, float]:
    """Natural value of the internal coordinate ``u``, and d value / d u."""
    kind = kind or coordinate(p)
    if kind == "log":
        x = math.exp(u)
        return x, x
    if kind == "atanh":
        mid, half = (p.upper + p.lower) / 2, (p.upper - p.lower) / 2
        t = math.tanh(u)
        return mid + half * t, half * (1 - t * t)
    return float(u), 1.0


def bounds(p: Param, u0: float, kind: str | None = None) -> tuple[float, float]:
    """Search interval in u: the parameter's bounds (open ones kept :data:`OPEN_MARGIN` of
    the width away), or u0 +- :data:`LOG_RANGE` for an unbounded log-scale side."""
    kind = kind or coordinate(p)
    if kind == "log":
        return (
            math.log(p.lower) if p.lower > 0 else u0 - LOG_RANGE,
            math.log(p.upper) if math.isfinite(p.upper) else u0 + LOG_RANGE,
        )
    if kind == "atanh":
        edge = math.atanh(1 - OPEN_MARGIN)
        return -edge, edge
    width = (p.upper - p.lower) if math.isfinite(p.upper - p.lower) else 1.0
    return (
        p.lower + OPEN_MARGIN * width if p.lower_open else p.lower,
        p.upper - OPEN_MARGIN * width if p.upper_open else p.upper,
    )


__all__ = ["LOG_RANGE", "OPEN_MARGIN", "EDGE", "coordinate", "to_u", "to_x", "bounds"]
