"""Starting values of the fits (docs/fitting.md), from the models' declarations: a coarse
grid over the nonlinear parameters (each model's ``START`` grid for its role in the fit)
with the scale parameters solved exactly at each grid point - the apparent value is linear
in the BRDF's scales (non-negative least squares) and quadratic in the medium's (a scan over
their ratio, or the roots of a cubic) - and the best distinct points.

:func:`step_starts` serves a fit with one unknown model (a step of the two-step method);
:func:`joint_starts` a joint fit, model by model: objects measured in clear water first,
then media seen through a known object, then the target with the media seen only through
it.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.optimize import nnls

from ..engine.apparent import check_finite, scales_text
from ..engine.integrator import BRDF_PARTS, column_scales, pairs
from ..errors import FitError
from .problem import ITERATION_ACCURACY, Block, Problem, SessionModel

#: Configurations per session used for the joint fit's starting grid (evenly spaced).
GRID_SUBSAMPLE = 64


# --------------------------------------------------------------------------------------
# the scales, exactly
# --------------------------------------------------------------------------------------
def weighted_nnls(columns: np.ndarray, rhs: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Coefficients >= 0 minimizing sum(w^2 (columns @ coef - rhs)^2) (columns and
    right-hand side equilibrated: finite inputs of any magnitude float64 holds)."""
    a = columns * w[:, None]
    b = rhs * w
    # each column's norm, and the right-hand side, scaled by their largest entry first: the
    # sum of squares of entries beyond 1e154 overflows float64
    big = np.max(np.abs(a), axis=0) if a.size else np.ones(a.shape[1])
    big[big == 0] = 1.0
    scale = np.linalg.norm(a / big, axis=0) * big
    scale[scale == 0] = 1.0
    size = float(np.max(np.abs(b))) if b.size else 0.0
    size = size if size > 0 else 1.0
    coef, _ = nnls(a / scale, b / size)
    return coef / scale * size


def _floor(value: float, column: np.ndarray, y: np.ndarray, w: np.ndarray) -> float:
    """A positive stand-in for a scale the linear solve put at 0 (log coordinates need > 0)."""
    if value > 0:
        return value
    a, b = column * w, y * w
    alone = float(a @ b) / float(a @ a) if float(a @ a) > 0 else 0.0
    return 1e-3 * alone if alone > 0 else 1e-12


def brdf_scales(basis: np.ndarray, x: np.ndarray, cls, fixed, y, w) -> tuple[np.ndarray, float]:
    """Best BRDF scales >= 0 for the part columns ``basis`` (M, parts) at vector ``x``; the
    scales named in ``fixed`` (and parts without a scale, weight 1) are kept. The cost is
    inf (``x`` returned as it is) where the model or its misfit overflows float64."""
    x = np.array(x, dtype=float)
    idx = [cls.scale_index(part) for part in BRDF_PARTS]
    names = cls.param_names()
    free = [k for k, i in enumerate(idx) if i is not None and names[i] not in fixed]
    weight = [1.0 if i is None else x[i] for i in idx]
    with np.errstate(over="ignore", invalid="ignore"):
        rhs = y - sum(basis[:, k] * weight[k] for k in range(len(idx)) if k not in free)
        if not (np.all(np.isfinite(rhs * w)) and np.all(np.isfinite(basis[:, free] * w[:, None]))):
            return x, math.inf
        if free:
            coef = weighted_nnls(basis[:, free], rhs, w)
            for c, k in zip(coef, free):
                x[idx[k]] = weight[k] = c
        model = basis @ np.array(weight)
        cost = float(np.sum(((model - y) * w) ** 2))
        for k in free:
            x[idx[k]] = _floor(x[idx[k]], basis[:, k], y, w)
    return x, cost if math.isfinite(cost) else math.inf


def quadratic_scale(a, b, c, y, w) -> float:
    """T >= 0 minimizing sum(w^2 (a T^2 + b T + c - y)^2): roots of the cubic derivative
    (NaN when the cubic's coefficients overflow float64)."""
    a, b, r = a * w, b * w, (c - y) * w
    coeffs = [2 * a @ a, 3 * a @ b, b @ b + 2 * a @ r, b @ r]
    if not all(math.isfinite(co) for co in coeffs):
        return math.nan
    cands = [0.0]
    if any(abs(co) > 0 for co in coeffs):
        lead = next(k for k, co in enumerate(coeffs) if co != 0)
        if lead < 3:
            roots = np.roots(coeffs[lead:])
            cands += [
                float(z.real) for z in roots if abs(z.imag) <= 1e-9 * (1 + abs(z)) and z.real > 0
            ]
    costs = [float(np.sum((a * t * t + b * t + r) ** 2)) for t in cands]
    return cands[int(np.argmin(costs))]


