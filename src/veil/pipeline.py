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
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .analysis.comparison import compare
from .data.measurements import CANONICAL
from .data.protocol import protocol
from .errors import FitError
from .fitting import (
    FitResult,
    fit_direct,
    fit_medium,
    fit_reference,
    fit_target,
    model_values,
    prepare,
    selection,
)
from .fitting.model_error import check_kind
from .fitting.propagation import check_method
from .fitting.session_data import channels_of
from .fitting.steps import prefetch
from .io import check_output_folder, output_folder, write_bytes_atomic, write_text_atomic
from .models import AUTO, model_class
from .models.base import VARIANT_OPTION
from .viz.documents import pipeline_report, ranking_section
from .viz.fit_figures import fit_figure
from .viz.fit_figures_colour import channel_fit_figure

#: Output files, by role.
FILES = {"reference": "reference.json", "medium": "medium.json", "target": "target.json",
         "direct": "target_direct.json", "report": "report.md",
         "reference_fig": "reference.png", "medium_fig": "medium.png",
         "target_fig": "target.png", "direct_fig": "target_direct.png"}
#: With ``models="auto"``: the rankings of the three steps.
RANKING_FILE = "ranking.json"
#: With ``keep_candidates``, every candidate's result under this folder, by step.
CANDIDATES_DIR = "candidates"
STEP_KEYS = ("reference", "medium", "target")
#: report.md's section on a pipeline over several channels.
CHANNELS_NOTE = ("## Channels\n\nEvery step fitted the channels {} at once, the parameters "
                 "declared per channel one per channel and the others tied (docs/channels.md). "
                 "The figures draw every channel in its colour.")
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
        raise FitError(f"{what} = {fixed!r}; expected a dict by step, e.g. "
                       f"{{'medium': {{'eta': 1.33}}, 'target': {{'eta': 1.5}}}} (steps "
                       f"{', '.join(STEP_KEYS)})")
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
                raise FitError(f"input {what} ({os.fspath(inp)}) would be overwritten by the "
                               f"output {out}; veil never overwrites an input: choose another "
                               f"output directory")


def _prepare_sessions(inputs: dict, channel: str | None = None) -> tuple[dict, list | None]:
    """Every session read and checked before the first (long) fit (black cloth subtracted
    from the sessions in the medium): ({session: its data}, the channels fitted at once or
    None). Of several channels (none chosen) every channel is checked, the data are the
    first channel's (the engine's configurations) and ``data[CHANNEL_DATA]`` holds
    {session: {channel: its data}} (the figures')."""
    black = inputs["black"]
    whats = {"reference_clear": "reference (clear medium)",
             "reference_medium": "reference (in the medium)",
             "target_medium": "target (in the medium)", "target_clear": "target (clear medium)"}
    keys = [k for k in whats if inputs[k] is not None]
    channels = None
    if channel is None:
        _, channels = channels_of(inputs["reference_clear"], whats["reference_clear"])
        channels = channels if channels is not None and len(channels) > 1 else None
    data: dict = {}
    picks: list[str | None] = list(channels) if channels else [channel]
    by_channel: dict = {}
    for key in keys:
        session_black = black if key in ("reference_medium", "target_medium") else None
        for c in picks:
            found = prepare(inputs[key], session_black, whats[key], channel=c)
            data.setdefault(key, found)
            by_channel.setdefault(key, {})[c] = found
    if channels:
        data[CHANNEL_DATA] = by_channel
    return data, channels


def _channel_sources(inputs: dict, channels, auto: bool, truth) -> dict | None:
    """{session: (table, black)} the steps fit over several ``channels`` (None for one);
    ``models="auto"`` and ``truth`` take one channel (a FitError)."""
    if channels is None:
        return None
    if auto or truth is not None:
        raise FitError(f"the tables hold channels {', '.join(channels)}: "
                       f"{'models=auto' if auto else 'truth='} takes one channel; choose one "
                       f"with channel= (--channel NAME)")
    return {k: (inputs[k], inputs["black"] if k.endswith("_medium") else None)
            for k in ("reference_clear", "reference_medium", "target_medium")}


