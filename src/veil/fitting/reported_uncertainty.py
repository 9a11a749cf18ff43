"""The uncertainties a weighted fit reports (docs/fitting.md), shared by the steps
(:mod:`veil.fitting.steps`) and the joint fit (:mod:`veil.fitting.joint`):

- the noise's covariance C of the free parameters (the solver's summary);
- ``stderr_total``: C plus a given model's covariance propagated into it, to first order or
  through sigma points (:mod:`veil.fitting.propagation`), when the given model came from a
  fit that has one (docs/model.md sec. 7);
- the model-discrepancy term (:mod:`veil.fitting.model_error`) in both, the uncertainties
  without it kept in its ``noise_only``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from . import model_error as discrepancy
from . import shared_error
from .problem import Problem
from .propagation import given_jacobian, propagated, sensitivity
from .solver import uncertainties, weighted_jacobian


@dataclass(frozen=True)
class Reported:
    """A fit's uncertainties: ``stderr`` and ``correlation`` (the given model exact),
    ``stderr_total`` and ``correlation_total`` (its covariance added; None without one) and
    the ``model_error`` term (None when "off" or unweighted); ``propagation`` says how the
    given model's covariance entered the totals (:func:`veil.fitting.propagation.propagated`)."""

    stderr: dict
    correlation: dict
    stderr_total: dict | None
    correlation_total: dict | None
    model_error: discrepancy.ModelError | None
    propagation: dict | None = None


def _same(stderr, correlation):
    return stderr, correlation


def _shared(
    problem: Problem,
    x,
    own_influence,
    given_result,
    given_column,
    term,
    how,
    dist,
    residuals,
    scaled,
    jw,
):
    """(this step's error correlation, the cross term, its share) for the error a step shares with
    its given medium's correlated term (:func:`veil.fitting.shared_error.shared`): this
    step's error is the shared process plus what its own s exceeds it by, with its own
    length, so that the two sessions' errors have a covariance that is a covariance; the
    cross term is scaled by how far the two are one (the share,
    :func:`veil.fitting.shared_error.session_correlation` from both fits' ``residuals``,
    ``scaled`` values and Jacobians; None, counted as 1, for a given result without its
    residuals). None when there is nothing shared, or when the given covariance entered
    through sigma points (the cross term is first order; it is then left out, which errs on
    the cautious side). ``dist`` holds the configurations' distances
    (:func:`veil.fitting.model_error.distances`)."""
    given = discrepancy.given_term(given_result)
    if given is None or given.influence is None or given.length == 0.0 or given.sigma == 0.0:
        return None
    if how is None or how.get("method") != "linear":
        return None
    extra = max(term.sigma**2 - given.sigma**2, 0.0)
    corr = discrepancy.correlation(dist, given.length)
    if extra > 0.0:
        corr = (
            given.sigma**2 * corr + extra * discrepancy.correlation(dist, term.length)
        ) / term.sigma**2
    names, cov_given = given_result.covariance(total=True)
    names = list(names)
    cols = [given_column(n) for n in names]
    share = shared_error.session_correlation(
        residuals,
        scaled,
        jw,
        problem.angles,
        term.sigma**2 * corr,
        given,
        names,
        given_jacobian(problem, x, cols),
        cov_given,
    )
    sens = sensitivity(problem, x, cols)
    cross = shared_error.shared(
        own_influence, problem.angles, given, names, sens, 1.0 if share is None else share
    )
    return corr, cross, share


def _term_correlation(problem: Problem, term, given_result) -> tuple:
    """(distances between the configurations, or None when no term has a length; the
    correlation of the fit's own term, None when independent)."""
    given = discrepancy.given_term(given_result)
    dist = (
        discrepancy.distances(problem.angles)
        if term.length > 0 or (given is not None and given.length > 0)
        else None
    )
    corr = (
        None
        if term.length == 0.0 or dist is None  # (a length: dist is not None)
        else discrepancy.correlation(dist, term.length)
    )
    return dist, corr


def _with_influence(term, rows: dict, problem: Problem, summary, scaled):
    """``term`` keeping its influence on the estimate (``rows``, by result name) and its
    configurations, for the step that is given this fit."""
    return dataclasses.replace(
        term,
        influence={k: tuple(float(v) for v in row) for k, row in rows.items()},
        angles=tuple(tuple(float(v) for v in a) for a in problem.angles),
        residuals=tuple(float(v) for v in summary.residuals),
        scaled=tuple(float(v) for v in scaled),
    )


