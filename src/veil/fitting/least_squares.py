"""The least-squares core of veil, written once (docs/fitting.md, docs/maps.md).

Two solvers iterate Levenberg-Marquardt on it: the single fits (:mod:`veil.fitting.solver`,
through the engine, with :func:`levenberg_marquardt`) and the per-pixel batched solve
(:mod:`veil.maps.solve`: tabulated columns, vectorized in JAX with a stopping test per pixel,
each pixel frozen once it stops). Both take every step with :func:`lm_step` and
:func:`lm_accept`; what they share is here, as functions of an array module ``xp`` (numpy or
``jax.numpy``):

- the rank and covariance of a weighted Jacobian: columns equilibrated to unit length first
  (natural units span many decades), rank deficient when the smallest singular value is
  below :data:`SINGULAR` of the largest, covariance (J^T W J)^-1, scaled by the residual
  variance for unweighted data (:func:`equilibrate`, :func:`covariance`,
  :func:`residual_variance`);
- bounds: a parameter is held at a bound when it sits there and the gradient pushes it out;
  steps are projected back into the box; a solution within a tolerance of a bound is "at the
  edge" (:func:`held`, :func:`reduced`, :func:`project`, :func:`at_bounds`);
- damping: Levenberg-Marquardt's diagonal scaling and the update of its factor
  (:func:`damped_step`, :func:`update_damping`); the maps scale by J^T J's diagonal, the
  single fits by the largest diagonal met so far over each parameter's room to the bound it
  is pushed to (:func:`damping_scale`, as scipy's trust-region-reflective method scales);
- the stopping rule: the undamped Gauss-Newton step over the parameters not held at a bound,
  in standard errors (:func:`gauss_newton_decrease`, :func:`stopped`, :func:`step_in_stderr`),
  below a tolerance ``tol`` in every such parameter. The decrease g^T A^-1 g bounds
  (step_j / stderr_j)^2 of every parameter j, and near the optimum that step is the distance
  to it: an iteration that stops is within about ``tol`` standard errors of the optimum (the
  single fits' tolerances are :mod:`veil.fitting.solver`'s ``TOL_*``, the maps' ``LM_TOL``);
- one step: the damped step over the parameters not held, projected into the box, and the
  decrease for the stopping rule (:func:`lm_step`); a trial point that lowers the cost is
  taken and the damping falls, else the damping rises (:func:`lm_accept`);
- the iteration of one problem, in numpy (:func:`levenberg_marquardt`), which also weighs
  each step's gain (actual over predicted decrease) in the damping: those steps until the
  stopping rule holds (status 1); or a trial step below ``tol`` standard errors does not
  lower the cost and changes it no more than the quadratic model allows (2,
  :func:`_no_lower_cost`); or, with a Jacobian that is only close (frozen: the polish, the
  sigma-point refits), a step lowers the cost by less than a step of ``tol`` standard
  errors would (3) - such a Jacobian leaves a Gauss-Newton step of its own error at the
  optimum. Not converged: the evaluations run out (0), no step lowers the cost with the
  damping at its maximum (-1), residuals or Jacobian not finite (-2);
- the small dense algebra, unrolled (batched LAPACK calls on tiny matrices are slow in XLA):
  :func:`ldl`, :func:`ldl_solve`, :func:`nnls_small`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

#: A singular value below this fraction of the largest (of the equilibrated Jacobian) makes
#: the Jacobian rank deficient.
SINGULAR = 1e-10
#: Levenberg-Marquardt's damping: the first factor, its change after a step that lowers the
#: cost (down) and after one that does not (up), and its range.
DAMPING_START = 1e-4
DAMPING_DOWN = 0.2
DAMPING_UP = 10.0
DAMPING_RANGE = (1e-12, 1e12)
#: The gain of a step taken (actual over predicted decrease of the cost) above which the
#: single fits lower the damping, and below which they raise it (:func:`lm_accept`).
GAIN_GOOD, GAIN_POOR = 0.75, 0.25


# --------------------------------------------------------------------------------------
# rank and covariance
# --------------------------------------------------------------------------------------
def equilibrate(jw: Any, xp: Any = np) -> tuple[Any, Any, Any]:
    """(Jacobian with unit columns, the column norms (1 where a column is zero), whether
    every column is nonzero and finite)."""
    norm = xp.sqrt(xp.sum(jw * jw, axis=0))
    ok = xp.all(norm > 0) & xp.all(xp.isfinite(jw))
    safe = xp.where(norm > 0, norm, 1.0)
    return jw / safe, safe, ok


def covariance(jw: Any, xp: Any = np) -> tuple[Any, Any]:
    """(covariance (J^T J)^-1 of the parameters of the weighted Jacobian ``jw`` (rows x
    parameters), whether ``jw`` has full rank). With numpy by a singular value decomposition
    of the equilibrated Jacobian (full rank: smallest singular value above :data:`SINGULAR`
    of the largest); with JAX, for the per-pixel batches, by the unrolled LDL^T of the
    equilibrated normal matrix, whose pivots are the squared singular values' counterpart (full
    rank: smallest pivot above SINGULAR^2 x parameters, the largest possible pivot)."""
    je, scale, ok = equilibrate(jw, xp)
    n = jw.shape[1]
    if xp is np:
        if not ok or n == 0:
            return np.full((n, n), np.nan), False
        _, s, vt = np.linalg.svd(je, full_matrices=False)
        full = bool(np.all(np.isfinite(s)) and s[-1] > s[0] * SINGULAR)
        return ((vt.T / s**2) @ vt) / np.outer(scale, scale), full
    inv, full = _equilibrated_inverse(je.T @ je, ok, xp)
    return inv / xp.outer(scale, scale), full


def _equilibrated_inverse(a: Any, ok: Any, xp: Any) -> tuple[Any, Any]:
    """(inverse, full rank) of an equilibrated normal matrix ``a`` by the unrolled LDL^T
    (the identity's where not ``ok``): full rank when ``ok`` and the smallest pivot is above
    SINGULAR^2 x parameters."""
    n = a.shape[0]
    low, piv = ldl(xp.where(ok, a, xp.eye(n)), xp)
    full = ok & (xp.min(xp.stack(piv)) > SINGULAR**2 * n) if n else ok
    eye = xp.eye(n)
    if not isinstance(low, list):  # factored by a loop: every column at once
        inv = _ldl_loop_solve(low, piv, eye)
    elif n:
        inv = xp.stack([ldl_solve(low, piv, eye[i], xp) for i in range(n)], axis=1)
    else:
        inv = xp.zeros((0, 0))
    return inv, full


def normal_covariance(a: Any, finite: Any, xp: Any) -> tuple[Any, Any]:
    """(covariance, full rank) from the normal matrix ``a`` = J^T J of a weighted Jacobian
    whose entries are all finite when ``finite``: :func:`covariance`'s rule with JAX (the
    matrix equilibrated to a unit diagonal, the unrolled LDL^T, full rank when the smallest
    pivot is above SINGULAR^2 x parameters), for a solver that forms J^T J from blocks
    without J (the maps over channels, :mod:`veil.maps.solve_channels`)."""
    norm = xp.sqrt(xp.maximum(xp.diag(a), 0.0))
    ok = finite & xp.all(norm > 0)
    safe = xp.where(norm > 0, norm, 1.0)
    inv, full = _equilibrated_inverse(a / xp.outer(safe, safe), ok, xp)
    return inv / xp.outer(safe, safe), full


def residual_variance(res: Any, dof: Any, xp: Any = np) -> Any:
    """Reduced chi-square res'res / dof (``dof`` at least 1): the factor of an unweighted
    fit's covariance."""
    return (res @ res) / xp.maximum(dof, 1)


