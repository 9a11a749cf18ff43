"""How a given model's covariance reaches the fit that held it fixed (docs/model.md sec. 7;
docs/uncertainty.md, "Propagation"): step 1's medium into step 2's target, step 0's reference
into step 1's medium.

- **linear**: the estimate x solves J_w^T r_w(x, theta) = 0, so it moves by
  d x = S d theta, S = -J_w^+ J_w,theta (weighted), and the total is Cov + S Cov_theta S^T.
- **sigma points**: where the given parameters are uncertain by a large part of their own
  scale (:meth:`veil.models.Param.relative_error` above :data:`RELATIVE_LIMIT`; at optical
  depth 0.1 step 1 leaves tau at 0.11 +- 0.18) the first order is far off (docs/validity.md,
  "Step 1's uncertainty at m01"). The fit is then repeated with the given model at the 2n
  points u0 +- sqrt(n lambda_k) e_k of its covariance (eigenpairs lambda_k, e_k) in the
  coordinates u in which that uncertainty is relative - the logarithm of the value, or of
  the distance to the nearer bound (``error_scale``) - mapped back inside the bounds, and
  the second moment of the refitted estimates about the estimate at u0 (each point weighing
  1/2n) takes the place of S Cov_theta S^T. For a response linear in u it is the first
  order's exactly; it keeps the response's curvature and its asymmetry (a mean shift counts
  as error). Up to :data:`RELATIVE_MAX`: beyond, a parameter is not determined and the first
  order is kept with a note, as it is for a fit that did not converge (the refits would
  start about a point that is no optimum). The rule looks at the worst given parameter: all
  of them go through sigma points, or none (in a joint fit over several media too).
- **a joint fit** (:func:`media_part`) estimates the media with the objects: the first
  order's share of the media in the objects' covariance, A C_mm A^T, is replaced by the
  spread of the objects' estimate over refits with the media held at the sigma points of
  the fit's own media block.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..errors import FitError, InputError
from ..models import Param
from .coordinates import OPEN_MARGIN
from .problem import ITERATION_ACCURACY, Problem
from .solver import TOL_ITER, solve

#: The propagation methods: "auto" picks "sigma-points" when the worst given parameter's
#: relative uncertainty exceeds RELATIVE_LIMIT and not RELATIVE_MAX and the fit converged,
#: else "linear".
METHODS = ("auto", "linear", "sigma-points", "off")
#: Relative uncertainty (stderr over the value or over the room to the nearer bound) of a
#: given parameter above which "auto" propagates through sigma points.
RELATIVE_LIMIT = 0.25
#: ... and up to which: beyond, the parameter is not determined and the first order is kept
#: with a note (sigma points e^(sqrt(n) RELATIVE_MAX) times apart are not a spread to refit).
RELATIVE_MAX = 3.0
#: Eigenvalues of the given covariance (in u) below this fraction of the largest carry no
#: spread worth a refit; a point pulled back to less than MIN_REACH of its step is dropped
#: (dividing its shift by the fraction kept would magnify the refit's tolerance).
NEGLIGIBLE = 1e-12
MIN_REACH = 0.1
#: Function evaluations allowed to each refit at a sigma point.
REFIT_NFEV = 50


def check_method(method) -> str:
    """The propagation method (None: "auto"); a FitError for anything else."""
    method = "auto" if method is None else method
    if method not in METHODS:
        raise FitError(f"propagation = {method!r}; expected one of {', '.join(METHODS)}")
    return method


@dataclass(frozen=True)
class Axis:
    """The coordinate u of one given parameter in which its uncertainty is relative:
    "log" (u = ln x), "upper" (u = -ln(upper - x)), "lower" (u = ln(x - lower)) or "plain"."""

    kind: str
    spec: Param

    @classmethod
    def of(cls, spec: Param, value: float) -> Axis:
        lo, hi = spec.lower, spec.upper
        if spec.error_scale == "bound" and math.isfinite(lo) and math.isfinite(hi):
            kind = "upper" if hi - value <= value - lo else "lower"
            if min(hi - value, value - lo) <= 0:
                kind = "plain"
        elif (spec.log_scale or lo >= 0) and value > 0:
            kind = "log"
        else:
            kind = "plain"
        return cls(kind, spec)

    def to_u(self, x: float) -> float:
        if self.kind == "log":
            return math.log(x)
        if self.kind == "upper":
            return -math.log(self.spec.upper - x)
        if self.kind == "lower":
            return math.log(x - self.spec.lower)
        return float(x)

    def du_dx(self, x: float) -> float:
        if self.kind == "log":
            return 1.0 / x
        if self.kind == "upper":
            return 1.0 / (self.spec.upper - x)
        if self.kind == "lower":
            return 1.0 / (x - self.spec.lower)
        return 1.0

    def to_x(self, u: float) -> float:
        """The natural value of ``u`` (possibly outside the bounds: :meth:`inside`)."""
        s = self.spec
        if self.kind == "log":
            return math.exp(min(u, 700.0))
        if self.kind == "upper":
            return s.upper - math.exp(min(-u, 700.0))
        if self.kind == "lower":
            return s.lower + math.exp(min(u, 700.0))
        return float(u)

    def inside(self, x: float) -> bool:
        """``x`` within the bounds, an open bound kept
        :data:`veil.fitting.coordinates.OPEN_MARGIN` of the interval's width away."""
        s = self.spec
        width = s.upper - s.lower
        margin = OPEN_MARGIN * (width if math.isfinite(width) else 0.0)
        lo_ok = x > s.lower + margin if s.lower_open else x >= s.lower
        hi_ok = x < s.upper - margin if s.upper_open else x <= s.upper
        return bool(lo_ok and hi_ok)


