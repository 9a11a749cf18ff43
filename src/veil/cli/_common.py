"""Shared pieces of the command line: model options, user-error handling (exit status 2)."""

from __future__ import annotations

import sys

import click

from ..models import HenyeyGreenstein, TorranceSparrow, preset


class UserError(click.ClickException):
    """A mistake in the user's input: printed without traceback, exit status 2."""

    exit_code = 2


class VeilGroup(click.Group):
    """Turns ValueError/TypeError/OSError raised by veil on user input into exit status 2."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (ValueError, TypeError, FileNotFoundError, IsADirectoryError, PermissionError) as exc:
            if isinstance(exc, click.ClickException):
                raise
            click.echo(f"Error: {exc}", err=True)
            sys.exit(2)


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
