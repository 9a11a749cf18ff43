"""Fitting one step's candidates and ranking them (:func:`select`, issue 29;
docs/choosing-models.md), screened: every candidate's quick fit first, the full fit only
for those that could still be chosen. In clear water (``fit_direct(screen=True)``) the
quick fit is the grid's best start to TOL_SCREEN; f_r has no quadrature there, so its rule
error is zero and its interval only allows for that tolerance's descent and the
discrepancy term's parameters.

- **Quick fit** (``screen=True`` of :func:`veil.fitting.fit_medium` / ``fit_target``): the
  starting grid's best start only, iterated at the "fast" quadrature to 0.3 standard errors
  (``solver.TOL_SCREEN``), not polished, no covariance propagated. A family's other
  candidates (other values of its ranked options: the forward series' order weights, a
  microfacet distribution) start from its first candidate's quick optimum instead of their
  grid, in a second round (:func:`quick_fits`): the options reweigh the same physics, and
  that start is closer (on session m05 the order weights' quick fits took 4 to 9
  evaluations from it against 21 to 39 from the grid).
- **Full fit**: continues from the candidate's quick optimum; the grid is evaluated only
  when that run does not convince, without its best start when the quick fit began there
  (``start`` of ``fit_medium``, ``fit_target`` and ``fit_joint``). The full fit then
  agrees with a fit from the grid to the fit's tolerance at the "fast" rule, not bit for
  bit; after a polish at a finer rule, within a fraction of a standard error (up to 0.23
  of tau's for m05's light-side weights, whose fast-rule cost is flat to 1e-4 along the
  tau-g valley, so the polish's frozen Jacobian is taken at another point of it).
- **Its BIC's interval**: a converged quick fit through a medium also evaluates its model
  once at the rule its full fit ends at (``stats["rule_error"]``, :func:`veil.fitting.solver.run`; a
  linear family one lobe width in use at a time, :func:`veil.fitting.linear_fit.rule_error`). That
  gives the deviance at the quick optimum under the finer rule, where the full fit starts
  (the upper end), and how far refitting can lower it: at most the squared norm of the rule
  error in the residuals' metric, to first order, since the quick optimum's residuals are
  orthogonal to the Jacobian (the lower end; :func:`measured_interval`; for a linear family
  to the extent of its penalty and bounds). The lower end also allows for the descent an
  iterative quick fit's tolerance leaves (TOL_SCREEN standard errors per parameter, scaled
  by the misfit; a linear family's quick fit is exact at its rule) and for the change of a
  discrepancy term's log-determinant with the model values. A full fit at the fast rule
  itself has no rule error. Without that measurement (an unconverged quick fit) every value
  may be off by :data:`FAST_ERROR` of itself: the fast quadrature is within that of a
  converged integral at every configuration of every parametric family pair (measured at
  most 7.2e-3 against "high" and 8.9e-3 against "default", rough conductor through the
  forward series: benchmarks/bench_fast_error.py; the nonparametric family's columns are
  single Beckmann lobes, as the rough conductor's), and moving every value that far toward
  the data and away from it bounds the deviance (the ranking's -2 ln L,
  :func:`veil.fitting.selection.deviance`) that the quadrature can explain. Either way the
  model-discrepancy term's (s, ell) are held, and 2 ln N either side allows for the full fit
  switching that term on or off: the interval [lower, upper] of the candidate's BIC.
- **Who goes on**: a candidate whose lower end lies more than :data:`SCREEN_MARGIN` above the
  smallest upper end of a converged quick fit is screened out: listed with its quick fit's
  BIC, not fitted further. Every other one gets the full fit, and the ranking is theirs.
  The full fits are the measure then: a screened-out candidate whose lower end is within
  SCREEN_MARGIN of the best full fit's BIC (every one, when no full fit ranks) is fitted in
  full too.
  What the interval does not bound: a minimum that only a later start would find, and the
  descent left to a quick fit that stopped without converging (its BIC is where it
  stopped); a candidate that misses by more than SCREEN_MARGIN from its first start is taken
  to be out.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .problem import ITERATION_ACCURACY
from .result import FitResult
from .selection import (
    NoCandidateError,
    Ranking,
    deviance,
    fit_candidates,
    rank,
    teller,
    workers,
)
from .solver import TOL_SCREEN
from .steps import warn_misfit

#: Relative error of the "fast" quadrature that the screen allows for: twice the largest
#: measured (module docstring).
FAST_ERROR = 2e-2
#: BIC by which a candidate's best case must miss the best one's worst case to be screened
#: out (Kass and Raftery 1995: above 10 is "very strong" evidence).
SCREEN_MARGIN = 10.0


def _measured(result: FitResult, data) -> tuple:
    """(weighted residuals r, their scale, weighted?, deviance, moved(residuals) -> deviance,
    the rule error in r's units or None) of a quick fit: what its intervals are made of."""
    r = np.asarray(result.residuals, dtype=float)
    weighted = result.weighted and data.sigma is not None
    scale = data.sigma if weighted else 1.0

    def moved(res):
        return deviance(dataclasses.replace(result, residuals=tuple(res.tolist())), data)[0]

    measured = result.stats.get("rule_error")
    delta = None
    if measured is not None and result.converged and len(measured["values"]) == r.size:
        delta = np.asarray(measured["values"], dtype=float) / scale
    return r, scale, weighted, deviance(result, data)[0], moved, delta


def bic_interval(result: FitResult, data, bic: float) -> tuple[float, float]:
    """[lower, upper] of a quick fit's ``bic`` (module docstring), widened by the BIC of the
    model-discrepancy term's two parameters (2 ln N) for a weighted fit: the full fit may
    switch the term on or off. From the quick fit's measured rule error when it has one
    (:func:`measured_interval`), else from FAST_ERROR of every model value."""
    r, scale, weighted, dev, moved, delta = _measured(result, data)
    term = 2.0 * math.log(max(r.size, 1)) if weighted else 0.0
    if delta is not None:
        # the descent an iterative quick fit's tolerance leaves (a step of TOL_SCREEN
        # standard errors, scaled by the misfit; a linear family's is its exact solution)
        # and how the discrepancy term's log-determinant moves with the model values
        spread = max(result.chi2_reduced, 1.0) if weighted else result.chi2_reduced
        iterative = "nfev" in result.stats
        slack = TOL_SCREEN**2 * max(len(result.stderr), 1) * spread if iterative else 0.0
        logdet = _logdet_change(result, data, delta * scale) if weighted else 0.0
        lower, upper = measured_interval(r, delta, moved, weighted, slack + abs(logdet))
        return bic + lower - dev - term, bic + upper - dev + term
    f = np.abs(data.y - r * scale)
    a = FAST_ERROR * np.maximum(f, 1e-3 * f.max(initial=0.0)) / scale
    sign = np.where(r < 0, -1.0, 1.0)
    toward = sign * np.maximum(np.abs(r) - a, 0.0)
    away = r + sign * a
    return bic + moved(toward) - dev - term, bic + moved(away) - dev + term


def rule_bic(result: FitResult, data, bic: float) -> float | None:
    """A quick fit's ``bic`` with its values at the rule its full fit would end at (its
    measured rule error; None without one): the BIC it would start from."""
    r, _, _, dev, moved, delta = _measured(result, data)
    return None if delta is None else bic + moved(r - delta) - dev


def _logdet_change(result: FitResult, data, change: np.ndarray) -> float:
    """How much the deviance's log-determinant (the model-discrepancy term's covariance,
    which scales with the model values) moves when the quick fit's values move by
    ``change``: 0 without a term."""
    values = data.y - np.asarray(result.residuals, dtype=float) * data.sigma
    zero = dataclasses.replace(result, residuals=(0.0,) * values.size)

    def logdet(f):
        return deviance(zero, dataclasses.replace(data, y=f))[0]

    return logdet(values + change) - logdet(values)


def measured_interval(
    r: np.ndarray, delta: np.ndarray, moved, weighted: bool, slack: float = 0.0
) -> tuple:
    """(lower, upper) deviance of the full fit from a converged quick fit's residuals ``r``
    and its rule error ``delta`` (the finer rule's values minus the fast rule's, in the
    residuals' units); ``moved(residuals)`` is the deviance of other residuals, ``slack``
    a further allowance (in sums of squares) below the lower end.

    At the quick optimum the finer rule's residuals are r - delta, and their deviance is
    where the full fit starts: the upper end. The quick optimum is stationary for the fast
    rule, so r is orthogonal to the Jacobian's columns; refitting to the finer rule lowers
    the sum of squares by the part of delta in their span, at most |delta|^2 (to first
    order; a discrepancy term's covariance is at least the identity, so also in its
    metric), below the lower of the two rules' deviances: the lower end."""
    upper = moved(r - delta)
    width = float(delta @ delta) + slack
    if weighted:
        return min(moved(r), upper) - width, upper
    rss = min(float((r - delta) @ (r - delta)), float(r @ r))
    n = max(r.size, 1)
    return n * math.log(max(rss - width, 1e-300 * n) / n), upper


def survivors(ranking: Ranking, quick: dict, data) -> tuple[list[str], dict]:
    """(labels that get the full fit, {label: (lower, upper)} of the rest's BIC) from the
    quick fits' ``ranking`` and results ``quick`` {label: FitResult or exception}."""
    bounds = {}
    for row in ranking.rows:
        result = quick.get(row["label"])
        if isinstance(result, FitResult) and row["bic"] is not None and math.isfinite(row["bic"]):
            bounds[row["label"]] = bic_interval(result, data, row["bic"])
    tops = [bounds[r["label"]][1] for r in ranking.rows if r["converged"] and r["label"] in bounds]
    limit = (min(tops) if tops else math.inf) + SCREEN_MARGIN
    keep, out = [], {}
    for row in ranking.rows:
        label, result = row["label"], quick.get(row["label"])
        if not isinstance(result, FitResult):
            continue  # it failed: reported as failed
        if label not in bounds or bounds[label][0] <= limit:
            keep.append(label)
        else:
            out[label] = bounds[label]
    return keep, out


def _screened_rows(quick_ranking: Ranking, out: dict, quick: dict, data) -> list[dict]:
    """The screened-out candidates' rows: their quick fit's numbers, weight 0, and what
    happened (:func:`veil.fitting.selection.rank` sets their dBIC against the best);
    ``quick`` {label: quick FitResult}."""
    rows = []
    for label, (lower, _) in out.items():
        row = dict(quick_ranking.row(label))
        result = quick[label]
        at_rule = rule_bic(result, data, row["bic"])
        rule = result.stats["rule_error"]["accuracy"] if at_rule is not None else ""
        at_rule = None if rule == ITERATION_ACCURACY else at_rule  # the quick fit's own
        row.update(
            screened=True,
            weight=0.0,
            error=None,
            note=(
                "screened out: its quick fit (one start"
                + ("" if result.given is None else ", fast quadrature")
                + ("" if row["converged"] else f"; {row['error']}")
                + f") has BIC {row['bic']:.4g}"
                + ("" if at_rule is None else f" ({at_rule:.4g} at the {rule!r} rule)")
                + f", at least {lower:.4g} with the "
                + ("fit's tolerance" if result.given is None else "quadrature's error")
                + f", more than {SCREEN_MARGIN:g} above the best; not fitted further"
            ),
        )
        rows.append(row)
    return sorted(rows, key=lambda r: r["bic"])


def quick_fits(step: str, cands, quick_fit, progress=None) -> dict:
    """Every candidate's ``quick_fit(candidate, start=...)`` in threads: the first candidate
    of each family from its starting grid (``start=None``), the family's other candidates
    (other values of its ranked options) then from where that one stopped, a closer start
    than the grid's even when it did not converge (on the paper's data the forward series'
    light-side weights took 1.8 s from it, 4.4 s from their grid; module docstring). Their
    full fits fall back to their whole grid, which their quick fits did not run. {label:
    (FitResult or exception, seconds)} in the candidates' order."""
    tell = teller(step, len(cands), progress, "quick fit ")
    heads: dict = {}
    for c in cands:
        heads.setdefault(c.family, c)
    quick = fit_candidates(quick_fit, list(heads.values()), tell)

    def from_sibling(c):  # from its own grid when the first candidate raised
        head = quick[heads[c.family].label][0]
        return quick_fit(c, start=head if isinstance(head, FitResult) else None)

    siblings = [c for c in cands if heads[c.family] is not c]
    if siblings:
        quick.update(fit_candidates(from_sibling, siblings, tell))
    return {c.label: quick[c.label] for c in cands}


def screen_fits(step: str, cands, data, fit, quick_fit, progress=None) -> tuple:
    """Every candidate's quick fit (:func:`quick_fits`), then ``fit(candidate, start=its
    quick fit)`` for the survivors (module docstring), in threads, ``progress(text, done,
    total)`` after each: ({label: (full FitResult or the exception of either fit, seconds
    of both)}, the screened-out candidates' rows)."""
    quick = quick_fits(step, cands, quick_fit, progress)
    quick_ranking = rank(step, quick, data, cands)
    keep, out = survivors(quick_ranking, {lab: q[0] for lab, q in quick.items()}, data)
    fitted = {lab: q for lab, q in quick.items() if isinstance(q[0], Exception)}

    def resumed(c):
        return fit(c, start=quick[c.label][0])

    while keep:
        going = [c for c in cands if c.label in keep]
        if progress is not None:
            progress(f"{step}: {len(going)} of {len(cands)} go on to the full fit", None, None)
        full = fit_candidates(resumed, going, teller(step, len(going), progress))
        fitted.update({lab: (res, sec + quick[lab][1]) for lab, (res, sec) in full.items()})
        # measured against the best full fit, which the quick fits only estimated: a
        # screened-out candidate now within reach (or every one, when no full fit ranks)
        # is fitted in full too
        ranked = [r["bic"] for r in rank(step, fitted, data, cands).rows if r["error"] is None]
        limit = (min(ranked) if ranked else math.inf) + SCREEN_MARGIN
        keep = [lab for lab, (lower, _) in out.items() if lower <= limit]
        out = {lab: b for lab, b in out.items() if lab not in keep}
    return fitted, _screened_rows(quick_ranking, out, {k: q[0] for k, q in quick.items()}, data)


def select(
    step: str, cands, data, fit, what: str, progress=None, quick_fit=None
) -> tuple[Ranking, dict]:
    """Fit every candidate (``fit(candidate)``, in threads) and rank them on ``data``:
    (ranking, {label: FitResult}); with ``quick_fit`` (a step through the medium) the
    candidates are screened first (:func:`screen_fits`; both callables then take a
    ``start``, a FitResult of the candidate's model to start from, or None). A
    :class:`NoCandidateError` when every candidate failed; the chosen one is warned about
    when it misses the data (``what`` names them)."""
    if progress is not None:
        progress(f"{step}: {len(cands)} candidates in {workers(len(cands))} thread(s)", None, None)
    screened: list = []
    if quick_fit is not None and len(cands) > 1:
        fitted, screened = screen_fits(step, cands, data, fit, quick_fit, progress)
    else:
        fitted = fit_candidates(fit, cands, teller(step, len(cands), progress))
    ranking = rank(step, fitted, data, cands, screened)
    results = {lab: res for lab, (res, _) in fitted.items() if isinstance(res, FitResult)}
    if ranking.chosen is None:
        raise NoCandidateError(step, ranking)
    chosen = results[ranking.chosen]
    warn_misfit(chosen.chi2_reduced, data, what, chosen.given is not None)
    return ranking, results


__all__ = [
    "FAST_ERROR",
    "SCREEN_MARGIN",
    "bic_interval",
    "measured_interval",
    "rule_bic",
    "survivors",
    "quick_fits",
    "screen_fits",
    "select",
]
