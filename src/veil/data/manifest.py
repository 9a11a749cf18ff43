"""The manifest of a photo stack (docs/ingest.md): one row per photo, its file name in the
photo directory and its goniometer angles, checked before any photo is read, and the files
of the directory that it does not list."""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError, MissingFileError
from ..io import as_path, not_a_regular_file, other_encoding
from .photo_files import PHOTO_SUFFIXES

#: Columns :func:`ingest` adds to the manifest's (``black``, ``black_sigma`` only with a black ROI).
ADDED_COLUMNS = ("value", "sigma", "black", "black_sigma", "saturated", "clipped", "n_pixels")


def manifest_photos(manifest, photo_dir) -> tuple[pd.DataFrame, list[str], str, list[Path]]:
    """The manifest read (:func:`read_manifest`) and the paths of its photos:
    (table, row names, manifest name, paths); MissingFileError naming the rows whose photo is
    not in ``photo_dir``."""
    table, rows, name = read_manifest(manifest, photo_dir)
    paths = [photo_dir / f for f in table["file"]]
    missing = [(row, f) for row, f, p in zip(rows, table["file"], paths) if not p.is_file()]
    for row, f in missing:
        path = os.fspath(photo_dir / f)
        kind = "a directory" if os.path.isdir(path) else not_a_regular_file(path)
        if kind:
            raise InputError(
                f"{row}, column 'file': {f!r} is {kind} in {photo_dir}, not a photo file"
            )
    if missing:
        shown = "; ".join(f"{f!r} ({row})" for row, f in missing[:10])
        more = f" and {len(missing) - 10} more" if len(missing) > 10 else ""
        raise MissingFileError(
            f"{name}: {len(missing)} photo(s) listed in the manifest are not "
            f"in {photo_dir}: {shown}{more}"
        )
    return table, rows, name, paths


def read_csv_file(path, empty: str, data: bytes | None = None, **options) -> pd.DataFrame:
    """``pd.read_csv`` of the file ``path``, read once (``data``: its bytes, when read
    already), so that a pipe (``--manifest <(...)``) reads as a file does; an InputError
    saying ``empty`` for an empty file, or that it is not a readable CSV file (or which
    UTF-16/32 it is, not UTF-8)."""
    if data is None:
        with open(path, "rb") as fh:
            data = fh.read()
    try:
        return pd.read_csv(io.BytesIO(data), **options)
    except pd.errors.EmptyDataError:
        raise InputError(empty) from None
    except (pd.errors.ParserError, UnicodeDecodeError) as exc:
        said = isinstance(exc, UnicodeDecodeError) and other_encoding(path, data[:4])
        raise InputError(said or _unreadable(path, exc, data)) from None


def _unreadable(path, exc: Exception, data: bytes) -> str:
    """Why the CSV file ``path`` could not be read, in the file's lines: a row with more
    cells than the header, or the first byte that is not UTF-8 text."""
    text = " ".join(str(exc).split())
    found = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
    if found:
        wanted, line, seen = found.groups()
        return (
            f"line {line} of {path} has {seen} cells, but the header has {wanted} columns; "
            f"quote a cell that holds a comma, or add the missing column names to the header"
        )
    found = re.search(r"EOF inside string starting at row (\d+)", text)
    if found:
        line = int(found.group(1)) + 1  # pandas counts rows from 0, the header's included
        return (
            f'line {line} of {path} opens a quoted cell (") that is never closed; close the '
            f"quote or remove it"
        )
    if isinstance(exc, UnicodeDecodeError):
        try:
            data.decode("utf-8")
        except UnicodeDecodeError as bad:
            line = data.count(b"\n", 0, bad.start) + 1
            return (
                f"{path} is not UTF-8 text: line {line} holds the byte 0x{data[bad.start]:02x}, "
                f"which is not UTF-8 ({bad.reason}); save the file as UTF-8 (a spreadsheet's "
                f"'CSV UTF-8'; Latin-1 text: iconv -f LATIN1 -t UTF-8)"
            )
    return f"{path}: not a readable CSV file ({text})"


def _manifest_table(manifest) -> tuple[pd.DataFrame, list[str], str]:
    """The manifest (a DataFrame, or a CSV file without its blank lines), a name for each
    row and its own name."""
    if isinstance(manifest, pd.DataFrame):
        name = "the manifest"
        table = manifest.copy()
        table.attrs = {"veil_name": name}
        rows = [f"row {label!r} (index label) of {name}" for label in table.index]
    else:
        name = as_path(manifest, "manifest")
        try:
            with open(name, "rb") as fh:
                data = fh.read()
        except FileNotFoundError:
            raise MissingFileError(f"manifest {name}: no such file") from None
        raw = read_csv_file(
            name,
            f"{name}: the manifest is empty; expected a header with 'file' and "
            f"angle columns, then one row per photo",
            data,
            skipinitialspace=True,
            keep_default_na=False,
            na_values=[""],
            dtype={"file": str},
            skip_blank_lines=False,
        )
        raw.columns = [str(c).strip() for c in _header(data, raw.columns)]
        kept = ~raw.isna().all(axis=1).to_numpy()  # blank lines
        lines = (np.flatnonzero(kept) + 2).tolist()
        table = raw[kept].reset_index(drop=True)
        table.attrs = {"veil_source": name, "veil_lines": tuple(lines)}
        rows = [f"line {line} of {name}" for line in lines]
    return table, rows, name