def _relative_to(inputs: dict, outdir: str) -> dict:
    """The inputs, those inside ``outdir`` named relative to it."""
    return {k: (os.path.relpath(v, outdir) if isinstance(v, (str, os.PathLike))
                and _inside(v, outdir) else v) for k, v in inputs.items()}


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
    figs = {"reference_fig": (data["reference_clear"], ref, None, None),
            "medium_fig": (data["reference_medium"], med, ref.one_model(), None),
            "target_fig": (data["target_medium"], tgt, med.one_model(), None)}
    if direct is not None:
        figs["direct_fig"] = (data["target_clear"], direct, None, tgt)
    for key, (d, result, other, extra) in figs.items():
        write_bytes_atomic(folder / FILES[key], fit_figure(d, result, other, extra))
    return {key: FILES[key] for key in figs}


def _write_channel_figures(folder, datas: dict, ref, med, tgt, direct) -> dict:
    """:func:`_write_figures` of fits over several channels: every channel in its colour."""
    channels = ref.channel_names
    figs = {"reference_fig": (datas["reference_clear"], ref, None, None),
            "medium_fig": (datas["reference_medium"], med, ref, None),
            "target_fig": (datas["target_medium"], tgt, med, None)}
    if direct is not None:
        figs["direct_fig"] = (datas["target_clear"], direct, None, tgt)
    for key, (d, result, other, extra) in figs.items():
        others = {c: None if other is None else other.as_model(channel=c) for c in channels}
        write_bytes_atomic(folder / FILES[key], channel_fit_figure(d, result, others, extra))
    return {key: FILES[key] for key in figs}


def _channel_lines(comparison: dict | None) -> str:
    """report.md's per-channel comparison of the estimate with the direct fit (if any)."""
    if not comparison or "rms_fr_relative_by_channel" not in comparison:
        return ""
    rows = [f"| {c} | {100 * v:.3g} |"
            for c, v in comparison["rms_fr_relative_by_channel"].items()]
    return ("\n\nThe estimate against the target measured directly, per channel (rms relative "
            "difference of f_r over the paper's protocol):\n\n| channel | rms [%] |\n|---|---|\n"
            + "\n".join(rows))


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


def _fit_steps(data: dict, fixed: dict, free: dict, *, variant, accuracy, max_nfev, progress,
               brdf_model, medium_model, brdf_options, medium_options, model_error,
               propagation, sources=None) -> tuple[FitResult, FitResult, FitResult]:
    """Steps 0-2 with the given families: (reference, medium, target). ``sources``
    {session: (table, black)} replaces the checked data's tables (several channels: each
    step fits them at once, the black cloth subtracted channel by channel)."""
    brdf = {"brdf_model": brdf_model, "options": brdf_options, "model_error": model_error}
    chained = {"model_error": model_error, "propagation": propagation}
    table, black = {}, {}
    for key in ("reference_clear", "reference_medium", "target_medium"):
        table[key], black[key] = (sources or {}).get(key, (data[key].table, None))
    prefetch(data["reference_medium"], brdf_model=brdf_model, brdf_options=brdf_options,
             medium_model=medium_model, medium_options=medium_options, variant=variant,
             accuracy=accuracy)
    ref = fit_reference(table["reference_clear"], fixed=fixed.get("reference"),
                        max_nfev=max_nfev, progress=_stage(progress, "step 0, reference"),
                        free=free.get("reference"), **brdf)
    med = fit_medium(table["reference_medium"], ref, fixed=fixed.get("medium"),
                     black=black["reference_medium"], variant=variant, accuracy=accuracy,
                     max_nfev=max_nfev, progress=_stage(progress, "step 1, medium"),
                     medium_model=medium_model, options=medium_options,
                     free=free.get("medium"), **chained)
    tgt = fit_target(table["target_medium"], med, fixed=fixed.get("target"),
                     black=black["target_medium"], accuracy=accuracy, max_nfev=max_nfev,
                     progress=_stage(progress, "step 2, target"), free=free.get("target"),
                     brdf_model=brdf_model, options=brdf_options,
                     **chained)
    return ref, med, tgt


def _fit_direct(session, fixed: dict, free: dict, *, chosen: bool, brdf_model, brdf_options,
                max_nfev, progress, model_error) -> FitResult:
    """The target fitted directly in the clear medium; ``chosen``: ``brdf_model`` was
    chosen among candidates, and only the target entries its family declares apply."""
    fix_d, free_d = fixed.get("target"), free.get("target")
    if chosen:
        cls = model_class(brdf_model)
        fix_d = _for_family(cls, fixed, "target", "fixed", set())
        free_d = _for_family(cls, free, "target", "free", set())
    table = session if isinstance(session, (str, os.PathLike)) else session.table
    return fit_direct(table, fixed=fix_d, max_nfev=max_nfev, free=free_d,
                      progress=_stage(progress, "target, clear medium"),
                      brdf_model=brdf_model, options=brdf_options, model_error=model_error)


