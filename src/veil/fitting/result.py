"""The result of a fit (MODEL.md sec. 7): :class:`FitResult`, its JSON file (key by key in
docs/fitting.md) and its text report; :class:`FitError` for fits that cannot be set up."""

from __future__ import annotations

import itertools
import json
import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import FitError, InputError, MissingFileError, NotAFileError
from ..data.measurements import atomic_write_text
from ..models import REGISTRY, Model, model_class
from ..models.henyey_greenstein import VARIANTS

#: The steps of the two-step method (MODEL.md sec. 7); results may also say "direct".
STEPS = ("reference", "medium", "target")
#: Value of the "format" key of a result file.
FORMAT = "veil.fit/1"


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
        """Names of the parameters the fit varied (those not held fixed)."""
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
        """The result as a JSON-ready dict (the keys of docs/fitting.md; NaN as null)."""
        return {
            "format": FORMAT,
            "model": self.model,
            "step": self.step,
            "params": {k: float(v) for k, v in self.params.items()},
            "stderr": {k: json_float(v) for k, v in self.stderr.items()},
            "correlation": {a: {b: json_float(r) for b, r in row.items()}
                            for a, row in self.correlation.items()},
            "chi2_reduced": json_float(self.chi2_reduced),
            "rms_relative": json_float(self.rms_relative),
            "n_points": int(self.n_points),
            "converged": bool(self.converged),
            "message": self.message,
            "variant": self.variant,
            "fixed": {k: float(v) for k, v in self.fixed.items()},
            "weighted": bool(self.weighted),
            "accuracy": self.accuracy,
            "given": self.given,
            "stderr_total": None if self.stderr_total is None else
            {k: json_float(v) for k, v in self.stderr_total.items()},
            "correlation_total": None if self.correlation_total is None else
            {a: {b: json_float(r) for b, r in row.items()}
             for a, row in self.correlation_total.items()},
            "stats": self.stats,
            "residuals": [json_float(r) for r in self.residuals],
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
        if variant is not None and variant not in VARIANTS:
            raise FitError(f"{source}: key 'variant' = {variant!r}; expected one of "
                           f"{', '.join(VARIANTS)} or null")
        try:
            model = mcls(**{k: float(v) for k, v in params.items()})
            if "variant" in model.options():
                if variant is None:
                    raise InputError(f"model {name} needs a variant ({', '.join(VARIANTS)})")
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
            stderr={k: from_json_float(stderr.get(k)) for k in names},
            correlation={a: {b: from_json_float(r) for b, r in row.items()}
                         for a, row in (data["correlation"] or {}).items()},
            residuals=tuple(from_json_float(r) for r in data.get("residuals") or ()),
            chi2_reduced=from_json_float(data["chi2_reduced"]),
            rms_relative=from_json_float(data["rms_relative"]),
            n_points=int(data["n_points"]), converged=data["converged"],
            message=str(data["message"]), variant=variant,
            fixed={k: float(v) for k, v in fixed.items()}, step=step,
            weighted=bool(data.get("weighted", True)), accuracy=data.get("accuracy"),
            given=data.get("given"),
            stderr_total=None if data.get("stderr_total") is None else
            {k: from_json_float(data["stderr_total"].get(k)) for k in names},
            correlation_total=None if data.get("correlation_total") is None else
            {a: {b: from_json_float(r) for b, r in row.items()}
             for a, row in data["correlation_total"].items()},
            stats=data.get("stats") or {})

    @classmethod
    def from_json(cls, path) -> "FitResult":
        """Read a result written by :meth:`to_json`; errors name the file and the key."""
        return cls.from_dict(read_json(path), os.fspath(path))

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
                 f"    reduced chi-square = {format_number(self.chi2_reduced, 5)}",
                 f"    rms relative resid = {format_number(100 * self.rms_relative, 4)} %",
                 f"    converged          = {'yes' if self.converged else 'NO'} ({self.message})"]
        if self.accuracy:
            lines.append(f"    accuracy           = {self.accuracy}")
        if self.stats:
            lines.append(f"    evaluations        = {self.stats.get('nfev', 0)} function, "
                         f"{self.stats.get('njev', 0)} Jacobian"
                         + (f" over {self.stats.get('starts', 1)} start(s)"
                            if self.stats.get("starts") else ""))
        if self.given:
            gp = ", ".join(f"{k}={format_number(v)}" for k, v in self.given.get("params", {}).items())
            lines.append(f"    given (fixed) model = {self.given.get('model')}({gp})")
        lines.append("[[Variables]]")
        width = max(len(n) for n in self.params)
        for p in mcls.PARAMS:
            v = self.params[p.name]
            unit = f" {p.unit}" if p.unit else ""
            if p.name in self.fixed:
                lines.append(f"    {p.name:<{width}}: {format_number(v)}{unit} (fixed)")
                continue
            se = self.stderr.get(p.name)
            if se is None or not math.isfinite(se):
                lines.append(f"    {p.name:<{width}}: {format_number(v)}{unit} +/- (not determined)")
            else:
                rel = f" ({100 * se / abs(v):.2f}%)" if v != 0 else ""
                total = ""
                if self.stderr_total is not None and self.stderr_total.get(p.name) is not None:
                    total = (f"; with the given model's uncertainty +/- "
                             f"{format_number(self.stderr_total[p.name], 3)}")
                lines.append(f"    {p.name:<{width}}: {format_number(v)}{unit} +/- {format_number(se, 3)}{rel}"
                             f"{total}")
        lines += self.correlation_lines(min_correlation)
        return "\n".join(lines)

    def correlation_lines(self, min_correlation: float, most: int | None = None) -> list[str]:
        """The report's [[Correlations]] section: pairs of free parameters with |r| >=
        ``min_correlation``, strongest first (the ``most`` strongest; all when None)."""
        pairs = []
        for a, b in itertools.combinations(self.free, 2):
            r = self.correlation.get(a, {}).get(b)
            if r is not None and math.isfinite(r) and abs(r) >= min_correlation:
                pairs.append((abs(r), a, b, r))
        if not pairs:
            return []
        lines = [f"[[Correlations]] (unreported correlations are < {min_correlation})"]
        for _, a, b, r in sorted(pairs, key=lambda t: -t[0])[:most]:
            lines.append(f"    C({a}, {b}) = {r:+.4f}")
        return lines

    def __str__(self) -> str:
        return self.report()


def format_number(x, digits=6, missing="n/a") -> str:
    """``x`` to ``digits`` significant digits; ``missing`` for None or a non-finite float."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return missing
    return f"{x:.{digits}g}"


def read_json(path):
    """The JSON data of a result file; errors name the file (a missing file, a directory, not
    UTF-8, not JSON)."""
    name = os.fspath(path)
    try:
        with open(name, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise MissingFileError(f"fit result {name} does not exist") from None
    except IsADirectoryError:
        raise NotAFileError(f"fit result {name} is a directory, not a JSON file") from None
    except UnicodeDecodeError as exc:
        raise FitError(f"{name} is not UTF-8 text ({exc.reason}); expected a JSON fit "
                       f"result") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FitError(f"{name}: not valid JSON at line {exc.lineno}, column {exc.colno}: "
                       f"{exc.msg}") from None


def json_float(x):
    """A number for a JSON file: float, or None (null) when missing or not finite."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def from_json_float(x):
    """A number read from a result file: float or None; anything else is a FitError."""
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise FitError(f"expected a number or null in a fit result, got {x!r}")
    return float(x)


__all__ = ["FitError", "FitResult", "FORMAT", "STEPS", "json_float", "from_json_float",
           "read_json", "format_number"]
