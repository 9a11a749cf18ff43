"""Shared pieces of the command line: model options, user-error handling (exit status 2)."""

from __future__ import annotations

import math
import os
import re
import sys
import tempfile

import click
import numpy as np

from ..models import HenyeyGreenstein, TorranceSparrow, preset


class UserError(click.ClickException):
    """A mistake in the user's input found by the command line itself: printed without
    traceback, exit status 2 (veil's own :class:`veil.errors.InputError` gets the same)."""

    exit_code = 2


#: Exit statuses (docs/errors.md): 0 done; 1 done, but a fit did not converge or the data do
#: not determine it; 2 a mistake in the input; 3 a bug in veil; 130 / 143 interrupted.
EXIT_INPUT = 2
EXIT_BUG = 3


def report_bug(exc: BaseException, debug: bool) -> None:
    """Exit status 3 for an exception that is not the user's mistake: one line of apology
    and where the traceback was written (all of it on stderr with ``--debug``)."""
    import traceback

    text = "".join(traceback.format_exception(exc))
    if debug:
        click.echo(text, err=True, nl=False)
    where = None
    try:
        fd, where = tempfile.mkstemp(prefix="veil-crash-", suffix=".txt")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(f"veil {' '.join(sys.argv[1:])}\n\n{text}")
    except OSError:
        where = None
    click.echo(f"veil: internal error, sorry - this is a bug in veil, not a mistake in your "
               f"input ({type(exc).__name__}: {exc}). "
               + (f"The traceback is in {where}; " if where else "")
               + "rerun with --debug to print it, and please report it.", err=True)
    sys.exit(EXIT_BUG)


class VeilGroup(click.Group):
    """Exit statuses of every command: a :class:`veil.errors.InputError` (or an operating
    system error naming a file) is the user's mistake, printed as "Error: ..." with status 2;
    any other exception is a bug in veil (status 3, :func:`report_bug`)."""

    def invoke(self, ctx):
        from ..errors import InputError

        try:
            return super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.exceptions.Abort,
                KeyboardInterrupt, SystemExit):
            raise
        except InputError as exc:
            click.echo(f"Error: {exc}", err=True)
            sys.exit(EXIT_INPUT)
        except OSError as exc:
            if exc.filename is None:
                report_bug(exc, ctx.obj.get("debug", False) if ctx.obj else False)
            click.echo(f"Error: {exc.filename}: {exc.strerror or exc}", err=True)
            sys.exit(EXIT_INPUT)
        except Exception as exc:  # noqa: BLE001 - anything else is a bug in veil
            report_bug(exc, bool(ctx.obj and ctx.obj.get("debug")))


def parse_brdf(text: str):
    """Preset name (BRDF1, BRDF2) or literal 'PD,PS,N,ETA'."""
    return _parse(text, TorranceSparrow, "PD,PS,N,ETA", "BRDF")


def parse_btdf(text: str, variant: str = "paper"):
    """Preset name (BTDF1..3) or literal 'TD,TT,G,ETA'; 'none' means a clear medium."""
    if text.strip().lower() == "none":
        return None
    model = _parse(text, HenyeyGreenstein, "TD,TT,G,ETA", "BTDF")
    return model.replace(variant=variant)


def _parse(text, cls, form, kind):
    parts = [p.strip() for p in text.split(",")]
    if len(parts) == 1:
        try:
            model = preset(parts[0])
        except ValueError:
            raise UserError(f"{kind} {text!r} is neither a preset name nor a literal {form}") from None
        if not isinstance(model, cls):
            raise UserError(f"{text!r} is not a {kind} preset")
        return model
    if len(parts) != len(cls.PARAMS):
        raise UserError(f"{kind} literal {text!r} must have {len(cls.PARAMS)} numbers: {form}")
    values = []
    for p, s in zip(cls.PARAMS, parts):
        try:
            values.append(float(s))
        except ValueError:
            raise UserError(f"{kind} parameter {p.name} = {s!r} is not a number (form {form})") from None
    try:
        return cls(*values)
    except (ValueError, TypeError) as exc:
        raise UserError(str(exc)) from None


