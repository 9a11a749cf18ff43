"""Settings and uncertainties shared by the least-squares fits (docs/fitting.md): the
iteration quadrature, scipy's termination tolerances, and the covariance, standard errors
and correlations from the weighted Jacobian at the solution."""

from __future__ import annotations

import numpy as np

#: Quadrature of the iterations through a medium; the polish uses the requested accuracy.
ITERATION_ACCURACY = "fast"
#: Termination of scipy's least_squares. A relative cost change below 1e-6 at the optimum
#: (cost ~ n_points / 2 for a good weighted fit) leaves every parameter within about 1 % of
#: its standard error of the optimum: enough for the iterations before a polish and for the
#: polish itself (whose fast-rule Jacobian makes finer steps a matter of chance). Direct
#: fits of f_r are cheap and use the tight tolerances.
TOL_ITER = {"ftol": 1e-6, "xtol": 1e-6, "gtol": 1e-8}
TOL_POLISH = TOL_ITER
TOL_FINAL = {"ftol": 1e-8, "xtol": 1e-8, "gtol": 1e-8}


def covariance_from_jacobian(jac_u: np.ndarray, d: np.ndarray):
    """Covariance of the free parameters (x units) from the weighted internal Jacobian
    ``jac_u`` (points x free parameters) and dx/du ``d``: (J^T J)^-1 scaled by d d^T; None
    when J is singular (smallest singular value <= 1e-10 of the largest)."""
    _, s, vt = np.linalg.svd(jac_u, full_matrices=False)
    if s.size == 0 or s[-1] <= s[0] * 1e-10 or not np.all(np.isfinite(s)):
        return None
    cov_u = (vt.T / s ** 2) @ vt
    return cov_u * np.outer(d, d)


def uncertainties(cov, names, free):
    """(stderr dict over all names, correlation dict over the free ones) from a covariance
    of the free parameters (``free``: their indices into ``names``)."""
    stderr = {n: None for n in names}
    corr = {}
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    for j, i in enumerate(free):
        stderr[names[i]] = float(se[j])
    for a, i in enumerate(free):
        corr[names[i]] = {}
        for b, jdx in enumerate(free):
            den = se[a] * se[b]
            corr[names[i]][names[jdx]] = float(cov[a, b] / den) if den > 0 else None
    return stderr, corr


__all__ = ["ITERATION_ACCURACY", "TOL_ITER", "TOL_POLISH", "TOL_FINAL",
           "covariance_from_jacobian", "uncertainties"]
