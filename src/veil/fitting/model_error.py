"""The model-discrepancy term of a weighted fit (docs/model.md secs. 7-8; docs/validity.md).

A weighted fit's standard errors count the data's noise only (docs/fitting.md). When the
model itself misses the data - the forward-series medium against path tracing, a GGX plate
fitted as Beckmann - its reduced chi-square is above 1 by more than the chi-square's own
spread, and the standard errors are too small. This module estimates that miss and adds it
to the covariance:

- **The model error is relative and smooth.** The model's value f_i is off by f_i d_i, d a
  Gaussian process over the configurations (a model discrepancy in the sense of Kennedy
  and O'Hagan, 2001): mean 0, standard deviation s, correlation
  exp(-D_ij / ell) with D_ij the angle between the two configurations' incident directions
  plus that between their reflected ones (degrees), ell = 0 meaning independent. A
  forward model's error is a smooth function of the angles: independent errors would
  average out over the configurations, and a systematic error does not.
- **s and ell from the residuals, when they show an error.** The chi-square test first:
  below ``1 + Z sqrt(2 / dof)`` (dof = points - free parameters, Z = :data:`CHI2_Z`) the data
  do not show a model error, s = 0 and (without a declared floor, below) the fit is unchanged
  bit for bit. Above, (s, ell)
  maximize the Gaussian likelihood of the weighted residuals r_i = (y_i - f_i) / sigma_i
  under their covariance I + s^2 A R(ell) A, A = diag(f_i / sigma_i), ell over the grid
  :data:`LENGTHS` and s continuous (the model with ell = 0 is the "excess variance" of a
  fit); restricted to the residuals' components outside the fit's Jacobian (REML,
  :func:`estimate`), since the fit absorbs the rest.
- **The estimate is not moved.** The weights stay 1/sigma^2; the covariance of that
  estimator under the larger variance is the sandwich
      Cov = C J_w^T (I + s^2 A R A) J_w C = C + s^2 (A J_w C)^T R (A J_w C),
  C = (J^T W J)^-1, J_w = W^(1/2) J the weighted Jacobian of the free parameters
  (docs/fitting.md).
- **Step 2 inherits step 1's.** Step 1 fits the medium through the reference, whose f_r
  is known from step 0: its excess measures how far the medium model misses data of that
  set-up. The target is seen through the same medium with the same model, so step 2 uses
  the given medium's (s, ell) when its s is the larger, its own otherwise (its own residuals
  can show less, its f_r absorbing part of the miss). The given model's covariance, its
  term included, is then propagated as before (``stderr_total``).
- **A model's declared error is a floor.** A model may declare its own error against
  physics (``Model.MODEL_ERROR_FLOOR`` = (s, ell)): the term then has at least that s and,
  when correlated, at least that ell (an error the residuals of one session may be too
  few to show, which the fit's parameters can still take up; docs/validity.md).
- **The error the two steps share is counted once.** With a correlation length the same
  process reaches both sessions: the medium absorbs in step 1 part of the error it gives
  back in step 2, and adding the two parts alone overstates the total 3-6 times
  (docs/validity.md). Step 1 keeps its influence G_1 = C J_w^T A on the medium, its
  configurations and residuals; step 2 adds the cross term of
  :func:`veil.fitting.shared_error.shared`, scaled by how far its error is step 1's
  (:func:`~veil.fitting.shared_error.session_correlation`: the two objects differ).

The result carries the term as ``model_error`` (:meth:`ModelError.to_dict`): s, where it came
from, the chi-square threshold, and the uncertainties without it (``noise_only``), which
:func:`noise_only` restores.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import minimize_scalar

from ..errors import FitError

if TYPE_CHECKING:
    from .result import FitResult

#: The chi-square test's level: a model error is estimated only when the reduced chi-square
#: exceeds 1 by more than CHI2_Z of its own standard deviations sqrt(2 / dof) (2: about
#: 2.3 % of well-specified fits, one-sided).
CHI2_Z = 2.0
#: Correlation lengths ell (degrees of D, the module docstring's distance) the likelihood
#: chooses from; 0 is independent errors.
LENGTHS = (0.0, 2.5, 5.0, 10.0, 20.0, 40.0, 80.0)
#: The kinds of term a fit can estimate (``model_error=``, ``--model-error``): none, an
#: independent error (ell = 0), or ell chosen by the likelihood among :data:`LENGTHS`.
KINDS = ("off", "independent", "correlated")
#: The fits' default kind: correlated (docs/validity.md: with the error steps 1 and 2 share
#: counted, :func:`~veil.fitting.shared_error.shared`, it covers every path-traced session
#: at 1.5-5 times the noise's standard errors; the independent one leaves four of ten short).
DEFAULT = "correlated"
#: The largest relative model error s a term holds (and a result file may give): s is the
#: standard deviation of the model's miss in units of its own value, so 1 already says the
#: model is off by as much as it predicts; beyond a million times its value it says nothing
#: more, and s^2 times a covariance stays far inside float64. The likelihood's estimate is
#: capped here (reached only by a model that is about zero where the data are not).
MAX_SIGMA = 1e6
#: Where a step's term came from (``ModelError.source``).
SOURCES = ("none", "own residuals", "given medium", "model's floor")


def chi2_threshold(dof: int) -> float:
    """The reduced chi-square above which a fit's residuals show a model error."""
    return 1.0 + CHI2_Z * math.sqrt(2.0 / max(int(dof), 1))


