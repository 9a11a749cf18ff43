"""The solver of veil's fits (docs/fitting.md): every fit - a step of the two-step method, a
joint fit, a profile or refit of the diagnostics - is a :class:`veil.fitting.problem.Problem`
solved here, on the least-squares core it shares with the per-pixel maps
(:mod:`veil.fitting.least_squares`: the Levenberg-Marquardt step, damping, bounds, the
stopping rule, rank and covariance).

- :func:`solve`: Levenberg-Marquardt (:func:`veil.fitting.least_squares.levenberg_marquardt`)
  in the problem's internal coordinates (log, atanh or plain, :mod:`veil.fitting.coordinates`)
  within their bounds, with the engine's Jacobian (in a medium's parameters on its phase
  grids held: docs/engine.md "Derivatives"); it stops when the undamped Gauss-Newton step
  is below a tolerance in standard errors in every free parameter not held at a bound;
- :func:`run`: several starts (the next only while the fits so far are not convincing),
  iterations at the "fast" quadrature, then a polish at the requested one with the fast
  Jacobian frozen at the fast solution (a chord method: it differs from the polish rule's
  Jacobian by that rule's ~0.3 % error, so the polish converges to the optimum of the
  requested rule);
- :func:`covariance`: (J^T W J)^-1 of the free parameters from the fast Jacobian at the
  solution (:func:`veil.fitting.least_squares.covariance`: columns equilibrated first,
  natural units span many decades), scaled by the reduced chi-square for unweighted data;
- :func:`summarize`: goodness of fit, standard errors and correlations, and the notes of a
  result: parameters at the edge of their search range, a singular Jacobian, data that
  cannot determine the model (which then never reads "converged").

The tolerances, in standard errors (the stopping rule of :mod:`veil.fitting.least_squares`):
:data:`TOL_ITER` = 1e-2 for the iterations at "fast" before a polish and the sigma-point
refits of :mod:`veil.fitting.propagation` (scipy's relative cost change of 1e-6 at n_points /
2); :data:`TOL_POLISH` = 1e-2, as the polish's frozen fast Jacobian leaves a Gauss-Newton step
of its own error (1e-3 to 1e-2 standard errors) at the optimum; :data:`TOL_FINAL` = 1e-4 for
every other run (f_r alone, fits at "fast", profiles). Against each run's exact optimum
(bench_fit.py's and bench_joint.py's sessions, central-difference Jacobians) the runs at
TOL_FINAL end within 1e-4 standard errors, those at TOL_ITER within 3e-3, the polished
estimates 0.9 to 7 % of one (the chord method sets that). A medium's fits, whose Jacobian
holds the phase grids (docs/engine.md "Derivatives"), end within 0.05 standard errors of the
fast rule's optimum and 0.061 of the default rule's (benchmarks/bench_optimum.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import FitError, InputError
from . import coordinates
from . import least_squares as lsq
from .problem import ITERATION_ACCURACY, Problem
from .undetermined import held_covariance, no_signal, silent_blocks

#: Stopping tolerances in standard errors: iterations, polish, every other run (module docstring).
TOL_ITER = 1e-2
TOL_POLISH = 1e-2
TOL_FINAL = 1e-4
#: The quick fits that screen candidates (:mod:`veil.fitting.screening`): a step of 0.3
#: standard errors (of the noise, or of the misfit where the reduced chi-square is above 1)
#: leaves the deviance about 0.1 above its minimum, far inside the screen's margin.
TOL_SCREEN = 0.3
#: Reduced chi-square up to which a converged weighted fit inside its search range makes
#: further starts unnecessary.
CONVINCING = 2.0
#: Deviance (2 x cost) within which two converged runs found one minimum (:func:`agreeing`):
#: a quarter of the ranking's close call, veil.fitting.selection.CLOSE_DELTA_BIC.
AGREEMENT = 0.5
#: Note of a result whose Jacobian is singular at the solution.
SINGULAR_NOTE = "Jacobian singular at the solution: uncertainties not determined"


# --------------------------------------------------------------------------------------
# options
# --------------------------------------------------------------------------------------
def check_max_nfev(max_nfev) -> None:
    """A FitError unless ``max_nfev`` is a positive integer or None."""
    if max_nfev is not None and (
        isinstance(max_nfev, bool) or not isinstance(max_nfev, int) or max_nfev < 1
    ):
        raise FitError(f"max_nfev = {max_nfev!r}; expected a positive integer or None")


def as_fixed(fixed) -> dict:
    """The ``fixed=`` argument of the fits as a new dict ({} for None); a FitError for
    anything but a dict."""
    if fixed is None:
        return {}
    if not isinstance(fixed, dict):
        raise FitError(f"fixed = {fixed!r}; expected a dict such as {{'eta': 1.5}}")
    return dict(fixed)


def check_fixed(name: str, value, param, owner: str) -> None:
    """A FitError unless ``value``, the fixed value of parameter ``name``, is a number inside
    the bounds of ``param`` (a :class:`veil.models.Param`; ``owner`` names it in the error)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise FitError(f"fixed {name} = {value!r} is not a number")
    try:
        param.check(float(value), owner)
    except InputError as exc:
        raise FitError(f"fixed {exc}") from None


