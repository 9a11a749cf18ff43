"""``models="auto"`` (issue 29): steps 0-2 with every candidate of each step fitted and
ranked (:mod:`veil.fitting.selection`), the chosen one handed on to the next step.

:func:`plan_candidates` lists the candidates and each one's options, fixed and free entries (checked
before any data are read); :func:`select_steps` fits and ranks them step by step. The
candidates are fitted without the given fit's covariance (it moves no estimate,
chi-square or BIC), the chosen one again with it, unless every candidate's result is kept.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..data.measurements import CANONICAL
from ..data.protocol import protocol
from ..errors import FitError
from ..models import model_class, registry
from ..models.base import VARIANT_OPTION
from . import screening, selection
from .result import FitResult
from .step_fit import fixes_of_step
from .steps import fit_direct, fit_medium, fit_target, model_values


def for_family(cls, per_step: dict, step: str, what: str, used: set) -> dict | list | None:
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


#: The command-line option of each keyword of the pipeline, for the messages.
_OPTION = {"fixed": "--fix", "free": "--free"}


def _per_family(cands, per_step: dict, step: str, what: str) -> dict:
    """{label: the ``fixed`` / ``free`` entries of ``step`` its family declares}; an entry no
    candidate declares is an error."""
    used: set = set()
    out = {c.label: for_family(model_class(c.family), per_step, step, what, used) for c in cands}
    unused = [f"{step}.{k}" for k in (per_step.get(step) or []) if (step, k) not in used]
    if unused:
        raise FitError(
            f"{what}={{...}} ({_OPTION[what]} {', '.join(unused)}): no candidate model has "
            "such a parameter"
        )
    return out


def refuse_unheld(step: str, ranking, fixes: dict | None) -> None:
    """A FitError when a fixed value of ``step`` ({label: {name: value}}) was held by no
    candidate of the ``ranking``: every one that has the parameter failed (a value outside
    its family's bounds), so the one chosen fits without it and the value went unused. The
    fixes of a candidate the ranking does not hold (a linear family left out over channels)
    are not looked at."""
    ranked = {r["label"] for r in ranking.rows}
    fixes = {lab: f for lab, f in (fixes or {}).items() if f and lab in ranked}
    held = {n: v for f in fixes.values() for n, v in f.items()}
    for name, value in held.items():
        errors = [ranking.row(lab)["error"] or "" for lab, f in fixes.items() if name in f]
        if errors and all(f".{name} = " in e for e in errors):  # each failed on the value
            said = f"{value:g}" if isinstance(value, (int, float)) else repr(value)
            raise FitError(
                f"fixed={{'{step}': {{'{name}': {value!r}}}}} (--fix {step}.{name}={said}): "
                f"no candidate could hold it ({errors[0].removeprefix('FitError: ')}), and "
                f"the one chosen ({ranking.chosen}) has no {name}: the value would go unused; "
                "give a value that a family having the parameter takes, or drop it"
            )


def fitted_curve(result: FitResult, data) -> np.ndarray:
    """The fit's model values at its data's configurations, from its residuals."""
    r = np.asarray(result.residuals, dtype=float)
    return data.y - (r * data.sigma if result.weighted and data.sigma is not None else r)


def rank_step(
    step, cands, data, fit_one, progress, curves, what, propagated=None, quick=None, fixes=None
) -> tuple[selection.Ranking, dict]:
    """Fit and rank one step's candidates (:func:`veil.fitting.screening.select`, screened
    by their ``quick`` fits when given); a close call's ranking carries the spread of the
    close candidates' ``curves``. With ``propagated``, the candidates are fitted by
    ``fit_one`` without the given fit's covariance (which moves no estimate, chi-square or
    BIC) and the chosen one again by ``propagated(candidate, start)``, with it, from its
    estimate: the derivatives in the given model are compiled and evaluated for that one
    only. ``fixes`` ({label: fixed}) that no candidate could hold are refused
    (:func:`refuse_unheld`)."""
    ranking, results = screening.select(step, cands, data, fit_one, what, progress, quick)
    refuse_unheld(step, ranking, fixes)
    if ranking.close_call:
        ranking = ranking.with_spread(
            selection.curve_spread(ranking, {lab: curves(results[lab]) for lab in ranking.close})
        )
    if propagated is not None:
        chosen = next(c for c in cands if c.label == ranking.chosen)
        results = {**results, ranking.chosen: propagated(chosen, results[ranking.chosen])}
    return ranking, results


def _refuse_unused(kind: str, unused: list, opts: dict) -> None:
    """A FitError for options no candidate of ``kind`` takes: those a registered family
    declares, but at a value with which it makes no model (no candidate then), say so."""
    families = registry.names("brdf" if kind == "BRDF" else "medium")
    owners = {o: [f for f in families if o in model_class(f).option_names()] for o in unused}
    refused = [f"{o} = {opts[o]} ({', '.join(owners[o])})" for o in unused if owners[o]]
    unknown = [o for o in unused if not owners[o]]
    parts = []
    if unknown:
        parts.append(f"option(s) {', '.join(unknown)}: no {kind} candidate declares them")
    if refused:
        parts.append(
            f"option(s) {'; '.join(refused)}: the families that declare them make no "
            "model with that value, so no candidate takes it"
        )
    raise FitError("; ".join(parts))


def check_candidates(kind: str, cands: list, opts: dict) -> None:
    """A FitError when no family of ``kind`` ("BRDF" or "medium") is a candidate, or when
    ``opts`` hold an option no candidate takes (:func:`_refuse_unused`): a family that makes
    no model with the value given is no candidate, and the option would go unused."""
    if not cands:
        raise FitError(f"no registered {kind} family is a candidate with options {opts}")
    declared = {o for c in cands for o in model_class(c.family).option_names()}
    unused = sorted(set(opts) - declared)
    if unused:
        _refuse_unused(kind, unused, opts)


def plan_candidates(fixed, free, brdf_options, medium_options, variant) -> dict:
    """The candidates of ``models="auto"`` and each one's options, fixed and free entries;
    an entry or option no candidate declares is an error."""
    brdf_options, medium_options = dict(brdf_options or {}), dict(medium_options or {})
    if variant is not None:
        medium_options.setdefault(VARIANT_OPTION, variant)
    b_cands = selection.candidates("brdf", brdf_options)
    m_cands = selection.candidates("medium", medium_options)
    check_candidates("BRDF", b_cands, brdf_options)
    check_candidates("medium", m_cands, medium_options)
    return {
        "brdf": b_cands,
        "medium": m_cands,
        "brdf_options": brdf_options,
        "medium_options": medium_options,
        "fix_b": _per_family(b_cands, fixed, "reference", "fixed"),
        "free_b": _per_family(b_cands, free, "reference", "free"),
        "fix_m": _per_family(m_cands, fixed, "medium", "fixed"),
        "free_m": _per_family(m_cands, free, "medium", "free"),
        "fix_t": _per_family(b_cands, fixed, "target", "fixed"),
        "free_t": _per_family(b_cands, free, "target", "free"),
    }


@dataclass(frozen=True)
class _Ranked:
    """What every candidate fit of :func:`select_steps` shares; the rankings and the
    candidates' results, by step, collected as the steps run."""

    data: dict
    #: {session: (table, black)} fitted over several channels (None: each ``data``'s table)
    sources: dict | None
    plan: dict
    accuracy: str
    max_nfev: int | None
    progress: Any
    model_error: Any
    #: the propagation of the candidates' fits, and of the chosen one's refit (None: none)
    each: str
    again: str | None
    #: every candidate fitted in full (its result written out), none screened out
    keep_all: bool = False
    rankings: dict = field(default_factory=dict)
    kept: dict = field(default_factory=dict)
    #: {"target": the chosen family's direct fit} when step 2 was ranked on clear data
    direct: dict = field(default_factory=dict)

    def table(self, session: str) -> tuple:
        """(table, black) a candidate of ``session`` fits: of every channel when the
        sessions hold several (the black cloth then subtracted channel by channel), else
        the checked data's table, its black cloth subtracted."""
        if self.sources is not None:
            return self.sources[session]
        return self.data[session].table, None

    def on_clear(self, step: str, session: str, what: str, curve) -> tuple:
        """Every BRDF candidate fitted directly to the clear ``session`` (no integral) and
        ranked, recorded as ``step``'s: (ranking, {label: result})."""
        key = "b" if step == "reference" else "t"
        fix, free, options = (
            self.plan[f"fix_{key}"],
            self.plan[f"free_{key}"],
            self.plan["brdf_options"],
        )

        def one(c, start=None, screen=False):
            with fixes_of_step(step):
                return fit_direct(
                    self.table(session)[0],
                    fixed=fix[c.label],
                    free=free[c.label],
                    max_nfev=self.max_nfev,
                    step="reference" if step == "reference" else "direct",
                    brdf_model=c.family,
                    options=c.model_options(options),
                    model_error=self.model_error,
                    screen=screen,
                    start=start,
                )

        # screened as the steps through the medium are (the quick fit: the grid's best
        # start only); over several channels, or with every result kept, each in full
        screened = self.sources is None and not self.keep_all
        ranking, results = rank_step(
            step,
            self.plan["brdf"],
            self.data[session],
            one,
            self.progress,
            curve,
            what,
            quick=(lambda c, start=None: one(c, start, True)) if screened else None,
            fixes=fix,
        )
        self.rankings[step], self.kept[step] = ranking, results
        return ranking, results

    def reference(self, curve) -> FitResult:
        """Step 0: every BRDF candidate fitted to the reference in clear water, ranked."""
        ranking, results = self.on_clear(
            "reference", "reference_clear", "reference (clear medium)", curve
        )
        return selection.with_selection(results[ranking.chosen], ranking)

    def fit_one(self, step, c, given, propagation, screen=False, start=None) -> FitResult:
        """Candidate ``c`` of step 1 ("medium") or 2 ("target") fitted through the ``given``
        model, with ``propagation``; a quick fit when ``screen``; from ``start`` (a
        FitResult of its model) when given."""
        medium = step == "medium"
        key, session = ("m", "reference_medium") if medium else ("t", "target_medium")
        fit: Callable[..., FitResult] = fit_medium if medium else fit_target
        kind = "medium" if medium else "brdf"
        table, black = self.table(session)
        with fixes_of_step(step):
            return fit(
                table,
                given,
                black=black,
                fixed=self.plan[f"fix_{key}"][c.label],
                free=self.plan[f"free_{key}"][c.label],
                accuracy=self.accuracy,
                max_nfev=self.max_nfev,
                options=c.model_options(self.plan[f"{kind}_options"]),
                model_error=self.model_error,
                propagation=propagation,
                screen=screen,
                start=start,
                **{f"{kind}_model": c.family},
            )

    def target_on_clear(self, medium: FitResult, curve) -> tuple[FitResult, selection.Ranking]:
        """Step 2 with the target's clear data: every BRDF candidate fitted to them directly
        and ranked there, the chosen one then fitted through ``medium``."""
        ranking, results = self.on_clear("target", "target_clear", "target (clear medium)", curve)
        ranking = dataclasses.replace(ranking, on="the target's clear-medium data")
        chosen = next(c for c in self.plan["brdf"] if c.label == ranking.chosen)
        tgt = self.fit_one("target", chosen, medium, self.again or self.each)
        self.rankings["target"] = ranking
        self.direct["target"] = results[ranking.chosen]
        return selection.with_selection(tgt, ranking), ranking

    def through_medium(self, step, given, curve) -> tuple[FitResult, selection.Ranking]:
        """Steps 1 ("medium") and 2 ("target"): every candidate fitted through the ``given``
        model and ranked; the chosen result."""
        again = self.again
        ranking, results = rank_step(
            step,
            self.plan["medium" if step == "medium" else "brdf"],
            self.data["reference_medium" if step == "medium" else "target_medium"],
            lambda c, start=None: self.fit_one(step, c, given, self.each, start=start),
            self.progress,
            curve,
            step,
            again and (lambda c, start: self.fit_one(step, c, given, again, start=start)),
            # --compare writes every candidate out: each one fitted in full
            None
            if self.keep_all
            else (lambda c, start=None: self.fit_one(step, c, given, "off", True, start)),
            self.plan["fix_m" if step == "medium" else "fix_t"],
        )
        self.rankings[step], self.kept[step] = ranking, results
        return selection.with_selection(results[ranking.chosen], ranking), ranking