# --------------------------------------------------------------------------------------
# bounds
# --------------------------------------------------------------------------------------
def held(p: Any, g: Any, lo: Any, hi: Any) -> Any:
    """Parameters held at a bound: on it, with the gradient ``g`` (J^T r, the descent
    direction) pushing them out."""
    return ((p <= lo) & (g < 0)) | ((p >= hi) & (g > 0))


def project(p: Any, lo: Any, hi: Any, xp: Any = np) -> Any:
    """``p`` moved into the box [lo, hi]."""
    return xp.clip(p, lo, hi)


def at_bounds(p: Any, lo: Any, hi: Any, tol: Any) -> tuple[Any, Any]:
    """(at the lower bound, at the upper bound): within ``tol`` of it."""
    return p - lo <= tol, hi - p <= tol


# --------------------------------------------------------------------------------------
# damping and the stopping rule
# --------------------------------------------------------------------------------------
def damped_step(a: Any, g: Any, lam: Any, xp: Any, scale: Any = None) -> Any:
    """Levenberg-Marquardt's step from the normal matrix ``a`` and gradient ``g``: the
    damping ``lam`` times a diagonal added, ``scale`` (default: ``a``'s diagonal), 1 where it
    is zero."""
    diag = xp.diag(a) if scale is None else scale
    scale = xp.where(diag > 0, diag, 1.0)
    low, piv = ldl(a + lam * xp.diag(scale), xp)
    return ldl_solve(low, piv, g, xp)