def relative_uncertainty(specs, values, cov, names=None) -> dict:
    """{name: stderr relative to its scale} of the given parameters (``Param.relative_error``;
    None where that is not finite), keyed by ``names`` (default the parameters' own)."""
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    names = [p.name for p in specs] if names is None else names
    out = {}
    for n, p, v, s in zip(names, specs, values, se):
        r = p.relative_error(float(v), float(s))
        out[n] = r if math.isfinite(r) else None
    return out


def _worst(relative: dict) -> float:
    return max((math.inf if r is None else r for r in relative.values()), default=0.0)


def choose(method: str, relative: dict) -> str:
    """The method "auto" resolves to for these relative uncertainties (None: not finite):
    sigma points above :data:`RELATIVE_LIMIT` up to :data:`RELATIVE_MAX`, else the first
    order (beyond RELATIVE_MAX a parameter is not determined: points e^(sqrt(n) r) times
    its value apart say nothing a fit can use; :func:`how_of` notes it)."""
    if method != "auto":
        return method
    return "sigma-points" if RELATIVE_LIMIT < _worst(relative) <= RELATIVE_MAX else "linear"


def how_of(method: str, relative: dict, converged: bool = True) -> dict:
    """The record of a propagation: the chosen method, the relative uncertainties, the
    limit, and a note when "auto" kept the first order for an undetermined parameter or
    for a fit that did not ``converge`` (sigma points refit about an optimum it lacks)."""
    chosen = choose(method, relative)
    how = {"method": chosen, "relative_uncertainty": relative, "limit": RELATIVE_LIMIT}
    if method == "auto" and not converged and chosen == "sigma-points":
        how["method"] = "linear"
        how["fallback"] = (
            "uncertainty propagated to first order, only indicative: sigma points would "
            "refit about an optimum the fit has not reached"
        )
        return how
    if method == "auto" and _worst(relative) > RELATIVE_MAX:
        worst = max(relative, key=lambda n: math.inf if relative[n] is None else relative[n])
        size = (
            "not determined"
            if relative[worst] is None
            else f"uncertain by {relative[worst]:.3g} of its scale"
        )
        how["fallback"] = (
            f"{worst} {size} (over {RELATIVE_MAX:g}): its uncertainty "
            f"propagated to first order, which is then only indicative"
        )
    return how