def shows_excess(residuals, dof: int) -> bool:
    """Whether finite weighted ``residuals`` with ``dof`` degrees of freedom have a reduced
    chi-square above :func:`chi2_threshold`: the test before any term is estimated."""
    r = np.asarray(residuals, dtype=float)
    dof = int(dof)
    if dof < 1 or r.size == 0 or not np.all(np.isfinite(r)):
        return False
    return float(r @ r) / dof > chi2_threshold(dof)


def _unit(theta, phi) -> np.ndarray:
    t, p = np.radians(theta), np.radians(phi)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def distances(angles, other=None) -> np.ndarray:
    """D_ij (degrees): the angle between configurations i and j's incident directions plus
    that between their reflected ones, from canonical ``angles`` (theta_i, phi_i, theta_r,
    phi_r in degrees); j over ``other``'s configurations when given (else ``angles``')."""
    ti, pi, tr, pr = (np.asarray(a, dtype=float) for a in angles)
    tj, pj, trj, prj = (
        (ti, pi, tr, pr) if other is None else (np.asarray(a, dtype=float) for a in other)
    )
    out = np.zeros((ti.size, tj.size))
    for u, v in ((_unit(ti, pi), _unit(tj, pj)), (_unit(tr, pr), _unit(trj, prj))):
        out += np.degrees(np.arccos(np.clip(u @ v.T, -1.0, 1.0)))
    return out


def correlation(dist: np.ndarray, length: float) -> np.ndarray:
    """exp(-D / ell), the identity for ell = 0."""
    if length == 0.0:
        return np.eye(len(dist))
    return np.exp(-np.asarray(dist) / length)


def _nll(r, a, corr, t) -> float:
    """Minus the log-likelihood (up to a constant) of weighted residuals ``r`` under
    I + t A R A."""
    cov = np.eye(r.size) + t * (a[:, None] * corr * a[None, :])
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, r)
    return float(np.sum(np.log(np.diag(chol))) + 0.5 * z @ z)


def check_kind(kind) -> str:
    """``kind`` as one of :data:`KINDS` (None: :data:`DEFAULT`; True and False mean
    "independent" and "off"); a FitError otherwise."""
    if kind is None:
        return DEFAULT
    if isinstance(kind, bool):
        return "independent" if kind else "off"
    if kind not in KINDS:
        raise FitError(f"model_error = {kind!r}; expected one of {', '.join(KINDS)}")
    return kind


