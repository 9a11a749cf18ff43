"""The angle columns of a measurement table (:mod:`veil.data.measurements`): which of the
three forms a table uses, its columns read as numbers and checked (ranges, the forms
agreeing on one configuration, angles that look like radians), and the rows named in the
messages ("line 7 of meas.csv")."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd

from ..engine.angles import direction, from_goniometer, from_signed_inplane
from ..errors import MeasurementError

#: Angle columns, in the order :func:`canonical_angles` writes them.
CANONICAL = ("theta_i", "phi_i", "theta_r", "phi_r")
ANGLE_COLUMNS = ("psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r")
KNOWN_COLUMNS = ANGLE_COLUMNS + ("value", "sigma")
FORMS = ("full", "inplane", "goniometer")

#: Two configurations closer than this (deg, for both I and R) are the same configuration.
SAME_TOL = 1e-6
#: The distance of unit-vector pairs (I, R) that are the same configuration, at most.
_SAME_RADIUS = 2.0 * math.sqrt(2.0) * math.sin(math.radians(SAME_TOL) / 2.0) * (1 + 1e-9)
#: Below these magnitudes every angle of its column looks like radians (pi/2, pi, 2 pi).
_RADIAN_LIMITS = {
    "theta_i": 1.6,
    "theta_r": 1.6,
    "rho": 1.6,
    "psi": 3.2,
    "phi_i": 6.3,
    "phi_r": 6.3,
}
_MAX_LISTED = 10


class LikelyRadiansWarning(UserWarning):
    """Every angle of a table is small enough to be in radians; veil expects degrees."""


# --------------------------------------------------------------------------------------
# naming rows in messages
# --------------------------------------------------------------------------------------
class RowNames:
    """Names row ``k`` (position) of a table: "line 7 of f.csv" or "row 5 (index label) of ..."."""

    def __init__(self, table: pd.DataFrame):
        source = table.attrs.get("veil_source")
        lines = table.attrs.get("veil_lines")
        self.lines = None
        if (
            source is not None
            and lines is not None
            and len(lines) == len(table)
            and table.index.equals(pd.RangeIndex(len(table)))
        ):
            self.lines = tuple(lines)
            self.what = str(source)
        else:
            self.what = str(table.attrs.get("veil_name", "the table"))
        self.labels = list(table.index)

    def __call__(self, k: int) -> str:
        if self.lines is not None:
            return f"line {self.lines[k]} of {self.what}"
        return f"row {self.labels[k]!r} (index label) of {self.what}"

    def many(self, positions) -> str:
        """Names of rows at ``positions``: "lines 2-5, 9 of f.csv" (runs of consecutive
        lines joined, the first few runs and a count of the rest)."""
        positions = list(positions)
        if self.lines is None:
            text = "; ".join(self(k) for k in positions[:_MAX_LISTED])
            if len(positions) > _MAX_LISTED:
                text += f"; and {len(positions) - _MAX_LISTED} more"
            return text
        runs: list[list[int]] = []
        for line in (self.lines[k] for k in positions):
            if runs and line == runs[-1][1] + 1:
                runs[-1][1] = line
            else:
                runs.append([line, line])
        named = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:_MAX_LISTED]]
        rest = sum(b - a + 1 for a, b in runs[_MAX_LISTED:])
        word = "line" if len(positions) == 1 else "lines"
        return (
            f"{word} {', '.join(named)}"
            + (f" and {rest} more" if rest else "")
            + f" of {self.what}"
        )


def _fmt(x: float) -> str:
    return f"{x:.10g}"


def _config_text(angles, k) -> str:
    ti, pi_, tr, pr = (a[k] for a in angles)
    return f"theta_i={_fmt(ti)}, phi_i={_fmt(pi_)}, theta_r={_fmt(tr)}, phi_r={_fmt(pr)}"


# --------------------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------------------
def separator_hint(columns) -> str:
    """A hint when the header looks separated by another character than the comma (a
    semicolon, as spreadsheets write with a decimal comma, or a tab); "" otherwise."""
    names = " ".join(map(str, columns))
    for sep, said in ((";", "';'"), ("\t", "tabs")):
        if len(columns) <= 2 and sep in names:
            return f" (the header looks separated by {said}: veil reads comma-separated values)"
    return ""


#: What a measurement table's header should name, for messages.
EXPECTED_HEADER = (
    "expected column names such as psi,rho,value or theta_i,theta_r,value (docs/measurements.md)"
)


def check_header_text(columns, what: str) -> None:
    """A :class:`MeasurementError` naming ``what`` (the file) when a column name of its
    header holds characters no column name has: a byte-order mark (U+FEFF) after the first
    (an editor that adds one to a file that had one), a control character, stray bytes."""
    for k, name in enumerate(map(str, columns)):
        # (a tab is a separator other than the comma: separator_hint names it)
        stray = [c for c in name if c == "\ufeff" or not (c.isprintable() or c == "\t")]
        if stray:
            kind = (
                "a repeated byte-order mark (U+FEFF)"
                if "\ufeff" in stray
                else "bytes that are not text"
            )
            clean = "".join(c for c in name if c not in stray)
            raise MeasurementError(
                f"the header of {what} has stray bytes in column {k + 1} ({name!r}: "
                f"{kind}; without them it reads {clean!r}): remove them; {EXPECTED_HEADER}"
            )


def _stray_hint(columns, missing: str) -> str:
    """A note for a column that ends with the ``missing`` name ("column 'xxpsi' looks like
    'psi' with stray characters before it"), or ""."""
    for c in map(str, columns):
        # ('sigma_theta_r' is a column of its own, not 'theta_r' with something before it)
        if c != missing and c.endswith(missing) and "_" not in c[: -len(missing)]:
            return f" (column {c!r} looks like {missing!r} with stray characters before it)"
    return ""


def _form(columns, what: str) -> dict:
    """Which angle forms the columns hold; raises for incomplete or contradictory sets."""
    check_header_text(columns, what)
    have = set(columns)
    pairs = (("psi", "rho"), ("theta_i", "theta_r"), ("phi_i", "phi_r"))
    for a, b in pairs:
        if (a in have) != (b in have):
            present, missing = (a, b) if a in have else (b, a)
            raise MeasurementError(
                f"{what} has column {present!r} but not {missing!r}"
                f"{_stray_hint(columns, missing)}: angle columns come in "
                f"pairs (theta_i,phi_i,theta_r,phi_r or theta_i,theta_r or psi,rho)"
            )
    if "phi_i" in have and "theta_i" not in have:
        raise MeasurementError(f"{what} has phi_i and phi_r but no theta_i and theta_r columns")
    forms = {
        "full": "phi_i" in have,
        "inplane": "theta_i" in have and "phi_i" not in have,
        "goniometer": "psi" in have,
    }
    if not any(forms.values()):
        raise MeasurementError(
            f"{what} has no angle columns: expected theta_i,phi_i,theta_r,phi_r (full), "
            f"theta_i,theta_r (signed in-plane) or psi,rho (goniometer), in degrees; "
            f"found columns {', '.join(map(str, columns))}{separator_hint(columns)}"
        )
    return forms


def _numbers(table: pd.DataFrame, column: str, rows: RowNames) -> np.ndarray:
    """Column as float64, raising for empty, non-numeric, NaN or infinite cells."""
    series = table[column]
    if pd.api.types.is_bool_dtype(series.dtype):
        raise MeasurementError(f"{rows(0)}, column {column!r}: {series.iloc[0]!r} is not a number")
    if pd.api.types.is_numeric_dtype(series.dtype):
        values = series.to_numpy(dtype=float, na_value=np.nan)
        problems: list = []
    else:
        values = np.empty(len(series))
        problems = []
        for k, cell in enumerate(series.tolist()):
            try:
                if (
                    cell is None
                    or (isinstance(cell, float) and math.isnan(cell))
                    or (isinstance(cell, str) and not cell.strip())
                ):
                    problems.append((k, "is empty"))
                    values[k] = 0.0
                    continue
                if isinstance(cell, (bool, np.bool_)) or (isinstance(cell, str) and "_" in cell):
                    raise ValueError
                values[k] = float(cell.strip() if isinstance(cell, str) else cell)
            except (TypeError, ValueError):
                problems.append((k, f"{cell!r} is not a number"))
                values[k] = 0.0
                continue
            if not math.isfinite(values[k]):
                problems.append((k, f"{cell!r} is not a finite number"))
                values[k] = 0.0
    for k in np.flatnonzero(~np.isfinite(values)).tolist():
        problems.append(
            (
                int(k),
                "is empty or NaN"
                if np.isnan(values[k])
                else f"{float(values[k])!r} is not a finite number (beyond float64's "
                f"range, magnitude above 1.8e308)",
            )
        )
    if problems:
        problems.sort()
        listed = "; ".join(
            f"{rows(k)}, column {column!r}: {msg}" for k, msg in problems[:_MAX_LISTED]
        )
        more = f"; and {len(problems) - _MAX_LISTED} more" if len(problems) > _MAX_LISTED else ""
        raise MeasurementError(
            listed
            + more
            + " (expected a finite number"
            + (", in degrees)" if column in ANGLE_COLUMNS else ")")
        )
    return values


def _range_error(rows, positions, describe, expected) -> MeasurementError:
    listed = "; ".join(f"{rows(k)}: {describe(k)}" for k in positions[:_MAX_LISTED])
    more = f"; and {len(positions) - _MAX_LISTED} more" if len(positions) > _MAX_LISTED else ""
    return MeasurementError(f"{listed}{more} ({expected})")


def _angles_from(cols: dict, forms: dict, rows: RowNames):
    """Canonical (theta_i, phi_i, theta_r, phi_r) of every form present, range-checked."""
    result = {}
    if forms["full"]:
        for name in ("theta_i", "theta_r"):
            a = cols[name]
            bad = np.flatnonzero((a < 0) | (a >= 90))
            if bad.size:
                raise _range_error(
                    rows,
                    bad,
                    lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                    f"{name} with phi columns is a polar angle in [0, 90) deg; "
                    f"signed in-plane angles go without phi columns",
                )
        for name in ("phi_i", "phi_r"):
            a = cols[name]
            bad = np.flatnonzero(np.abs(a) > 360)
            if bad.size:
                raise _range_error(
                    rows,
                    bad,
                    lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                    f"{name} is an azimuth in [-360, 360] deg",
                )
        phi_i, phi_r = (_wrap(cols["phi_i"]), _wrap(cols["phi_r"]))
        result["full"] = (cols["theta_i"] + 0.0, phi_i, cols["theta_r"] + 0.0, phi_r)
    if forms["inplane"]:
        for name in ("theta_i", "theta_r"):
            a = cols[name]
            bad = np.flatnonzero(np.abs(a) >= 90)
            if bad.size:
                raise _range_error(
                    rows,
                    bad,
                    lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                    f"signed in-plane {name} must lie in (-90, 90) deg",
                )
        ti, pi_, tr, pr = from_signed_inplane(cols["theta_i"], cols["theta_r"])
        result["inplane"] = (ti, pi_, tr, pr)
    if forms["goniometer"]:
        psi, rho = cols["psi"], cols["rho"]
        ti, tr = from_goniometer(psi, rho)
        bad = np.flatnonzero((np.abs(ti) >= 90) | (np.abs(tr) >= 90))
        if bad.size:
            raise _range_error(
                rows,
                bad,
                lambda k: (
                    f"psi = {_fmt(psi[k])}, rho = {_fmt(rho[k])} give "
                    f"theta_i = {_fmt(ti[k])}, theta_r = {_fmt(tr[k])}"
                ),
                "theta_i = psi/2 + rho and theta_r = psi/2 - rho must lie in (-90, 90) deg",
            )
        result["goniometer"] = from_signed_inplane(ti, tr)
    return result


def _wrap(phi: np.ndarray) -> np.ndarray:
    out = np.mod(phi, 360.0) + 0.0
    return np.where(out >= 360.0, 0.0, out)


def _vectors(angles) -> np.ndarray:
    """(n, 6) array of the unit vectors I and R of canonical angles."""
    ti, pi_, tr, pr = angles
    return np.concatenate([direction(ti, pi_), direction(tr, pr)], axis=1)


def _separation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest of the angles (deg) between the I vectors and between the R vectors of a and b."""

    def ang(u, v):
        return np.rad2deg(2.0 * np.arcsin(np.clip(np.linalg.norm(u - v, axis=-1) / 2.0, 0, 1)))

    return np.maximum(ang(a[..., :3], b[..., :3]), ang(a[..., 3:], b[..., 3:]))


def _check_agreement(found: dict, rows: RowNames) -> tuple:
    names = [f for f in FORMS if f in found]
    primary = found[names[0]]
    if len(names) > 1:
        ref = _vectors(primary)
        for other in names[1:]:
            sep = _separation(ref, _vectors(found[other]))
            bad = np.flatnonzero(sep > SAME_TOL)
            if bad.size:
                cols = {
                    "full": "theta_i,phi_i,theta_r,phi_r",
                    "inplane": "theta_i,theta_r",
                    "goniometer": "psi,rho",
                }
                raise _range_error(
                    rows,
                    bad,
                    lambda k, cols=cols, other=other: (
                        f"{cols[names[0]]} give {_config_text(primary, k)} but "
                        f"{cols[other]} give {_config_text(found[other], k)}"
                    ),
                    f"ambiguous angles: the table has both {cols[names[0]]} and {cols[other]} "
                    f"columns and they disagree; keep one form or make them agree",
                )
    return primary


def _warn_radians(cols: dict, what: str) -> bool:
    present = [c for c in _RADIAN_LIMITS if c in cols]
    small = all(np.all(np.abs(cols[c]) < _RADIAN_LIMITS[c]) for c in present)
    # angles that are all 0 (psi = 0, the plane of incidence) are 0 in either unit
    if present and small and any(np.any(np.asarray(cols[c]) != 0) for c in present):
        warnings.warn(
            f"every angle in {what} is small (|theta|, |rho| < 1.6, |psi| < 3.2, |phi| < 6.3): "
            f"were they written in radians? veil reads angles in degrees (docs/model.md sec. 1)",
            LikelyRadiansWarning,
            stacklevel=3,
        )
        return True
    return False


__all__ = [
    "CANONICAL",
    "ANGLE_COLUMNS",
    "KNOWN_COLUMNS",
    "FORMS",
    "SAME_TOL",
    "LikelyRadiansWarning",
    "RowNames",
]
