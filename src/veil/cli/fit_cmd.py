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
    UserError,
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

IN_FILE = click.Path(exists=True, dir_okay=False, path_type=Path)
OUT_FILE = click.Path(dir_okay=False, path_type=Path)
STEPS = ("reference", "medium", "target")


# --------------------------------------------------------------------------------------
# options shared by the subcommands
# --------------------------------------------------------------------------------------
def _fix_option(help_text):
    return click.option("--fix", "fix", multiple=True, metavar="NAME=VALUE", help=help_text)


_accuracy_option = click.option(
    "--accuracy", type=click.Choice(["fast", "default", "high"]), default="default",
    show_default=True,
    help="Quadrature of the reported result; iterations run at 'fast' and are polished at "
         "this accuracy.")
_black_option = click.option(
    "--black", "black", type=IN_FILE,
    help="Black-cloth session in the medium (same configurations), subtracted first.")
_max_nfev_option = click.option(
    "--max-nfev", type=click.IntRange(min=1), default=None,
    help="Limit on function evaluations of each least-squares run (default: 100 per free "
         "parameter).")


def _free_option(help_text):
    return click.option("--free", "free", multiple=True, metavar="NAME", help=help_text)


def _write_fit(ctx, result, output) -> None:
    """A step's result: its JSON written (atomically), its report shown, the run finished."""
    result.to_json(output)
    click.echo(result.report())
    finish_fits(ctx, [result], [output])


_BRDF_FIX_HELP = ("Hold a parameter of the BRDF (e.g. eta=1.5; 'veil models' lists them) at "
                  "VALUE; repeatable.")
#: The help of the options steps 1 and 2 word differently, by the kind of model they fit:
#: what -o holds, --fix and --free.
_STEP_HELP = {
    "medium": ("the fitted medium", "Hold a parameter of the medium (e.g. g=0.9; 'veil models' "
               "lists them) at VALUE; repeatable.", "Fit a parameter the medium model holds by "
               "default (held ones are marked in 'veil models', e.g. forward-series' s, the "
               "exposure factor); repeatable."),
    "brdf": ("the fitted target f_r", _BRDF_FIX_HELP, "Fit a parameter the BRDF family holds "
             "by default (marked held in 'veil models'); repeatable."),
}


def _step_through_medium_options(ranked_kind: str, given):
    """The arguments and options of a step through the medium (steps 1 and 2): the TABLE,
    the ``given`` model's option, the output, --fix and --free of the fitted model (of kind
    ``ranked_kind``), the channel, the black cloth, the accuracy, the evaluation budget, the
    model error, the propagation and the models (the fitted one may be ``auto``)."""
    output, fix, free = _STEP_HELP[ranked_kind]

    def decorate(command):
        for option in (click.pass_context, model_options(auto_kinds=(ranked_kind,)),
                       propagation_option, model_error_option, _max_nfev_option,
                       _accuracy_option, _black_option, _step_channel_option,
                       _free_option(free), _fix_option(fix),
                       click.option("-o", "--output", required=True, type=OUT_FILE,
                                    help=f"JSON file for {output} (written atomically)."),
                       given, click.argument("table", type=IN_FILE)):
            command = option(command)
        return command

    return decorate


#: Steps 1 and 2 by the kind of model they fit: the step and what its table holds.
_THROUGH_MEDIUM = {"medium": ("step 1, medium", "reference (in the medium)"),
                   "brdf": ("step 2, target", "target (in the medium)")}


def _fit_through_medium(ctx, fit_step, kind: str, table, given, output, *, fix, free, black,
                        models, channel, **fit_options) -> None:
    """``veil fit medium`` and ``veil fit target``: ``fit_step`` (veil.fitting's fit_medium
    or fit_target) of the ``kind`` model to ``table`` through the medium, ``given`` the
    (model held, file or preset it was read from) - the reference's f_r or the medium; the
    result written to ``output``. ``fit_options``: the accuracy, the evaluation budget, the
    model error and the propagation, as the command received them."""
    model, source = given
    check_output_path(output, [table, black] + ([source] if os.path.exists(source) else []))
    step, what = _THROUGH_MEDIUM[kind]

    def fit(family, options, fixed, freed, progress):
        return fit_step(table, model, fixed=fixed, black=black, progress=progress,
                        options=options, free=freed, channel=channel,
                        **{f"{kind}_model": family}, **fit_options)

    result = _fit_step(ctx, kind, step, models, fit, (table, black, channel), what, fix, free)
    _write_fit(ctx, result, output)


