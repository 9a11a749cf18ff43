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
"""

from __future__ import annotations

import itertools
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pandas as pd
from scipy.optimize import least_squares, nnls

from ._jax import jax, jnp
from .angles import direction
from .apparent import RULES
from .forward import Forward
from .measurements import (CANONICAL, MeasurementError, _Rows, atomic_write_text,
                           canonical_angles, load_measurements, subtract_black, validate)
from .models import BRDF, BTDF, HenyeyGreenstein, Model, REGISTRY, TorranceSparrow, model_class
from .simulate import CHUNK

STEPS = ("reference", "medium", "target")
#: Quadrature of the iterations through a medium; the polish uses the requested accuracy.
ITERATION_ACCURACY = "fast"
#: Grids of starting values over the nonlinear parameters, by model class and step.
START_GRIDS = {
    (TorranceSparrow, "reference"): {"n": tuple(np.round(np.geomspace(0.03, 5.0, 16), 4)),
                                     "eta": (1.2, 1.5, 2.0)},
    (TorranceSparrow, "target"): {"n": (0.08, 0.13, 0.2, 0.3, 0.45, 0.65, 0.9, 1.3, 2.0),
                                  "eta": (1.5,)},
    (HenyeyGreenstein, "medium"): {"g": (0.5, 0.7, 0.8, 0.88, 0.93, 0.96, 0.98, 0.99, 0.995),
                                   "eta": (1.33,)},
}
#: Least-squares runs started from the best distinct grid points, by step.
STARTS = {"reference": 3, "medium": 2, "target": 2}
#: Internal search range (natural-log units) of log-scale parameters without a finite bound.
LOG_RANGE = 40.0
#: Open bounds are kept this fraction of the interval's width away.
OPEN_MARGIN = 1e-6
#: Termination of scipy's least_squares. A relative cost change below 1e-6 at the optimum
#: (cost ~ n_points / 2 for a good weighted fit) leaves every parameter within about 1 % of
#: its standard error of the optimum: enough for the iterations before a polish and for the
#: polish itself (whose fast-rule Jacobian makes finer steps a matter of chance). Direct
#: fits of f_r are cheap and use the tight tolerances.
_TOL_ITER = {"ftol": 1e-6, "xtol": 1e-6, "gtol": 1e-8}
_TOL_POLISH = _TOL_ITER
_TOL_FINAL = {"ftol": 1e-8, "xtol": 1e-8, "gtol": 1e-8}
FORMAT = "veil.fit/1"

#: Signature of the ``progress`` callbacks: progress(stage, done, total or None).
Progress = Callable[[str, "int | None", "int | None"], None]


class FitError(ValueError):
    """A fit that cannot be set up (bad data, bad options, bad reference); says what to fix."""


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FitResult:
    """One fitted model (MODEL.md sec. 7): values, uncertainties and goodness of fit.

    ``params`` holds every parameter in the model's order (fixed ones too, see ``fixed``);
    ``stderr`` is None for fixed parameters or when the Jacobian is singular. ``residuals``
    are (value - model) / sigma when ``weighted``, else value - model. ``chi2_reduced`` is
    sum(residuals^2) / (n_points - free parameters); ``rms_relative`` the rms of
    (value - model) / model. ``given`` is the model held fixed (the reference BRDF for the
    medium step, the medium for the target step). ``stderr`` and ``correlation`` treat it as
    exact; ``stderr_total`` and ``correlation_total`` add its own uncertainty when it came
    from a fit (first-order propagation, docs/fitting.md), else they are None.
    """

    model: str
    params: dict
    stderr: dict
    correlation: dict
    residuals: tuple
    chi2_reduced: float
    rms_relative: float
    n_points: int
    converged: bool
    message: str
    variant: str | None = None
    fixed: dict = field(default_factory=dict)
    step: str | None = None
    weighted: bool = True
    accuracy: str | None = None
    given: dict | None = None
    stderr_total: dict | None = None
    correlation_total: dict | None = None
    stats: dict = field(default_factory=dict)

    # -- models ----------------------------------------------------------------------------
    def as_model(self) -> Model:
        """The fitted model instance (TorranceSparrow or HenyeyGreenstein with its variant)."""
        cls = model_class(self.model)
        model = cls(**self.params)
        if self.variant is not None and "variant" in model.options():
            model = model.replace(variant=self.variant)
        return model

    @property
    def free(self) -> tuple[str, ...]:
        return tuple(n for n in self.params if n not in self.fixed)

    def covariance(self, total: bool = True):
        """(free names, covariance matrix) from the standard errors and correlations;
        ``total`` prefers the propagated ones. None if the uncertainties are undetermined."""
        se, corr = self.stderr, self.correlation
        if total and self.stderr_total is not None:
            se, corr = self.stderr_total, self.correlation_total or {}
        names = self.free
        if not names or any(se.get(n) is None for n in names):
            return None
        s = np.array([se[n] for n in names])
        r = np.eye(len(names))
        for a, na in enumerate(names):
            for b, nb in enumerate(names):
                if a != b:
                    v = corr.get(na, {}).get(nb)
                    r[a, b] = 0.0 if v is None else v
        return names, r * np.outer(s, s)

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "model": self.model,
            "step": self.step,
            "params": {k: float(v) for k, v in self.params.items()},
            "stderr": {k: _json_float(v) for k, v in self.stderr.items()},
            "correlation": {a: {b: _json_float(r) for b, r in row.items()}
                            for a, row in self.correlation.items()},
            "chi2_reduced": _json_float(self.chi2_reduced),
            "rms_relative": _json_float(self.rms_relative),
            "n_points": int(self.n_points),
            "converged": bool(self.converged),
            "message": self.message,
            "variant": self.variant,
            "fixed": {k: float(v) for k, v in self.fixed.items()},
            "weighted": bool(self.weighted),
            "accuracy": self.accuracy,
            "given": self.given,
            "stderr_total": None if self.stderr_total is None else
            {k: _json_float(v) for k, v in self.stderr_total.items()},
            "correlation_total": None if self.correlation_total is None else
            {a: {b: _json_float(r) for b, r in row.items()}
             for a, row in self.correlation_total.items()},
            "stats": self.stats,
            "residuals": [_json_float(r) for r in self.residuals],
        }

    def to_json(self, path) -> None:
        """Write the result as JSON (keys in docs/fitting.md), atomically."""
        text = json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"
        atomic_write_text(path, text)

    @classmethod
    def from_dict(cls, data: dict, source: str = "the fit result") -> "FitResult":
        """Check and convert a dictionary written by :meth:`to_dict`."""
        if not isinstance(data, dict):
            raise FitError(f"{source}: expected a JSON object with keys model, params, ...; "
                           f"got {type(data).__name__}")
        required = ("model", "params", "stderr", "correlation", "chi2_reduced", "rms_relative",
                    "n_points", "converged", "message", "variant")
        missing = [k for k in required if k not in data]
        if missing:
            raise FitError(f"{source}: missing key(s) {', '.join(missing)}; is this a fit "
                           f"result written by veil (veil fit ... -o FILE.json)?")
        name = data["model"]
        if name not in REGISTRY:
            raise FitError(f"{source}: key 'model' = {name!r} is not a known model "
                           f"({', '.join(sorted(REGISTRY))})")
        mcls = REGISTRY[name]
        names = mcls.param_names()
        params = data["params"]
        if not isinstance(params, dict) or list(params) != list(names):
            got = list(params) if isinstance(params, dict) else params
            raise FitError(f"{source}: key 'params' must map exactly {', '.join(names)} (in "
                           f"this order) for model {name}; got {got!r}")
        for k, v in params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise FitError(f"{source}: params.{k} = {v!r} is not a number")
        variant = data["variant"]
        from .models.henyey_greenstein import VARIANTS
        if variant is not None and variant not in VARIANTS:
            raise FitError(f"{source}: key 'variant' = {variant!r}; expected one of "
                           f"{', '.join(VARIANTS)} or null")
        try:
            model = mcls(**{k: float(v) for k, v in params.items()})
            if "variant" in model.options():
                if variant is None:
                    raise ValueError(f"model {name} needs a variant ({', '.join(VARIANTS)})")
                model.replace(variant=variant)
        except (ValueError, TypeError) as exc:
            raise FitError(f"{source}: {exc}") from None
        stderr = data["stderr"]
        if not isinstance(stderr, dict) or set(stderr) - set(names):
            raise FitError(f"{source}: key 'stderr' must map parameter names ({', '.join(names)})"
                           f" to numbers or null; got {stderr!r}")
        fixed = data.get("fixed") or {}
        if not isinstance(fixed, dict) or set(fixed) - set(names):
            raise FitError(f"{source}: key 'fixed' must map parameter names to values; "
                           f"got {fixed!r}")
        step = data.get("step")
        if step is not None and step not in STEPS + ("direct",):
            raise FitError(f"{source}: key 'step' = {step!r}; expected one of "
                           f"{', '.join(STEPS)}, direct or null")
        for key in ("n_points",):
            if isinstance(data[key], bool) or not isinstance(data[key], int) or data[key] < 0:
                raise FitError(f"{source}: key {key!r} = {data[key]!r}; expected an integer >= 0")
        if not isinstance(data["converged"], bool):
            raise FitError(f"{source}: key 'converged' = {data['converged']!r}; expected "
                           f"true or false")
        return cls(
            model=name, params={k: float(v) for k, v in params.items()},
            stderr={k: _from_json_float(stderr.get(k)) for k in names},
            correlation={a: {b: _from_json_float(r) for b, r in row.items()}
                         for a, row in (data["correlation"] or {}).items()},
            residuals=tuple(_from_json_float(r) for r in data.get("residuals") or ()),
            chi2_reduced=_from_json_float(data["chi2_reduced"]),
            rms_relative=_from_json_float(data["rms_relative"]),
            n_points=int(data["n_points"]), converged=data["converged"],
            message=str(data["message"]), variant=variant,
            fixed={k: float(v) for k, v in fixed.items()}, step=step,
            weighted=bool(data.get("weighted", True)), accuracy=data.get("accuracy"),
            given=data.get("given"),
            stderr_total=None if data.get("stderr_total") is None else
            {k: _from_json_float(data["stderr_total"].get(k)) for k in names},
            correlation_total=None if data.get("correlation_total") is None else
            {a: {b: _from_json_float(r) for b, r in row.items()}
             for a, row in data["correlation_total"].items()},
            stats=data.get("stats") or {})

    @classmethod
    def from_json(cls, path) -> "FitResult":
        """Read a result written by :meth:`to_json`; errors name the file and the key."""
        name = os.fspath(path)
        try:
            with open(name, encoding="utf-8") as fh:
                text = fh.read()
        except FileNotFoundError:
            raise FileNotFoundError(f"fit result {name} does not exist") from None
        except IsADirectoryError:
            raise IsADirectoryError(f"fit result {name} is a directory, not a JSON file") from None
        except UnicodeDecodeError as exc:
            raise FitError(f"{name} is not UTF-8 text ({exc.reason}); expected a JSON fit "
                           f"result") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FitError(f"{name}: not valid JSON at line {exc.lineno}, column {exc.colno}: "
                           f"{exc.msg}") from None
        return cls.from_dict(data, name)

    # -- text ------------------------------------------------------------------------------
    def report(self, min_correlation: float = 0.1) -> str:
        """A readable fit report (like lmfit's): statistics, variables, correlations."""
        mcls = model_class(self.model)
        what = {"reference": "step 0, reference object in a clear medium (f_r directly)",
                "medium": "step 1, medium through the reference object (f_r fixed)",
                "target": "step 2, target object through the medium (f_t fixed)",
                "direct": "target object in a clear medium (f_r directly)"}.get(self.step, "")
        free = self.free
        lines = [f"[[Fit: {self.model}" + (f", variant {self.variant}" if self.variant else "")
                 + (f" - {what}" if what else "") + "]]",
                 f"    data points        = {self.n_points}"
                 + ("  (weighted by sigma)" if self.weighted
                    else "  (UNWEIGHTED: no sigma column; errors scaled by reduced chi-square)"),
                 f"    free parameters    = {len(free)}"
                 + (f"  (fixed: {', '.join(self.fixed)})" if self.fixed else ""),
                 f"    reduced chi-square = {_num(self.chi2_reduced, 5)}",
                 f"    rms relative resid = {_num(100 * self.rms_relative, 4)} %",
                 f"    converged          = {'yes' if self.converged else 'NO'} ({self.message})"]
        if self.accuracy:
            lines.append(f"    accuracy           = {self.accuracy}")
        if self.stats:
            lines.append(f"    evaluations        = {self.stats.get('nfev', 0)} function, "
                         f"{self.stats.get('njev', 0)} Jacobian"
                         + (f" over {self.stats.get('starts', 1)} start(s)"
                            if self.stats.get("starts") else ""))
        if self.given:
            gp = ", ".join(f"{k}={_num(v)}" for k, v in self.given.get("params", {}).items())
            lines.append(f"    given (fixed) model = {self.given.get('model')}({gp})")
        lines.append("[[Variables]]")
        width = max(len(n) for n in self.params)
        for p in mcls.PARAMS:
            v = self.params[p.name]
            unit = f" {p.unit}" if p.unit else ""
            if p.name in self.fixed:
                lines.append(f"    {p.name:<{width}}: {_num(v)}{unit} (fixed)")
                continue
            se = self.stderr.get(p.name)
            if se is None or not math.isfinite(se):
                lines.append(f"    {p.name:<{width}}: {_num(v)}{unit} +/- (not determined)")
            else:
                rel = f" ({100 * se / abs(v):.2f}%)" if v != 0 else ""
                total = ""
                if self.stderr_total is not None and self.stderr_total.get(p.name) is not None:
                    total = (f"; with the given model's uncertainty +/- "
                             f"{_num(self.stderr_total[p.name], 3)}")
                lines.append(f"    {p.name:<{width}}: {_num(v)}{unit} +/- {_num(se, 3)}{rel}"
                             f"{total}")
        pairs = []
        for a, b in itertools.combinations(free, 2):
            r = self.correlation.get(a, {}).get(b)
            if r is not None and math.isfinite(r) and abs(r) >= min_correlation:
                pairs.append((abs(r), a, b, r))
        if pairs:
            lines.append(f"[[Correlations]] (unreported correlations are < {min_correlation})")
            for _, a, b, r in sorted(pairs, key=lambda t: -t[0]):
                lines.append(f"    C({a}, {b}) = {r:+.4f}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()


def _num(x, digits=6) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    return f"{x:.{digits}g}"


def _json_float(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _from_json_float(x):
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise FitError(f"expected a number or null in a fit result, got {x!r}")
    return float(x)


# --------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------
@dataclass
class _Data:
    angles: tuple          # canonical theta_i, phi_i, theta_r, phi_r (degrees)
    y: np.ndarray
    sigma: np.ndarray | None
    table: pd.DataFrame    # validated, black subtracted

    @property
    def w(self) -> np.ndarray:
        return np.ones_like(self.y) if self.sigma is None else 1.0 / self.sigma

    @property
    def size(self) -> int:
        return len(self.y)


def _load(table, what: str) -> pd.DataFrame:
    if isinstance(table, (str, os.PathLike)):
        return load_measurements(table)
    if not isinstance(table, pd.DataFrame):
        raise TypeError(f"{what}: expected a measurement table (pandas DataFrame) or a CSV "
                        f"path, got {type(table).__name__}")
    if "veil_source" not in table.attrs and "veil_name" not in table.attrs:
        table = table.copy()
        table.attrs["veil_name"] = f"the {what} table"
    return table


def prepare(table, black=None, what: str = "measurement") -> _Data:
    """Validated data of a session (MODEL.md sec. 7), the black cloth subtracted if given."""
    table = _load(table, what)
    if black is not None:
        black = _load(black, "black-cloth")
        checked = subtract_black(table, black)
    else:
        checked = validate(table)
    canon = canonical_angles(checked)
    angles = tuple(canon[c].to_numpy(dtype=float) for c in CANONICAL)
    y = checked["value"].to_numpy(dtype=float)
    sigma = None
    if "sigma" in checked.columns:
        sigma = checked["sigma"].to_numpy(dtype=float)
        zero = np.flatnonzero(sigma <= 0)
        if zero.size:
            rows = _Rows(checked)
            raise MeasurementError(
                f"{rows.many(zero)}, column 'sigma': 0 ({zero.size} row(s)); a zero standard "
                f"deviation would give the point infinite weight: give every row a positive "
                f"sigma, or drop the sigma column to fit unweighted")
    return _Data(angles, y, sigma, checked)


# --------------------------------------------------------------------------------------
# parameters: free/fixed split and the internal (transformed) coordinates
# --------------------------------------------------------------------------------------
class _Space:
    """Free parameters of one model and their internal coordinates u (module docstring)."""

    def __init__(self, cls: type[Model], fixed: dict, what: str):
        self.cls = cls
        self.names = cls.param_names()
        fixed = dict(fixed or {})
        unknown = [k for k in fixed if k not in self.names]
        if unknown:
            raise FitError(f"cannot fix {', '.join(map(repr, unknown))} in the {what} fit: "
                           f"{cls.NAME} has parameters {', '.join(self.names)}")
        for k, v in fixed.items():
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise FitError(f"fixed {k} = {v!r} is not a number")
            param = cls.PARAMS[self.names.index(k)]
            try:
                param.check(float(v), cls.__name__)
            except (ValueError, TypeError) as exc:
                raise FitError(f"fixed {exc}") from None
        self.fixed = {k: float(fixed[k]) for k in self.names if k in fixed}
        self.free = [i for i, n in enumerate(self.names) if n not in self.fixed]
        if not self.free:
            raise FitError(f"every parameter of the {what} fit is fixed "
                           f"({', '.join(self.names)}): nothing to fit")
        self.kind = []
        for i in self.free:
            p = cls.PARAMS[i]
            if p.log_scale:
                self.kind.append("log")
            elif p.lower_open and p.upper_open and math.isfinite(p.lower) \
                    and math.isfinite(p.upper):
                self.kind.append("atanh")
            else:
                self.kind.append("plain")

    def to_u(self, x: np.ndarray) -> np.ndarray:
        u = []
        for k, i in zip(self.kind, self.free):
            p = self.cls.PARAMS[i]
            if k == "log":
                u.append(math.log(x[i]))
            elif k == "atanh":
                mid, half = (p.upper + p.lower) / 2, (p.upper - p.lower) / 2
                u.append(math.atanh(min(max((x[i] - mid) / half, -1 + OPEN_MARGIN),
                                        1 - OPEN_MARGIN)))
            else:
                u.append(float(x[i]))
        return np.array(u)

    def to_x(self, u: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full parameter vector for internal coordinates u, and dx/du of the free ones."""
        x = np.array(base, dtype=float)
        d = np.empty(len(self.free))
        for j, (k, i) in enumerate(zip(self.kind, self.free)):
            p = self.cls.PARAMS[i]
            if k == "log":
                x[i] = math.exp(u[j])
                d[j] = x[i]
            elif k == "atanh":
                mid, half = (p.upper + p.lower) / 2, (p.upper - p.lower) / 2
                t = math.tanh(u[j])
                x[i] = mid + half * t
                d[j] = half * (1 - t * t)
            else:
                x[i] = u[j]
                d[j] = 1.0
        return x, d

    def bounds(self, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = [], []
        for j, (k, i) in enumerate(zip(self.kind, self.free)):
            p = self.cls.PARAMS[i]
            if k == "log":
                lo.append(math.log(p.lower) if p.lower > 0 else u0[j] - LOG_RANGE)
                hi.append(math.log(p.upper) if math.isfinite(p.upper) else u0[j] + LOG_RANGE)
            elif k == "atanh":
                edge = math.atanh(1 - OPEN_MARGIN)
                lo.append(-edge)
                hi.append(edge)
            else:
                width = (p.upper - p.lower) if math.isfinite(p.upper - p.lower) else 1.0
                lo.append(p.lower + OPEN_MARGIN * width if p.lower_open else p.lower)
                hi.append(p.upper - OPEN_MARGIN * width if p.upper_open else p.upper)
        return np.array(lo), np.array(hi)

    def at_bound(self, u: np.ndarray, u0_bounds) -> list[str]:
        lo, hi = u0_bounds
        span = np.maximum(hi - lo, 1e-300)
        near = (u - lo <= 1e-6 * span) | (hi - u <= 1e-6 * span)
        return [self.names[i] for i, hit in zip(self.free, near) if hit]


# --------------------------------------------------------------------------------------
# evaluations
# --------------------------------------------------------------------------------------
def _padded(angles, start: int, size: int):
    """Configurations start..start+CHUNK, padded with the last one (one shape, one compile)."""
    idx = np.minimum(np.arange(start, start + CHUNK), size - 1)
    return tuple(a[idx] for a in angles)


class _Engine:
    """Apparent reflectance at the data's configurations, CHUNK at a time (the same shape as
    :func:`veil.simulate`, so both share one compilation per accuracy)."""

    def __init__(self, brdf: BRDF, medium: BTDF, angles, rule):
        self.size = len(angles[0])
        self.parts = []
        for start in range(0, self.size, CHUNK):
            ti, pi_, tr, pr = _padded(angles, start, self.size)
            self.parts.append((Forward(brdf, medium, ti, tr, pi_, pr, rule),
                               min(CHUNK, self.size - start)))
        nb, nm = len(brdf.PARAMS), len(medium.PARAMS)
        # every parameter of both models: one compiled Jacobian serves steps 1 and 2 and any
        # choice of fixed parameters
        self.all_b, self.all_m = tuple(range(nb)), tuple(range(nm))
        self.values_calls = 0
        self.jacobian_calls = 0

    def prepare(self, values: bool = True, jacobian: bool = False) -> None:
        """Compile in the background what :meth:`values`/:meth:`terms` and
        :meth:`value_and_jacobian` will need (every chunk shares one compilation)."""
        self.parts[0][0].prepare(values, (self.all_b, self.all_m) if jacobian else None)

    def terms(self, vb, vm) -> np.ndarray:
        self.values_calls += 1
        return np.concatenate([f.terms(vb, vm)[:n] for f, n in self.parts])

    def values(self, vb, vm) -> np.ndarray:
        self.values_calls += 1
        return np.concatenate([f(vb, vm)[:n] for f, n in self.parts])

    def value_and_jacobian(self, vb, vm):
        """Values (M,) and d value / d (every BRDF parameter, every medium parameter)."""
        self.jacobian_calls += 1
        vals, jacs = [], []
        for f, n in self.parts:
            v, j = f.value_and_jacobian(vb, vm, free_brdf=self.all_b, free_medium=self.all_m)
            vals.append(v[:n])
            jacs.append(j[:n])
        return np.concatenate(vals), np.concatenate(jacs)


_DIRECT_FNS: dict = {}


def _direct_fns(cls):
    """Jitted f_r(v, wi, wr) and its Jacobian in v for a BRDF class (MODEL.md sec. 2)."""
    if cls not in _DIRECT_FNS:
        def f(v, wi, wr):
            return cls.evaluate(v, wi, wr)
        _DIRECT_FNS[cls] = (jax.jit(f), jax.jit(jax.jacfwd(f)))
    return _DIRECT_FNS[cls]


class _Direct:
    """f_r at the data's configurations, padded to a multiple of CHUNK (one compile)."""

    def __init__(self, cls, angles):
        self.cls = cls
        self.size = len(angles[0])
        total = CHUNK * math.ceil(self.size / CHUNK)
        idx = np.minimum(np.arange(total), self.size - 1)
        ti, pi_, tr, pr = (a[idx] for a in angles)
        self.wi = jnp.asarray(np.asarray(direction(ti, pi_)))
        self.wr = jnp.asarray(np.asarray(direction(tr, pr)))
        self.values_calls = 0
        self.jacobian_calls = 0

    def values(self, v) -> np.ndarray:
        self.values_calls += 1
        f, _ = _direct_fns(self.cls)
        return np.asarray(f(jnp.asarray(v, dtype=float), self.wi, self.wr))[: self.size]

    def value_and_jacobian(self, v):
        self.jacobian_calls += 1
        f, jf = _direct_fns(self.cls)
        vj = jnp.asarray(v, dtype=float)
        return (np.asarray(f(vj, self.wi, self.wr))[: self.size],
                np.asarray(jf(vj, self.wi, self.wr))[: self.size])


# --------------------------------------------------------------------------------------
# scale parameters solved exactly (starting values)
# --------------------------------------------------------------------------------------
def _weighted_nnls(columns: np.ndarray, rhs: np.ndarray, w: np.ndarray) -> np.ndarray:
    a = columns * w[:, None]
    b = rhs * w
    scale = np.linalg.norm(a, axis=0)
    scale[scale == 0] = 1.0
    coef, _ = nnls(a / scale, b)
    return coef / scale


def _floor(value: float, column: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """A positive stand-in for a scale the linear solve put at 0 (log coordinates need > 0)."""
    if value > 0:
        return value
    a, b = column * w, y * w
    alone = float(a @ b) / float(a @ a) if float(a @ a) > 0 else 0.0
    return 1e-3 * alone if alone > 0 else 1e-12


def _brdf_scales(basis: np.ndarray, x: np.ndarray, cls, fixed: dict, y, w):
    """Best (P_d, P_s) >= 0 for the separable and lobe basis columns (M, 2); fixed ones kept."""
    idx = [cls.scale_index("separable"), cls.scale_index("lobe")]
    x = np.array(x, dtype=float)
    free = [k for k, i in enumerate(idx) if cls.param_names()[i] not in fixed]
    rhs = y - sum(basis[:, k] * x[idx[k]] for k in range(2) if k not in free)
    if free:
        coef = _weighted_nnls(basis[:, free], rhs, w)
        for c, k in zip(coef, free):
            x[idx[k]] = c
    model = basis @ x[idx]
    cost = float(np.sum(((model - y) * w) ** 2))
    for k in free:
        x[idx[k]] = _floor(x[idx[k]], basis[:, k], y, w)
    return x, cost


def _quadratic_scale(a, b, c, y, w) -> float:
    """T >= 0 minimizing sum(w^2 (a T^2 + b T + c - y)^2): roots of the cubic derivative."""
    a, b, r = a * w, b * w, (c - y) * w
    coeffs = [2 * a @ a, 3 * a @ b, b @ b + 2 * a @ r, b @ r]
    cands = [0.0]
    if any(abs(co) > 0 for co in coeffs):
        roots = np.roots(coeffs) if coeffs[0] != 0 else np.roots(coeffs[1:])
        cands += [float(z.real) for z in roots if abs(z.imag) <= 1e-9 * (1 + abs(z)) and z.real > 0]
    costs = [float(np.sum((a * t * t + b * t + r) ** 2)) for t in cands]
    return cands[int(np.argmin(costs))]


_RATIOS = np.concatenate([[0.0], np.logspace(-6, 8, 561)])


def _medium_scales(basis: np.ndarray, x: np.ndarray, cls, fixed: dict, y, w):
    """Best (T_d, T_t) >= 0 for basis columns (M, 3) of T_d^2, T_d T_t, T_t^2; fixed kept."""
    i_d, i_t = cls.scale_index("iso"), cls.scale_index("lobe")
    names = cls.param_names()
    x = np.array(x, dtype=float)
    a0, a1, a2 = basis[:, 0], basis[:, 1], basis[:, 2]
    free_d, free_t = names[i_d] not in fixed, names[i_t] not in fixed
    if free_d and free_t:
        # value = T_d^2 (a0 + r a1 + r^2 a2) with r = T_t / T_d: exact in T_d^2 per ratio
        cols = np.concatenate([(a0[None, :] + _RATIOS[:, None] * a1[None, :]
                                + _RATIOS[:, None] ** 2 * a2[None, :]), a2[None, :]]) * w
        yw = y * w
        num, den = cols @ yw, np.einsum("km,km->k", cols, cols)
        s = np.where(den > 0, np.maximum(num, 0.0) / np.where(den > 0, den, 1.0), 0.0)
        costs = np.sum((s[:, None] * cols - yw) ** 2, axis=1)
        k = int(np.argmin(costs))
        if k == len(_RATIOS):  # T_d = 0
            x[i_d], x[i_t] = 0.0, math.sqrt(s[k])
        else:
            x[i_d] = math.sqrt(s[k])
            x[i_t] = _RATIOS[k] * x[i_d]
    elif free_d:
        t = x[i_t]
        x[i_d] = _quadratic_scale(a0, t * a1, t * t * a2, y, w)
    elif free_t:
        d = x[i_d]
        x[i_t] = _quadratic_scale(a2, d * a1, d * d * a0, y, w)
    model = basis @ np.array([x[i_d] ** 2, x[i_d] * x[i_t], x[i_t] ** 2])
    cost = float(np.sum(((model - y) * w) ** 2))
    if free_d and x[i_d] <= 0:
        x[i_d] = 1e-3 * x[i_t] if x[i_t] > 0 else 1e-12
    if free_t and x[i_t] <= 0:
        x[i_t] = 1e-3 * x[i_d] if x[i_d] > 0 else 1e-12
    return x, cost


def _grid_points(cls, step: str, space: _Space, base: np.ndarray):
    """Grid over the free nonlinear parameters: list of (index tuple, vector)."""
    grid = START_GRIDS.get((cls, step), {})
    scales = set(cls.SCALES.values())
    axes = []
    for i in space.free:
        name = space.names[i]
        if name in scales:
            continue
        values = grid.get(name)
        if values is None:
            raise FitError(f"no starting grid for parameter {name} of {cls.NAME}")
        p = cls.PARAMS[i]
        values = [v for v in values if p.lower < v < p.upper]
        axes.append((i, values))
    points = []
    for combo in itertools.product(*[range(len(v)) for _, v in axes]):
        x = np.array(base, dtype=float)
        for (i, values), k in zip(axes, combo):
            x[i] = values[k]
        points.append((combo, x))
    return points


def _pick_starts(scored, count: int):
    """Best grid points, skipping neighbours (one grid step) of points already chosen."""
    chosen = []
    for cost, combo, x in sorted(scored, key=lambda t: t[0]):
        if not np.isfinite(cost):
            continue
        if any(max((abs(a - b) for a, b in zip(combo, c)), default=0) <= 1 for _, c, _ in chosen):
            continue
        chosen.append((cost, combo, x))
        if len(chosen) == count:
            break
    return chosen


# --------------------------------------------------------------------------------------
# the least-squares driver
# --------------------------------------------------------------------------------------
class _Objective:
    """Residuals and Jacobian in internal coordinates, with a one-point cache."""

    def __init__(self, space: _Space, base, data: _Data, values, jacobian, on_eval=None):
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


def _covariance(jac_u: np.ndarray, d: np.ndarray):
    """Covariance of the free parameters (x units) from the weighted internal Jacobian."""
    _, s, vt = np.linalg.svd(jac_u, full_matrices=False)
    if s.size == 0 or s[-1] <= s[0] * 1e-10 or not np.all(np.isfinite(s)):
        return None
    cov_u = (vt.T / s ** 2) @ vt
    return cov_u * np.outer(d, d)


def _uncertainties(cov, names, free):
    """(stderr dict over all names, correlation dict over the free ones) from a covariance."""
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


def _finish(step, cls, space: _Space, x, data: _Data, model_values, jac_x, lsq, message_extra,
            variant, accuracy, given, stats, propagate=None) -> FitResult:
    """Assemble a FitResult from the solution x (full vector) and the final Jacobian.

    ``propagate`` = (d values / d given parameters (M, kg), their covariance (kg, kg)) adds
    the given model's uncertainty to first order: d x / d theta = -J^+ J_theta."""
    y, w = data.y, data.w
    k = len(space.free)
    dof = data.size - k
    res = (y - model_values) * w
    chi2 = float(res @ res) / dof
    nonzero = model_values != 0
    rel = (y[nonzero] - model_values[nonzero]) / model_values[nonzero]
    rms_rel = float(np.sqrt(np.mean(rel ** 2))) if rel.size else float("nan")
    jw = jac_x[:, space.free] * w[:, None]
    cov = _covariance(jw, np.ones(k))
    notes = list(message_extra)
    if cov is not None and data.sigma is None:
        cov = cov * chi2
    names = space.names
    stderr, corr = {n: None for n in names}, {}
    stderr_total = corr_total = None
    if cov is None:
        notes.append("Jacobian singular at the solution: uncertainties not determined")
    else:
        stderr, corr = _uncertainties(cov, names, space.free)
        if propagate is not None:
            jg, cov_g = propagate
            sens = -np.linalg.lstsq(jw, jg * w[:, None], rcond=None)[0]
            stderr_total, corr_total = _uncertainties(cov + sens @ cov_g @ sens.T, names,
                                                      space.free)
    converged = bool(lsq.status > 0)
    message = lsq.message if not notes else lsq.message + "; " + "; ".join(notes)
    if not converged:
        message = "did not converge: " + message
    return FitResult(model=cls.NAME, params={n: float(x[i]) for i, n in enumerate(names)},
                     stderr=stderr, correlation=corr, residuals=tuple(float(r) for r in res),
                     chi2_reduced=chi2, rms_relative=rms_rel, n_points=data.size,
                     converged=converged, message=message, variant=variant,
                     fixed=dict(space.fixed), step=step, weighted=data.sigma is not None,
                     accuracy=accuracy, given=given, stderr_total=stderr_total,
                     correlation_total=corr_total, stats=stats)


def _check_size(data: _Data, space: _Space, what: str) -> None:
    k = len(space.free)
    if data.size <= k:
        raise FitError(f"the {what} data have {data.size} point(s) but the fit has {k} free "
                       f"parameter(s) ({', '.join(space.names[i] for i in space.free)}): "
                       f"need more points than free parameters (fix some with fixed=... / "
                       f"--fix NAME=VALUE, or measure more configurations)")


def _check_accuracy(accuracy: str) -> None:
    if accuracy not in RULES:
        raise FitError(f"accuracy = {accuracy!r}; expected one of {', '.join(RULES)}")


def _check_max_nfev(max_nfev) -> None:
    if max_nfev is not None and (isinstance(max_nfev, bool) or not isinstance(max_nfev, int)
                                 or max_nfev < 1):
        raise FitError(f"max_nfev = {max_nfev!r}; expected a positive integer or None")


def _emit(progress, stage, done, total):
    if progress is not None:
        progress(stage, done, total)


def _convincing(lsq, space, bounds, data) -> bool:
    """A weighted fit that converged inside its search range with reduced chi-square <= 2."""
    dof = data.size - len(space.free)
    return (lsq.status > 0 and data.sigma is not None and 2 * lsq.cost / dof <= 2.0
            and not space.at_bound(lsq.x, bounds))


def _multi_start(step, space, data, scored, values_fn, jac_fn, max_nfev, progress, tol,
                 every: bool):
    """Least squares from the best distinct grid points: all of them when ``every``, else
    the next only while the fits so far are not convincing. Returns (best, runs, starts)."""
    runs = []
    starts = _pick_starts(scored, STARTS[step])
    for s, (cost0, combo, x0) in enumerate(starts):
        if runs and not every and any(_convincing(r[0], space, r[2], data) for r in runs):
            break
        u0 = space.to_u(x0)
        bounds = space.bounds(u0)
        counter = {"n": 0}

        def tick(s=s, counter=counter):
            counter["n"] += 1
            _emit(progress, f"start {s + 1}/{len(starts)}: iteration", counter["n"], None)

        obj = _Objective(space, x0, data, values_fn, jac_fn, tick)
        lsq = _run_lsq(obj, u0, bounds, tol, max_nfev)
        runs.append((lsq, obj, bounds))
    best = min(range(len(runs)), key=lambda r: (runs[r][0].cost, r))
    return best, runs, starts


# --------------------------------------------------------------------------------------
# step 0: the reference's f_r in a clear medium
# --------------------------------------------------------------------------------------
def _as_fixed(fixed) -> dict:
    if fixed is None:
        return {}
    if not isinstance(fixed, dict):
        raise FitError(f"fixed = {fixed!r}; expected a dict such as {{'eta': 1.5}}")
    return dict(fixed)


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
    _check_max_nfev(max_nfev)
    cls = TorranceSparrow
    what = "reference" if step == "reference" else "target"
    space = _Space(cls, _as_fixed(fixed), f"{what} (clear medium)")
    data = prepare(table, black, f"{what} (clear medium)")
    _check_size(data, space, f"{what} (clear medium)")
    direct = _Direct(cls, data.angles)
    base = np.array([space.fixed.get(n, 1.0) for n in space.names], dtype=float)
    i_d, i_s = cls.scale_index("separable"), cls.scale_index("lobe")
    points = _grid_points(cls, "reference", space, base)
    scored = []
    for k, (combo, x) in enumerate(points):
        xs, xl = x.copy(), x.copy()
        xs[i_d], xs[i_s] = 1.0, 0.0
        xl[i_d], xl[i_s] = 0.0, 1.0
        basis = np.stack([direct.values(xs), direct.values(xl)], axis=1)
        x, cost = _brdf_scales(basis, x, cls, space.fixed, data.y, data.w)
        scored.append((cost, combo, x))
        _emit(progress, "starting grid", k + 1, len(points))

    def values_fn(x):
        return direct.values(x)

    def jac_fn(x):
        return direct.value_and_jacobian(x)[1]

    best, runs, starts = _multi_start("reference", space, data, scored, values_fn, jac_fn,
                                      max_nfev, progress, _TOL_FINAL, every=True)
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
    return [f"{', '.join(hit)} at the edge of the search range (uncertainty unreliable)"] \
        if hit else []


def _run_stats(lsq, obj) -> dict:
    return {"nfev": int(obj.nfev), "njev": int(obj.njev), "status": int(lsq.status),
            "cost": float(lsq.cost)}


# --------------------------------------------------------------------------------------
# steps 1 and 2: through the medium
# --------------------------------------------------------------------------------------
def _as_brdf_model(reference) -> BRDF:
    if isinstance(reference, FitResult):
        if model_class(reference.model).KIND != "brdf":
            raise FitError(f"the reference must be a BRDF fit (step 0, 'veil fit reference', "
                           f"model torrance-sparrow); got a {reference.model} result"
                           + (f" of step {reference.step!r}" if reference.step else ""))
        if not reference.converged:
            warnings.warn("the reference fit did not converge; its f_r is used as it is",
                          stacklevel=3)
        return reference.as_model()
    if isinstance(reference, BRDF):
        return reference
    if isinstance(reference, BTDF):
        raise FitError(f"the reference must be a BRDF (TorranceSparrow); got the medium "
                       f"{reference}")
    raise TypeError(f"reference: expected a FitResult of step 0 or a TorranceSparrow, got "
                    f"{type(reference).__name__}")


def _as_medium_model(medium, variant) -> BTDF:
    if isinstance(medium, FitResult):
        if model_class(medium.model).KIND != "btdf":
            raise FitError(f"the medium must be a medium fit (step 1, 'veil fit medium', model "
                           f"henyey-greenstein); got a {medium.model} result"
                           + (f" of step {medium.step!r}" if medium.step else ""))
        if not medium.converged:
            warnings.warn("the medium fit did not converge; its f_t is used as it is",
                          stacklevel=3)
        model = medium.as_model()
    elif isinstance(medium, BTDF):
        model = medium
    elif isinstance(medium, BRDF):
        raise FitError(f"the medium must be a BTDF (HenyeyGreenstein); got the BRDF {medium}")
    else:
        raise TypeError(f"medium: expected a FitResult of step 1 or a HenyeyGreenstein, got "
                        f"{type(medium).__name__}")
    if variant is not None and model.options().get("variant") != variant:
        raise FitError(f"variant = {variant!r} but the medium was fitted with variant "
                       f"{model.options().get('variant')!r}; leave variant unset to use the "
                       f"medium's")
    return model


def _check_variant(variant) -> None:
    from .models.henyey_greenstein import VARIANTS
    if variant not in VARIANTS:
        raise FitError(f"variant = {variant!r}; expected one of {', '.join(VARIANTS)}")


def _model_dict(model: Model) -> dict:
    opts = model.options()
    return {"model": model.NAME, "params": model.as_dict(), **opts}


def _through_medium(step, cls, space, data, brdf, medium, accuracy, max_nfev, progress,
                    given_result=None):
    """Steps 1 (medium free) and 2 (BRDF free): grid, fast iterations, polish."""
    fitting_medium = step == "medium"
    iter_rule = RULES[ITERATION_ACCURACY]
    fast = _Engine(brdf, medium, data.angles, iter_rule)
    polish = accuracy != ITERATION_ACCURACY
    # everything this fit will compile, compiled side by side while the grid starts
    fast.prepare(values=True, jacobian=True)
    if polish:
        final = _Engine(brdf, medium, data.angles, RULES[accuracy])
        final.prepare(values=True)
    template = medium if fitting_medium else brdf
    base = template.to_vector()
    for n, v in space.fixed.items():
        base[space.names.index(n)] = v
    vb_fixed, vm_fixed = brdf.to_vector(), medium.to_vector()

    def split(x):
        return (vb_fixed, x) if fitting_medium else (x, vm_fixed)

    points = _grid_points(cls, step, space, base)
    scored = []
    for k, (combo, x) in enumerate(points):
        vb, vm = split(x)
        terms = fast.terms(vb, vm)
        if fitting_medium:
            cols = np.array([vb[brdf.scale_index("separable")], vb[brdf.scale_index("lobe")]])
            basis = np.einsum("mkb,b->mk", terms, cols)
            x, cost = _medium_scales(basis, x, cls, space.fixed, data.y, data.w)
        else:
            td, tt = vm[medium.scale_index("iso")], vm[medium.scale_index("lobe")]
            basis = np.einsum("mkb,k->mb", terms, np.array([td * td, td * tt, tt * tt]))
            x, cost = _brdf_scales(basis, x, cls, space.fixed, data.y, data.w)
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

    tol = _TOL_ITER if polish else _TOL_FINAL
    best, runs, starts = _multi_start(step, space, data, scored, fast_values, fast_jac,
                                      max_nfev, progress, tol, every=False)
    lsq, obj, bounds = runs[best]
    run_stats = [_run_stats(r[0], r[1]) for r in runs]
    notes = []
    if polish:
        if lsq.status <= 0:
            notes.append(f"iterations at {ITERATION_ACCURACY!r} accuracy stopped early "
                         f"({lsq.message})")
        counter = {"n": 0}

        def tick():
            counter["n"] += 1
            _emit(progress, f"polish at {accuracy!r}: iteration", counter["n"], None)

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
        lsq = _run_lsq(pobj, lsq.x, bounds, _TOL_POLISH, max_nfev)
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
    given = _model_dict(brdf if fitting_medium else medium)
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
    _check_accuracy(accuracy)
    _check_variant(variant)
    _check_max_nfev(max_nfev)
    brdf = _as_brdf_model(reference)
    cls = HenyeyGreenstein
    space = _Space(cls, _as_fixed(fixed), "medium")
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
    _check_accuracy(accuracy)
    if variant is not None:
        _check_variant(variant)
    _check_max_nfev(max_nfev)
    model_m = _as_medium_model(medium, variant)
    cls = TorranceSparrow
    space = _Space(cls, _as_fixed(fixed), "target")
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
        return _Direct(type(model), angles).values(model.to_vector())
    if isinstance(other, FitResult):
        other = other.as_model()
    brdf, medium = (model, other) if isinstance(model, BRDF) else (other, model)
    engine = _Engine(brdf, medium, angles, RULES[accuracy])
    return engine.values(brdf.to_vector(), medium.to_vector())


__all__ = ["FitResult", "FitError", "fit_reference", "fit_direct", "fit_medium", "fit_target",
           "prepare", "model_values", "STEPS", "START_GRIDS", "STARTS"]