def ticker(progress, stage: str) -> Callable[..., None]:
    """A callback for each evaluation of a least-squares run: calls progress(stage, n, None)
    at the n-th call (nothing when ``progress`` is None or false)."""
    count = 0

    def tick():
        nonlocal count
        count += 1
        if progress:
            progress(stage, count, None)

    return tick


# --------------------------------------------------------------------------------------
# one run
# --------------------------------------------------------------------------------------
@dataclass
class Solution:
    """A least-squares solution of a :class:`Problem` (natural ``x``, full vector)."""

    x: np.ndarray
    cost: float
    status: int
    message: str
    nfev: int
    njev: int
    at_bound: list
    at_lower: list = field(default_factory=list)

    def stats(self, **extra) -> dict:
        return {
            "nfev": self.nfev,
            "njev": self.njev,
            "status": self.status,
            "cost": self.cost,
            **extra,
        }


def solve(
    problem: Problem,
    x0,
    *,
    accuracy: str = ITERATION_ACCURACY,
    tol=None,
    max_nfev=None,
    jacobian_at=None,
    on_eval=None,
) -> Solution:
    """Weighted least squares from natural start ``x0`` by Levenberg-Marquardt
    (:func:`veil.fitting.least_squares.levenberg_marquardt`): values at ``accuracy``,
    Jacobians at the "fast" quadrature, recomputed at every point taken, or frozen at the
    natural parameters ``jacobian_at`` (the polish's chord method); ``tol`` (standard errors)
    defaults to TOL_FINAL, ``max_nfev`` to 100 evaluations per free parameter; ``on_eval`` is
    called at every evaluation of the values."""
    tol = TOL_FINAL if tol is None else tol
    u0 = problem.to_u(x0)
    lo, hi = problem.bounds(u0)
    base = problem.values  # fixed parameters keep their values
    evaluated: dict = {}

    def fun(u):
        x, _ = problem.to_x(u, base)
        if on_eval:
            on_eval()
        val = problem.model_values(x, accuracy)
        evaluated[x.tobytes()] = val
        return np.concatenate([(val - problem.y) * problem.w, problem.prior_rows(x)[0]])

    def jac(u):
        x, d = problem.to_x(u, base)
        at = x if jacobian_at is None else jacobian_at
        _, full = problem.value_and_jacobian(at, ITERATION_ACCURACY, problem.free)
        full = np.concatenate([full * problem.w[:, None], problem.prior_rows(x)[1]])
        return full[:, problem.free] * d[None, :]

    yw = problem.y * problem.w
    fit = lsq.levenberg_marquardt(
        fun,
        jac,
        u0,
        lo,
        hi,
        tol=tol,
        max_nfev=max_nfev,
        yy=float(yw @ yw),
        dof=problem.n_points - problem.n_free,
        weighted=problem.weighted,
        exact=jacobian_at is None,
    )
    x, _ = problem.to_x(fit.p, base)
    problem.remember(x, accuracy, evaluated.get(x.tobytes()))
    low, high = lsq.at_bounds(fit.p, lo, hi, coordinates.EDGE * np.maximum(hi - lo, 1e-300))
    names = problem.free_names
    return Solution(
        x=x,
        cost=fit.cost,
        status=fit.status,
        message=fit.message,
        nfev=fit.nfev,
        njev=fit.njev,
        at_bound=[n for n, a, b in zip(names, low, high) if a or b],
        at_lower=[n for n, a in zip(names, low) if a],
    )