def update_damping(
    lam: Any, better: Any, frozen: Any, xp: Any, good: Any = None, poor: Any = None
) -> Any:
    """The next damping: lower after a step that lowered the cost, higher after one that did
    not, unchanged for a pixel that has stopped. Told how well the model predicted a step
    taken (the single fits, :func:`lm_accept`), it lowers the damping only after a ``good``
    prediction, keeps it after a fair one and raises it after a ``poor`` one."""
    low, high = DAMPING_RANGE
    down = xp.maximum(lam * DAMPING_DOWN, low)
    up = xp.minimum(lam * DAMPING_UP, high)
    if good is not None:
        down = xp.where(good, down, xp.where(poor, up, lam))
    return xp.where(frozen, lam, xp.where(better, down, up))


def damping_scale(largest: Any, p: Any, g: Any, lo: Any, hi: Any) -> Any:
    """The diagonal the single fits' damping multiplies (numpy): in the Jacobian's
    equilibrated coordinates (``largest``: the largest diagonal of J^T J met so far, as
    MINPACK and scipy keep it, so that a parameter whose column vanishes on the way is not
    thrown across its range) the identity, divided by each parameter's room - its distance
    to the bound the descent direction ``g`` points to, in those coordinates, relative to
    the geometric mean of all (Coleman and Li's scaling, as scipy's trust-region-reflective
    method has it: a parameter close to its bound takes shorter steps, one far from it
    longer). A parameter without a bound that way, or on it, keeps the identity."""
    col = np.sqrt(largest)
    room = np.where(g > 0, hi - p, p - lo) * col
    finite = np.isfinite(room) & (room > 0)
    if not np.any(finite):
        return largest
    mean = np.exp(np.mean(np.log(room[finite])))
    return largest * np.where(finite, mean / np.where(finite, room, 1.0), 1.0)


def reduced(p: Any, a: Any, g: Any, lo: Any, hi: Any, xp: Any) -> tuple[Any, Any]:
    """The normal matrix ``a`` and descent direction ``g`` over the parameters not held at a
    bound (:func:`held`): a held parameter's row and column are the identity's and its entry
    of ``g`` is 0, so that its step is 0 (both unchanged when none is held)."""
    n = a.shape[0]
    hold = held(p, g, lo, hi)
    pair = hold[:, None] | hold[None, :]
    return xp.where(pair, xp.eye(n), a), xp.where(hold, 0.0, g)


def gauss_newton_decrease(p: Any, a: Any, g: Any, lo: Any, hi: Any, xp: Any) -> Any:
    """Predicted cost decrease of the undamped Gauss-Newton step over the parameters not
    held at a bound: an upper bound on (step / standard error)^2 of every such parameter,
    times the residual variance when unweighted."""
    ar, gr = reduced(p, a, g, lo, hi, xp)
    low, piv = ldl(ar, xp)
    return gr @ ldl_solve(low, piv, gr, xp)


