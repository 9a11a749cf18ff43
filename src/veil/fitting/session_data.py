"""The measurements of one session as a fit uses them (docs/model.md sec. 7): :func:`prepare`
validates a table (black cloth subtracted) into a :class:`FitData`."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..data.black_cloth import subtract_black
from ..data.channels import CHANNEL, channel_label, channel_order, channel_rows
from ..data.measurements import (
    CANONICAL,
    MeasurementError,
    RowNames,
    canonical_angles,
    load_measurements,
    table_channels,
    validate,
)
from ..errors import InputTypeError


@dataclass
class FitData:
    """One session's data: canonical ``angles``, values ``y``, their ``sigma`` (None: fit
    unweighted) and the validated ``table``; ``w`` are the residual weights 1/sigma (or 1)."""

    angles: tuple  # canonical theta_i, phi_i, theta_r, phi_r (degrees)
    y: np.ndarray
    sigma: np.ndarray | None
    table: pd.DataFrame  # validated, black subtracted
    black: bool = False  # whether a black-cloth session was subtracted

    @property
    def w(self) -> np.ndarray:
        return np.ones_like(self.y) if self.sigma is None else 1.0 / self.sigma

    @property
    def size(self) -> int:
        return len(self.y)


def _load(table, what: str) -> pd.DataFrame:
    if isinstance(table, (str, os.PathLike)):
        return load_measurements(table)
    if not isinstance(table, pd.DataFrame):
        raise InputTypeError(
            f"{what}: expected a measurement table (pandas DataFrame) or a CSV "
            f"path, got {type(table).__name__}"
        )
    if "veil_source" not in table.attrs and "veil_name" not in table.attrs:
        table = table.copy()
        table.attrs["veil_name"] = f"the {what} table"
    return table


def channels_of(table, what: str = "measurement") -> tuple[pd.DataFrame, list[str] | None]:
    """(the table loaded and checked, its channels in order or None without a ``channel``
    column; docs/measurements.md, "Channels")."""
    table = validate(_load(table, what))
    labels = table_channels(table)
    return table, None if labels is None else channel_order(labels)


#: How a multi-channel table's one channel is chosen, for the messages.
SELECT = (
    "select one with --channel NAME in veil fit reference, medium or target "
    "(channel='NAME' in Python), or keep one channel's rows of the table"
)


def one_channel(
    table: pd.DataFrame, channel: str | None, what: str, several: str = ""
) -> tuple[pd.DataFrame, str | None]:
    """The rows of ``channel`` of a table with a ``channel`` column, without it (a table
    without one as it is; its only channel when ``channel`` is None). A MeasurementError for
    a channel the table lacks, a channel asked of a table without channels, or several
    channels and none chosen (``several`` says what supports them). Returns the rows and
    the channel's name (None without a ``channel`` column)."""
    labels = table_channels(table)
    source = RowNames(table).what
    if labels is None:
        if channel is not None:
            raise MeasurementError(
                f"channel {channel!r} asked, but {source} has no "
                f"{CHANNEL!r} column (it is one channel)"
            )
        return table, None
    order = channel_order(labels)
    if channel is None and len(order) > 1:
        raise MeasurementError(
            f"{source} holds {len(order)} channels ({', '.join(order)}): the {what} fit does "
            f"not fit several channels at once{several}; {SELECT}"
        )
    name = order[0] if channel is None else channel_label(channel)
    if name not in order:
        raise MeasurementError(
            f"{source} has no channel {channel!r}; its channels are {', '.join(order)}"
        )
    return channel_rows(table, labels, name), name


def _warn_unsubtracted_black(table: pd.DataFrame) -> None:
    """A UserWarning, once per table, when a table fitted without a black-cloth table has a
    nonzero ``black`` column (``veil ingest --black-roi``: the black cloth beside the
    object): the fit does not subtract it (docs/ingest.md). The table is marked, so that
    the fits that prepare it again (every candidate of a ranking) do not say it again."""
    if "black" not in table.columns or table.attrs.get(_BLACK_SAID):
        return
    table.attrs[_BLACK_SAID] = True
    black = pd.to_numeric(table["black"], errors="coerce").to_numpy(dtype=float)
    if np.any(np.isfinite(black) & (black != 0)):
        warnings.warn(
            f"{RowNames(table).what} has a 'black' column (the black cloth beside the object, "
            f"veil ingest --black-roi), which the fit does not subtract: subtract it first "
            f"(docs/ingest.md); through a medium, a black-cloth table (--black) does that",
            UserWarning,
            stacklevel=3,
        )


#: The attribute that marks a table whose ``black`` column was warned of.
_BLACK_SAID = "veil_black_column_said"


