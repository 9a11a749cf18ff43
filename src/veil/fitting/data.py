"""The measurements of one session as a fit uses them (docs/model.md sec. 7): :func:`prepare`
validates a table (black cloth subtracted) into a :class:`FitData`."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputTypeError
from ..data.measurements import (CANONICAL, MeasurementError, RowNames, canonical_angles,
                           load_measurements, subtract_black, validate)


@dataclass
class FitData:
    """One session's data: canonical ``angles``, values ``y``, their ``sigma`` (None: fit
    unweighted) and the validated ``table``; ``w`` are the residual weights 1/sigma (or 1)."""

    angles: tuple          # canonical theta_i, phi_i, theta_r, phi_r (degrees)
    y: np.ndarray
    sigma: np.ndarray | None
    table: pd.DataFrame    # validated, black subtracted

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
    return FitData(angles, y, sigma, checked)


__all__ = ["FitData", "prepare"]
