"""Honest uncertainty through the two-step pipeline (docs/model.md sec. 7).

Step 2 fits the target with the medium of step 1 held fixed, and step 1 the medium with the
reference of step 0 held fixed; each step's own standard errors say nothing of what the
previous step left uncertain - the paper's failure (docs/model.md sec. 7) hides there. The fits
of :mod:`veil.fitting` add the given model's covariance (``stderr_total``; to first order,
or through sigma points where it is large, :mod:`veil.fitting.propagation`);
this module splits that total into a per-step budget, can compute step 0's part from the
reference's own data, and checks the linearization by sampling.

The target's estimate solves J_t^T W r(theta_t, theta_m) = 0, so a change d theta_m of the
medium moves it by

    d theta_t = -A d theta_m,   A = (J_t^T W J_t)^-1 J_t^T W J_m   (= J_t^+ J_m, weighted)

with J_t, J_m the Jacobians of the target session's model w.r.t. the target's and the
medium's free parameters and W the fit's weights (1/sigma^2). Hence

    Cov_t,total = Cov_t (step 2's own) + A Cov_m A^T (step 1)
                                       + A B Cov_ref B^T A^T (step 0)

where B is the same sensitivity of step 1 (the reference in the medium) to the reference's
f_r. The three parts' noise comes from independent data sets, so those variances add up
exactly to the total: :func:`propagate` reports them per parameter (the "budget"). A
model-discrepancy term (:mod:`veil.fitting.model_error`) enters each step's own part; a
correlated one that step 2 shares with step 1 also has a cross term between the two parts
(it mostly cancels: the medium absorbs the error in step 1 and gives it back in step 2),
counted as the budget's part "shared" (:func:`veil.fitting.shared_error.shared`).
:func:`sample_propagation` checks the linearization by refitting the target over media drawn
from step 1's distribution. Where step 1 leaves the medium uncertain by a large part of its
scale the fits propagate through sigma points instead (:mod:`veil.fitting.propagation`), and
:func:`propagate` follows the method the target's fit used. All in natural units (the
FitResult's).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, cast

import numpy as np

from ..engine.evaluator import DirectModel
from ..errors import FitError, InputTypeError
from ..fitting.problem import ITERATION_ACCURACY, session_problem
from ..fitting.propagation import sigma_part
from ..fitting.result import FitResult, JointResult
from ..fitting.solver import solve

if TYPE_CHECKING:  # the result's kind: a fit of a BRDF or of a medium
    from ..models import BRDF, Medium

#: Parts of the error budget, in pipeline order; a correlated model error that step 2 shares
#: with step 1 adds their cross term as the part "shared" (docs/fitting.md; it can be
#: negative: the medium absorbed in step 1 what it gives back in step 2).
PARTS = ("step2", "step1", "step0")
SHARED = "shared"


def covariance_of(result: FitResult, total: bool = False) -> tuple[list[str], np.ndarray]:
    """(free names, covariance in natural units) of a result: its own (``total=False``) or
    including what its given model left uncertain (``total=True``, when the fit propagated
    it); raises FitError when the uncertainties were not determined."""
    if not isinstance(result, FitResult):
        raise InputTypeError(f"expected a FitResult, got {type(result).__name__}")
    found = result.covariance(total=total)
    if found is None:
        missing = [n for n in result.free if result.stderr.get(n) is None]
        raise FitError(
            f"the {result.model} fit ({result.step or 'result'}) has no standard "
            f"error for {', '.join(missing) or 'its parameters'} (Jacobian "
            f"singular): its uncertainty cannot be propagated"
        )
    names, cov = found
    return list(names), np.asarray(cov, dtype=float)


def sensitivity(problem, x, theta, nuisance, accuracy: str = ITERATION_ACCURACY) -> np.ndarray:
    """A = (J_t^T W J_t)^-1 J_t^T W J_n at natural parameters ``x``: the estimate of the
    ``theta`` parameters moves by -A d nuisance (module docstring). Shape (len(theta),
    len(nuisance)); columns are scaled internally for conditioning."""
    it, iu = [problem.index(n) for n in theta], [problem.index(n) for n in nuisance]
    _, full = problem.value_and_jacobian(x, accuracy, it + iu)
    w = problem.w[:, None]
    jt = full[:, it] * w
    jn = full[:, iu] * w
    scale = np.linalg.norm(jt, axis=0)
    if np.any(scale == 0):
        dead = [n for n, s in zip(theta, scale) if s == 0]
        raise FitError(f"the data do not depend on {', '.join(dead)}: cannot propagate")
    sol, *_ = np.linalg.lstsq(jt / scale, jn, rcond=None)
    return sol / scale[:, None]


def _medium_map(medium_result: FitResult, names) -> list[str]:
    """A medium result's parameter names -> its names in a session's problem (aliases)."""
    cls = medium_result.model_class
    return [cls.param(n).key for n in names]


def _step_fit(result, kind: str) -> bool:
    """Whether ``result`` is one step's fit (not a joint fit) of a model of ``kind``."""
    single = isinstance(result, FitResult) and not isinstance(result, JointResult)
    return single and result.kind == kind