def _spectrum(r, a, corr, basis=None):
    """(lam, (Q^T r)^2) of B = A R A = Q diag(lam) Q^T: the likelihood under I + t B for
    every t from one eigendecomposition (O(N) per t instead of a Cholesky). With a
    ``basis`` P of the residuals' space (:func:`_complement`), of P^T B P and P^T r."""
    b = a[:, None] * np.asarray(corr) * a[None, :]
    if basis is not None:
        b, r = basis.T @ b @ basis, basis.T @ r
    lam, q = np.linalg.eigh(0.5 * (b + b.T))
    return np.maximum(lam, 0.0), (q.T @ r) ** 2


def _nll_spectrum(spectrum, t) -> float:
    """:func:`_nll` from :func:`_spectrum`."""
    lam, rq2 = spectrum
    v = 1.0 + t * lam
    return float(0.5 * np.sum(np.log(v) + rq2 / v))


def _nll_independent(r, a, t) -> float:
    """:func:`_nll` for R = I, in closed form (no N x N matrix)."""
    v = 1.0 + t * a * a
    return float(0.5 * np.sum(np.log(v) + r * r / v))


def _complement(weighted_jacobian, n: int) -> np.ndarray | None:
    """An orthonormal basis (n x (n - p)) of the complement of the weighted Jacobian's
    columns (its first ``n`` rows, the data's): the directions the fit leaves in its
    residuals. None without a Jacobian."""
    if weighted_jacobian is None:
        return None
    jw = np.asarray(weighted_jacobian, dtype=float)[:n]
    # full column rank (the fits that get here have a covariance): the span is that of all
    # columns, whatever their units
    u, _, _ = np.linalg.svd(jw, full_matrices=True)
    return u[:, min(jw.shape[1], n) :]


def estimate(
    residuals, scaled_values, dof: int, dist, lengths=LENGTHS, weighted_jacobian=None
) -> tuple[float, float]:
    """(s, ell) of the module docstring: (0, 0) when the reduced chi-square is not above
    :func:`chi2_threshold`, else the maximum of the likelihood over ell in ``lengths``
    and s. ``residuals`` r_i = (y - f) / sigma, ``scaled_values`` a_i = f / sigma, ``dist``
    the configurations' distances (:func:`distances`; a callable returning them is called
    only when a length ell > 0 is tried). With the fit's ``weighted_jacobian`` J_w (free
    parameters' columns) the likelihood is the restricted one (REML): that of the residuals'
    components outside J_w's columns, Q^T r ~ N(0, I + s^2 Q^T A R A Q), since the fit
    absorbs the rest of the error into its parameters - most of a smooth one, which the
    residuals alone would under-estimate. s is at most :data:`MAX_SIGMA`. A FitError when
    no relative error can explain an excess (every a_i = 0)."""
    r = np.asarray(residuals, dtype=float)
    a = np.asarray(scaled_values, dtype=float)
    dof = int(dof)
    if not np.all(np.isfinite(a)) or not shows_excess(r, dof):
        return 0.0, 0.0
    if not np.any(a != 0):
        raise FitError(
            "the residuals exceed the noise where the model is zero: no relative "
            "model error explains them"
        )
    best = min(_profile(r, a, dof, dist, lengths, weighted_jacobian), key=lambda t: t[0])
    return min(best[1], MAX_SIGMA), best[2]


def _profile(r, a, dof: int, dist, lengths, weighted_jacobian) -> list[tuple[float, float, float]]:
    """(minus the restricted log-likelihood at its best s, that s, ell) for each ell of
    ``lengths`` (:func:`estimate`'s likelihood, without its chi-square test)."""
    # s^2 a^2 of the order of the excess per point: search log s around it, wide
    guess = math.sqrt(max(float(r @ r) / dof - 1.0, 1e-6) / float(np.mean(a**2)))
    basis = _complement(weighted_jacobian, r.size)
    out = []
    for length in lengths:
        if length == 0.0 and basis is None:

            def nll_independent(u):
                return _nll_independent(r, a, math.exp(2 * u))

            nll = nll_independent
        else:
            if length > 0.0 and callable(dist):
                dist = dist()
            corr = np.eye(r.size) if length == 0.0 else correlation(dist, length)
            spectrum = _spectrum(r, a, corr, basis)

            def nll_spectrum(u, spectrum=spectrum):
                return _nll_spectrum(spectrum, math.exp(2 * u))

            nll = nll_spectrum
        found = minimize_scalar(
            nll,
            bounds=(math.log(guess) - 6.0, math.log(guess) + 6.0),
            method="bounded",
            options={"xatol": 1e-6},
        )
        out.append((float(found.fun), math.exp(float(found.x)), float(length)))
    return out