_RATIOS = np.concatenate([[0.0], np.logspace(-6, 8, 561)])


def medium_scales(basis: np.ndarray, x: np.ndarray, cls, fixed, y, w) -> tuple[np.ndarray, float]:
    """Best medium scales >= 0 for the row columns ``basis`` (M, rows) at vector ``x``: rows
    are products s_a s_b of the components' scales (veil.engine.integrator.pairs; 1 for a
    component without one) times the gain. Two free component scales (the paper's T_d,
    T_t) by a scan over their ratio, one by the roots of a cubic, the gain linearly; the
    scales named in ``fixed`` are kept. The cost is inf (``x`` returned as it is) where the
    model or its misfit overflows float64."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        if np.all(np.isfinite(basis * w[:, None])):
            out, cost = _medium_scales(basis, x, cls, fixed, y, w)
            if math.isfinite(cost) and np.all(np.isfinite(out)):
                return out, cost
    return np.array(x, dtype=float), math.inf


def _medium_scales(basis: np.ndarray, x: np.ndarray, cls, fixed, y, w) -> tuple[np.ndarray, float]:
    """:func:`medium_scales`, whatever the overflow."""
    names = cls.param_names()
    x = np.array(x, dtype=float)
    prs = pairs(cls)
    idx = {c: cls.scale_index(c) for c in cls.COMPONENTS}
    s = {c: (1.0 if i is None else x[i]) for c, i in idx.items()}
    free = [c for c, i in idx.items() if i is not None and names[i] not in fixed]
    gi = None if cls.GAIN is None else names.index(cls.GAIN)
    gain = 1.0 if gi is None else x[gi]
    gain_free = gi is not None and names[gi] not in fixed
    if len(free) > 2:
        raise FitError(
            f"{cls.NAME}: starting values for more than two scaled components are not implemented"
        )
    if len(free) == 2:
        # value = s1^2 (c11 + r c12 + r^2 c22) with r = s2 / s1: exact in s1^2 per ratio
        c1, c2 = free
        col = {pr: basis[:, k] * gain for k, pr in enumerate(prs)}
        a0, a1, a2 = col[(c1, c1)], col[(c1, c2)], col[(c2, c2)]
        rest = (
            sum(col[pr] * s[pr[0]] * s[pr[1]] for pr in prs if c1 not in pr and c2 not in pr)
            if len(prs) > 3
            else 0.0
        )
        target = y - rest
        cols = (
            np.concatenate(
                [
                    (
                        a0[None, :]
                        + _RATIOS[:, None] * a1[None, :]
                        + _RATIOS[:, None] ** 2 * a2[None, :]
                    ),
                    a2[None, :],
                ]
            )
            * w
        )
        yw = target * w
        num, den = cols @ yw, np.einsum("km,km->k", cols, cols)
        sq = np.where(den > 0, np.maximum(num, 0.0) / np.where(den > 0, den, 1.0), 0.0)
        costs = np.sum((sq[:, None] * cols - yw) ** 2, axis=1)
        k = int(np.argmin(costs))
        if k == len(_RATIOS):
            s[c1], s[c2] = 0.0, math.sqrt(sq[k])
        else:
            s[c1] = math.sqrt(sq[k])
            s[c2] = _RATIOS[k] * s[c1]
    elif len(free) == 1:
        (c,) = free
        coef = [np.zeros_like(y), np.zeros_like(y), np.zeros_like(y)]
        for k, (a, b) in enumerate(prs):
            e = (a == c) + (b == c)
            other = (1.0 if a == c else s[a]) * (1.0 if b == c else s[b])
            coef[e] = coef[e] + basis[:, k] * gain * other
        s[c] = quadratic_scale(coef[2], coef[1], coef[0], y, w)
    unit = basis @ np.array([s[a] * s[b] for a, b in prs])
    if gain_free:
        a, b = unit * w, y * w
        gain = max(float(a @ b) / float(a @ a), 0.0) if float(a @ a) > 0 else 0.0
    model = unit * gain
    cost = float(np.sum(((model - y) * w) ** 2))
    for c in free:
        if s[c] <= 0:
            others = [s[o] for o in free if o != c and s[o] > 0]
            s[c] = 1e-3 * others[0] if others else 1e-12
        x[idx[c]] = s[c]
    if gain_free:
        x[gi] = gain if gain > 0 else 1e-12
    return x, cost


# --------------------------------------------------------------------------------------
# grids
# --------------------------------------------------------------------------------------
def grid_points(cls, role: str, free, base: np.ndarray) -> list[tuple[tuple[int, ...], np.ndarray]]:
    """Grid over the free nonlinear parameters (``free``: indices into ``cls.PARAMS``) of
    the model's starting grid for ``role``, the others as in ``base``: a list of (index
    tuple, vector). A free nonlinear parameter without a grid starts at ``base``."""
    grid = cls.start_grid(role)
    scales = set(cls.scale_names())
    names = cls.param_names()
    axes = []
    for i in free:
        name = names[i]
        if name in scales or name not in grid:
            continue
        p = cls.PARAMS[i]
        axes.append((i, [v for v in grid[name] if p.contains(v)]))
    points = []
    for combo in itertools.product(*[range(len(v)) for _, v in axes]):
        x = np.array(base, dtype=float)
        for (i, values), k in zip(axes, combo):
            x[i] = values[k]
        points.append((combo, x))
    return points


def pick_starts(scored, count: int) -> list[tuple[float, tuple[int, ...], np.ndarray]]:
    """Best ``count`` of the (cost, index tuple, vector) grid points, skipping neighbours (one
    grid step) of points already chosen."""
    chosen: list[tuple] = []
    for cost, combo, x in sorted(scored, key=lambda t: t[0]):
        if not np.isfinite(cost):
            continue
        if any(max((abs(a - b) for a, b in zip(combo, c)), default=0) <= 1 for _, c, _ in chosen):
            continue
        chosen.append((cost, combo, x))
        if len(chosen) == count:
            break
    return chosen


def _rows(block: Block, vm) -> np.ndarray:
    return block.model(ITERATION_ACCURACY).row_weights(vm)


def _fixed_names(problem: Problem, block: Block, kind: str) -> set:
    """Model parameter names of ``block``'s ``kind`` model that the problem holds fixed."""
    idx = block.ib if kind == "brdf" else block.im
    model = block.brdf if kind == "brdf" else block.medium
    assert model is not None and idx is not None  # a block of a session with a medium
    return {type(model).PARAMS[j].name for j, k in enumerate(idx) if not problem.free[k]}


