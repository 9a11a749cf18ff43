"""Starting values of the fits (docs/fitting.md): a coarse grid over the nonlinear
parameters (n, eta or g, eta_u) with the scale parameters solved exactly at each grid point
- the apparent value is linear in P_d, P_s (non-negative least squares) and quadratic in
T_d, T_t (a scan over T_t/T_d, or the roots of a cubic) - and the best distinct points."""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.optimize import nnls

from .result import FitError
from ..models import HenyeyGreenstein, TorranceSparrow

#: Grids of starting values over the nonlinear parameters, by model class and step.
START_GRIDS = {
    (TorranceSparrow, "reference"): {"n": tuple(np.round(np.geomspace(0.03, 5.0, 16), 4)),
                                     "eta": (1.2, 1.5, 2.0)},
    (TorranceSparrow, "target"): {"n": (0.08, 0.13, 0.2, 0.3, 0.45, 0.65, 0.9, 1.3, 2.0),
                                  "eta": (1.5,)},
    (HenyeyGreenstein, "medium"): {"g": (0.5, 0.7, 0.8, 0.88, 0.93, 0.96, 0.98, 0.99, 0.995),
                                   "eta": (1.33,)},
}


def weighted_nnls(columns: np.ndarray, rhs: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Coefficients >= 0 minimizing sum(w^2 (columns @ coef - rhs)^2) (columns equilibrated)."""
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


def brdf_scales(basis: np.ndarray, x: np.ndarray, cls, fixed: dict, y, w):
    """Best (P_d, P_s) >= 0 for the separable and lobe basis columns (M, 2); fixed ones kept."""
    idx = [cls.scale_index("separable"), cls.scale_index("lobe")]
    x = np.array(x, dtype=float)
    free = [k for k, i in enumerate(idx) if cls.param_names()[i] not in fixed]
    rhs = y - sum(basis[:, k] * x[idx[k]] for k in range(2) if k not in free)
    if free:
        coef = weighted_nnls(basis[:, free], rhs, w)
        for c, k in zip(coef, free):
            x[idx[k]] = c
    model = basis @ x[idx]
    cost = float(np.sum(((model - y) * w) ** 2))
    for k in free:
        x[idx[k]] = _floor(x[idx[k]], basis[:, k], y, w)
    return x, cost


def quadratic_scale(a, b, c, y, w) -> float:
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


def medium_scales(basis: np.ndarray, x: np.ndarray, cls, fixed: dict, y, w):
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
        x[i_d] = quadratic_scale(a0, t * a1, t * t * a2, y, w)
    elif free_t:
        d = x[i_d]
        x[i_t] = quadratic_scale(a2, d * a1, d * d * a0, y, w)
    model = basis @ np.array([x[i_d] ** 2, x[i_d] * x[i_t], x[i_t] ** 2])
    cost = float(np.sum(((model - y) * w) ** 2))
    if free_d and x[i_d] <= 0:
        x[i_d] = 1e-3 * x[i_t] if x[i_t] > 0 else 1e-12
    if free_t and x[i_t] <= 0:
        x[i_t] = 1e-3 * x[i_d] if x[i_d] > 0 else 1e-12
    return x, cost


def grid_points(cls, step: str, free, base: np.ndarray):
    """Grid over the free nonlinear parameters (``free``: indices into ``cls.PARAMS``) of
    START_GRIDS[cls, step], the others as in ``base``: list of (index tuple, vector)."""
    grid = START_GRIDS.get((cls, step), {})
    scales = set(cls.SCALES.values())
    names = cls.param_names()
    axes = []
    for i in free:
        name = names[i]
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


def pick_starts(scored, count: int):
    """Best ``count`` of the (cost, index tuple, vector) grid points, skipping neighbours (one
    grid step) of points already chosen."""
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


__all__ = ["START_GRIDS", "weighted_nnls", "brdf_scales", "quadratic_scale", "medium_scales",
           "grid_points", "pick_starts"]
