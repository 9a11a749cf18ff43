"""Settings, checks and results shared by the least-squares fits (docs/fitting.md): the
iteration quadrature, scipy's termination tolerances, the checks of the fit options
(accuracy, max_nfev, fixed values), progress while iterating, when a start is convincing,
the goodness of fit, the covariance, standard errors and correlations from the weighted
Jacobian at the solution, and the notes of a result's message."""

from __future__ import annotations

import numpy as np

from ..engine.apparent import RULES
from .result import FitError

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
#: Reduced chi-square up to which a converged weighted fit inside its search range makes
#: further starts unnecessary.
CONVINCING = 2.0


# --------------------------------------------------------------------------------------
# options
# --------------------------------------------------------------------------------------
def check_accuracy(accuracy) -> None:
    """A FitError unless ``accuracy`` names a quadrature rule ("fast", "default", "high")."""
    if accuracy not in RULES:
        raise FitError(f"accuracy = {accuracy!r}; expected one of {', '.join(RULES)}")


def check_max_nfev(max_nfev) -> None:
    """A FitError unless ``max_nfev`` is a positive integer or None."""
    if max_nfev is not None and (isinstance(max_nfev, bool) or not isinstance(max_nfev, int)
                                 or max_nfev < 1):
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
    except (ValueError, TypeError) as exc:
        raise FitError(f"fixed {exc}") from None


# --------------------------------------------------------------------------------------
# iterating
# --------------------------------------------------------------------------------------
def ticker(progress, stage: str):
    """A callback for each evaluation of a least-squares run: calls progress(stage, n, None)
    at the n-th call (nothing when ``progress`` is None)."""
    count = 0

    def tick():
        nonlocal count
        count += 1
        if progress is not None:
            progress(stage, count, None)

    return tick


def convincing(status: int, cost: float, dof: int, weighted: bool, at_edge) -> bool:
    """A weighted fit that converged (``status`` > 0) with no parameter at the edge of its
    search range (``at_edge``) and reduced chi-square 2 ``cost`` / ``dof`` <= CONVINCING."""
    return (status > 0 and weighted and 2 * cost / dof <= CONVINCING and not at_edge)


# --------------------------------------------------------------------------------------
# the solution
# --------------------------------------------------------------------------------------
def goodness(y: np.ndarray, w: np.ndarray, values: np.ndarray, n_free: int):
    """(residuals (y - values) * w, reduced chi-square sum(residuals^2) / (points - n_free),
    rms of the relative residuals (y - values) / values over nonzero values, nan if none)."""
    res = (y - values) * w
    chi2 = float(res @ res) / (y.size - n_free)
    nonzero = values != 0
    rel = (y[nonzero] - values[nonzero]) / values[nonzero]
    rms_rel = float(np.sqrt(np.mean(rel ** 2))) if rel.size else float("nan")
    return res, chi2, rms_rel


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


# --------------------------------------------------------------------------------------
# the message
# --------------------------------------------------------------------------------------
#: Note of a result whose Jacobian is singular at the solution.
SINGULAR_NOTE = "Jacobian singular at the solution: uncertainties not determined"


def stopped_early_note(message: str) -> str:
    """Note of a polished result whose iterations did not converge (scipy's ``message``)."""
    return f"iterations at {ITERATION_ACCURACY!r} accuracy stopped early ({message})"


def edge_note(names) -> str:
    """Note of a result with parameters ``names`` at the edge of their search range."""
    return f"{', '.join(names)} at the edge of the search range (uncertainty unreliable)"


def outcome(status: int, message: str, notes) -> tuple[bool, str]:
    """(converged, message) of a result: scipy's ``status`` > 0, and its ``message`` with the
    ``notes`` appended, prefixed "did not converge: " unless converged."""
    converged = bool(status > 0)
    message = message if not notes else message + "; " + "; ".join(notes)
    if not converged:
        message = "did not converge: " + message
    return converged, message


__all__ = ["ITERATION_ACCURACY", "TOL_ITER", "TOL_POLISH", "TOL_FINAL", "CONVINCING",
           "check_accuracy", "check_max_nfev", "check_fixed", "ticker", "convincing",
           "goodness", "covariance_from_jacobian", "uncertainties", "SINGULAR_NOTE",
           "stopped_early_note", "edge_note", "outcome"]