def describe(how: dict, what: str) -> str:
    """One line for a result's message on how ``what`` (e.g. "the medium fit's covariance")
    entered; empty for the first order, which every total has unless said."""
    if how.get("fallback"):
        return how["fallback"]
    if how.get("method") != "sigma-points":
        return ""
    rel = how["relative_uncertainty"]
    worst = max(rel, key=lambda n: math.inf if rel[n] is None else rel[n])
    size = "undetermined" if rel[worst] is None else f"{rel[worst]:.2f} of its scale"
    return (
        f"{what} propagated through {how['refits']} refits at "
        f"{how['points']} sigma points ({how['converged']} converged; {worst} uncertain "
        f"by {size}, limit {how['limit']:g})"
    )


def _reach(axes, u0, step) -> float:
    """The largest t in [0, 1] with u0 + t step inside every parameter's bounds (bisection;
    each coordinate is monotone in t and the bounds are intervals)."""

    def ok(t):
        return all(a.inside(a.to_x(float(v))) for a, v in zip(axes, u0 + t * step))

    if ok(1.0):
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def sigma_points(specs, values, cov) -> tuple[np.ndarray, np.ndarray]:
    """(points, reach): the 2n given-parameter vectors (natural units) at u0 +- sqrt(n
    lambda_k) e_k (module docstring), the + and - point of each direction side by side, and
    the fraction of its step each keeps to stay inside the bounds (1: all of it; a point
    that would leave them is pulled back along its direction, e.g. omega fitted at its bound
    1). Directions with a negligible lambda_k (:data:`NEGLIGIBLE`) are left out: they carry
    no spread, and the moment still weighs each point 1/2n with n the full dimension."""
    values = np.asarray(values, dtype=float)
    axes = [Axis.of(p, float(v)) for p, v in zip(specs, values)]
    d = np.array([a.du_dx(float(v)) for a, v in zip(axes, values)])
    cov_u = cov * np.outer(d, d)
    lam, vec = np.linalg.eigh(cov_u)
    n = len(values)
    u0 = np.array([a.to_u(float(v)) for a, v in zip(axes, values)])
    points, reach = [], []
    for k in range(n):
        if lam[k] <= NEGLIGIBLE * max(float(lam.max()), 0.0):
            continue
        for sign in (1.0, -1.0):
            step = sign * math.sqrt(n * lam[k]) * vec[:, k]
            t = _reach(axes, u0, step)
            points.append([a.to_x(float(v)) for a, v in zip(axes, u0 + t * step)])
            reach.append(t)
    return np.array(points).reshape(-1, n), np.array(reach)


def _weighted_columns(problem: Problem, x, cols: list[int]):
    """(J_w of the free parameters, J_w,theta of the given parameters in problem columns
    ``cols``), the data's rows."""
    _, full = problem.value_and_jacobian(
        x, ITERATION_ACCURACY, list(problem.free_index) + list(cols)
    )
    w = problem.w[:, None]
    return full[:, problem.free] * w, full[:, cols] * w


def sensitivity(problem: Problem, x, cols: list[int]) -> np.ndarray:
    """S = d x / d theta = -J_w^+ J_w,theta (free parameters x the given parameters in
    problem columns ``cols``; module docstring)."""
    jw, jg = _weighted_columns(problem, x, cols)
    return -np.linalg.lstsq(jw, jg, rcond=None)[0]


def given_jacobian(problem: Problem, x, cols: list[int]) -> np.ndarray:
    """J_w,theta: the weighted residual model's derivative in the given parameters in
    problem columns ``cols`` (points x parameters)."""
    return _weighted_columns(problem, x, cols)[1]


