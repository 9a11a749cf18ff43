"""Joint estimation over several media (MODEL.md sec. 7, the paper's proposed remedy).

The two-step method (MODEL.md sec. 7) takes each step's result as exact; a smooth target in
a strongly scattering medium and a rough one in a weak medium then look alike (paper sec.
5.2.4). :func:`fit_joint` instead fits all sessions at once - the target (and optionally the
reference) measured under several media, e.g. several concentrations of one drink - as one
weighted least-squares problem: each object's f_r is shared by all its sessions, each
medium has its own T_d and T_t, and g and eta_u are shared by the media or free per medium
as declared (default: g per medium, eta_u shared). Residuals, weights (1/sigma, or plain
squared error without a sigma column), internal coordinates (log, atanh), iterations at
the "fast" quadrature with a polish at the requested one, and the result (FitResult, JSON)
follow :mod:`veil.fitting`; see docs/ambiguity.md.

Parameter names in results: the target's ``Pd, Ps, n, eta``; the reference's ``ref.Pd``
...; per medium ``Td[label]``, ``Tt[label]``, ``g[label]`` / ``eta_u[label]``; shared
``g`` / ``eta_u``.

:class:`SessionModel` and :class:`Problem` (stacked sessions, block Jacobian) are also the
machinery of :mod:`veil.uncertainty`, :mod:`veil.diagnostics` and :mod:`veil.design`.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from . import coordinates
from ..engine.angles import direction
from ..engine.apparent import RULES
from ..engine.evaluator import ApparentModel, DirectModel
from .data import FitData, prepare
from .result import FitError, FitResult, format_number, from_json_float, read_json
from .steps import fit_reference
from .given import as_brdf_model, check_variant, model_dict
from .solver import CONVINCING  # noqa: F401
from .solver import (ITERATION_ACCURACY, SINGULAR_NOTE, TOL_FINAL, TOL_ITER,
                            as_fixed, check_accuracy, check_fixed, check_max_nfev, convincing,
                            covariance_from_jacobian, edge_note, goodness, outcome,
                            stopped_early_note, ticker, uncertainties)
from ..models import BRDF, BTDF, HenyeyGreenstein, TorranceSparrow
from ..models.base import Param
from .start_values import START_GRIDS, brdf_scales, medium_scales

#: Labels meaning clear water (no medium: the session measures f_r directly).
CLEAR = ("none", "clear")
OBJECTS = ("target", "reference")
#: Medium parameters that may be shared by the media or free per medium.
SHAREABLE = ("g", "eta_u")
#: Default declaration: g differs between concentrations (the paper's media, MODEL.md sec. 6,
#: broaden with concentration), the medium's refractive index does not.
DEFAULT_SHARED = ("eta_u",)
#: Two configurations closer than this (deg, for both I and R) are the same one when
#: checking that sessions overlap (the black-cloth matching tolerance).
OVERLAP_TOL = 0.05
#: Starting grids of the joint fit (nonlinear parameters; scales are solved exactly).
N_GRID = START_GRIDS[(TorranceSparrow, "target")]["n"]
G_GRID = START_GRIDS[(HenyeyGreenstein, "medium")]["g"]
#: Configurations per session used for the starting grid (evenly spaced in the table).
GRID_SUBSAMPLE = 64
#: Least-squares runs from the best distinct starting points.
STARTS = 2
FORMAT = "veil.joint/1"
# CONVINCING (veil.least_squares): reduced chi-square up to which a converged weighted fit
# makes further starts unnecessary (veil.fitting's rule); it stays importable from here.
_MEDIUM_NAMES = {"Td": 0, "Tt": 1, "g": 2, "eta_u": 3}


class SessionModel:
    """Model values of one session at fixed configurations (MODEL.md sec. 2, 5), with the
    Jacobian w.r.t. every parameter of both models; ``medium=None`` is clear water (f_r
    directly). Built on :mod:`veil.evaluation`'s chunked models (one compilation per accuracy).
    """

    def __init__(self, brdf: BRDF, medium: BTDF | None, angles, rule="fast"):
        if isinstance(rule, str):
            check_accuracy(rule)
            rule = RULES[rule]
        angles = tuple(np.asarray(a, dtype=float).ravel() for a in angles)
        self.size = angles[0].size
        if self.size == 0:
            raise FitError("a session has no configurations")
        self.brdf, self.medium = brdf, medium
        self.nb = len(type(brdf).PARAMS)
        self.nm = 0 if medium is None else len(type(medium).PARAMS)
        if medium is None:
            self._direct = DirectModel(type(brdf), angles)
        else:
            self._engine = ApparentModel(brdf, medium, angles, rule)

    def prepare(self, values: bool = True, jacobian: bool = False) -> None:
        """Compile in the background what later calls will need (see Forward.prepare)."""
        if self.medium is not None:
            self._engine.prepare(values, jacobian)

    def values(self, vb, vm=None) -> np.ndarray:
        if self.medium is None:
            return self._direct.values(np.asarray(vb, dtype=float))
        return self._engine.values(np.asarray(vb, dtype=float), np.asarray(vm, dtype=float))

    def terms(self, vb, vm) -> np.ndarray:
        """Term matrices (M, 3, 2), scales set to 1 (rows T_d^2, T_d T_t, T_t^2; columns the
        BRDF's separable and lobe parts)."""
        return self._engine.terms(np.asarray(vb, dtype=float), np.asarray(vm, dtype=float))

    def jacobian(self, vb, vm=None):
        """Values (M,), d/d vb (M, nb) and d/d vm (M, nm)."""
        vb = np.asarray(vb, dtype=float)
        if self.medium is None:
            val, jac = self._direct.value_and_jacobian(vb)
            return val, jac, np.zeros((self.size, 0))
        val, jac = self._engine.value_and_jacobian(vb, np.asarray(vm, dtype=float))
        return val, jac[:, : self.nb], jac[:, self.nb:]


# --------------------------------------------------------------------------------------
# sessions
# --------------------------------------------------------------------------------------
@dataclass
class Session:
    """One measured session (MODEL.md sec. 7): a measurement ``table`` (DataFrame or CSV
    path, black cloth already subtracted), the ``medium`` label it was measured in ("none"
    for clear water) and the ``object`` measured ("target" or "reference")."""

    table: object
    medium: str = "none"
    object: str = "target"
    name: str | None = None

    def __post_init__(self):
        if not isinstance(self.medium, str) or not self.medium.strip():
            raise FitError(f"session medium = {self.medium!r}: expected a non-empty label "
                           f"(e.g. 'low', 'x2') or 'none' for clear water")
        self.medium = self.medium.strip()
        if self.medium.lower() in CLEAR:
            self.medium = "none"
        bad = [c for c in "[]=,:@ " if c in self.medium]
        if bad:
            raise FitError(f"session medium label {self.medium!r} contains {bad[0]!r}; labels "
                           f"may not contain spaces or any of [ ] = , : @")
        if self.object not in OBJECTS:
            raise FitError(f"session object = {self.object!r}: expected 'target' or "
                           f"'reference'")
        if self.name is None:
            src = self.table if isinstance(self.table, (str, os.PathLike)) else None
            self.name = f"{self.object} in {self.medium if self.medium != 'none' else 'water'}" \
                + (f" ({os.fspath(src)})" if src is not None else "")

    @property
    def clear(self) -> bool:
        return self.medium == "none"


def as_sessions(sessions) -> list[Session]:
    """Sessions from a list of :class:`Session` / (table, medium[, object]) tuples, or a dict
    {medium label: target table}."""
    if isinstance(sessions, dict):
        sessions = [Session(t, m, "target") for m, t in sessions.items()]
    if isinstance(sessions, (Session, pd.DataFrame, str)) or sessions is None:
        raise FitError("sessions: expected a list of Session(table, medium, object) or a dict "
                       "{medium label: target table}")
    out = []
    for s in sessions:
        if isinstance(s, Session):
            out.append(s)
        elif isinstance(s, tuple) and 2 <= len(s) <= 3:
            out.append(Session(*s))
        else:
            raise FitError(f"sessions: {s!r} is neither a Session nor a (table, medium[, "
                           f"object]) tuple")
    if not out:
        raise FitError("no sessions given: a joint fit needs at least one session of the "
                       "target measured in a medium")
    return out


# --------------------------------------------------------------------------------------
# parameters
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GlobalParam:
    """One parameter of a stacked problem: its result ``name``, the model parameter it is
    (``spec``), and the model it belongs to (``kind`` brdf/medium, ``owner`` an object name
    or medium label, "*" when shared by the media)."""

    name: str
    kind: str
    owner: str
    index: int
    spec: Param

    @property
    def coordinate(self) -> str:
        """Fit coordinate (:mod:`veil.coordinates`): log, atanh (open finite interval) or plain."""
        return coordinates.coordinate(self.spec)

    @property
    def is_scale(self) -> bool:
        return self.spec.name in ("Pd", "Ps", "Td", "Tt")

    def to_u(self, x: float) -> float:
        """Internal coordinate of the natural value ``x``."""
        return coordinates.to_u(self.spec, x, self.coordinate)

    def to_x(self, u: float) -> tuple[float, float]:
        """Natural value and d value / d u."""
        return coordinates.to_x(self.spec, u, self.coordinate)

    def bounds(self, u0: float) -> tuple[float, float]:
        """Search interval in internal coordinates (``u0`` the start)."""
        return coordinates.bounds(self.spec, u0, self.coordinate)


@dataclass
class Block:
    """One session inside a :class:`Problem`: data, global indices of its BRDF vector ``ib``
    and medium vector ``im`` (None in clear water), and its engines (fast, final)."""

    session: Session
    data: FitData
    ib: np.ndarray
    im: np.ndarray | None
    brdf: BRDF
    medium: BTDF | None
    models: dict = field(default_factory=dict)

    def model(self, accuracy: str) -> SessionModel:
        if accuracy not in self.models:
            self.models[accuracy] = SessionModel(self.brdf, self.medium, self.data.angles,
                                                 accuracy)
        return self.models[accuracy]

    @property
    def size(self) -> int:
        return self.data.size


class Problem:
    """Stacked weighted least squares over sessions (module docstring).

    ``params`` lists every global parameter, ``values`` their natural values (fixed ones
    included), ``free`` which are estimated. Residuals are (model - value) * w session after
    session (w = 1/sigma, or 1 without sigma columns).
    """

    def __init__(self, blocks, params, values, free, weighted: bool):
        self.blocks = list(blocks)
        self.params = list(params)
        self.values = np.asarray(values, dtype=float).copy()
        self.free = np.asarray(free, dtype=bool).copy()
        self.weighted = weighted
        self.names = [p.name for p in self.params]
        self.n_points = int(sum(b.size for b in self.blocks))
        self.y = np.concatenate([b.data.y for b in self.blocks])
        self.w = np.concatenate([b.data.w for b in self.blocks])
        self._cache: dict = {}
        self.calls = {"values": 0, "jacobian": 0}
        self.prior = None

    def set_prior(self, names, mean, cov) -> None:
        """A Gaussian prior N(mean, cov) (natural units) on parameters ``names``: extra
        residuals L^-1 (x - mean), L L^T = cov. It carries a previous step's result into a
        refit (veil.diagnostics: a step-2 fit with the medium of step 1 free but held to
        its uncertainty)."""
        cov = np.asarray(cov, dtype=float)
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise FitError("the prior covariance is not positive definite") from None
        idx = np.array([self.index(n) for n in names])
        self.prior = (idx, np.asarray(mean, dtype=float), np.linalg.inv(chol))

    def prior_rows(self, x):
        """Prior residuals (k,) and their Jacobian (k, P) w.r.t. all natural parameters."""
        if self.prior is None:
            return np.zeros(0), np.zeros((0, len(self.params)))
        idx, mean, inv = self.prior
        jac = np.zeros((len(idx), len(self.params)))
        jac[:, idx] = inv
        return inv @ (np.asarray(x)[idx] - mean), jac

    @property
    def free_index(self) -> np.ndarray:
        return np.flatnonzero(self.free)

    @property
    def free_names(self) -> list[str]:
        return [self.names[k] for k in self.free_index]

    def index(self, name: str) -> int:
        return self.names.index(name)

    # -- coordinates ---------------------------------------------------------------------
    def to_u(self, x) -> np.ndarray:
        return np.array([self.params[k].to_u(x[k]) for k in self.free_index])

    def to_x(self, u, base=None) -> tuple[np.ndarray, np.ndarray]:
        x = (self.values if base is None else np.asarray(base, dtype=float)).copy()
        d = np.empty(len(u))
        for j, k in enumerate(self.free_index):
            x[k], d[j] = self.params[k].to_x(u[j])
        return x, d

    def bounds(self, u0) -> tuple[np.ndarray, np.ndarray]:
        pairs = [self.params[k].bounds(u0[j]) for j, k in enumerate(self.free_index)]
        return np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])

    # -- evaluation ----------------------------------------------------------------------
    def split(self, block: Block, x):
        return x[block.ib], (None if block.im is None else x[block.im])

    def model_values(self, x, accuracy=ITERATION_ACCURACY) -> np.ndarray:
        """Model values of all sessions, concatenated, at natural parameters ``x``."""
        self.calls["values"] += 1
        x = np.asarray(x, dtype=float)
        return np.concatenate([b.model(accuracy).values(*self.split(b, x)) for b in self.blocks])

    def value_and_jacobian(self, x, accuracy=ITERATION_ACCURACY):
        """Model values (N,) and d values / d (every global parameter) (N, P), unweighted."""
        x = np.asarray(x, dtype=float)
        key = (x.tobytes(), accuracy)
        if key in self._cache:
            return self._cache[key]
        self.calls["jacobian"] += 1
        vals, rows = [], []
        for b in self.blocks:
            val, jb, jm = b.model(accuracy).jacobian(*self.split(b, x))
            full = np.zeros((b.size, len(self.params)))
            np.add.at(full.T, b.ib, jb.T)
            if b.im is not None:
                np.add.at(full.T, b.im, jm.T)
            vals.append(val)
            rows.append(full)
        out = (np.concatenate(vals), np.concatenate(rows))
        self._cache = {key: out}
        return out

    def slices(self) -> list[slice]:
        out, start = [], 0
        for b in self.blocks:
            out.append(slice(start, start + b.size))
            start += b.size
        return out

    def with_fixed(self, names_values: dict) -> "Problem":
        """A copy of the problem with more parameters held fixed (profiles, refits)."""
        out = Problem.__new__(Problem)
        out.__dict__.update(self.__dict__)
        out.values = self.values.copy()
        out.free = self.free.copy()
        out._cache = {}
        out.calls = {"values": 0, "jacobian": 0}
        out.prior = self.prior
        for n, v in names_values.items():
            k = self.index(n)
            out.values[k] = float(v)
            out.free[k] = False
        if not out.free.any():
            raise FitError("every parameter is fixed: nothing to fit")
        return out