# -- CSV input -----------------------------------------------------------------------------

#: How error messages count rows: as lines of the file, the header line being row 1.
ROW_CONVENTION = "rows counted as lines of the file, header = row 1"


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
    import pandas as pd  # heavy; only commands that read CSV pay for it

    path = os.fspath(path)
    try:
        raw = pd.read_csv(path, header=None, dtype=str, keep_default_na=False,
                          skip_blank_lines=False, skipinitialspace=True, encoding="utf-8")
    except pd.errors.EmptyDataError:
        raise UserError(f"{path}: the file is empty; expected a header line naming the columns "
                        f"{expected or ', '.join(required)}, then one row per entry") from None
    except pd.errors.ParserError as exc:
        text = " ".join(str(exc).split())
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
        if m:
            raise UserError(f"{path}: row {m[2]} ({ROW_CONVENTION}) has {m[3]} fields but the "
                            f"header (row 1) has {m[1]}") from None
        raise UserError(f"{path}: not a well-formed CSV file ({text})") from None
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not UTF-8 text ({exc.reason}); save the file as UTF-8") from None
    header = [str(c) for c in raw.iloc[0].tolist()]
    if callable(required):
        required = tuple(required(header))
    body = raw.iloc[1:]
    missing = [c for c in required if c not in header]
    if missing:
        plural = "s" if len(missing) > 1 else ""
        raise UserError(f"{path}: missing column{plural} {', '.join(map(repr, missing))} "
                        f"(required: {', '.join(required)}); the header (row 1) has: "
                        f"{', '.join(map(repr, header))}")
    for c in required:
        if header.count(c) > 1:
            raise UserError(f"{path}: column {c!r} appears {header.count(c)} times in the "
                            f"header (row 1); it must appear once")
    blank = (body == "").all(axis=1).to_numpy()
    body = body[~blank]
    rows = body.index.to_numpy() + 1
    if len(body) == 0:
        raise UserError(f"{path}: no data rows after the header (row 1); expected one row per "
                        f"entry with columns {expected or ', '.join(required)}")
    table = pd.DataFrame(body.to_numpy(), columns=header)
    numbers = {}
    first_bad = None  # (row, column position, message): report the first in file order
    for k, c in enumerate(required):
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
                    first_bad = key + (f"{path}: row {rows[j]} ({ROW_CONVENTION}), column "
                                       f"{c!r}: {problem}; expected {unit}",)
                break
        numbers[c] = values
    if first_bad is not None:
        raise UserError(first_bad[2])
    return table, numbers, rows


# -- output files --------------------------------------------------------------------------

def check_output_path(output, inputs=()):
    """Fail early (UserError) if ``output`` cannot be written or is one of the ``inputs``."""
    output = os.fspath(output)
    for inp in inputs:
        if inp is None:
            continue
        inp = os.fspath(inp)
        same = (os.path.exists(output) and os.path.exists(inp) and os.path.samefile(output, inp))
        if same or os.path.abspath(output) == os.path.abspath(inp):
            raise UserError(f"output {output} is the input file {inp}; veil never overwrites "
                            f"an input: choose another output path")
    check_file_target(output, f"output {output}", output)


def check_file_target(path, named: str, written: str) -> None:
    """UserError unless ``path`` names a file in an existing, writable directory; messages
    call it ``named`` ("<named> is a directory") and ``written`` ("cannot write <written>")."""
    if os.path.isdir(path):
        raise UserError(f"{named} is a directory; give a file name")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise UserError(f"cannot write {written}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK):
        raise UserError(f"cannot write {written}: directory {directory} is not writable")


def write_atomic(path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically: :func:`veil.io.write_text_atomic`."""
    from ..io import write_text_atomic

    write_text_atomic(path, text)