def linear_part(problem: Problem, x, cols: list[int], cov_given) -> np.ndarray:
    """S Cov_theta S^T (module docstring) for the given parameters in problem columns
    ``cols``."""
    sens = sensitivity(problem, x, cols)
    return sens @ cov_given @ sens.T


@dataclass(frozen=True)
class Refits:
    """The sigma-point part (module docstring) and what it took: the points (natural units of
    the given parameters), the refitted free parameters' shifts from the estimate at u0 (one
    row per point), how many refits were made and how many of them converged."""

    covariance: np.ndarray
    points: np.ndarray
    shifts: np.ndarray
    converged: int
    refits: int


def sigma_part(
    problem: Problem, x, cols: list[int], specs, cov_given, max_nfev: int = REFIT_NFEV
) -> Refits:
    """The fit repeated at the given model's sigma points (module docstring), from ``x`` at
    the iteration quadrature, the free parameters' Jacobian taken once at each start (a
    chord method: the point's medium is exact, the shifts are small; the same to 0.5 % of
    the standard errors as fresh Jacobians at m01 and m05, at half the time). The shifts
    are taken from a refit at the given values themselves made the same way, so that they
    hold the given model's change alone. A point that had to be pulled back inside the
    bounds counts as the mirror of its twin when the twin is whole (the linear response's
    moment is kept); when both were pulled back each shift is scaled up by the fraction
    kept, and one kept below :data:`MIN_REACH` is replaced by its twin's mirror (both: the
    direction counts as without spread)."""
    names = [problem.names[c] for c in cols]
    values = np.array([x[c] for c in cols])
    points, reach = sigma_points(specs, values, cov_given)
    free = problem.free_index
    nominal = solve(problem.with_fixed({}), x, tol=TOL_ITER, max_nfev=max_nfev, jacobian_at=x)
    shifts = np.zeros((len(points), len(free)))
    done = np.zeros(len(points), dtype=bool)
    converged = 0
    for i, point in enumerate(points):
        twin = i ^ 1  # the other point of its pair
        if reach[i] < 1.0 and reach[twin] == 1.0:
            continue  # mirrored below
        if reach[i] < MIN_REACH:
            continue  # no room either way: no spread
        sub = problem.with_fixed(dict(zip(names, point)))
        start = nominal.x.copy()
        start[cols] = point
        sol = solve(sub, start, tol=TOL_ITER, max_nfev=max_nfev, jacobian_at=start)
        if not np.all(np.isfinite(sol.x)) or not np.isfinite(sol.cost):
            raise FitError(
                f"the refit at the given model's sigma point "
                f"{dict(zip(names, point))} gave non-finite values"
            )
        shifts[i] = (sol.x[free] - nominal.x[free]) / reach[i]
        done[i] = True
        converged += int(sol.status > 0)
    for i in range(len(points)):
        if not done[i] and done[i ^ 1]:
            shifts[i] = -shifts[i ^ 1]
    # each point weighs 1/2n, n the given parameters (directions without spread have none)
    cov = shifts.T @ shifts / (2 * len(values))
    return Refits(cov, points, shifts, converged, int(done.sum()))


def _refitted(problem: Problem, x, cols, specs, cov, how: dict):
    """:func:`sigma_part` with ``how`` updated by what it took; None (and ``how`` saying
    so, the method the first order) when a refit failed."""
    try:
        refits = sigma_part(problem, x, cols, specs, cov)
    except InputError as exc:  # FitError too: a refit that failed
        how.update(method="linear", fallback=f"sigma points failed ({exc}); first order used")
        return None
    how.update(points=len(refits.points), refits=refits.refits, converged=refits.converged)
    return refits


def given_covariance(given_result, method: str) -> tuple | None:
    """(names, covariance) of ``given_result``'s total covariance when ``method`` propagates
    it; None with "off", without a given fit, or when it has none."""
    if given_result is None or method == "off":
        return None
    return given_result.covariance(total=True)