def stopped(decrease: Any, tol: float, variance: Any, yy: Any, xp: Any) -> Any:
    """The stopping rule: the Gauss-Newton step is below ``tol`` standard errors in every
    free parameter (``variance``: the residual variance, 1 when weighted; ``yy``: the data's
    own sum of squares, for a cost at rounding level)."""
    return (decrease <= tol**2 * variance + 1e-24 * yy) & xp.isfinite(decrease)


def step_in_stderr(step: Any, stderr: Any, xp: Any) -> Any:
    """The largest |step| in standard errors (0 for no parameter)."""
    if step.shape[-1] == 0:
        return 0.0
    return xp.max(xp.abs(step) / xp.where(stderr > 0, stderr, 1.0))


# --------------------------------------------------------------------------------------
# one step, and the iteration of one problem
# --------------------------------------------------------------------------------------
def lm_step(
    p: Any, a: Any, g: Any, lam: Any, lo: Any, hi: Any, xp: Any, scale: Any = None
) -> tuple[Any, Any]:
    """One Levenberg-Marquardt step from ``p`` with normal matrix ``a`` (J^T J of the
    weighted Jacobian), descent direction ``g`` (J^T r, r = data - model) and damping
    ``lam`` (times ``scale``, :func:`damped_step`): (the trial point, the undamped
    Gauss-Newton decrease for :func:`stopped`). The step is damped over the parameters not
    held at a bound (held ones stay, :func:`reduced`) and the trial point projected into the
    box; a step component that is not finite is 0."""
    ar, gr = reduced(p, a, g, lo, hi, xp)
    low, piv = ldl(ar, xp)
    decrease = gr @ ldl_solve(low, piv, gr, xp)
    step = damped_step(ar, gr, lam, xp, scale)
    return project(p + xp.where(xp.isfinite(step), step, 0.0), lo, hi, xp), decrease


def lm_accept(
    cost: Any, trial_cost: Any, lam: Any, frozen: Any, xp: Any, predicted: Any = None
) -> tuple[Any, Any]:
    """(whether the trial point is taken: it lowers the cost - a cost that is not finite
    does not - and the iteration has not stopped; the next damping, :func:`update_damping`).
    Given the ``predicted`` decrease of the step, the gain (actual over predicted decrease)
    tells the damping how well the model predicted it: good above :data:`GAIN_GOOD`, poor
    below :data:`GAIN_POOR` (or without a predicted decrease)."""
    better = xp.logical_and(trial_cost < cost, xp.logical_not(frozen))
    if predicted is None:
        return better, update_damping(lam, better, frozen, xp)
    actual = cost - trial_cost  # -inf for a cost that is not finite: poor
    good = xp.logical_and(predicted > 0, actual > GAIN_GOOD * predicted)
    poor = xp.logical_or(predicted <= 0, actual < GAIN_POOR * predicted)
    return better, update_damping(lam, better, frozen, xp, good, poor)


#: The status of :func:`levenberg_marquardt` (> 0 converged) and its message.
STOPS = {
    1: "the Gauss-Newton step is below {tol:g} standard errors",
    2: "no step of more than {tol:g} standard errors lowers the cost",
    3: "a step lowered the cost by less than one of {tol:g} standard errors does",
    0: "the maximum number of function evaluations ({limit}) is exceeded",
    -1: "no step lowers the cost (damping at its maximum)",
    -2: "the residuals or the Jacobian are not finite",
}
#: Evaluations of the residuals per parameter that :func:`levenberg_marquardt` makes at most
#: when no limit is given.
NFEV_PER_PARAMETER = 100


@dataclass
class Iterations:
    """What :func:`levenberg_marquardt` found: the parameters ``p``, the ``residuals``
    there, the ``cost`` 0.5 sum(residuals^2), the ``status`` (> 0 converged) and its
    ``message``, the evaluations of the residuals (``nfev``) and of the Jacobian
    (``njev``)."""

    p: np.ndarray
    residuals: np.ndarray
    cost: float
    status: int
    message: str
    nfev: int
    njev: int