def _per_candidate(items, cands, parse, option: str) -> dict:
    """{candidate label: ``parse(items of its family's parameters, family)``} for a ranked
    fit: each NAME=VALUE (or NAME) applies to the candidates that declare the parameter; one
    that no candidate declares is a UserError."""
    from ..models import model_class

    used, out = set(), {}
    for c in cands:
        cls = model_class(c.family)
        mine = [i for i in items if i.partition("=")[0].strip() in cls.param_names()]
        used.update(mine)
        out[c.label] = parse(mine, cls)
    unused = [i for i in items if i not in used]
    if unused:
        raise UserError(f"{option} {', '.join(map(repr, unused))}: no candidate family has "
                        f"such a parameter")
    return out


def _ranked_fit(ctx, kind: str, step: str, models, data, fit, what: str, fix=(), free=()):
    """``--brdf-model auto`` / ``--medium-model auto``: every registered family of ``kind``
    (with each value of its discrete options) fitted by ``fit(candidate, fixed, freed)`` and
    ranked by BIC on ``data`` (veil.fitting.selection); the ranking printed and the chosen
    result returned with it in ``stats["selection"]``. Exit 1 with the table when every
    candidate failed."""
    from ..fitting import selection
    from ..fitting.session_data import prepare

    cands = selection.candidates(kind, models.brdf_options if kind == "brdf"
                                 else models.medium_options)
    fixes = _per_candidate(fix, cands, parse_fix, "--fix")
    frees = _per_candidate(free, cands, _parse_free, "--free")
    table, black, channel = data
    prepared = prepare(table, black, what, channel)

    def one(c):
        return fit(c, fixes[c.label], frees[c.label])

    try:
        with echo_warnings(), fit_progress(step) as progress:
            ranking, results = selection.select(step.rpartition(", ")[2], cands, prepared, one,
                                                what, progress)
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
    cls = models.brdf if kind == "brdf" else models.medium
    options = models.brdf_options if kind == "brdf" else models.medium_options
    if kind in models.ranked:
        return _ranked_fit(ctx, kind, step, models, data,
                           lambda c, fixed, freed: fit(c.family, c.model_options(options),
                                                       fixed, freed, None), what, fix, free)
    fixed, freed = parse_fix(fix, cls), _parse_free(free, cls)
    with echo_warnings(), fit_progress(step) as progress:
        return fit(cls.NAME, options, fixed, freed, progress)


def _parse_free(items, cls, option="--free") -> list:
    """Names of parameters held by default (``Param.held``) to fit too."""
    names = cls.param_names()
    out = []
    for item in items:
        name = item.strip()
        if name not in names:
            raise UserError(f"{option} {item!r}: {cls.NAME} has no parameter {name!r}; its "
                            f"parameters are {', '.join(names)}")
        if name in out:
            raise UserError(f"{option}: {name} is freed twice")
        out.append(name)
    return out


def _parse_step_free(items, models) -> dict:
    """``STEP.NAME`` strings of ``fit pipeline --free`` -> {step: [name, ...]}, checked
    against the chosen families."""
    classes = {"reference": models.brdf, "medium": models.medium, "target": models.brdf}
    return {step: _parse_free(names, classes[step], f"--free ({step})")
            for step, names in _step_entries(items, "--free").items()}


def _parse_step_fix(items, models) -> dict:
    """``STEP.NAME=VALUE`` strings of ``fit pipeline`` -> {step: {name: value}}."""
    by_step: dict = {}
    classes = {"reference": models.brdf, "medium": models.medium, "target": models.brdf}
    for item in items:
        head, sep, _ = item.partition("=")
        step, dot, name = head.partition(".")
        if not sep or not dot or step.strip() not in classes:
            raise UserError(f"--fix {item!r}: expected STEP.NAME=VALUE with STEP one of "
                            f"{', '.join(STEPS)}, e.g. medium.{models.medium.param_names()[-1]}"
                            f"=1.33")
        step = step.strip()
        by_step.setdefault(step, []).append(f"{name}={item.partition('=')[2]}")
    return {step: parse_fix(entries, classes[step], f"--fix ({step})")
            for step, entries in by_step.items()}


