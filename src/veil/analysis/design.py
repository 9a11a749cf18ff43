"""Acquisition design: which configurations and media to measure (docs/model.md sec. 1, 7).

The Fisher information of a measurement plan at given parameters is J^T W J, J the
Jacobian of the apparent reflectance (docs/model.md eq. 1) with respect to the parameters and
W = 1 / sigma^2 with sigma^2 = (noise f)^2 + floor^2 (relative noise as the simulator's,
optionally an absolute floor). A plan is chosen greedily: each step adds the candidate - a
goniometer configuration (psi, rho) under one medium condition - that most increases
log det of the information about the parameters of interest (D_s-optimality: the other
parameters are nuisances, profiled out through the Schur complement).

Conditions are media: given models (e.g. the paper's BTDF1-3, thin to thick, docs/model.md sec. 6)
and/or concentration factors c of each (the medium model says what a concentration does:
the paper's scales T_d and T_t; :meth:`veil.models.Medium.concentrated`). Note that a common
factor on the paper medium's T_d and T_t multiplies the apparent value by c^2 (docs/model.md
sec. 5): under purely relative noise it carries no information of its own; it matters
through an absolute noise floor.

Parameters are taken in fit coordinates (log for scale parameters). Of the target's BRDF
only ratios of its scales mean anything (docs/model.md sec. 2): its first scale is the level (a
nuisance), the others enter as ratios to it (the paper's Ps/Pd), and the ratios and the
BRDF's other parameters (the paper's n and eta) are the parameters of interest. With
``mode="joint"`` (default) every medium parameter is a nuisance - per condition, or shared
when the model declares it shareable and all conditions have the same value, as in
:func:`veil.fit_joint`; with ``mode="known"`` the media are taken as exactly known (the
two-step view).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from ..data.measurements import ANGLE_COLUMNS
from ..data.protocol import protocol
from ..engine.apparent import as_brdf, as_btdf
from ..errors import InputError
from ..fitting.problem import SessionModel
from ..models import BTDF, default_class, model_class

DEFAULT_PSI = (30.0, 45.0, 60.0, 75.0, 90.0, 105.0, 120.0)
MODES = ("joint", "known")
#: Weak Gaussian prior (standard deviation in fit coordinates: log units for scale
#: parameters, plain for g and the indices). It only makes the first greedy steps well
#: defined; an interest parameter whose predicted stderr is close to it is not identified.
PRIOR_SD_LOG = 10.0
PRIOR_SD_PLAIN = 1.0
#: Smallest relative noise of a measurement: below, 1/sigma^2 swamps the weak prior in
#: float64 and the information matrix is singular.
MIN_RELATIVE_NOISE = 1e-6


def interest_names(brdf_cls) -> tuple[str, ...]:
    """The BRDF's parameters of interest: ratios of its scales to the first (the level),
    then its other parameters (module docstring)."""
    scales = brdf_cls.scale_names()
    ratios = tuple(f"{s}/{scales[0]}" for s in scales[1:])
    return ratios + tuple(p.name for p in brdf_cls.PARAMS if p.name not in scales)


def plan_columns(medium_cls) -> tuple[str, ...]:
    """Columns of a plan: step, condition, the angles, medium_<parameter> of the row's
    condition, gain."""
    return (
        ("step", "condition")
        + ANGLE_COLUMNS
        + tuple(f"medium_{p.name}" for p in medium_cls.PARAMS)
        + ("gain",)
    )


#: Interest and plan columns of the paper's models.
INTEREST = interest_names(default_class("brdf"))
PLAN_COLUMNS = plan_columns(default_class("medium"))


def _floats(name, values, positive=True):
    out = []
    for v in np.atleast_1d(values):
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{name}: {v!r} is not a number") from None
        if not math.isfinite(x) or (positive and x <= 0):
            wanted = "a finite number" + (" > 0" if positive else "")
            raise InputError(f"{name} = {x:g}: expected {wanted}")
        out.append(x)
    if not out:
        raise InputError(f"{name} is empty")
    if len(set(out)) != len(out):
        raise InputError(f"{name} = {out}: a value is repeated")
    return tuple(out)


def condition_medium(medium, factor: float) -> BTDF:
    """The medium at concentration factor ``factor`` (module docstring)."""
    return as_btdf(medium).concentrated(factor)


def conditions(media, factors=None) -> dict:
    """Medium conditions {label: medium model}: each medium (model or preset name) at each
    concentration factor (default: as given). Labels: the preset name or "medium k", with
    " x<factor>" when factors are given."""
    if isinstance(media, (str,)) or not isinstance(media, (list, tuple)):
        media = [media]
    if not media:
        raise InputError("no medium given: the design needs at least one medium condition")
    out = {}
    for k, m in enumerate(media):
        model = as_btdf(m)
        base = (
            m.upper() if isinstance(m, str) else (f"medium {k + 1}" if len(media) > 1 else "medium")
        )
        if factors is None:
            label = base
            if label in out:
                raise InputError(f"medium {label} is given twice")
            out[label] = model
            continue
        for f in _floats("factors", factors):
            label = f"{base} x{f:g}"
            if label in out:
                raise InputError(f"condition {label} is given twice")
            out[label] = condition_medium(model, f)
    return out


def candidates(
    conds: dict,
    psi=DEFAULT_PSI,
    *,
    fine_step: float = 1.0,
    coarse_step: float = 5.0,
    window: float = 10.0,
    limit: float = 85.0,
) -> pd.DataFrame:
    """Candidate measurements: every protocol configuration (:func:`veil.protocol.protocol`)
    under every condition. Columns condition, psi, rho, theta_i, phi_i, theta_r, phi_r
    (degrees)."""
    psi = _floats("psi", psi)
    configs = protocol(
        psi, fine_step=fine_step, coarse_step=coarse_step, window=window, limit=limit
    )
    blocks = []
    for label in conds:
        block = configs.copy()
        block.insert(0, "condition", label)
        blocks.append(block)
    return pd.concat(blocks, ignore_index=True)


def _check_noise(noise, floor) -> None:
    """The relative noise and the noise floor: finite, >= 0, not both 0."""
    for name, v in (("noise", noise), ("noise floor", floor)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise InputError(f"{name} = {v!r}: expected a finite number >= 0")
    if noise == 0 and floor == 0:
        raise InputError(
            "noise and noise floor are both 0: the information would be "
            "infinite; give a relative noise (e.g. 0.01) or a floor"
        )


def _medium_columns(mcls, media: list, labels: list, names: list, prior_log: list) -> dict:
    """The columns of the media's parameters in a joint design: {(condition, parameter):
    column}, one per condition, or one for all when the media share the value. Appends the
    columns' names and whether their prior is in logs to ``names`` and ``prior_log``."""
    col = {}
    shared = {
        p.name: p.share is not None and len({getattr(m, p.name) for m in media}) == 1
        for p in mcls.PARAMS
    }
    for label in labels:
        for p in mcls.PARAMS:
            if shared[p.name]:
                continue
            col[(label, p.name)] = len(names)
            names.append(f"{p.key}[{label}]")
            prior_log.append(p.log_scale)
    for p in mcls.PARAMS:
        if shared[p.name]:
            idx = len(names)
            names.append(p.key)
            prior_log.append(p.log_scale)
            for label in labels:
                col[(label, p.name)] = idx
    return col


