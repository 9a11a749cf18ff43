"""Black-cloth subtraction (docs/model.md sec. 7): the medium's own signal, measured with a
black cloth in place of the object, taken from a session configuration by configuration."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..errors import InputError
from .channels import channel_order
from .measurements import (
    MeasurementError,
    RowNames,
    _check_type,
    _config_text,
    _range_error,
    _separation,
    _validated,
    _vectors,
    table_channels,
)


def _one_channel(frame: pd.DataFrame, what: str) -> None:
    """A MeasurementError when ``frame`` holds several channels: the black cloth is
    subtracted channel by channel, by a command that fits one channel at a time."""
    labels = table_channels(frame)
    if labels is None:
        return
    order = channel_order(labels)
    if len(order) > 1:
        raise MeasurementError(
            f"the {what} {RowNames(frame).what} holds {len(order)} channels "
            f"({', '.join(order)}): this command takes one channel's rows (veil fit "
            f"reference, medium and target select one with --channel NAME)"
        )


def subtract_black(table: pd.DataFrame, black: pd.DataFrame, tol: float = 0.05) -> pd.DataFrame:
    """Subtract the black-cloth (medium-only) signal from a session (docs/model.md sec. 7).

    Every row of ``table`` is matched to the row of ``black`` whose light and view
    directions are both within ``tol`` degrees; ``value`` becomes the difference and
    ``sigma`` the quadrature sum (a missing sigma counts as 0; no sigma column in either
    table gives none). The table's other columns are kept; unused black rows are ignored.
    Raises :class:`MeasurementError` naming the configurations with no match, or with more
    than one match (tolerance too large).
    """
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol >= 0):
        raise InputError(f"tol = {tol!r}: expected a finite tolerance >= 0 in degrees")
    _check_type(table)
    _check_type(black)
    for frame, what in ((table, "session"), (black, "black-cloth table")):
        _one_channel(frame, what)
    rows_t = RowNames(table)
    checked, angles = _validated(table, rows_t)
    if "veil_source" not in black.attrs:
        black = black.copy()
        black.attrs["veil_name"] = "the black-cloth table"
    rows_b = RowNames(black)
    black_checked, black_angles = _validated(black, rows_b)

    from scipy.spatial import cKDTree

    vt, vb = _vectors(angles), _vectors(black_angles)
    radius = 2.0 * math.sqrt(2.0) * math.sin(math.radians(tol) / 2.0) * (1 + 1e-9) + 1e-15
    candidates = cKDTree(vb).query_ball_point(vt, radius)
    match = np.empty(len(vt), dtype=int)
    missing, ambiguous = [], []
    for k, cand in enumerate(candidates):
        cand = sorted(j for j in cand if _separation(vt[k], vb[j]) <= tol)
        if not cand:
            missing.append(k)
        elif len(cand) > 1:
            ambiguous.append((k, cand))
        else:
            match[k] = cand[0]
    if missing:
        raise _range_error(
            rows_t,
            missing,
            lambda k: _config_text(angles, k),
            f"{len(missing)} configuration(s) have no black-cloth measurement within "
            f"{tol:g} deg in {rows_b.what}",
        )
    if ambiguous:
        k, cand = ambiguous[0]
        raise MeasurementError(
            f"{rows_t(k)} ({_config_text(angles, k)}) is within {tol:g} deg of several "
            f"black-cloth rows: {rows_b.many(cand)} ({len(ambiguous)} such row(s)); "
            f"use a smaller tolerance"
        )
    out = checked.copy()
    out["value"] = checked["value"].to_numpy() - black_checked["value"].to_numpy()[match]
    has_t, has_b = "sigma" in checked.columns, "sigma" in black_checked.columns
    if has_t or has_b:
        st = checked["sigma"].to_numpy() if has_t else 0.0
        sb = black_checked["sigma"].to_numpy()[match] if has_b else 0.0
        out["sigma"] = np.hypot(st, sb)
    out.attrs = dict(table.attrs)
    return out


__all__ = ["subtract_black"]