# --------------------------------------------------------------------------------------
# commands
# --------------------------------------------------------------------------------------
@click.group("fit", cls=LazyGroup)
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


_merl_option = click.option(
    "--merl", "merl", type=IN_FILE,
    help="A measured BRDF in the MERL binary format instead of a table: sampled at the "
         "--sampling configurations (docs/interop.md).")
_channel_option = click.option(
    "--channel", default=None, metavar="NAME",
    help="The one channel to fit of a TABLE with a channel column (r, g, b or a wavelength "
         "in nm; without it every channel is fitted at once, docs/fitting.md \"Channels\"), "
         "or the colour channel of the --merl file (r, g or b; without it the file's three "
         "channels are fitted at once).")
_step_channel_option = click.option(
    "--channel", default=None, metavar="NAME",
    help="The one channel to fit of a TABLE with a channel column (r, g, b or a wavelength "
         "in nm); a result fitted over several channels gives its model of this channel. "
         "Without it every channel is fitted at once, through a result of the same channels "
         "(docs/fitting.md \"Channels\").")
MERL_CHANNELS = ("r", "g", "b")
_sampling_option = click.option(
    "--sampling", type=click.Choice(["protocol", "inplane"]), default="protocol",
    show_default=True,
    help="Where the --merl BRDF is sampled: the paper's protocol (psi 30, 60, 90 deg) or every "
         "in-plane configuration on a 5-degree grid.")


def merl_table(merl, channel, sampling):
    """The measurement table of a MERL file's f_r (relative sigma of 1 %): of ``channel``,
    or of the three channels (None)."""
    from ..data.merl import channels_table, measurement_table, read_merl

    if channel is None:
        return channels_table(read_merl(merl), sampling=sampling)
    return measurement_table(read_merl(merl), channel, sampling)


@fit_command.command("reference")
@click.argument("table", type=IN_FILE, required=False)
@click.option("-o", "--output", required=True, type=OUT_FILE,
              help="JSON file for the fitted f_r (written atomically).")
@_fix_option(_BRDF_FIX_HELP)
@_black_option
@_max_nfev_option
@_merl_option
@_channel_option
@_sampling_option
@model_error_option
@model_options(("brdf",), auto_kinds=("brdf",))
@click.pass_context
def reference_command(ctx, table, output, fix, black, max_nfev, merl, channel, sampling,
                      model_error, models):
    """Step 0: fit the reference's f_r (default Torrance-Sparrow) to clear-medium data,
    directly: a measurement TABLE, or a measured BRDF (--merl FILE: its r, g, b channels at
    once, or one with --channel g)."""
    if (table is None) == (merl is None):
        raise UserError("give a measurement TABLE or --merl FILE (one of the two)")
    if merl is not None and black is not None:
        raise UserError("--black applies to a measurement table, not to --merl")
    check_output_path(output, [table, black, merl])
    if merl is not None and channel not in (None,) + MERL_CHANNELS:
        raise UserError(f"--channel {channel!r}: a MERL file has channels "
                        f"{', '.join(MERL_CHANNELS)}")
    data = table if merl is None else merl_table(merl, channel, sampling)
    one = channel if merl is None else None
    from ..fitting import fit_reference

    def fit(family, options, fixed, _, progress):
        return fit_reference(data, fixed=fixed, black=black, max_nfev=max_nfev,
                             progress=progress, brdf_model=family, options=options,
                             model_error=model_error, channel=one)

    result = _fit_step(ctx, "brdf", "step 0, reference", models, fit, (data, black, one),
                       "reference (clear medium)", fix)
    _write_fit(ctx, result, output)


@fit_command.command("medium")
@_step_through_medium_options("medium", click.option(
    "--reference", "reference", required=True, metavar="REF",
    help="The reference's f_r: a JSON file from 'veil fit reference', a preset (BRDF1, BRDF2) "
         "or a literal list of the BRDF's parameters (PD,PS,N,ETA for the paper's)."))
