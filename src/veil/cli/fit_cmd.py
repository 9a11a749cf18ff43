"""``veil fit``: the two-step estimation of docs/model.md sec. 7 from measurement tables.

Subcommands ``reference`` (step 0), ``medium`` (step 1), ``target`` (step 2) and ``pipeline``
(all of them, with figures and report.md). Exit status 0 when every fit converged, 1 when a
fit did not (its result is still written, with ``"converged": false``), 2 for mistakes in
the input. Result format: docs/fitting.md.
"""

from __future__ import annotations

import os
from pathlib import Path

import click

from ._common import (
    LazyGroup,
    OutputPath,
    UserError,
    check_black_apart,
    check_output_path,
    echo_warnings,
    finish_fits,
    fit_progress,
    load_medium,
    load_reference,
    model_error_option,
    model_options,
    parse_fix,
    propagation_option,
)
from ._fit_options import (
    _BRDF_FIX_HELP,
    IN_FILE,
    MERL_CHANNELS,
    OUT_FILE,
    _accuracy_option,
    _black_option,
    _channel_option,
    _fix_option,
    _max_nfev_option,
    _merl_option,
    _parse_free,
    _parse_step_fix,
    _parse_step_free,
    _raw_step_fix,
    _sampling_option,
    _step_entries,
    _step_through_medium_options,
    refuse_fixed_and_freed,
)
from ._fit_reports import print_pipeline, print_ranking


def _write_fit(ctx, result, output) -> None:
    """A step's result: its JSON written (atomically), its report shown, the run finished."""
    result.to_json(output)
    click.echo(result.report())
    finish_fits(ctx, [result], [output])


#: Steps 1 and 2 by the kind of model they fit: the step and what its table holds.
_THROUGH_MEDIUM = {
    "medium": ("step 1, medium", "reference (in the medium)"),
    "brdf": ("step 2, target", "target (in the medium)"),
}


def _fit_through_medium(
    ctx,
    fit_step,
    kind: str,
    table,
    given,
    output,
    *,
    fix,
    free,
    black,
    models,
    channel,
    **fit_options,
) -> None:
    """``veil fit medium`` and ``veil fit target``: ``fit_step`` (veil.fitting's fit_medium
    or fit_target) of the ``kind`` model to ``table`` through the medium, ``given`` the
    (model held, file or preset it was read from) - the reference's f_r or the medium; the
    result written to ``output``. ``fit_options``: the accuracy, the evaluation budget, the
    model error and the propagation, as the command received them."""
    model, source = given
    check_output_path(output, [table, black] + ([source] if os.path.exists(source) else []))
    check_black_apart(black, {"the measurement TABLE": table})
    step, what = _THROUGH_MEDIUM[kind]

    def fit(family, options, fixed, freed, progress, screen=False, start=None):
        return fit_step(
            table,
            model,
            fixed=fixed,
            black=black,
            progress=progress,
            options=options,
            free=freed,
            channel=channel,
            screen=screen,
            start=start,
            **{f"{kind}_model": family},
            **fit_options,
        )

    result = _fit_step(ctx, kind, step, models, fit, (table, black, channel), what, fix, free)
    _write_fit(ctx, result, output)


def _per_candidate(items, cands, parse, option: str) -> dict:
    """{candidate label: ``parse(items of its family's parameters, family)``} for a ranked
    fit: each NAME=VALUE (or NAME) applies to the candidates that declare the parameter; one
    that no candidate declares is a UserError."""
    from ..models import model_class
    from ._model_options import fix_value

    if option == "--fix":  # a VALUE that is no number is said so, without the hint below
        for item in items:
            name, sep, text = item.partition("=")
            if not sep or not name.strip():
                raise UserError(f"{option} {item!r}: expected NAME=VALUE, e.g. n=0.5")
            fix_value(option, item, name.strip(), text, {})
    used, out = set(), {}
    for c in cands:
        cls = model_class(c.family)
        mine = [i for i in items if i.partition("=")[0].strip() in cls.param_names()]
        used.update(mine)
        try:
            out[c.label] = parse(mine, cls)
        except UserError as exc:  # a value this family cannot hold (its bounds), others can
            named = {i.partition("=")[0].strip() for i in mine if repr(i) in exc.message}
            if not named:  # not a value (a name given twice)
                raise
            owners = dict.fromkeys(
                d.family for d in cands if named & set(model_class(d.family).param_names())
            )
            raise UserError(
                f"{exc.message}; with auto {option} applies to every candidate family that "
                f"has the parameter ({', '.join(owners)}): give a value they all take, or "
                f"choose the family (--{cls.KIND}-model FAMILY)"
            ) from None
    unused = [i for i in items if i not in used]
    if unused:
        raise UserError(
            f"{option} {', '.join(map(repr, unused))}: no candidate family has such a parameter"
        )
    return out


