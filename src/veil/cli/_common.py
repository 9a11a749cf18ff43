"""Shared pieces of the command line: the commands' group, the given models loaded, progress,
warnings and outputs; the model options (:mod:`veil.cli._model_options`) and the error
handling (:mod:`veil.cli._errors`) are imported from here too."""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
import time
import warnings
from pathlib import Path

import click

from ..errors import InputError
from ._errors import EXIT_INPUT, UserError, family_words, options_named, report_bug

# the number types of options, imported by the commands from here
from ._floats import FINITE as FINITE
from ._floats import FiniteFloat as FiniteFloat
from ._floats import FloatRange as FloatRange

# the model options, imported by the commands from here
from ._model_options import ModelChoice as ModelChoice
from ._model_options import ModelName as ModelName
from ._model_options import fix_value as fix_value
from ._model_options import model_error_option as model_error_option
from ._model_options import model_options as model_options
from ._model_options import parse_fix as parse_fix
from ._model_options import propagation_option as propagation_option


def parse_psi(text: str) -> tuple[float, ...]:
    """``--psi 30,60,90``: the light-camera angles in degrees."""
    values = []
    for part in text.split(","):
        try:
            values.append(float(part))
        except ValueError:
            raise UserError(
                f"--psi {text!r}: {part.strip()!r} is not a number (expected "
                f"comma-separated angles in degrees, e.g. 30,60,90)"
            ) from None
    return tuple(values)


def empty_path(what: str = "file") -> str:
    """The message of an empty output path, which would name the current directory."""
    return f"the path is empty; give a {what} name"