def step_starts(
    problem: Problem, kind: str, role: str, count: int, progress=None, explain: bool = True
) -> tuple[list[np.ndarray], int]:
    """Starting vectors (natural, best first) of a one-session problem whose ``kind`` model
    is free: the model's grid for ``role``, scales exact at each point. Returns (starts,
    number of grid points). An InputError when the given model's scales make the model
    overflow float64 (:func:`_step_basis`); when no point has a finite cost and
    ``explain`` (no other start ran), a FitError naming the fixed or given scales that
    make it overflow (:func:`_blame_fixed`, :func:`_blame_given`) if any do."""
    block = problem.blocks[0]
    model = block.brdf if kind == "brdf" else block.medium
    cls = type(model)
    idx = block.ib if kind == "brdf" else block.im
    free = [j for j, k in enumerate(idx) if problem.free[k]]
    fixed = _fixed_names(problem, block, kind)
    points = grid_points(cls, role, free, problem.values[idx])
    engine = block.model(ITERATION_ACCURACY)
    y, w = block.data.y, block.data.w
    solve = medium_scales if kind == "medium" else brdf_scales
    scored, bases = [], []
    for k, (combo, v) in enumerate(points):
        x = problem.values.copy()
        x[idx] = v
        vb, vm = problem.split(block, x)
        basis = _step_basis(block, kind, engine.terms(vb, vm), vb, vm)
        bases.append((basis, v))
        v, cost = solve(basis, v, cls, fixed, y, w)
        x[idx] = v
        scored.append((cost, combo, x))
        if progress:
            progress("starting grid", k + 1, len(points))
    chosen = pick_starts(scored, count)
    if not chosen and explain:
        _blame_fixed(cls, solve, bases, fixed, y, w)
        vb, vm = problem.split(block, problem.values)
        given, gv = (block.brdf, vb) if kind == "medium" else (block.medium, vm)
        _blame_given(given, gv, cls, solve, bases, fixed, y, w)
    return [x for _, _, x in chosen], len(points)