def _write_outputs(outdir: str, fits: dict, data: dict, rankings: dict, kept: dict, *,
                   figures: bool, progress, comparison, truth, shown: dict,
                   channels=None) -> dict:
    """The pipeline's files in ``outdir``, as one transaction: {key: file name}. ``shown``:
    the inputs as report.md names them."""
    names = {}
    owned = list(FILES.values()) + [RANKING_FILE, CANDIDATES_DIR]
    with output_folder(outdir, owned=owned) as folder:
        for key, result in fits.items():
            if result is not None:
                result.to_json(folder / FILES[key])
                names[key] = FILES[key]
        names.update(_write_selection(folder, rankings, kept))
        ref, med, tgt, direct = (fits[k] for k in ("reference", "medium", "target", "direct"))
        if figures:
            if progress is not None:
                progress("figures", None, None)
            names.update(_write_figures(folder, data, ref, med, tgt, direct))
        report = pipeline_report(ref, med, tgt, direct, comparison, truth, names, shown)
        if rankings:
            report = report.rstrip("\n") + "\n\n" + "\n".join(ranking_section(rankings)) + "\n"
        if channels is not None:
            report = report.rstrip("\n") + "\n\n" + CHANNELS_NOTE.format(
                ", ".join(channels)) + _channel_lines(comparison) + "\n"
        write_text_atomic(folder / FILES["report"], report)
        names["report"] = FILES["report"]
    return names


