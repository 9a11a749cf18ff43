"""How the command line reports errors (docs/errors.md): the user's mistakes it finds
itself (:class:`UserError`, exit status 2) and a bug in veil (:func:`report_bug`, exit
status 3, the traceback written to a file)."""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile

import click

from ..errors import InputError


class UserError(click.ClickException):
    """A mistake in the user's input found by the command line itself: printed without
    traceback, exit status 2 (veil's own :class:`veil.errors.InputError` gets the same)."""

    exit_code = 2


def option_words(text: str, names: dict) -> str:
    """``text`` (a message of veil's library) with the Python keywords in ``names`` said as
    the command's options: ``fine_step = 0.1 deg`` -> ``--fine-step 0.1 deg``, ``give
    reference=`` -> ``give --reference``, ``fixed={...} (--fix 'X=...')`` -> ``--fix 'X=...'``.
    A keyword followed by "in Python" (the library naming both) is left alone."""
    for word, option in names.items():
        # not inside a path, a quoted name or a longer word
        w = rf"(?<![\w.\[/\\'\"-]){re.escape(word)}"
        said = option.replace("\\", "\\\\")  # literal in a replacement
        # fixed={...} (--fix ...), its dict of one level of dicts at most (the pipeline's)
        text = re.sub(w + r"=\{(?:[^{}]|\{[^{}]*\})*\}\s*\((--[^()]*)\)", r"\1", text)
        # "word = value" said as "--option value", unless the option follows already
        text = re.sub(w + r" = (?![^()\s]*\s*\(" + re.escape(option) + r"\))", said + " ", text)
        text = re.sub(w + r"=(?=[\s,;)]|$)(?! in Python)", said, text)
    return text


def family_words(text: str) -> str:
    """``text`` with the Python class names of model families said as the families' names,
    as the options and ``veil models`` give them: ``TorranceSparrow.Pd = -1`` ->
    ``torrance-sparrow Pd = -1``, ``HenyeyGreenstein.variant`` -> ``henyey-greenstein
    variant``. (No model was made if the registry was never imported.)"""
    registry = sys.modules.get("veil.models.registry")
    for cls in set(getattr(registry, "REGISTRY", {}).values()):
        names = (*cls.param_names(), *cls.option_names())  # a parameter or an option
        params = "|".join(map(re.escape, names))
        if params:  # ClassName.parameter only: never a file named after the class
            pattern = rf"(?<![\w/\\.-]){re.escape(cls.__name__)}\.(?=(?:{params})\b)"
            text = re.sub(pattern, f"{cls.NAME} ", text)
    return text


@contextlib.contextmanager
def options_named(names: dict, words=None):
    """Within the block (or the decorated command), an :class:`veil.errors.InputError` of the
    library names the command's options (``names``: Python keyword -> option, e.g.
    ``{"max_relative": "--max-relative"}``) instead of its Python keywords
    (:func:`option_words`), then says what else ``words`` (text -> text) says in the
    command's terms, as does a :class:`UserError` passing one on; the exception is
    re-raised with the new words."""

    def said(text: str) -> str:
        text = option_words(text, names)
        return words(text) if words else text

    try:
        yield
    except UserError as exc:
        raise UserError(said(exc.message)) from exc.__cause__
    except InputError as exc:
        text = said(str(exc))
        if text != str(exc):
            exc.args = (text,)
        raise


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