def levenberg_marquardt(
    fun: Callable[[np.ndarray], Any],
    jac: Callable[[np.ndarray], Any],
    p0: Any,
    lo: Any,
    hi: Any,
    *,
    tol: float,
    max_nfev: int | None = None,
    dof: int | None = None,
    weighted: bool = True,
    yy: float | None = None,
    exact: bool = True,
) -> Iterations:
    """Levenberg-Marquardt for one problem in numpy (module docstring): residuals ``fun(p)``
    (model - data, weighted) evaluated at every trial point, their Jacobian ``jac(p)`` at
    every point taken (``exact``: False when it is only close, frozen), from ``p0`` projected
    into the box [``lo``, ``hi``]. The damping scales with the largest diagonal of J^T J met
    so far (as MINPACK's: a parameter whose column vanishes on the way is not thrown across
    its range) and follows each step's gain. Steps are measured in standard errors with the
    residual variance sum(r^2) / ``dof`` for data not ``weighted``; for weighted data with
    1, or that reduced chi-square where it is above 1 (a model that misses the data by more
    than their noise; 1 when ``dof`` is None). ``yy``: the data's own sum of squares
    (default: the start's); ``max_nfev``: evaluations of the residuals (default:
    :data:`NFEV_PER_PARAMETER` each)."""
    p = project(np.asarray(p0, dtype=float), lo, hi, np)
    limit = max_nfev or NFEV_PER_PARAMETER * max(p.size, 1)
    f = np.asarray(fun(p), dtype=float)
    nfev, njev, lam, largest = 1, 0, DAMPING_START, np.zeros(p.size)
    yy = float(f @ f) if yy is None else yy
    while np.all(np.isfinite(f)):
        jm = np.asarray(jac(p), dtype=float)
        njev += 1
        a, g = jm.T @ jm, -(jm.T @ f)
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(g))):
            break
        if p.size == 0:
            return _end(p, f, 1, nfev, njev, tol, limit)
        largest = np.maximum(largest, np.diag(a))
        scale = damping_scale(largest, p, g, lo, hi)
        cost = float(f @ f)
        variance = 1.0 if dof is None else cost / max(dof, 1)
        variance = max(variance, 1.0) if weighted else variance
        trial, decrease = lm_step(p, a, g, lam, lo, hi, np, scale)
        if stopped(decrease, tol, variance, yy, np):
            return _end(p, f, 1, nfev, njev, tol, limit)
        while True:  # trial points until one lowers the cost
            if nfev >= limit:
                return _end(p, f, 0, nfev, njev, tol, limit)
            ft = np.asarray(fun(trial), dtype=float)
            nfev += 1
            trial_cost = float(ft @ ft) if np.all(np.isfinite(ft)) else np.inf
            step = trial - p
            better, lam = lm_accept(
                cost, trial_cost, lam, False, np, 2 * step @ g - step @ a @ step
            )
            lam = float(lam)
            if better and not exact and cost - trial_cost <= tol**2 * variance:
                return _end(trial, ft, 3, nfev, njev, tol, limit)
            if better:
                break
            if _no_lower_cost(step, a, decrease, trial_cost - cost, tol**2 * variance, cost):
                return _end(p, f, 2, nfev, njev, tol, limit)
            if lam >= DAMPING_RANGE[1]:
                return _end(p, f, -1, nfev, njev, tol, limit)
            trial, _ = lm_step(p, a, g, lam, lo, hi, np, scale)
        p, f = trial, ft
    return _end(p, f, -2, nfev, njev, tol, limit)


def _no_lower_cost(
    step: np.ndarray, a: np.ndarray, decrease: float, rise: float, limit: float, cost: float
) -> bool:
    """Whether a trial ``step`` that did not lower the cost ends the iterations: it is within
    the tolerance (its squared A-norm, in standard errors, at most ``limit``) and the cost
    rose by no more than the local quadratic model allows (10 times its bound
    2 sqrt(decrease) |step|_A + |step|_A^2, plus rounding). The optimum is then within about
    the step: an approximate Jacobian (the polish's frozen one) leaves a Gauss-Newton step of
    its own error there, which the rule of :func:`stopped` would wait for in vain. A step
    that changes the cost far more than the model says (a parameter whose column has
    vanished) ends nothing."""
    size = float(step @ a @ step)
    allowed = 10 * (2 * np.sqrt(max(decrease, 0.0) * size) + size) + 1e-12 * cost
    return size <= limit and rise <= allowed


