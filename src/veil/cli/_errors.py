"""How the command line reports errors (docs/errors.md): the user's mistakes it finds
itself (:class:`UserError`, exit status 2) and a bug in veil (:func:`report_bug`, exit
status 3, the traceback written to a file)."""

from __future__ import annotations

import os
import sys
import tempfile

import click


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
    click.echo(
        f"veil: internal error, sorry - this is a bug in veil, not a mistake in your "
        f"input ({type(exc).__name__}: {exc}). "
        + (f"The traceback is in {where}; " if where else "")
        + "rerun with --debug to print it, and please report it.",
        err=True,
    )
    sys.exit(EXIT_BUG)