# --------------------------------------------------------------------------------------
# solving
# --------------------------------------------------------------------------------------
@dataclass
class Solution:
    """A least-squares solution of a :class:`Problem` (natural ``x``, full vector)."""

    x: np.ndarray
    cost: float
    status: int
    message: str
    nfev: int
    njev: int
    at_bound: list


def solve(problem: Problem, x0, *, accuracy: str = ITERATION_ACCURACY, tol=None,
          max_nfev=None, jac_accuracy: str = ITERATION_ACCURACY, on_eval=None) -> Solution:
    """Weighted least squares (scipy "trf", x_scale="jac") from natural start ``x0``;
    values at ``accuracy``, Jacobians at ``jac_accuracy``, recomputed at every iterate
    (:mod:`veil.fitting`'s polish instead freezes the fast Jacobian); ``tol`` defaults to
    TOL_FINAL."""
    tol = tol or TOL_FINAL
    u0 = problem.to_u(x0)
    lo, hi = problem.bounds(u0)
    u0 = np.clip(u0, lo, hi)
    base = problem.values  # fixed parameters keep their values
    counts = {"f": 0, "j": 0}

    def fun(u):
        counts["f"] += 1
        x, _ = problem.to_x(u, base)
        if on_eval:
            on_eval()
        cached = problem._cache.get((x.tobytes(), accuracy))
        val = cached[0] if cached is not None else problem.model_values(x, accuracy)
        return np.concatenate([(val - problem.y) * problem.w, problem.prior_rows(x)[0]])

    def jac(u):
        counts["j"] += 1
        x, d = problem.to_x(u, base)
        _, full = problem.value_and_jacobian(x, jac_accuracy)
        full = np.concatenate([full * problem.w[:, None], problem.prior_rows(x)[1]])
        return full[:, problem.free] * d[None, :]

    lsq = least_squares(fun, u0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac",
                        max_nfev=max_nfev, **tol)
    x, _ = problem.to_x(lsq.x, base)
    hit = coordinates.at_bound(lsq.x, (lo, hi), problem.free_names)
    return Solution(x=x, cost=float(lsq.cost), status=int(lsq.status), message=lsq.message,
                    nfev=counts["f"], njev=counts["j"], at_bound=hit)