def medium_command(ctx, table, reference, output, models, **opts):
    """Step 1: fit the medium (default the paper's Td, Tt, g, eta) to the reference measured
    in it."""
    from ..fitting import fit_medium

    ref = load_reference(reference, models)
    _fit_through_medium(ctx, fit_medium, "medium", table, (ref, reference), output,
                        models=models, **opts)


@fit_command.command("target")
@_step_through_medium_options("brdf", click.option(
    "--medium", "medium", required=True, metavar="MEDIUM",
    help="The medium's f_t: a JSON file from 'veil fit medium', a preset (BTDF1, BTDF2, "
         "BTDF3) or a literal list of the medium's parameters (TD,TT,G,ETA for the paper's)."))
def target_command(ctx, table, medium, output, models, channel, **opts):
    """Step 2: fit the target's f_r (default Torrance-Sparrow) through the fitted medium.
    A JSON --medium keeps its own model and options (a contradicting option is an error)."""
    med = load_medium(medium, models)
    several = getattr(med, "channels", None)    # a fit of several channels: any one's options
    given = med.as_model(channel=(channel or next(iter(several))) if several else None) \
        if hasattr(med, "as_model") else med
    if "medium-model" in models.explicit and type(given) is not models.medium:
        raise UserError(f"--medium-model {models.medium.NAME} but {medium} is a "
                        f"{given.NAME} medium")
    for k, v in models.medium_options.items():
        if given.options().get(k) != v:
            raise UserError(f"--{k} {v} but {medium} has {k} {given.options().get(k)}; "
                            f"leave --{k} out to use the medium's")
    from ..fitting import fit_target

    _fit_through_medium(ctx, fit_target, "brdf", table, (med, medium), output,
                        models=models, channel=channel, **opts)


def print_pipeline(result) -> None:
    """The rankings (``--models auto``), the fit reports of a
    :class:`veil.pipeline.PipelineResult` and its comparison."""
    for ranking in getattr(result, "rankings", {}).values():
        print_ranking(ranking)
    for r in (result.reference, result.medium, result.target, result.direct):
        if r is not None:
            click.echo(r.report())
            click.echo("")
    if result.comparison is not None:
        c = result.comparison
        click.echo("[[Estimated target f_r against the direct fit]]")
        for name, row in c["params"].items():
            z = "n/a" if row["z"] is None else f"{row['z']:+.2f}"
            click.echo(f"    {name:<4}: estimated {row['estimated']:.6g}, direct "
                       f"{row['direct']:.6g}, difference {row['difference']:+.3g} "
                       f"({z} combined stderr)")
        click.echo(f"    rms f_r difference over {c['n_configurations']} protocol "
                   f"configurations: {c['rms_fr_difference']:.4g} "
                   f"({100 * c['rms_fr_relative']:.3g} % rms relative)")


@fit_command.command("pipeline")
@click.option("--reference-clear", required=True, type=IN_FILE,
              help="Reference object in a clear medium (step 0).")
@click.option("--reference-medium", required=True, type=IN_FILE,
              help="Reference object in the scattering medium (step 1).")
@click.option("--target-medium", required=True, type=IN_FILE,
              help="Target object in the scattering medium (step 2).")
@_black_option
@click.option("--target-clear", type=IN_FILE,
              help="Target object in a clear medium: fitted directly and compared with the "
                   "estimate.")
@click.option("-o", "--outdir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Directory for the JSON results, figures and report.md (created).")
@_fix_option("Hold a parameter of one step: STEP.NAME=VALUE, STEP reference, medium or "
             "target (e.g. medium.eta=1.33); repeatable. Target values also hold in the "
             "direct fit.")
@click.option("--free", "free", multiple=True, metavar="STEP.NAME",
              help="Fit a parameter the family holds by default in one step (e.g. medium.s, "
                   "the forward-series exposure factor); repeatable.")
@click.option("--models", "model_spec", default=None, metavar="auto|paper|FAMILY+MEDIUM",
              help="Which models: 'auto' fits every registered family (each value of its "
                   "discrete options) and ranks them per step by BIC with the fit's "
                   "model-discrepancy term, using the best (step 0 the reference's BRDF, step "
                   "1 the medium, step 2 the target's BRDF; tables in the output and "
                   "report.md); 'paper' the paper's Torrance-Sparrow + Henyey-Greenstein; "
                   "FAMILY+MEDIUM pins a pair (e.g. rough-plastic+forward-series).  "
                   "[default: paper]")