def convincing(problem: Problem, sol: Solution) -> bool:
    """A weighted fit that converged inside its search range with reduced chi-square <=
    CONVINCING: further starts are unnecessary (a second minimum of similar cost is what
    veil.analysis.diagnostics' profiles look for)."""
    dof = problem.n_points - problem.n_free
    return (
        sol.status > 0
        and problem.weighted
        and dof > 0
        and 2 * sol.cost / dof <= CONVINCING
        and not sol.at_bound
    )


def agreeing(problem: Problem, runs: list) -> bool:
    """Two runs (from different starts) of a weighted fit that converged with reduced
    chi-square <= CONVINCING to costs within AGREEMENT: the same minimum, even at a bound
    (where :func:`convincing` asks for another start)."""
    dof = problem.n_points - problem.n_free
    if not problem.weighted or dof <= 0:
        return False
    costs = sorted(2 * r.cost for r in runs if r.status > 0 and 2 * r.cost / dof <= CONVINCING)
    return any(b - a <= AGREEMENT for a, b in zip(costs, costs[1:]))


# --------------------------------------------------------------------------------------
# several starts and the polish
# --------------------------------------------------------------------------------------
@dataclass
class Outcome:
    """What :func:`run` found: the ``solution``, the model ``values`` there at the requested
    accuracy, the ``notes`` of its message and the ``stats`` of every run."""

    solution: Solution
    values: np.ndarray
    accuracy: str | None
    notes: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)


def start_vector(problem: Problem, named: dict, source: str = "start") -> np.ndarray:
    """The problem's natural vector with every free parameter at ``named`` {problem name:
    value} (a fit to continue from: docs/fitting.md "Starting values"); the held ones keep
    their values. A FitError names a free parameter ``named`` lacks, or a value that is not
    finite or outside its parameter's bounds."""
    x = problem.values.copy()
    for k in np.flatnonzero(problem.free):
        slot = problem.params[k]
        if slot.name not in named:
            raise FitError(
                f"{source} has no value of {slot.name!r}: give a fit of the same model, "
                f"sessions and channels"
            )
        value = float(named[slot.name])
        if not (math.isfinite(value) and slot.spec.contains(value)):
            raise FitError(f"{source}: {slot.name} = {value!r} is outside {slot.spec.interval()}")
        x[k] = value
    return x


def linear_free(problem: Problem) -> None:
    """A FitError when the problem would fit a linear family's coefficients iteratively:
    such a family (``LINEAR``, docs/nonparametric.md) is fitted by one linear solve in a
    step fit of one session and one channel, and held everywhere else."""
    for b in problem.blocks:
        if type(b.brdf).LINEAR and any(problem.free[k] for k in b.ib):
            raise FitError(
                f"{b.brdf.NAME} is fitted by linear least squares in a step fit of one session "
                f"and one channel (veil fit reference, target, direct, pipeline); a joint fit, "
                f"a fit over several channels and a map hold it given (docs/nonparametric.md)"
            )


def _starts_run(problem: Problem, starts: list, more, every: bool, tol, max_nfev, progress):
    """(the runs of :func:`run`, the number of starts skipped): the next start only while
    no run convinces and no two agree (all when ``every``); ``more()`` adds starts once."""
    runs: list[Solution] = []
    skipped = s = 0
    while True:
        if (
            runs
            and not every
            and (any(convincing(problem, r) for r in runs) or agreeing(problem, runs))
        ):
            skipped = len(starts) - s
            break
        if s == len(starts) and more is not None:
            starts, more = starts + list(more()), None
        if s == len(starts):
            break
        tick = ticker(progress, f"start {s + 1}/{len(starts)}: iteration")
        runs.append(solve(problem, starts[s], tol=tol, max_nfev=max_nfev, on_eval=tick))
        s += 1
    return runs, skipped


