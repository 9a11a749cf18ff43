"""Measurement tables (docs/model.md sec. 7): reading, checking, writing, black-cloth subtraction.

One observation a row, angles in degrees (docs/model.md sec. 1) in one of three forms
(parsed and checked by :mod:`veil.data.table_angles`):

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
from pathlib import Path

import numpy as np
import pandas as pd

from ..engine.angles import (
    to_goniometer,
    to_signed_inplane,
)
from ..errors import InputError, InputTypeError, MeasurementError, MissingFileError, NotAFileError
from ..io import as_path, other_encoding, write_text_atomic
from .channels import CHANNEL, channel_labels, channel_order, check_same_configurations
from .table_angles import (
    _MAX_LISTED,
    _SAME_RADIUS,
    ANGLE_COLUMNS,
    CANONICAL,
    FORMS,
    KNOWN_COLUMNS,
    SAME_TOL,
    LikelyRadiansWarning,
    RowNames,
    _angles_from,
    _check_agreement,
    _config_text,
    _fmt,
    _form,
    _numbers,
    _range_error,
    _separation,
    _vectors,
    _warn_radians,
    check_header_text,
    separator_hint,
)


def _check_type(table) -> None:
    if not isinstance(table, pd.DataFrame):
        raise InputTypeError(
            f"expected a pandas DataFrame measurement table, got {type(table).__name__}"
        )


def check_column_names(columns, what: str) -> None:
    """MeasurementError naming the column names repeated in ``columns`` (of table ``what``)."""
    columns = pd.Index(columns)
    dup = columns[columns.duplicated()].unique().tolist()
    if dup:
        raise MeasurementError(f"{what} has duplicate column names: {', '.join(map(repr, dup))}")


def _check_columns(table: pd.DataFrame, what: str) -> None:
    check_column_names(table.columns, what)
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


def _duplicates(
    angles, rows: RowNames, positions: np.ndarray | None = None, where: str = ""
) -> None:
    """A MeasurementError for a configuration measured twice (among ``positions``: the rows
    of one channel, which ``where`` names; all rows when None)."""
    from scipy.spatial import cKDTree

    at = np.arange(len(angles[0])) if positions is None else positions
    vec = _vectors(angles)[at]
    pairs = sorted(cKDTree(vec).query_pairs(_SAME_RADIUS))
    pairs = [(int(at[i]), int(at[j])) for i, j in pairs if _separation(vec[i], vec[j]) <= SAME_TOL]
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
        listed = [
            f"{' and '.join(rows(k) for k in g)} ({_config_text(angles, g[0])})"
            for g in list(groups.values())[:_MAX_LISTED]
        ]
        more = f"; and {len(groups) - _MAX_LISTED} more" if len(groups) > _MAX_LISTED else ""
        raise MeasurementError(
            f"duplicate configurations in {rows.what}{where} (same angles within "
            f"{SAME_TOL:g} deg): "
            + "; ".join(listed)
            + more
            + "; average repeated measurements into one row"
        )


def _validated(table: pd.DataFrame, rows: RowNames | None = None) -> tuple[pd.DataFrame, tuple]:
    """Checked copy of ``table`` (known columns float64) and its canonical angles."""
    _check_type(table)
    rows = rows or RowNames(table)
    _check_columns(table, rows.what)
    if "value" not in table.columns:
        raise MeasurementError(
            f"{rows.what} has no 'value' column (the measured values); "
            f"found columns {', '.join(map(str, table.columns))}"
            f"{separator_hint(table.columns)}"
        )
    cols, angles = _parse_angles(table, rows)
    cols["value"] = _numbers(table, "value", rows)
    if "sigma" in table.columns:
        sigma = cols["sigma"] = _numbers(table, "sigma", rows)
        bad = np.flatnonzero(sigma < 0)
        if bad.size:
            raise _range_error(
                rows,
                bad,
                lambda k: f"sigma = {_fmt(float(sigma[k]))}",
                "sigma is a standard deviation and must be >= 0",
            )
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
    cells = table[CHANNEL].astype(str).str.strip()
    for name in channel_order(labels):
        at = np.flatnonzero(labels == name)
        spelt = sorted(set(cells.iloc[at]))
        where = f", channel {name!r}" + (
            f" (column {CHANNEL!r} writes it {' and '.join(map(repr, spelt))}: one channel)"
            if len(spelt) > 1
            else ""
        )
        _duplicates(angles, rows, at, where)
    check_same_configurations(
        labels, _vectors(angles), rows, lambda a, b: _separation(a, b) <= SAME_TOL, _SAME_RADIUS
    )


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
            raise _range_error(
                rows,
                off,
                lambda k: _config_text(angles, k),
                f"not in the plane of incidence (phi 0 or 180 deg): cannot be "
                f"written in the {form} form",
            ) from None
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
def _decoded(raw: bytes, name: str) -> str:
    """The text of a measurement file's bytes: UTF-8, with or without a byte-order mark; a
    MeasurementError naming the line otherwise (UTF-16 or UTF-32 said as such)."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise MeasurementError(
            other_encoding(name, raw[:4])
            or f"line {line} of {name} is not UTF-8 text (byte {exc.start}); expected a CSV "
            f"text file"
        ) from None


