"""Profile likelihoods of a fit (docs/ambiguity.md "Identifiability diagnostics"): one
parameter held on a grid about its estimate, all others refitted; the rise of chi-square,
Delta chi^2, against the held value.

The refits are the solver's (:func:`veil.fitting.solver.solve`, warm starts walking
outward), or, when every free parameter is a coefficient of a linear family
(``LINEAR``, docs/nonparametric.md) with the other model held and no prior, one
non-negative solve on the family's columns (:class:`LinearRefit`): the columns are made
once, at the profiles' rule, and each refit solves the objective the fit minimized, with
the fit's smoothness penalty, exactly and with no engine call. Delta chi^2 is then
measured from that objective's own minimum on those columns, and the grid spans 3 of its
standard errors (the penalized normal matrix's) each side, clipped at the bound 0.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import FitError
from ..fitting.linear_fit import design, nonnegative_solve, penalized_covariance, penalty
from ..fitting.problem import ITERATION_ACCURACY, Problem
from ..fitting.solver import solve

FLAT = 1.0  # Delta chi^2 below which a profile end counts as flat
#: Largest half-width of a profile grid in fit coordinates (log units for scale parameters,
#: atanh units for g, plain for indices); otherwise 3 standard errors.
MAX_SPAN = {"log": math.log(4.0), "atanh": 1.0, "plain": 0.5}
PROFILE_POINTS = 9
#: A linear family's profile when the result does not record its smoothness.
NO_SMOOTHNESS = (
    "the result records no smoothness (stats 'smoothness', written by later versions): "
    "profiled without the penalty, an objective the estimate does not minimize; refit to "
    "profile the fit's own"
)


@dataclass(frozen=True)
class Profile:
    """Profile likelihood of one parameter: held ``values`` (natural), ``delta_chi2`` (in
    noise units; the reduced chi-square scales it for unweighted data), the 1-sigma
    ``interval`` where Delta chi^2 <= 1 (None on a side that never reaches 1), ``flat`` sides
    ("lower"/"upper") that stay below :data:`FLAT`, and whether every refit ``converged``."""

    name: str
    estimate: float
    values: list
    delta_chi2: list
    interval: tuple
    flat: list
    converged: bool
    #: what to know in reading it (a linear family's profile without its smoothness)
    note: str | None = None

    def to_dict(self) -> dict:
        out = {
            "name": self.name,
            "estimate": self.estimate,
            "values": self.values,
            "delta_chi2": self.delta_chi2,
            "interval": list(self.interval),
            "flat": self.flat,
            "converged": self.converged,
        }
        if self.note:
            out["note"] = self.note
        return out


class SolverRefit:
    """Refits by the solver, any family: ``cost(x)`` of the problem at natural ``x`` and
    ``refit(name, value, start)`` -> (x, cost, converged) with ``name`` held at ``value``."""

    def __init__(self, problem: Problem, accuracy: str, max_nfev: int = 30):
        self.problem, self.accuracy, self.max_nfev = problem, accuracy, max_nfev

    def cost(self, x: np.ndarray) -> float:
        val = self.problem.model_values(x, self.accuracy)
        r = np.concatenate([(val - self.problem.y) * self.problem.w, self.problem.prior_rows(x)[0]])
        return 0.5 * float(r @ r)

    def base(self, x: np.ndarray) -> float:
        """The level Delta chi^2 is measured from: the cost at the estimate ``x``."""
        return self.cost(x)

    def refit(self, name: str, value: float, start: np.ndarray) -> tuple[np.ndarray, float, bool]:
        sub = self.problem.with_fixed({name: value})
        sol = solve(sub, start, accuracy=self.accuracy, max_nfev=self.max_nfev)
        return sol.x, float(sol.cost), bool(sol.status > 0)


class LinearRefit:
    """Refits of a linear family's coefficients (module docstring): the weighted columns of
    the free coefficients at ``accuracy`` (:func:`veil.fitting.linear_fit.design`, the fixed
    ones' part on the right-hand side), made once; each refit an exact non-negative solve
    of the objective the fit minimized, |W (X c - y)|^2 + ``smoothness`` |D c|^2 with the
    family's penalty D (:func:`veil.fitting.linear_fit.penalty`; the fixed coefficients'
    differences on its right-hand side). ``bound``: the coefficients the fit's solve held at
    0 (``FitResult.at_bound``), free in every refit as they were in the fit, but neither
    profiled nor reported (``names`` are all the refits' coefficients, ``reported`` the
    problem's own free ones among them). Without ``smoothness`` (a result that does not
    record it) the objective is unpenalized. :meth:`of` says whether a problem is one."""

    def __init__(self, problem: Problem, accuracy: str, progress=None, smoothness=None, bound=()):
        wide = problem.with_freed(bound)
        x, held = design(wide, accuracy, progress)
        self.index = wide.free_index
        self.names = wide.free_names
        self.reported = np.isin(self.index, problem.free_index)
        self.xw = x * problem.w[:, None]
        self.yw = (problem.y - held) * problem.w
        self.weighted = problem.weighted
        self.smoothness = None if smoothness is None else float(smoothness)
        self.lam = self.smoothness or 0.0
        block = wide.blocks[0]
        cls = type(block.brdf)
        ib = np.asarray(block.ib)
        free = wide.free[ib]
        d = penalty(cls, list(cls.keys()))
        self.d, self.dr = d[:, free], -d[:, ~free] @ wide.values[ib][~free]

    @staticmethod
    def of(problem: Problem) -> bool:
        """Whether every free parameter of ``problem`` is a coefficient of a linear family,
        in one session, with no prior (the values then linear in them)."""
        if problem.prior is not None or len(problem.blocks) != 1:
            return False
        block = problem.blocks[0]
        return bool(type(block.brdf).LINEAR) and set(problem.free_index) <= {
            int(k) for k in block.ib
        }

    def cost(self, x: np.ndarray) -> float:
        """Half the objective at natural ``x``."""
        return self._half_objective(np.asarray(x)[self.index])

    def _half_objective(self, c: np.ndarray) -> float:
        r, q = self.xw @ c - self.yw, self.d @ c - self.dr
        return 0.5 * float(r @ r + self.lam * (q @ q))

    @functools.cached_property
    def minimum(self) -> float:
        """Half the objective's minimum over every free coefficient (>= 0), on these
        columns (one solve, whichever parameter is profiled)."""
        return self._half_objective(nonnegative_solve(self.xw, self.yw, self.d, self.lam, self.dr))

    def base(self, x: np.ndarray) -> float:
        """The level Delta chi^2 is measured from: the objective's :attr:`minimum` (>= 0 by
        construction), the estimate ``x``'s own where it is that minimum (the same rule)."""
        return self.minimum

    def covariance(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(the fit's covariance of the reported coefficients at ``x``, the penalized normal
        matrix's inverse (X'WX + lam D'D)^-1 in noise units): the first as the family's
        fit reports it (:func:`veil.fitting.linear_fit.penalized_covariance`, the sandwich),
        the second the curvature of the profiled objective (0 where a coefficient is 0)."""
        c = np.asarray(x, dtype=float)[self.index]
        res = self.yw - self.xw @ c
        cov, inv, _ = penalized_covariance(self.xw, self.d, self.lam, c, res, self.weighted)
        full = np.zeros_like(cov)
        if inv is not None:
            full[np.ix_(c > 0, c > 0)] = inv
        mine = np.ix_(self.reported, self.reported)
        return cov[mine], full[mine]

    def refit(self, name: str, value: float, start: np.ndarray) -> tuple[np.ndarray, float, bool]:
        j = self.names.index(name)
        rest = np.arange(len(self.names)) != j
        d, xw = self.d, self.xw
        c = nonnegative_solve(
            xw[:, rest], self.yw - value * xw[:, j], d[:, rest], self.lam, self.dr - value * d[:, j]
        )
        x = np.array(start, dtype=float)
        x[self.index[rest]] = c
        x[self.index[j]] = value
        return x, self.cost(x), True


def profiles(
    problem: Problem,
    x: np.ndarray,
    which: list,
    stderr: dict,
    points: int,
    accuracy: str,
    progress=None,
    refits: SolverRefit | LinearRefit | None = None,
) -> dict:
    """{name: profile likelihood} of the free parameters ``which``; ``progress(stage, done,
    total)`` is told each refit, the stage naming the parameter profiled. ``refits`` by
    default the solver's, or a linear family's columns (:meth:`LinearRefit.of`; then
    unpenalized: give a :class:`LinearRefit` with the fit's smoothness). A linear family's
    grid is in the profiled objective's own standard errors (the penalized normal matrix's,
    :meth:`LinearRefit.covariance`), not ``stderr``."""
    names = problem.free_names
    unknown = [n for n in which if n not in names]
    if unknown:
        raise FitError(
            f"cannot profile {', '.join(map(repr, unknown))}: the free "
            f"parameters are {', '.join(names)}"
        )
    say = progress or (lambda stage, done, total: None)
    chi2_scale = 1.0
    if not problem.weighted:
        dof = problem.n_points - len(names)
        res = (problem.y - problem.model_values(x, accuracy)) * problem.w
        chi2_scale = max(float(res @ res) / dof, 1e-300)
    if refits is None:
        refits = SolverRefit(problem, accuracy)
        if LinearRefit.of(problem):
            refits = LinearRefit(problem, accuracy, lambda s, d, t: say(f"profiles: {s}", d, t))
    spread, note = dict(stderr), None
    if isinstance(refits, LinearRefit):
        # the grid in the profiled objective's own standard errors (LinearRefit.covariance)
        inv = np.diag(refits.covariance(x)[1])
        spread.update({n: math.sqrt(max(v, 0.0) * chi2_scale) for n, v in zip(names, inv)})
        note = None if refits.smoothness is not None else NO_SMOOTHNESS
    total, done, out = len(which) * 2 * (points // 2), 0, {}
    for k, n in enumerate(which):
        stage = f"profile {k + 1}/{len(which)}: {n}"
        say(stage, done, total)

        def tick(stage: str = stage) -> None:
            nonlocal done
            done += 1
            say(stage, done, total)

        out[n] = profile_likelihood(
            problem,
            x,
            n,
            spread[n],
            points=points,
            scale=chi2_scale,
            accuracy=accuracy,
            refits=refits,
            on_point=tick,
            note=note,
        )
    return out


def profile_likelihood(
    problem: Problem,
    x: np.ndarray,
    name: str,
    stderr: float,
    *,
    points: int = PROFILE_POINTS,
    scale: float = 1.0,
    accuracy: str = ITERATION_ACCURACY,
    max_nfev: int = 30,
    refits: SolverRefit | LinearRefit | None = None,
    on_point: Callable[[], None] | None = None,
    note: str | None = None,
) -> Profile:
    """Hold ``name`` on a grid about its estimate and refit the rest (``refits``: the
    solver's, at most ``max_nfev`` evaluations, warm starts walking outward, by default);
    Delta chi^2 = (chi^2 - chi^2_min) / ``scale``, chi^2_min the refits' ``base``. The grid
    spans 3 standard errors each side in fit coordinates, at most :data:`MAX_SPAN` (a linear
    family's coefficient: no cap but the bound 0); ``on_point()`` after each refit."""
    refits = refits or SolverRefit(problem, accuracy, max_nfev)
    k = problem.index(name)
    p = problem.params[k]
    u_hat = p.to_u(x[k])
    _, dxdu = p.to_x(u_hat)
    se_u = stderr / dxdu if dxdu > 0 and math.isfinite(stderr) else math.inf
    span = min(3.0 * se_u, MAX_SPAN[p.coordinate])
    if math.isfinite(se_u) and _linear(problem, k):  # a coefficient: no cap but its bound 0
        span = 3.0 * se_u
    lo, hi = p.bounds(u_hat)
    half = points // 2
    grid_u = np.clip(u_hat + np.linspace(-span, span, 2 * half + 1), lo, hi)
    base_cost = refits.base(x)
    chi2 = np.empty(grid_u.size)
    chi2[half] = 0.0
    if isinstance(refits, LinearRefit):  # (0 where the estimate is the objective's minimum)
        chi2[half] = max(2.0 * (refits.refit(name, x[k], x)[1] - base_cost), 0.0) / scale
    converged = True
    for direction in (1, -1):
        start = x.copy()
        for j in range(half + direction, half + direction * (half + 1), direction):
            v, _ = p.to_x(grid_u[j])
            start[k] = v
            start, cost, ok = refits.refit(name, v, start)
            converged &= ok
            chi2[j] = max(2.0 * (cost - base_cost), 0.0) / scale
            if on_point:
                on_point()
    values = [float(p.to_x(u)[0]) for u in grid_u]
    flat = [side for side, c in (("lower", chi2[0]), ("upper", chi2[-1])) if c < FLAT]
    interval = (
        _crossing(values[: half + 1][::-1], chi2[: half + 1][::-1]),
        _crossing(values[half:], chi2[half:]),
    )
    return Profile(
        name=name,
        estimate=float(x[k]),
        values=values,
        delta_chi2=[float(c) for c in chi2],
        interval=interval,
        flat=flat,
        converged=bool(converged),
        note=note,
    )


def _linear(problem: Problem, k: int) -> bool:
    """Whether parameter ``k`` is a coefficient of a linear family (docs/nonparametric.md)."""
    return any(bool(type(b.brdf).LINEAR) and k in {int(i) for i in b.ib} for b in problem.blocks)


def _crossing(values, chi2):
    """First value (walking outward from the estimate) where Delta chi^2 reaches 1,
    interpolating sqrt(Delta chi^2) (linear in the value for a quadratic profile)."""
    for j in range(1, len(values)):
        if chi2[j] >= 1.0:
            a, b = math.sqrt(chi2[j - 1]), math.sqrt(chi2[j])
            t = (1.0 - a) / (b - a) if b > a else 1.0
            return float(values[j - 1] + t * (values[j] - values[j - 1]))
    return None


__all__ = [
    "Profile",
    "profiles",
    "profile_likelihood",
    "SolverRefit",
    "LinearRefit",
    "FLAT",
    "MAX_SPAN",
    "PROFILE_POINTS",
    "NO_SMOOTHNESS",
]
