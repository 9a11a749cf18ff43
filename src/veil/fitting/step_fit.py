"""One step of the two-step method solved (:mod:`veil.fitting.steps`): its problem of one
session (the fitted model free, the given one held), starts from the model's grid, the
least-squares run, the reported uncertainties (the given fit's covariance propagated, the
model-discrepancy term) and the :class:`~veil.fitting.result.FitResult`; a converged
weighted fit that misses its data far warns (:class:`MisfitWarning`)."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Iterator
from typing import cast

import numpy as np

from ..errors import FitError
from ..models import BRDF, Medium, Model
from ..models.base import VARIANT_OPTION
from .arguments import refuse_fixed_and_freed
from .linear_fit import fit_linear
from .problem import ITERATION_ACCURACY, Problem, session_problem
from .propagation import describe, given_covariance
from .reported_uncertainty import model_floor, reported
from .result import FitResult, model_entry
from .session_data import FitData
from .solver import check_fixed, run_from, start_vector, summarize
from .start_values import step_starts

#: Least-squares runs started from the best distinct grid points, by step.
STARTS = {"reference": 3, "direct": 3, "medium": 2, "target": 2}
#: The fit role (starting grid of the model's declaration) of each step.
ROLE = {"reference": "reference", "direct": "reference", "medium": "medium", "target": "target"}


@contextlib.contextmanager
def fixes_of_step(step: str) -> Iterator[None]:
    """Within the block (a pipeline's ``step``: "reference", "medium" or "target"), a
    FitError's hint to hold parameters says it as the pipeline takes them:
    ``fixed={'medium': {'NAME': VALUE}} (--fix medium.NAME=VALUE)``."""
    try:
        yield
    except FitError as exc:
        text = str(exc)
        for generic, of_step in (
            ("fixed={'NAME': VALUE}", f"fixed={{'{step}': {{'NAME': VALUE}}}}"),
            ("fixed={...}", f"fixed={{'{step}': {{...}}}}"),
            ("--fix NAME=VALUE", f"--fix {step}.NAME=VALUE"),
        ):
            text = text.replace(generic, of_step)
        if text != str(exc):
            exc.args = (text,)
        raise


def _fixed_slots(problem: Problem, cls, fixed: dict, what: str) -> dict:
    """{slot name: value} for ``fixed`` given in ``cls``'s own parameter names."""
    out = {}
    for name, value in fixed.items():
        if name not in cls.param_names():
            raise FitError(
                f"cannot fix {name!r} in the {what} fit: {cls.NAME} has parameters "
                f"{', '.join(cls.param_names())}"
            )
        check_fixed(name, value, cls.param(name), cls.__name__)
        out[cls.param(name).key] = float(value)
    return out


def _prepare_engine(
    problem, cls, given, given_result, accuracy: str, propagation: str, screen: bool
) -> None:
    """Everything a fit through a medium will compile (or load), side by side: derivatives
    in the fitted model's parameters, and in the given model's to propagate its covariance
    (not with ``propagation`` "off"); the values at ``accuracy`` but for a ``screen``, which
    needs them only if it converges (:func:`veil.fitting.solver.run`)."""
    block = problem.blocks[0]
    propagates = given_covariance(given_result, propagation) is not None
    wrt = [(cls.KIND,)] + ([(type(given).KIND,)] if propagates else [])
    block.model(ITERATION_ACCURACY).prepare(values=True, jacobians=wrt)
    if accuracy != ITERATION_ACCURACY and not screen:
        block.model(accuracy).prepare(values=True)


def _problem(data: FitData, cls, brdf, medium, free: list, fixed: dict, what: str) -> Problem:
    """The step's problem: ``free`` slots, the ``fixed`` values set; more points than free
    parameters, or a FitError."""
    # by kind: a medium step holds the BRDF given, the others fit the BRDF
    problem = session_problem(
        None, cast(BRDF, brdf), cast("Medium | None", medium), free=free, data=data, what=what
    )
    for key, value in _fixed_slots(problem, cls, fixed, what).items():
        problem.values[problem.index(key)] = value
    if data.size <= len(free) and not cls.LINEAR:  # regularized: df < points (linear_fit)
        raise FitError(
            f"the {what} data have {data.size} point(s) but the fit has "
            f"{len(free)} free parameter(s) ({', '.join(free)}): need more points "
            f"than free parameters (fix some with fixed={{'NAME': VALUE}} (--fix NAME=VALUE), "
            f"or measure more configurations)"
        )
    return problem


def _step_grid(problem: Problem, cls, step: str, progress, explain: bool = True) -> tuple:
    """(a function giving the step's starts from its grid, a dict whose "points" it sets to
    the grid's size); ``explain``: a grid without a finite cost says why, when it can (no
    start of the user's ran before it: :func:`~veil.fitting.start_values.step_starts`)."""
    grid = {"points": 0}

    def from_grid() -> list:
        starts, grid["points"] = step_starts(
            problem, cls.KIND, ROLE[step], STARTS[step], progress, explain=explain
        )
        return starts

    return from_grid, grid


def _start_vector(problem: Problem, cls, start: dict) -> np.ndarray:
    """The problem's natural vector with the fitted model's free parameters at ``start``
    ({name: value} in the model's own names; a FitError for a missing or invalid one)."""
    keys = {cls.param(n).key: v for n, v in start.items() if n in cls.param_names()}
    return start_vector(problem, keys, f"the start ({cls.NAME})")


def stats_and_message(outcome, summary, rep, given_result, n_grid: int) -> tuple[dict, str]:
    """A step's ``stats`` (the run's, the starting grid's size, how the given fit's
    covariance was propagated) and its message (the solver's, with a note on that)."""
    stats = dict(outcome.stats, grid_points=n_grid)
    message = summary.message
    if rep.propagation is not None:
        stats["propagation"] = rep.propagation
        note = describe(rep.propagation, f"the {given_result.step or 'given'} fit's covariance")
        message += f"; {note}" if note else ""
    return stats, message


def _result(
    step: str,
    data: FitData,
    problem: Problem,
    outcome,
    summary,
    rep,
    fitted: Model,
    given: Model | None,
    given_result,
    free: list,
    what: str,
    n_grid: int,
) -> FitResult:
    """The step's :class:`FitResult` from the solver's outcome and the reported
    uncertainties ``rep`` (``n_grid`` starting grid points); a converged weighted fit far
    from its data warns."""
    cls = type(fitted)
    medium = fitted if cls.KIND == "medium" else given
    x = outcome.solution.x
    own = {p.key: p.name for p in cls.PARAMS}  # slot name -> model's own name
    names = [own[k] for k in cls.keys()]
    media = [m for m in (medium,) if m is not None]
    variant = media[0].options().get(VARIANT_OPTION) if media else None
    stats, message = stats_and_message(outcome, summary, rep, given_result, n_grid)
    stats["black_subtracted"] = bool(data.black)  # (diagnose asks for the same data)
    if summary.converged:  # one that did not converge says so (exit status 1)
        warn_misfit(summary.chi2_reduced, data, what, medium is not None)
    return FitResult(
        model=cls.NAME,
        params={own[k]: float(x[problem.index(k)]) for k in cls.keys()},
        stderr=rep.stderr,
        correlation=rep.correlation,
        residuals=tuple(float(r) for r in summary.residuals),
        chi2_reduced=summary.chi2_reduced,
        rms_relative=summary.rms_relative,
        n_points=data.size,
        converged=summary.converged,
        message=message,
        variant=variant,
        fixed={
            n: float(x[problem.index(cls.param(n).key)])
            for n in names
            if cls.param(n).key not in free
        },
        step=step,
        weighted=data.sigma is not None,
        accuracy=outcome.accuracy,
        given=None if given is None else model_entry(given),
        stderr_total=rep.stderr_total,
        correlation_total=rep.correlation_total,
        stats=stats,
        options=fitted.options(),
        determined=summary.determined,
        model_error=rep.model_error,
    )


#: A weighted fit whose reduced chi-square exceeds this misses its data by about ten
#: standard deviations on average: a systematic error in the data, not noise.
MISFIT_CHI2 = 100.0


class MisfitWarning(UserWarning):
    """A fit that converged but describes its data far worse than their sigma says."""


def warn_misfit(chi2_reduced: float, data: FitData, what: str, medium: bool = True) -> None:
    """Warn (:class:`MisfitWarning`) when a weighted fit's reduced chi-square exceeds
    :data:`MISFIT_CHI2` (called for converged fits), pointing through a ``medium`` to the
    black cloth: glow left in the data (no black session subtracted) or a wrong one is the
    usual cause; negative values say so. In clear water: the sigma column and the fixed
    parameters."""
    if data.sigma is None or not chi2_reduced > MISFIT_CHI2:
        return
    negative = int(np.count_nonzero(data.y < 0))
    seen = f"; {negative} of {data.size} values are negative" if negative else ""
    if not medium:
        cause = (
            "no medium lies between object and camera here: check the sigma column, any "
            "parameter held fixed, and an offset in the values (a dark frame to subtract "
            "with --black)"
        )
    elif data.black:
        cause = (
            "check the black-cloth session subtracted (same configurations, same medium) "
            "and the sigma column"
        )
    else:
        cause = (
            "no black-cloth session was subtracted: measure the medium with the black cloth "
            "(docs/measurements.md) and give it with --black (black=...)"
        )
    warnings.warn(
        f"the {what} fit's reduced chi-square is {chi2_reduced:.4g}: the model "
        f"misses the data by about {np.sqrt(chi2_reduced):.3g} standard deviations "
        f"on average{seen}; {cause}",
        MisfitWarning,
        stacklevel=4,
    )


#: What each step fits, as messages say.
WHAT = {
    "reference": "reference (clear medium)",
    "direct": "target (clear medium)",
    "medium": "medium",
    "target": "target",
}


def _free(cls, fixed: dict, freed, what: str) -> list[str]:
    """The free slots: every parameter but the ``fixed`` and the held ones not ``freed``."""
    refuse_fixed_and_freed(fixed, freed)
    free = [p.key for p in cls.PARAMS if p.name not in fixed and (not p.held or p.name in freed)]
    if not free:
        raise FitError(
            f"every parameter of the {what} fit is fixed "
            f"({', '.join(cls.param_names())}): nothing to fit"
        )
    return free


def fit_step(
    step: str,
    data: FitData,
    fitted: Model,
    given: Model | None,
    given_result,
    fixed: dict,
    accuracy: str,
    max_nfev,
    progress,
    freed=(),
    model_error: str = "off",
    propagation: str = "auto",
    screen: bool = False,
    start: dict | None = None,
    start_ran_best: bool = False,
) -> FitResult:
    """One step: the ``fitted`` model's parameters free (but ``fixed``, and the held ones not
    ``freed``), ``given`` held; unless ``model_error`` is "off" a weighted fit estimates the
    model-discrepancy term of that kind (:mod:`veil.fitting.model_error`); ``propagation``
    is how a given fit's covariance enters (:mod:`veil.fitting.propagation`); a ``screen``
    is a candidate's quick fit (:func:`veil.fitting.solver.run`), without propagation.
    ``start`` ({name: value} of the fitted model) runs first, the grid only when it does not
    convince, without its best start when ``start_ran_best`` (the start is a fit that began
    there: a candidate's fit continued from its quick fit, :mod:`veil.fitting.screening`)."""
    if screen:  # iterated at the fast rule, its error measured at accuracy (solver.run)
        propagation = "off"
    cls = type(fitted)
    brdf, medium = (given, fitted) if cls.KIND == "medium" else (fitted, given)
    what = WHAT[step]
    free = _free(cls, fixed, freed, what)
    problem = _problem(data, cls, brdf, medium, free, fixed, what)
    if cls.LINEAR:  # one linear problem (docs/nonparametric.md)
        lin = dict(accuracy=accuracy, propagation=propagation, model_error=model_error)
        result = fit_linear(
            step, problem, fitted, given, given_result, progress=progress, screen=screen, **lin
        )
        if result.converged:  # as an iterative fit's (_result)
            warn_misfit(result.chi2_reduced, data, what, medium is not None)
        return result
    if medium is not None:
        _prepare_engine(problem, cls, given, given_result, accuracy, propagation, screen)
    from_grid, grid = _step_grid(problem, cls, step, progress, explain=start is None)
    first = None if start is None else _start_vector(problem, cls, start)
    kw = dict(accuracy=accuracy, max_nfev=max_nfev, progress=progress, screen=screen)
    outcome = run_from(problem, first, start_ran_best, from_grid, every=medium is None, **kw)
    n_grid = grid["points"]
    summary = summarize(problem, outcome)
    x = outcome.solution.x
    own = {p.key: p.name for p in cls.PARAMS}  # slot name -> model's own name

    def rename(se, corr):
        """(stderr, correlation) in the model's own names."""
        return (
            {own[k]: se[k] for k in cls.keys()},
            {own[a]: {own[b]: r for b, r in row.items()} for a, row in corr.items()},
        )

    rep = reported(
        problem,
        x,
        summary,
        outcome.values,
        kind=model_error,
        rename=rename,
        given_result=given_result,
        given_column=None if given is None else lambda n: problem.index(type(given).param(n).key),
        propagation=propagation,
        keep_influence=cls.KIND == "medium",
        floor=model_floor(brdf, medium),
    )
    return _result(
        step, data, problem, outcome, summary, rep, fitted, given, given_result, free, what, n_grid
    )


__all__ = [
    "fit_step",
    "fixes_of_step",
    "stats_and_message",
    "warn_misfit",
    "MisfitWarning",
    "MISFIT_CHI2",
    "STARTS",
    "ROLE",
]
