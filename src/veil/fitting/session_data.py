"""The measurements of one session as a fit uses them (docs/model.md sec. 7): :func:`prepare`
validates a table (black cloth subtracted) into a :class:`FitData`."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..data.black_cloth import subtract_black
from ..data.measurements import (
    CANONICAL,
    MeasurementError,
    RowNames,
    canonical_angles,
    load_measurements,
    validate,
)
from ..errors import InputTypeError


@dataclass
class FitData:
    """One session's data: canonical ``angles``, values ``y``, their ``sigma`` (None: fit
    unweighted) and the validated ``table``; ``w`` are the residual weights 1/sigma (or 1)."""

    angles: tuple          # canonical theta_i, phi_i, theta_r, phi_r (degrees)
    y: np.ndarray
    sigma: np.ndarray | None
    table: pd.DataFrame    # validated, black subtracted
    black: bool = False    # whether a black-cloth session was subtracted

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
        raise InputTypeError(f"{what}: expected a measurement table (pandas DataFrame) or a CSV "
                        f"path, got {type(table).__name__}")
    if "veil_source" not in table.attrs and "veil_name" not in table.attrs:
        table = table.copy()
        table.attrs["veil_name"] = f"the {what} table"
    return table


def prepare(table, black=None, what: str = "measurement") -> FitData:
    """Validated data of a session (docs/model.md sec. 7), the black cloth subtracted if given."""
    table = _load(table, what)
    if black is not None:
        black = _load(black, "black-cloth")
        checked = subtract_black(table, black)
    else:
        checked = validate(table)
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
                f"sigma, or drop the sigma column to fit unweighted")
    for column, values in (("value", y), ("sigma", sigma)):
        if values is not None:
            _check_magnitude(values, column, checked)
    return FitData(angles, y, sigma, checked, black is not None)


#: Magnitudes a fit handles: beyond, squares and products of values leave float64's range
#: (a value of 1e-300 squares to 0; one of 1e200 to infinity).
MAGNITUDE = (1e-100, 1e100)


def _check_magnitude(values: np.ndarray, column: str, table: pd.DataFrame) -> None:
    """Refuse a column whose values are finite but too large or too small to fit in
    float64's range (MeasurementError naming the row and column, exit status 2)."""
    lo, hi = MAGNITUDE
    size = np.abs(values)
    rows = RowNames(table)
    big = np.flatnonzero(size > hi)
    how = (f"veil fits values of magnitude {lo:g} to {hi:g}: rescale the table (multiply "
           f"'value' and 'sigma' by one factor; the fitted scale coefficients follow it)")
    if big.size:
        k = int(big[np.argmax(size[big])])
        raise MeasurementError(f"{rows(k)}, column {column!r}: {values[k]:.6g} ({big.size} "
                               f"row(s) above {hi:g}); {how}")
    top = float(size.max()) if size.size else 0.0
    if 0 < top < lo:
        k = int(np.argmax(size))
        raise MeasurementError(f"{rows.what}, column {column!r}: the largest magnitude is "
                               f"{top:.6g} ({rows(k)}), below {lo:g}; {how}")


__all__ = ["FitData", "prepare"]