def covariance(problem: Problem, x, accuracy: str = ITERATION_ACCURACY):
    """Covariance (natural units) of the free parameters at ``x`` from the weighted Jacobian,
    scaled by the reduced chi-square when the data carry no sigma (as :mod:`veil.fitting`);
    None when the Jacobian is singular."""
    val, full = problem.value_and_jacobian(x, accuracy)
    jw = np.concatenate([full * problem.w[:, None], problem.prior_rows(x)[1]])[:, problem.free]
    # columns equilibrated first: natural units span many decades (Ps ~ 1e6, Td ~ 1e-3)
    scale = np.linalg.norm(jw, axis=0)
    if np.any(scale == 0) or not np.all(np.isfinite(scale)):
        return None
    cov = covariance_from_jacobian(jw / scale, np.ones(int(problem.free.sum())))
    if cov is not None:
        cov = cov / np.outer(scale, scale)
    if cov is not None and not problem.weighted:
        res = (problem.y - val) * problem.w
        cov = cov * float(res @ res) / max(problem.n_points - int(problem.free.sum()), 1)
    return cov


# --------------------------------------------------------------------------------------
# the joint result
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class JointResult(FitResult):
    """A joint fit (MODEL.md sec. 7): a :class:`veil.fitting.FitResult` whose ``params``
    span several models (names in the module docstring) and whose ``layout`` says which:
    ``objects`` {object: {model parameter: result name}}, ``media`` {label: {Td, Tt, g,
    eta_u: result name}}, ``shared``, ``sessions`` (name, object, medium, n_points,
    chi2, rms_relative each)."""

    layout: dict = field(default_factory=dict)

    # -- models ----------------------------------------------------------------------------
    def brdf(self, obj: str = "target") -> TorranceSparrow:
        names = self.layout["objects"].get(obj)
        if names is None:
            raise FitError(f"the joint fit has no object {obj!r}; it has "
                           f"{', '.join(self.layout['objects'])}")
        return TorranceSparrow(**{p: self.params[n] for p, n in names.items()})

    def medium(self, label: str) -> HenyeyGreenstein:
        names = self.layout["media"].get(label)
        if names is None:
            raise FitError(f"the joint fit has no medium {label!r}; it has "
                           f"{', '.join(self.layout['media']) or 'none'}")
        vals = {"Td": self.params[names["Td"]], "Tt": self.params[names["Tt"]],
                "g": self.params[names["g"]], "eta": self.params[names["eta_u"]]}
        return HenyeyGreenstein(**vals, variant=self.variant or "paper")

    def as_model(self):
        """The target's BRDF (what :meth:`FitResult.as_model` gives for a step-2 fit)."""
        return self.brdf("target")

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = super().to_dict()
        out["format"] = FORMAT
        out["layout"] = self.layout
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "the joint fit result") -> "JointResult":
        if not isinstance(data, dict) or data.get("model") != "joint":
            raise FitError(f"{source}: not a joint fit result (expected key 'model' = 'joint')")
        required = ("params", "stderr", "correlation", "chi2_reduced", "rms_relative",
                    "n_points", "converged", "message", "variant", "layout")
        missing = [k for k in required if k not in data]
        if missing:
            raise FitError(f"{source}: missing key(s) {', '.join(missing)}; is this a joint "
                           f"fit result written by veil (veil fit joint -o FILE.json)?")
        layout = data["layout"]
        if not isinstance(layout, dict) or not {"objects", "media"} <= set(layout):
            raise FitError(f"{source}: key 'layout' must hold 'objects' and 'media'")
        params = data["params"]
        if not isinstance(params, dict):
            raise FitError(f"{source}: key 'params' must map names to numbers")
        named = [n for names in layout["objects"].values() for n in names.values()]
        named += [n for names in layout["media"].values() for n in names.values()]
        absent = [n for n in dict.fromkeys(named) if n not in params]
        if absent:
            raise FitError(f"{source}: layout names parameter(s) {', '.join(absent)} missing "
                           f"from 'params'")
        for k, v in params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise FitError(f"{source}: params.{k} = {v!r} is not a number")
        if not isinstance(data["converged"], bool):
            raise FitError(f"{source}: key 'converged' must be true or false")
        try:
            result = cls(
                model="joint", params={k: float(v) for k, v in params.items()},
                stderr={k: from_json_float(data["stderr"].get(k)) for k in params},
                correlation={a: {b: from_json_float(r) for b, r in row.items()}
                             for a, row in (data["correlation"] or {}).items()},
                residuals=tuple(from_json_float(r) for r in data.get("residuals") or ()),
                chi2_reduced=from_json_float(data["chi2_reduced"]),
                rms_relative=from_json_float(data["rms_relative"]),
                n_points=int(data["n_points"]), converged=data["converged"],
                message=str(data["message"]), variant=data["variant"],
                fixed={k: float(v) for k, v in (data.get("fixed") or {}).items()},
                step="joint", weighted=bool(data.get("weighted", True)),
                accuracy=data.get("accuracy"), given=data.get("given"),
                stats=data.get("stats") or {}, layout=layout)
            for obj in layout["objects"]:
                result.brdf(obj)
            for label in layout["media"]:
                result.medium(label)
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            raise FitError(f"{source}: {exc}") from None
        return result

    # -- text ------------------------------------------------------------------------------
    def report(self, min_correlation: float = 0.1) -> str:
        free = self.free
        lines = [f"[[Joint fit: {len(self.layout.get('sessions', []))} sessions, "
                 f"{len(self.layout['media'])} media, variant {self.variant}]]",
                 f"    data points        = {self.n_points}"
                 + ("  (weighted by sigma)" if self.weighted
                    else "  (UNWEIGHTED: errors scaled by reduced chi-square)"),
                 f"    free parameters    = {len(free)}"
                 + (f"  (fixed: {', '.join(self.fixed)})" if self.fixed else ""),
                 f"    shared by the media = {', '.join(self.layout.get('shared', [])) or '-'}",
                 f"    reduced chi-square = {_fmt(self.chi2_reduced, 5)}",
                 f"    rms relative resid = {_fmt(100 * self.rms_relative, 4)} %",
                 f"    converged          = {'yes' if self.converged else 'NO'} ({self.message})"]
        if self.accuracy:
            lines.append(f"    accuracy           = {self.accuracy}")
        lines.append("[[Sessions]]")
        for s in self.layout.get("sessions", []):
            lines.append(f"    {s['name']}: {s['n_points']} points, chi2/N "
                         f"{_fmt(s['chi2'], 4)}, rms rel {_fmt(100 * s['rms_relative'], 3)} %")
        lines.append("[[Variables]]")
        width = max(len(n) for n in self.params)
        for name, v in self.params.items():
            if name in self.fixed:
                lines.append(f"    {name:<{width}}: {_fmt(v)} (fixed)")
                continue
            se = self.stderr.get(name)
            if se is None or not math.isfinite(se):
                lines.append(f"    {name:<{width}}: {_fmt(v)} +/- (not determined)")
            else:
                rel = f" ({100 * se / abs(v):.2f}%)" if v != 0 else ""
                lines.append(f"    {name:<{width}}: {_fmt(v)} +/- {_fmt(se, 3)}{rel}")
        lines += self.correlation_lines(min_correlation, most=20)
        return "\n".join(lines)


