"""The model error steps 1 and 2 share, counted once (docs/uncertainty.md,
docs/validity-coverage.md; the module docstring of :mod:`veil.fitting.model_error`): step
1's influence G_1 on the medium (:func:`influence`), the cross term it adds to step 2's
covariance (:func:`shared`) and how far step 2's error is step 1's, c in [0, 1], from the
restricted likelihood of both fits' residuals (:func:`session_correlation`)."""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_triangular

from ..errors import FitError
from .model_error import ModelError, _complement, correlation, distances

#: Points of the grid over c in [0, 1] on which :func:`session_correlation` averages c under
#: its likelihood (the trapezoid rule; the likelihood is smooth in c).
SHARE_GRID = 41


def influence(cov, weighted_jacobian, scaled_values) -> np.ndarray:
    """G = C J_w^T A (free parameters x points): the estimate's change per unit relative
    error at each configuration (module docstring)."""
    return (
        np.asarray(cov, dtype=float)
        @ np.asarray(weighted_jacobian, dtype=float).T
        * np.asarray(scaled_values, dtype=float)[None, :]
    )


def session_correlation(
    residuals,
    scaled_values,
    weighted_jacobian,
    angles,
    own_cov,
    given: ModelError,
    given_names,
    given_jacobian,
    given_cov,
) -> float | None:
    """How far step 2's model error is the one its given medium's fit showed, in [0, 1] (1:
    one process over both sessions, :func:`shared`; 0: independent): the mean of c under
    the restricted likelihood of both fits' residuals at once, normalized over c in [0, 1]
    (a uniform prior; :func:`share_likelihood` on :data:`SHARE_GRID` points,
    :func:`likelihood_mean`). The mean, not the likelihood's maximum: step 2's total
    covariance is A + c B (the cross term of :func:`shared` is linear in c) and the
    estimate does not depend on c, so averaging over c's uncertainty gives A + E[c] B - an
    approximation (the residuals that inform c are not independent of the estimate's error
    given c), which pulls c towards 1/2 where one session holds little about it: towards
    less cancellation where c is near 1, more where it is near 0 (synthetic medians 0.36 /
    0.49 / 0.74 for the truths 0 / 0.5 / 1). The maximum sat at the bound c = 1 where the
    likelihood barely prefers it and cancelled more of the error than the data show
    (docs/validity.md: the 10 cm cylinder with the smooth reference, 56 % of the curves
    within two standard errors at c = 1, 100 % at c <= 0.75)."""
    found = share_likelihood(
        residuals,
        scaled_values,
        weighted_jacobian,
        angles,
        own_cov,
        given,
        given_names,
        given_jacobian,
        given_cov,
    )
    return None if found is None else likelihood_mean(*found)


def likelihood_mean(grid, nll) -> float | None:
    """The mean of ``grid`` under the normalized likelihood exp(-``nll``) (trapezoid rule;
    non-finite nll weigh 0; None when none is finite)."""
    grid, nll = np.asarray(grid, dtype=float), np.asarray(nll, dtype=float)
    finite = np.isfinite(nll)
    if not np.any(finite):
        return None
    w = np.where(finite, np.exp(-(nll - np.min(nll[finite]))), 0.0)
    h = np.diff(grid)
    mass = float(np.sum(h * (w[1:] + w[:-1])) / 2.0)
    first = float(np.sum(h * (grid[1:] * w[1:] + grid[:-1] * w[:-1])) / 2.0)
    if mass <= 0.0:  # one finite point alone
        return float(grid[int(np.argmax(w))])
    return float(np.clip(first / mass, grid[0], grid[-1]))


def _share_blocks(
    given: ModelError, g1, q1, q2, a1, a2, r1, residuals, angles, own_cov, given_jacobian, given_cov
) -> tuple:
    """The covariance of both fits' residual components at c = 0, the blocks that c scales
    (b12, h22), the components z and the size of step 1's (:func:`share_likelihood`)."""
    jm = np.asarray(given_jacobian, dtype=float)[: a2.size]
    k11 = given.sigma**2 * correlation(distances(given.angles), given.length)
    k12 = given.sigma**2 * correlation(distances(given.angles, angles), given.length)
    m1, m2 = a1[:, None] * q1, a2[:, None] * q2
    jq = jm.T @ q2  # J_m^T Q_2
    b11 = m1.T @ k11 @ m1
    b12 = m1.T @ k12 @ m2  # scaled by c
    f12 = (m1.T @ k11 @ g1.T) @ jq  # through step 1's estimate
    b22 = m2.T @ np.asarray(own_cov, dtype=float) @ m2 + jq.T @ np.asarray(given_cov) @ jq
    h22 = (m2.T @ k12.T @ g1.T) @ jq  # scaled by c, with its transpose
    z = np.concatenate([q1.T @ r1, q2.T @ np.asarray(residuals, dtype=float)])
    n1 = b11.shape[0]
    base = np.eye(z.size)
    base[:n1, :n1] += 0.5 * (b11 + b11.T)
    base[n1:, n1:] += 0.5 * (b22 + b22.T)
    base[:n1, n1:] -= f12
    base[n1:, :n1] -= f12.T

    return base, b12, h22, z, n1