def _ranked_fit(
    ctx, kind: str, step: str, models, data, fit, what: str, fix=(), free=(), quick=None
):
    """``--brdf-model auto`` / ``--medium-model auto``: every registered family of ``kind``
    (with each value of its discrete options) fitted by ``fit(candidate, fixed, freed)`` and
    ranked by BIC on ``data`` (veil.fitting.selection), screened by ``quick(candidate,
    fixed, freed, start)`` first when given (veil.fitting.screening; ``fit`` then takes a
    ``start`` too); the ranking printed and the
    chosen result returned with it in ``stats["selection"]``. Exit 1 with the table when
    every candidate failed."""
    from ..fitting import screening, selection
    from ..fitting.auto import check_candidates
    from ..fitting.session_data import prepare_all

    options = models.brdf_options if kind == "brdf" else models.medium_options
    cands = selection.candidates(kind, options)
    check_candidates("BRDF" if kind == "brdf" else "medium", cands, options)
    fixes = _per_candidate(fix, cands, parse_fix, "--fix")
    frees = _per_candidate(free, cands, _parse_free, "--free")
    table, black, channel = data
    prepared = prepare_all(table, black, what, channel)  # every channel's, stacked

    def one(c, **start):  # a step through the medium: start= (veil.fitting.screening)
        return fit(c, fixes[c.label], frees[c.label], **start)

    def first(c, start=None):
        return quick(c, fixes[c.label], frees[c.label], start)

    try:
        with echo_warnings(), fit_progress(step) as progress:
            ranking, results = screening.select(
                step.rpartition(", ")[2],
                cands,
                prepared,
                one,
                what,
                progress,
                None if quick is None else first,
            )
    except selection.NoCandidateError as exc:
        print_ranking(exc.ranking)
        click.echo(f"Error: {exc}; nothing was written", err=True)
        ctx.exit(1)
    print_ranking(ranking)
    return selection.with_selection(results[ranking.chosen], ranking)


def _fit_step(ctx, kind: str, step: str, models, fit, data, what: str, fix=(), free=()):
    """One step's fit of the ``kind`` model: ``fit(family, options, fixed, freed,
    progress)`` with the chosen family, or every candidate ranked (:func:`_ranked_fit`)
    when it is ``auto``. ``data`` are the (table, black, channel) the fit reads, ``what``
    names them."""
    refuse_fixed_and_freed(fix, free)
    cls = models.brdf if kind == "brdf" else models.medium
    options = models.brdf_options if kind == "brdf" else models.medium_options
    if kind in models.ranked:
        # the candidates screened by a quick fit each, the full fits started from it
        # (veil.fitting.screening); in clear water of one channel only
        def each(c, fixed, freed, start=None, screen=False):
            return fit(c.family, c.model_options(options), fixed, freed, None, screen, start)

        medium_step = step in {s for s, _ in _THROUGH_MEDIUM.values()}
        screened = medium_step or _one_channel(data, what)
        return _ranked_fit(
            ctx,
            kind,
            step,
            models,
            data,
            each,
            what,
            fix,
            free,
            (lambda c, fixed, freed, start=None: each(c, fixed, freed, start, True))
            if screened
            else None,
        )
    fixed, freed = parse_fix(fix, cls), _parse_free(free, cls)
    with echo_warnings(), fit_progress(step) as progress:
        return fit(cls.NAME, options, fixed, freed, progress)


def _one_channel(data, what: str) -> bool:
    """Whether the (table, black, channel) ``data`` are fitted as one channel."""
    from ..fitting.session_data import channels_of

    table, _, channel = data
    return channel is not None or len(channels_of(table, what)[1] or ()) <= 1


# --------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------
@click.group("fit", cls=LazyGroup, short_help="Estimate f_r and f_t from measurement tables.")
def fit_command():
    """Estimate f_r and f_t from measurement tables (docs/model.md sec. 7, docs/fitting.md).

    \b
        veil fit reference clear.csv -o reference.json
        veil fit medium ref_medium.csv --reference reference.json --black black.csv -o medium.json
        veil fit target target_medium.csv --medium medium.json --black black.csv -o target.json
        veil fit pipeline --reference-clear clear.csv --reference-medium ref_medium.csv \\
            --target-medium target_medium.csv --black black.csv -o fit-out

    Exit status 1 when a fit did not converge (the result is written anyway), 2 for input
    mistakes.
    """


def merl_table(merl, channel, sampling):
    """The measurement table of a MERL file's f_r (relative sigma of 1 %): of ``channel``,
    or of the three channels (None)."""
    from ..data.merl import channels_table, measurement_table, read_merl

    if channel is None:
        return channels_table(read_merl(merl), sampling=sampling)
    return measurement_table(read_merl(merl), channel, sampling)