def run(
    problem: Problem,
    starts,
    *,
    accuracy: str = "default",
    max_nfev=None,
    progress=None,
    every: bool = False,
    screen: bool = False,
    more: Callable[[], list] | None = None,
) -> Outcome:
    """Least squares from each natural start vector (best first): all of them when
    ``every``, else the next only while none convinces and no two agree; ``more()``
    gives further starts after ``starts``, asked for only when they are needed (a fit
    continued from a candidate's quick fit: the grid's starts). The best is polished at
    ``accuracy`` when the problem has a medium (module docstring). A ``screen`` runs the
    first start only, at the "fast" quadrature to TOL_SCREEN, unpolished: a candidate's
    quick fit for ranking (:mod:`veil.fitting.screening`); a converged one's values are then
    evaluated at ``accuracy`` (where its full fit would end; in clear water the same rule):
    ``stats["rule_error"]``, that rule's values minus the fast rule's."""
    linear_free(problem)
    through_medium = any(b.medium is not None for b in problem.blocks)
    starts = list(starts)
    check = accuracy  # a screen's rule error is measured at the rule asked for
    if screen:  # the first start only
        if not starts and more is not None:
            starts = list(more())
        starts, accuracy, every, more = starts[:1], ITERATION_ACCURACY, False, None
    polish = through_medium and accuracy != ITERATION_ACCURACY
    tol = TOL_SCREEN if screen else (TOL_ITER if polish else TOL_FINAL)
    runs, skipped = _starts_run(problem, starts, more, every, tol, max_nfev, progress)
    if not runs:
        raise FitError("no starting point: the starting grid gave no finite cost")
    best = min(range(len(runs)), key=lambda r: (runs[r].cost, r))
    sol = runs[best]
    run_stats = [r.stats() for r in runs]
    notes = []
    final_accuracy = accuracy if through_medium else None
    if polish:
        if sol.status <= 0:
            notes.append(
                f"iterations at {ITERATION_ACCURACY!r} accuracy stopped early ({sol.message})"
            )
        tick = ticker(progress, f"polish at {accuracy!r}: iteration")
        sol = solve(
            problem,
            sol.x,
            accuracy=accuracy,
            tol=TOL_POLISH,
            max_nfev=max_nfev,
            jacobian_at=sol.x if sol.status > 0 else None,
            on_eval=tick,
        )
        run_stats.append(sol.stats(polish=True))
    values = problem.model_values(sol.x, accuracy if through_medium else ITERATION_ACCURACY)
    stats = {
        "starts": len(runs),
        "starts_skipped": skipped,
        "best_start": best + 1,
        "nfev": sum(r["nfev"] for r in run_stats),
        "njev": sum(r["njev"] for r in run_stats),
        "runs": run_stats,
        "configurations": problem.n_points,
    }
    if screen:
        stats["screen"] = True
        use = sol.status > 0  # a converged one's; undetermined: nothing more read
        if use and through_medium:
            use = not _undetermined(problem, sol, covariance(problem, sol.x, values=values))[0]
        if use:
            at = values if check == ITERATION_ACCURACY else problem.model_values(sol.x, check)
            stats["rule_error"] = {"accuracy": check, "values": (at - values).tolist()}
    if through_medium:
        stats["engine_calls"] = problem.engine_calls()
    return Outcome(sol, values, final_accuracy, notes, stats)


def began_at_grid(result) -> bool:
    """Whether a fit result ran its grid's best start (:func:`run_from` marks a fit begun
    from a given start ``stats["start"] = "given"``)."""
    return result.stats.get("start") != "given"


def check_start_family(result, name: str) -> None:
    """A FitError when the fit ``result`` to start from is not of the family ``name``."""
    if result.model != name:
        raise FitError(f"start: a {result.model} result; this fit's model is {name}")


def run_from(problem: Problem, start, ran_best: bool, grid: Callable[[], list], **kw) -> Outcome:
    """:func:`run` from the natural vector ``start`` (a fit to continue from), the starts of
    ``grid()`` after it only when it does not convince, without the grid's best one when
    ``ran_best`` (the start is a fit that began there); ``stats["start"]`` = "given". Without
    a start, :func:`run` from ``grid()``. ``kw`` as :func:`run`'s."""
    if start is None:
        return run(problem, [], more=grid, **kw)
    outcome = run(problem, [start], more=(lambda: grid()[1:]) if ran_best else grid, **kw)
    outcome.stats["start"] = "given"
    return outcome


