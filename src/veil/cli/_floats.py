"""The number types of the command's options: a range that refuses nan too
(:class:`FloatRange`), a finite number (:class:`FiniteFloat`, :data:`FINITE`). Imported by
the commands from :mod:`veil.cli._common`."""

from __future__ import annotations

import math

import click


class FloatRange(click.FloatRange):
    """``click.FloatRange`` that refuses nan too (nan passes click's comparisons)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if math.isnan(number):
            self.fail(f"{value!r} is not a number; expected {self._describe_range()}", param, ctx)
        return number


class FiniteFloat(click.types.FloatParamType):
    """A float option of which only a finite number is meaningful (an angle, a step, a
    scale...): nan and inf are refused when the command line is read, naming the option."""

    name = "float"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


#: The type of those float options (:class:`FiniteFloat`).
FINITE = FiniteFloat()