def length_profile(
    residuals, scaled_values, dof: int, dist, lengths=LENGTHS, weighted_jacobian=None
) -> np.ndarray | None:
    """Minus the restricted log-likelihood of :func:`estimate` at its best s for each ell
    of ``lengths`` (one fit's part of a likelihood summed over several fits that share ell:
    the maps' pixels, docs/maps-model-error.md); None when the fit's reduced chi-square
    does not show a model error (:func:`estimate` would give s = 0)."""
    r = np.asarray(residuals, dtype=float)
    a = np.asarray(scaled_values, dtype=float)
    dof = int(dof)
    if not np.all(np.isfinite(a)) or not shows_excess(r, dof) or not np.any(a != 0):
        return None
    return np.array([f for f, _, _ in _profile(r, a, dof, dist, lengths, weighted_jacobian)])


def sandwich(
    cov: np.ndarray,
    weighted_jacobian: np.ndarray,
    scaled_values,
    sigma: float,
    corr: np.ndarray | None = None,
) -> np.ndarray:
    """C + s^2 (A J_w C)^T R (A J_w C) (module docstring): the covariance of the weighted
    estimate with the relative model error ``sigma`` (correlation ``corr``, None:
    independent) beside the noise. ``cov`` is C (free parameters, natural units),
    ``weighted_jacobian`` J_w (points x free parameters), ``scaled_values`` a = f / sigma."""
    cov = np.asarray(cov, dtype=float)
    if sigma == 0.0:
        return cov
    if not 0.0 <= sigma <= MAX_SIGMA:
        raise FitError(
            f"the model error sigma = {sigma!r}; expected a relative error in [0, {MAX_SIGMA:g}]"
        )
    m = (
        np.asarray(weighted_jacobian, dtype=float) * np.asarray(scaled_values, dtype=float)[:, None]
    ) @ cov
    rm = m if corr is None else np.asarray(corr, dtype=float) @ m
    extra = m.T @ rm
    return cov + sigma**2 * 0.5 * (extra + extra.T)