def share_likelihood(
    residuals,
    scaled_values,
    weighted_jacobian,
    angles,
    own_cov,
    given: ModelError,
    given_names,
    given_jacobian,
    given_cov,
) -> tuple | None:
    """(c on :data:`SHARE_GRID` points of [0, 1], the negative log restricted likelihood at
    each) of :func:`session_correlation`.

    The components of each fit's weighted residuals outside its Jacobian, z_1 = Q_1^T r_1 and
    z_2 = Q_2^T r_2, are normal with mean 0. Step 1's medium estimate is off by
    delta = G_1 d_1 + (noise), and step 2 sees its data through it: r_2 = (I - H_2)(e_2 - J_m
    delta), J_m = ``given_jacobian`` (step 2's weighted Jacobian in the medium's parameters
    ``given_names``, points x parameters). With K_11 = s_1^2 R(ell_1) over step 1's
    configurations, K_21 = s_1^2 R_21(ell_1) between the sessions' and K_22 = ``own_cov``
    (step 2's error: the shared process plus its excess):

        Cov(z_1)      = I + Q_1^T A_1 K_11 A_1 Q_1
        Cov(z_1, z_2) = Q_1^T A_1 (c K_12 A_2 - K_11 G_1^T J_m^T) Q_2
        Cov(z_2)      = I + Q_2^T (A_2 K_22 A_2 + J_m C_m J_m^T
                                   - c (A_2 K_21 G_1^T J_m^T + transpose)) Q_2

    c the correlation sought, C_m = ``given_cov`` the medium's covariance (its total, the
    term included; rows as ``given_names``). Q_1 spans the complement of step 1's Jacobian,
    recovered from its influence G_1 = C J_w^T A (its rows span J_w's columns once A is
    divided out). c is one number for every direction: the likelihood sees the error only
    outside the Jacobians, the cross term it scales lives inside them. The reference and
    the target are different objects: where the medium model's miss depends on the object's
    lobe (a wide plate's view side), the two errors are not one. None (the error then
    counted as one process, c = 1) when the given term lacks its residuals (result files of
    earlier veils), a scaled value is 0, or a fit leaves no residual component."""
    if (
        given is None
        or given.residuals is None
        or given.influence is None
        or given.length == 0.0
        or given.sigma == 0.0
    ):
        return None
    a1 = np.asarray(given.scaled, dtype=float)
    r1 = np.asarray(given.residuals, dtype=float)
    if np.any(a1 == 0.0):
        return None
    g1 = np.array([given.influence[n] for n in given_names], dtype=float)
    q1 = _complement((g1 / a1[None, :]).T, a1.size)
    a2 = np.asarray(scaled_values, dtype=float)
    q2 = _complement(weighted_jacobian, a2.size)
    assert q1 is not None and q2 is not None  # both from a Jacobian
    if q1.shape[1] == 0 or q2.shape[1] == 0:
        return None
    base, b12, h22, z, n1 = _share_blocks(
        given, g1, q1, q2, a1, a2, r1, residuals, angles, own_cov, given_jacobian, given_cov
    )

    def nll(c):
        cov = base.copy()
        cov[:n1, n1:] += c * b12
        cov[n1:, :n1] += c * b12.T
        cov[n1:, n1:] -= c * (h22 + h22.T)
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:  # not a covariance at this c: not a candidate
            return math.inf
        w = solve_triangular(chol, z, lower=True)
        return float(np.sum(np.log(np.diag(chol))) + 0.5 * w @ w)

    grid = np.linspace(0.0, 1.0, SHARE_GRID)
    return grid, np.array([nll(c) for c in grid])


def shared(
    own_influence, angles, given: ModelError, given_names, sensitivity, share: float = 1.0
) -> np.ndarray | None:
    """The covariance that the error a step shares with its given medium's fit adds to its
    total: step 2's estimate moves by G_2 d_2 + S G_1 d_1 (S = d estimate / d medium, first
    order), and d_1, d_2 are one process over the configurations of both sessions with the
    given fit's s and ell, so beside the two steps' own parts it has the cross term s^2 (G_2
    R_21 G_1^T S^T + its transpose), R_21 = exp(-D(step 2's, step 1's) / ell). It is
    negative where the medium absorbed in step 1 the error it gives back in step 2.
    ``share`` scales it: how far step 2's error is step 1's (:func:`session_correlation`).
    None when the given term has no length (ell = 0: the two sessions' errors independent)
    or no influence. Step 2's own part must then be that of the shared process plus what its
    own s exceeds it by (veil.fitting.reported_uncertainty), so that the two are one
    covariance."""
    if given is None or given.sigma == 0.0 or given.length == 0.0 or given.influence is None:
        return None
    missing = [n for n in given_names if n not in given.influence]
    if missing:
        raise FitError(
            f"the medium result's model_error.influence has no row for "
            f"{', '.join(missing)} (it has {', '.join(given.influence)})"
        )
    g1 = np.array([given.influence[n] for n in given_names], dtype=float)
    r21 = correlation(distances(angles, given.angles), given.length)
    cross = own_influence @ r21 @ g1.T @ np.asarray(sensitivity, dtype=float).T
    return share * given.sigma**2 * (cross + cross.T)


__all__ = [
    "influence",
    "shared",
    "session_correlation",
    "likelihood_mean",
    "share_likelihood",
    "SHARE_GRID",
]