def _end(
    p: np.ndarray, f: np.ndarray, status: int, nfev: int, njev: int, tol: float, limit: int
) -> Iterations:
    message = STOPS[status].format(tol=tol, limit=limit)
    if p.size == 0 and status == 1:
        message = "no free parameter"
    return Iterations(p, f, 0.5 * float(f @ f), status, message, nfev, njev)


# --------------------------------------------------------------------------------------
# small dense algebra
# --------------------------------------------------------------------------------------
def nnls_small(gram: Any, b: Any, yy: Any, q: int, xp: Any) -> tuple[Any, Any]:
    """Non-negative least squares in q <= 2 unknowns from the normal equations
    (``gram`` (..., q, q), ``b`` (..., q), ``yy`` = y'y): (solution (..., q), cost (...,));
    every active set is tried."""
    if q == 0:
        return xp.zeros(yy.shape + (0,)), yy
    if q == 1:
        g00 = gram[..., 0, 0]
        s = xp.maximum(b[..., 0] / xp.where(g00 > 0, g00, 1.0), 0.0)
        s = xp.where(g00 > 0, s, 0.0)[..., None]
        cost = yy - 2 * s[..., 0] * b[..., 0] + s[..., 0] ** 2 * g00
        return s, cost
    zero = xp.zeros_like(b[..., 0])
    # both active
    det = gram[..., 0, 0] * gram[..., 1, 1] - gram[..., 0, 1] * gram[..., 1, 0]
    ok = xp.abs(det) > 1e-14 * (gram[..., 0, 0] * gram[..., 1, 1] + 1e-300)
    dd = xp.where(ok, det, 1.0)
    s0 = (gram[..., 1, 1] * b[..., 0] - gram[..., 0, 1] * b[..., 1]) / dd
    s1 = (gram[..., 0, 0] * b[..., 1] - gram[..., 1, 0] * b[..., 0]) / dd
    cands = [(s0, s1, ok & (s0 >= 0) & (s1 >= 0))]
    for j in range(2):
        gj = gram[..., j, j]
        sj = xp.where(gj > 0, xp.maximum(b[..., j] / xp.where(gj > 0, gj, 1.0), 0.0), 0.0)
        cands.append((sj, zero, xp.ones_like(ok)) if j == 0 else (zero, sj, xp.ones_like(ok)))
    best_s0, best_s1, best_cost = zero, zero, yy
    for c0, c1, feasible in cands:
        cost = (
            yy
            - 2 * (c0 * b[..., 0] + c1 * b[..., 1])
            + c0 * c0 * gram[..., 0, 0]
            + 2 * c0 * c1 * gram[..., 0, 1]
            + c1 * c1 * gram[..., 1, 1]
        )
        better = feasible & (cost < best_cost)
        best_s0 = xp.where(better, c0, best_s0)
        best_s1 = xp.where(better, c1, best_s1)
        best_cost = xp.where(better, cost, best_cost)
    return xp.stack([best_s0, best_s1], axis=-1), best_cost


#: The largest matrix :func:`ldl` unrolls with JAX; a larger one is factored by a loop over
#: its columns (the unrolled code grows as n^3: the seven parameters of a map over three
#: channels made 2,400 of its iterations program's 3,700 lines, docs/performance-maps.md).
UNROLLED_MAX = 5


