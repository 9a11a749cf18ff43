"""Least-squares estimation of the two-step method (MODEL.md sec. 7); format in docs/fitting.md.

- step 0, :func:`fit_reference`: the reference object's f_r from clear-medium data, directly
  (MODEL.md sec. 2, no integral);
- step 1, :func:`fit_medium`: the medium's (T_d, T_t, g, eta_u) from the reference object in
  the medium, its f_r held fixed (MODEL.md sec. 3 and 5);
- step 2, :func:`fit_target`: the target's (P_d, P_s, n, eta_b) from the target in the medium,
  f_t held fixed.

Every fit minimizes sum(((model - value) / sigma)^2) (plain squared error without a sigma
column) with scipy's trust-region-reflective Levenberg-Marquardt ("trf"). Parameters
declared ``log_scale`` are fitted as logarithms, an open interval such as g in (-1, 1) through
atanh, the rest inside their bounds. Starting values never come from the caller: a coarse grid
over the nonlinear parameters (n, eta or g, eta_u), with the scale parameters solved exactly
at each grid point (the apparent value is linear in P_d, P_s and in T_d^2, T_d T_t, T_t^2),
gives several starts; the best fit among them wins. Through a medium the iterations run on
the "fast" quadrature and a final polish on the requested one, so the reported parameters,
residuals and chi-square are those of the requested accuracy.

Shared with :mod:`veil.joint`: the result (:mod:`veil.fit_result`), the data
(:mod:`veil.fit_data`), model evaluation (:mod:`veil.evaluation`), internal coordinates
(:mod:`veil.coordinates`), starting values (:mod:`veil.start_values`), tolerances, option
checks, goodness of fit and covariances (:mod:`veil.least_squares`) and the given models
(:mod:`veil.given_model`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from . import coordinates
from ..engine.apparent import RULES
from .coordinates import LOG_RANGE, OPEN_MARGIN  # noqa: F401
from ..engine.evaluator import ApparentModel, DirectModel
from .data import FitData, prepare
from .result import FORMAT, STEPS, FitError, FitResult  # noqa: F401
from .given import as_brdf_model, as_medium_model, check_variant, model_dict
from .solver import (ITERATION_ACCURACY, SINGULAR_NOTE, TOL_FINAL, TOL_ITER, TOL_POLISH,
                            as_fixed, check_accuracy, check_fixed, check_max_nfev, convincing,
                            covariance_from_jacobian, edge_note, goodness, outcome,
                            stopped_early_note, ticker, uncertainties)
from ..data.measurements import MeasurementError  # noqa: F401  (raised by the fits; importable here)
from ..models import BRDF, HenyeyGreenstein, Model, TorranceSparrow
from .start_values import START_GRIDS, brdf_scales, grid_points, medium_scales, pick_starts

# LOG_RANGE, OPEN_MARGIN (veil.coordinates) and FORMAT (veil.fit_result) stay importable from
# here, as do ITERATION_ACCURACY (veil.least_squares) and START_GRIDS (veil.start_values).

#: Least-squares runs started from the best distinct grid points, by step.
STARTS = {"reference": 3, "medium": 2, "target": 2}


# --------------------------------------------------------------------------------------
# parameters: free/fixed split and the internal (transformed) coordinates
# --------------------------------------------------------------------------------------
class _Space:
    """Free parameters of one model and their internal coordinates u (veil.coordinates)."""

    def __init__(self, cls: type[Model], fixed: dict, what: str):
        self.cls = cls
        self.names = cls.param_names()
        fixed = dict(fixed or {})
        unknown = [k for k in fixed if k not in self.names]
        if unknown:
            raise FitError(f"cannot fix {', '.join(map(repr, unknown))} in the {what} fit: "
                           f"{cls.NAME} has parameters {', '.join(self.names)}")
        for k, v in fixed.items():
            check_fixed(k, v, cls.PARAMS[self.names.index(k)], cls.__name__)
        self.fixed = {k: float(fixed[k]) for k in self.names if k in fixed}
        self.free = [i for i, n in enumerate(self.names) if n not in self.fixed]
        if not self.free:
            raise FitError(f"every parameter of the {what} fit is fixed "
                           f"({', '.join(self.names)}): nothing to fit")
        self.kind = [coordinates.coordinate(cls.PARAMS[i]) for i in self.free]

    def to_u(self, x: np.ndarray) -> np.ndarray:
        return np.array([coordinates.to_u(self.cls.PARAMS[i], x[i], k)
                         for k, i in zip(self.kind, self.free)])

    def to_x(self, u: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full parameter vector for internal coordinates u, and dx/du of the free ones."""
        x = np.array(base, dtype=float)
        d = np.empty(len(self.free))
        for j, (k, i) in enumerate(zip(self.kind, self.free)):
            x[i], d[j] = coordinates.to_x(self.cls.PARAMS[i], u[j], k)
        return x, d

    def bounds(self, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pairs = [coordinates.bounds(self.cls.PARAMS[i], u0[j], k)
                 for j, (k, i) in enumerate(zip(self.kind, self.free))]
        return np.array([lo for lo, _ in pairs]), np.array([hi for _, hi in pairs])

    def at_bound(self, u: np.ndarray, u0_bounds) -> list[str]:
        return coordinates.at_bound(u, u0_bounds, [self.names[i] for i in self.free])


# --------------------------------------------------------------------------------------
# the least-squares driver
# --------------------------------------------------------------------------------------
class _Objective:
    """Residuals and Jacobian in internal coordinates, with a one-point cache."""

    def __init__(self, space: _Space, base, data: FitData, values, jacobian, on_eval=None):
        self.space, self.base, self.data = space, np.asarray(base, float), data
        self._values, self._jacobian = values, jacobian
        self.w = data.w
        self.on_eval = on_eval
        self.nfev = self.njev = 0
        self._key = None
        self._val = None

    def residuals(self, u):
        x, _ = self.space.to_x(u, self.base)
        self.nfev += 1
        val = self._values(x)
        self._key, self._val = u.tobytes(), val
        if self.on_eval:
            self.on_eval()
        return (val - self.data.y) * self.w

    def jac(self, u):
        x, d = self.space.to_x(u, self.base)
        self.njev += 1
        jac = self._jacobian(x)
        return jac[:, self.space.free] * d[None, :] * self.w[:, None]


def _run_lsq(objective: _Objective, u0, bounds, tol, max_nfev):
    lo, hi = bounds
    u0 = np.clip(u0, lo, hi)
    return least_squares(objective.residuals, u0, jac=objective.jac, bounds=(lo, hi),
                         method="trf", x_scale="jac", max_nfev=max_nfev, **tol)


def _finish(step, cls, space: _Space, x, data: FitData, model_values, jac_x, lsq,
            message_extra, variant, accuracy, given, stats, propagate=None) -> FitResult:
    """Assemble a FitResult from the solution x (full vector) and the final Jacobian.

    ``propagate`` = (d values / d given parameters (M, kg), their covariance (kg, kg)) adds
    the given model's uncertainty to first order: d x / d theta = -J^+ J_theta."""
    w = data.w
    k = len(space.free)
    res, chi2, rms_rel = goodness(data.y, w, model_values, k)
    jw = jac_x[:, space.free] * w[:, None]
    cov = covariance_from_jacobian(jw, np.ones(k))
    notes = list(message_extra)
    if cov is not None and data.sigma is None:
        cov = cov * chi2
    names = space.names
    stderr, corr = {n: None for n in names}, {}
    stderr_total = corr_total = None
    if cov is None:
        notes.append(SINGULAR_NOTE)
    else:
        stderr, corr = uncertainties(cov, names, space.free)
        if propagate is not None:
            jg, cov_g = propagate
            sens = -np.linalg.lstsq(jw, jg * w[:, None], rcond=None)[0]
            stderr_total, corr_total = uncertainties(cov + sens @ cov_g @ sens.T, names,
                                                      space.free)
    converged, message = outcome(lsq.status, lsq.message, notes)
    return FitResult(model=cls.NAME, params={n: float(x[i]) for i, n in enumerate(names)},
                     stderr=stderr, correlation=corr, residuals=tuple(float(r) for r in res),
                     chi2_reduced=chi2, rms_relative=rms_rel, n_points=data.size,
                     converged=converged, message=message, variant=variant,
                     fixed=dict(space.fixed), step=step, weighted=data.sigma is not None,
                     accuracy=accuracy, given=given, stderr_total=stderr_total,
                     correlation_total=corr_total, stats=stats)


def _check_size(data: FitData, space: _Space, what: str) -> None:
    k = len(space.free)
    if data.size <= k:
        raise FitError(f"the {what} data have {data.size} point(s) but the fit has {k} free "
                       f"parameter(s) ({', '.join(space.names[i] for i in space.free)}): "
                       f"need more points than free parameters (fix some with fixed=... / "
                       f"--fix NAME=VALUE, or measure more configurations)")


def _emit(progress, stage, done, total):
    if progress is not None:
        progress(stage, done, total)


def _convincing(lsq, space, bounds, data) -> bool:
    """A weighted fit that converged inside its search range with reduced chi-square <= 2."""
    return convincing(lsq.status, lsq.cost, data.size - len(space.free),
                      data.sigma is not None, space.at_bound(lsq.x, bounds))


def _multi_start(step, space, data, scored, values_fn, jac_fn, max_nfev, progress, tol,
                 every: bool):
    """Least squares from the best distinct grid points: all of them when ``every``, else
    the next only while the fits so far are not convincing. Returns (best, runs, starts)."""
    runs = []
    starts = pick_starts(scored, STARTS[step])
    for s, (cost0, combo, x0) in enumerate(starts):
        if runs and not every and any(_convincing(r[0], space, r[2], data) for r in runs):
            break
        u0 = space.to_u(x0)
        bounds = space.bounds(u0)
        tick = ticker(progress, f"start {s + 1}/{len(starts)}: iteration")
        obj = _Objective(space, x0, data, values_fn, jac_fn, tick)
        lsq = _run_lsq(obj, u0, bounds, tol, max_nfev)
        runs.append((lsq, obj, bounds))
    best = min(range(len(runs)), key=lambda r: (runs[r][0].cost, r))
    return best, runs, starts


# --------------------------------------------------------------------------------------
# step 0: the reference's f_r in a clear medium
# --------------------------------------------------------------------------------------
def fit_reference(table, *, fixed=None, black=None, max_nfev=None,
                  progress=None) -> FitResult:
    """Step 0 (MODEL.md sec. 7): fit Torrance-Sparrow f_r to clear-medium data, directly.

    table : measurement table (DataFrame or CSV path, docs/measurements.md).
    fixed : parameters held at given values, e.g. ``{"eta": 1.5}``.
    black : black-cloth table subtracted first (a clear medium normally has none).
    max_nfev : limit on function evaluations of each least-squares run (None: scipy's).
    progress : called as progress(stage, done, total) while fitting.
    """
    return fit_direct(table, fixed=fixed, black=black, max_nfev=max_nfev, progress=progress,
                      step="reference")


def fit_direct(table, *, fixed=None, black=None, max_nfev=None, progress=None,
               step: str = "direct") -> FitResult:
    """f_r fitted to clear-medium data (MODEL.md sec. 2); ``step`` labels the result
    ("reference" for step 0, "direct" for a target measured without the medium)."""
    check_max_nfev(max_nfev)
    cls = TorranceSparrow
    what = "reference" if step == "reference" else "target"
    space = _Space(cls, as_fixed(fixed), f"{what} (clear medium)")
    data = prepare(table, black, f"{what} (clear medium)")
    _check_size(data, space, f"{what} (clear medium)")
    direct = DirectModel(cls, data.angles)
    base = np.array([space.fixed.get(n, 1.0) for n in space.names], dtype=float)
    i_d, i_s = cls.scale_index("separable"), cls.scale_index("lobe")
    points = grid_points(cls, "reference", space.free, base)
    scored = []
    for k, (combo, x) in enumerate(points):
        xs, xl = x.copy(), x.copy()
        xs[i_d], xs[i_s] = 1.0, 0.0
        xl[i_d], xl[i_s] = 0.0, 1.0
        basis = np.stack([direct.values(xs), direct.values(xl)], axis=1)
        x, cost = brdf_scales(basis, x, cls, space.fixed, data.y, data.w)
        scored.append((cost, combo, x))
        _emit(progress, "starting grid", k + 1, len(points))

    def values_fn(x):
        return direct.values(x)

    def jac_fn(x):
        return direct.value_and_jacobian(x)[1]

    best, runs, starts = _multi_start("reference", space, data, scored, values_fn, jac_fn,
                                      max_nfev, progress, TOL_FINAL, every=True)
    lsq, obj, bounds = runs[best]
    x, _ = space.to_x(lsq.x, obj.base)
    values, jac = direct.value_and_jacobian(x)
    notes = _bound_notes(space, lsq.x, bounds)
    stats = {"grid_points": len(points), "starts": len(runs), "best_start": best + 1,
             "nfev": sum(r[1].nfev for r in runs), "njev": sum(r[1].njev for r in runs),
             "runs": [_run_stats(r[0], r[1]) for r in runs]}
    return _finish(step, cls, space, x, data, values, jac, lsq, notes, None, None, None, stats)


def _bound_notes(space, u, bounds) -> list[str]:
    hit = space.at_bound(u, bounds)
    return [edge_note(hit)] if hit else []


def _run_stats(lsq, obj) -> dict:
    return {"nfev": int(obj.nfev), "njev": int(obj.njev), "status": int(lsq.status),
            "cost": float(lsq.cost)}


# --------------------------------------------------------------------------------------
# steps 1 and 2: through the medium
# --------------------------------------------------------------------------------------
def _through_medium(step, cls, space, data, brdf, medium, accuracy, max_nfev, progress,
                    given_result=None):
    """Steps 1 (medium free) and 2 (BRDF free): grid, fast iterations, polish."""
    fitting_medium = step == "medium"
    iter_rule = RULES[ITERATION_ACCURACY]
    fast = ApparentModel(brdf, medium, data.angles, iter_rule)
    polish = accuracy != ITERATION_ACCURACY
    # everything this fit will compile, compiled side by side while the grid starts
    fast.prepare(values=True, jacobian=True)
    if polish:
        final = ApparentModel(brdf, medium, data.angles, RULES[accuracy])
        final.prepare(values=True)
    template = medium if fitting_medium else brdf
    base = template.to_vector()
    for n, v in space.fixed.items():
        base[space.names.index(n)] = v
    vb_fixed, vm_fixed = brdf.to_vector(), medium.to_vector()

    def split(x):
        return (vb_fixed, x) if fitting_medium else (x, vm_fixed)

    points = grid_points(cls, step, space.free, base)
    scored = []
    for k, (combo, x) in enumerate(points):
        vb, vm = split(x)
        terms = fast.terms(vb, vm)
        if fitting_medium:
            cols = np.array([vb[brdf.scale_index("separable")], vb[brdf.scale_index("lobe")]])
            basis = np.einsum("mkb,b->mk", terms, cols)
            x, cost = medium_scales(basis, x, cls, space.fixed, data.y, data.w)
        else:
            td, tt = vm[medium.scale_index("iso")], vm[medium.scale_index("lobe")]
            basis = np.einsum("mkb,k->mb", terms, np.array([td * td, td * tt, tt * tt]))
            x, cost = brdf_scales(basis, x, cls, space.fixed, data.y, data.w)
        scored.append((cost, combo, x))
        _emit(progress, "starting grid", k + 1, len(points))
    nb = len(brdf.PARAMS)
    cut = slice(nb, None) if fitting_medium else slice(0, nb)
    cache = {}

    def fast_values(x):
        return fast.values(*split(x))

    def full_jac(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = fast.value_and_jacobian(*split(x))
        return cache[key][1]

    def fast_jac(x):
        return full_jac(x)[:, cut]

    tol = TOL_ITER if polish else TOL_FINAL
    best, runs, starts = _multi_start(step, space, data, scored, fast_values, fast_jac,
                                      max_nfev, progress, tol, every=False)
    lsq, obj, bounds = runs[best]
    run_stats = [_run_stats(r[0], r[1]) for r in runs]
    notes = []
    if polish:
        if lsq.status <= 0:
            notes.append(stopped_early_note(lsq.message))
        tick = ticker(progress, f"polish at {accuracy!r}: iteration")

        def final_values(x):
            return final.values(*split(x))

        # The polish uses the Jacobian of the fast rule, frozen at the fast solution when
        # that converged (a chord method: it differs from the polish rule's Jacobian by that
        # rule's ~0.3 % error and the solution moves by a fraction of a standard error, so
        # the polish still converges to the optimum of the requested rule); the standard
        # errors use the fast rule's Jacobian at the final solution.
        if lsq.status > 0:
            x_fast, _ = space.to_x(lsq.x, obj.base)
            frozen = fast_jac(x_fast)

            def polish_jac(x):
                return frozen
        else:
            polish_jac = fast_jac
        pobj = _Objective(space, obj.base, data, final_values, polish_jac, tick)
        lsq = _run_lsq(pobj, lsq.x, bounds, TOL_POLISH, max_nfev)
        run_stats.append({**_run_stats(lsq, pobj), "polish": True})
        x, _ = space.to_x(lsq.x, obj.base)
        if pobj._key == lsq.x.tobytes():
            values = pobj._val
        else:
            values = final_values(x)
        engine_calls = {ITERATION_ACCURACY: [fast.values_calls, fast.jacobian_calls],
                        accuracy: [final.values_calls, final.jacobian_calls]}
    else:
        x, _ = space.to_x(lsq.x, obj.base)
        values = fast_values(x)
        engine_calls = {ITERATION_ACCURACY: [fast.values_calls, fast.jacobian_calls]}
    jac = fast_jac(x)
    propagate = None
    if given_result is not None:
        found = given_result.covariance(total=True)
        if found is not None:
            gnames, gcov = found
            gmodel = brdf if fitting_medium else medium
            offset = 0 if fitting_medium else nb
            cols = [offset + gmodel.param_names().index(n) for n in gnames]
            propagate = (full_jac(x)[:, cols], gcov)
    notes += _bound_notes(space, lsq.x, bounds)
    stats = {"grid_points": len(points), "starts": len(runs), "best_start": best + 1,
             "nfev": sum(r["nfev"] for r in run_stats), "njev": sum(r["njev"] for r in run_stats),
             "runs": run_stats, "engine_calls": engine_calls,
             "configurations": data.size}
    given = model_dict(brdf if fitting_medium else medium)
    variant = medium.options().get("variant")
    return _finish(step, cls, space, x, data, values, jac, lsq, notes, variant, accuracy,
                   given, stats, propagate)


def fit_medium(table, reference, *, fixed=None, black=None, variant: str = "paper",
               accuracy: str = "default", max_nfev=None, progress=None) -> FitResult:
    """Step 1 (MODEL.md sec. 7): fit the medium (T_d, T_t, g, eta_u), the reference f_r fixed.

    table : the reference object measured in the medium (DataFrame or CSV path).
    reference : the step-0 :class:`FitResult` or a :class:`TorranceSparrow`.
    variant : Fresnel variant of the medium, "paper" or "exit" (MODEL.md sec. 3).
    accuracy : quadrature of the reported result ("fast", "default", "high"); iterations
        run at "fast" and are polished at this accuracy.
    Other arguments as :func:`fit_reference`.
    """
    check_accuracy(accuracy)
    check_variant(variant)
    check_max_nfev(max_nfev)
    brdf = as_brdf_model(reference)
    cls = HenyeyGreenstein
    space = _Space(cls, as_fixed(fixed), "medium")
    data = prepare(table, black, "reference (in the medium)")
    _check_size(data, space, "medium")
    template = HenyeyGreenstein(1.0, 1.0, 0.9, 1.33, variant=variant)
    return _through_medium("medium", cls, space, data, brdf, template, accuracy, max_nfev,
                           progress, reference if isinstance(reference, FitResult) else None)


def fit_target(table, medium, *, fixed=None, black=None, variant: str | None = None,
               accuracy: str = "default", max_nfev=None, progress=None) -> FitResult:
    """Step 2 (MODEL.md sec. 7): fit the target's (P_d, P_s, n, eta_b), the medium fixed.

    table : the target object measured in the medium (DataFrame or CSV path).
    medium : the step-1 :class:`FitResult` or a :class:`HenyeyGreenstein`.
    variant : None uses the medium's; a different value is an error.
    Other arguments as :func:`fit_medium`.
    """
    check_accuracy(accuracy)
    if variant is not None:
        check_variant(variant)
    check_max_nfev(max_nfev)
    model_m = as_medium_model(medium, variant)
    cls = TorranceSparrow
    space = _Space(cls, as_fixed(fixed), "target")
    data = prepare(table, black, "target (in the medium)")
    _check_size(data, space, "target")
    template = TorranceSparrow(1.0, 1.0, 0.5, 1.5)
    return _through_medium("target", cls, space, data, template, model_m, accuracy, max_nfev,
                           progress, medium if isinstance(medium, FitResult) else None)


def model_values(result_or_model, other, angles, accuracy: str = "default") -> np.ndarray:
    """Values of a fitted model at canonical ``angles``: f_r alone for a BRDF when ``other`` is
    None, else the apparent reflectance with ``other`` (the medium or the BRDF)."""
    model = result_or_model.as_model() if isinstance(result_or_model, FitResult) \
        else result_or_model
    angles = tuple(np.asarray(a, dtype=float) for a in angles)
    if other is None:
        return DirectModel(type(model), angles).values(model.to_vector())
    if isinstance(other, FitResult):
        other = other.as_model()
    brdf, medium = (model, other) if isinstance(model, BRDF) else (other, model)
    engine = ApparentModel(brdf, medium, angles, RULES[accuracy])
    return engine.values(brdf.to_vector(), medium.to_vector())


__all__ = ["FitResult", "FitError", "fit_reference", "fit_direct", "fit_medium", "fit_target",
           "prepare", "model_values", "STEPS", "START_GRIDS", "STARTS"]