@click.option("--compare", is_flag=True,
              help="--models auto with the ranking written out in full: every candidate's "
                   "result in OUTDIR/candidates/STEP/. Options, --fix and --free apply to the "
                   "candidates that declare them.")
@click.option("--figures/--no-figures", default=True, show_default=True,
              help="Draw the data against the fitted curves (the PNGs); --no-figures writes "
                   "the results and report.md only, faster.")
@_accuracy_option
@_max_nfev_option
@model_error_option
@propagation_option
@click.option("--channel", default=None, metavar="NAME",
              help="The one channel to fit of tables with a channel column; without it every "
                   "step fits every channel at once (docs/fitting.md \"Channels\").")
@model_options()
@click.pass_context
def pipeline_command(ctx, reference_clear, reference_medium, target_medium, black, target_clear,
                     outdir, fix, free, model_spec, compare, figures, accuracy, max_nfev,
                     model_error, propagation, models, channel):
    """Steps 0-2 in one go, with figures (data against fitted curves, over their relative
    residuals) and report.md; --models auto lets the data choose the models."""
    from ..models import AUTO
    from ..pipeline import run_pipeline

    auto = models.mode == AUTO
    if auto:
        fixed = _raw_step_fix(fix)
        freed = _step_entries(free, "--free")
    else:
        fixed = _parse_step_fix(fix, models)
        freed = _parse_step_free(free, models)
    if outdir.exists() and not outdir.is_dir():
        raise UserError(f"--outdir {outdir} exists and is not a directory")
    if not outdir.parent.exists() and not outdir.exists():
        raise UserError(f"cannot create {outdir}: directory {outdir.parent} does not exist")
    chosen = ({"models": AUTO} if auto else
              {"brdf_model": models.brdf.NAME, "medium_model": models.medium.NAME})
    from ..fitting.selection import NoCandidateError

    try:
        with echo_warnings(), fit_progress("pipeline") as progress:
            result = run_pipeline(reference_clear, reference_medium, target_medium,
                                  black=black, target_clear=target_clear, outdir=outdir,
                                  accuracy=accuracy, fixed=fixed, max_nfev=max_nfev,
                                  progress=progress, brdf_options=models.brdf_options,
                                  medium_options=models.medium_options, free=freed,
                                  figures=figures, model_error=model_error,
                                  propagation=propagation, keep_candidates=compare,
                                  channel=channel, **chosen)
    except NoCandidateError as exc:
        print_ranking(exc.ranking)
        click.echo(f"Error: {exc}; nothing was written", err=True)
        ctx.exit(1)
    print_pipeline(result)
    fits = [result.reference, result.medium, result.target, result.direct]
    finish_fits(ctx, fits, list(result.files.values()))


def print_ranking(ranking) -> None:
    """One step's ranking of ``--models auto`` as a table."""
    from ..fitting.selection import table_lines

    click.echo(f"[[Candidates of step '{ranking.step}', ranked by BIC with the "
               f"model-discrepancy term; * the one used]]")
    for line in table_lines(ranking):
        click.echo("    " + line)
    click.echo("")


def _raw_step_fix(items) -> dict:
    """``STEP.NAME=VALUE`` -> {step: {name: value}}, names checked against the candidates
    later (veil.pipeline)."""
    import math

    fixed: dict[str, dict[str, float]] = {}
    for step, entries in _step_entries(items, "--fix").items():
        for entry in entries:
            name, sep, text = entry.partition("=")
            try:
                value = float(text)
            except ValueError:
                value = math.nan
            if not sep or not math.isfinite(value):
                raise UserError(f"--fix {step}.{entry!r}: expected STEP.NAME=VALUE with a "
                                f"finite number")
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
            raise UserError(f"{option} {item!r}: expected STEP.NAME with STEP one of "
                            f"{', '.join(STEPS)}")
        by_step.setdefault(step.strip(), []).append(rest.strip())
    return by_step