#: Numbers in the joint report: as the step reports', "nan" where they print "n/a".
_fmt = functools.partial(format_number, missing="nan")


def load_result(path) -> FitResult:
    """Read any veil fit result (a step of :mod:`veil.fitting` or a joint fit) from JSON."""
    data = read_json(path)
    if isinstance(data, dict) and data.get("model") == "joint":
        return JointResult.from_dict(data, os.fspath(path))
    return FitResult.from_dict(data, os.fspath(path))


#: Names of a single session's parameters (:func:`session_problem`): the BRDF's as in the
#: step fits, the medium's index renamed eta_u (the BRDF has an eta too).
BRDF_NAMES = ("Pd", "Ps", "n", "eta")
MEDIUM_NAMES = ("Td", "Tt", "g", "eta_u")


def session_problem(table, brdf: BRDF, medium: BTDF | None = None, *, free=(), black=None,
                    what: str = "session") -> Problem:
    """One session as a :class:`Problem` over the BRDF's parameters (``Pd, Ps, n, eta``) and
    the medium's (``Td, Tt, g, eta_u``); ``free`` names the estimated ones, the others hold
    the given models' values. The least-squares problem of a step fit of MODEL.md sec. 7
    (same residuals and weights as :mod:`veil.fitting`)."""
    data = prepare(table, black, what)
    session = Session(data.table, "none" if medium is None else "m", "target", name=what)
    params = [GlobalParam(n, "brdf", "target", i, p)
              for i, (n, p) in enumerate(zip(BRDF_NAMES, type(brdf).PARAMS))]
    values = list(brdf.to_vector())
    im = None
    if medium is not None:
        params += [GlobalParam(n, "medium", "m", i, p)
                   for i, (n, p) in enumerate(zip(MEDIUM_NAMES, type(medium).PARAMS))]
        values += list(medium.to_vector())
        im = np.arange(4, 8)
    names = [p.name for p in params]
    free = list(free)
    unknown = [n for n in free if n not in names]
    if unknown:
        raise FitError(f"{', '.join(map(repr, unknown))}: not a parameter of this session "
                       f"(parameters: {', '.join(names)})")
    mask = np.array([n in free for n in names])
    if not mask.any():
        raise FitError("no free parameter: nothing to fit")
    block = Block(session, data, np.arange(4), im, brdf, medium)
    return Problem([block], params, values, mask, weighted=data.sigma is not None)


