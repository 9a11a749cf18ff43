"""CSV input of the command line (``veil eval --configs``): every cell read as text, the
required columns parsed, and every problem a :class:`UserError` naming the file, the row and
the column."""

from __future__ import annotations

import math
import os
import re

from ._common import UserError

#: How error messages count rows: as lines of the file, the header line being row 1.
ROW_CONVENTION = "rows counted as lines of the file, header = row 1"


def _read_cells(path: str, required, expected):
    """Every cell of a CSV file as text (pandas), or a UserError naming the file."""
    import pandas as pd

    try:
        return pd.read_csv(
            path,
            header=None,
            dtype=str,
            keep_default_na=False,
            skip_blank_lines=False,
            skipinitialspace=True,
            encoding="utf-8",
        )
    except pd.errors.EmptyDataError:
        columns = expected or ", ".join(required) if not callable(required) else expected
        raise UserError(
            f"{path}: the file is empty; expected a header line naming the columns "
            f"{columns}, then one row per entry"
        ) from None
    except pd.errors.ParserError as exc:
        text = " ".join(str(exc).split())
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
        if m:
            raise UserError(
                f"{path}: row {m[2]} ({ROW_CONVENTION}) has {m[3]} fields but the "
                f"header (row 1) has {m[1]}"
            ) from None
        raise UserError(f"{path}: not a well-formed CSV file ({text})") from None
    except UnicodeDecodeError as exc:
        from ..io import other_encoding

        raise UserError(
            other_encoding(path) or f"{path}: not UTF-8 text ({exc.reason}); save the file as UTF-8"
        ) from None


def read_csv_table(path, required, *, unit="a number", expected=None):
    """Read a CSV file with pandas, keeping every cell as text, and parse ``required`` columns.

    Returns ``(table, numbers, rows)``: ``table`` is a DataFrame of strings with every column
    of the file in file order (for passthrough; lines that are entirely blank are dropped),
    ``numbers`` maps each required column to a float array (finite values only) and ``rows``
    holds each kept row's number in the file (header = row 1). Any problem - unreadable,
    empty, ragged, a required column missing or duplicated, an empty, non-numeric or
    non-finite cell - raises :class:`UserError` naming the file, the row and the column.
    ``unit`` words what a cell should hold, e.g. "an angle in degrees"; ``expected`` the
    columns a file should have, for messages (default: ``required``). ``required`` may be a
    function of the header (list of column names) returning the columns to parse.
    """
    import numpy as np
    import pandas as pd  # heavy; only commands that read CSV pay for it

    path = os.fspath(path)
    raw = _read_cells(path, required, expected)
    header = [str(c) for c in raw.iloc[0].tolist()]
    if callable(required):
        required = tuple(required(header))
    body = raw.iloc[1:]
    missing = [c for c in required if c not in header]
    if missing:
        plural = "s" if len(missing) > 1 else ""
        raise UserError(
            f"{path}: missing column{plural} {', '.join(map(repr, missing))} "
            f"(required: {', '.join(required)}); the header (row 1) has: "
            f"{', '.join(map(repr, header))}"
        )
    for c in required:
        if header.count(c) > 1:
            raise UserError(
                f"{path}: column {c!r} appears {header.count(c)} times in the "
                f"header (row 1); it must appear once"
            )
    blank = (body == "").all(axis=1).to_numpy()
    body = body[~blank]
    rows = body.index.to_numpy() + 1
    if len(body) == 0:
        raise UserError(
            f"{path}: no data rows after the header (row 1); expected one row per "
            f"entry with columns {expected or ', '.join(required)}"
        )
    table = pd.DataFrame(body.to_numpy(), columns=header)
    numbers = {}
    first_bad = None  # (row, column position, message): report the first in file order
    for c in required:
        cells = body.iloc[:, header.index(c)].tolist()
        values = np.empty(len(cells))
        for j, cell in enumerate(cells):
            text = cell.strip()
            problem = None
            if text == "":
                problem = "empty cell"
            else:
                try:
                    values[j] = float(text)
                except ValueError:
                    problem = f"{cell!r} is not a number"
                else:
                    if not math.isfinite(values[j]):
                        problem = f"{cell!r} is not a finite number"
            if problem is not None:
                key = (int(rows[j]), header.index(c))
                if first_bad is None or key < first_bad[:2]:
                    first_bad = key + (
                        f"{path}: row {rows[j]} ({ROW_CONVENTION}), column "
                        f"{c!r}: {problem}; expected {unit}",
                    )
                break
        numbers[c] = values
    if first_bad is not None:
        raise UserError(first_bad[2])
    return table, numbers, rows