def _header(data: bytes, columns) -> list:
    """The header of a CSV file (its bytes ``data``) as written: pandas renames a repeated
    column name (``theta_i`` -> ``theta_i.1``), which would hide it from the duplicate check."""
    first = pd.read_csv(
        io.BytesIO(data),
        header=None,
        nrows=1,
        dtype=str,
        keep_default_na=False,
        skipinitialspace=True,
    )
    header = first.iloc[0].tolist() if len(first) else []
    if len(header) != len(columns):
        return list(columns)
    return [h if h.strip() else c for h, c in zip(header, columns)]  # blank: "Unnamed: k"


def _manifest_files(table: pd.DataFrame, rows: list[str], photo_dir) -> list[str]:
    """The ``file`` column checked: each a path inside ``photo_dir``, none twice."""
    seen: dict[Path, str] = {}
    root = Path(photo_dir).resolve()
    files = []
    for row, cell in zip(rows, table["file"].tolist()):
        where = f"{row}, column 'file'"
        if not isinstance(cell, str) or cell.strip() == "":
            raise InputError(f"{where}: empty; expected the photo's file name in PHOTO_DIR")
        if "\x00" in cell:
            raise InputError(
                f"{where}: {cell!r} holds a NUL byte (\\x00), which no file name can hold; "
                f"expected the photo's file name in PHOTO_DIR (is the manifest a text file?)"
            )
        rel = Path(cell.strip())
        if rel.is_absolute() or not (root / rel).resolve().is_relative_to(root):
            link = os.path.islink(root / rel)
            raise InputError(
                f"{where}: {cell!r} is not a path inside PHOTO_DIR ({photo_dir})"
                + (f": a symbolic link to {(root / rel).resolve()}" if link else "")
                + "; give file names relative to PHOTO_DIR"
            )
        key = (root / rel).resolve()
        if key in seen:
            raise InputError(
                f"{where}: {cell!r} is listed again (first on {seen[key]}); each "
                f"photo has one geometry"
            )
        seen[key] = row
        files.append(cell.strip())
    return files


def _mark_hint(columns) -> str:
    """A note for a header that holds a byte-order mark after the first (an editor that adds
    one to a file that had one): pandas keeps the second in the first column's name."""
    for name in map(str, columns):
        if "\ufeff" in name:
            clean = name.replace("\ufeff", "")
            return (
                f" (column {name!r} is {clean!r} after a repeated byte-order mark, U+FEFF: "
                f"remove it, saving the file as UTF-8 once)"
            )
    return ""


def read_manifest(manifest, photo_dir) -> tuple[pd.DataFrame, list[str], str]:
    """The manifest (all its columns; angles as float), a name for each row, its own name.

    Checks the column names (none twice), the ``file`` column (present, non-empty, unique,
    inside ``photo_dir``) and the angle columns (one of the three forms of
    :mod:`veil.measurements`, no configuration twice).
    Rows of a file are named by their line (header = line 1), as :mod:`veil.measurements` does.
    """
    from .measurements import ANGLE_COLUMNS, check_column_names, validate
    from .table_angles import separator_hint

    table, rows, name = _manifest_table(manifest)
    check_column_names(table.columns, name)
    if "file" not in table.columns:
        raise InputError(
            f"{name}: no column 'file'; the header has "
            f"{', '.join(map(repr, map(str, table.columns)))}; the manifest names "
            f"each photo (relative to PHOTO_DIR) in a column 'file'"
            f"{separator_hint(table.columns)}{_mark_hint(table.columns)}"
        )
    if len(table) == 0:
        raise InputError(f"{name}: no photos listed (no rows after the header)")
    clash = [c for c in ADDED_COLUMNS if c in table.columns]
    if clash:
        raise InputError(
            f"{name}: column(s) {', '.join(map(repr, clash))} would be "
            f"overwritten by ingest's results; rename or remove them"
        )
    files = _manifest_files(table, rows, photo_dir)
    table["file"] = files
    probe = table.assign(value=0.0)
    probe.attrs = dict(table.attrs)
    checked = validate(probe)  # angle forms, ranges, duplicate configurations
    for column in ANGLE_COLUMNS:
        if column in table.columns:
            table[column] = checked[column].to_numpy()
    return table.reset_index(drop=True), rows, name


def unlisted_photos(photo_dir: Path, listed: set, ignore: set) -> list[str]:
    """Photo files in ``photo_dir`` (and the sub-folders the manifest uses) not in ``listed``."""
    folders = {photo_dir.resolve()} | {p.parent for p in listed}
    extra = []
    for folder in sorted(folders):
        for entry in sorted(folder.iterdir()):
            if (
                entry.is_file()
                and entry.suffix.lower() in PHOTO_SUFFIXES
                and entry.resolve() not in listed
                and entry.resolve() not in ignore
            ):
                extra.append(os.path.relpath(entry, photo_dir))
    return extra


# -- ingest --------------------------------------------------------------------------------


__all__ = [
    "ADDED_COLUMNS",
    "manifest_photos",
    "read_csv_file",
    "read_manifest",
    "unlisted_photos",
]