def _step_basis(block: Block, kind: str, terms: np.ndarray, vb, vm) -> np.ndarray:
    """The columns whose scales the grid of a step fitting the ``kind`` model solves for:
    the terms times the given model's scales (the medium's rows, or the BRDF's columns for
    a medium). Where they overflow float64 at a grid point: an InputError naming the given
    model's scales, the values' linear factors (veil.engine.apparent.check_finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        if kind == "medium":
            basis = np.einsum("mkb,b->mk", terms, column_scales_of(block, vb))
        else:
            basis = np.einsum("mkb,k->mb", terms, _rows(block, vm))
    given, v = (block.brdf, vb) if kind == "medium" else (block.medium, vm)
    what = "the apparent reflectance" + (
        "" if given is None else f" with the given {given.NAME} {given.KIND}"
    )
    # the engine's own terms not finite: a bug (FloatingPointError), else the given scales
    return check_finite(basis, what, [given], [v], terms=terms)


def _blame_fixed(cls, solve, bases: list, fixed: set, y, w) -> None:
    """When no grid point of a step has a finite cost: a FitError naming the fitted model's
    fixed scales (and gain) whose values make its values or their misfit overflow float64,
    those that, freed, give a finite cost somewhere on the grid (``bases``: each point's
    (basis, vector); ``solve`` the scales' solve). Nothing when freeing them does not help:
    then something else is the cause, and the solver says there is no starting point."""
    gain = getattr(cls, "GAIN", None)
    scalable = [n for n in cls.scale_names() + ((gain,) if gain else ()) if n in fixed]

    def finite_without(names) -> bool:
        rest = set(fixed) - set(names)
        return any(math.isfinite(solve(basis, v, cls, rest, y, w)[1]) for basis, v in bases)

    blamed = [n for n in scalable if finite_without([n])]
    if not blamed and len(scalable) > 1 and finite_without(scalable):
        blamed = scalable
    if not blamed:
        return
    v = bases[0][1]
    one = len(blamed) == 1
    them = "it" if one else "them"
    values = " and ".join(f"{n} fixed at {v[cls.index(n)]:.4g}" for n in blamed)
    raise FitError(
        f"no starting point: with {values} the {cls.NAME} model's values, or their "
        f"weighted misfit to the data (at most {float(np.max(np.abs(y))):.4g}), overflow "
        f"float64 at every point of the starting grid, and with {' and '.join(blamed)} free "
        f"they do not; {'it scales' if one else 'they scale'} the model (relative units): "
        f"fix {them} at a smaller value ({', '.join(f'--fix {n}=VALUE' for n in blamed)}, "
        f"fixed={{...}} in Python) or leave {them} free"
    )


def _blame_given(given, v, cls, solve, bases: list, fixed: set, y, w) -> None:
    """When no grid point of a step has a finite cost and the fitted model's fixed values
    are not the cause: a FitError naming the ``given`` model's scales (at its vector
    ``v``) when the grid with the basis scaled to at most 1 has finite costs - the given
    model's magnitude makes the solves overflow float64. Nothing otherwise."""
    if given is None or not given.SCALES:
        return
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        down = [(basis / max(float(np.max(np.abs(basis))), 1.0), x) for basis, x in bases]
        if not any(math.isfinite(solve(basis, x, cls, fixed, y, w)[1]) for basis, x in down):
            return
    named = scales_text(given, v)
    raise FitError(
        f"no starting point: at every point of the starting grid the model's misfit to the "
        f"data overflows float64 (beyond 1.8e308) with the given {given.NAME} {given.KIND}'s "
        f"{named}: these coefficients scale the model (relative units) and smaller ones "
        f"would not overflow; give them smaller values"
    )


def column_scales_of(block: Block, vb) -> np.ndarray:
    """The BRDF part weights of ``block``'s BRDF at ``vb``."""
    return column_scales(type(block.brdf), vb)


# --------------------------------------------------------------------------------------
# the joint fit
# --------------------------------------------------------------------------------------
def _subsample(block: Block) -> np.ndarray:
    m = block.size
    if m <= GRID_SUBSAMPLE:
        return np.arange(m)
    return np.unique(np.round(np.linspace(0, m - 1, GRID_SUBSAMPLE)).astype(int))