def load_measurements(path) -> pd.DataFrame:
    """Read and check a measurement CSV (docs/model.md sec. 7; format in docs/measurements.md).

    Returns the table with its columns in file order; angle, ``value`` and ``sigma`` columns
    as float64 (exactly the decimal numbers written), other columns as pandas infers them.
    Errors name the line of the file (the header is line 1). See :func:`validate`.
    """
    path = Path(as_path(path, "path"))
    name = str(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise MissingFileError(f"measurement file {name} does not exist") from None
    except IsADirectoryError:
        raise NotAFileError(f"measurement file {name} is a directory, not a CSV file") from None
    text = _decoded(raw, name)
    if not text.strip():
        raise MeasurementError(
            f"{name} is empty: expected a CSV header line naming the columns (value and angle "
            f"columns in degrees, e.g. psi,rho,value) and one row per observation"
        )
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
        raise MeasurementError(
            f"line {reader.line_num} of {name} is not valid CSV: {exc}"
        ) from None
    if header is None:  # nothing but blank cells (e.g. lines of "")
        raise MeasurementError(
            f"{name} has no header: every line is blank; expected a CSV header line naming "
            f"the columns (value and angle columns in degrees, e.g. psi,rho,value)"
        )
    check_header_text(header, name)
    for k, h in enumerate(header):
        if not h:
            raise MeasurementError(
                f"column {k + 1} in the header (line {header_line}) of {name} has no name"
            )
    seen = set()
    for h in header:
        if h in seen:
            raise MeasurementError(
                f"the header (line {header_line}) of {name} names column {h!r} twice"
            )
        seen.add(h)
    for rec, line in zip(records, lines):
        if len(rec) != len(header):
            raise MeasurementError(
                f"line {line} of {name} has {len(rec)} fields but the header "
                f"(line {header_line}) has {len(header)}: {', '.join(header)}"
            )
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
    # a line of blanks is a row of blank cells, not a line to skip (the rows must stay
    # aligned with the file's; csv writes a row of one empty cell as "")
    frame = pd.read_csv(buf, dtype=None, keep_default_na=True, skip_blank_lines=False)
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
    text = measurements_text(table)
    write_text_atomic(as_path(path, "path"), text)


def measurements_text(table: pd.DataFrame) -> str:
    """The CSV text :func:`save_measurements` writes (``table`` checked first)."""
    checked, _ = _validated(table)
    frame = table.copy()
    for c in frame.columns:
        if c in KNOWN_COLUMNS:
            frame[c] = [repr(float(x)) for x in checked[c].to_numpy()]
        elif pd.api.types.is_float_dtype(frame[c].dtype):
            frame[c] = [
                "" if math.isnan(x) else repr(float(x)) for x in frame[c].to_numpy(dtype=float)
            ]
    return frame.to_csv(index=False, lineterminator="\n")


__all__ = [
    "load_measurements",
    "save_measurements",
    "canonical_angles",
    "validate",
    "to_form",
    "MeasurementError",
    "measurements_text",
    "LikelyRadiansWarning",
    "CANONICAL",
    "FORMS",
    "table_channels",
    "CHANNEL",
]