@fit_command.command("reference")
@click.argument("table", type=IN_FILE, required=False)
@click.option(
    "-o",
    "--output",
    required=True,
    type=OUT_FILE,
    help="JSON file for the fitted f_r (written atomically).",
)
@_fix_option(_BRDF_FIX_HELP)
@_black_option
@_max_nfev_option
@_merl_option
@_channel_option
@_sampling_option
@model_error_option
@model_options(("brdf",), auto_kinds=("brdf",))
@click.pass_context
def reference_command(
    ctx, table, output, fix, black, max_nfev, merl, channel, sampling, model_error, models
):
    """Step 0: fit the reference's f_r (default Torrance-Sparrow) to clear-medium data,
    directly: a measurement TABLE, or a measured BRDF (--merl FILE: its r, g, b channels at
    once, or one with --channel g)."""
    if (table is None) == (merl is None):
        raise UserError("give a measurement TABLE or --merl FILE (one of the two)")
    if merl is not None and black is not None:
        raise UserError("--black applies to a measurement table, not to --merl")
    check_output_path(output, [table, black, merl])
    check_black_apart(black, {"the measurement TABLE": table})
    if merl is not None and channel not in (None,) + MERL_CHANNELS:
        raise UserError(
            f"--channel {channel!r}: a MERL file has channels {', '.join(MERL_CHANNELS)}"
        )
    data = table if merl is None else merl_table(merl, channel, sampling)
    one = channel if merl is None else None
    from ..fitting import fit_reference

    def fit(family, options, fixed, _, progress, screen=False, start=None):
        return fit_reference(
            data,
            fixed=fixed,
            black=black,
            max_nfev=max_nfev,
            progress=progress,
            brdf_model=family,
            options=options,
            model_error=model_error,
            channel=one,
            screen=screen,
            start=start,
        )

    result = _fit_step(
        ctx,
        "brdf",
        "step 0, reference",
        models,
        fit,
        (data, black, one),
        "reference (clear medium)",
        fix,
    )
    _write_fit(ctx, result, output)


@fit_command.command("medium")
@_step_through_medium_options(
    "medium",
    click.option(
        "--reference",
        "reference",
        required=True,
        metavar="REF",
        help="The reference's f_r: a JSON file from 'veil fit reference', a preset (BRDF1, BRDF2) "
        "or a literal list of the BRDF's parameters (PD,PS,N,ETA for the paper's).",
    ),
)
def medium_command(ctx, table, reference, output, models, **opts):
    """Step 1: fit the medium (default the paper's Td, Tt, g, eta) to the reference measured
    in it."""
    from ..fitting import fit_medium

    ref = load_reference(reference, models)
    _fit_through_medium(
        ctx, fit_medium, "medium", table, (ref, reference), output, models=models, **opts
    )


@fit_command.command("target")
@_step_through_medium_options(
    "brdf",
    click.option(
        "--medium",
        "medium",
        required=True,
        metavar="MEDIUM",
        help="The medium's f_t: a JSON file from 'veil fit medium', a preset (BTDF1, BTDF2, "
        "BTDF3) or a literal list of the medium's parameters (TD,TT,G,ETA for the paper's).",
    ),
)
def target_command(ctx, table, medium, output, models, channel, **opts):
    """Step 2: fit the target's f_r (default Torrance-Sparrow) through the fitted medium.
    A JSON --medium keeps its own model and options (a contradicting option is an error)."""
    med = load_medium(medium, models)
    several = getattr(med, "channels", None)  # a fit of several channels: any one's options
    given = (
        med.as_model(channel=(channel or next(iter(several))) if several else None)
        if hasattr(med, "as_model")
        else med
    )
    if "medium-model" in models.explicit and type(given) is not models.medium:
        raise UserError(
            f"--medium-model {models.medium.NAME} but {medium} is a {given.NAME} medium"
        )
    for k, v in models.medium_options.items():
        if given.options().get(k) != v:
            raise UserError(
                f"--{k} {v} but {medium} has {k} {given.options().get(k)}; "
                f"leave --{k} out to use the medium's"
            )
    from ..fitting import fit_target

    _fit_through_medium(
        ctx,
        fit_target,
        "brdf",
        table,
        (med, medium),
        output,
        models=models,
        channel=channel,
        **opts,
    )


