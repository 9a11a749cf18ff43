"""What can go wrong, by whose mistake (docs/errors.md has the exit codes).

Every mistake in what a user gives veil - a measurement table, a photo, an option, a model
parameter, a result file - raises an :class:`InputError` (or a subclass) whose message says
what is wrong and where (file, row, column, value, what was expected). The command line
prints that message and exits with status 2. Any other exception is a bug in veil: the
command line exits with status 3 and says where the traceback is.

The classes also derive from the built-in exception a Python caller would expect (an
:class:`InputError` is a ``ValueError``, an :class:`InputTypeError` a ``TypeError``, a
:class:`MissingFileError` a ``FileNotFoundError``), so ``except ValueError`` keeps working.
"""

from __future__ import annotations


class InputError(ValueError):
    """A mistake in the user's input; the message says what to fix."""


class InputTypeError(InputError, TypeError):
    """An input of the wrong type (a string where a number belongs, a BRDF for a medium)."""


class MissingFileError(InputError, FileNotFoundError):
    """An input file or folder that does not exist."""


class NotAFileError(InputError, IsADirectoryError):
    """A folder given where a file was expected."""


class UnwritableError(InputError, PermissionError):
    """An output that cannot be written (read-only folder, missing directory)."""


class MeasurementError(InputError):
    """A measurement table (or photo set) that cannot be used as it is."""


class ParameterError(InputError):
    """A model parameter or option outside its declared bounds or choices."""


class FitError(InputError):
    """A fit that cannot be set up (bad data, bad options, bad given model or result file)."""


__all__ = [
    "InputError",
    "InputTypeError",
    "MissingFileError",
    "NotAFileError",
    "UnwritableError",
    "MeasurementError",
    "ParameterError",
    "FitError",
]


class MissingExtraError(InputError, ImportError):
    """An optional dependency a command needs is not installed; the message has the pip line."""


__all__ += ["MissingExtraError"]


def as_flag(value, name: str, error: type[InputError] = InputError) -> bool:
    """An on/off argument ``name`` as a bool: True, False or a numpy bool; an ``error`` (an
    InputError) naming it for anything else (the string "no" or the number 2 would be true)."""
    if isinstance(value, bool):
        return value
    import numpy as np  # here: importing veil.errors stays cheap

    if isinstance(value, np.bool_):
        return bool(value)
    raise error(
        f"{name} = {value!r}: expected True or False (an on/off flag), got {type(value).__name__}"
    )


__all__ += ["as_flag"]
