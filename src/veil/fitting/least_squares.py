"""The least-squares rules of veil, written once (docs/fitting.md, docs/maps.md).

Two solvers run on them: the single fits (:mod:`veil.fitting.solver`: scipy's
trust-region-reflective iterations through the engine) and the per-pixel batched solve
(:mod:`veil.maps.solve`: Levenberg-Marquardt on tabulated columns, vectorized in JAX with a
stopping test per pixel). What they share is here, as functions of an array module ``xp``
(numpy or ``jax.numpy``):

- the rank and covariance of a weighted Jacobian: columns equilibrated to unit length first
  (natural units span many decades), rank deficient when the smallest singular value is
  below :data:`SINGULAR` of the largest, covariance (J^T W J)^-1, scaled by the residual
  variance for unweighted data (:func:`equilibrate`, :func:`covariance`,
  :func:`residual_variance`);
- bounds: a parameter is held at a bound when it sits there and the gradient pushes it out;
  steps are projected back into the box; a solution within a tolerance of a bound is "at the
  edge" (:func:`held`, :func:`project`, :func:`at_bounds`);
- damping: Levenberg-Marquardt's diagonal scaling and the update of its factor
  (:func:`damped_step`, :func:`update_damping`);
- the stopping rule: the undamped Gauss-Newton step over the parameters not held at a bound,
  in standard errors (:func:`gauss_newton_decrease`, :func:`stopped`, :func:`step_in_stderr`);
- the small dense algebra the batched solve unrolls (batched LAPACK calls on tiny matrices
  are slow in XLA): :func:`ldl`, :func:`ldl_solve`, :func:`nnls_small`.
"""

from __future__ import annotations

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
    low, piv = ldl(xp.where(ok, je.T @ je, xp.eye(n)), xp)
    full = ok & (xp.min(xp.stack(piv)) > SINGULAR**2 * n) if n else ok
    eye = xp.eye(n)
    inv = (
        xp.stack([ldl_solve(low, piv, eye[i], xp) for i in range(n)], axis=1)
        if n
        else xp.zeros((0, 0))
    )
    return inv / xp.outer(scale, scale), full


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
def damped_step(a: Any, g: Any, lam: Any, xp: Any) -> Any:
    """Levenberg-Marquardt's step from the normal matrix ``a`` and gradient ``g``: the
    damping ``lam`` times ``a``'s diagonal (1 where it is zero) added."""
    diag = xp.diag(a)
    scale = xp.where(diag > 0, diag, 1.0)
    low, piv = ldl(a + lam * xp.diag(scale), xp)
    return ldl_solve(low, piv, g, xp)


def update_damping(lam: Any, better: Any, frozen: Any, xp: Any) -> Any:
    """The next damping: lower after a step that lowered the cost, higher after one that did
    not, unchanged for a pixel that has stopped."""
    low, high = DAMPING_RANGE
    return xp.where(
        frozen,
        lam,
        xp.where(better, xp.maximum(lam * DAMPING_DOWN, low), xp.minimum(lam * DAMPING_UP, high)),
    )


def gauss_newton_decrease(p: Any, a: Any, g: Any, lo: Any, hi: Any, xp: Any) -> Any:
    """Predicted cost decrease of the undamped Gauss-Newton step over the parameters not
    held at a bound: an upper bound on (step / standard error)^2 of every such parameter,
    times the residual variance when unweighted."""
    n = a.shape[0]
    hold = held(p, g, lo, hi)
    pair = hold[:, None] | hold[None, :]
    reduced = xp.where(pair, xp.eye(n), a)
    gr = xp.where(hold, 0.0, g)
    low, piv = ldl(reduced, xp)
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


def ldl(a: Any, xp: Any) -> tuple[list, list]:
    """Unrolled LDL^T of a small symmetric matrix (n <= 5): (L as nested lists, pivots D).
    A handful of fused arithmetic ops, where a batched LAPACK call on tiny matrices is slow
    in XLA."""
    n = a.shape[0]
    low: list = [[None] * n for _ in range(n)]
    piv: list = []
    for j in range(n):
        dj = a[j, j] - sum(low[j][k] ** 2 * piv[k] for k in range(j))
        dj = xp.where(xp.abs(dj) > 1e-300, dj, 1e-300)
        piv.append(dj)
        for i in range(j + 1, n):
            low[i][j] = (a[i, j] - sum(low[i][k] * low[j][k] * piv[k] for k in range(j))) / dj
    return low, piv


def ldl_solve(low: list, piv: list, b: Any, xp: Any) -> Any:
    """x with L D L^T x = b, from :func:`ldl`'s factors."""
    n = len(piv)
    z: list = []
    for i in range(n):
        z.append(b[i] - sum(low[i][k] * z[k] for k in range(i)))
    x: list = [None] * n
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
    "gauss_newton_decrease",
    "stopped",
    "step_in_stderr",
    "nnls_small",
    "ldl",
    "ldl_solve",
]