# --------------------------------------------------------------------------------------
# building the problem
# --------------------------------------------------------------------------------------
def _declarations(shared, per_medium) -> tuple[str, ...]:
    """Which of g, eta_u are shared by the media (checked; contradictions are errors)."""
    def names(arg, what):
        if arg is None:
            return None
        if isinstance(arg, str):
            arg = [a for a in arg.replace(" ", "").split(",") if a]
        arg = list(arg)
        for a in arg:
            if a in ("Td", "Tt"):
                raise FitError(f"{what} lists {a!r}: T_d and T_t are always per medium (each "
                               f"medium or concentration has its own); only "
                               f"{' and '.join(SHAREABLE)} can be shared")
            if a == "eta":
                raise FitError(f"{what} lists 'eta': the medium's index is called 'eta_u' here "
                               f"('eta' is the target's); choose among {', '.join(SHAREABLE)}")
            if a not in SHAREABLE:
                raise FitError(f"{what} lists {a!r}: not a medium parameter that can be shared; "
                               f"choose among {', '.join(SHAREABLE)}")
        dup = [a for a in set(arg) if arg.count(a) > 1]
        if dup:
            raise FitError(f"{what} lists {dup[0]!r} twice")
        return arg

    s, p = names(shared, "shared"), names(per_medium, "per_medium")
    if s is not None and p is not None:
        both = [a for a in s if a in p]
        if both:
            raise FitError(f"contradictory sharing declarations: {', '.join(both)} declared "
                           f"both shared by the media and free per medium; declare each of "
                           f"{', '.join(SHAREABLE)} once")
    if s is None and p is None:
        return DEFAULT_SHARED
    if s is None:
        return tuple(a for a in SHAREABLE if a not in p)
    return tuple(a for a in SHAREABLE if a in s)


def _unit_vectors(angles) -> np.ndarray:
    ti, pi_, tr, pr = angles
    return np.concatenate([np.asarray(direction(ti, pi_)), np.asarray(direction(tr, pr))], axis=1)


def _check_overlap(sessions, datas) -> None:
    """Every session must share a configuration with another (module constant OVERLAP_TOL)."""
    if len(sessions) < 2:
        return
    from scipy.spatial import cKDTree

    vecs = [_unit_vectors(d.angles) for d in datas]
    radius = 2.0 * math.sqrt(2.0) * math.sin(math.radians(OVERLAP_TOL) / 2.0) * (1 + 1e-9)
    for k, s in enumerate(sessions):
        others = np.concatenate([v for j, v in enumerate(vecs) if j != k])
        dist, _ = cKDTree(others).query(vecs[k], k=1)
        if not np.any(dist <= radius):
            raise FitError(
                f"session {s.name!r} shares no configuration (within {OVERLAP_TOL:g} deg) with "
                f"any other session: a joint fit compares the same object or medium under "
                f"the same configurations; check its angle columns (degrees, MODEL.md sec. 1)")


def _anchor_check(sessions, fixed_names, reference_given, params) -> None:
    """The overall scale (P x T^2, MODEL.md sec. 2-3) must be pinned in every connected set of
    objects and media, or the fit has an exact degeneracy."""
    parent: dict = {}

    def find(a):
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    for s in sessions:
        find(("obj", s.object))
        if not s.clear:
            parent[find(("obj", s.object))] = find(("med", s.medium))
    anchored = set()
    for s in sessions:
        if s.clear:
            anchored.add(find(("obj", s.object)))
    if reference_given and any(s.object == "reference" for s in sessions):
        anchored.add(find(("obj", "reference")))
    for p in params:
        if p.name in fixed_names and p.is_scale:
            key = ("obj", p.owner) if p.kind == "brdf" else ("med", p.owner)
            anchored.add(find(key))
    roots = {find(("obj", s.object)) for s in sessions}
    for r in roots:
        if r not in anchored:
            members = sorted(f"{a[0] == 'obj' and 'object' or 'medium'} {a[1]}"
                             for a in parent if find(a) == r)
            raise FitError(
                f"the overall scale is not determined for {', '.join(members)}: the apparent "
                f"value is proportional to (Pd, Ps) x (Td, Tt)^2, so scaling the media up and "
                f"the object down fits equally well (MODEL.md sec. 2-3). Add the reference "
                f"measured in clear water (object 'reference', medium 'none') and in the "
                f"media, give reference=, or fix one scale, e.g. fixed={{'Td[label]': 1e-3}} "
                f"(--fix 'Td[label]=1e-3')")


