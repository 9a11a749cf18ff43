"""Colour channels of a measurement table (docs/measurements.md, "Channels").

A table may hold several channels of one session - the red, green and blue of a colour
camera, or wavelengths - in an optional ``channel`` column: ``r``, ``g``, ``b`` (any case)
or a wavelength in nm (a number in :data:`WAVELENGTH_RANGE`). Every channel must measure the
same configurations (docs/model.md sec. 7: one configuration, one value per channel). A
table without the column is one channel, exactly as before.

The functions here read the column and compare the channels' configurations; the table's
other checks and the naming of rows are :mod:`veil.data.measurements`'s, which calls them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np
import pandas as pd

from ..errors import MeasurementError

#: The column naming each row's channel.
CHANNEL = "channel"
#: Channel names of a colour camera.
RGB = ("r", "g", "b")
#: Wavelengths (nm) a channel may name: ultraviolet to the short-wave infrared.
WAVELENGTH_RANGE = (200.0, 2500.0)
_MAX_LISTED = 10


class RowNaming(Protocol):
    """How rows are named in messages (``veil.data.measurements.RowNames``)."""

    what: str

    def __call__(self, k: int) -> str: ...

    def many(self, positions: Sequence[int]) -> str: ...


def channel_label(cell: object) -> str | None:
    """The channel a cell names ("r", "g", "b" or a wavelength's shortest decimal), None
    when it names none."""
    if isinstance(cell, (bool, np.bool_)) or cell is None:
        return None
    if isinstance(cell, str):
        text = cell.strip().lower()
        if text in RGB:
            return text
        if "_" in text:  # float() reads "6_50" as 650: not a wavelength as written
            return None
        try:
            cell = float(text)
        except ValueError:
            return None
    try:
        nm = float(cell)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    if not math.isfinite(nm) or not WAVELENGTH_RANGE[0] <= nm <= WAVELENGTH_RANGE[1]:
        return None
    return f"{nm:.10g}"


def _cell_text(cell: object) -> str:
    """How a message shows a cell that names no channel: "empty" for an empty cell (read as
    NaN or None, or only blanks), else the cell's text quoted."""
    if cell is None or (isinstance(cell, str) and not cell.strip()):
        return "empty"
    if not isinstance(cell, (list, tuple, np.ndarray)) and pd.isna(cell) is True:  # NaN, NA
        return "empty"
    return repr(str(cell))


def channel_labels(column: pd.Series, rows: RowNaming) -> np.ndarray:
    """The channel of every row (labels as :func:`channel_label` writes them), or a
    MeasurementError naming the file, the rows and the column: an empty cell, an unknown
    name, a wavelength outside :data:`WAVELENGTH_RANGE`, or names mixed with wavelengths."""
    labels = [channel_label(cell) for cell in column.tolist()]
    bad = [k for k, lab in enumerate(labels) if lab is None]
    if bad:
        listed = "; ".join(
            f"{rows(k)}, column {CHANNEL!r}: {_cell_text(column.iloc[k])}"
            for k in bad[:_MAX_LISTED]
        )
        more = f"; and {len(bad) - _MAX_LISTED} more" if len(bad) > _MAX_LISTED else ""
        lo, hi = WAVELENGTH_RANGE
        raise MeasurementError(
            f"{listed}{more} (expected a channel: r, g or b, or a "
            f"wavelength in nm from {lo:g} to {hi:g})"
        )
    named = [k for k, lab in enumerate(labels) if lab in RGB]
    if named and len(named) < len(labels):
        k = next(k for k, lab in enumerate(labels) if lab not in RGB)
        raise MeasurementError(
            f"{rows(k)}, column {CHANNEL!r}: wavelength {labels[k]} in a "
            f"table whose other rows name colour channels ({rows(named[0])}"
            f": {labels[named[0]]}); a table's channels are r, g, b or "
            f"wavelengths, not both"
        )
    return np.array(labels, dtype=object)


def channel_order(labels: np.ndarray) -> list[str]:
    """The channels of ``labels`` in the order they first appear."""
    return list(dict.fromkeys(labels.tolist()))


def check_same_configurations(
    labels: np.ndarray,
    vectors: np.ndarray,
    rows: RowNaming,
    same: Callable[[np.ndarray, np.ndarray], np.ndarray],
    radius: float,
) -> None:
    """Every channel must measure the configurations of the first channel, no more, no
    fewer: a MeasurementError naming the file, the channel and the rows that differ.

    vectors : (n, 6) unit vectors I, R of every row; ``same(a, b)`` says which rows of a are
        the same configuration as rows of b (within the table's tolerance), and ``radius``
        bounds the distance of such vectors (the neighbour search).
    """
    from scipy.spatial import cKDTree

    order = channel_order(labels)
    first = np.flatnonzero(labels == order[0])
    tree_first = cKDTree(vectors[first])
    for name in order[1:]:
        mine = np.flatnonzero(labels == name)
        extra = _unmatched(vectors[mine], tree_first, vectors[first], same, radius)
        missing = _unmatched(vectors[first], cKDTree(vectors[mine]), vectors[mine], same, radius)
        if extra.size or missing.size:
            parts = []
            if extra.size:
                parts.append(
                    f"channel {name!r} measures configurations that channel "
                    f"{order[0]!r} does not ({rows.many(mine[extra])})"
                )
            if missing.size:
                parts.append(
                    f"channel {name!r} lacks configurations of channel "
                    f"{order[0]!r} ({rows.many(first[missing])})"
                )
            raise MeasurementError(
                f"the channels of {rows.what} differ: "
                + "; ".join(parts)
                + "; every channel must measure the same configurations (one value per "
                "channel at each configuration)"
            )


def channel_rows(table: pd.DataFrame, labels: np.ndarray, name: str) -> pd.DataFrame:
    """The rows of channel ``name`` (``labels`` from :func:`channel_labels`), without the
    ``channel`` column: a one-channel table that still names its rows by the lines of its
    file (``attrs``)."""
    keep = np.flatnonzero(labels == name)
    out = table.iloc[keep].drop(columns=[CHANNEL]).reset_index(drop=True)
    out.attrs = dict(table.attrs)
    lines = table.attrs.get("veil_lines")
    if lines is not None and len(lines) == len(table):
        out.attrs["veil_lines"] = tuple(lines[k] for k in keep)
    return out


def _unmatched(
    points: np.ndarray,
    tree,
    others: np.ndarray,
    same: Callable[[np.ndarray, np.ndarray], np.ndarray],
    radius: float,
) -> np.ndarray:
    """Positions of ``points`` with no configuration of ``others`` (indexed by ``tree``)
    within the tolerance."""
    dist, nearest = tree.query(points, k=1, distance_upper_bound=2 * radius)
    found = np.isfinite(dist)
    ok = np.zeros(len(points), dtype=bool)
    ok[found] = same(points[found], others[nearest[found]])
    return np.flatnonzero(~ok)


__all__ = [
    "CHANNEL",
    "RGB",
    "WAVELENGTH_RANGE",
    "channel_label",
    "channel_labels",
    "channel_order",
    "check_same_configurations",
    "channel_rows",
]
