"""The fits' arguments that name things, checked where they enter: a family's ``options``
(a dict), parameter names (``free=``, the joint fit's ``shared=`` and ``per_medium=``) and a
fit's ``start`` given as {name: value}. Each is a :class:`~veil.errors.FitError` naming the
argument and what it takes (and a parameter both fixed and freed); ``fixed=`` and
``max_nfev=`` are checked in :mod:`veil.fitting.solver`."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

from ..errors import FitError


def as_options(options, what: str = "options") -> dict:
    """A family's options as a new dict ({} for None); a FitError for anything but a dict."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise FitError(
            f"{what} = {options!r}; expected a dict of the family's options, e.g. "
            f"{{'distribution': 'ggx'}}"
        )
    return dict(options)


def as_names(names, what: str) -> list[str] | None:
    """Parameter names as a list (None for None): a list of strings, or one string of names
    separated by commas ("g" or "g,eta_u"); a FitError for anything else (a number, a
    string's characters would be no names)."""
    if names is None:
        return None
    if isinstance(names, str):
        return [n for n in names.replace(" ", "").split(",") if n]
    if isinstance(names, Mapping) or not isinstance(names, Iterable):
        raise FitError(f"{what} = {names!r}; expected a list of parameter names, e.g. ['s']")
    listed = list(names)
    bad = [n for n in listed if not isinstance(n, str)]
    if bad:
        raise FitError(f"{what} lists {bad[0]!r}; expected parameter names (strings), e.g. ['s']")
    return listed


def as_start(start, names: list[str], family: str) -> dict:
    """A fit's ``start`` given as {name: value} checked: a dict naming parameters of the
    family (``names``) with numbers (their bounds are checked where the start is used);
    a FitError otherwise."""
    if not isinstance(start, Mapping):
        raise FitError(
            f"start = {start!r}; expected a fit result of {family} or a dict "
            f"{{name: value}} of its parameters ({', '.join(names)})"
        )
    unknown = [k for k in start if k not in names]
    if unknown:
        raise FitError(
            f"start names {', '.join(map(repr, unknown))}: {family} has parameters "
            f"{', '.join(names)}"
        )
    for k, v in start.items():
        number = isinstance(v, (int, float, np.integer, np.floating))
        if isinstance(v, (bool, np.bool_)) or not number or not math.isfinite(v):
            raise FitError(f"start {k} = {v!r} is not a finite number")
    return {k: float(v) for k, v in start.items()}


def refuse_fixed_and_freed(fixed, freed) -> None:
    """A FitError naming the parameters both in ``fixed`` and in ``freed``: a parameter is
    held at its fixed value or fitted, not both."""
    clash = [n for n in freed if n in fixed]
    if clash:
        raise FitError(
            f"{', '.join(clash)} both fixed and freed: a parameter is held at its fixed "
            "value or fitted (freed: one its family holds by default), not both; give one"
        )


__all__ = ["as_options", "as_names", "as_start", "refuse_fixed_and_freed"]