def _check_pair(target_result, medium_result, reference_result):
    """Results of the right steps, chained (the target fitted through this medium...)."""
    if not _step_fit(target_result, "brdf") or target_result.step != "target":
        raise FitError(
            "target_result must be a step-2 fit (veil fit target: a BRDF fitted "
            "through a medium, step 'target')"
        )
    if not _step_fit(medium_result, "medium"):
        raise FitError("medium_result must be a step-1 fit (veil fit medium: a medium model)")
    given = target_result.given or {}
    if given.get("params"):
        if given.get("model") != medium_result.model:
            raise FitError(
                f"the target was fitted through a {given.get('model')} medium, not "
                f"the {medium_result.model} of the medium result"
            )
        for k, v in medium_result.params.items():
            g = given["params"].get(k)
            if g is None or not math.isclose(float(g), v, rel_tol=1e-9, abs_tol=1e-15):
                raise FitError(
                    f"the target was fitted through a different medium ({k} = {g} "
                    f"in the target result, {v} in the medium result): propagate "
                    f"with the medium result the target fit used"
                )
    if reference_result is not None:
        if not _step_fit(reference_result, "brdf"):
            raise FitError("reference_result must be a step-0 fit (veil fit reference)")
        given = medium_result.given or {}
        for k, v in reference_result.params.items():
            g = (given.get("params") or {}).get(k)
            if g is not None and not math.isclose(float(g), v, rel_tol=1e-9, abs_tol=1e-15):
                raise FitError(
                    f"the medium was fitted with a different reference ({k} = {g} "
                    f"in the medium result, {v} in the reference result)"
                )


def medium_parts(
    medium_result: FitResult,
    reference_result: FitResult | None = None,
    reference_table=None,
    *,
    black=None,
    accuracy: str = ITERATION_ACCURACY,
) -> tuple[list[str], dict[str, np.ndarray]]:
    """The medium's covariance split into step 1's own part and step 0's (docs/model.md sec. 7).

    Returns (names, {"step1": Cov, "step0": Cov}). Step 0's part is computed from the
    reference's result and its in-medium table (step 1's data) when both are given, else
    taken from the medium result's total covariance (``stderr_total``, which
    :func:`veil.fit_medium` fills when the reference came from a fit); without either there
    is no "step0" entry.
    """
    names, cov1 = covariance_of(medium_result)
    parts = {"step1": cov1}
    if (reference_result is None) != (reference_table is None):
        raise FitError(
            "give both reference_result (step 0) and reference_table (the reference "
            "in the medium, step 1's data) to propagate step 0, or neither"
        )
    if reference_result is not None:
        ref_names, cov0 = covariance_of(reference_result)
        problem = session_problem(
            reference_table,
            cast("BRDF", reference_result.one_model()),
            cast("Medium", medium_result.one_model()),
            free=_medium_map(medium_result, names),
            black=black,
            what="reference (in the medium)",
        )
        if problem.n_points != medium_result.n_points:
            raise FitError(
                f"the reference table has {problem.n_points} points but the medium "
                f"fit used {medium_result.n_points}: give the table (and black "
                f"cloth) of that fit"
            )
        b = sensitivity(
            problem, problem.values, _medium_map(medium_result, names), list(ref_names), accuracy
        )
        parts["step0"] = b @ cov0 @ b.T
    elif medium_result.stderr_total is not None:
        names_t, cov_t = covariance_of(medium_result, total=True)
        if names_t != names:
            raise FitError(
                "the medium result's total and own uncertainties cover different parameters"
            )
        parts["step0"] = cov_t - cov1
    return names, parts