class OutputPath(click.Path):
    """``click.Path`` of an output: a file, or (``file_okay=False``, or ``what="folder"``) a
    folder. An empty value is refused at once with status 2, naming the option: it would
    be the current directory, and a folder's outputs would land among the user's files."""

    def __init__(self, *args, what: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.what = what or ("file" if self.file_okay else "folder")

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value:
            self.fail(empty_path(self.what), param, ctx)
        if value == "-":  # (click's convention for standard output, which veil does not take)
            self.fail(
                f"'-' would be a {self.what} named '-', not standard output: veil writes "
                f"each output to a {self.what} of its own, whole or not at all; give its name",
                param,
                ctx,
            )
        if isinstance(value, str) and self.what == "file":
            from ..io import output_file_problem  # (here: the command line starts fast)

            wrong = output_file_problem(value)
            if wrong:
                self.fail(f"cannot write {value}: {wrong}", param, ctx)
        return super().convert(value, param, ctx)


class LazyGroup(click.Group):
    """A group whose commands are imported when they are used (run, or their help shown):
    ``lazy`` maps a command's name to ``"module:attribute"`` in :mod:`veil.cli`; a name
    ``"group sub"`` is the subcommand ``sub`` of the group ``group`` (itself a LazyGroup, or
    given it eagerly). Commands added with :meth:`add_command` work as in any group."""

    def __init__(self, *args, lazy=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.lazy = dict(lazy or {})

    def list_commands(self, ctx):
        return sorted(set(self.commands) | {n for n in self.lazy if " " not in n})

    def get_command(self, ctx, name):
        if name not in self.commands and name in self.lazy:
            self.add_command(self._load(name), name)
        return self.commands.get(name)

    def _load(self, name: str) -> click.Command:
        module, _, attribute = self.lazy[name].partition(":")
        command = getattr(importlib.import_module(f"veil.cli.{module}"), attribute)
        subcommands = {
            k[len(name) + 1 :]: v for k, v in self.lazy.items() if k.startswith(name + " ")
        }
        if subcommands:
            if isinstance(command, LazyGroup):
                command.lazy.update(subcommands)
            else:
                loader = LazyGroup(lazy=subcommands)
                for sub in subcommands:
                    if " " not in sub:
                        command.add_command(loader.get_command(None, sub), sub)
        return command


class VeilGroup(LazyGroup):
    """Exit statuses of every command: a :class:`veil.errors.InputError` (or an operating
    system error naming a file) is the user's mistake, printed as "Error: ..." with status 2;
    any other exception is a bug in veil (status 3, :func:`report_bug`)."""

    def invoke(self, ctx):
        from .compile_display import shown

        try:
            with shown():
                return super().invoke(ctx)
        except click.ClickException as exc:
            exc.message = family_words(exc.message)
            raise
        except (
            click.exceptions.Exit,
            click.exceptions.Abort,
            KeyboardInterrupt,
            SystemExit,
        ):
            raise
        except InputError as exc:
            click.echo(f"Error: {family_words(str(exc))}", err=True)
            sys.exit(EXIT_INPUT)
        except OSError as exc:
            if exc.filename is None:
                report_bug(exc, ctx.obj.get("debug", False) if ctx.obj else False)
            click.echo(f"Error: {exc.filename}: {exc.strerror or exc}", err=True)
            sys.exit(EXIT_INPUT)
        except Exception as exc:
            report_bug(exc, bool(ctx.obj and ctx.obj.get("debug")))


#: The engine's named accuracies (veil.engine.quadrature.RULES, which imports JAX; the
#: command line names them without it - tests/test_cli_startup.py checks they agree).
ACCURACIES = ("fast", "default", "high")
#: The angle forms of measurement tables (veil.data.measurements.FORMS) and the default
#: glow of simulated sessions (veil.data.simulate.GLOW_LEVEL), likewise.
TABLE_FORMS = ("full", "inplane", "goniometer")
GLOW_LEVEL = 0.03


def accuracy_option(help_text: str, default: str = "default"):
    """``--accuracy``: one of :data:`ACCURACIES`, the engine's quadrature for what
    ``help_text`` says."""
    return click.option(
        "--accuracy",
        type=click.Choice(list(ACCURACIES)),
        default=default,
        show_default=True,
        help=help_text,
    )


def seed_option(help_text: str):
    """``--seed``: the noise generator's seed, an integer >= 0 (0 by default)."""
    return click.option(
        "--seed", type=click.IntRange(min=0), default=0, show_default=True, help=help_text
    )


def noise_option(help_text: str, positive: bool = False):
    """``--noise``: a relative noise level, 0.01 by default, >= 0 (> 0 if ``positive``)."""
    return click.option(
        "--noise",
        type=FloatRange(min=0.0, min_open=positive),
        default=0.01,
        show_default=True,
        help=help_text,
    )


def photo_channel_option(help_text: str):
    """``--channel`` of the photo readers: gray, r, g, b or rgb (every channel at once)."""
    return click.option(
        "--channel",
        type=click.Choice(["gray", "r", "g", "b", "rgb"]),
        default="gray",
        show_default=True,
        help=help_text,
    )


#: The Python keywords of the protocol's rotations (veil.data.protocol) -> their options.
ROTATION_OPTIONS = {
    "fine_step": "--fine-step",
    "coarse_step": "--coarse-step",
    "window": "--window",
    "limit": "--limit",
}


def rotation_options(candidate: bool = False):
    """The protocol's rotations (veil.data.protocol.rho_values, its defaults): --fine-step,
    --window, --coarse-step and --limit; ``candidate``: the steps of a design's candidates."""
    step = "Candidate rotation step" if candidate else "Rotation step"
    options = (
        click.option(
            "--fine-step",
            type=FINITE,
            default=1.0,
            show_default=True,
            help=f"{step} near the mirror configuration, degrees.",
        ),
        click.option(
            "--window",
            type=FINITE,
            default=10.0,
            show_default=True,
            help="Half-width of the dense region around rho = 0, degrees.",
        ),
        click.option(
            "--coarse-step",
            type=FINITE,
            default=5.0,
            show_default=True,
            help=f"{step} outside the window, degrees.",
        ),
        click.option(
            "--limit",
            type=FINITE,
            default=85.0,
            show_default=True,
            help="Keep configurations with both |theta_i| and |theta_r| below this, degrees.",
        ),
    )

    def decorate(command):
        command = options_named(ROTATION_OPTIONS)(command)  # the protocol's words
        for option in reversed(options):
            command = option(command)
        return command

    return decorate


def load_result_file(path, kind: str, option: str):
    """A fit result holding a model of ``kind`` (a clear error for the other kind)."""
    from ..fitting.result import load_model_result

    return load_model_result(path, kind, option)


# -- loading the given models --------------------------------------------------------------


def _is_file(text: str) -> bool:
    return os.path.exists(text) or text.lower().endswith(".json")


def load_reference(text: str, models, option: str = "--reference"):
    """A BRDF fit result (JSON file), or a BRDF preset / literal of the chosen family."""
    if _is_file(text):
        return load_result_file(text, "brdf", option)
    try:
        return models.brdf_model(text, option)
    except click.ClickException as exc:
        raise UserError(
            f"{option} {text!r} is not an existing JSON file and {exc.message}"
        ) from None


def load_medium(text: str, models, option: str = "--medium"):
    """A medium fit result (JSON file), or a medium preset / literal of the chosen model."""
    if _is_file(text):
        return load_result_file(text, "medium", option)
    try:
        model = models.medium_model(text, option)
    except click.ClickException as exc:
        raise UserError(
            f"{option} {text!r} is not an existing JSON file and {exc.message}"
        ) from None
    if model is None:
        raise UserError(
            f"{option} none: this needs a scattering medium; for a target in a "
            "clear medium use 'veil fit reference'"
        )
    return model


# -- progress, warnings and the exit status of fits ---------------------------------------


def _count(done, total) -> str:
    """The progress display's count: "3/14", "120 evaluations" or nothing."""
    if done is None:
        return ""
    return f"{done}/{total}" if total else f"{done} evaluation{'' if done == 1 else 's'}"


#: Off a terminal, a stage that has said nothing for this many seconds says its count again.
STAGE_LINE_SECONDS = 30.0


def _stage_lines(title: str, clock=time.monotonic):
    """A ``progress(stage, done, total)`` callback that writes one line on stderr per new
    stage (``veil TITLE: STAGE (COUNT)``), as the compile display does off a terminal, and
    within a long stage one whenever its count moved and :data:`STAGE_LINE_SECONDS` have
    passed since the last line (a log of a five-minute stage is not silent)."""
    last: list = [None, 0.0, None]  # stage, time and count of the last line

    def progress(stage, done, total):
        now = clock()
        quiet = now - last[1] >= STAGE_LINE_SECONDS and done != last[2]
        if stage != last[0] or quiet:
            last[:] = [stage, now, done]
            count = _count(done, total)
            click.echo(f"veil {title}: {stage}" + (f" ({count})" if count else ""), err=True)

    return progress


@contextlib.contextmanager
def fit_progress(title: str, lines: bool = True):
    """A rich progress display on stderr; yields the ``progress(stage, done, total)`` callback.
    Off a terminal (a log, a pipe, CI) one line per stage (:func:`_stage_lines`), or nothing
    without ``lines``."""
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from .compile_display import console

    if lines and not console().is_terminal:
        yield _stage_lines(title)
        return
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.fields[count]}"),
        TimeElapsedColumn(),
        console=console(),
        transient=True,
    ) as bar:
        task = bar.add_task(title, total=None, count="")

        def progress(stage, done, total):
            count = _count(done, total)
            bar.update(
                task, description=f"{title}: {stage}", completed=done or 0, total=total, count=count
            )

        yield progress