# --------------------------------------------------------------------------------------
# the solution's statistics
# --------------------------------------------------------------------------------------
def goodness(
    y: np.ndarray, w: np.ndarray, values: np.ndarray, n_free: int
) -> tuple[np.ndarray, float, float]:
    """(residuals (y - values) * w, reduced chi-square sum(residuals^2) / (points - n_free),
    rms of the relative residuals (y - values) / values over nonzero values, nan if none)."""
    res = (y - values) * w
    chi2 = float(res @ res) / max(y.size - n_free, 1)
    nonzero = values != 0
    rel = (y[nonzero] - values[nonzero]) / values[nonzero]
    rms_rel = float(np.sqrt(np.mean(rel**2))) if rel.size else float("nan")
    return res, chi2, rms_rel


def weighted_jacobian(problem: Problem, x, accuracy: str = ITERATION_ACCURACY) -> np.ndarray:
    """d residuals / d free natural parameters (with prior rows)."""
    _, full = problem.value_and_jacobian(x, accuracy, problem.free)
    return np.concatenate([full * problem.w[:, None], problem.prior_rows(x)[1]])[:, problem.free]


def covariance(
    problem: Problem, x, accuracy: str = ITERATION_ACCURACY, values=None
) -> np.ndarray | None:
    """Covariance (natural units) of the free parameters at ``x`` (module docstring;
    :func:`veil.fitting.least_squares.covariance`); None when the Jacobian is singular.
    Unweighted data scale it by the reduced chi-square of ``values`` (the reported model
    values; by default the model at ``accuracy``)."""
    cov, full = lsq.covariance(weighted_jacobian(problem, x, accuracy))
    if not full:
        return None
    if not problem.weighted:
        val = problem.model_values(x, accuracy) if values is None else values
        res = (problem.y - val) * problem.w
        cov = cov * float(lsq.residual_variance(res, problem.n_points - problem.n_free))
    return cov


def undetermined_parameters(problem: Problem, x, accuracy: str = ITERATION_ACCURACY) -> list:
    """Free parameters the data do not determine at ``x``: those the data do not depend on
    at all, and those that take part in a direction of the (equilibrated) Jacobian's null
    space."""
    jw = weighted_jacobian(problem, x, accuracy)
    names = problem.free_names
    dead = [n for n, c in zip(names, np.linalg.norm(jw, axis=0)) if not c > 0]
    if dead:
        return dead
    je, _, ok = lsq.equilibrate(jw)
    if not ok or je.shape[1] == 0:
        return list(names)
    _, s, vt = np.linalg.svd(je, full_matrices=False)
    weak = vt[s <= s[0] * lsq.SINGULAR] if np.all(np.isfinite(s)) else vt
    return [n for j, n in enumerate(names) if np.any(np.abs(weak[:, j]) > 0.1)]


def uncertainties(
    cov, names, free
) -> tuple[dict[str, float | None], dict[str, dict[str, float | None]]]:
    """(stderr dict over all names, correlation dict over the free ones) from a covariance
    of the free parameters (``free``: their indices into ``names``)."""
    stderr: dict[str, float | None] = {n: None for n in names}
    corr: dict[str, dict[str, float | None]] = {}
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    for j, i in enumerate(free):
        stderr[names[i]] = float(se[j])
    for a, i in enumerate(free):
        corr[names[i]] = {}
        for b, jdx in enumerate(free):
            den = se[a] * se[b]
            corr[names[i]][names[jdx]] = float(cov[a, b] / den) if den > 0 else None
    return stderr, corr


def covariance_matrix(stderr: dict, correlation: dict | None, names) -> np.ndarray | None:
    """The covariance of ``names`` from standard errors and correlations as
    :func:`uncertainties` writes them (a missing or None correlation is 0); None when a
    standard error is missing."""
    if not names or any(stderr.get(n) is None for n in names):
        return None
    s = np.array([stderr[n] for n in names], dtype=float)
    r = np.eye(len(names))
    for a, na in enumerate(names):
        for b, nb in enumerate(names):
            if a != b:
                v = (correlation or {}).get(na, {}).get(nb)
                r[a, b] = 0.0 if v is None else v
    return r * np.outer(s, s)