def ldl(a: Any, xp: Any) -> tuple[Any, Any]:
    """LDL^T of a small symmetric matrix: (L, pivots D). Unrolled (L as nested lists, D a
    list): a handful of fused arithmetic ops, where a batched LAPACK call on tiny matrices is
    slow in XLA; with JAX above :data:`UNROLLED_MAX` rows, a loop over the columns (L an
    array, unit lower triangular, D an array: :func:`_ldl_loop`)."""
    n = a.shape[0]
    if xp is not np and n > UNROLLED_MAX:
        return _ldl_loop(a)
    low: list = [[None] * n for _ in range(n)]
    piv: list = []
    # a singular matrix overflows here; the callers test what comes out (isfinite), so
    # numpy's warnings would only repeat on the terminal what the fit reports
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for j in range(n):
            dj = a[j, j] - sum(low[j][k] ** 2 * piv[k] for k in range(j))
            dj = xp.where(xp.abs(dj) > 1e-300, dj, 1e-300)
            piv.append(dj)
            for i in range(j + 1, n):
                low[i][j] = (a[i, j] - sum(low[i][k] * low[j][k] * piv[k] for k in range(j))) / dj
    return low, piv


def _ldl_loop(a: Any) -> tuple[Any, Any]:
    """:func:`ldl` by a loop over the columns (JAX): (L (n, n), pivots (n,)), each pivot
    kept away from 0 as the unrolled factorization keeps it."""
    from .._jax import jax, jnp

    n = a.shape[0]
    ks = jnp.arange(n)

    def column(j, factors):
        low, piv = factors
        before = jnp.where(ks < j, low[j] * piv, 0.0)  # L[j, k] D[k], k < j
        dj = a[j, j] - before @ low[j]
        dj = jnp.where(jnp.abs(dj) > 1e-300, dj, 1e-300)
        below = (a[:, j] - low @ before) / dj
        return jnp.where(ks > j, below, low[:, j]), piv.at[j].set(dj)

    def step(j, factors):
        col, piv = column(j, factors)
        return factors[0].at[:, j].set(col), piv

    start = (jnp.eye(n, dtype=a.dtype), jnp.zeros(n, a.dtype))
    return jax.lax.fori_loop(0, n, step, start)


def _ldl_loop_solve(low: Any, piv: Any, b: Any) -> Any:
    """x with L D L^T x = b (b of n rows, one or more columns) from :func:`_ldl_loop`'s
    factors: forward and back substitution as loops over the rows."""
    from .._jax import jax, jnp

    n = piv.shape[0]
    ks = jnp.arange(n)

    def forward(i, z):  # z_i = b_i - sum_{k<i} L[i, k] z_k
        lower = jnp.where(ks < i, low[i], 0.0)
        return z.at[i].set(b[i] - jnp.tensordot(lower, z, axes=1))

    def back(k, x):  # x_i = z_i / D_i - sum_{k>i} L[k, i] x_k, i from the last row up
        i = n - 1 - k
        upper = jnp.where(ks > i, low[:, i], 0.0)
        return x.at[i].set(x[i] / piv[i] - jnp.tensordot(upper, x, axes=1))

    z = jax.lax.fori_loop(0, n, forward, jnp.zeros_like(b))
    return jax.lax.fori_loop(0, n, back, z)


def ldl_solve(low: Any, piv: Any, b: Any, xp: Any) -> Any:
    """x with L D L^T x = b, from :func:`ldl`'s factors."""
    if not isinstance(low, list):
        return _ldl_loop_solve(low, piv, b)
    n = len(piv)
    z: list = []
    x: list = [None] * n
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # as in ldl
        for i in range(n):
            z.append(b[i] - sum(low[i][k] * z[k] for k in range(i)))
        for i in reversed(range(n)):
            x[i] = z[i] / piv[i] - sum(low[k][i] * x[k] for k in range(i + 1, n))
    return xp.stack(x)


__all__ = [
    "SINGULAR",
    "DAMPING_START",
    "equilibrate",
    "covariance",
    "residual_variance",
    "held",
    "project",
    "at_bounds",
    "damped_step",
    "update_damping",
    "damping_scale",
    "reduced",
    "gauss_newton_decrease",
    "stopped",
    "step_in_stderr",
    "lm_step",
    "lm_accept",
    "STOPS",
    "NFEV_PER_PARAMETER",
    "Iterations",
    "levenberg_marquardt",
    "nnls_small",
    "ldl",
    "ldl_solve",
]