def reported(
    problem: Problem,
    x,
    summary,
    values,
    *,
    kind: str,
    rename: Callable = _same,
    given_result=None,
    given_column: Callable[[str], int] | None = None,
    propagation: str = "auto",
    keep_influence: bool = False,
    floor=None,
) -> Reported:
    """The uncertainties of a fit at natural ``x``: the solver's ``summary`` (the noise's
    covariance of the free parameters, None when undetermined) and the model ``values``;
    ``rename(stderr, correlation)`` puts the problem's names into the result's.
    ``given_result`` (with ``given_column``) is a given model's fit, propagated into the
    totals; a step-1 medium also passes its model error on (step 2 inherits it). ``kind`` is
    the model-discrepancy term's (:data:`veil.fitting.model_error.KINDS`), estimated for a
    weighted problem only. ``propagation`` is the method of
    :func:`veil.fitting.propagation.propagated`. A correlated term of a fit with
    ``keep_influence`` (step 1) keeps its influence on the estimate and its configurations;
    given such a fit, step 2's total adds the error the two share
    (:func:`veil.fitting.shared_error.shared`). ``floor`` is the fit's models' declared
    error (:func:`model_floor`): the least term of a weighted fit whose ``kind`` is not
    "off" and whose covariance is determined."""
    totals = _Totals(problem, x, rename, given_column, propagation, summary.converged)
    cov = summary.covariance
    stderr, corr = rename(summary.stderr, summary.correlation)
    # the given fit without any model-discrepancy term (its own or inherited): "off" reports
    # the noise alone, and every fit keeps its noise-only uncertainties when a term entered
    given_noise = None if given_result is None else discrepancy.noise_only(given_result)
    stderr_total, corr_total, how = totals.of(cov, given_noise if kind == "off" else given_result)
    if kind == "off" or not problem.weighted or cov is None:
        return Reported(stderr, corr, stderr_total, corr_total, None, how)
    jw = weighted_jacobian(problem, x)
    term = discrepancy.step_term(
        summary.residuals,
        values,
        problem.w,
        problem.n_points - problem.n_free,
        problem.angles,
        discrepancy.given_term(given_result),
        kind,
        jw,
        floor,
    )
    if not (term.sigma > 0 or given_noise is not given_result):
        return Reported(stderr, corr, stderr_total, corr_total, term, how)
    # without an inherited term the total above is already the noise-only one
    noise_total = (
        (stderr_total, corr_total)
        if given_noise is given_result
        else totals.of(cov, given_noise)[:2]
    )
    noise_only = {
        "stderr": stderr,
        "correlation": corr,
        "stderr_total": noise_total[0],
        "correlation_total": noise_total[1],
    }
    if term.sigma > 0:
        stderr, corr, stderr_total, corr_total, how, term = _with_term(
            totals, term, cov, jw, values, summary, given_result, how, keep_influence
        )
    term = dataclasses.replace(term, noise_only=noise_only)
    return Reported(stderr, corr, stderr_total, corr_total, term, how)


@dataclass(frozen=True)
class _Totals:
    """A fit's uncertainties in the result's names (``rename``), and its totals: a given
    fit's propagated part added (made once per given fit: it depends on that fit's
    covariance alone)."""

    problem: Problem
    x: Any
    rename: Callable
    given_column: Callable[[str], int] | None
    propagation: str
    converged: bool = True
    parts: dict = field(default_factory=dict)

    def named(self, c) -> tuple:
        return self.rename(*uncertainties(c, self.problem.names, self.problem.free_index))

    def named_rows(self, m) -> dict:
        """{result name: row} of a (free parameters x ...) matrix."""
        keys = dict.fromkeys(self.problem.names)
        keys.update(zip(self.problem.free_names, m))
        return {k: v for k, v in self.rename(keys, {})[0].items() if v is not None}

    def of(self, c, given_res, extra=None) -> tuple:
        """(stderr, correlation, how) of ``c`` with ``given_res``'s part (and ``extra``)."""
        if given_res is None or c is None:
            return None, None, None
        if id(given_res) not in self.parts:
            assert self.given_column is not None  # a given fit comes with its columns
            self.parts[id(given_res)] = propagated(
                self.problem,
                self.x,
                given_res,
                self.given_column,
                self.propagation,
                self.converged,
            )
        part, how = self.parts[id(given_res)]
        if part is None:
            return None, None, how
        return (*self.named(c + part + (0.0 if extra is None else extra)), how)


def _with_term(
    totals: _Totals, term, cov, jw, values, summary, given_result, how, keep_influence: bool
) -> tuple:
    """(stderr, correlation, their totals, how, the term) of a fit whose model-discrepancy
    ``term`` enters its covariance (the sandwich), with the error it shares with its given
    medium's fit and, with ``keep_influence``, its influence kept for step 2."""
    problem = totals.problem
    dist, corr_d = _term_correlation(problem, term, given_result)
    scaled = values * problem.w
    g = shared_error.influence(cov, jw, scaled)
    shared = _shared(
        problem,
        totals.x,
        g,
        given_result,
        totals.given_column,
        term,
        how,
        dist,
        summary.residuals,
        scaled,
        jw,
    )
    if shared is not None:  # the sum of the shared process and step 2's own
        corr_d, _, share = shared
        term = dataclasses.replace(term, session_correlation=share)
    cov = discrepancy.sandwich(cov, jw, scaled, term.sigma, corr_d)
    stderr, corr = totals.named(cov)
    stderr_total, corr_total, how = totals.of(
        cov, given_result, None if shared is None else shared[1]
    )
    if keep_influence and term.length > 0:
        term = _with_influence(term, totals.named_rows(g), problem, summary, scaled)
    return stderr, corr, stderr_total, corr_total, how, term


def model_floor(*models) -> tuple[float, float] | None:
    """The largest declared model error (s, ell) of ``models`` (classes or instances; None
    skipped), ``Model.MODEL_ERROR_FLOOR``; None when none declares one. (Only media declare
    one today; should a BRDF and a medium both declare, the larger is taken, not their sum.)"""
    floors = [
        m.MODEL_ERROR_FLOOR for m in models if m is not None and m.MODEL_ERROR_FLOOR is not None
    ]
    return max(floors, default=None)


__all__ = ["Reported", "reported", "model_floor"]
