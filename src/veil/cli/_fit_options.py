"""The options the fit commands share (the files, the black cloth, the accuracy, the
channel, a MERL file, steps 1 and 2's options together) and ``--fix`` / ``--free`` parsed:
a step's ``NAME`` checked against its family, the pipeline's ``STEP.NAME[=VALUE]`` by step
(against the chosen families, or unchecked for the candidates of ``--models auto``)."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ._common import (
    OutputPath,
    UserError,
    accuracy_option,
    model_error_option,
    model_options,
    options_named,
    parse_fix,
    propagation_option,
)

IN_FILE = click.Path(exists=True, dir_okay=False, path_type=Path)
OUT_FILE = OutputPath(dir_okay=False, path_type=Path)


def _fix_option(help_text):
    """``--fix``, which the library's messages then call by its name, not ``fixed=``."""
    option = click.option("--fix", "fix", multiple=True, metavar="NAME=VALUE", help=help_text)
    return lambda command: option(options_named({"fixed": "--fix"})(command))


_accuracy_option = accuracy_option(
    "Quadrature of the reported result; iterations run at 'fast' and are polished at this accuracy."
)
_black_option = click.option(
    "--black",
    "black",
    type=IN_FILE,
    help="Black-cloth session in the medium (same configurations), subtracted first.",
)
_max_nfev_option = click.option(
    "--max-nfev",
    type=click.IntRange(min=1),
    default=None,
    help="Limit on function evaluations of each least-squares run (default: 100 per free "
    "parameter).",
)


def _free_option(help_text):
    return click.option("--free", "free", multiple=True, metavar="NAME", help=help_text)


_merl_option = click.option(
    "--merl",
    "merl",
    type=IN_FILE,
    help="A measured BRDF in the MERL binary format instead of a table: sampled at the "
    "--sampling configurations (docs/interop.md).",
)
_channel_option = click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="The one channel to fit of a TABLE with a channel column (r, g, b or a wavelength "
    'in nm; without it every channel is fitted at once, docs/fitting.md "Channels"), '
    "or the colour channel of the --merl file (r, g or b; without it the file's three "
    "channels are fitted at once).",
)
_step_channel_option = click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="The one channel to fit of a TABLE with a channel column (r, g, b or a wavelength "
    "in nm); a result fitted over several channels gives its model of this channel. "
    "Without it every channel is fitted at once, through a result of the same channels "
    '(docs/fitting.md "Channels").',
)
MERL_CHANNELS = ("r", "g", "b")
_sampling_option = click.option(
    "--sampling",
    type=click.Choice(["protocol", "inplane"]),
    default="protocol",
    show_default=True,
    help="Where the --merl BRDF is sampled: the paper's protocol (psi 30, 60, 90 deg) or every "
    "in-plane configuration on a 5-degree grid.",
)


_BRDF_FIX_HELP = (
    "Hold a parameter of the BRDF (e.g. eta=1.5; 'veil models' lists them) at VALUE; repeatable."
)
#: The help of the options steps 1 and 2 word differently, by the kind of model they fit:
#: what -o holds, --fix and --free.
_STEP_HELP = {
    "medium": (
        "the fitted medium",
        "Hold a parameter of the medium (e.g. g=0.9; 'veil models' "
        "lists them) at VALUE; repeatable.",
        "Fit a parameter the medium model holds by "
        "default (held ones are marked in 'veil models', e.g. forward-series' s, the "
        "exposure factor); repeatable.",
    ),
    "brdf": (
        "the fitted target f_r",
        _BRDF_FIX_HELP,
        "Fit a parameter the BRDF family holds "
        "by default (marked held in 'veil models'); repeatable.",
    ),
}


def _step_through_medium_options(ranked_kind: str, given):
    """The arguments and options of a step through the medium (steps 1 and 2): the TABLE,
    the ``given`` model's option, the output, --fix and --free of the fitted model (of kind
    ``ranked_kind``), the channel, the black cloth, the accuracy, the evaluation budget, the
    model error, the propagation and the models (the fitted one may be ``auto``)."""
    output, fix, free = _STEP_HELP[ranked_kind]

    def decorate(command):
        for option in (
            click.pass_context,
            model_options(auto_kinds=(ranked_kind,)),
            propagation_option,
            model_error_option,
            _max_nfev_option,
            _accuracy_option,
            _black_option,
            _step_channel_option,
            _free_option(free),
            _fix_option(fix),
            click.option(
                "-o",
                "--output",
                required=True,
                type=OUT_FILE,
                help=f"JSON file for {output} (written atomically).",
            ),
            given,
            click.argument("table", type=IN_FILE),
        ):
            command = option(command)
        return command

    return decorate


