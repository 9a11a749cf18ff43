"""Every colour channel of a photo stack at once (``veil ingest --channel rgb``,
docs/ingest.md "Channels"): one measurement table with a ``channel`` column (r, g, b),
channel after channel, each channel's rows what the one-channel ingest of that channel
writes; the photo stack checked to be all colour or all grey; camera raw's white balance
recorded, never applied.

The ROI statistics are :mod:`veil.data.ingest`'s; this module holds what several channels
add to them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..errors import InputError
from .channels import CHANNEL, RGB
from .photo_files import Photo

#: The ``channel`` choice that reads r, g and b at once.
ALL_RGB = "rgb"
#: The column of camera raw's as-shot white-balance multiplier of the row's channel.
WHITE_BALANCE = "white_balance"


def channels_read(channel: str) -> tuple[str, ...]:
    """The channels one ingest of ``channel`` reads: r, g, b for ``rgb``, else itself."""
    return RGB if channel == ALL_RGB else (channel,)


def check_channel_columns(table: pd.DataFrame, name: str) -> None:
    """A manifest of an ingest of every channel must not have the columns it adds."""
    clash = [c for c in (CHANNEL, WHITE_BALANCE) if c in table.columns]
    if clash:
        raise InputError(
            f"{name}: column(s) {', '.join(map(repr, clash))} would be overwritten by the "
            f"ingest of every channel (--channel {ALL_RGB}); rename or remove them"
        )


def is_colour(photo: Photo) -> bool:
    """A colour photo: an RGB image or a camera raw mosaic (one of several colours)."""
    return photo.kind == "raw" or photo.shape[2] == 3


def sample_type(photo: Photo) -> str:
    """A photo's samples as a message names them, one name per scale of code values:
    "16-bit integer", "float" (any width: floats carry no code-value scale), "camera raw"."""
    if photo.kind == "raw":
        return "camera raw"
    dtype = photo.dtype
    return "float" if dtype.kind == "f" else f"{dtype.itemsize * 8}-bit integer"


class StackKind:
    """The photos of one stack are all colour or all grey, and all of one size (the same
    ROIs are read in each): :meth:`check` each in turn. Photos of other samples than the
    first (8-bit among 16-bit, float among integer, camera raw among images) are warned
    about once: their code values may have another scale."""

    def __init__(self) -> None:
        self.first: tuple[bool, str, tuple, str] | None = None
        self.odd_samples = False

    def check(self, photo: Photo, where: str) -> str | None:
        """An InputError naming ``where`` (the photo) and the first photo when ``photo`` is
        grey in a colour stack or colour in a grey one, or of another size; the warning
        for the first photo of other samples than the first photo's (None otherwise)."""
        colour = is_colour(photo)
        size = tuple(photo.shape[:2])
        samples = sample_type(photo)
        if self.first is None:
            self.first = (colour, where, size, samples)
            return None
        first_colour, first_where, first_size, first_samples = self.first
        if size != first_size:
            raise InputError(
                f"{where}: {size[1]} x {size[0]} pixels, but the stack's first photo "
                f"{first_where} is {first_size[1]} x {first_size[0]}; every photo of a stack "
                f"must have the same size (the same ROIs are read in each): ingest photos "
                f"of another size with a manifest of their own"
            )
        if colour != first_colour:
            kinds = ("a colour image", "a grey (single-channel) image")
            mine, theirs = (kinds[0], kinds[1]) if colour else (kinds[1], kinds[0])
            raise InputError(
                f"{where}: {mine}, but the stack's first photo {first_where} is {theirs}; "
                f"a photo stack is all colour (RGB images or camera raw) or all grey: "
                f"convert the odd photo(s), or ingest them with a manifest of their own"
            )
        if samples == first_samples or self.odd_samples:
            return None
        self.odd_samples = True
        return (
            f"{where}: {samples} samples, but the stack's first photo {first_where} has "
            f"{first_samples} samples: their code values may have another scale (8-bit "
            f"values are 1/257 of 16-bit ones); export every photo of a stack alike"
        )


def excluded_message(where: str, rows: dict, level, floor, keep_saturated: bool) -> str | None:
    """The warning for a photo with saturated or clipped pixels in its ROIs (None without):
    ``rows`` {channel: its row}; with several channels each one's counts are named, and a
    photo excluded is excluded from every channel (the channels measure the same
    configurations)."""
    parts = []
    for channel, row in rows.items():
        what = []
        if row["saturated"]:
            what.append(f"{row['saturated']} saturated pixel(s) (code >= {level:g})")
        if row["clipped"]:
            what.append(f"{row['clipped']} clipped pixel(s) (code <= {floor:g})")
        if what:
            text = " and ".join(what)
            parts.append(text if len(rows) == 1 else f"channel {channel}: {text}")
    if not parts:
        return None
    action = (
        "kept as asked"
        if keep_saturated
        else "excluded (--keep-saturated / keep_saturated=True keeps it)"
    )
    if len(rows) > 1 and not keep_saturated:
        action = action.replace("excluded", "excluded from every channel", 1)
    return f"{where}: {'; '.join(parts)} in the ROIs; {action}"


def channel_table(
    table: pd.DataFrame, keep: list[int], results: dict, balances: list, order: list[str]
) -> pd.DataFrame:
    """The table of every channel: the kept manifest rows once per channel, channel after
    channel, a ``channel`` column before ``value``, then the columns ``order`` names from
    ``results`` {channel: rows}; with camera raw photos a ``white_balance`` column, the
    as-shot multiplier of each row's channel (``balances``: each kept photo's
    :func:`photo_balance`; other photos' cells are empty)."""
    kept = table.iloc[keep].reset_index(drop=True)
    raw = any(b is not None for b in balances)
    parts = []
    for c in results:
        part = kept.copy()
        part[CHANNEL] = c
        added = pd.DataFrame(results[c])
        for col in order:
            part[col] = added[col].to_numpy()
        if raw:
            part[WHITE_BALANCE] = [np.nan if b is None else b[RGB.index(c)] for b in balances]
        parts.append(part)
    out = pd.concat(parts, ignore_index=True)
    out.attrs = dict(kept.attrs)
    return out


def photo_balance(photo: Photo) -> tuple | None:
    """What :func:`channel_table` records of ``photo``: the as-shot white balance of camera
    raw (R, G, B over G; NaN when the camera recorded none), None for other photos."""
    if photo.kind != "raw":
        return None
    nan = float("nan")
    return photo.white_balance if photo.white_balance is not None else (nan, nan, nan)


__all__ = [
    "ALL_RGB",
    "WHITE_BALANCE",
    "channels_read",
    "check_channel_columns",
    "is_colour",
    "StackKind",
    "excluded_message",
    "channel_table",
    "photo_balance",
]