def _sigma_point_parts(problem, medium_result: FitResult, m_names, m_parts: dict, mapped) -> dict:
    """Step 1's part (and step 0's) through sigma-point refits: step 0's is what adding its
    covariance to step 1's adds."""
    cols = [problem.index(n) for n in mapped]
    specs = [medium_result.model_class.param(n) for n in m_names]
    spread = {}
    for part, cov_m in (
        ("step1", m_parts["step1"]),
        ("step0", m_parts["step1"] + m_parts.get("step0", 0.0)),
    ):
        if part in m_parts:
            spread[part] = sigma_part(problem, problem.values, cols, specs, cov_m).covariance
    parts = {"step1": spread["step1"]}
    if "step0" in spread:
        parts["step0"] = spread["step0"] - spread["step1"]
    return parts


def propagate(
    target_result: FitResult,
    medium_result: FitResult,
    table,
    *,
    reference_result: FitResult | None = None,
    reference_table=None,
    black=None,
    reference_black=None,
    accuracy: str = ITERATION_ACCURACY,
    method: str | None = None,
) -> FitResult:
    """The target's result with total uncertainties and their budget (module docstring).

    target_result, medium_result : the step-2 and step-1 FitResults (the target fitted
        through this medium).
    table : the target session the step-2 fit used (DataFrame or CSV path; ``black`` the
        black cloth subtracted there, if any).
    reference_result, reference_table : optionally step 0's result and step 1's data (the
        reference in the medium; ``reference_black``): step 0's part computed explicitly;
        otherwise it comes from the medium result's total covariance when present.
    accuracy : quadrature of the sensitivities (the fits' covariances use "fast" too).
    method : "linear" or "sigma-points" (:mod:`veil.fitting.propagation`); None: the one
        the step-2 fit used (linear for a result that does not say). Through sigma points,
        step 1's part is that of its own covariance and step 0's what adding step 0's
        covariance adds (the parts of a nonlinear response do not add up otherwise).

    Returns a new FitResult: ``stderr``/``correlation`` stay step 2's own;
    ``stderr_total``/``correlation_total`` are the totals; ``stats["budget"]`` maps each free
    parameter to its variance from "step2" (its own: noise, and the model error when it has
    a term), "step1", "step0" (when known), "shared" (when step 2 shares step 1's
    correlated model error: their cross term, possibly negative) and "total" (their sum);
    ``stats["sensitivity"]`` holds d target / d medium.
    """
    _check_pair(target_result, medium_result, reference_result)
    method = _method(method, target_result)
    theta, cov2 = covariance_of(target_result)
    m_names, m_parts = medium_parts(
        medium_result, reference_result, reference_table, black=reference_black, accuracy=accuracy
    )
    problem = session_problem(
        table,
        cast("BRDF", target_result.one_model()),
        cast("Medium", medium_result.one_model()),
        free=theta,
        black=black,
        what="target (in the medium)",
    )
    if problem.n_points != target_result.n_points:
        raise FitError(
            f"the table has {problem.n_points} points but the target fit used "
            f"{target_result.n_points}: give the table (and black cloth) of that fit"
        )
    mapped = _medium_map(medium_result, m_names)
    a = sensitivity(problem, problem.values, theta, mapped, accuracy)
    parts = {"step2": cov2}
    if method == "linear":
        for part, cov_m in m_parts.items():
            parts[part] = a @ cov_m @ a.T
    else:
        parts.update(_sigma_point_parts(problem, medium_result, m_names, m_parts, mapped))
    cross = _shared_part(problem, target_result, medium_result, m_names, -a)
    if cross is not None:
        parts[SHARED] = cross
    total, se, budget, corr = _totals(theta, parts)
    stderr_total: dict[str, float | None] = {n: None for n in target_result.params}
    stderr_total.update({n: float(s) for n, s in zip(theta, se)})
    sens = {n: {m: float(-a[j, k]) for k, m in enumerate(m_names)} for j, n in enumerate(theta)}
    what = "the medium's (step 1)" + (" and the reference's (step 0)" if "step0" in parts else "")
    how = "by linearization" if method == "linear" else "through sigma-point refits"
    message = f"{target_result.message}; total standard errors include {what} uncertainty, "
    message += f"propagated {how}"
    stats = dict(target_result.stats, budget=budget, sensitivity=sens)
    return dataclasses.replace(
        target_result,
        stderr_total=stderr_total,
        correlation_total=corr,
        message=message,
        stats=stats,
    )