def select_steps(
    data, plan, *, accuracy, max_nfev, progress, model_error, propagation, keep, sources=None
) -> tuple[FitResult, FitResult, FitResult, FitResult | None, str, dict, dict, dict]:
    """Steps 0-2 with every candidate ranked: (reference, medium, target, the target's
    direct fit when step 2 was ranked on its clear data (``data["target_clear"]``), the
    chosen BRDF family, its options, {step: ranking}, {step: {label: result}} when
    ``keep``).

    ``data`` {session: the data the candidates are ranked on}; of sessions of several
    channels every channel's data stacked (:func:`veil.fitting.session_data.stack`), and
    ``sources`` {session: (table, black)}: each candidate is then fitted over every channel
    at once, its BIC counting every channel's points and its free parameters (the shared
    ones once)."""
    # the candidates without the given fit's covariance, the chosen one with it; with
    # ``keep`` (every candidate's result written out) each one with it
    each = propagation if keep or propagation == "off" else "off"
    if sources is not None:  # over several channels: no linear family (docs/nonparametric.md)
        plan = dict(plan, brdf=[c for c in plan["brdf"] if not model_class(c.family).LINEAR])
    run = _Ranked(
        data,
        sources,
        plan,
        accuracy,
        max_nfev,
        progress,
        model_error,
        each,
        None if each == propagation else propagation,
        keep,
    )
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in CANONICAL)

    def fr_curve(result):
        if not result.channels:
            return model_values(result, None, angles)
        # channel after channel, as the comparison's curves (veil.analysis.comparison)
        return np.concatenate(
            [model_values(result.as_model(channel=c), None, angles) for c in result.channel_names]
        )

    ref = run.reference(fr_curve)
    med, _ = run.through_medium("medium", ref, lambda r: fitted_curve(r, data["reference_medium"]))
    if data.get("target_clear") is not None:
        tgt, ranking = run.target_on_clear(med, fr_curve)
    else:
        tgt, ranking = run.through_medium("target", med, fr_curve)
    assert ranking.chosen is not None  # select() raised NoCandidateError otherwise
    chosen = ranking.row(ranking.chosen)
    brdf_options = plan["brdf_options"]
    opts = {
        k: v for k, v in brdf_options.items() if k in model_class(chosen["family"]).option_names()
    }
    opts.update(chosen["options"])
    kept = run.kept if keep else {}
    return ref, med, tgt, run.direct.get("target"), chosen["family"], opts, run.rankings, kept


__all__ = [
    "check_candidates",
    "plan_candidates",
    "select_steps",
    "rank_step",
    "fitted_curve",
    "for_family",
]