class _GridEngines:
    """Engines at the "fast" quadrature on each block's subsampled configurations, and their
    term matrices by the models' vectors with the scales at 1 (the terms do not depend on
    the scales)."""

    def __init__(self):
        self.engines: dict = {}
        self.terms_cache: dict = {}

    def __call__(self, block: Block):
        key = id(block)
        if key not in self.engines:
            idx = _subsample(block)
            angles = tuple(a[idx] for a in block.data.angles)
            self.engines[key] = (
                SessionModel(block.brdf, block.medium, angles, ITERATION_ACCURACY),
                idx,
            )
        return self.engines[key]

    def terms(self, block: Block, vb, vm) -> np.ndarray:
        vb1, vm1 = _unit(block.brdf, vb), _unit(block.medium, vm)
        key = (id(block), vb1.tobytes(), vm1.tobytes())
        if key not in self.terms_cache:
            self.terms_cache[key] = self(block)[0].terms(vb1, vm1)
        return self.terms_cache[key]


def _unit(model, v) -> np.ndarray:
    """``v`` with the model's scales (and gain) at 1: the term matrices do not depend on
    them."""
    v = np.array(v, dtype=float)
    cls = type(model)
    for name in cls.scale_names() + (
        (getattr(cls, "GAIN", None),) if getattr(cls, "GAIN", None) else ()
    ):
        v[cls.index(name)] = 1.0
    return v


def _target_grid(problem: Problem, x, known_media: set, engines, count: int, progress) -> list:
    """The target's starting grid through the media (scales alternating), best first."""
    fixed_mask = ~problem.free
    tblocks = [b for b in problem.blocks if b.session.object == "target" and not b.session.clear]
    cls = type(tblocks[0].brdf)
    ib = tblocks[0].ib
    free = [j for j, k in enumerate(ib) if not fixed_mask[k]]
    points = grid_points(cls, "target", free, x[ib])
    scored = []
    for k, (combo, vb) in enumerate(points):
        xt = x.copy()
        _set_block(xt, ib, vb, fixed_mask)
        cost, xt = _target_point(problem, xt, tblocks, known_media, engines)
        scored.append((cost, combo, xt))
        if progress:
            progress("starting grid", k + 1, len(points))
    chosen = pick_starts(scored, count)
    return [xt for _, _, xt in chosen] or [x]


def joint_starts(
    problem: Problem, layout: dict, start: dict | None, count: int, direct_fit, progress=None
) -> list[np.ndarray]:
    """Starting vectors (natural, best first) of a joint fit (module docstring).

    ``layout`` maps objects and media to their parameter names (veil.fitting.joint);
    ``start`` optional models {object or medium label: model}; ``direct_fit(block, fixed)``
    returns the fitted BRDF vector of an object from its clear-water block."""
    x = problem.values.copy()
    fixed_mask = ~problem.free
    idx_of = {n: k for k, n in enumerate(problem.names)}
    objects, media = layout["objects"], layout["media"]
    blocks = problem.blocks

    def set_(name, value):
        k = idx_of[name]
        if not fixed_mask[k]:
            x[k] = value

    known_media: set[str] = set()
    known_objects: set[str] = set()
    if layout.get("reference_given"):
        known_objects.add("reference")
    for key, model in dict(start or {}).items():
        kind = "brdf" if key in objects else "medium" if key in media else None
        if kind is None:
            raise FitError(
                f"start: {key!r} is neither an object ({', '.join(objects)}) nor a "
                f"medium ({', '.join(media)}) of the joint fit"
            )
        block = next(
            b
            for b in blocks
            if (b.session.object == key if kind == "brdf" else b.session.medium == key)
        )
        family = type(block.brdf if kind == "brdf" else block.medium)
        if type(model) is not family:
            raise FitError(
                f"start[{key!r}] is a {model.NAME} model; the joint fit's "
                f"{'objects' if kind == 'brdf' else 'media'} are {family.NAME}"
            )
        names = (objects if kind == "brdf" else media)[key]
        for p in family.PARAMS:
            set_(names[p.key], getattr(model, p.name))
        (known_objects if kind == "brdf" else known_media).add(key)
    # objects with a clear session: f_r directly (step 0)
    for obj, names in objects.items():
        if obj in known_objects:
            continue
        clear = [b for b in blocks if b.session.object == obj and b.session.clear]
        if clear:
            fixed = {
                p: problem.values[idx_of[n]] for p, n in names.items() if fixed_mask[idx_of[n]]
            }
            vb = direct_fit(clear[0], fixed)
            for j, k in enumerate(clear[0].ib):
                if not fixed_mask[k]:
                    x[k] = vb[j]
            known_objects.add(obj)
    if progress:
        progress("starting values: objects in clear water", 1, 1)
    engines = _GridEngines()
    # media seen through a known object: the medium's grid, scales exact
    for label in media:
        if label in known_media:
            continue
        through = [
            b for b in blocks if b.session.medium == label and b.session.object in known_objects
        ]
        if through:
            cost, vm = _best_medium(problem, through[0], x, engines)
            _set_block(x, through[0].im, vm, fixed_mask)
            known_media.add(label)
    if progress:
        progress("starting values: media", 1, 1)
    # the target (and media seen only through it): its grid, alternating scales
    if "target" in known_objects:
        return [x]
    return _target_grid(problem, x, known_media, engines, count, progress)


