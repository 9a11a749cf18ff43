"""``veil diagnose``: identifiability of a fit (docs/model.md sec. 7; docs/ambiguity.md).

Prints the parameters that are poorly determined (relative standard error above a threshold,
flat profile likelihood) and the pairs that trade off; with ``-o DIR`` writes
``diagnostics.json`` and ``diagnostics.png`` there. Exit status 0 (also when something is
flagged), 2 for input mistakes.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

from ._common import (
    FloatRange,
    ModelChoice,
    OutputPath,
    UserError,
    check_black_apart,
    check_output_path,
    model_options,
    options_named,
)

IN_FILE = click.Path(exists=True, dir_okay=False, path_type=Path)


def _one_channel(result, named: str) -> None:
    """A UserError naming the file when ``result`` is a step fit of several channels."""
    channels = getattr(result, "channels", None)
    if channels and not getattr(result, "JOINT", False):
        raise UserError(
            f"{named}: the file fits channels {', '.join(channels)} at once; "
            f"veil diagnose takes results of one channel (fit one with --channel NAME)"
        )


def _load_other(text, kind, result, models):
    """--medium / --reference: a fit result of that kind, or a preset / literal of the family
    the result was fitted with (its given model's), else of --brdf-model / --medium-model."""
    from ..fitting import load_result

    option = "--medium" if kind == "medium" else "--reference"
    if os.path.exists(text) or text.lower().endswith(".json"):
        other = load_result(text)  # diagnose checks that it fits the result's step
        _one_channel(other, f"{option} {text}")
        got = getattr(other, "kind", None) if not hasattr(other, "layout") else "joint"
        takes = {"medium": "target", "brdf": "medium"}[kind]  # the step that takes option
        if got != kind and getattr(result, "step", None) == takes:
            what = (
                "a joint fit result"
                if got == "joint"
                else f"a {other.model} ({got}) fit result of step {other.step}"
            )
            wanted = (
                "the medium's fit result (step 1, a medium model)"
                if kind == "medium"
                else "the reference's fit result (step 0, a BRDF)"
            )
            raise UserError(
                f"{option} {text}: the file is {what}; {option} takes {wanted}, or a model"
            )
        return other
    given = result.given_model() if result.given else None
    if given is not None and given.KIND == kind:
        models = ModelChoice(
            type(given) if kind == "brdf" else models.brdf,
            type(given) if kind == "medium" else models.medium,
            given.options() if kind == "brdf" else models.brdf_options,
            given.options() if kind == "medium" else models.medium_options,
        )
    try:
        model = models.parse(text, kind, option)
    except click.ClickException as exc:
        raise UserError(
            f"{option} {text!r} is not an existing JSON file and {exc.message}"
        ) from None
    if model is None:
        raise UserError("--medium none: a target fit's medium scatters; give its fit result")
    return model


def _print(diag, console) -> None:
    from rich.markup import escape as e
    from rich.table import Table

    table = Table(title="Identifiability", title_justify="left")
    for col in ("parameter", "value", "stderr", "relative", "profile 1-sigma", "flag"):
        table.add_column(col, justify="left" if col in ("parameter", "flag") else "right")
    flagged: dict = {}
    for n, reason in diag.poorly_determined:
        flagged.setdefault(n, []).append(reason)
    for n in diag.names:
        prof = diag.profiles.get(n)
        interval = "-"
        if prof is not None:
            lo, hi = prof.interval
            low = "<" + format(prof.values[0], ".4g") if lo is None else format(lo, ".4g")
            high = ">" + format(prof.values[-1], ".4g") if hi is None else format(hi, ".4g")
            interval = f"[{low}, {high}]"
        rel = diag.relative[n]
        table.add_row(
            e(n),
            f"{diag.values[n]:.5g}",
            f"{diag.stderr[n]:.3g}",
            "-" if rel == float("inf") else f"{100 * rel:.3g} %",
            interval,
            "POOR" if n in flagged else "",
        )
    console.print(table)
    console.print(
        f"condition number of the weighted Jacobian: {diag.condition['values']:.4g} "
        f"(columns x values), {diag.condition['stderr']:.4g} (columns x stderr)"
    )
    weak = ", ".join(f"{c:+.2f} {e(n)}" for n, c in diag.weakest.items() if abs(c) >= 0.1)
    console.print(f"weakest direction (relative units): {weak}")
    if diag.poorly_determined:
        console.print("[bold]Poorly determined:[/bold]")
        for n, reason in diag.poorly_determined:
            console.print(f"  {e(n)}: {e(reason)}")
    if diag.tradeoffs:
        console.print(f"[bold]Trade-offs (|r| > {diag.thresholds['max_correlation']:g}):[/bold]")
        for a, b, r in diag.tradeoffs:
            console.print(f"  {e(a)} <-> {e(b)}: r = {r:+.3f}")
    if diag.ok:
        console.print("No parameter poorly determined, no trade-off above the thresholds.")
    for note in diag.notes:
        console.print(f"note: {e(note)}")


@click.command("diagnose")
@click.argument("result_path", metavar="RESULT.json", type=IN_FILE)
@click.option(
    "--data",
    "data",
    multiple=True,
    required=True,
    metavar="TABLE",
    help="The fit's measurement table. For a joint result: each session as "
    "LABEL=PATH (target) or ref:LABEL=PATH (reference), repeated.",
)
@click.option(
    "--black", type=IN_FILE, help="Black-cloth table subtracted in the fit (step results)."
)
@click.option(
    "--medium",
    metavar="MEDIUM",
    help="For a target fit: the medium's fit result (JSON; its uncertainty is "
    "included) or a model (held exact). Default: the medium in RESULT, exact.",
)
@click.option(
    "--reference",
    metavar="REF",
    help="For a medium fit: the reference's fit result (JSON; its uncertainty is "
    "included) or a model. Default: the reference in RESULT, exact.",
)
@click.option("--profile", is_flag=True, help="Compute profile likelihoods (refits; slower).")
@click.option(
    "--profile-param",
    "profile_params",
    multiple=True,
    metavar="NAME",
    help="Profile only this parameter (repeatable; implies --profile).",
)
@click.option(
    "--points",
    type=click.IntRange(min=3),
    default=9,
    show_default=True,
    help="Grid points of each profile.",
)
@click.option(
    "--max-relative",
    type=FloatRange(min=0, min_open=True),
    default=0.25,
    show_default=True,
    help="Relative standard error above which a parameter is "
    "poorly determined (for g: relative to 1 - |g|).",
)
@click.option(
    "--max-correlation",
    type=FloatRange(0, 1, min_open=True),
    default=0.9,
    show_default=True,
    help="|correlation| above which a pair trades off.",
)
@click.option(
    "-o",
    "--outdir",
    type=OutputPath(file_okay=False, path_type=Path),
    help="Directory for diagnostics.json and diagnostics.png (created; both are "
    "replaced together, other files in it are left alone).",
)
@model_options()
@options_named({"max_relative": "--max-relative", "max_correlation": "--max-correlation"})
def diagnose_command(
    result_path,
    data,
    black,
    medium,
    reference,
    profile,
    profile_params,
    points,
    max_relative,
    max_correlation,
    outdir,
    models,
):
    """Which parameters of a fit are poorly determined, and which trade off.

    \b
        veil diagnose target.json --data target_medium.csv --black black.csv \\
            --medium medium.json --profile -o diag
    """
    from rich.console import Console

    from ..analysis.diagnostics import diagnose
    from ..fitting import JointResult, load_result

    result = load_result(result_path)
    _one_channel(result, str(result_path))
    inputs = [result_path, black]
    if isinstance(result, JointResult):
        if black is not None or medium is not None or reference is not None:
            raise UserError(
                "a joint result takes only --data LABEL=PATH / ref:LABEL=PATH "
                "(black cloth already subtracted; media and reference are in it)"
            )
        table = _sessions(data, inputs)
    else:
        if len(data) != 1:
            raise UserError(f"--data given {len(data)} times: a {result.step} fit has one table")
        table = data[0]
        if not os.path.isfile(table):
            raise UserError(f"--data {table}: file does not exist")
        check_black_apart(black, {"--data": table})
        inputs.append(table)
    med = _load_other(medium, "medium", result, models) if medium else None
    ref = _load_other(reference, "brdf", result, models) if reference else None
    for text in (medium, reference):
        if text and os.path.exists(text):
            inputs.append(text)
    files = {}
    if outdir is not None:
        from ..io import check_output_folder

        check_output_folder(outdir)
        files = {"json": outdir / "diagnostics.json", "png": outdir / "diagnostics.png"}
        if outdir.exists():
            for path in files.values():
                check_output_path(path, inputs)
    prof = list(profile_params) if profile_params else bool(profile)
    from ._common import echo_warnings, fit_progress

    with echo_warnings(), fit_progress("diagnose") as progress:
        diag = diagnose(
            result,
            table,
            medium=med,
            reference=ref,
            black=None if black is None else os.fspath(black),
            profile=prof,
            points=points,
            max_relative=max_relative,
            max_correlation=max_correlation,
            progress=progress,
        )
    _print(diag, Console())
    if files:
        _write(diag, outdir, files)


def _sessions(data, inputs: list) -> list:
    """The sessions of a joint result from ``--data LABEL=PATH`` / ``ref:LABEL=PATH`` (their
    paths added to ``inputs``)."""
    from ..data.measurements import load_measurements
    from ..fitting import Session

    sessions = []
    for item in data:
        head, sep, path = item.partition("=")
        if not sep or not head.strip() or not path.strip():
            raise UserError(
                f"--data {item!r}: a joint result needs LABEL=PATH or "
                f"ref:LABEL=PATH for each session"
            )
        obj, label = ("reference", head[4:]) if head.startswith("ref:") else ("target", head)
        path = path.strip()
        if not os.path.isfile(path):
            raise UserError(f"--data {item!r}: file {path} does not exist")
        sessions.append(
            Session(
                load_measurements(path),
                label.strip(),
                obj,
                name=f"{obj} in {label.strip()} ({path})",
            )
        )
        inputs.append(path)
    return sessions


def _write(diag, outdir, files: dict) -> None:
    """diagnostics.json and diagnostics.png in ``outdir``, as one transaction."""
    from ..io import output_folder, write_text_atomic
    from ..viz.fit_figures import diagnosis_figure

    names = {key: path.name for key, path in files.items()}
    with output_folder(outdir, owned=names.values()) as folder:
        write_text_atomic(
            folder / names["json"], json.dumps(diag.to_dict(), indent=2, allow_nan=False) + "\n"
        )
        diagnosis_figure(diag, folder / names["png"])
    for path in files.values():
        click.echo(f"wrote {path}", err=True)
