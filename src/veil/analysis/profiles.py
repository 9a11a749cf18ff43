"""Profile likelihoods of a fit (docs/ambiguity.md "Identifiability diagnostics"): one
parameter held on a grid about its estimate, all others refitted; the rise of chi-square,
Delta chi^2, against the held value.

The refits are the solver's (:func:`veil.fitting.solver.solve`, warm starts walking
outward), or, when every free parameter is a coefficient of a linear family
(``LINEAR``, docs/nonparametric.md) with the other model held and no prior, one
non-negative least-squares solve on the family's columns (:class:`LinearRefit`): the
columns are made once, at the profiles' rule, and each refit solves the same bounded
problem exactly with no engine call.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import FitError
from ..fitting.linear_fit import design, nonnegative_solve
from ..fitting.problem import ITERATION_ACCURACY, Problem
from ..fitting.solver import solve

FLAT = 1.0  # Delta chi^2 below which a profile end counts as flat
#: Largest half-width of a profile grid in fit coordinates (log units for scale parameters,
#: atanh units for g, plain for indices); otherwise 3 standard errors.
MAX_SPAN = {"log": math.log(4.0), "atanh": 1.0, "plain": 0.5}
PROFILE_POINTS = 9


@dataclass
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

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "estimate": self.estimate,
            "values": self.values,
            "delta_chi2": self.delta_chi2,
            "interval": list(self.interval),
            "flat": self.flat,
            "converged": self.converged,
        }


class SolverRefit:
    """Refits by the solver, any family: ``cost(x)`` of the problem at natural ``x`` and
    ``refit(name, value, start)`` -> (x, cost, converged) with ``name`` held at ``value``."""

    def __init__(self, problem: Problem, accuracy: str, max_nfev: int = 30):
        self.problem, self.accuracy, self.max_nfev = problem, accuracy, max_nfev

    def cost(self, x: np.ndarray) -> float:
        val = self.problem.model_values(x, self.accuracy)
        r = np.concatenate([(val - self.problem.y) * self.problem.w, self.problem.prior_rows(x)[0]])
        return 0.5 * float(r @ r)

    def refit(self, name: str, value: float, start: np.ndarray) -> tuple[np.ndarray, float, bool]:
        sub = self.problem.with_fixed({name: value})
        sol = solve(sub, start, accuracy=self.accuracy, max_nfev=self.max_nfev)
        return sol.x, float(sol.cost), bool(sol.status > 0)


class LinearRefit:
    """Refits of a linear family's coefficients (module docstring): the weighted columns of
    the free coefficients at ``accuracy`` (:func:`veil.fitting.linear_fit.design`, the fixed
    ones' part on the right-hand side), made once; each refit an exact non-negative
    least-squares solve, as the solver's bounded problem (coefficients >= 0) without
    iterating. :meth:`of` says whether a problem is one."""

    def __init__(self, problem: Problem, accuracy: str, progress=None):
        x, held = design(problem, accuracy, progress)
        self.index = problem.free_index
        self.names = problem.free_names
        self.xw = x * problem.w[:, None]
        self.yw = (problem.y - held) * problem.w

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
        r = self.xw @ np.asarray(x)[self.index] - self.yw
        return 0.5 * float(r @ r)

    def refit(self, name: str, value: float, start: np.ndarray) -> tuple[np.ndarray, float, bool]:
        j = self.names.index(name)
        rest = np.arange(len(self.names)) != j
        c = nonnegative_solve(self.xw[:, rest], self.yw - value * self.xw[:, j])
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
) -> dict:
    """{name: profile likelihood} of the free parameters ``which``; ``progress(stage, done,
    total)`` is told each refit, the stage naming the parameter profiled."""
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
    refits: SolverRefit | LinearRefit = SolverRefit(problem, accuracy)
    if LinearRefit.of(problem):
        refits = LinearRefit(problem, accuracy, lambda s, d, t: say(f"profiles: {s}", d, t))
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
            stderr[n],
            points=points,
            scale=chi2_scale,
            accuracy=accuracy,
            refits=refits,
            on_point=tick,
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
) -> Profile:
    """Hold ``name`` on a grid about its estimate and refit the rest (``refits``: the
    solver's, at most ``max_nfev`` evaluations, warm starts walking outward, by default);
    Delta chi^2 = (chi^2 - chi^2_min) / ``scale``. The grid spans 3 standard errors each
    side in fit coordinates, at most :data:`MAX_SPAN`; ``on_point()`` after each refit."""
    refits = refits or SolverRefit(problem, accuracy, max_nfev)
    k = problem.index(name)
    p = problem.params[k]
    u_hat = p.to_u(x[k])
    _, dxdu = p.to_x(u_hat)
    se_u = stderr / dxdu if dxdu > 0 and math.isfinite(stderr) else math.inf
    span = min(3.0 * se_u, MAX_SPAN[p.coordinate])
    lo, hi = p.bounds(u_hat)
    half = points // 2
    grid_u = np.clip(u_hat + np.linspace(-span, span, 2 * half + 1), lo, hi)
    base_cost = refits.cost(x)
    chi2 = np.empty(grid_u.size)
    chi2[half] = 0.0
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
    )


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
]