def build(sessions, *, reference=None, shared=None, per_medium=None, fixed=None,
          variant: str = "paper") -> tuple[Problem, dict]:
    """The stacked :class:`Problem` of a joint fit and its layout (see :func:`fit_joint`)."""
    check_variant(variant)
    sessions = as_sessions(sessions)
    shared_names = _declarations(shared, per_medium)
    if not any(s.object == "target" for s in sessions):
        raise FitError("no session of the target: a joint fit estimates the target object "
                       "through the media; add at least one session with object 'target'")
    if not any(s.object == "target" and not s.clear for s in sessions):
        raise FitError("every target session is in clear water: there is no medium to fit "
                       "jointly; use veil fit direct (f_r directly) instead")
    seen = {}
    for s in sessions:
        key = (s.object, s.medium)
        if key in seen:
            raise FitError(f"two sessions of the {s.object} in medium {s.medium!r} "
                           f"({seen[key]!r} and {s.name!r}): merge them into one table")
        seen[key] = s.name
    media = list(dict.fromkeys(s.medium for s in sessions if not s.clear))
    for m in media:
        if not any(s.medium == m and s.object == "target" for s in sessions):
            raise FitError(f"medium {m!r} has a reference session but no target session: "
                           f"every medium of a joint fit must have a session of the target "
                           f"(fit that medium alone with veil fit medium)")
    ref_sessions = [s for s in sessions if s.object == "reference"]
    reference_model = None
    if reference is not None:
        reference_model = as_brdf_model(reference)
        if not ref_sessions:
            raise FitError("reference= given but no session of the reference object: the "
                           "reference's f_r only matters through its sessions (object "
                           "'reference')")
    elif ref_sessions and not any(s.clear for s in ref_sessions):
        raise FitError("reference sessions in a medium need the reference's f_r: give "
                       "reference= (the step-0 result or a TorranceSparrow) or add its "
                       "clear-water session (object 'reference', medium 'none')")

    datas = [prepare(s.table, None, s.name) for s in sessions]
    weighted = {d.sigma is not None for d in datas}
    if len(weighted) > 1:
        which = [s.name for s, d in zip(sessions, datas) if d.sigma is None]
        raise FitError(f"session(s) {', '.join(which)} have no sigma column but the others "
                       f"do: weighted and unweighted residuals cannot be mixed in one fit; "
                       f"give every session a sigma column or none")
    _check_overlap(sessions, datas)

    params: list[GlobalParam] = []
    objects_layout: dict = {}
    for obj, prefix in (("target", ""), ("reference", "ref.")):
        if not any(s.object == obj for s in sessions):
            continue
        objects_layout[obj] = {}
        for i, p in enumerate(TorranceSparrow.PARAMS):
            name = prefix + p.name
            params.append(GlobalParam(name, "brdf", obj, i, p))
            objects_layout[obj][p.name] = name
    media_layout: dict = {}
    for pname in ("g", "eta_u"):
        if pname in shared_names and media:
            spec = HenyeyGreenstein.PARAMS[_MEDIUM_NAMES[pname]]
            params.append(GlobalParam(pname, "medium", "*", _MEDIUM_NAMES[pname], spec))
    for m in media:
        media_layout[m] = {}
        for pname, i in _MEDIUM_NAMES.items():
            if pname in shared_names:
                media_layout[m][pname] = pname
                continue
            name = f"{pname}[{m}]"
            params.append(GlobalParam(name, "medium", m, i, HenyeyGreenstein.PARAMS[i]))
            media_layout[m][pname] = name
    names = [p.name for p in params]
    index = {n: k for k, n in enumerate(names)}

    fixed = as_fixed(fixed)
    for k, v in fixed.items():
        if k not in index:
            hint = ""
            if k in ("g", "eta_u") and k not in shared_names:
                hint = f" ({k} is free per medium here: fix {k}[label] for each medium)"
            raise FitError(f"cannot fix {k!r}: the joint fit's parameters are "
                           f"{', '.join(names)}{hint}")
        check_fixed(k, v, params[index[k]].spec, k)
    values = np.array([p.spec.lower + 1.0 if math.isfinite(p.spec.lower) else 1.0
                       for p in params])
    free = np.ones(len(params), dtype=bool)
    if reference_model is not None:
        for pname, gname in objects_layout["reference"].items():
            if gname in fixed:
                raise FitError(f"cannot fix {gname!r}: the reference is given (reference=) "
                               f"and held fixed as a whole")
            values[index[gname]] = getattr(reference_model, pname)
            free[index[gname]] = False
    for k, v in fixed.items():
        values[index[k]] = float(v)
        free[index[k]] = False
    if not free.any():
        raise FitError("every parameter of the joint fit is fixed: nothing to fit")
    _anchor_check(sessions, set(fixed), reference_model is not None, params)

    template_m = HenyeyGreenstein(1e-3, 0.1, 0.9, 1.33, variant=variant)
    template_b = TorranceSparrow(1.0, 1.0, 0.5, 1.5)
    blocks = []
    for s, d in zip(sessions, datas):
        ib = np.array([index[n] for n in objects_layout[s.object].values()])
        im = None if s.clear else np.array([index[media_layout[s.medium][p]]
                                            for p in _MEDIUM_NAMES])
        blocks.append(Block(s, d, ib, im, template_b, None if s.clear else template_m))
    problem = Problem(blocks, params, values, free, weighted=weighted.pop())
    n_free = int(free.sum())
    if problem.n_points <= n_free:
        raise FitError(f"the sessions have {problem.n_points} points but the joint fit has "
                       f"{n_free} free parameters: measure more configurations or fix some")
    layout = {"objects": objects_layout, "media": media_layout, "shared": list(shared_names),
              "reference_given": reference_model is not None}
    return problem, layout


# --------------------------------------------------------------------------------------
# starting values
# --------------------------------------------------------------------------------------
def _subsample(block: Block) -> tuple:
    m = block.size
    if m <= GRID_SUBSAMPLE:
        idx = np.arange(m)
    else:
        idx = np.unique(np.round(np.linspace(0, m - 1, GRID_SUBSAMPLE)).astype(int))
    return idx


def _rows(td, tt):
    return np.array([td * td, td * tt, tt * tt])


def _grid_engine(block: Block, idx, cache: dict):
    key = id(block)
    if key not in cache:
        angles = tuple(a[idx] for a in block.data.angles)
        cache[key] = SessionModel(block.brdf, block.medium, angles, ITERATION_ACCURACY)
    return cache[key]


