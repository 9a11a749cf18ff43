"""The whole estimation of docs/model.md sec. 7 in one call: steps 0-2, result files,
figures, report.

:func:`run_pipeline` fits the reference's f_r in a clear medium (step 0), the medium through
the reference (step 1) and the target through the medium (step 2), and writes into ``outdir``
(as one transaction, :func:`veil.io.output_folder`: a rerun replaces these files together,
an interrupted or failed run leaves the folder as it was):

- ``reference.json``, ``medium.json``, ``target.json``: :class:`veil.fitting.FitResult` files;
- ``reference.png``, ``medium.png``, ``target.png``: data against the fitted curves, value
  against the signed reflection angle theta_r, one curve per psi (like the paper's figs.
  15-17), over a panel of the relative residuals with the fit's model-error band, where a
  trend in the angles that the model cannot follow shows;
- with ``target_clear``: ``target_direct.json`` (the target fitted directly, no medium),
  ``target_direct.png`` and a comparison of the estimated f_r with it;
- ``report.md``: the parameter tables and the comparison.

Formats and the meaning of the uncertainties: docs/fitting.md.

More arguments of :func:`run_pipeline`:

- ``truth``: optional true models {"reference": ..., "medium": ..., "target": ...}
  (simulated data) listed beside the estimates in report.md; over several channels each
  one model for every channel, or {channel: model} (a ``ChannelModel``), compared
  channel by channel (:func:`veil.analysis.comparison.true_values`).
- ``brdf_model``, ``medium_model``, ``brdf_options``, ``medium_options``: the families of
  the objects and of the medium (registered names; default the paper's) and their options.
- ``model_error``: the model-discrepancy term of every weighted step ("off", "independent"
  or "correlated", the default; :mod:`veil.fitting.model_error`): step 2 uses step 1's
  when larger than its own and counts the error the two share.
- ``propagation``: how each step's given covariance enters its ``stderr_total`` ("auto",
  the default, "linear" or "sigma-points"; :mod:`veil.fitting.propagation`).
- ``models``: None (``brdf_model`` / ``medium_model`` as given), "paper" (the paper's
  models), "BRDF+MEDIUM" (a pinned pair) or "auto": every registered candidate ranked per
  step by BIC with its model-discrepancy term (:mod:`veil.fitting.selection`,
  :mod:`veil.fitting.auto`), the best one used; step 2 ranked on ``target_clear`` when
  given, the steps through the medium screened (:mod:`veil.fitting.screening`); options,
  ``fixed`` and ``free`` then apply to the candidates that declare them. Rankings in
  ``ranking.json``, report.md and
  each chosen result's ``stats["selection"]``; with ``keep_candidates`` every candidate's
  result too, in ``candidates/<step>/``. Every candidate failing raises
  :class:`veil.fitting.selection.NoCandidateError` (with the rankings).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from typing import Any

from .analysis.comparison import check_truth, compare
from .errors import FitError, as_flag
from .fitting import (
    FitResult,
    fit_direct,
    fit_medium,
    fit_reference,
    fit_target,
    prepare,
    selection,
)
from .fitting.auto import for_family, plan_candidates, select_steps
from .fitting.model_error import check_kind
from .fitting.propagation import check_method
from .fitting.session_data import channels_of, stack
from .fitting.step_fit import fixes_of_step
from .fitting.steps import prefetch
from .io import as_path, check_output_folder, output_folder, write_bytes_atomic, write_text_atomic
from .models import AUTO, model_class
from .viz.fit_figures import fit_figure
from .viz.fit_figures_colour import channel_fit_figure
from .viz.pipeline_report import channels_section, pipeline_report, ranking_section

#: Output files, by role.
FILES = {
    "reference": "reference.json",
    "medium": "medium.json",
    "target": "target.json",
    "direct": "target_direct.json",
    "report": "report.md",
    "reference_fig": "reference.png",
    "medium_fig": "medium.png",
    "target_fig": "target.png",
    "direct_fig": "target_direct.png",
}
#: With ``models="auto"``: the rankings of the three steps.
RANKING_FILE = "ranking.json"
#: With ``keep_candidates``, every candidate's result under this folder, by step.
CANDIDATES_DIR = "candidates"
STEP_KEYS = ("reference", "medium", "target")
#: The key of ``data`` (:func:`_prepare_sessions`) holding every channel's data.
CHANNEL_DATA = "by channel"


@dataclass(frozen=True)
class PipelineResult:
    """The three fits (and the direct fit of the target), the comparison and the files."""

    reference: FitResult
    medium: FitResult
    target: FitResult
    direct: FitResult | None = None
    comparison: dict | None = None
    files: dict = field(default_factory=dict)
    #: With ``models="auto"``: {step: :class:`veil.fitting.selection.Ranking`}.
    rankings: dict = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        fits = [self.reference, self.medium, self.target] + ([self.direct] if self.direct else [])
        return all(f.converged for f in fits)


def _check_fixed(fixed, what: str = "fixed") -> dict:
    if fixed is None:
        return {}
    if not isinstance(fixed, dict) or set(fixed) - set(STEP_KEYS):
        raise FitError(
            f"{what} = {fixed!r}; expected a dict by step, e.g. "
            f"{{'medium': {{'eta': 1.33}}, 'target': {{'eta': 1.5}}}} (steps "
            f"{', '.join(STEP_KEYS)})"
        )
    return fixed


def _same(a, b) -> bool:
    a, b = os.fspath(a), os.fspath(b)
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.abspath(a) == os.path.abspath(b)


def _inside(path, folder) -> bool:
    path, folder = os.path.abspath(os.fspath(path)), os.path.abspath(os.fspath(folder))
    return path.startswith(folder + os.sep)


def _check_outputs(outdir: str, inputs: dict) -> None:
    check_output_folder(outdir)
    for name in FILES.values():
        out = os.path.join(outdir, name)
        for what, inp in inputs.items():
            if isinstance(inp, (str, os.PathLike)) and _same(out, inp):
                raise FitError(
                    f"input {what} ({os.fspath(inp)}) would be overwritten by the "
                    f"output {out}; veil never overwrites an input: choose another "
                    f"output directory"
                )


def _prepare_sessions(inputs: dict, channel: str | None = None) -> tuple[dict, list | None]:
    """Every session read and checked before the first (long) fit (black cloth subtracted
    from the sessions in the medium): ({session: its data}, the channels fitted at once or
    None). Of several channels (none chosen) every channel is checked, the data are the
    first channel's (the engine's configurations) and ``data[CHANNEL_DATA]`` holds
    {session: {channel: its data}} (the figures')."""
    black = inputs["black"]
    whats = {
        "reference_clear": "reference (clear medium)",
        "reference_medium": "reference (in the medium)",
        "target_medium": "target (in the medium)",
        "target_clear": "target (clear medium)",
    }
    keys = [k for k in whats if inputs[k] is not None]
    # each session read once: with no channel chosen, with its channels
    loaded = {
        k: channels_of(inputs[k], whats[k]) if channel is None else (inputs[k], None) for k in keys
    }
    channels = loaded["reference_clear"][1]
    channels = channels if channels is not None and len(channels) > 1 else None
    data: dict = {}
    by_channel: dict = {}
    for key in keys:
        session_black = black if key in ("reference_medium", "target_medium") else None
        table, own = loaded[key]
        for c in _session_channels(inputs[key], own, whats[key], channels, channel):
            found = prepare(table, session_black, whats[key], channel=c)
            data.setdefault(key, found)
            by_channel.setdefault(key, {})[c] = found
    if channels:
        data[CHANNEL_DATA] = by_channel
    return data, channels


def _session_channels(table, own: list | None, what: str, channels, channel) -> list:
    """The channels of the session ``table`` in its own order ``own`` (the order of a fit's
    residuals over them, which the ranking's stacked data must follow); a FitError when
    they are not the reference's ``channels`` (or one, when it has one)."""
    if not channels and len(own or ()) < 2:
        return [channel]
    if own is None or set(own) != set(channels or ()):
        named = f" {os.fspath(table)}" if isinstance(table, (str, os.PathLike)) else ""
        raise FitError(
            f"the {what} table{named} has channels {', '.join(own or ['(none)'])} but the "
            f"reference (clear medium) table has {', '.join(channels or ['one channel'])}: every "
            f"session needs the same channels (or fit one: channel='NAME', --channel NAME)"
        )
    return own


def _channel_sources(inputs: dict, channels) -> dict | None:
    """{session: (table, black)} the steps fit over several ``channels`` (None for one)."""
    if channels is None:
        return None
    return {
        k: (inputs[k], inputs["black"] if k.endswith("_medium") else None)
        for k in ("reference_clear", "reference_medium", "target_medium", "target_clear")
        if inputs[k] is not None
    }


def _relative_to(inputs: dict, outdir: str) -> dict:
    """The inputs, those inside ``outdir`` named relative to it."""
    return {
        k: (
            os.path.relpath(v, outdir)
            if isinstance(v, (str, os.PathLike)) and _inside(v, outdir)
            else v
        )
        for k, v in inputs.items()
    }


def _stage(progress, name: str):
    """The progress callback of one step (None without ``progress``); announces the step at
    once."""
    if progress is None:
        return None
    progress(f"{name}: starting", None, None)
    return lambda what, done, total: progress(f"{name}: {what}", done, total)


def _write_figures(folder, data: dict, ref, med, tgt, direct) -> dict:
    """The figure of each fit in ``folder``: {figure key: file name}."""
    if CHANNEL_DATA in data:
        return _write_channel_figures(folder, data[CHANNEL_DATA], ref, med, tgt, direct)
    figs = {
        "reference_fig": (data["reference_clear"], ref, None, None),
        "medium_fig": (data["reference_medium"], med, ref.one_model(), None),
        "target_fig": (data["target_medium"], tgt, med.one_model(), None),
    }
    if direct is not None:
        figs["direct_fig"] = (data["target_clear"], direct, None, tgt)
    for key, (d, result, other, extra) in figs.items():
        write_bytes_atomic(folder / FILES[key], fit_figure(d, result, other, extra))
    return {key: FILES[key] for key in figs}


def _write_channel_figures(folder, datas: dict, ref, med, tgt, direct) -> dict:
    """:func:`_write_figures` of fits over several channels: every channel in its colour."""
    channels = ref.channel_names
    figs = {
        "reference_fig": (datas["reference_clear"], ref, None, None),
        "medium_fig": (datas["reference_medium"], med, ref, None),
        "target_fig": (datas["target_medium"], tgt, med, None),
    }
    if direct is not None:
        figs["direct_fig"] = (datas["target_clear"], direct, None, tgt)
    for key, (d, result, other, extra) in figs.items():
        others = {c: None if other is None else other.as_model(channel=c) for c in channels}
        write_bytes_atomic(folder / FILES[key], channel_fit_figure(d, result, others, extra))
    return {key: FILES[key] for key in figs}


def _resolve_models(models, brdf_model, medium_model) -> tuple[Any, Any, bool]:
    """``models=`` against ``brdf_model`` / ``medium_model``: (the BRDF family, the medium
    family, whether the data choose them, ``models="auto"``)."""
    if models is None:
        return brdf_model, medium_model, False
    mode = selection.parse_models(models)
    if brdf_model is not None or medium_model is not None:
        raise FitError("give models= or brdf_model= / medium_model=, not both")
    if isinstance(mode, tuple):  # a pinned pair
        return mode[0], mode[1], False
    return None, None, mode == AUTO  # PAPER: the default families


@dataclass(frozen=True)
class _Run:
    """The settings of one pipeline run, checked (:func:`run_pipeline`'s arguments)."""

    outdir: str
    fixed: dict
    free: dict
    variant: str | None
    accuracy: str
    max_nfev: int | None
    progress: Any
    truth: Any
    figures: bool
    brdf_model: Any
    medium_model: Any
    brdf_options: Any
    medium_options: Any
    model_error: Any
    propagation: Any
    auto: bool
    keep_candidates: bool
    channel: str | None


def _fit_steps(data: dict, run: _Run, sources=None) -> tuple[FitResult, FitResult, FitResult]:
    """Steps 0-2 with the given families: (reference, medium, target). ``sources``
    {session: (table, black)} replaces the checked data's tables (several channels: each
    step fits them at once, the black cloth subtracted channel by channel)."""
    fixed, free, progress = run.fixed, run.free, run.progress
    brdf = {
        "brdf_model": run.brdf_model,
        "options": run.brdf_options,
        "model_error": run.model_error,
    }
    chained = {
        "model_error": run.model_error,
        "propagation": run.propagation,
        "accuracy": run.accuracy,
        "max_nfev": run.max_nfev,
    }
    table, black = {}, {}
    for key in ("reference_clear", "reference_medium", "target_medium"):
        table[key], black[key] = (sources or {}).get(key, (data[key].table, None))
    prefetch(
        data["reference_medium"],
        brdf_model=run.brdf_model,
        brdf_options=run.brdf_options,
        medium_model=run.medium_model,
        medium_options=run.medium_options,
        variant=run.variant,
        accuracy=run.accuracy,
    )
    with fixes_of_step("reference"):
        ref = fit_reference(
            table["reference_clear"],
            fixed=fixed.get("reference"),
            max_nfev=run.max_nfev,
            progress=_stage(progress, "step 0, reference"),
            free=free.get("reference"),
            **brdf,
        )
    with fixes_of_step("medium"):
        med = fit_medium(
            table["reference_medium"],
            ref,
            fixed=fixed.get("medium"),
            black=black["reference_medium"],
            variant=run.variant,
            progress=_stage(progress, "step 1, medium"),
            medium_model=run.medium_model,
            options=run.medium_options,
            free=free.get("medium"),
            **chained,
        )
    with fixes_of_step("target"):
        tgt = fit_target(
            table["target_medium"],
            med,
            fixed=fixed.get("target"),
            black=black["target_medium"],
            progress=_stage(progress, "step 2, target"),
            free=free.get("target"),
            brdf_model=run.brdf_model,
            options=run.brdf_options,
            **chained,
        )
    return ref, med, tgt


def _fit_direct(session, run: _Run, *, chosen: bool, brdf_model, brdf_options) -> FitResult:
    """The target fitted directly in the clear medium; ``chosen``: ``brdf_model`` was
    chosen among candidates, and only the target entries its family declares apply."""
    fix_d, free_d = run.fixed.get("target"), run.free.get("target")
    if chosen:
        cls = model_class(brdf_model)
        fix_d = for_family(cls, run.fixed, "target", "fixed", set())
        free_d = for_family(cls, run.free, "target", "free", set())
    table = session if isinstance(session, (str, os.PathLike)) else session.table
    with fixes_of_step("target"):  # the target's entries hold in the direct fit too
        return fit_direct(
            table,
            fixed=fix_d,
            max_nfev=run.max_nfev,
            free=free_d,
            progress=_stage(run.progress, "target, clear medium"),
            brdf_model=brdf_model,
            options=brdf_options,
            model_error=run.model_error,
        )


def _write_outputs(
    run: _Run,
    fits: dict,
    data: dict,
    rankings: dict,
    kept: dict,
    *,
    comparison,
    shown: dict,
    channels=None,
) -> dict:
    """The pipeline's files in ``run.outdir``, as one transaction: {key: file name}.
    ``shown``: the inputs as report.md names them."""
    names = {}
    owned = list(FILES.values()) + [RANKING_FILE, CANDIDATES_DIR]
    with output_folder(run.outdir, owned=owned) as folder:
        for key, result in fits.items():
            if result is not None:
                result.to_json(folder / FILES[key])
                names[key] = FILES[key]
        names.update(_write_selection(folder, rankings, kept))
        ref, med, tgt, direct = (fits[k] for k in ("reference", "medium", "target", "direct"))
        if run.figures:
            if run.progress is not None:
                run.progress("figures", None, None)
            names.update(_write_figures(folder, data, ref, med, tgt, direct))
        report = pipeline_report(ref, med, tgt, direct, comparison, run.truth, names, shown)
        if rankings:
            report = report.rstrip("\n") + "\n\n" + "\n".join(ranking_section(rankings)) + "\n"
        if channels is not None:
            report = report.rstrip("\n") + "\n\n" + channels_section(channels, comparison)
        write_text_atomic(folder / FILES["report"], report)
        names["report"] = FILES["report"]
    return names


def _pipeline(run: _Run, inputs: dict) -> PipelineResult:
    """:func:`run_pipeline` with its settings checked: read every session, fit (or rank the
    candidates of) steps 0-2, fit the target directly if given, write the files."""
    brdf_model, brdf_options = run.brdf_model, run.brdf_options
    # the candidates and their entries, checked before any reading
    plan = (
        plan_candidates(run.fixed, run.free, brdf_options, run.medium_options, run.variant)
        if run.auto
        else None
    )
    # read and check every input before the first (long) fit
    data, channels = _prepare_sessions(inputs, run.channel)
    run = replace(run, truth=check_truth(run.truth, channels, run.channel))
    sources = _channel_sources(inputs, channels)
    rankings, kept = dict[str, Any](), dict[str, Any]()
    if plan is not None:
        # of several channels, the candidates are ranked on every channel's data
        ranked = data if sources is None else {k: stack(v) for k, v in data[CHANNEL_DATA].items()}
        ref, med, tgt, direct, brdf_model, brdf_options, rankings, kept = select_steps(
            ranked,
            plan,
            accuracy=run.accuracy,
            max_nfev=run.max_nfev,
            progress=run.progress,
            model_error=run.model_error,
            propagation=run.propagation,
            keep=run.keep_candidates,
            sources=sources,
        )
    else:
        ref, med, tgt = _fit_steps(data, run, sources)
        direct = None
    comparison = None
    if direct is None and inputs["target_clear"] is not None:
        direct = _fit_direct(
            inputs["target_clear"] if channels else data["target_clear"],
            run,
            chosen=bool(rankings),
            brdf_model=brdf_model,
            brdf_options=brdf_options,
        )
    if direct is not None:
        comparison = compare(tgt, direct)

    fits = {"reference": ref, "medium": med, "target": tgt, "direct": direct}
    # inputs inside the output folder are named relative to it (links from report.md)
    names = _write_outputs(
        run,
        fits,
        data,
        rankings,
        kept,
        comparison=comparison,
        shown=_relative_to(inputs, run.outdir),
        channels=channels,
    )
    files = {key: os.path.join(run.outdir, name) for key, name in names.items()}
    return PipelineResult(ref, med, tgt, direct, comparison, files, rankings)


def run_pipeline(
    reference_clear,
    reference_medium,
    target_medium,
    black=None,
    target_clear=None,
    outdir="veil-fit",
    *,
    variant: str | None = None,
    accuracy: str = "default",
    fixed=None,
    max_nfev=None,
    progress=None,
    truth=None,
    figures: bool = True,
    brdf_model=None,
    medium_model=None,
    brdf_options=None,
    medium_options=None,
    free=None,
    model_error=None,
    propagation=None,
    models=None,
    keep_candidates: bool = False,
    channel: str | None = None,
) -> PipelineResult:
    """Steps 0-2 of docs/model.md sec. 7 with files, figures and report.md in ``outdir``.

    reference_clear, reference_medium, target_medium : sessions (DataFrames or CSV paths):
        the reference in a clear medium, the reference in the medium, the target in the medium.
    black : black-cloth session in the medium, subtracted from both medium sessions.
    target_clear : optional target in a clear medium: fitted directly and compared with the
        estimate (parameter differences in units of their combined standard error, rms of
        the f_r difference over the protocol's configurations).
    fixed : parameters held per step, e.g. ``{"medium": {"eta": 1.33}}``; the target's also
        apply to the direct fit.
    free : parameters the families hold by default (``Param.held``) to fit too, per step,
        e.g. ``{"medium": ["s"]}``; the target's also apply to the direct fit.
    channel : one channel of the tables; None: all in every step (docs/channels.md).
    truth, the models and their options, model_error, propagation, models and
    keep_candidates: the module docstring. Other arguments as :func:`veil.fit_medium`.
    """
    model_error, propagation = check_kind(model_error), check_method(propagation)
    fixed, free, outdir = _check_fixed(fixed), _check_fixed(free, "free"), as_path(outdir, "outdir")
    inputs = {
        "reference_clear": reference_clear,
        "reference_medium": reference_medium,
        "target_medium": target_medium,
        "black": black,
        "target_clear": target_clear,
    }
    _check_outputs(outdir, inputs)
    brdf_model, medium_model, auto = _resolve_models(models, brdf_model, medium_model)
    run = _Run(
        outdir,
        fixed,
        free,
        variant,
        accuracy,
        max_nfev,
        progress,
        truth,
        as_flag(figures, "figures", FitError),
        brdf_model,
        medium_model,
        brdf_options,
        medium_options,
        model_error,
        propagation,
        auto,
        as_flag(keep_candidates, "keep_candidates", FitError),
        channel,
    )
    return _pipeline(run, inputs)


# --------------------------------------------------------------------------------------
# models="auto": the rankings and every candidate's result in the output folder
# --------------------------------------------------------------------------------------
def _file_name(label: str) -> str:
    """A candidate's result file: its label with [ , = ] made file-name safe."""
    for a, b in (("[", "_"), ("]", ""), (",", "_"), ("=", "-")):
        label = label.replace(a, b)
    return label + ".json"


def _write_selection(folder, rankings: dict, kept: dict) -> dict:
    """``ranking.json`` (with rankings) and every kept candidate's result in ``folder``:
    {key: file name}."""
    names = {}
    if rankings:
        write_text_atomic(
            folder / RANKING_FILE,
            json.dumps({step: r.to_dict() for step, r in rankings.items()}, indent=1) + "\n",
        )
        names["ranking"] = RANKING_FILE
    for step, results in kept.items():
        (folder / CANDIDATES_DIR / step).mkdir(parents=True, exist_ok=True)
        for label, result in results.items():
            name = os.path.join(CANDIDATES_DIR, step, _file_name(label))
            result.to_json(folder / name)
            names[f"{CANDIDATES_DIR}/{step}/{label}"] = name
    return names


__all__ = [
    "run_pipeline",
    "PipelineResult",
    "compare",
    "fit_figure",
    "FILES",
    "RANKING_FILE",
    "CANDIDATES_DIR",
]
