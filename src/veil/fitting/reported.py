"""The uncertainties a weighted fit reports (docs/fitting.md), shared by the steps
(:mod:`veil.fitting.steps`) and the joint fit (:mod:`veil.fitting.joint`):

- the noise's covariance C of the free parameters (the solver's summary);
- ``stderr_total``: C plus a given model's covariance propagated to first order,
  d x / d theta = -J_w^+ J_w,theta (weighted), Cov + S Cov_theta S^T, when the given model
  came from a fit that has one (MODEL.md sec. 7);
- the model-discrepancy term (:mod:`veil.fitting.model_error`) in both, the uncertainties
  without it kept in its ``noise_only``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import model_error as discrepancy
from .problem import ITERATION_ACCURACY, Problem
from .solver import uncertainties, weighted_jacobian


@dataclass(frozen=True)
class Reported:
    """A fit's uncertainties: ``stderr`` and ``correlation`` (the given model exact),
    ``stderr_total`` and ``correlation_total`` (its covariance added; None without one) and
    the ``model_error`` term (None when "off" or unweighted)."""

    stderr: dict
    correlation: dict
    stderr_total: dict | None
    correlation_total: dict | None
    model_error: discrepancy.ModelError | None


def propagated(problem: Problem, x, cov, given_result, column: Callable[[str], int]):
    """The free parameters' covariance ``cov`` with ``given_result``'s (total) covariance
    added to first order; ``column`` maps a name of the given result to its index in the
    problem. None when the given result has no covariance."""
    found = given_result.covariance(total=True)
    if found is None:
        return None
    gnames, gcov = found
    cols = [column(n) for n in gnames]
    _, full = problem.value_and_jacobian(x, ITERATION_ACCURACY,
                                         list(problem.free_index) + cols)
    w = problem.w[:, None]
    jw = full[:, problem.free] * w
    sens = -np.linalg.lstsq(jw, full[:, cols] * w, rcond=None)[0]
    return cov + sens @ gcov @ sens.T


def _same(stderr, correlation):
    return stderr, correlation


def reported(problem: Problem, x, summary, values, *, kind: str, rename: Callable = _same,
             given_result=None, given_column: Callable[[str], int] | None = None) -> Reported:
    """The uncertainties of a fit at natural ``x``: the solver's ``summary`` (the noise's
    covariance of the free parameters, None when undetermined) and the model ``values``;
    ``rename(stderr, correlation)`` puts the problem's names into the result's.
    ``given_result`` (with ``given_column``) is a given model's fit, propagated into the
    totals; a step-1 medium also passes its model error on (step 2 inherits it). ``kind`` is
    the model-discrepancy term's (:data:`veil.fitting.model_error.KINDS`), estimated for a
    weighted problem only."""
    cov = summary.covariance
    stderr, corr = rename(summary.stderr, summary.correlation)

    def named(c):
        return rename(*uncertainties(c, problem.names, problem.free_index))

    def total_of(c, given_res):
        if given_res is None or c is None:
            return None, None
        total = propagated(problem, x, c, given_res, given_column)
        return (None, None) if total is None else named(total)

    # the given fit without any model-discrepancy term (its own or inherited): "off" reports
    # the noise alone, and every fit keeps its noise-only uncertainties when a term entered
    given_noise = None if given_result is None else discrepancy.noise_only(given_result)
    stderr_total, corr_total = total_of(cov, given_noise if kind == "off" else given_result)
    term = None
    if kind != "off" and problem.weighted and cov is not None:
        term = discrepancy.step_term(summary.residuals, values, problem.w,
                                     problem.n_points - problem.n_free, problem.angles,
                                     discrepancy.given_term(given_result), kind)
        if term.sigma > 0 or given_noise is not given_result:
            # without an inherited term the total above is already the noise-only one
            noise_total = ((stderr_total, corr_total) if given_noise is given_result
                           else total_of(cov, given_noise))
            noise_only = {"stderr": stderr, "correlation": corr,
                          "stderr_total": noise_total[0], "correlation_total": noise_total[1]}
            if term.sigma > 0:
                corr_d = (None if term.length == 0.0 else discrepancy.correlation(
                    discrepancy.distances(problem.angles), term.length))
                cov = discrepancy.sandwich(cov, weighted_jacobian(problem, x),
                                           values * problem.w, term.sigma, corr_d)
                stderr, corr = named(cov)
                stderr_total, corr_total = total_of(cov, given_result)
            term = dataclasses.replace(term, noise_only=noise_only)
    return Reported(stderr, corr, stderr_total, corr_total, term)


__all__ = ["Reported", "propagated", "reported"]
