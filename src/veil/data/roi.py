"""A region of interest of a photo (docs/ingest.md): :class:`ROI`, :func:`parse_roi`."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError


@dataclass(frozen=True)
class ROI:
    """A rectangle in pixel coordinates: x to the right, y down, origin at the top-left pixel."""

    x: int
    y: int
    w: int
    h: int

    def __str__(self):
        return f"{self.x},{self.y},{self.w},{self.h}"

    @property
    def slices(self):
        return slice(self.y, self.y + self.h), slice(self.x, self.x + self.w)

    def overlaps(self, other: ROI) -> bool:
        return (
            self.x < other.x + other.w
            and other.x < self.x + self.w
            and self.y < other.y + other.h
            and other.y < self.y + self.h
        )


def parse_roi(value, name: str = "roi") -> ROI:
    """``"X,Y,W,H"`` (or 4 numbers, or a :class:`ROI`) -> :class:`ROI`; integers, W, H >= 1."""
    if isinstance(value, ROI):
        return value
    parts = [p.strip() for p in value.split(",")] if isinstance(value, str) else list(value)
    form = "X,Y,W,H in pixels (x to the right, y down, origin top-left)"
    if len(parts) != 4:
        raise InputError(f"{name} {value!r}: expected 4 integers {form}")
    numbers = []
    for label, part in zip("XYWH", parts):
        try:
            number = float(part)
        except (TypeError, ValueError):
            raise InputError(
                f"{name} {value!r}: {label} = {part!r} is not an integer; expected {form}"
            ) from None
        if not number.is_integer():
            raise InputError(
                f"{name} {value!r}: {label} = {part!r} is not an integer; expected {form}"
            )
        numbers.append(int(number))
    x, y, w, h = numbers
    if x < 0 or y < 0:
        raise InputError(
            f"{name} {value!r}: X and Y must be >= 0 (pixel coordinates, origin at the top-left)"
        )
    if w < 1 or h < 1:
        raise InputError(f"{name} {value!r}: W and H must be >= 1 pixel")
    return ROI(x, y, w, h)


__all__ = ["ROI", "parse_roi"]