def run_pipeline(reference_clear, reference_medium, target_medium, black=None, target_clear=None,
                 outdir="veil-fit", *, variant: str | None = None, accuracy: str = "default",
                 fixed=None, max_nfev=None, progress=None, truth=None,
                 figures: bool = True, brdf_model=None, medium_model=None, brdf_options=None,
                 medium_options=None, free=None, model_error=None,
                 propagation=None, models=None, keep_candidates: bool = False,
                 channel: str | None = None) -> PipelineResult:
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
    truth : optional true models {"reference": ..., "medium": ..., "target": ...} (simulated
        data) listed beside the estimates in report.md.
    brdf_model, medium_model, brdf_options, medium_options : the families of the objects and
        of the medium (registered names; default the paper's) and their options.
    model_error : the model-discrepancy term of every weighted step ("off", "independent"
        or "correlated", the default; :mod:`veil.fitting.model_error`): step 2 uses step 1's
        when larger than its own and counts the error the two share.
    propagation : how each step's given covariance enters its ``stderr_total`` ("auto", the
        default, "linear" or "sigma-points"; :mod:`veil.fitting.propagation`).
    models : None (``brdf_model`` / ``medium_model`` as given), "paper" (the paper's models),
        "BRDF+MEDIUM" (a pinned pair) or "auto": every registered candidate ranked per step
        by BIC with its model-discrepancy term (:mod:`veil.fitting.selection`), the best
        one used; options, ``fixed`` and ``free`` then apply to the candidates that declare
        them. Rankings in ``ranking.json``, report.md and each chosen result's
        ``stats["selection"]``; with ``keep_candidates`` every candidate's result too, in
        ``candidates/<step>/``. Every candidate failing raises
        :class:`veil.fitting.selection.NoCandidateError` (with the rankings).
    channel : one channel of the tables; None: all in every step (docs/channels.md).
    Other arguments as :func:`veil.fit_medium`. Returns a :class:`PipelineResult`.
    """
    model_error = check_kind(model_error)
    propagation = check_method(propagation)
    fixed = _check_fixed(fixed)
    free = _check_fixed(free, "free")
    outdir = os.fspath(outdir)
    inputs = {"reference_clear": reference_clear, "reference_medium": reference_medium,
              "target_medium": target_medium, "black": black, "target_clear": target_clear}
    _check_outputs(outdir, inputs)

    brdf_model, medium_model, auto = _resolve_models(models, brdf_model, medium_model)
    # the candidates and their entries, checked before any reading
    plan = _plan(fixed, free, brdf_options, medium_options, variant) if auto else None
    # read and check every input before the first (long) fit
    data, channels = _prepare_sessions(inputs, channel)
    sources = _channel_sources(inputs, channels, auto, truth)
    rankings, kept = dict[str, Any](), dict[str, Any]()
    if plan is not None:
        ref, med, tgt, brdf_model, brdf_options, rankings, kept = _select(
            data, plan, accuracy=accuracy, max_nfev=max_nfev, progress=progress,
            model_error=model_error, propagation=propagation, keep=keep_candidates)
    else:
        ref, med, tgt = _fit_steps(
            data, fixed, free, variant=variant, accuracy=accuracy, max_nfev=max_nfev,
            progress=progress, brdf_model=brdf_model, medium_model=medium_model,
            brdf_options=brdf_options, medium_options=medium_options,
            model_error=model_error, propagation=propagation, sources=sources)
    direct = comparison = None
    if target_clear is not None:
        direct = _fit_direct(data["target_clear"] if channels is None else target_clear,
                             fixed, free, chosen=bool(rankings), brdf_model=brdf_model,
                             brdf_options=brdf_options, max_nfev=max_nfev, progress=progress,
                             model_error=model_error)
        comparison = compare(tgt, direct)

    fits = {"reference": ref, "medium": med, "target": tgt, "direct": direct}
    # inputs inside the output folder are named relative to it (links from report.md)
    names = _write_outputs(outdir, fits, data, rankings, kept, progress=progress,
                           figures=figures, comparison=comparison, truth=truth,
                           shown=_relative_to(inputs, outdir), channels=channels)
    files = {key: os.path.join(outdir, name) for key, name in names.items()}
    return PipelineResult(ref, med, tgt, direct, comparison, files, rankings)


# --------------------------------------------------------------------------------------
# models="auto": the data choose the model (issue 29)
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
        write_text_atomic(folder / RANKING_FILE, json.dumps(
            {step: r.to_dict() for step, r in rankings.items()}, indent=1) + "\n")
        names["ranking"] = RANKING_FILE
    for step, results in kept.items():
        (folder / CANDIDATES_DIR / step).mkdir(parents=True, exist_ok=True)
        for label, result in results.items():
            name = os.path.join(CANDIDATES_DIR, step, _file_name(label))
            result.to_json(folder / name)
            names[f"{CANDIDATES_DIR}/{step}/{label}"] = name
    return names


def _per_family(cands, per_step: dict, step: str, what: str) -> dict:
    """{label: the ``fixed`` / ``free`` entries of ``step`` its family declares}; an entry no
    candidate declares is an error."""
    used: set = set()
    out = {c.label: _for_family(model_class(c.family), per_step, step, what, used)
           for c in cands}
    unused = [f"{step}.{k}" for k in (per_step.get(step) or []) if (step, k) not in used]
    if unused:
        raise FitError(f"{what} {', '.join(unused)}: no candidate model has such a parameter")
    return out


def _fitted_curve(result: FitResult, data) -> np.ndarray:
    """The fit's model values at its data's configurations, from its residuals."""
    r = np.asarray(result.residuals, dtype=float)
    return data.y - (r * data.sigma if result.weighted and data.sigma is not None else r)


def _rank_step(step, cands, data, fit_one, progress, curves, what, propagated=None):
    """Fit and rank one step's candidates (:func:`veil.fitting.selection.select`); a close
    call's ranking carries the spread of the close candidates' ``curves``. With
    ``propagated``, the candidates are fitted by ``fit_one`` without the given fit's
    covariance (which moves no estimate, chi-square or BIC) and the chosen one again by
    ``propagated``, with it: the derivatives in the given model are compiled and evaluated
    for that one only."""
    ranking, results = selection.select(step, cands, data, fit_one, what, progress)
    if ranking.close_call:
        ranking = ranking.with_spread(selection.curve_spread(
            ranking, {lab: curves(results[lab]) for lab in ranking.close}))
    if propagated is not None:
        chosen = next(c for c in cands if c.label == ranking.chosen)
        results = dict(results, **{ranking.chosen: propagated(chosen)})
    return ranking, results


def _plan(fixed, free, brdf_options, medium_options, variant) -> dict:
    """The candidates of ``models="auto"`` and each one's options, fixed and free entries;
    an entry or option no candidate declares is an error."""
    brdf_options, medium_options = dict(brdf_options or {}), dict(medium_options or {})
    if variant is not None:
        medium_options.setdefault(VARIANT_OPTION, variant)
    b_cands = selection.candidates("brdf", brdf_options)
    m_cands = selection.candidates("medium", medium_options)
    for kind, cands, opts in (("BRDF", b_cands, brdf_options),
                              ("medium", m_cands, medium_options)):
        if not cands:
            raise FitError(f"no registered {kind} family is a candidate with options {opts}")
        declared = {o for c in cands for o in model_class(c.family).option_names()}
        unused = sorted(set(opts) - declared)
        if unused:
            raise FitError(f"option(s) {', '.join(unused)}: no {kind} candidate declares them")
    return {"brdf": b_cands, "medium": m_cands, "brdf_options": brdf_options,
            "medium_options": medium_options,
            "fix_b": _per_family(b_cands, fixed, "reference", "fixed"),
            "free_b": _per_family(b_cands, free, "reference", "free"),
            "fix_m": _per_family(m_cands, fixed, "medium", "fixed"),
            "free_m": _per_family(m_cands, free, "medium", "free"),
            "fix_t": _per_family(b_cands, fixed, "target", "fixed"),
            "free_t": _per_family(b_cands, free, "target", "free")}


def _select(data, plan, *, accuracy, max_nfev, progress, model_error, propagation, keep):
    """Steps 0-2 with every candidate ranked (``models="auto"``)."""
    brdf_options, medium_options = plan["brdf_options"], plan["medium_options"]
    fix_b, free_b, fix_m, free_m, fix_t, free_t = (
        plan[k] for k in ("fix_b", "free_b", "fix_m", "free_m", "fix_t", "free_t"))
    # the candidates without the given fit's covariance, the chosen one with it; with
    # ``keep`` (every candidate's result written out) each one with it
    screen = propagation if keep or propagation == "off" else "off"
    again = None if screen == propagation else propagation
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in CANONICAL)

    def fr_curve(result):
        return model_values(result, None, angles)

    rankings, kept = {}, {}

    def step0(c):
        return fit_reference(data["reference_clear"].table, fixed=fix_b[c.label],
                             free=free_b[c.label], max_nfev=max_nfev, brdf_model=c.family,
                             options=c.model_options(brdf_options), model_error=model_error)

    ranking, results = _rank_step("reference", plan["brdf"], data["reference_clear"], step0,
                                  progress, fr_curve, "reference (clear medium)")
    rankings["reference"], kept["reference"] = ranking, results
    ref = selection.with_selection(results[ranking.chosen], ranking)

    def through_medium(step, fit, session, given, kind, fix, free, options, curve, what):
        """Steps 1 and 2: ``fit`` (fit_medium, fit_target) of every candidate of ``kind``
        to ``session`` through the ``given`` model, ranked; the chosen result."""
        def one(c, chained=screen):
            return fit(data[session].table, given, fixed=fix[c.label], free=free[c.label],
                       accuracy=accuracy, max_nfev=max_nfev,
                       options=c.model_options(options), model_error=model_error,
                       propagation=chained, **{f"{kind}_model": c.family})

        ranking, results = _rank_step(step, plan[kind], data[session], one, progress, curve,
                                      what, again and (lambda c: one(c, again)))
        rankings[step], kept[step] = ranking, results
        return selection.with_selection(results[ranking.chosen], ranking), ranking

    med, _ = through_medium("medium", fit_medium, "reference_medium", ref, "medium", fix_m,
                            free_m, medium_options,
                            lambda r: _fitted_curve(r, data["reference_medium"]), "medium")
    tgt, ranking = through_medium("target", fit_target, "target_medium", med, "brdf", fix_t,
                                  free_t, brdf_options, fr_curve, "target")
    chosen = ranking.row(ranking.chosen)
    opts = {k: v for k, v in brdf_options.items()
            if k in model_class(chosen["family"]).option_names()}
    opts.update(chosen["options"])
    return (ref, med, tgt, chosen["family"], opts, rankings,
            kept if keep else {})


# --------------------------------------------------------------------------------------
# the entries of one family
# --------------------------------------------------------------------------------------
def _for_family(cls, per_step: dict, step: str, what: str, used: set) -> dict | list | None:
    """The entries of ``per_step[step]`` that name parameters of ``cls`` (a fixed dict or a
    free list); records which were used."""
    entries = per_step.get(step)
    if not entries:
        return None
    names = cls.param_names()
    kept: dict | list
    if isinstance(entries, dict):
        kept = {k: v for k, v in entries.items() if k in names}
    else:
        kept = [k for k in entries if k in names]
    used.update((step, k) for k in kept)
    return kept


__all__ = ["run_pipeline", "PipelineResult", "compare", "fit_figure", "FILES", "RANKING_FILE",
           "CANDIDATES_DIR"]