#: The steps of the two-step method, as ``--fix`` / ``--free`` of ``fit pipeline`` name them.
STEPS = ("reference", "medium", "target")


def _parse_free(items, cls, option="--free") -> list:
    """Names of parameters held by default (``Param.held``) to fit too."""
    names = cls.param_names()
    out = []
    for item in items:
        name = item.strip()
        if name not in names:
            raise UserError(
                f"{option} {item!r}: {cls.NAME} has no parameter {name!r}; its "
                f"parameters are {', '.join(names)}"
            )
        if name in out:
            raise UserError(f"{option}: {name} is freed twice")
        out.append(name)
    return out


def refuse_fixed_and_freed(fix, free, step: str | None = None, by_step: bool = False) -> None:
    """A UserError for a parameter given to both ``--fix`` (``NAME=VALUE`` items, or of
    ``step`` of the pipeline; ``by_step``: the pipeline's ``STEP.NAME=VALUE`` items) and
    ``--free`` (``NAME`` items, or ``STEP.NAME``): held at a value or fitted, not both."""
    if by_step:
        for step, names in _step_entries(free, "--free").items():
            held = [i.partition(".")[2] for i in fix if i.partition(".")[0].strip() == step]
            refuse_fixed_and_freed(held, names, step)
        return
    fixed = {i.partition("=")[0].strip(): i.partition("=")[2].strip() for i in fix}
    both = [n.strip() for n in free if n.strip() in fixed]
    if both:
        name = both[0] if step is None else f"{step}.{both[0]}"
        raise UserError(
            f"--fix {name}={fixed[both[0]]} and --free {name}: a parameter is held at a "
            f"value (--fix) or fitted (--free, for one its family holds by default), not "
            f"both; give one of the two"
        )


def _parse_step_free(items, models) -> dict:
    """``STEP.NAME`` strings of ``fit pipeline --free`` -> {step: [name, ...]}, checked
    against the chosen families."""
    classes = {"reference": models.brdf, "medium": models.medium, "target": models.brdf}
    return {
        step: _parse_free(names, classes[step], f"--free ({step})")
        for step, names in _step_entries(items, "--free").items()
    }


def _parse_step_fix(items, models) -> dict:
    """``STEP.NAME=VALUE`` strings of ``fit pipeline`` -> {step: {name: value}}."""
    by_step: dict = {}
    classes = {"reference": models.brdf, "medium": models.medium, "target": models.brdf}
    for item in items:
        head, sep, _ = item.partition("=")
        step, dot, name = head.partition(".")
        if not sep or not dot or step.strip() not in classes:
            raise UserError(
                f"--fix {item!r}: expected STEP.NAME=VALUE with STEP one of "
                f"{', '.join(STEPS)}, e.g. medium.{models.medium.param_names()[-1]}"
                f"=1.33"
            )
        step = step.strip()
        by_step.setdefault(step, []).append(f"{name}={item.partition('=')[2]}")
    return {
        step: parse_fix(entries, classes[step], f"--fix ({step})")
        for step, entries in by_step.items()
    }


def _raw_step_fix(items) -> dict:
    """``STEP.NAME=VALUE`` -> {step: {name: value}}, names checked against the candidates
    later (veil.pipeline)."""
    fixed: dict[str, dict[str, float]] = {}
    for step, entries in _step_entries(items, "--fix").items():
        for entry in entries:
            name, sep, text = entry.partition("=")
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not sep or not math.isfinite(value):
                raise UserError(
                    f"--fix {step}.{entry!r}: expected STEP.NAME=VALUE with a finite number"
                )
            if name.strip() in fixed.get(step, {}):
                raise UserError(f"--fix: {step}.{name.strip()} is fixed twice")
            fixed.setdefault(step, {})[name.strip()] = value
    return fixed


def _step_entries(items, option: str) -> dict:
    """``STEP.NAME[=VALUE]`` strings -> {step: [NAME[=VALUE], ...]} (names unchecked)."""
    by_step: dict = {}
    for item in items:
        step, dot, rest = item.partition(".")
        if not dot or step.strip() not in STEPS or not rest.strip():
            raise UserError(
                f"{option} {item!r}: expected STEP.NAME with STEP one of {', '.join(STEPS)}"
            )
        by_step.setdefault(step.strip(), []).append(rest.strip())
    return by_step
