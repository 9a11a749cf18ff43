"""The step fit of a linear family (``LINEAR = True``: :mod:`veil.models.nonparametric`):
every coefficient enters the model linearly, so with the other model held the step is one
non-negative, regularized least-squares problem (docs/nonparametric.md).

- **Columns** (:func:`design`): the engine's values with one coefficient at 1 and the others
  at 0, through the given medium (or f_r directly in clear water): one column per free
  coefficient, one compiled program for all of them.
- **Columns at two rules** (:func:`solve`, docs/nonparametric.md "The fit"): at a rule
  finer than the iterations', every column is first made at the iterations' rule and the
  problem solved; the columns above 0 are then made at the finer rule and the problem
  solved again, until every column above 0 is the finer rule's. The values, residuals,
  degrees of freedom and covariance involve only those; the columns at 0 enter only the
  conditions that hold them there and the smoothness grid's scale, at the iterations' rule.
- **Solve** (:func:`solve`): minimize |W (X c - y)|^2 + lambda |D c|^2 over c >= 0, where D
  takes second differences of the lobe coefficients across the widths and first differences
  across the Fresnel nodes (``penalty``); scipy's NNLS on the stacked system.
- **Smoothness** (:func:`choose`): lambda minimizes generalized cross-validation,
  GCV = N RSS / (N - df)^2, over a fixed grid; df = trace of the hat matrix on the active set,
  the effective degrees of freedom that the BIC counts (``stats["effective_dof"]``).
- **Uncertainty**: the penalized estimator's sandwich covariance on the active set, scaled by
  the reduced chi-square when it exceeds 1 (the family's own misfit, and the scale of
  unweighted data); coefficients at 0 are held at the bound (in ``fixed``, and named in
  ``stats["at_bound"]``: the report says "at its bound", not "fixed"). A
  given fit's covariance is propagated to first order through the engine's exact
  derivative of the family's values in the given parameters, at the iterations' rule, as a
  parametric family's (:mod:`veil.fitting.propagation`). A fixed coefficient's part of the
  values and of the penalty moves to the right-hand side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls

from ..errors import FitError
from ..models.base import VARIANT_OPTION
from .problem import ITERATION_ACCURACY, Problem, session_problem
from .propagation import given_covariance
from .result import FitResult, model_entry
from .solver import goodness, uncertainties

#: The smoothness weights tried, relative to trace(X'WX) / trace(D'D).
LAMBDAS = tuple(10.0 ** (k / 4.0) for k in range(-40, 9))


@dataclass(frozen=True)
class LinearSolution:
    """A solved linear step: coefficients ``c`` of the free columns, the smoothness
    ``lam`` (absolute), effective degrees of freedom ``dof``, the ``gcv`` score, the
    covariance ``cov`` of the free coefficients (noise, scaled by the misfit when > 1), the
    model ``values``, the weighted residuals and the weighted columns ``xw``."""

    c: np.ndarray
    lam: float
    dof: float
    gcv: float
    cov: np.ndarray
    values: np.ndarray
    residuals: np.ndarray
    xw: np.ndarray
    #: the penalty over the free coefficients
    d: np.ndarray
    #: (X'WX + lam D'D)^-1 on the coefficients above 0 (None when there are none)
    inv: np.ndarray | None
    #: {rule: the number of columns computed at it} (:func:`solve`)
    rules: dict = field(default_factory=dict)


def penalty(cls, names: list[str]) -> np.ndarray:
    """Rows of D over the coefficients ``names`` (every one of the family's: a fixed
    coefficient's columns go to the right-hand side, :func:`solve`): second differences
    across the lobe widths (per Fresnel node), first differences across the Fresnel nodes
    (per width)."""
    rows = []
    grid = cls.lobe_grid()  # (K, M) parameter names
    k_count, m_count = len(grid), len(grid[0])
    for m in range(m_count):
        for k in range(1, k_count - 1):
            rows.append({grid[k - 1][m]: 1.0, grid[k][m]: -2.0, grid[k + 1][m]: 1.0})
    for k in range(k_count):
        for m in range(m_count - 1):
            rows.append({grid[k][m]: -1.0, grid[k][m + 1]: 1.0})
    out = [[row.get(n, 0.0) for n in names] for row in rows]
    return np.array(out, dtype=float).reshape(len(out), len(names))


def design(
    problem: Problem,
    accuracy: str,
    progress=None,
    only=None,
    fixed: bool = True,
    stage: str = "columns",
) -> tuple[np.ndarray, np.ndarray]:
    """(columns X (N, F) of the free coefficients, the fixed ones' part of the values (N,))
    at the problem's held parameters: one engine call per coefficient, each of the family's
    column model (``columns()``: a basis function alone, sampled as it needs) at
    ``accuracy``; with ``only`` (a mask over the free coefficients) those columns alone, the
    others 0; without ``fixed`` the fixed ones' part is not made (0). ``progress(stage,
    done, total)`` is told each column made."""
    block = problem.blocks[0]
    column_cls, vectors = type(block.brdf).columns()
    columns = session_problem(
        None,
        column_cls.template(),
        block.medium,
        free=[column_cls.param_names()[0]],
        data=block.data,
    )
    nb = len(column_cls.PARAMS)
    base = columns.values.copy()
    ib = np.asarray(block.ib)
    names = [problem.names[k] for k in ib]

    def column(name: str) -> np.ndarray:
        x = base.copy()
        x[:nb] = vectors[name]
        return columns.model_values(x, accuracy)

    free = [n for k, n in zip(ib, names) if problem.free[k]]
    held = np.zeros(problem.n_points)
    for k, n in zip(ib, names):
        if fixed and not problem.free[k] and problem.values[k] != 0.0:
            held = held + problem.values[k] * column(n)
    cols = []
    made, total = 0, len(free) if only is None else int(np.count_nonzero(only))
    for j, name in enumerate(free):
        if only is None or only[j]:
            cols.append(column(name))
            made += 1
            if progress:
                progress(stage, made, total)
        else:
            cols.append(np.zeros(problem.n_points))
    return np.stack(cols, axis=1), held


def nonnegative_solve(
    xw: np.ndarray,
    yw: np.ndarray,
    d: np.ndarray | None = None,
    lam: float = 0.0,
    dr: np.ndarray | None = None,
) -> np.ndarray:
    """c >= 0 minimizing |xw c - yw|^2 + lam |d c - dr|^2 (columns equilibrated; without
    ``d`` no penalty): scipy's NNLS on the stacked system, the fit's solve at each lambda
    (:func:`choose`) and the profile likelihood's refits (:mod:`veil.analysis.profiles`)."""
    if d is None:
        d, lam = np.zeros((0, xw.shape[1])), 0.0
    dr = np.zeros(d.shape[0]) if dr is None else dr
    a = np.concatenate([xw, math.sqrt(lam) * d])
    b = np.concatenate([yw, math.sqrt(lam) * dr])
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    try:
        coef, _ = nnls(a / scale, b, maxiter=50 * a.shape[1])
    except RuntimeError as exc:  # scipy: the iteration limit
        raise FitError(f"the non-negative least-squares solve did not converge ({exc})") from None
    return coef / scale


def penalized_covariance(
    xw: np.ndarray, d: np.ndarray, lam: float, c: np.ndarray, res: np.ndarray, weighted: bool
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """(covariance of ``c``, (X'WX + lam D'D)^-1 on the coefficients above 0 or None, the
    effective degrees of freedom): the penalized estimator's sandwich covariance
    inv X'WX inv on the coefficients above 0 (0 elsewhere), scaled by the reduced
    chi-square of the weighted residuals ``res`` (module docstring, "Uncertainty")."""
    active = c > 0
    cov = np.zeros((len(c), len(c)))
    if not active.any():
        return cov, None, 0.0
    dof, inv = _hat_trace(xw, d, lam, active)
    xa = xw[:, active]
    chi2_red = float(res @ res) / max(xw.shape[0] - dof, 1.0)
    scale = chi2_red if not weighted else max(chi2_red, 1.0)
    cov[np.ix_(active, active)] = (inv @ (xa.T @ xa) @ inv) * scale
    return cov, inv, dof


def _hat_trace(xw: np.ndarray, d: np.ndarray, lam: float, active: np.ndarray) -> tuple:
    """(trace of the hat matrix, inverse penalized normal matrix) on the ``active`` columns."""
    xa, da = xw[:, active], d[:, active]
    normal = xa.T @ xa + lam * (da.T @ da)
    inv = np.linalg.pinv(normal, rcond=1e-13, hermitian=True)
    return float(np.trace(inv @ (xa.T @ xa))), inv


def choose(
    xw: np.ndarray, yw: np.ndarray, d: np.ndarray, dr=None
) -> tuple[float, np.ndarray, float, float]:
    """(lambda, c, dof, gcv) minimizing GCV over :data:`LAMBDAS` (relative to the ratio of
    the traces of X'WX and D'D); the first of equal scores (the smoothest is listed last).
    ``dr``: the penalty's right-hand side (minus the fixed coefficients' differences)."""
    n = xw.shape[0]
    dr = np.zeros(d.shape[0]) if dr is None else dr
    unit = float(np.sum(xw * xw)) / max(float(np.sum(d * d)), 1e-300)
    best = None
    for rel in LAMBDAS:
        lam = rel * unit
        c = nonnegative_solve(xw, yw, d, lam, dr)
        active = c > 0
        dof, _ = _hat_trace(xw, d, lam, active) if active.any() else (0.0, None)
        rss = float(np.sum((xw @ c - yw) ** 2))
        score = n * rss / max(n - dof, 1e-9) ** 2
        if best is None or score < best[3]:
            best = (lam, c, dof, score)
    assert best is not None
    return best


def rule_error(problem: Problem, sol: LinearSolution, check: str, x: np.ndarray) -> dict:
    """A quick fit's model values at the rule ``check`` minus the fast rule's at its
    parameters ``x`` (``stats["rule_error"]``, :mod:`veil.fitting.screening`): the family
    evaluated at ``check`` as veil evaluates it through a medium, one engine call per lobe
    width in use (:class:`veil.engine.forward.LinearForward`), not the whole design."""
    if check == ITERATION_ACCURACY:  # the quick fit's own rule
        return {"accuracy": check, "values": [0.0] * problem.n_points}
    return {"accuracy": check, "values": (problem.model_values(x, check) - sol.values).tolist()}


def _check_held(problem: Problem, held: np.ndarray) -> None:
    """:func:`_overflow` when the fixed coefficients' part of the values, or its weighted
    misfit to the data times the number of points (GCV's scale), is not finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        misfit = float(np.sum(((problem.y - held) * problem.w) ** 2)) * problem.n_points
    if not (np.all(np.isfinite(held)) and math.isfinite(misfit)):
        _overflow(problem)


def _check_solution(problem: Problem, sol: LinearSolution) -> None:
    """:func:`_overflow` when anything the result reports is not finite (the penalty of a
    huge fixed coefficient, a misfit near float64's limit)."""
    with np.errstate(over="ignore", invalid="ignore"):
        rss = float(sol.residuals @ sol.residuals) * problem.n_points
    numbers = (rss, sol.gcv, sol.dof, sol.lam)
    if not (all(map(math.isfinite, numbers)) and np.all(np.isfinite(sol.values))):
        _overflow(problem)


def _overflow(problem: Problem) -> None:
    """A FitError naming the fixed coefficients whose values overflow float64 (or, with none
    fixed, the data's own weighted values)."""
    ib = problem.blocks[0].ib
    fixed = [k for k in ib if not problem.free[k] and problem.values[k] != 0.0]
    values = ", ".join(f"{problem.names[k]} fixed at {problem.values[k]:.4g}" for k in fixed)
    largest = float(np.max(np.abs(problem.y)))
    if not fixed:
        raise FitError(
            f"the data's values (the largest |value| is {largest:.4g}) divided by their "
            "sigma overflow float64 when squared and summed: rescale the table's values "
            "(relative units) or its sigma column"
        )
    raise FitError(
        f"with {values} the {type(problem.blocks[0].brdf).NAME} model's values, or their "
        f"weighted misfit to the data (the data's largest |value| is {largest:.4g}), "
        "overflow float64; the coefficients scale the model (relative units): fix them at "
        "smaller values (--fix NAME=VALUE, fixed={...} in Python) or leave them free"
    )


def _columns_at(problem: Problem, accuracy: str, d, dr, progress=None) -> tuple:
    """(X, held, (lambda, c, dof, gcv), {rule: columns computed at it}): the design at
    ``accuracy`` where it matters (module docstring, "Columns at two rules"). Every column at
    the iterations' rule first; those above 0 in its solution, then in each solution that
    follows, at ``accuracy``, until the solution's active set is all at ``accuracy``. The
    columns that stay at 0 keep the iterations' rule: they enter neither the values nor the
    degrees of freedom, only the conditions that keep them at 0."""
    w = problem.w
    if accuracy == ITERATION_ACCURACY or problem.blocks[0].medium is None:  # (f_r: no rule)
        x, held = design(problem, accuracy, progress)
        _check_held(problem, held)
        return (
            x,
            held,
            choose(x * w[:, None], (problem.y - held) * w, d, dr),
            {accuracy: x.shape[1]},
        )
    x, held = design(problem, ITERATION_ACCURACY, progress)
    _check_held(problem, held)
    counts = {ITERATION_ACCURACY: x.shape[1]}
    have = np.zeros(x.shape[1], dtype=bool)
    chosen = choose(x * w[:, None], (problem.y - held) * w, d, dr)
    fine_held = None
    passes = 0
    while True:
        new = (chosen[1] > 0) & ~have
        if fine_held is not None and not new.any():
            break
        passes += 1
        stage = f"columns at the {accuracy!r} rule, pass {passes}"
        # (the first pass also makes the fixed coefficients' part at ``accuracy``)
        fine, part = design(problem, accuracy, progress, new, fine_held is None, stage)
        fine_held = part if fine_held is None else fine_held
        x = np.where(new[None, :], fine, x)
        have |= new
        chosen = choose(x * w[:, None], (problem.y - fine_held) * w, d, dr)
    counts[accuracy] = int(have.sum())
    return x, fine_held, chosen, counts


def solve(problem: Problem, accuracy: str, d: np.ndarray, progress=None) -> LinearSolution:
    """The step's linear problem solved at ``accuracy`` (module docstring); ``d`` the
    penalty over every coefficient of the family, in order."""
    ib = np.asarray(problem.blocks[0].ib)
    free = problem.free[ib]
    d, dr = d[:, free], -d[:, ~free] @ problem.values[ib][~free]
    x, held, (lam, c, dof, gcv), counts = _columns_at(problem, accuracy, d, dr, progress)
    w = problem.w
    xw = x * w[:, None]
    values = x @ c + held
    res = (problem.y - values) * w
    cov, inv, _ = penalized_covariance(xw, d, lam, c, res, problem.weighted)
    return LinearSolution(c, lam, dof, gcv, cov, values, res, xw, d, inv, counts)


def given_influence(problem: Problem, sol: LinearSolution, names: list[str]) -> np.ndarray:
    """d c / d (given parameters ``names``) (F, G) on the active set, the solution held at
    its active set: -(X'WX + lam D'D)^-1 X'W^2 (d values / d given) (the Gauss-Newton
    form: the term in d X / d given times the residuals is left out), d values / d given
    the engine's Jacobian at the iterations' rule (one pass over the active groups)."""
    block = problem.blocks[0]
    free = [k for k in np.asarray(block.ib) if problem.free[k]]
    x = problem.values.copy()
    x[free] = sol.c
    active = sol.c > 0
    out = np.zeros((len(sol.c), len(names)))
    if sol.inv is None:
        return out
    cols = [problem.index(name) for name in names]
    _, full = problem.value_and_jacobian(x, ITERATION_ACCURACY, cols)
    dv = full[:, cols] * problem.w[:, None]
    out[active] = -sol.inv @ (sol.xw[:, active].T @ dv)
    return out


def _given_total(
    problem, sol, given_result, given_cov, propagation
) -> tuple[np.ndarray | None, dict]:
    """(the covariance with the given fit's (``given_cov``: names, matrix) propagated, stats
    on how) or (None, {})."""
    if given_cov is None or problem.blocks[0].medium is None or not (sol.c > 0).any():
        return None, {}
    names, cov_given = given_cov
    given_cls = type(given_result.one_model())
    keys = [given_cls.param(n).key for n in names]
    infl = given_influence(problem, sol, keys)
    how = {
        "method": "linear",
        "asked": propagation,
        "derivatives": f"the engine's Jacobian at the {ITERATION_ACCURACY!r} rule",
    }
    return sol.cov + infl @ np.asarray(cov_given) @ infl.T, how


def _named(cls, values: dict) -> dict:
    """A dict by slot name in the family's own names."""
    own = {p.key: p.name for p in cls.PARAMS}
    return {own[k]: values[k] for k in cls.keys()}


def _named_matrix(cls, rows: dict) -> dict:
    """A correlation dict (slot names) in the family's own names."""
    own = {p.key: p.name for p in cls.PARAMS}
    return {own[a]: {own[b]: r for b, r in row.items()} for a, row in rows.items()}


def _message(sol: LinearSolution, chi2: float, model_error: str) -> str:
    active = int(np.count_nonzero(sol.c))
    notes = [
        f"linear least squares: {active} of {len(sol.c)} coefficients above 0 (those at 0 "
        f"held at the bound), smoothness {sol.lam:.3g} by generalized cross-validation, "
        f"{sol.dof:.1f} effective degrees of freedom"
    ]
    if chi2 > 1:
        term = "" if model_error == "off" else " in place of a model-discrepancy term"
        notes.append(f"uncertainties scaled by the reduced chi-square{term}")
    return "; ".join(notes)


def _stats(problem: Problem, sol: LinearSolution, at_bound: list[str], how) -> dict:
    """The result's ``stats`` (docs/nonparametric.md "The fit"); ``at_bound`` the free
    coefficients the solve holds at 0 (in ``fixed`` with the user's, apart from them here);
    ``how`` the propagation's."""
    stats = {
        "effective_dof": sol.dof,
        "smoothness": sol.lam,
        "gcv": sol.gcv,
        "active": len(sol.c) - len(at_bound),
        "columns": len(sol.c),
        "at_bound": at_bound,
        "engine_calls": problem.engine_calls(),
        "columns_at_rule": dict(sol.rules),
    }
    if how:
        stats["propagation"] = how
    return stats


def _undetermined(problem: Problem, sol: LinearSolution) -> str | None:
    """Why the data cannot determine the coefficients (None when they can): no positive
    value, as a parametric family's "not determined" (:func:`veil.fitting.solver.summarize`).
    A FitError when the solution interpolates the points (less than one degree of freedom
    left: GCV degenerates on a handful of points), as a parametric fit with no more points
    than free parameters."""
    n, y = problem.n_points, problem.y
    if not np.any(y > 0):
        block = problem.blocks[0]
        return (
            f"session {block.session.name!r} has no positive value (all "
            f"{'zero' if np.all(y == 0) else 'zero or negative'}"
            f"{' after any black-cloth subtraction' if block.medium is not None else ''}): it "
            "carries no signal to fit the coefficients"
        )
    if n - sol.dof < 1.0 - 1e-6:  # (less than one left, beyond rounding)
        raise FitError(
            f"the {problem.blocks[0].session.name} data have {n} point(s) and the "
            f"non-parametric fit's smoothness (generalized cross-validation) takes "
            f"{sol.dof:.4g} effective degrees of freedom, less than one left: it "
            "interpolates them, and determines neither the lobes nor their uncertainties; "
            "need more points (measure more configurations) or a parametric family "
            "(--brdf-model)"
        )
    return None


def fit_linear(
    step: str,
    problem: Problem,
    fitted,
    given,
    given_result,
    *,
    accuracy: str,
    propagation: str,
    model_error: str = "off",
    progress=None,
    screen: bool = False,
) -> FitResult:
    """A linear family's step fit (module docstring) as a :class:`FitResult`; a ``screen``
    (a candidate's quick fit) uses the iterations' rule and propagates nothing."""
    cls = type(fitted)
    check = accuracy if screen else None
    accuracy = ITERATION_ACCURACY if screen else accuracy
    names = problem.names
    given_cov = None if screen else given_covariance(given_result, propagation)
    if given_cov is not None and problem.blocks[0].medium is not None:
        # the derivative in the medium's parameters (given_influence), compiled (or loaded)
        # in the background while the design is made
        problem.blocks[0].model(ITERATION_ACCURACY).prepare(values=False, jacobians=[("medium",)])
    sol = solve(problem, accuracy, penalty(cls, list(cls.keys())), progress)
    _check_solution(problem, sol)
    why = _undetermined(problem, sol)
    free_index = [k for k in problem.blocks[0].ib if problem.free[k]]
    x = problem.values.copy()
    x[free_index] = sol.c
    # the coefficients at 0 are held at the bound: in ``fixed``, no uncertainty, named in
    # stats["at_bound"] (the report's "at its bound", not the user's "fixed")
    held = [k for k, c in zip(free_index, sol.c) if c == 0.0]
    reported = [k for k in free_index if k not in held]
    keep = np.array([k not in held for k in free_index])
    res, _, rms = goodness(problem.y, problem.w, sol.values, 0)
    chi2 = float(res @ res) / max(problem.n_points - sol.dof, 1.0)
    stderr, corr = uncertainties(sol.cov[np.ix_(keep, keep)], names, reported)
    total, how = _given_total(problem, sol, given_result, given_cov, propagation)
    se_total, corr_total = (
        (None, None) if total is None else uncertainties(total[np.ix_(keep, keep)], names, reported)
    )
    own = {p.key: p.name for p in cls.PARAMS}
    stats = _stats(problem, sol, [own[names[k]] for k in held], how)
    if check is not None:  # f_r directly: the quick fit's own rule (no error)
        stats["rule_error"] = rule_error(problem, sol, check, x)
    free_keys = {names[k] for k in reported}
    return FitResult(
        model=cls.NAME,
        params=_named(cls, {k: float(x[problem.index(k)]) for k in cls.keys()}),
        stderr=_named(cls, stderr),
        correlation=_named_matrix(cls, corr),
        residuals=tuple(float(r) for r in res),
        chi2_reduced=chi2,
        rms_relative=rms,
        n_points=problem.n_points,
        converged=why is None,
        message=("" if why is None else f"not determined: {why}; ")
        + _message(sol, chi2, model_error),
        variant=None if given is None else given.options().get(VARIANT_OPTION),
        fixed={own[k]: float(x[problem.index(k)]) for k in cls.keys() if k not in free_keys},
        step=step,
        weighted=problem.weighted,
        accuracy=accuracy,
        given=None if given is None else model_entry(given),
        stderr_total=None if se_total is None else _named(cls, se_total),
        correlation_total=None if corr_total is None else _named_matrix(cls, corr_total),
        stats=stats,
        options=fitted.options(),
        determined=why is None,
        model_error=None,
    )


__all__ = [
    "fit_linear",
    "LinearSolution",
    "LAMBDAS",
    "penalty",
    "design",
    "nonnegative_solve",
    "penalized_covariance",
    "choose",
    "solve",
    "given_influence",
]
