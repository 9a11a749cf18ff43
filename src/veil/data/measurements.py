"""Measurement tables (docs/model.md sec. 7): reading, checking, writing, black-cloth subtraction.

One observation a row, angles in degrees (docs/model.md sec. 1) in one of three forms:

- full:        ``theta_i, phi_i, theta_r, phi_r`` (polar angles in [0, 90), azimuths);
- in-plane:    ``theta_i, theta_r`` without phi columns (signed in-plane angles);
- goniometer:  ``psi, rho`` (theta_i = psi/2 + rho, theta_r = psi/2 - rho, signed).

``psi, rho`` may be given together with either theta form; the two must then describe the
same configuration (checked to 1e-6 deg). Column ``value`` is required and may be negative
(black-cloth subtracted data scatter around zero); ``sigma`` (standard deviation, >= 0) is
optional; every other column is kept and passed through unchanged.

Rows of a file are named by their physical line in the file, the header being line 1
("line 7 of meas.csv"); rows of a DataFrame by their index label.
See docs/measurements.md.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from ..engine.angles import (
    direction,
    from_goniometer,
    from_signed_inplane,
    to_goniometer,
    to_signed_inplane,
)
from ..errors import InputError, InputTypeError, MeasurementError, MissingFileError, NotAFileError
from ..io import write_text_atomic
from .channels import CHANNEL, channel_labels, channel_order, check_same_configurations

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
_RADIAN_LIMITS = {"theta_i": 1.6, "theta_r": 1.6, "rho": 1.6, "psi": 3.2, "phi_i": 6.3,
                  "phi_r": 6.3}
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
        if source is not None and lines is not None and len(lines) == len(table) \
                and table.index.equals(pd.RangeIndex(len(table))):
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
        return (f"{word} {', '.join(named)}" + (f" and {rest} more" if rest else "")
                + f" of {self.what}")


def _fmt(x: float) -> str:
    return f"{x:.10g}"


def _config_text(angles, k) -> str:
    ti, pi_, tr, pr = (a[k] for a in angles)
    return (f"theta_i={_fmt(ti)}, phi_i={_fmt(pi_)}, theta_r={_fmt(tr)}, phi_r={_fmt(pr)}")


# --------------------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------------------
def _form(columns, what: str) -> dict:
    """Which angle forms the columns hold; raises for incomplete or contradictory sets."""
    have = set(columns)
    pairs = (("psi", "rho"), ("theta_i", "theta_r"), ("phi_i", "phi_r"))
    for a, b in pairs:
        if (a in have) != (b in have):
            present, missing = (a, b) if a in have else (b, a)
            raise MeasurementError(
                f"{what} has column {present!r} but not {missing!r}: angle columns come in "
                f"pairs (theta_i,phi_i,theta_r,phi_r or theta_i,theta_r or psi,rho)")
    if "phi_i" in have and "theta_i" not in have:
        raise MeasurementError(f"{what} has phi_i and phi_r but no theta_i and theta_r columns")
    forms = {"full": "phi_i" in have, "inplane": "theta_i" in have and "phi_i" not in have,
             "goniometer": "psi" in have}
    if not any(forms.values()):
        raise MeasurementError(
            f"{what} has no angle columns: expected theta_i,phi_i,theta_r,phi_r (full), "
            f"theta_i,theta_r (signed in-plane) or psi,rho (goniometer), in degrees; "
            f"found columns {', '.join(map(str, columns))}")
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
                if cell is None or (isinstance(cell, float) and math.isnan(cell)) \
                        or (isinstance(cell, str) and not cell.strip()):
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
        problems.append((int(k), "is empty or NaN" if np.isnan(values[k])
                         else f"{values[k]!r} is not a finite number"))
    if problems:
        problems.sort()
        listed = "; ".join(f"{rows(k)}, column {column!r}: {msg}"
                           for k, msg in problems[:_MAX_LISTED])
        more = f"; and {len(problems) - _MAX_LISTED} more" if len(problems) > _MAX_LISTED else ""
        raise MeasurementError(listed + more + " (expected a finite number"
                               + (", in degrees)" if column in ANGLE_COLUMNS else ")"))
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
                raise _range_error(rows, bad, lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                                   f"{name} with phi columns is a polar angle in [0, 90) deg; "
                                   f"signed in-plane angles go without phi columns")
        for name in ("phi_i", "phi_r"):
            a = cols[name]
            bad = np.flatnonzero(np.abs(a) > 360)
            if bad.size:
                raise _range_error(rows, bad, lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                                   f"{name} is an azimuth in [-360, 360] deg")
        phi_i, phi_r = (_wrap(cols["phi_i"]), _wrap(cols["phi_r"]))
        result["full"] = (cols["theta_i"] + 0.0, phi_i, cols["theta_r"] + 0.0, phi_r)
    if forms["inplane"]:
        for name in ("theta_i", "theta_r"):
            a = cols[name]
            bad = np.flatnonzero(np.abs(a) >= 90)
            if bad.size:
                raise _range_error(rows, bad, lambda k, name=name, a=a: f"{name} = {_fmt(a[k])}",
                                   f"signed in-plane {name} must lie in (-90, 90) deg")
        ti, pi_, tr, pr = from_signed_inplane(cols["theta_i"], cols["theta_r"])
        result["inplane"] = (ti, pi_, tr, pr)
    if forms["goniometer"]:
        psi, rho = cols["psi"], cols["rho"]
        ti, tr = from_goniometer(psi, rho)
        bad = np.flatnonzero((np.abs(ti) >= 90) | (np.abs(tr) >= 90))
        if bad.size:
            raise _range_error(
                rows, bad, lambda k: (f"psi = {_fmt(psi[k])}, rho = {_fmt(rho[k])} give "
                                      f"theta_i = {_fmt(ti[k])}, theta_r = {_fmt(tr[k])}"),
                "theta_i = psi/2 + rho and theta_r = psi/2 - rho must lie in (-90, 90) deg")
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
                cols = {"full": "theta_i,phi_i,theta_r,phi_r", "inplane": "theta_i,theta_r",
                        "goniometer": "psi,rho"}
                raise _range_error(
                    rows, bad,
                    lambda k, cols=cols, other=other: (
                        f"{cols[names[0]]} give {_config_text(primary, k)} but "
                        f"{cols[other]} give {_config_text(found[other], k)}"),
                    f"ambiguous angles: the table has both {cols[names[0]]} and {cols[other]} "
                    f"columns and they disagree; keep one form or make them agree")
    return primary


def _warn_radians(cols: dict, what: str) -> bool:
    present = [c for c in _RADIAN_LIMITS if c in cols]
    if present and all(np.all(np.abs(cols[c]) < _RADIAN_LIMITS[c]) for c in present):
        warnings.warn(
            f"every angle in {what} is small (|theta|, |rho| < 1.6, |psi| < 3.2, |phi| < 6.3): "
            f"were they written in radians? veil reads angles in degrees (docs/model.md sec. 1)",
            LikelyRadiansWarning, stacklevel=3)
        return True
    return False


def _check_type(table) -> None:
    if not isinstance(table, pd.DataFrame):
        raise InputTypeError(f"expected a pandas DataFrame measurement table, got "
                             f"{type(table).__name__}")


def _check_columns(table: pd.DataFrame, what: str) -> None:
    dup = table.columns[table.columns.duplicated()].unique().tolist()
    if dup:
        raise MeasurementError(f"{what} has duplicate column names: {', '.join(map(repr, dup))}")
    if len(table) == 0:
        raise MeasurementError(f"{what} has no rows: expected one observation a row")


#: Key of a table's attrs recording which angles the radians warning was given for.
_RADIANS_WARNED = "veil_radians_warned"


def _parse_angles(table: pd.DataFrame, rows: RowNames, warn: bool = True):
    forms = _form(table.columns, rows.what)
    cols = {c: _numbers(table, c, rows) for c in ANGLE_COLUMNS if c in table.columns}
    if warn:
        # once per table: loading, validating and converting the same angles (as a fit
        # does) warn one time; the mark travels with the table's copies in attrs
        key = hash(tuple((c, v.tobytes()) for c, v in sorted(cols.items())))
        if table.attrs.get(_RADIANS_WARNED) != key and _warn_radians(cols, rows.what):
            table.attrs[_RADIANS_WARNED] = key
    return cols, _check_agreement(_angles_from(cols, forms, rows), rows)


def _duplicates(angles, rows: RowNames, positions: np.ndarray | None = None) -> None:
    """A MeasurementError for a configuration measured twice (among ``positions``: the rows
    of one channel; all rows when None)."""
    from scipy.spatial import cKDTree

    at = np.arange(len(angles[0])) if positions is None else positions
    vec = _vectors(angles)[at]
    pairs = sorted(cKDTree(vec).query_pairs(_SAME_RADIUS))
    pairs = [(int(at[i]), int(at[j])) for i, j in pairs
             if _separation(vec[i], vec[j]) <= SAME_TOL]
    if pairs:
        root: dict[int, int] = {}

        def find(i):
            while root.get(i, i) != i:
                i = root[i]
            return i

        for i, j in pairs:
            a, b = find(i), find(j)
            root[max(a, b)] = min(a, b)
        groups: dict[int, list[int]] = {}
        for k in sorted({k for pair in pairs for k in pair}):
            groups.setdefault(find(k), []).append(k)
        listed = [f"{' and '.join(rows(k) for k in g)} ({_config_text(angles, g[0])})"
                  for g in list(groups.values())[:_MAX_LISTED]]
        more = f"; and {len(groups) - _MAX_LISTED} more" if len(groups) > _MAX_LISTED else ""
        raise MeasurementError(
            f"duplicate configurations in {rows.what} (same angles within {SAME_TOL:g} deg): "
            + "; ".join(listed) + more + "; average repeated measurements into one row")


def _validated(table: pd.DataFrame, rows: RowNames | None = None) -> tuple[pd.DataFrame, tuple]:
    """Checked copy of ``table`` (known columns float64) and its canonical angles."""
    _check_type(table)
    rows = rows or RowNames(table)
    _check_columns(table, rows.what)
    if "value" not in table.columns:
        raise MeasurementError(f"{rows.what} has no 'value' column (the measured values); "
                               f"found columns {', '.join(map(str, table.columns))}")
    cols, angles = _parse_angles(table, rows)
    cols["value"] = _numbers(table, "value", rows)
    if "sigma" in table.columns:
        sigma = cols["sigma"] = _numbers(table, "sigma", rows)
        bad = np.flatnonzero(sigma < 0)
        if bad.size:
            raise _range_error(rows, bad, lambda k: f"sigma = {_fmt(float(sigma[k]))}",
                               "sigma is a standard deviation and must be >= 0")
    _check_configurations(table, angles, rows)
    out = table.copy()
    for c, v in cols.items():
        out[c] = v
    out.attrs = dict(table.attrs)
    return out, angles


def _check_configurations(table: pd.DataFrame, angles, rows: RowNames) -> None:
    """No configuration twice (in any one channel), and every channel the same ones."""
    if CHANNEL not in table.columns:
        _duplicates(angles, rows)
        return
    labels = channel_labels(table[CHANNEL], rows)
    for name in channel_order(labels):
        _duplicates(angles, rows, np.flatnonzero(labels == name))
    check_same_configurations(labels, _vectors(angles), rows,
                              lambda a, b: _separation(a, b) <= SAME_TOL, _SAME_RADIUS)


def table_channels(table: pd.DataFrame) -> np.ndarray | None:
    """The channel of every row of a table (docs/measurements.md, "Channels": ``r``, ``g``,
    ``b`` or a wavelength in nm, as text), None without a ``channel`` column."""
    if CHANNEL not in table.columns:
        return None
    return channel_labels(table[CHANNEL], RowNames(table))


def validate(table: pd.DataFrame) -> pd.DataFrame:
    """Check a measurement table (docs/model.md sec. 7) and return a copy with float columns.

    Raises :class:`MeasurementError` naming row and column for: no rows, missing ``value``,
    incomplete or disagreeing angle forms, empty/non-numeric/NaN/infinite cells, angles out
    of range, negative ``sigma``, duplicate configurations; with a ``channel`` column, an
    unknown channel, a wavelength out of range, or channels that measure different
    configurations (:mod:`veil.data.channels`). Warns
    (:class:`LikelyRadiansWarning`) if every angle is small enough to be radians. Negative
    ``value`` is allowed (black-subtracted data).
    """
    return _validated(table)[0]


def canonical_angles(table: pd.DataFrame) -> pd.DataFrame:
    """Copy of ``table`` with float columns theta_i, phi_i, theta_r, phi_r first (docs/model.md
    sec. 1).

    Polar angles are unsigned in [0, 90), azimuths in [0, 360), whatever the input form; the
    table's other columns follow in their order (signed in-plane theta_i, theta_r are
    replaced by the polar angle and azimuth they mean). Only the angle columns are checked.
    """
    _check_type(table)
    rows = RowNames(table)
    _check_columns(table, rows.what)
    _, angles = _parse_angles(table, rows)
    out = pd.DataFrame({name: a for name, a in zip(CANONICAL, angles)}, index=table.index)
    rest = [c for c in table.columns if c not in CANONICAL]
    out = pd.concat([out, table[rest]], axis=1)
    out.attrs = dict(table.attrs)
    return out


def to_form(table: pd.DataFrame, form: str) -> pd.DataFrame:
    """Copy of ``table`` with its angle columns rewritten in ``form`` (docs/model.md sec. 1).

    "full": theta_i, phi_i, theta_r, phi_r; "inplane": signed theta_i, theta_r;
    "goniometer": psi, rho and the signed theta_i, theta_r they imply (redundant, for
    plotting; checked on reading). Angle columns come first, the others follow in order.
    In-plane and goniometer forms need every row in the plane of incidence.
    """
    if form not in FORMS:
        raise InputError(f"form = {form!r}; expected one of {', '.join(FORMS)}")
    canon = canonical_angles(table)
    rows = RowNames(table)
    angles = tuple(canon[c].to_numpy() for c in CANONICAL)
    if form == "full":
        head = {c: a for c, a in zip(CANONICAL, angles)}
    else:
        try:
            ti, tr = to_signed_inplane(*angles)
        except ValueError:
            _, pi_, _, pr = angles
            off = np.flatnonzero(~(_inplane(angles[0], pi_, 180.0) & _inplane(angles[2], pr, 0.0)))
            raise _range_error(rows, off, lambda k: _config_text(angles, k),
                               f"not in the plane of incidence (phi 0 or 180 deg): cannot be "
                               f"written in the {form} form") from None
        if form == "inplane":
            head = {"theta_i": ti, "theta_r": tr}
        else:
            if "psi" in table.columns:
                psi, rho = _numbers(table, "psi", rows), _numbers(table, "rho", rows)
            else:
                psi, rho = to_goniometer(ti, tr)
            head = {"psi": psi, "rho": rho, "theta_i": ti, "theta_r": tr}
    out = pd.DataFrame(head, index=table.index)
    rest = [c for c in table.columns if c not in ANGLE_COLUMNS]
    out = pd.concat([out, table[rest]], axis=1)
    out.attrs = dict(table.attrs)
    return out


def _inplane(theta, phi, positive_at, tol=1e-6):
    d = np.abs(np.mod(phi - positive_at + 180.0, 360.0) - 180.0)
    return (theta < tol) | (d < tol) | (np.abs(d - 180.0) < tol)


# --------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------
def load_measurements(path) -> pd.DataFrame:
    """Read and check a measurement CSV (docs/model.md sec. 7; format in docs/measurements.md).

    Returns the table with its columns in file order; angle, ``value`` and ``sigma`` columns
    as float64 (exactly the decimal numbers written), other columns as pandas infers them.
    Errors name the line of the file (the header is line 1). See :func:`validate`.
    """
    path = Path(path)
    name = str(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise MissingFileError(f"measurement file {name} does not exist") from None
    except IsADirectoryError:
        raise NotAFileError(f"measurement file {name} is a directory, not a CSV file") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise MeasurementError(f"line {line} of {name} is not UTF-8 text (byte {exc.start}); "
                               f"expected a CSV text file") from None
    if not text.strip():
        raise MeasurementError(
            f"{name} is empty: expected a CSV header line naming the columns (value and angle "
            f"columns in degrees, e.g. psi,rho,value) and one row per observation")
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    header, header_line, records, lines = None, 0, [], []
    try:
        for rec in reader:
            if not rec or (len(rec) == 1 and not rec[0].strip()):
                continue  # blank line
            if header is None:
                header, header_line = [h.strip() for h in rec], reader.line_num
            else:
                records.append(rec)
                lines.append(reader.line_num)
    except csv.Error as exc:
        raise MeasurementError(f"line {reader.line_num} of {name} is not valid CSV: {exc}"
                               ) from None
    if header is None:  # nothing but blank cells (e.g. lines of "")
        raise MeasurementError(
            f"{name} has no header: every line is blank; expected a CSV header line naming "
            f"the columns (value and angle columns in degrees, e.g. psi,rho,value)")
    for k, h in enumerate(header):
        if not h:
            raise MeasurementError(f"column {k + 1} in the header (line {header_line}) of {name} "
                                   f"has no name")
    seen = set()
    for h in header:
        if h in seen:
            raise MeasurementError(f"the header (line {header_line}) of {name} names column "
                                   f"{h!r} twice")
        seen.add(h)
    for rec, line in zip(records, lines):
        if len(rec) != len(header):
            raise MeasurementError(f"line {line} of {name} has {len(rec)} fields but the header "
                                   f"(line {header_line}) has {len(header)}: {', '.join(header)}")
    if not records:
        raise MeasurementError(f"{name} has a header (line {header_line}) but no data rows")
    columns = list(zip(*records))
    data = {}
    other = [k for k, h in enumerate(header) if h not in KNOWN_COLUMNS]
    if other:
        inferred = _infer(header, columns, other)
    for k, h in enumerate(header):
        data[h] = pd.Series(list(columns[k]), dtype=object) if h in KNOWN_COLUMNS else inferred[h]
    table = pd.DataFrame(data)
    table.attrs["veil_source"] = name
    table.attrs["veil_lines"] = tuple(lines)
    out, _ = _validated(table, RowNames(table))
    return out


def _infer(header, columns, which) -> dict:
    """Pass-through columns typed as pandas infers them, floats parsed exactly."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow([header[k] for k in which])
    writer.writerows(zip(*(columns[k] for k in which)))
    buf.seek(0)
    frame = pd.read_csv(buf, dtype=None, keep_default_na=True)
    out = {}
    for k in which:
        h = header[k]
        series = frame[h]
        if pd.api.types.is_float_dtype(series.dtype):
            exact = series.to_numpy(dtype=float).copy()
            for j, cell in enumerate(columns[k]):
                if not math.isnan(exact[j]):
                    try:
                        exact[j] = float(cell)
                    except ValueError:
                        pass
            series = pd.Series(exact, name=h)
        out[h] = series
    return out


def save_measurements(table: pd.DataFrame, path) -> None:
    """Check ``table`` and write it as CSV to ``path`` atomically (docs/model.md sec. 7).

    Floats are written in the shortest form that reads back to the same number, so
    :func:`load_measurements` returns an equal table (same columns, same order, same
    floats). Rows and columns are written as they are; the index is not written.
    """
    write_text_atomic(path, measurements_text(table))


def measurements_text(table: pd.DataFrame) -> str:
    """The CSV text :func:`save_measurements` writes (``table`` checked first)."""
    checked, _ = _validated(table)
    frame = table.copy()
    for c in frame.columns:
        if c in KNOWN_COLUMNS:
            frame[c] = [repr(float(x)) for x in checked[c].to_numpy()]
        elif pd.api.types.is_float_dtype(frame[c].dtype):
            frame[c] = ["" if math.isnan(x) else repr(float(x))
                        for x in frame[c].to_numpy(dtype=float)]
    return frame.to_csv(index=False, lineterminator="\n")


__all__ = ["load_measurements", "save_measurements", "canonical_angles",
           "validate", "to_form", "MeasurementError", "measurements_text",
           "LikelyRadiansWarning", "CANONICAL", "FORMS", "table_channels", "CHANNEL"]