def propagated(
    problem: Problem,
    x,
    given_result,
    column: Callable[[str], int],
    method: str = "auto",
    converged: bool = True,
) -> tuple[np.ndarray | None, dict | None]:
    """(part, how): the covariance that ``given_result``'s (total) covariance adds to the free
    parameters of the fit at natural ``x``, linearly or through sigma points (``method``;
    "auto" chooses by the given parameters' relative uncertainty); ``column`` maps a name of
    the given result to its index in the problem; a fit that did not ``converge`` keeps the
    first order under "auto" (:func:`how_of`). ``how`` records the method, the relative
    uncertainties and, for sigma points, the refits. (None, None) when the given result has
    no covariance, or with ``method`` "off" (the totals are then not reported: the ranking of
    candidates, whose estimates, chi-square and BIC the given covariance does not move)."""
    found = given_covariance(given_result, method)
    if found is None:
        return None, None
    gnames, gcov = found
    gcov = np.asarray(gcov, dtype=float)
    cols = [column(n) for n in gnames]
    # the problem's slots of the given parameters (a fit of several channels names them
    # per channel, Td[r]; docs/channels.md)
    specs = [problem.params[c].spec for c in cols]
    relative = relative_uncertainty(specs, [x[c] for c in cols], gcov)
    how = how_of(method, relative, converged)
    refits = None if how["method"] == "linear" else _refitted(problem, x, cols, specs, gcov, how)
    if refits is None:
        return linear_part(problem, x, cols, gcov), how
    return refits.covariance, how


def media_part(
    problem: Problem, x, cov, method: str = "auto", converged: bool = True
) -> tuple[list[int], np.ndarray | None, dict | None]:
    """A joint fit's counterpart of sigma points (it estimates the media with the objects):
    by the law of total covariance, E[Cov(o | m)] + Cov(E[o | m]), the media's share of the
    objects' covariance is to first order A C_mm A^T; it is replaced by the spread of the
    objects' estimate over refits at the sigma points of the media's block C_mm of ``cov``
    (free parameters, problem order; the rest of ``cov`` - a model-discrepancy sandwich, a
    reference's propagated part - kept as it is). Returns (object columns, delta = sigma part -
    A C_mm A^T, how); delta is None when "auto" (``method``) keeps the first order or
    there is nothing to do (no media or no objects free); how None then too when nothing,
    and with ``method`` "off" (the first order, which the joint covariance holds, kept). A
    fit that did not ``converge`` keeps the first order under "auto" (:func:`how_of`)."""
    free = [int(k) for k in problem.free_index]
    cols_m = [k for k in free if problem.params[k].kind == "medium"]
    cols_o = [k for k in free if problem.params[k].kind != "medium"]
    if method == "off" or not cols_m or not cols_o or cov is None:
        return cols_o, None, None
    pos = {k: j for j, k in enumerate(free)}
    jm = [pos[k] for k in cols_m]
    cmm = np.asarray(cov, dtype=float)[np.ix_(jm, jm)]
    specs = [problem.params[k].spec for k in cols_m]
    relative = relative_uncertainty(specs, x[cols_m], cmm, [problem.names[k] for k in cols_m])
    how = how_of(method, relative, converged)
    if how["method"] == "linear":
        return cols_o, None, how
    cond = problem.with_fixed({problem.names[k]: float(x[k]) for k in cols_m})
    refits = _refitted(cond, x, cols_m, specs, cmm, how)
    if refits is None:
        return cols_o, None, how
    return cols_o, refits.covariance - linear_part(cond, x, cols_m, cmm), how


__all__ = [
    "METHODS",
    "RELATIVE_LIMIT",
    "RELATIVE_MAX",
    "how_of",
    "NEGLIGIBLE",
    "MIN_REACH",
    "REFIT_NFEV",
    "check_method",
    "given_covariance",
    "Axis",
    "relative_uncertainty",
    "choose",
    "describe",
    "sigma_points",
    "sensitivity",
    "linear_part",
    "Refits",
    "sigma_part",
    "propagated",
    "media_part",
]