def _set_block(x, idx, v, fixed_mask) -> None:
    for j, k in enumerate(idx):
        if not fixed_mask[k]:
            x[k] = v[j]


def _best_medium(problem: Problem, block: Block, x, engines):
    """(cost, medium vector) of ``block``'s medium over its grid with exact scales, the BRDF
    at ``x``."""
    _, idx = engines(block)
    cls = type(block.medium)
    assert block.im is not None  # a block of a session with a medium
    free = [j for j, k in enumerate(block.im) if problem.free[k]]
    fixed = _fixed_names(problem, block, "medium")
    vb = x[block.ib]
    best = None
    for _combo, vm in grid_points(cls, "medium", free, x[block.im]):
        terms = engines.terms(block, vb, vm)
        basis = np.einsum("mkb,b->mk", terms, column_scales_of(block, vb))
        vm, cost = medium_scales(basis, vm, cls, fixed, block.data.y[idx], block.data.w[idx])
        if best is None or cost < best[0]:
            best = (cost, vm)
    return best


def _target_point(problem: Problem, x, tblocks, known_media, engines):
    """Exact scales of the target and of the unknown media at one grid point of the target:
    alternately the target's scales pooled over its sessions given the media, and each
    unknown medium over its grid given the target. Returns (cost, x)."""
    fixed_mask = ~problem.free
    cls = type(tblocks[0].brdf)
    fixed_b = _fixed_names(problem, tblocks[0], "brdf")
    # unknown media start from the middle of their grid
    for b in tblocks:
        if b.session.medium not in known_media:
            points = grid_points(
                type(b.medium),
                "medium",
                [j for j, k in enumerate(b.im) if problem.free[k]],
                x[b.im],
            )
            _set_block(x, b.im, points[len(points) // 2][1], fixed_mask)
    cost = np.inf
    for _ in range(3):
        cols, ys, ws = [], [], []
        for b in tblocks:
            _, idx = engines(b)
            terms = engines.terms(b, x[b.ib], x[b.im])
            cols.append(np.einsum("mkb,k->mb", terms, _rows(b, x[b.im])))
            ys.append(b.data.y[idx])
            ws.append(b.data.w[idx])
        basis, y, w = np.concatenate(cols), np.concatenate(ys), np.concatenate(ws)
        vb, _ = brdf_scales(basis, x[tblocks[0].ib], cls, fixed_b, y, w)
        _set_block(x, tblocks[0].ib, vb, fixed_mask)
        cost = 0.0
        for b in tblocks:
            _, idx = engines(b)
            if b.session.medium in known_media:
                terms = engines.terms(b, x[b.ib], x[b.im])
                model = np.einsum(
                    "mkb,k,b->m", terms, _rows(b, x[b.im]), column_scales_of(b, x[b.ib])
                )
                cost += float(np.sum(((model - b.data.y[idx]) * b.data.w[idx]) ** 2))
                continue
            c, vm = _best_medium(problem, b, x, engines)
            _set_block(x, b.im, vm, fixed_mask)
            cost += c
    return cost, x


__all__ = [
    "GRID_SUBSAMPLE",
    "weighted_nnls",
    "brdf_scales",
    "quadratic_scale",
    "medium_scales",
    "grid_points",
    "pick_starts",
    "step_starts",
    "joint_starts",
]