def prepare(
    table, black=None, what: str = "measurement", channel: str | None = None, several: str = ""
) -> FitData:
    """Validated data of a session (docs/model.md sec. 7), the black cloth subtracted if
    given; of one channel of a multi-channel table (:func:`one_channel`)."""
    table = _load(table, what)
    source = table
    if CHANNEL in table.columns or channel is not None:
        table, channel = one_channel(validate(table), channel, what, several)
    if black is not None:
        black = _load(black, "black-cloth")
        if CHANNEL in black.columns or channel is not None:
            black = _black_channel(validate(black), source, channel)
        checked = subtract_black(table, black)
    else:
        checked = validate(table)
        _warn_unsubtracted_black(checked)
    canon = canonical_angles(checked)
    angles = tuple(canon[c].to_numpy(dtype=float) for c in CANONICAL)
    y = checked["value"].to_numpy(dtype=float)
    sigma = None
    if "sigma" in checked.columns:
        sigma = checked["sigma"].to_numpy(dtype=float)
        zero = np.flatnonzero(sigma <= 0)
        if zero.size:
            rows = RowNames(checked)
            raise MeasurementError(
                f"{rows.many(zero)}, column 'sigma': 0 ({zero.size} row(s)); a zero standard "
                f"deviation would give the point infinite weight: give every row a positive "
                f"sigma, or drop the sigma column to fit unweighted"
            )
    for column, values in (("value", y), ("sigma", sigma)):
        if values is not None:
            _check_magnitude(values, column, checked, channel)
    return FitData(angles, y, sigma, checked, black is not None)


def stack(datas: dict[str, FitData]) -> FitData:
    """The data of several channels ({channel: its data}, the same configurations) as one
    session, channel after channel: the order of a fit over the channels' residuals
    (:mod:`veil.fitting.channel_fit`), for what reads a fit with its data (the ranking of
    :mod:`veil.fitting.selection`). Its table has the ``channel`` column back."""
    parts = list(datas.values())
    sigmas = [d.sigma for d in parts if d.sigma is not None]
    table = pd.concat([d.table.assign(**{CHANNEL: c}) for c, d in datas.items()], ignore_index=True)
    return FitData(
        tuple(np.concatenate(a) for a in zip(*(d.angles for d in parts))),
        np.concatenate([d.y for d in parts]),
        np.concatenate(sigmas) if len(sigmas) == len(parts) else None,
        table,
        any(d.black for d in parts),
    )


def prepare_all(
    table, black=None, what: str = "measurement", channel: str | None = None
) -> FitData:
    """:func:`prepare`, but of a table of several channels when no ``channel`` is chosen
    every channel's data :func:`stack` ed: the data a fit over the channels reads."""
    if channel is None:
        loaded, channels = channels_of(table, what)
        if channels is not None and len(channels) > 1:
            return stack({c: prepare(loaded, black, what, channel=c) for c in channels})
    return prepare(table, black, what, channel)


def _black_channel(black: pd.DataFrame, table: pd.DataFrame, channel: str | None) -> pd.DataFrame:
    """The black-cloth rows of the session's ``channel``: a MeasurementError naming the
    black file when it lacks that channel, or when only one of the two tables has channels."""
    source = RowNames(black).what
    if channel is None:
        raise MeasurementError(
            f"the black-cloth table {source} has a {CHANNEL!r} column but "
            f"the session {RowNames(table).what} has none: give both "
            f"tables per channel or neither"
        )
    if CHANNEL not in black.columns:
        raise MeasurementError(
            f"the black-cloth table {source} has no {CHANNEL!r} column: "
            f"the session's channel {channel!r} needs the black cloth "
            f"measured in that channel"
        )
    labels = table_channels(black)
    assert labels is not None  # it has the column
    if channel not in channel_order(labels):
        raise MeasurementError(
            f"the black-cloth table {source} has no channel {channel!r} "
            f"(its channels are {', '.join(channel_order(labels))}); "
            f"measure the black cloth in every channel of the session"
        )
    return channel_rows(black, labels, channel)


#: Magnitudes a fit handles: beyond, squares and products of values leave float64's range
#: (a value of 1e-300 squares to 0; one of 1e200 to infinity).
MAGNITUDE = (1e-100, 1e100)


def _check_magnitude(
    values: np.ndarray, column: str, table: pd.DataFrame, channel: str | None = None
) -> None:
    """Refuse a column whose values are finite but too large or too small to fit in
    float64's range (MeasurementError naming the row, column and ``channel``, exit
    status 2)."""
    lo, hi = MAGNITUDE
    size = np.abs(values)
    rows = RowNames(table)
    big = np.flatnonzero(size > hi)
    scope = "the table" if channel is None else f"the rows of channel {channel!r}"
    how = (
        f"veil fits values of magnitude {lo:g} to {hi:g}: rescale {scope} (multiply "
        f"'value' and 'sigma' by one factor; the fitted scale coefficients follow it)"
    )
    named = f"column {column!r}" + ("" if channel is None else f" of channel {channel!r}")
    if big.size:
        k = int(big[np.argmax(size[big])])
        raise MeasurementError(
            f"{rows(k)}, {named}: {values[k]:.6g} ({big.size} row(s) above {hi:g}); {how}"
        )
    top = float(size.max()) if size.size else 0.0
    if 0 < top < lo:
        k = int(np.argmax(size))
        raise MeasurementError(
            f"{rows.what}, {named}: the largest magnitude is "
            f"{top:.6g} ({rows(k)}), below {lo:g}; {how}"
        )


__all__ = ["FitData", "prepare", "prepare_all", "stack", "channels_of", "one_channel", "SELECT"]