def _interest(bcls, interest) -> tuple:
    """The parameters of interest (default: every one a plan can inform), checked."""
    possible = interest_names(bcls)
    if not possible:
        raise InputError(
            f"the BRDF family {bcls.NAME} has one scale and no other "
            f"parameter: only its level, which no plan can separate from the "
            f"media's, could be estimated; there is nothing to design for"
        )
    interest = possible if interest is None else tuple(interest)
    unknown = [p for p in interest if p not in possible]
    if unknown or not interest:
        raise InputError(
            f"parameters of interest {list(interest)}: choose among {', '.join(possible)}"
        )
    return interest


def _check_conditions(conditions: dict, table: pd.DataFrame) -> None:
    """Every candidate's condition is known, and every condition of one medium model."""
    missing = set(table["condition"]) - set(conditions)
    if missing:
        raise InputError(f"candidates name unknown condition(s) {', '.join(sorted(missing))}")
    classes = {type(m) for m in conditions.values()}
    if len(classes) > 1:
        raise InputError(
            "the conditions mix medium models "
            f"({', '.join(sorted(c.NAME for c in classes))}); use one"
        )


class Information:
    """Per-candidate information rows of a design problem (module docstring).

    ``rows[k]`` is d f_k / d theta / sigma_k over the parameters ``names`` in fit
    coordinates (log for scale parameters, including the ratio Ps/Pd); the information of
    a plan is the sum of rows[k] rows[k]^T plus the weak prior ``prior`` (precisions).
    ``interest`` indexes the parameters of interest.
    """

    def __init__(
        self,
        brdf,
        conds: dict,
        table: pd.DataFrame,
        *,
        noise: float = 0.01,
        floor: float = 0.0,
        mode: str = "joint",
        interest=None,
        accuracy: str = "fast",
    ):
        if mode not in MODES:
            raise InputError(f"medium mode {mode!r}; expected one of {', '.join(MODES)}")
        _check_noise(noise, floor)
        self.brdf = as_brdf(brdf)
        bcls = type(self.brdf)
        interest = _interest(bcls, interest)
        self.conditions = dict(conds)
        self.table = table.reset_index(drop=True)
        _check_conditions(self.conditions, self.table)
        self.noise, self.floor, self.mode = float(noise), float(floor), mode
        labels = list(self.conditions)
        media = list(self.conditions.values())
        mcls = type(media[0])
        scales = bcls.scale_names()
        level = bcls.index(scales[0]) if scales else None
        # BRDF columns: ratios, other parameters, the level (a nuisance) last
        specs = [(f"{s}/{scales[0]}", bcls.index(s), True, "ratio") for s in scales[1:]]
        specs += [
            (p.name, i, p.log_scale, "own")
            for i, p in enumerate(bcls.PARAMS)
            if p.name not in scales
        ]
        names = [s[0] for s in specs] + ([scales[0]] if scales else [])
        prior_log = [s[2] for s in specs] + ([True] if scales else [])
        col = _medium_columns(mcls, media, labels, names, prior_log) if mode == "joint" else {}
        self.names = names
        self.interest = [names.index(p) for p in interest]
        self.nuisance = [k for k in range(len(names)) if k not in self.interest]
        self.prior = np.array(
            [1.0 / PRIOR_SD_LOG**2 if lg else 1.0 / PRIOR_SD_PLAIN**2 for lg in prior_log]
        )
        vb = self.brdf.to_vector()
        rows = np.zeros((len(self.table), len(names)))
        values = np.zeros(len(self.table))
        angles_all = [
            self.table[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r")
        ]
        cond = self.table["condition"].to_numpy()
        for label, medium in self.conditions.items():
            sel = np.flatnonzero(cond == label)
            if sel.size == 0:
                continue
            vm = medium.to_vector()
            model = SessionModel(self.brdf, medium, [a[sel] for a in angles_all], accuracy)
            val, jb, jm = model.jacobian(vb, vm)
            sigma = self._sigma(val)
            # fit coordinates: log for log-scale parameters; a ratio s_j / s_1 moves s_j only,
            # the level s_1 moves every scale together
            r = np.zeros((sel.size, len(names)))
            for k, (_, i, log, _kind) in enumerate(specs):
                r[:, k] = jb[:, i] * (vb[i] if log else 1.0)
            if level is not None:
                r[:, len(specs)] = sum(jb[:, bcls.index(s)] * vb[bcls.index(s)] for s in scales)
            if mode == "joint":
                for i, p in enumerate(mcls.PARAMS):
                    r[:, col[(label, p.name)]] += jm[:, i] * (vm[i] if p.log_scale else 1.0)
            rows[sel] = r / sigma[:, None]
            values[sel] = val
        self.rows = rows
        self.values = values

    def _sigma(self, val: np.ndarray) -> np.ndarray:
        """Each candidate's noise (relative and floor in quadrature) at model values ``val``:
        an InputError when it is beyond float64, 0, or so small against the values that the
        information would swamp the prior."""
        with np.errstate(over="ignore"):  # beyond float64: refused below
            sigma = np.hypot(self.noise * val, self.floor)
        if not np.all(np.isfinite(sigma)):
            raise InputError(
                f"noise = {self.noise:g}, noise floor = {self.floor:g}: a measurement's "
                f"noise would be beyond the range of float64 (model values up to "
                f"{float(np.max(np.abs(val))):.3g}); give smaller values"
            )
        if np.any(sigma <= 0):
            raise InputError(
                "the model is 0 at some candidate configuration and there is "
                "no noise floor: give --noise-floor"
            )
        small = float(np.min(sigma / np.maximum(np.abs(val), 1e-300)))
        if small < MIN_RELATIVE_NOISE:
            raise InputError(
                f"noise = {self.noise:g}, noise floor = {self.floor:g}: a measurement "
                f"would have a relative noise of {small:.3g}, below "
                f"{MIN_RELATIVE_NOISE:g}; the information would swamp the weak prior "
                f"in float64 arithmetic; give a larger noise or floor"
            )
        return sigma

    # ----------------------------------------------------------------------------------
    def matrix(self, selected=()) -> np.ndarray:
        """Information of the candidates ``selected`` (indices), prior included."""
        sel = np.asarray(list(selected), dtype=int)
        r = self.rows[sel]
        return np.diag(self.prior) + r.T @ r

    def criterion(self, m: np.ndarray) -> float:
        """log det of the interest block of the inverse, negated (D_s): larger is better."""
        nu = self.nuisance
        s = m[np.ix_(self.interest, self.interest)]
        if nu:
            s = s - m[np.ix_(self.interest, nu)] @ np.linalg.solve(
                m[np.ix_(nu, nu)], m[np.ix_(nu, self.interest)]
            )
        sign, logdet = np.linalg.slogdet(s)
        return float(logdet) if sign > 0 else -np.inf

    def gains(self, m: np.ndarray) -> np.ndarray:
        """Increase of :meth:`criterion` from adding each candidate once to information m."""
        full = np.einsum("kp,pq,kq->k", self.rows, np.linalg.inv(m), self.rows)
        g = np.log1p(full)
        nu = self.nuisance
        if nu:
            rn = self.rows[:, nu]
            part = np.einsum("kp,pq,kq->k", rn, np.linalg.inv(m[np.ix_(nu, nu)]), rn)
            g = g - np.log1p(part)
        return g

    def stderr(self, m: np.ndarray) -> dict[str, float]:
        """Predicted standard errors (fit coordinates: relative for log parameters)."""
        cov = np.linalg.inv(m)
        return {n: float(math.sqrt(max(cov[k, k], 0.0))) for k, n in enumerate(self.names)}


def greedy(info: Information, size: int, base=(), allowed=None) -> tuple[np.ndarray, np.ndarray]:
    """Greedy D_s-optimal selection of ``size`` distinct candidates on top of ``base``
    (indices already measured), among ``allowed`` (boolean mask; default all).

    Returns (indices in order, gain of each step). Ties go to the lowest index, so the
    plan is deterministic.
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
        raise InputError(f"size = {size!r}: expected a positive integer")
    base = [int(k) for k in base]
    available = (
        np.ones(len(info.rows), dtype=bool)
        if allowed is None
        else np.asarray(allowed, dtype=bool).copy()
    )
    available[base] = False
    if size > available.sum():
        raise InputError(
            f"size = {size} but only {int(available.sum())} candidate configurations are available"
        )
    m = info.matrix(base)
    chosen, gains = [], []
    for _ in range(size):
        g = info.gains(m)
        g[~available] = -np.inf
        k = int(np.argmax(g))
        chosen.append(k)
        gains.append(float(g[k]))
        available[k] = False
        m = m + np.outer(info.rows[k], info.rows[k])
    return np.array(chosen, dtype=int), np.array(gains)


def rank(info: Information, base=()) -> pd.DataFrame:
    """Every candidate not in ``base`` with the gain of adding it alone to the plan ``base``
    (indices), best first (ties: lowest index): the candidates table plus columns ``index``
    and ``gain``."""
    base = [int(k) for k in base]
    g = info.gains(info.matrix(base))
    out = info.table.copy()
    out.insert(0, "index", np.arange(len(out)))
    out["gain"] = g
    out = out.drop(index=base)
    return out.sort_values(
        ["gain", "index"], ascending=[False, True], kind="mergesort"
    ).reset_index(drop=True)


def plan_table(info: Information, chosen, gains) -> pd.DataFrame:
    """The plan as a table (columns :func:`plan_columns`); angles in degrees, the medium
    parameters of each row's condition in the medium_* columns."""
    rows = info.table.iloc[np.asarray(chosen, dtype=int)].reset_index(drop=True)
    out = pd.DataFrame(
        {"step": np.arange(1, len(rows) + 1), "condition": rows["condition"].to_numpy()}
    )
    for c in ("psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r"):
        out[c] = rows[c].to_numpy(dtype=float)
    meds = [info.conditions[label] for label in out["condition"]]
    for p in type(meds[0]).PARAMS:
        out[f"medium_{p.name}"] = [getattr(m, p.name) for m in meds]
    out["gain"] = np.asarray(gains, dtype=float)
    return out


def design(
    brdf,
    media,
    size: int = 60,
    *,
    factors=None,
    psi=DEFAULT_PSI,
    noise: float = 0.01,
    floor: float = 0.0,
    mode: str = "joint",
    interest=None,
    accuracy: str = "fast",
    fine_step: float = 1.0,
    coarse_step: float = 5.0,
    window: float = 10.0,
    limit: float = 85.0,
) -> dict[str, Any]:
    """Recommend a measurement plan of ``size`` configurations (module docstring).

    brdf : the target (model or preset) at which the information is evaluated.
    media, factors : the candidate conditions (:func:`conditions`).
    Returns a dict: ``plan`` (DataFrame, :func:`plan_table`), ``stderr`` (predicted standard
    errors of every parameter after the plan, fit coordinates: relative for log
    parameters), ``conditions`` (DataFrame: per condition, the plan rows using it and the
    predicted stderr of the interest parameters with a plan of the same size from that
    condition alone), ``information`` (the :class:`Information`) and ``criterion``.
    """
    if getattr(brdf, "LINEAR", False):
        raise InputError(
            f"{brdf.NAME}: the design's information is that of an iterative fit of the "
            f"target's parameters, and a linear family is fitted by a regularized linear "
            f"solve (docs/nonparametric.md); design for the closest parametric family"
        )
    conds = conditions(media, factors)
    table = candidates(
        conds, psi, fine_step=fine_step, coarse_step=coarse_step, window=window, limit=limit
    )
    info = Information(
        brdf,
        conds,
        table,
        noise=noise,
        floor=floor,
        mode=mode,
        interest=interest,
        accuracy=accuracy,
    )
    chosen, gains = greedy(info, size)
    plan = plan_table(info, chosen, gains)
    m = info.matrix(chosen)
    interest_names = [info.names[k] for k in info.interest]
    rows = []
    cond = table["condition"].to_numpy()
    for label in conds:
        k = min(size, int(np.sum(cond == label)))
        pick, _ = greedy(info, k, allowed=cond == label)
        se = info.stderr(info.matrix(pick))
        row = {"condition": label, "in_plan": int(np.sum(cond[chosen] == label)), "alone_size": k}
        row.update({f"alone_se_{n}": se[n] for n in interest_names})
        rows.append(row)
    return {
        "plan": plan,
        "stderr": info.stderr(m),
        "conditions": pd.DataFrame(rows),
        "information": info,
        "criterion": info.criterion(m),
    }


def simulate_plan(
    plan: pd.DataFrame,
    brdf,
    *,
    noise: float = 0.01,
    seed: int = 0,
    accuracy: str = "default",
    variant: str | None = None,
    medium_model=None,
    options=None,
) -> dict:
    """Simulated measurement tables of a plan, one per condition {label: table} (no glow):
    value = apparent reflectance through the row's medium (medium_* columns; the medium
    family ``medium_model``, default the paper's, with ``options``; ``variant`` the Fresnel
    variant shortcut) times (1 + noise z), z ~ N(0, 1) from
    ``numpy.random.default_rng(seed)`` in plan order; sigma = noise * value. A plan written
    by ``veil design`` can so be simulated and fitted with :func:`veil.fit_joint`.
    """
    from ..models.base import VARIANT_OPTION

    mcls = default_class("medium") if medium_model is None else model_class(medium_model, "medium")
    options = dict(options or {})
    if variant is not None:
        options[VARIANT_OPTION] = variant
    need = [c for c in plan_columns(mcls) if c not in ("step", "gain")]
    missing = [c for c in need if c not in plan.columns]
    if missing:
        raise InputError(
            f"the plan lacks column(s) {', '.join(missing)} (written by veil design "
            f"for the {mcls.NAME} medium)"
        )
    b = as_brdf(brdf)
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(len(plan))
    out = {}
    cond = plan["condition"].astype(str).to_numpy()
    for label in dict.fromkeys(cond):
        sel = np.flatnonzero(cond == label)
        first = plan.iloc[sel[0]]
        med = mcls.from_params(
            {p.name: float(first[f"medium_{p.name}"]) for p in mcls.PARAMS}, options
        )
        sub = plan.iloc[sel]
        angles = [sub[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r")]
        val = SessionModel(b, med, angles, accuracy).values(b.to_vector(), med.to_vector())
        table = sub[list(ANGLE_COLUMNS)].reset_index(drop=True)
        table["value"] = val * (1.0 + noise * z[sel])
        table["sigma"] = noise * np.abs(val)
        out[label] = table
    return out


__all__ = [
    "conditions",
    "candidates",
    "condition_medium",
    "Information",
    "greedy",
    "rank",
    "plan_table",
    "design",
    "simulate_plan",
    "DEFAULT_PSI",
    "INTEREST",
    "PLAN_COLUMNS",
    "interest_names",
    "plan_columns",
]