def _start_points(problem: Problem, layout: dict, start: dict | None, progress):
    """Starting vectors (natural), best first: reference by step 0, media with a reference
    session by a grid over g, the target (and media seen only through it) by a grid over n
    with every scale solved exactly (linear and quadratic least squares, as veil.fitting)."""
    x = problem.values.copy()
    fixed_mask = ~problem.free
    idx_of = {n: k for k, n in enumerate(problem.names)}
    objects, media = layout["objects"], layout["media"]

    def set_(name, value):
        k = idx_of[name]
        if not fixed_mask[k]:
            x[k] = value

    def get(name):
        return x[idx_of[name]]

    start = dict(start or {})
    # 1. defaults
    for obj, names in objects.items():
        for p, n in zip(("Pd", "Ps", "n", "eta"), (1.0, 1.0, 0.5, 1.5)):
            set_(names[p], n)
    for label, names in media.items():
        for p, v in (("Td", 1e-3), ("Tt", 0.1), ("g", 0.9), ("eta_u", 1.33)):
            set_(names[p], v)
    known_media, known_objects = set(), set()
    if layout.get("reference_given"):
        known_objects.add("reference")
    for key, model in start.items():
        if key in objects:
            for p in ("Pd", "Ps", "n", "eta"):
                set_(objects[key][p], getattr(model, p))
            known_objects.add(key)
        elif key in media:
            for p, attr in (("Td", "Td"), ("Tt", "Tt"), ("g", "g"), ("eta_u", "eta")):
                set_(media[key][p], getattr(model, attr))
            known_media.add(key)
        else:
            raise FitError(f"start: {key!r} is neither an object ({', '.join(objects)}) nor a "
                           f"medium ({', '.join(media)}) of the joint fit")
    blocks = problem.blocks
    # 2. objects with a clear session: fit f_r directly (step 0)
    for obj in objects:
        if obj in known_objects:
            continue
        clear = [b for b in blocks if b.session.object == obj and b.session.clear]
        if clear:
            fx = {p: problem.values[idx_of[n]] for p, n in objects[obj].items()
                  if fixed_mask[idx_of[n]]}
            r = fit_reference(clear[0].data.table, fixed=fx or None)
            for p in ("Pd", "Ps", "n", "eta"):
                set_(objects[obj][p], r.params[p])
            known_objects.add(obj)
    if progress:
        progress("starting values: objects in clear water", 1, 1)
    cache: dict = {}
    # 3. media seen through a known object: grid over g, scales exact
    for label, names in media.items():
        if label in known_media:
            continue
        through = [b for b in blocks if b.session.medium == label
                   and b.session.object in known_objects]
        if not through:
            continue
        b = through[0]
        idx = _subsample(b)
        eng = _grid_engine(b, idx, cache)
        vb = x[b.ib]
        best = None
        grid = [get(names["g"])] if fixed_mask[idx_of[names["g"]]] else G_GRID
        for g in grid:
            vm = x[b.im].copy()
            vm[2] = g
            terms = eng.terms(vb, vm)
            basis = np.einsum("mkb,b->mk", terms, np.array([vb[0], vb[1]]))
            fx = {p: vm[i] for p, i in (("Td", 0), ("Tt", 1))
                  if fixed_mask[idx_of[names[p]]]}
            vm, cost = medium_scales(basis, vm, HenyeyGreenstein, fx, b.data.y[idx],
                                     b.data.w[idx])
            if best is None or cost < best[0]:
                best = (cost, vm)
        for p, i in _MEDIUM_NAMES.items():
            if p in ("Td", "Tt", "g"):
                set_(names[p], best[1][i])
        known_media.add(label)
    if progress:
        progress("starting values: media", 1, 1)
    # 4. the target (and media seen only through it): grid over n
    if "target" in known_objects:
        return [x]
    tnames = objects["target"]
    tblocks = [b for b in blocks if b.session.object == "target" and not b.session.clear]
    n_fixed = fixed_mask[idx_of[tnames["n"]]]
    n_grid = [get(tnames["n"])] if n_fixed else list(N_GRID)
    scored = []
    for k, n in enumerate(n_grid):
        xt = x.copy()
        xt[idx_of[tnames["n"]]] = n
        cost, xt = _target_point(problem, xt, tblocks, known_media, media, idx_of, cache)
        scored.append((cost, k, xt))
        if progress:
            progress("starting grid over n", k + 1, len(n_grid))
    scored.sort(key=lambda t: (t[0], t[1]))
    chosen = []
    for cost, k, xt in scored:
        if not np.isfinite(cost) or any(abs(k - c) <= 1 for _, c, _ in chosen):
            continue
        chosen.append((cost, k, xt))
        if len(chosen) == STARTS:
            break
    return [xt for _, _, xt in chosen] or [x]