@dataclass(frozen=True)
class ModelError:
    """One fit's model-discrepancy term: ``sigma`` the relative model error used (0: none)
    and ``length`` its correlation length ell (degrees), ``own`` the s its own residuals
    show, ``given`` the given medium's (step 2; None otherwise), ``source`` which of them is
    used (:data:`SOURCES`), ``chi2_threshold`` the test's limit on the reduced chi-square,
    ``noise_only`` the uncertainties without any term, this fit's or one its given fit
    carried into ``stderr_total`` (keys stderr, correlation, stderr_total,
    correlation_total; None when no term entered). A medium's correlated term also keeps
    ``influence``, {parameter: d estimate / d_i for each configuration i, per unit s} (G =
    C J_w^T A of the module docstring's sandwich), and its configurations' canonical
    ``angles``, with its weighted ``residuals`` and scaled values a = f / sigma (``scaled``):
    step 2 needs them for the error the two steps share
    (:func:`~veil.fitting.shared_error.shared`) and how far it is shared
    (:func:`~veil.fitting.shared_error.session_correlation`). Step 2's term keeps that
    correlation as ``session_correlation`` (None when nothing is shared)."""

    sigma: float
    length: float
    own: float
    given: float | None
    source: str
    chi2_threshold: float
    noise_only: dict | None = None
    influence: dict | None = None
    angles: tuple | None = None
    residuals: tuple | None = None
    scaled: tuple | None = None
    session_correlation: float | None = None

    def to_dict(self) -> dict:
        out: dict[str, Any] = {
            "sigma": self.sigma,
            "length": self.length,
            "own": self.own,
            "given": self.given,
            "source": self.source,
            "chi2_threshold": self.chi2_threshold,
            "noise_only": self.noise_only,
        }
        if self.influence is not None:
            assert self.angles is not None  # they come together (from_dict)
            out["influence"] = {k: [float(v) for v in row] for k, row in self.influence.items()}
            out["angles"] = [[float(v) for v in a] for a in self.angles]
            if self.residuals is not None:
                assert self.scaled is not None  # they come together (from_dict)
                out["residuals"] = [float(v) for v in self.residuals]
                out["scaled"] = [float(v) for v in self.scaled]
        if self.session_correlation is not None:
            out["session_correlation"] = float(self.session_correlation)
        return out

    @classmethod
    def from_dict(cls, data, source: str = "the fit result") -> ModelError:
        """Check and convert the ``model_error`` entry of a result file."""
        keys = ("sigma", "length", "own", "given", "source", "chi2_threshold")
        if not isinstance(data, dict) or any(k not in data for k in keys):
            raise FitError(
                f"{source}: key 'model_error' must be null or an object with keys "
                f"{', '.join(keys)}, noise_only; got {data!r}"
            )
        for k in ("sigma", "length", "own", "chi2_threshold") + (
            ("given",) if data["given"] is not None else ()
        ):
            v = data[k]
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v < 0
            ):
                raise FitError(f"{source}: model_error.{k} = {v!r}; expected a number >= 0")
            if k in ("sigma", "own", "given") and v > MAX_SIGMA:
                raise FitError(
                    f"{source}: model_error.{k} = {v!r}; expected a relative model error "
                    f"in [0, {MAX_SIGMA:g}] (the model's miss in units of its own value)"
                )
        if data["source"] not in SOURCES:
            raise FitError(
                f"{source}: model_error.source = {data['source']!r}; expected one "
                f"of {', '.join(SOURCES)}"
            )
        noise = data.get("noise_only")
        if noise is not None and not isinstance(noise, dict):
            raise FitError(f"{source}: model_error.noise_only must be an object or null")
        influence, angles = data.get("influence"), data.get("angles")
        residuals, scaled = data.get("residuals"), data.get("scaled")
        if (
            (influence is None) != (angles is None)
            or (residuals is None) != (scaled is None)
            or (residuals is not None and influence is None)
        ):
            raise FitError(
                f"{source}: model_error.influence and model_error.angles come "
                f"together, and residuals and scaled only with them"
            )
        if influence is not None:
            influence, angles = _read_influence(influence, angles, source)
        if residuals is not None:
            assert angles is not None  # checked above: residuals come with the influence
            rows, _ = _read_influence(
                {"residuals": residuals, "scaled": scaled},
                [list(a) for a in angles],
                source,
                key="",
            )
            residuals, scaled = rows["residuals"], rows["scaled"]
        rho = data.get("session_correlation")
        if rho is not None and (
            isinstance(rho, bool) or not isinstance(rho, (int, float)) or not 0.0 <= rho <= 1.0
        ):
            raise FitError(
                f"{source}: model_error.session_correlation = {rho!r}; expected a number in [0, 1]"
            )
        return cls(
            float(data["sigma"]),
            float(data["length"]),
            float(data["own"]),
            None if data["given"] is None else float(data["given"]),
            data["source"],
            float(data["chi2_threshold"]),
            noise,
            influence,
            angles,
            residuals,
            scaled,
            None if rho is None else float(rho),
        )


