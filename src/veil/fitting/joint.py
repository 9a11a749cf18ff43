"""Joint estimation over several media (docs/model.md sec. 7, the paper's proposed remedy).

The two-step method takes each step's result as exact; a smooth target in a strongly
scattering medium and a rough one in a weak medium then look alike (paper sec. 5.2.4).
:func:`fit_joint` instead fits all sessions at once - the target (and optionally the
reference) measured under several media, e.g. several concentrations of one drink - as one
weighted least-squares problem (:mod:`veil.fitting.problem`, solved by
:mod:`veil.fitting.solver` as every fit): each object's f_r is shared by all its sessions,
each medium has its own parameters, and those the medium model declares shareable are
shared by the media or free per medium as declared (the paper's medium: g per medium,
eta_u shared, by default); see docs/ambiguity.md.

Parameter names in results: the target's as its BRDF declares them (``Pd, Ps, n, eta``);
the reference's prefixed ``ref.``; per medium ``NAME[label]`` (``Td[low]``); shared ones
plain (``eta_u``; a medium's parameter takes its declared alias).

``propagation`` of :func:`fit_joint`: how the media's uncertainty reaches the objects'
``stderr_total``: "auto" (the default, None: through refits at sigma points where a medium
parameter is uncertain by more than a quarter of its scale, as tau at optical depth 0.1, and
at most 3 times it), "linear" or "sigma-points"
(:func:`veil.fitting.propagation.media_part`). ``stats["propagation"]`` records it,
``stats["propagation_reference"]`` how the reference's covariance entered.

The problem (sessions, slots, checks): :mod:`veil.fitting.joint_problem`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..engine.evaluator import check_progress
from ..errors import FitError, as_flag
from ..models import Model, model_class
from ..models.base import VARIANT_OPTION
from . import model_error as discrepancy
from .joint_channels import block_channels, channel_starts, reference_entry, reference_names
from .joint_problem import OVERLAP_TOL, as_sessions, build, shareable
from .problem import (
    ITERATION_ACCURACY,
    Block,
    Problem,
    Session,
    check_accuracy,
)
from .propagation import check_method, describe, media_part
from .reported_uncertainty import Reported, model_floor, reported
from .result import FitResult, JointResult, load_result, target_channels
from .solver import (
    began_at_grid,
    check_max_nfev,
    covariance_matrix,
    linear_free,
    run,
    run_from,
    start_vector,
    summarize,
    uncertainties,
)
from .start_values import joint_starts, step_starts

#: Least-squares runs from the best distinct starting points.
STARTS = 2


def _direct_fit(problem: Problem):
    """The fit of an object's f_r from its clear-water block (step 0 inside a joint fit):
    returns the fitted BRDF vector."""

    def fit(block: Block, fixed: dict) -> np.ndarray:
        cls = type(block.brdf)
        own = Block(block.session, block.data, np.arange(len(block.ib)), None, block.brdf, None)
        sub = Problem(
            [own],
            [problem.params[k] for k in block.ib],
            problem.values[block.ib],
            [problem.free[k] for k in block.ib],
            weighted=problem.weighted,
        )
        for name, value in fixed.items():
            sub.values[cls.index(name)] = value
        starts, _ = step_starts(sub, "brdf", "reference", 3)
        return run(sub, starts, every=True).solution.x

    return fit


def _floor(problem: Problem, layout: dict):
    """The declared model error of the joint fit's models (``Model.MODEL_ERROR_FLOOR``) when
    every session is seen through a medium; None with a clear-water session among them:
    the term is one process over all sessions, and a medium's error does not reach clear
    water (the BRDF families declare none)."""
    if any(b.medium is None for b in problem.blocks):
        return None
    return model_floor(*(model_class(layout["models"][k], k) for k in ("brdf", "medium")))


def _checked(accuracy, max_nfev, progress, model_error, propagation) -> tuple[str, str]:
    """The settings of the joint fit checked: (model_error, propagation)."""
    check_accuracy(accuracy)
    check_max_nfev(max_nfev)
    check_progress(progress)
    return discrepancy.check_kind(model_error), check_method(propagation)


def _start_models(start) -> dict | JointResult | None:
    """The optional starting models {object or medium label: model}, fit results as their
    models; a joint fit result as it is (continued from: :func:`_solve`)."""
    if start is None or isinstance(start, JointResult):
        return start
    if not isinstance(start, dict):
        raise FitError("start: expected a dict {object or medium label: model} or a joint fit")
    start = {k: (v.one_model() if isinstance(v, FitResult) else v) for k, v in start.items()}
    for k, v in start.items():
        if not isinstance(v, Model):
            raise FitError(f"start[{k!r}]: expected a model or a fit result, got {v!r}")
    return start


def _prepare_engines(problem: Problem, ref_cols: list, accuracy: str, screen: bool) -> None:
    """Compile (or load) side by side what the fit will need: every block's values and its
    derivatives in the free parameters (and the given reference's ``ref_cols``); the values
    at ``accuracy`` but for a ``screen``, which needs them only if it converges."""
    for block, wrt in zip(problem.blocks, problem.wrt(list(problem.free_index) + ref_cols)):
        block.model(ITERATION_ACCURACY).prepare(values=True, jacobians=[wrt])
        if accuracy != ITERATION_ACCURACY and not screen:
            block.model(accuracy).prepare(values=True)


def _solve(
    problem: Problem,
    layout: dict,
    reference,
    start,
    accuracy: str,
    max_nfev,
    progress,
    model_error: str,
    propagation: str,
    screen: bool = False,
) -> JointResult:
    """The joint problem solved from its starts, its uncertainties reported (the given
    reference's covariance to first order, the media's as ``propagation`` says); a
    ``screen`` is a quick fit (:func:`veil.fitting.solver.run`), nothing propagated."""
    if screen:  # iterated at the fast rule, its error measured at accuracy (solver.run)
        propagation = "off"
    given_result = (
        reference
        if not screen
        and isinstance(reference, FitResult)
        and reference.covariance(total=True) is not None
        else None
    )
    index = {n: k for k, n in enumerate(problem.names)}
    ref_names = reference_names(layout, reference)
    ref_cols = [] if given_result is None else [index[ref_names[n]] for n in given_result.free]
    linear_free(problem)
    _prepare_engines(problem, ref_cols, accuracy, screen)
    resumed = start if isinstance(start, JointResult) else None
    models = None if resumed is not None else start

    def grid() -> list:
        if "channels" in layout:
            return channel_starts(
                problem,
                layout,
                lambda sub, own: joint_starts(sub, own, models, STARTS, _direct_fit(sub), progress),
            )
        return joint_starts(problem, layout, models, STARTS, _direct_fit(problem), progress)

    # a joint fit continued from a joint result (its quick fit, veil.fitting.screening): the
    # grid's starts only when that run does not convince
    first = None if resumed is None else start_vector(problem, resumed.params, "the start")
    ran_best = resumed is not None and began_at_grid(resumed)
    kw = dict(accuracy=accuracy, max_nfev=max_nfev, progress=progress, screen=screen)
    outcome = run_from(problem, first, ran_best, grid, **kw)
    summary = summarize(problem, outcome)
    given = reference_entry(reference, layout)
    rep = reported(
        problem,
        outcome.solution.x,
        summary,
        outcome.values,
        kind=model_error,
        given_result=given_result,
        given_column=lambda n: index[ref_names[n]],
        propagation="linear",  # the reference's covariance, to first order
        floor=_floor(problem, layout),
    )
    rep = _media_beyond_first_order(
        problem, outcome.solution.x, rep, propagation, summary.converged
    )
    return _result(
        problem, layout, outcome, summary, ITERATION_ACCURACY if screen else accuracy, given, rep
    )


def fit_joint(
    sessions,
    *,
    reference=None,
    shared=None,
    per_medium=None,
    fixed=None,
    start=None,
    variant: str | None = None,
    accuracy: str = "default",
    max_nfev=None,
    progress=None,
    brdf_model=None,
    medium_model=None,
    brdf_options=None,
    medium_options=None,
    free=None,
    model_error=None,
    propagation=None,
    channel: str | None = None,
    screen: bool = False,
) -> JointResult:
    """Fit several sessions of one target under several media at once (module docstring).

    sessions : list of :class:`Session` (table, medium label, object "target"/"reference")
        or (table, medium[, object]) tuples, or a dict {medium label: target table}; medium
        "none" is clear water. Tables are DataFrames or CSV paths, black cloth subtracted.
    reference : the reference's f_r (step-0 FitResult or a BRDF model), held fixed; without
        it a clear-water reference session makes the reference's parameters free.
    shared, per_medium : which of the medium's shareable parameters the media share
        (default as the model declares: for the paper's medium eta_u shared, g per medium);
        a name in both is an error. Scale parameters are always per medium.
    fixed : {parameter name: value}, names as in the result (e.g. "eta", "Td[low]", "g").
    free : names (as in the result) of parameters the families hold by default
        (``Param.held``, e.g. the physical medium's ``s[label]``) to fit too.
    start : starting models {object or medium label: model}, or a joint fit to continue.
    brdf_model, medium_model, brdf_options, medium_options : the families (registered
        names, default the paper's) and their options; ``variant`` is the shortcut for the
        medium's Fresnel variant.
    accuracy, max_nfev, progress, model_error : as :func:`veil.fitting.steps.fit_medium`.
        A weighted joint fit whose residuals exceed the noise gets the model-discrepancy
        term over all its sessions (:mod:`veil.fitting.model_error`; nothing is inherited;
        at least the models' declared error when every session is in a medium),
        and a reference given as a fit result has its covariance propagated into
        ``stderr_total`` to first order (:mod:`veil.fitting.reported_uncertainty`).
    propagation : how the media's uncertainty reaches the objects' ``stderr_total``
        (module docstring).
    channel : of tables with a ``channel`` column, the one channel to fit; None fits every
        channel at once when they hold several (:mod:`veil.fitting.joint_channels`: the
        parameters the families declare per channel one per channel, ``Pd[r]``,
        ``Td[low][r]``, the others tied; ``fixed`` and ``free`` name a parameter of
        every channel by its one-channel name, or one channel's; ``reference`` a fit over
        the same channels or a model of every channel). With ``channel``, a reference
        fitted over several channels gives its model of that channel.
    screen : a candidate's quick fit to rank it (:mod:`veil.fitting.screening`).
    """
    model_error, propagation = _checked(accuracy, max_nfev, progress, model_error, propagation)
    as_flag(screen, "screen", FitError)
    start = _start_models(start)
    if channel is not None and isinstance(reference, FitResult) and reference.channels:
        # one channel of a reference fitted over several: its model of that channel, held
        # as a model (as fit_medium and fit_target take it)
        reference = reference.one_model(channel)
    problem, layout = build(
        sessions,
        reference=reference,
        shared=shared,
        per_medium=per_medium,
        fixed=fixed,
        variant=variant,
        brdf_model=brdf_model,
        medium_model=medium_model,
        brdf_options=brdf_options,
        medium_options=medium_options,
        free=free,
        channel=channel,
    )
    how = (accuracy, max_nfev, progress, model_error, propagation, screen)
    return _solve(problem, layout, reference, start, *how)


def _media_beyond_first_order(
    problem: Problem, x, rep: Reported, method: str, converged: bool = True
) -> Reported:
    """``rep`` with the objects' block of its total covariance (its own without a total)
    carrying the media's uncertainty through sigma points where :func:`media_part` says so;
    the media's block and the cross terms stay. When the result would not be a covariance
    (the sigma points' spread below the first order's in some direction) the first order is
    kept and the record says so."""
    se: dict = rep.stderr
    corr: dict | None = rep.correlation
    if rep.stderr_total is not None:
        se, corr = rep.stderr_total, rep.correlation_total
    cov = covariance_matrix(se, corr, problem.free_names)
    if cov is None:
        return rep
    cols_o, delta, how = media_part(problem, x, cov, method, converged)
    if how is None:
        return rep
    if rep.propagation is not None:
        how = dict(how, reference=rep.propagation)
    if delta is not None:
        pos = {int(k): j for j, k in enumerate(problem.free_index)}
        jo = [pos[k] for k in cols_o]
        total = cov.copy()
        total[np.ix_(jo, jo)] += delta
        d = np.sqrt(np.maximum(np.diag(total), 0.0))
        if not np.all(d > 0):
            how = dict(
                how,
                method="linear",
                fallback="a parameter's variance vanished with the sigma points: first order kept",
            )
        elif np.linalg.eigvalsh(total / np.outer(d, d)).min() > -1e-10:
            st, ct = uncertainties(total, problem.names, problem.free_index)
            return dataclasses.replace(rep, stderr_total=st, correlation_total=ct, propagation=how)
        else:
            how = dict(
                how,
                method="linear",
                fallback="the sigma points' spread is below the "
                "first order's in some direction: first order kept",
            )
    return dataclasses.replace(rep, propagation=how)


def _result(
    problem: Problem, layout, outcome, summary, accuracy, given, rep: Reported
) -> JointResult:
    """Assemble the JointResult from the solver's outcome and summary."""
    y, values = problem.y, outcome.values
    res = summary.residuals
    sessions = []
    channels = block_channels(problem, layout)
    for b, sl, c in zip(problem.blocks, problem.slices(), channels):
        r = res[sl]
        v = values[sl]
        nzb = v != 0
        relb = (y[sl][nzb] - v[nzb]) / v[nzb]
        sessions.append(
            {
                "name": b.session.name,
                "object": b.session.object,
                "medium": b.session.medium,
                "n_points": int(b.size),
                "chi2": float(r @ r) / b.size,
                "rms_relative": float(np.sqrt(np.mean(relb**2))) if relb.size else None,
                **({} if c is None else {"channel": c}),
            }
        )
    layout = dict(layout, sessions=sessions)
    x = outcome.solution.x
    names = problem.names
    fixed = {n: float(x[k]) for k, n in enumerate(names) if not problem.free[k]}
    stats, message = outcome.stats, summary.message
    if rep.propagation is not None:
        how = dict(rep.propagation)
        reference = how.pop("reference", None)
        stats = dict(stats, propagation=how)
        if reference is not None:
            stats["propagation_reference"] = reference
        note = describe(rep.propagation, "the media's uncertainty")
        message += f"; {note}" if note else ""
    variant = layout["options"]["medium"].get(VARIANT_OPTION)
    return JointResult(
        model="joint",
        params={n: float(v) for n, v in zip(names, x)},
        stderr=rep.stderr,
        correlation=rep.correlation,
        stderr_total=rep.stderr_total,
        correlation_total=rep.correlation_total,
        model_error=rep.model_error,
        residuals=tuple(float(r) for r in res),
        chi2_reduced=summary.chi2_reduced,
        rms_relative=summary.rms_relative,
        n_points=problem.n_points,
        converged=summary.converged,
        message=message,
        variant=variant,
        fixed=fixed,
        step="joint",
        weighted=problem.weighted,
        accuracy=accuracy,
        given=given,
        stats=stats,
        determined=summary.determined,
        layout=layout,
        channels=target_channels(layout),
    )


__all__ = [
    "fit_joint",
    "Session",
    "JointResult",
    "load_result",
    "build",
    "as_sessions",
    "shareable",
    "OVERLAP_TOL",
    "STARTS",
]