def _target_point(problem, x, tblocks, known_media, media, idx_of, cache):
    """Exact scales of target and unknown media at one n; returns (cost, x)."""
    fixed_mask = ~problem.free
    tnames = {p: problem.names[k] for p, k in zip(("Pd", "Ps", "n", "eta"), tblocks[0].ib)}
    # term matrices of every target session: per unknown medium for each g of its grid
    terms = {}
    for b in tblocks:
        idx = _subsample(b)
        eng = _grid_engine(b, idx, cache)
        label = b.session.medium
        names = media[label]
        g_fixed = fixed_mask[idx_of[names["g"]]]
        grid = [x[idx_of[names["g"]]]] if (label in known_media or g_fixed) else G_GRID
        for g in grid:
            vm = x[b.im].copy()
            vm[2] = g
            terms[(id(b), g)] = (eng.terms(x[b.ib], vm), idx, g)
    # alternate: (Pd, Ps) pooled given the media; each unknown medium's (g, Td, Tt) given them
    chosen_g = {}
    for b in tblocks:
        label = b.session.medium
        opts = [v for (bid, g), v in terms.items() if bid == id(b)]
        chosen_g[id(b)] = opts[len(opts) // 2][2] if label not in known_media else opts[0][2]
    c_fixed = {p: x[idx_of[tnames[p]]] for p in ("Pd", "Ps") if fixed_mask[idx_of[tnames[p]]]}
    cost = np.inf
    for _ in range(3):
        cols, ys, ws = [], [], []
        for b in tblocks:
            t, idx, _ = terms[(id(b), chosen_g[id(b)])]
            vm = x[b.im]
            cols.append(np.einsum("mkb,k->mb", t, _rows(vm[0], vm[1])))
            ys.append(b.data.y[idx])
            ws.append(b.data.w[idx])
        basis, y, w = np.concatenate(cols), np.concatenate(ys), np.concatenate(ws)
        vb = x[tblocks[0].ib].copy()
        vb, _ = brdf_scales(basis, vb, TorranceSparrow, c_fixed, y, w)
        for p, i in (("Pd", 0), ("Ps", 1)):
            if not fixed_mask[idx_of[tnames[p]]]:
                x[idx_of[tnames[p]]] = vb[i]
        cost = 0.0
        for b in tblocks:
            label = b.session.medium
            names = media[label]
            if label in known_media:
                t, idx, _ = terms[(id(b), chosen_g[id(b)])]
                vm = x[b.im]
                model = np.einsum("mkb,k,b->m", t, _rows(vm[0], vm[1]), x[b.ib][:2])
                cost += float(np.sum(((model - b.data.y[idx]) * b.data.w[idx]) ** 2))
                continue
            best = None
            for (bid, g), (t, idx, _) in terms.items():
                if bid != id(b):
                    continue
                basis_m = np.einsum("mkb,b->mk", t, x[b.ib][:2])
                vm = x[b.im].copy()
                vm[2] = g
                fx = {p: vm[i] for p, i in (("Td", 0), ("Tt", 1))
                      if fixed_mask[idx_of[names[p]]]}
                vm, c = medium_scales(basis_m, vm, HenyeyGreenstein, fx, b.data.y[idx],
                                      b.data.w[idx])
                if best is None or c < best[0]:
                    best = (c, g, vm)
            c, g, vm = best
            chosen_g[id(b)] = g
            for p, i in (("Td", 0), ("Tt", 1), ("g", 2)):
                k = idx_of[names[p]]
                if not fixed_mask[k]:
                    x[k] = vm[i]
            cost += c
    return cost, x


# --------------------------------------------------------------------------------------
# the fit
# --------------------------------------------------------------------------------------
def fit_joint(sessions, *, reference=None, shared=None, per_medium=None, fixed=None,
              start=None, variant: str = "paper", accuracy: str = "default", max_nfev=None,
              progress=None) -> JointResult:
    """Fit several sessions of one target under several media at once (module docstring).

    sessions : list of :class:`Session` (table, medium label, object "target"/"reference")
        or (table, medium[, object]) tuples, or a dict {medium label: target table}; medium
        "none" is clear water. Tables are DataFrames or CSV paths, black cloth subtracted.
    reference : the reference's f_r (step-0 FitResult or TorranceSparrow), held fixed; without
        it a clear-water reference session makes the reference's parameters free.
    shared, per_medium : which of g, eta_u the media share (default: eta_u shared, g per
        medium); a name in both is an error. T_d and T_t are always per medium.
    fixed : {parameter name: value}, names as in the result (e.g. "eta", "Td[low]", "g").
    start : optional starting models {object or medium label: TorranceSparrow/HenyeyGreenstein}.
    variant, accuracy, max_nfev, progress : as :func:`veil.fitting.fit_medium`.
    """
    check_accuracy(accuracy)
    check_max_nfev(max_nfev)
    if start is not None:
        if not isinstance(start, dict):
            raise FitError("start: expected a dict {object or medium label: model}")
        start = {k: (v.as_model() if isinstance(v, FitResult) else v) for k, v in start.items()}
    problem, layout = build(sessions, reference=reference, shared=shared,
                            per_medium=per_medium, fixed=fixed, variant=variant)
    polish = accuracy != ITERATION_ACCURACY
    for block in problem.blocks:  # compile side by side what the fit will need
        block.model(ITERATION_ACCURACY).prepare(values=True, jacobian=True)
        if polish:
            block.model(accuracy).prepare(values=True)
    starts = _start_points(problem, layout, start, progress)
    runs = []
    skipped = 0
    for s, x0 in enumerate(starts):
        if runs and any(_convincing(problem, r) for r in runs):
            skipped = len(starts) - s
            break
        # progress or None: a progress that tests false reports nothing (as `if progress:`)
        tick = ticker(progress or None, f"start {s + 1}/{len(starts)}: iteration")
        runs.append(solve(problem, x0, tol=TOL_ITER if polish else TOL_FINAL,
                          max_nfev=max_nfev, on_eval=tick))
    best = min(range(len(runs)), key=lambda r: (runs[r].cost, r))
    sol = runs[best]
    run_stats = [{"nfev": r.nfev, "njev": r.njev, "status": r.status, "cost": r.cost}
                 for r in runs]
    notes = []
    if polish:
        if sol.status <= 0:
            notes.append(stopped_early_note(sol.message))
        tick_polish = ticker(progress or None, f"polish at {accuracy!r}: iteration")
        sol = solve(problem, sol.x, accuracy=accuracy, tol=TOL_FINAL, max_nfev=max_nfev,
                    on_eval=tick_polish)
        run_stats.append({"nfev": sol.nfev, "njev": sol.njev, "status": sol.status,
                          "cost": sol.cost, "polish": True})
    values = problem.model_values(sol.x, accuracy)
    if sol.at_bound:
        notes.append(edge_note(sol.at_bound))
    stats = {"starts": len(runs), "starts_skipped": skipped, "best_start": best + 1,
             "nfev": sum(r["nfev"] for r in run_stats),
             "njev": sum(r["njev"] for r in run_stats), "runs": run_stats,
             "configurations": problem.n_points}
    given = model_dict(as_brdf_model(reference)) if reference is not None else None
    return _result(problem, layout, sol, values, notes, variant, accuracy, given, stats)


def _convincing(problem: Problem, sol: Solution) -> bool:
    """As veil.fitting's multi-start: a weighted fit that converged inside its search range
    with reduced chi-square <= CONVINCING; further starts are then skipped (a second minimum
    of similar cost is what veil.diagnostics' profiles look for)."""
    return convincing(sol.status, sol.cost, problem.n_points - int(problem.free.sum()),
                      problem.weighted, sol.at_bound)


def _result(problem: Problem, layout, sol: Solution, values, notes, variant, accuracy, given,
            stats) -> JointResult:
    """Assemble the JointResult (the FitResult conventions of veil.fitting)."""
    y = problem.y
    res, chi2, rms_rel = goodness(y, problem.w, values, int(problem.free.sum()))
    cov = covariance(problem, sol.x)
    notes = list(notes)
    names = problem.names
    stderr = {n: None for n in names}
    corr: dict = {}
    if cov is None:
        notes.append(SINGULAR_NOTE)
    else:
        stderr, corr = uncertainties(cov, names, problem.free_index)
    sessions = []
    for b, sl in zip(problem.blocks, problem.slices()):
        r = res[sl]
        v = values[sl]
        nzb = v != 0
        relb = (y[sl][nzb] - v[nzb]) / v[nzb]
        sessions.append({"name": b.session.name, "object": b.session.object,
                         "medium": b.session.medium, "n_points": int(b.size),
                         "chi2": float(r @ r) / b.size,
                         "rms_relative": float(np.sqrt(np.mean(relb ** 2))) if relb.size else None})
    layout = dict(layout, sessions=sessions)
    converged, message = outcome(sol.status, sol.message, notes)
    fixed = {n: float(sol.x[k]) for k, n in enumerate(names) if not problem.free[k]}
    return JointResult(model="joint", params={n: float(v) for n, v in zip(names, sol.x)},
                       stderr=stderr, correlation=corr, residuals=tuple(float(r) for r in res),
                       chi2_reduced=chi2, rms_relative=rms_rel, n_points=problem.n_points,
                       converged=converged, message=message, variant=variant, fixed=fixed,
                       step="joint", weighted=problem.weighted, accuracy=accuracy,
                       given=given, stats=stats, layout=layout)


__all__ = ["fit_joint", "Session", "JointResult", "load_result", "SessionModel", "Problem",
           "session_problem",
           "GlobalParam", "build", "solve", "covariance", "SHAREABLE", "DEFAULT_SHARED"]