def _read_influence(influence, angles, source: str, key: str = "influence"):
    """A result file's model_error.influence ({name: N numbers}; ``key`` names the entry in
    messages, "" for top-level lists) and angles (4 lists of N canonical angles), checked:
    finite numbers, one length."""

    def numbers(row, where):
        if (
            not isinstance(row, list)
            or not row
            or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                for v in row
            )
        ):
            raise FitError(f"{source}: {where} must be a non-empty list of finite numbers")
        return tuple(float(v) for v in row)

    if not isinstance(influence, dict) or not influence:
        raise FitError(f"{source}: model_error.influence must be an object of lists")
    if not isinstance(angles, list) or len(angles) != 4:
        raise FitError(
            f"{source}: model_error.angles must be 4 lists (theta_i, phi_i, theta_r, phi_r)"
        )
    rows = {
        k: numbers(v, f"model_error.{key + '.' if key else ''}{k}") for k, v in influence.items()
    }
    cols = tuple(numbers(a, "model_error.angles") for a in angles)
    sizes = {len(r) for r in rows.values()} | {len(a) for a in cols}
    if len(sizes) != 1:
        raise FitError(
            f"{source}: model_error.{key or ', '.join(rows)} and angles have "
            f"different lengths ({sorted(sizes)})"
        )
    return rows, cols


def step_term(
    residuals,
    values,
    weights,
    dof: int,
    angles,
    given=None,
    kind: str = DEFAULT,
    weighted_jacobian=None,
    floor=None,
    lengths=LENGTHS,
    dist=None,
) -> ModelError:
    """The term of one step (module docstring): its own (s, ell) from ``residuals``
    (weighted), the model ``values``, the ``weights`` 1/sigma and the configurations'
    canonical ``angles``, ell = 0 unless ``kind`` is "correlated"; ``given`` the given
    medium's term (step 2), None otherwise; ``weighted_jacobian`` the fit's J_w for the
    restricted likelihood (:func:`estimate`); ``floor`` the fit's models' declared error
    (s, ell) (``Model.MODEL_ERROR_FLOOR``): the term's s and ell are each at least the
    floor's (ell only when ``kind`` is "correlated"; source "model's floor" where its s
    decides). A shorter length with a larger s would average out over the configurations
    and report less than the floor's own process. ``lengths``: the ells a correlated term
    chooses from (the maps give the one their tile chose); ``dist``: the configurations'
    distances (or a callable returning them) when the caller has them."""
    correlated = check_kind(kind) == "correlated"
    lengths = lengths if correlated else (0.0,)
    own, length = estimate(
        residuals,
        np.asarray(values) * np.asarray(weights),
        dof,
        (lambda: distances(angles)) if dist is None else dist,
        lengths,
        weighted_jacobian,
    )
    sigma, source = own, "own residuals" if own > 0 else "none"
    if given is not None and given.sigma > own:  # its length only for a correlated term
        sigma, length, source = given.sigma, given.length if correlated else 0.0, "given medium"
    if floor is not None:
        floor_sigma, floor_length = float(floor[0]), (float(floor[1]) if correlated else 0.0)
        if floor_sigma > sigma:
            sigma, length, source = floor_sigma, floor_length, "model's floor"
        else:
            length = max(length, floor_length)
    return ModelError(
        float(sigma),
        float(length),
        float(own),
        None if given is None else float(given.sigma),
        source,
        chi2_threshold(dof),
    )


def given_term(given_result) -> ModelError | None:
    """The model-discrepancy term of a given medium's fit (a FitResult of step 1), else
    None."""
    if getattr(given_result, "kind", None) != "medium":
        return None
    return getattr(given_result, "model_error", None)


def noise_only(result) -> FitResult:
    """The result as without the model-discrepancy term: its uncertainties counting the
    data's noise only (the same object when it has no active term)."""
    me = result.model_error
    if me is None or me.noise_only is None:
        return result
    n = me.noise_only
    return dataclasses.replace(
        result,
        stderr=n["stderr"],
        correlation=n["correlation"],
        stderr_total=n.get("stderr_total"),
        correlation_total=n.get("correlation_total"),
        model_error=None,
    )


__all__ = [
    "CHI2_Z",
    "LENGTHS",
    "KINDS",
    "DEFAULT",
    "MAX_SIGMA",
    "SOURCES",
    "check_kind",
    "chi2_threshold",
    "shows_excess",
    "distances",
    "correlation",
    "estimate",
    "length_profile",
    "sandwich",
    "ModelError",
    "step_term",
    "given_term",
    "noise_only",
]