@contextlib.contextmanager
def echo_warnings():
    """Collect the warnings of the block and print them to stderr as "Warning: ..." after it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        click.echo(f"Warning: {w.message}", err=True)


def finish_fits(ctx, results, written):
    """Report the ``written`` files on stderr; exit status 1 if a result did not converge."""
    for path in written:
        click.echo(f"wrote {path}", err=True)
    failed = [r for r in results if r is not None and not r.converged]
    if failed:
        click.echo(
            "Error: a fit did not converge (its result was written with "
            '"converged": false): ' + "; ".join(r.message for r in failed),
            err=True,
        )
        ctx.exit(1)


# -- output files --------------------------------------------------------------------------


def check_outside(output, folder, named: str, kept: str = "an input") -> None:
    """UserError if ``output`` is ``folder`` or inside it (``named`` says what the folder is,
    ``kept`` what veil never modifies)."""
    if Path(output).resolve().is_relative_to(Path(folder).resolve()):
        raise UserError(
            f"output {output} is inside {named}; veil never modifies {kept}: choose another "
            f"output path"
        )


def written_kind(target: str, fmt: str) -> str:
    """What an export wrote, for its last line: the renderer, and its format if another."""
    return target if fmt == target else f"{target} {fmt}"


def check_black_apart(black, sessions: dict) -> None:
    """UserError if the --black table is one of the ``sessions`` ({what: path}): subtracted
    from itself, a session would be all zero, a fit with nothing to fit."""
    if black is None:
        return
    for what, path in sessions.items():
        if path is not None and os.path.exists(path) and os.path.samefile(path, black):
            raise UserError(
                f"--black {black} is {what} ({path}) itself: the black cloth is a session of "
                f"its own (the medium over black cloth, same configurations); subtracted from "
                f"itself the data would be all zero"
            )


def check_output_path(output, inputs=()):
    """Fail early (UserError) if ``output`` cannot be written or is one of the ``inputs``."""
    output = os.fspath(output)
    for inp in inputs:
        if inp is None:
            continue
        inp = os.fspath(inp)
        same = os.path.exists(output) and os.path.exists(inp) and os.path.samefile(output, inp)
        if same or os.path.abspath(output) == os.path.abspath(inp):
            raise UserError(
                f"output {output} is the input file {inp}; veil never overwrites "
                f"an input: choose another output path"
            )
    check_file_target(output, f"output {output}", output)


def check_file_target(path, named: str, written: str) -> None:
    """UserError unless ``path`` names a file in an existing, writable directory; messages
    call it ``named`` ("<named> is a directory") and ``written`` ("cannot write <written>")."""
    if not os.fspath(path):
        raise UserError(f"{named.rstrip()}: {empty_path()}")
    if os.path.isdir(path):
        raise UserError(f"{named} is a directory; give a file name")
    from ..io import output_file_problem

    wrong = None if os.path.islink(path) else output_file_problem(os.fspath(path))
    if wrong:
        raise UserError(f"cannot write {written}: {wrong}")
    # a symbolic link is written through (veil.io): its target must be a file (or nothing
    # yet) in a writable directory, and a loop of links is refused before any work
    link = os.path.islink(path)
    directory = os.path.dirname(os.path.realpath(path) if link else os.path.abspath(path))
    if link:
        from ..errors import UnwritableError
        from ..io import through_link

        try:
            target = through_link(os.fspath(path))
        except UnwritableError as exc:
            raise UserError(str(exc)) from None
        written = f"{written} (a symbolic link to {target})"
        if os.path.exists(target) and not os.path.isfile(target):
            raise UserError(f"cannot write {written}: it is not a regular file")
    if not os.path.isdir(directory):
        from ..io import no_directory

        raise UserError(f"cannot write {written}: {no_directory(directory)}")
    if not os.access(directory, os.W_OK):
        raise UserError(f"cannot write {written}: directory {directory} is not writable")