@fit_command.command("pipeline")
@click.option(
    "--reference-clear",
    required=True,
    type=IN_FILE,
    help="Reference object in a clear medium (step 0).",
)
@click.option(
    "--reference-medium",
    required=True,
    type=IN_FILE,
    help="Reference object in the scattering medium (step 1).",
)
@click.option(
    "--target-medium",
    required=True,
    type=IN_FILE,
    help="Target object in the scattering medium (step 2).",
)
@_black_option
@click.option(
    "--target-clear",
    type=IN_FILE,
    help="Target object in a clear medium: fitted directly and compared with the estimate "
    "(with --models auto, step 2's families are ranked on it).",
)
@click.option(
    "-o",
    "--outdir",
    required=True,
    type=OutputPath(file_okay=False, path_type=Path),
    help="Directory for the JSON results, figures and report.md (created).",
)
@_fix_option(
    "Hold a parameter of one step: STEP.NAME=VALUE, STEP reference, medium or "
    "target (e.g. medium.eta=1.33); repeatable. Target values also hold in the "
    "direct fit."
)
@click.option(
    "--free",
    "free",
    multiple=True,
    metavar="STEP.NAME",
    help="Fit a parameter the family holds by default in one step (e.g. medium.s, "
    "the forward-series exposure factor); repeatable.",
)
@click.option(
    "--models",
    "model_spec",
    default=None,
    metavar="auto|paper|FAMILY+MEDIUM",
    help="Which models: 'auto' fits every registered family (each value of its "
    "discrete options) and ranks them per step by BIC with the fit's "
    "model-discrepancy term, using the best (step 0 the reference's BRDF, step "
    "1 the medium, step 2 the target's BRDF; tables in the output and "
    "report.md); 'paper' the paper's Torrance-Sparrow + Henyey-Greenstein; "
    "FAMILY+MEDIUM pins a pair (e.g. rough-plastic+forward-series).  "
    "[default: paper]",
)
@click.option(
    "--compare",
    is_flag=True,
    help="--models auto with the ranking written out in full: every candidate's "
    "result in OUTDIR/candidates/STEP/. Options, --fix and --free apply to the "
    "candidates that declare them.",
)
@click.option(
    "--figures/--no-figures",
    default=True,
    show_default=True,
    help="Draw the data against the fitted curves (the PNGs); --no-figures writes "
    "the results and report.md only, faster.",
)
@_accuracy_option
@_max_nfev_option
@model_error_option
@propagation_option
@click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="The one channel to fit of tables with a channel column; without it every "
    'step fits every channel at once (docs/fitting.md "Channels").',
)
@model_options()
@click.pass_context
def pipeline_command(
    ctx,
    reference_clear,
    reference_medium,
    target_medium,
    black,
    target_clear,
    outdir,
    fix,
    free,
    model_spec,
    compare,
    figures,
    accuracy,
    max_nfev,
    model_error,
    propagation,
    models,
    channel,
):
    """Steps 0-2 in one go, with figures (data against fitted curves, over their relative
    residuals) and report.md; --models auto lets the data choose the models."""
    from ..models import AUTO
    from ..pipeline import run_pipeline

    auto = models.mode == AUTO
    refuse_fixed_and_freed(fix, free, by_step=True)
    if auto:
        fixed = _raw_step_fix(fix)
        freed = _step_entries(free, "--free")
    else:
        fixed = _parse_step_fix(fix, models)
        freed = _parse_step_free(free, models)
    sessions = {"--reference-clear": reference_clear, "--reference-medium": reference_medium}
    sessions |= {"--target-medium": target_medium, "--target-clear": target_clear}
    check_black_apart(black, sessions)
    if outdir.exists() and not outdir.is_dir():
        raise UserError(f"--outdir {outdir} exists and is not a directory")
    if not outdir.parent.exists() and not outdir.exists():
        from ..io import no_directory

        raise UserError(f"cannot create {outdir}: {no_directory(str(outdir.parent))}")
    chosen = (
        {"models": AUTO}
        if auto
        else {"brdf_model": models.brdf.NAME, "medium_model": models.medium.NAME}
    )
    from ..fitting.selection import NoCandidateError

    try:
        with echo_warnings(), fit_progress("pipeline") as progress:
            result = run_pipeline(
                reference_clear,
                reference_medium,
                target_medium,
                black=black,
                target_clear=target_clear,
                outdir=outdir,
                accuracy=accuracy,
                fixed=fixed,
                max_nfev=max_nfev,
                progress=progress,
                brdf_options=models.brdf_options,
                medium_options=models.medium_options,
                free=freed,
                figures=figures,
                model_error=model_error,
                propagation=propagation,
                keep_candidates=compare,
                channel=channel,
                **chosen,
            )
    except NoCandidateError as exc:
        print_ranking(exc.ranking)
        click.echo(f"Error: {exc}; nothing was written", err=True)
        ctx.exit(1)
    print_pipeline(result)
    fits = [result.reference, result.medium, result.target, result.direct]
    finish_fits(ctx, fits, list(result.files.values()))