@dataclass
class Summary:
    """Goodness of fit and uncertainties of an :class:`Outcome` (names: the problem's).
    ``undetermined`` names the free parameters the data cannot determine (empty when they
    can); ``covariance`` is then None, and so are their uncertainties (:func:`summarize`)."""

    residuals: np.ndarray
    chi2_reduced: float
    rms_relative: float
    covariance: np.ndarray | None
    stderr: dict
    correlation: dict
    converged: bool
    message: str
    determined: bool
    undetermined: list


def summarize(problem: Problem, outcome: Outcome, extra_notes=()) -> Summary:
    """The statistics and the message of a solution (module docstring). A fit whose data
    cannot determine its parameters - no positive value, a singular Jacobian, a scale at
    the floor of its search range - is "not determined" and never reads "converged". It
    reports no uncertainties, unless the only undetermined parameters are those of sessions
    without a signal (:mod:`veil.fitting.undetermined`): then the other parameters get theirs,
    with those held."""
    sol = outcome.solution
    res, chi2, rms_rel = goodness(problem.y, problem.w, outcome.values, problem.n_free)
    cov = covariance(problem, sol.x, values=outcome.values)
    why, which = _undetermined(problem, sol, cov)
    notes = list(outcome.notes) + list(extra_notes)
    edge = [n for n in sol.at_bound if n not in which]
    if edge:
        notes.append(f"{', '.join(edge)} at the edge of the search range (uncertainty unreliable)")
    stderr: dict[str, float | None] = {n: None for n in problem.names}
    corr: dict[str, dict[str, float | None]] = {}
    if why:  # the determined ones' from the rest, when only silent blocks' are not
        cov, silent = None, no_signal(problem)[1]
        if any(silent_blocks(problem)) and set(which) <= set(silent):
            part = held_covariance(problem, weighted_jacobian(problem, sol.x), which, res)
            if part is not None:
                stderr, corr = uncertainties(part[0], problem.names, part[1])
            else:
                notes.append(SINGULAR_NOTE)
    elif cov is None:
        notes.append(SINGULAR_NOTE)
    else:
        stderr, corr = uncertainties(cov, problem.names, problem.free_index)
    converged = sol.status > 0 and not why
    message = sol.message if not notes else sol.message + "; " + "; ".join(notes)
    if why:
        message = "not determined: " + "; ".join(why) + "; " + message
    elif not converged:
        message = "did not converge: " + message
    return Summary(res, chi2, rms_rel, cov, stderr, corr, converged, message, not why, which)


def _undetermined(problem: Problem, sol: Solution, cov) -> tuple[list[str], list[str]]:
    """(reasons why the data cannot determine the fit, the free parameters concerned); both
    empty when they can."""
    why, which = no_signal(problem)  # a silent block's own parameters
    if cov is None:
        found = undetermined_parameters(problem, sol.x)
        why.append(
            f"the data do not constrain "
            f"{', '.join(found) or 'a combination of the free parameters'} (the "
            f"Jacobian's rank is below the {problem.n_free} free parameters, so their "
            f"uncertainties are not determined)"
        )
        which += found
    floor = [n for n in sol.at_lower if problem.params[problem.index(n)].scale]
    if floor:
        why.append(
            f"{', '.join(floor)} at the floor of the search range (the data ask for "
            f"a vanishing scale)"
        )
        which += floor
    return why, [n for n in problem.free_names if n in which]


__all__ = [
    "TOL_ITER",
    "TOL_POLISH",
    "TOL_FINAL",
    "CONVINCING",
    "AGREEMENT",
    "agreeing",
    "SINGULAR_NOTE",
    "check_max_nfev",
    "as_fixed",
    "check_fixed",
    "ticker",
    "Solution",
    "solve",
    "convincing",
    "Outcome",
    "run",
    "goodness",
    "weighted_jacobian",
    "covariance",
    "undetermined_parameters",
    "uncertainties",
    "Summary",
    "summarize",
]