def _method(method, target_result: FitResult) -> str:
    """The propagation method: as given, or the one the step-2 fit used (linear when the
    result does not say)."""
    if method is None:
        method = (target_result.stats.get("propagation") or {}).get("method", "linear")
    if method not in ("linear", "sigma-points"):
        raise FitError(f"method = {method!r}; expected 'linear' or 'sigma-points'")
    return method


def _totals(theta: list, parts: dict) -> tuple:
    """(the total covariance, its standard errors, the budget {name: {part: variance,
    "total": ...}}, the total correlation {name: {name: r}}) of the ``parts``."""
    total = cast(np.ndarray, sum(parts.values()))  # (of arrays: an array)
    se = np.sqrt(np.maximum(np.diag(total), 0.0))
    budget = {}
    for j, n in enumerate(theta):
        entry = {part: float(parts[part][j, j]) for part in PARTS + (SHARED,) if part in parts}
        entry["total"] = float(total[j, j])
        budget[n] = entry
    corr = {}
    for i, na in enumerate(theta):
        corr[na] = {
            nb: (float(total[i, j] / (se[i] * se[j])) if se[i] * se[j] > 0 else None)
            for j, nb in enumerate(theta)
        }
    return total, se, budget, corr


def _shared_part(problem, target_result, medium_result, m_names, sens):
    """The cross term of the correlated model error steps 1 and 2 share
    (:func:`veil.fitting.shared_error.shared`) at the target's estimate, None without one."""
    from ..fitting.model_error import noise_only
    from ..fitting.shared_error import influence, shared
    from ..fitting.solver import weighted_jacobian

    term = medium_result.model_error
    if term is None or term.influence is None or term.length == 0.0 or term.sigma == 0.0:
        return None
    if target_result.model_error is None or target_result.model_error.sigma == 0.0:
        return None
    if (target_result.stats.get("propagation") or {}).get("method", "linear") != "linear":
        return None  # as the fit: no first-order cross term beside sigma points
    _, cov_noise = covariance_of(noise_only(target_result))
    x = problem.values
    values = problem.model_values(x, ITERATION_ACCURACY)
    g2 = influence(cov_noise, weighted_jacobian(problem, x), values * problem.w)
    share = target_result.model_error.session_correlation
    return shared(g2, problem.angles, term, list(m_names), sens, 1.0 if share is None else share)


def budget_table(result: FitResult) -> list[dict]:
    """Rows (parameter, value, total stderr, % of the variance from each step) of a result
    returned by :func:`propagate`."""
    budget = result.stats.get("budget")
    if not budget:
        raise FitError("this result carries no uncertainty budget (see veil.uncertainty.propagate)")
    rows = []
    for n, entry in budget.items():
        total = entry["total"]
        row = {
            "parameter": n,
            "value": result.params[n],
            "stderr": math.sqrt(total),
            "stderr_step2": math.sqrt(entry["step2"]),
        }
        for part in PARTS + (SHARED,):
            if part in entry:
                row[f"{part}_%"] = 100.0 * entry[part] / total if total > 0 else 0.0
        rows.append(row)
    return rows


def _draw(rng, mean, cov, names, n_draws, cls):
    """Medium parameter draws from N(mean, cov), redrawing those outside the model's bounds:
    (draws, how many were redrawn)."""
    chol = np.linalg.cholesky(cov + 1e-300 * np.eye(len(names)))
    specs = [cls.param(n) for n in names]
    out = []
    tries = 0
    while len(out) < n_draws:
        tries += 1
        if tries > 100 * n_draws:
            raise FitError(
                "the medium's distribution lies mostly outside the parameter "
                "bounds: draws cannot be made"
            )
        d = mean + chol @ rng.standard_normal(len(names))
        try:
            for s, v in zip(specs, d):
                s.check(float(v), "medium")
        except ValueError:
            continue
        out.append(d)
    return np.array(out), tries - n_draws


def curve_stderr(
    result: FitResult, angles, channel: str | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """f_r of a fitted BRDF at canonical ``angles`` and its standard error per configuration,
    the result's covariance (the total one when it has it) through f_r's exact Jacobian:
    se_k^2 = J_k Cov J_k^T (of a joint fit, the target's f_r and the block of its
    parameters; of a fit over several channels, ``channel``'s f_r and its parameters). The
    error is None when the covariance is undetermined."""
    model = result.one_model(channel)
    if model.KIND != "brdf":
        raise InputTypeError(f"expected a BRDF result, got a {model.KIND} result ({result.model})")
    angles = tuple(np.asarray(a, dtype=float) for a in angles)
    values, jac = DirectModel(model, angles).value_and_jacobian(model.to_vector())
    found = result.covariance(total=True)
    if found is None:
        return values, None
    names, cov = found
    # a joint fit: the target's parameters (by their result names) out of all it fitted
    layout = result.target_names() if channel is None else (result.channels or {})[channel]
    own = {r: p for p, r in layout.items()}
    keep = [k for k, n in enumerate(names) if n in own]
    names, cov = [own[names[k]] for k in keep], cov[np.ix_(keep, keep)]
    order = type(model).param_names()
    j = jac[:, [order.index(n) for n in names]]
    var = np.einsum("ij,jk,ik->i", j, cov, j)
    return values, np.sqrt(np.maximum(var, 0.0))


def sample_propagation(
    target_result: FitResult,
    medium_result: FitResult,
    table,
    *,
    n_draws: int = 100,
    seed: int = 0,
    black=None,
    accuracy: str = ITERATION_ACCURACY,
    max_nfev: int | None = 50,
) -> dict:
    """Step 1's contribution by sampling: refit the target with the medium drawn from step 1's
    distribution (normal, natural units), each refit warm-started from the target fitted with
    the nominal medium by the same machinery (so the two differ only by the draw).

    Returns a dict with ``names`` (target parameters), ``medium_names``, ``draws``
    (n_draws, k), ``shifts`` (refit minus nominal refit, (n_draws, p)), ``linear`` (the
    linearization's prediction -A d theta_m for each draw), ``covariance`` (of the shifts),
    ``linear_covariance`` (A Cov_m A^T), ``converged`` (per draw) and ``redrawn`` (draws
    outside the model's bounds, drawn again: when many, the draws are a truncated normal,
    narrower than step 1's, and ``covariance`` is not the linear one's counterpart;
    docs/validity-model-error.md, "Step 1's uncertainty at m01").
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, int) or n_draws < 2:
        raise FitError(f"n_draws = {n_draws!r}; expected an integer >= 2")
    _check_pair(target_result, medium_result, None)
    theta = list(target_result.free)
    m_names, cov_m = covariance_of(medium_result)
    medium = cast("Medium", medium_result.one_model())
    base = session_problem(
        table,
        cast("BRDF", target_result.one_model()),
        medium,
        free=theta,
        black=black,
        what="target (in the medium)",
    )
    nominal = solve(base, base.values, max_nfev=max_nfev)
    x0 = nominal.x
    mapped = _medium_map(medium_result, m_names)
    a = sensitivity(base, x0, theta, mapped, accuracy)
    rng = np.random.default_rng(seed)
    mean = np.array([medium_result.params[n] for n in m_names])
    draws, redrawn = _draw(rng, mean, cov_m, m_names, n_draws, medium_result.model_class)
    it = [base.index(n) for n in theta]
    im = [base.index(n) for n in mapped]
    shift_rows, conv = [], []
    for d in draws:
        sub = base.with_fixed(dict(zip(mapped, d)))
        start = x0.copy()
        start[im] = d
        sol = solve(sub, start, max_nfev=max_nfev)
        shift_rows.append(sol.x[it] - x0[it])
        conv.append(sol.status > 0)
    shifts = np.array(shift_rows)
    linear = -(draws - mean) @ a.T
    return {
        "names": theta,
        "medium_names": m_names,
        "draws": draws,
        "shifts": shifts,
        "linear": linear,
        "covariance": np.cov(shifts, rowvar=False),
        "linear_covariance": a @ cov_m @ a.T,
        "converged": np.array(conv),
        "redrawn": redrawn,
    }


__all__ = [
    "propagate",
    "sample_propagation",
    "curve_stderr",
    "medium_parts",
    "covariance_of",
    "sensitivity",
    "budget_table",
    "PARTS",
    "SHARED",
]
