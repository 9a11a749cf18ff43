"""Per-pixel step 2 (docs/maps.md): the target's BRDF at every pixel of a photo stack,
through a fixed medium, at fixed configurations.

For a fixed medium and fixed configurations the apparent value (docs/model.md eq. 1) is linear
in the BRDF's scale parameters (``SCALES``): with the engine's term matrices
(:meth:`veil.engine.evaluator.ApparentModel.terms`, rows combined with the medium's row
weights, :func:`veil.engine.integrator.row_scales`) it is

    f(theta, s) = sum_k s_k B_k(theta) + C(theta)

with B_k the columns of the parts whose scale is free and C the parts whose weight is known
(a fixed scale, or a part without a scale). :class:`MapTables` tabulates B and C over a
regular grid of the free nonlinear parameters theta (in their fit coordinates: logarithms
for ``log_scale`` parameters) once per acquisition, and keeps the tensor-product cubic
B-spline that interpolates them (not-a-knot ends, C2, exact derivatives). :func:`solve_pixels`
then fits every pixel against the tables, vectorized in JAX:

1. at every grid node the scales by exact non-negative least squares (closed form for up to
   two scales: every active set is tried);
2. the best node;
3. Levenberg-Marquardt in (scales, theta) on the B-spline, a fixed number of iterations,
   then an undamped Gauss-Newton step whose size, in standard errors, decides convergence.

Every pixel gets its parameters, standard errors, reduced chi-square, number of points and
a status (:data:`STATUS`); a pixel is reported converged only when the final step is below
:data:`STEP_TOL` standard errors, no scale is at zero, the Jacobian has full rank and no
nonlinear parameter sits at the edge of the table.
"""

from __future__ import annotations

import hashlib
import itertools
import math
import threading
from dataclasses import dataclass, field

import numpy as np

from ..engine.integrator import BRDF_PARTS, row_scales
from ..errors import FitError

#: Pixel status codes (the ``status`` map).
STATUS = {
    0: "converged",
    1: "masked (outside the mask, or no photo usable at this pixel)",
    2: "too few points (fewer usable photos than free parameters + 1: saturated, clipped "
       "or dark)",
    3: "not determined (a scale at zero, a rank-deficient Jacobian, or no positive value)",
    4: "at the edge of the table (a nonlinear parameter at the end of its tabulated range)",
    5: "did not converge (last Gauss-Newton step above the tolerance)",
}
CONVERGED, MASKED, FEW_POINTS, UNDETERMINED, EDGE, NOT_CONVERGED = range(6)
#: Convergence: the last undamped step, in standard errors, below this in every parameter
#: (the full fit's own tolerance leaves it within about 1 % of a standard error).
STEP_TOL = 1e-2
#: Levenberg-Marquardt iterations from the best node, at most: a pixel stops (its state
#: frozen) once its Gauss-Newton step over the parameters not held at a bound is below
#: :data:`LM_TOL` standard errors, and a batch once all its pixels have stopped.
ITERATIONS = 20
#: Iterations in a batch's first call: the pixels still running then (a few per cent) are
#: gathered from all batches of the call into full batches of their own for the rest, so
#: that a few slow pixels do not hold up the whole batch.
FIRST_ITERATIONS = 4
#: Stopping tolerance of the iterations, in standard errors (half of :data:`STEP_TOL`, so
#: that a stopped pixel passes the final convergence test).
LM_TOL = 5e-3
#: Grid nodes per nonlinear axis by the number of axes (``grid=`` overrides).
NODES = {1: 48, 2: 24, 3: 12}
#: Pixels per solver call: every call has this shape, so results do not depend on how
#: pixels are grouped into tiles or workers (bit for bit).
BATCH = 512
#: Batches dispatched to a device and not yet collected, at most.
IN_FLIGHT = 2
#: Equilibrated condition number above which the Jacobian counts as rank-deficient.
SINGULAR = 1e-10
#: Near-field tables: pixels whose node values the node stage holds at once (a divisor of
#: BATCH; their node values are NEAR_GROUP x nodes x configurations x columns).
NEAR_GROUP = 32


# --------------------------------------------------------------------------------------
# the grid
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Axis:
    """One tabulated nonlinear parameter: ``count`` nodes uniform in its fit coordinate
    (log for ``log_scale``) from ``lo`` to ``hi`` (physical values)."""

    name: str
    index: int
    log: bool
    lo: float
    hi: float
    count: int

    def coord(self, value):
        return np.log(value) if self.log else np.asarray(value, dtype=float)

    @property
    def step(self) -> float:
        return float((self.coord(self.hi) - self.coord(self.lo)) / (self.count - 1))

    def nodes(self) -> np.ndarray:
        c = np.linspace(float(self.coord(self.lo)), float(self.coord(self.hi)), self.count)
        return np.exp(c) if self.log else c

    def physical(self, u):
        """Physical value at grid coordinate ``u`` (0 .. count - 1); numpy or JAX."""
        c = float(self.coord(self.lo)) + u * self.step
        if self.log:
            return np.exp(c) if isinstance(c, (float, np.ndarray)) else _jnp().exp(c)
        return c

    def describe(self) -> str:
        kind = "log-spaced" if self.log else "evenly spaced"
        return f"{self.name} {self.lo:.6g}..{self.hi:.6g} ({self.count} nodes, {kind})"


def _jnp():
    from .._jax import jnp
    return jnp


def parse_grid(items, cls) -> dict:
    """``NAME=LO:HI[:COUNT]`` strings -> {name: (lo, hi, count or None)}."""
    out = {}
    for item in items or ():
        name, sep, text = str(item).partition("=")
        name = name.strip()
        parts = text.split(":")
        if not sep or len(parts) not in (2, 3):
            raise FitError(f"grid {item!r}: expected NAME=LO:HI or NAME=LO:HI:COUNT")
        if name not in cls.param_names():
            raise FitError(f"grid {item!r}: {cls.NAME} has no parameter {name!r}; its "
                           f"parameters are {', '.join(cls.param_names())}")
        try:
            lo, hi = float(parts[0]), float(parts[1])
            count = int(parts[2]) if len(parts) == 3 else None
        except ValueError:
            raise FitError(f"grid {item!r}: LO and HI must be numbers, COUNT an integer"
                           ) from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise FitError(f"grid {item!r}: expected finite LO < HI")
        if count is not None and not 4 <= count <= 400:
            raise FitError(f"grid {item!r}: COUNT must be between 4 and 400")
        p = cls.param(name)
        for v in (lo, hi):
            if not p.contains(v):
                raise FitError(f"grid {item!r}: {v:g} is outside {name}'s bounds "
                               f"{p.interval()}")
        out[name] = (lo, hi, count)
    return out


def make_axes(cls, free_nonlinear, grid=None) -> list[Axis]:
    """The table's axes over the free nonlinear parameters (indices into ``cls.PARAMS``):
    the range of the model's starting grids (target and reference roles together) unless
    ``grid`` ({name: (lo, hi, count)}) says otherwise."""
    grid = dict(grid or {})
    unknown = [n for n in grid if cls.param_names().index(n) not in free_nonlinear]
    if unknown:
        raise FitError(f"grid given for {', '.join(unknown)}, which is not a free nonlinear "
                       f"parameter of this fit (a scale, fixed, or held)")
    d = len(free_nonlinear)
    if d > 3:
        raise FitError(f"{d} free nonlinear parameters; per-pixel tables handle at most 3: "
                       f"fix some with --fix NAME=VALUE")
    axes = []
    for i in free_nonlinear:
        p = cls.PARAMS[i]
        if p.name in grid:
            lo, hi, count = grid[p.name]
        else:
            values = set()
            for role in ("target", "reference"):
                values |= {float(v) for v in cls.start_grid(role).get(p.name, ())
                           if p.contains(float(v))}
            if len(values) < 2:
                raise FitError(f"{cls.NAME}.{p.name}: the model's starting grids give no "
                               f"range to tabulate; fix it (--fix {p.name}=VALUE) or give "
                               f"its range (--grid {p.name}=LO:HI)")
            lo, hi, count = min(values), max(values), None
        if p.log_scale and lo <= 0:
            raise FitError(f"grid of {p.name}: a log-scaled parameter needs LO > 0")
        axes.append(Axis(p.name, i, bool(p.log_scale), float(lo), float(hi),
                         int(count or NODES[d])))
    return axes


# --------------------------------------------------------------------------------------
# cubic B-spline interpolation with not-a-knot ends
# --------------------------------------------------------------------------------------
def _bspline_inverse(k: int) -> np.ndarray:
    """(k + 2, k) matrix taking node values to the coefficients of the uniform cubic
    B-spline that interpolates them with not-a-knot ends (third derivative continuous at
    the second and the second-last node). Coefficient j is the B-spline centred at node
    j - 1."""
    a = np.zeros((k + 2, k + 2))
    for i in range(k):  # value at node i: (c_i + 4 c_{i+1} + c_{i+2}) / 6
        a[i, i:i + 3] = (1 / 6, 4 / 6, 1 / 6)
    if k >= 4:  # jump of the third derivative at nodes 1 and k - 2: a fourth difference
        a[k, 0:5] = (1, -4, 6, -4, 1)
        a[k + 1, k - 3:k + 2] = (1, -4, 6, -4, 1)
    else:  # natural ends
        a[k, 0:3] = (1, -2, 1)
        a[k + 1, k - 1:k + 2] = (1, -2, 1)
    rhs = np.zeros((k + 2, k))
    rhs[:k, :] = np.eye(k)
    return np.linalg.solve(a, rhs)


def _weights(t, jnp):
    """Cubic B-spline weights and their derivatives at offset t in [0, 1] of a cell."""
    t2, t3 = t * t, t * t * t
    w = jnp.stack([(1 - t) ** 3 / 6, (3 * t3 - 6 * t2 + 4) / 6,
                   (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6])
    dw = jnp.stack([-0.5 * (1 - t) ** 2, (3 * t2 - 4 * t) / 2,
                    (-3 * t2 + 2 * t + 1) / 2, t2 / 2])
    return w, dw


# --------------------------------------------------------------------------------------
# the tables
# --------------------------------------------------------------------------------------
@dataclass
class MapTables:
    """Basis columns of the apparent value at a grid of the nonlinear parameters.

    ``values``: (K_1, ..., K_d, M, q + 1) node values: the q free scales' columns, then the
    known part C. ``coef``: the same with each axis replaced by its K + 2 B-spline
    coefficients. ``base``: the BRDF vector (fixed and held values; the free ones are
    overwritten per pixel). ``free_scales``: indices of the free scale parameters, in column
    order. ``axes``: the nonlinear axes.
    """

    model: str
    options: dict
    names: tuple
    base: np.ndarray
    free_scales: tuple
    axes: list
    values: np.ndarray
    coef: np.ndarray
    fixed: dict
    medium: dict
    accuracy: str
    angles: tuple = field(repr=False, default=())
    #: near-field tables (docs/maps-geometry.md "Geometry"): the field grid (a
    #: :class:`veil.fitting.maps_near.FieldGrid`), None for distant light and camera. Then
    #: ``values`` and ``coef`` have two leading axes more (the grid's x and y nodes);
    #: ``field_error`` is the largest interpolation error measured against exact per-pixel
    #: columns (relative to each column's maximum).
    near: object = None
    field_error: float = float("nan")

    @property
    def n_free(self) -> int:
        return len(self.free_scales) + len(self.axes)

    @property
    def n_configs(self) -> int:
        return self.values.shape[-2]

    @property
    def solver_arrays(self) -> tuple:
        """(node values, spline coefficients) the solver runs on."""
        return self.values, self.coef

    def field_coords(self, x, y) -> np.ndarray:
        """(N, 2) field-grid coordinates of pixels (x, y) of the full photo (near field)."""
        fx, fy = self.near.coords(np.ravel(x), np.ravel(y))
        return np.stack([fx, fy], axis=1)

    @property
    def free_names(self) -> tuple:
        idx = list(self.free_scales) + [a.index for a in self.axes]
        return tuple(self.names[i] for i in idx)

    def fingerprint(self) -> str:
        """Hash of everything the tables depend on (and of the tables themselves)."""
        h = hashlib.sha256()
        h.update(repr((self.model, sorted(self.options.items()), self.names,
                       self.base.tolist(), self.free_scales, [a.__dict__ for a in self.axes],
                       sorted(self.fixed.items()), self.medium, self.accuracy)).encode())
        for a in self.angles:
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        if self.near is not None:  # (distant tables hash as they always did)
            h.update(repr(self.near.as_dict()).encode())
        h.update(np.ascontiguousarray(self.values).tobytes())
        return h.hexdigest()

    def describe(self) -> str:
        grid = "; ".join(a.describe() for a in self.axes) or "no nonlinear parameter"
        nodes = int(np.prod([a.count for a in self.axes])) if self.axes else 1
        text = (f"{self.model}: free {', '.join(self.free_names)}; table {grid}; {nodes} "
                f"node(s) x {self.n_configs} configurations ({self.accuracy} quadrature)")
        if self.near is not None:
            text += (f"; {self.near.describe()}, interpolation error "
                     f"{self.field_error:.2g} of a column's maximum")
        return text

    def basis(self, node_values: dict, pixel=None) -> np.ndarray:
        """(M, q + 1) columns at physical values of the nonlinear parameters, by the
        spline (numpy; for checks); near-field tables at ``pixel`` (x, y) of the photo."""
        jnp = _jnp()
        u = np.array([(a.coord(node_values[a.name]) - a.coord(a.lo)) / a.step
                      for a in self.axes])
        if self.near is None:
            b, _ = _interp(jnp.asarray(self.coef), jnp.asarray(u), len(self.axes))
        else:
            fu = self.field_coords(*pixel)[0]
            b, _ = _interp_near(jnp.asarray(self.coef), jnp.asarray(fu), jnp.asarray(u),
                                len(self.axes))
        return np.asarray(b)


def build_tables(brdf_cls, medium, angles, *, fixed=None, options=None, free=None,
                 grid=None, accuracy: str = "default", progress=None, near=None,
                 roi=None) -> MapTables:
    """The tables of a per-pixel target fit: ``brdf_cls`` through ``medium`` (a medium
    model) at ``angles`` (theta_i, phi_i, theta_r, phi_r arrays, degrees). ``fixed``,
    ``free`` (held parameters to fit) and ``options`` as :func:`veil.fit_target`;
    ``grid`` {name: (lo, hi, count)} overrides a nonlinear axis; ``progress(done, total)``
    after each node. ``near`` (a :class:`veil.fitting.maps_near.NearGeometry`) with
    ``roi`` (x, y, w, h of the photo): near-field tables over a grid of plate points
    (:func:`veil.fitting.maps_near.field_grid`, docs/maps-geometry.md "Geometry")."""
    from ..engine.evaluator import ApparentModel
    from ..engine.quadrature import RULES
    from .solver import check_fixed

    fixed = dict(fixed or {})
    freed = set(free or ())
    names = cls_names = brdf_cls.param_names()
    for n in list(fixed) + list(freed):
        if n not in cls_names:
            raise FitError(f"{brdf_cls.NAME} has no parameter {n!r}; its parameters are "
                           f"{', '.join(cls_names)}")
    for n, v in fixed.items():
        check_fixed(n, v, brdf_cls.param(n), brdf_cls.__name__)
    try:
        template = brdf_cls.template(**dict(options or {}))
    except (ValueError, TypeError) as exc:
        raise FitError(str(exc)) from None
    base = template.to_vector()
    for n, v in fixed.items():
        base[names.index(n)] = float(v)
    free_set = [i for i, p in enumerate(brdf_cls.PARAMS)
                if p.name not in fixed and (not p.held or p.name in freed)]
    scale_of = {brdf_cls.scale_index(part): part for part in BRDF_PARTS
                if brdf_cls.scale_index(part) is not None}
    free_scales = tuple(i for i in free_set if i in scale_of)
    nonlinear = [i for i in free_set if i not in scale_of]
    if not free_set:
        raise FitError("every parameter of the target is fixed: nothing to fit")
    axes = make_axes(brdf_cls, nonlinear, parse_grid([], brdf_cls) | dict(grid or {}))
    free_parts = [BRDF_PARTS.index(scale_of[i]) for i in free_scales]
    known_weight = np.ones(len(BRDF_PARTS))
    for k, part in enumerate(BRDF_PARTS):
        i = brdf_cls.scale_index(part)
        if i is not None:
            known_weight[k] = 0.0 if i in free_scales else base[i]
    angles = tuple(np.ascontiguousarray(a, dtype=float) for a in angles)
    if near is not None:
        return _build_near(brdf_cls, medium, angles, template, names, base, free_scales,
                           axes, free_parts, known_weight, fixed, accuracy, progress, near,
                           roi)
    engine = ApparentModel(template, medium, angles, RULES[accuracy])
    vm = medium.to_vector()
    rows = row_scales(type(medium), vm)
    shape = tuple(a.count for a in axes)
    q = len(free_scales)
    values = np.empty(shape + (len(angles[0]), q + 1))
    total = int(np.prod(shape)) if shape else 1
    for done, combo in enumerate(itertools.product(*[range(k) for k in shape])):
        vb = base.copy()
        for a, j in zip(axes, combo):
            vb[a.index] = a.nodes()[j]
        terms = engine.terms(vb, vm)  # (M, rows, parts), scales at 1
        cols = np.einsum("mrb,r->mb", terms, rows)
        for c, k in enumerate(free_parts):
            values[combo + (slice(None), c)] = cols[:, k]
        values[combo + (slice(None), q)] = cols @ known_weight
        if progress is not None:
            progress(done + 1, total)
    coef = values
    for ax, a in enumerate(axes):
        inv = _bspline_inverse(a.count)
        coef = np.moveaxis(np.tensordot(inv, coef, axes=([1], [ax])), 0, ax)
    medium_entry = {"model": type(medium).NAME, "params": medium.as_dict(),
                    "options": medium.options()}
    return MapTables(brdf_cls.NAME, dict(template.options()), names, base, free_scales, axes,
                     values, np.ascontiguousarray(coef), dict(fixed), medium_entry, accuracy,
                     angles)


def smoothest_facet(brdf_cls, names, base, axes, options) -> float:
    """The BRDF's facet half angle (deg) at the smoothest corner of the table (inf when the
    family has no facet lobe)."""
    corners = itertools.product(*[(a.lo, a.hi) for a in axes]) if axes else [()]
    widths = []
    for corner in corners:
        v = np.array(base, dtype=float)
        for a, value in zip(axes, corner):
            v[a.index] = value
        try:
            model = brdf_cls.from_params(dict(zip(names, v)), options)
            widths.append(model.facet_half_angle())
        except (ValueError, TypeError):
            continue
    return min(widths) if widths else float("inf")


def _columns(engine, vb, vm, rows, free_parts, known_weight, q):
    """(M, q + 1) basis columns of the engine's configurations at BRDF vector ``vb``."""
    terms = engine.terms(vb, vm)  # (M, rows, parts), scales at 1
    cols = np.einsum("mrb,r->mb", terms, rows)
    out = np.empty(cols.shape[:1] + (q + 1,))
    for c, k in enumerate(free_parts):
        out[:, c] = cols[:, k]
    out[:, q] = cols @ known_weight
    return out


def _to_coef(values, axes_first: int, count: int):
    """B-spline coefficients along axes ``axes_first .. axes_first + count - 1``."""
    for ax in range(axes_first, axes_first + count):
        inv = _bspline_inverse(values.shape[ax])
        values = np.moveaxis(np.tensordot(inv, values, axes=([1], [ax])), 0, ax)
    return values


def _field_block(field_values, fu):
    """Node values (K_1, ..., K_d, M, q + 1) at field-grid coordinates ``fu`` (2,) from the
    field coefficients (numpy; for the tables' own check of the interpolation)."""
    ws = []
    for a in range(2):
        k = field_values.shape[a] - 2
        i = int(np.clip(np.floor(fu[a]), 0, k - 2))
        w, _ = _weights(fu[a] - i, np)
        ws.append((i, w))
    (ix, wx), (iy, wy) = ws
    block = field_values[ix:ix + 4, iy:iy + 4]
    return np.einsum("ab...,a,b->...", block, wx, wy)


#: Field-grid check points of the interpolation error (fractions of the grid's cells):
#: the centres of two opposite corner cells, farthest from the nodes in both axes.
FIELD_CHECKS = ((0.5, 0.5), (-0.5, -0.5))


def _build_near(brdf_cls, medium, angles, template, names, base, free_scales, axes,
                free_parts, known_weight, fixed, accuracy, progress, near, roi):
    """Near-field tables: the columns at every node of a grid of plate points and of the
    nonlinear axes, with the pixel's own angles (docs/maps-geometry.md "Geometry"); the field
    interpolation checked against exact columns at :data:`FIELD_CHECKS`."""
    from ..engine.evaluator import ApparentModel
    from ..engine.quadrature import RULES
    from .maps_near import apparent_lobe, field_grid

    if roi is None:
        raise FitError("near-field tables need the region of the photo (roi)")
    lobe = apparent_lobe(smoothest_facet(brdf_cls, names, base, axes, template.options()),
                         medium.lobe_half_width())
    fgrid = field_grid(near, angles, roi, lobe)
    kx, ky = fgrid.shape
    m = len(angles[0])
    node_angles = tuple(np.ascontiguousarray(a.reshape(-1)) for a in fgrid.node_angles(angles))
    # the check pixels: cell centres of two opposite corner cells
    checks = []
    for fx, fy in FIELD_CHECKS:
        gx = fx if fx >= 0 else kx - 1 + fx
        gy = fy if fy >= 0 else ky - 1 + fy
        x = fgrid.xs[0] + gx * (fgrid.xs[-1] - fgrid.xs[0]) / (kx - 1)
        y = fgrid.ys[0] + gy * (fgrid.ys[-1] - fgrid.ys[0]) / (ky - 1)
        checks.append(((gx, gy), near.angles(angles, x, y)))
    all_angles = tuple(np.concatenate([node_angles[j]] + [c[1][j] for c in checks])
                       for j in range(4))
    engine = ApparentModel(template, medium, all_angles, RULES[accuracy])
    vm = medium.to_vector()
    rows = row_scales(type(medium), vm)
    shape = tuple(a.count for a in axes)
    q = len(free_scales)
    values = np.empty((kx, ky) + shape + (m, q + 1))
    exact = np.empty((len(checks),) + shape + (m, q + 1))
    total = int(np.prod(shape)) if shape else 1
    for done, combo in enumerate(itertools.product(*[range(k) for k in shape])):
        vb = base.copy()
        for a, j in zip(axes, combo):
            vb[a.index] = a.nodes()[j]
        cols = _columns(engine, vb, vm, rows, free_parts, known_weight, q)
        values[(slice(None), slice(None)) + combo] = cols[:kx * ky * m].reshape(kx, ky, m,
                                                                             q + 1)
        exact[(slice(None),) + combo] = cols[kx * ky * m:].reshape(len(checks), m, q + 1)
        if progress is not None:
            progress(done + 1, total)
    field_values = np.ascontiguousarray(_to_coef(values, 0, 2))
    coef = np.ascontiguousarray(_to_coef(field_values, 2, len(axes)))
    error = 0.0
    for k, ((gx, gy), _) in enumerate(checks):
        approx = _field_block(field_values, (gx, gy))
        scale = np.max(np.abs(exact[k]), axis=-2, keepdims=True)
        scale = np.where(scale > 0, scale, 1.0)
        error = max(error, float(np.max(np.abs(approx - exact[k]) / scale)))
    medium_entry = {"model": type(medium).NAME, "params": medium.as_dict(),
                    "options": medium.options()}
    return MapTables(brdf_cls.NAME, dict(template.options()), names, base, free_scales, axes,
                     values, coef, dict(fixed), medium_entry, accuracy, angles, near=fgrid,
                     field_error=error)


# --------------------------------------------------------------------------------------
# the per-pixel solver (JAX)
# --------------------------------------------------------------------------------------
def _interp(coef, u, d):
    """Basis (M, q + 1) and its derivatives (d, M, q + 1) at grid coordinates ``u`` (d,)."""
    from .._jax import jnp

    if d == 0:
        return coef, jnp.zeros((0,) + coef.shape)
    if d == 1:  # dense weights over every coefficient: a matrix product, no gather
        x = jnp.abs(u[0] - (jnp.arange(coef.shape[0]) - 1.0))
        sign = jnp.sign(u[0] - (jnp.arange(coef.shape[0]) - 1.0))
        inner, outer = x < 1, (x >= 1) & (x < 2)
        w = jnp.where(inner, 2 / 3 - x * x + 0.5 * x ** 3,
                      jnp.where(outer, (2 - x) ** 3 / 6, 0.0))
        dw = sign * jnp.where(inner, -2 * x + 1.5 * x * x,
                              jnp.where(outer, -0.5 * (2 - x) ** 2, 0.0))
        both = jnp.tensordot(jnp.stack([w, dw]), coef, axes=([1], [0]))
        return both[0], both[1:]
    block, ws, dws = _spline_block(coef, u, d)
    return _contract(block, ws, dws, d)


def _spline_block(coef, pos, axes):
    """The (4,) * axes block of cubic B-spline coefficients around grid coordinates ``pos``
    (axes,) and the weights and their slopes along each of those axes."""
    from .._jax import jax, jnp

    sizes = coef.shape[:axes]
    cells, ws, dws = [], [], []
    for a in range(axes):
        i = jnp.clip(jnp.floor(pos[a]), 0, sizes[a] - 4).astype(jnp.int64)
        w, dw = _weights(pos[a] - i, jnp)
        cells.append(i)
        ws.append(w)
        dws.append(dw)
    start = tuple(cells) + (0,) * (coef.ndim - axes)
    return jax.lax.dynamic_slice(coef, start, (4,) * axes + coef.shape[axes:]), ws, dws


def _contract(block, ws, dws, d):
    """Value and derivatives (d, ...) of a (4,) * d block with its axes' weights."""
    from .._jax import jnp

    letters = "abc"[:d]
    spec = f"{letters}...," + ",".join(letters) + "->..."
    value = jnp.einsum(spec, block, *ws)
    derivs = [jnp.einsum(spec, block, *[dws[b] if b == a else ws[b] for b in range(d)])
              for a in range(d)]
    return value, jnp.stack(derivs)


def _interp_near(coef, fu, u, d):
    """Near-field tables: basis (M, q + 1) at field-grid coordinates ``fu`` (2,) and grid
    coordinates ``u`` (d,), and its derivatives (d, M, q + 1) along the nonlinear axes
    (the pixel's position is not fitted)."""
    from .._jax import jnp

    block, ws, dws = _spline_block(coef, jnp.concatenate([fu, u]), d + 2)
    # the field axes first: a (4,) * d block of the pixel's own coefficients
    block = jnp.einsum("ab...,a,b->...", block, ws[0], ws[1])
    if d == 0:
        return block, jnp.zeros((0,) + block.shape)
    return _contract(block, ws[2:], dws[2:], d)


def _nnls_small(g, b, yy, q, jnp):
    """Non-negative least squares in q <= 2 unknowns from the normal equations
    (g (..., q, q), b (..., q), yy = y'y): (solution (..., q), cost (...,))."""
    if q == 0:
        return jnp.zeros(yy.shape + (0,)), yy
    cands = []
    if q == 1:
        s = jnp.maximum(b[..., 0] / jnp.where(g[..., 0, 0] > 0, g[..., 0, 0], 1.0), 0.0)
        s = jnp.where(g[..., 0, 0] > 0, s, 0.0)[..., None]
        cost = yy - 2 * s[..., 0] * b[..., 0] + s[..., 0] ** 2 * g[..., 0, 0]
        return s, cost
    zero = jnp.zeros_like(b[..., 0])
    # both active
    det = g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] * g[..., 1, 0]
    ok = jnp.abs(det) > 1e-14 * (g[..., 0, 0] * g[..., 1, 1] + 1e-300)
    dd = jnp.where(ok, det, 1.0)
    s0 = (g[..., 1, 1] * b[..., 0] - g[..., 0, 1] * b[..., 1]) / dd
    s1 = (g[..., 0, 0] * b[..., 1] - g[..., 1, 0] * b[..., 0]) / dd
    cands.append((s0, s1, ok & (s0 >= 0) & (s1 >= 0)))
    for j in range(2):
        gj = g[..., j, j]
        sj = jnp.where(gj > 0, jnp.maximum(b[..., j] / jnp.where(gj > 0, gj, 1.0), 0.0), 0.0)
        cands.append((sj, zero, jnp.ones_like(ok)) if j == 0 else (zero, sj, jnp.ones_like(ok)))
    best_s0, best_s1, best_cost = zero, zero, yy
    for s0, s1, feasible in cands:
        cost = (yy - 2 * (s0 * b[..., 0] + s1 * b[..., 1]) + s0 * s0 * g[..., 0, 0]
                + 2 * s0 * s1 * g[..., 0, 1] + s1 * s1 * g[..., 1, 1])
        better = feasible & (cost < best_cost)
        best_s0 = jnp.where(better, s0, best_s0)
        best_s1 = jnp.where(better, s1, best_s1)
        best_cost = jnp.where(better, cost, best_cost)
    return jnp.stack([best_s0, best_s1], axis=-1), best_cost


def _ldl(a, jnp):
    """Unrolled LDL^T of a small symmetric matrix (n <= 5): (L as nested lists, pivots D).
    Batched LAPACK calls on tiny matrices are slow in XLA; this is a handful of fused
    arithmetic ops."""
    n = a.shape[0]
    low = [[None] * n for _ in range(n)]
    piv = []
    for j in range(n):
        dj = a[j, j] - sum(low[j][k] ** 2 * piv[k] for k in range(j))
        dj = jnp.where(jnp.abs(dj) > 1e-300, dj, 1e-300)
        piv.append(dj)
        for i in range(j + 1, n):
            low[i][j] = (a[i, j] - sum(low[i][k] * low[j][k] * piv[k] for k in range(j))) / dj
    return low, piv


def _ldl_solve(low, piv, b, jnp):
    n = len(piv)
    z = []
    for i in range(n):
        z.append(b[i] - sum(low[i][k] * z[k] for k in range(i)))
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = z[i] / piv[i] - sum(low[k][i] * x[k] for k in range(i + 1, n))
    return jnp.stack(x)


_SOLVERS: dict = {}
#: One solver call at a time per process: concurrent first calls of a jitted function from
#: several threads (dask's threaded scheduler) were seen to deadlock, and XLA already uses
#: every core inside one call.
_CALL_LOCK = threading.Lock()


def _solver(q: int, d: int, sizes: tuple, weighted: bool, near: bool = False):
    """The jitted batch solver for q scales, d axes of ``sizes`` nodes; ``near``: tables
    with two field axes first, each pixel at its own field coordinates (docs/maps.md
    "Geometry")."""
    key = (q, d, sizes, weighted) + ((True,) if near else ())
    if key in _SOLVERS:
        return _SOLVERS[key]
    from .._jax import jax, jnp

    if near:
        def interp(coef, fu, u):
            return _interp_near(coef, fu, u, d)
    else:
        def interp(coef, fu, u):
            return _interp(coef, u, d)

    n = q + d
    hi = jnp.asarray([float(k - 1) for k in sizes])
    lo = jnp.zeros(n)
    hi_all = jnp.concatenate([jnp.full(q, jnp.inf), hi]) if d else jnp.full(q, jnp.inf)

    def model(coef, fu, p):
        s, u = p[:q], p[q:]
        b, db = interp(coef, fu, u)
        val = b[:, :q] @ s + b[:, q]
        jac_s = b[:, :q]
        jac_u = (jnp.einsum("amk,k->ma", db[..., :q], s) + db[..., q].T
                 if d else jnp.zeros((b.shape[0], 0)))
        return val, jnp.concatenate([jac_s, jac_u], axis=1)

    def initial(coef, fu, u0, s0, y, w2):
        """The iterations' state at the best node: (iterations, p, lambda, cost, value,
        Jacobian, stopped)."""
        p0 = jnp.concatenate([s0, u0])
        v0, j0 = model(coef, fu, p0)
        r0 = (y - v0) * jnp.sqrt(w2)
        return (jnp.asarray(0), p0, jnp.asarray(1e-4), r0 @ r0, v0, j0, jnp.asarray(False))

    def one_pixel(coef, fu, y, w2, state, limit):
        """Iterations from ``state`` until the pixel stops or has had ``limit``, then its
        statistics: (results, state)."""
        w = jnp.sqrt(w2)

        def refit(p):
            """(p with its scales replaced by their non-negative least-squares optimum at
            its nonlinear parameters, value, Jacobian): the model is linear in the scales,
            so every trial point of the iterations lies on the valley floor s*(theta)
            (variable projection), where a curved valley between a scale and a roughness
            would otherwise make the steps creep."""
            u = p[q:]
            b, db = interp(coef, fu, u)
            bw = b[:, :q] * w[:, None]
            rw = (y - b[:, q]) * w
            s, _ = _nnls_small(bw.T @ bw, bw.T @ rw, rw @ rw, q, jnp)
            p = jnp.concatenate([s, u])
            val = b[:, :q] @ s + b[:, q]
            jac_u = (jnp.einsum("amk,k->ma", db[..., :q], s) + db[..., q].T
                     if d else jnp.zeros((b.shape[0], 0)))
            return p, val, jnp.concatenate([b[:, :q], jac_u], axis=1)

        def project(p):
            s = jnp.maximum(p[:q], 0.0)
            u = jnp.clip(p[q:], 0.0, hi) if d else p[q:]
            return jnp.concatenate([s, u])

        def reduced_gn(p, a, g):
            """Predicted cost decrease of the undamped Gauss-Newton step over the
            parameters not held at a bound (a parameter is held when it sits on its bound
            and the gradient pushes it out): an upper bound on (step / standard error)^2
            of every such parameter, times the residual variance when unweighted."""
            held = ((p <= lo) & (g < 0)) | ((p >= hi_all) & (g > 0))
            pair = held[:, None] | held[None, :]
            ar = jnp.where(pair, jnp.eye(n), a)
            gr = jnp.where(held, 0.0, g)
            low, piv = _ldl(ar, jnp)
            return gr @ _ldl_solve(low, piv, gr, jnp)

        def lm(state):
            # one evaluation of the spline (value and Jacobian) per iteration
            it, p, lam, cost, val, jac, _ = state
            r = (y - val) * w
            jw = jac * w[:, None]
            a = jw.T @ jw
            g = jw.T @ r
            # converged at p: the reduced Gauss-Newton step is below LM_TOL standard
            # errors in every free parameter; the pixel is then frozen
            s2 = cost / dof if not weighted else 1.0
            dec = reduced_gn(p, a, g)
            now = (dec <= LM_TOL ** 2 * s2 + 1e-24 * yy) & jnp.isfinite(dec)
            diag = jnp.diag(a)
            scale = jnp.where(diag > 0, diag, 1.0)
            low, piv = _ldl(a + lam * jnp.diag(scale), jnp)
            step = _ldl_solve(low, piv, g, jnp)
            trial, tval, tjac = refit(
                project(p + jnp.where(jnp.isfinite(step), step, 0.0)))
            tr = (y - tval) * w
            tcost = tr @ tr
            better = (tcost < cost) & ~now
            lam = jnp.where(now, lam, jnp.where(better, jnp.maximum(lam * 0.2, 1e-12),
                                                 jnp.minimum(lam * 10, 1e12)))
            return (it + jnp.where(now, 0, 1), jnp.where(better, trial, p), lam,
                    jnp.where(better, tcost, cost), jnp.where(better, tval, val),
                    jnp.where(better, tjac, jac), now)

        def running(state):
            return (state[0] < limit) & ~state[-1]

        yy = (y * w) @ (y * w)
        npts = jnp.sum(w2 > 0)
        dof = jnp.maximum(npts - n, 1)
        # under vmap the loop runs while any pixel of the batch runs; a frozen pixel's
        # state is selected unchanged (and the body leaves it unchanged too)
        state = jax.lax.while_loop(running, lm, state)
        iters, p, _, _, val, jac, _ = state
        r = (y - val) * w
        jw = jac * w[:, None]
        colnorm = jnp.sqrt(jnp.sum(jw * jw, axis=0))
        ok_cols = jnp.all(colnorm > 0)
        je = jw / jnp.where(colnorm > 0, colnorm, 1.0)
        a = je.T @ je
        # pivots of the equilibrated normal matrix (unit diagonal): a pivot near 0 is a
        # direction the data do not constrain
        low, piv = _ldl(jnp.where(ok_cols, a, jnp.eye(n)), jnp)
        rank_ok = ok_cols & (jnp.min(jnp.stack(piv)) > SINGULAR ** 2 * n)
        eye = jnp.eye(n)
        ainv = jnp.stack([_ldl_solve(low, piv, eye[i], jnp) for i in range(n)], axis=1)
        cov = ainv / jnp.outer(jnp.where(colnorm > 0, colnorm, 1.0),
                               jnp.where(colnorm > 0, colnorm, 1.0))
        chi2 = (r @ r) / dof
        if not weighted:
            cov = cov * chi2
        se = jnp.sqrt(jnp.maximum(jnp.diag(cov), 0.0))
        # the undamped Gauss-Newton step from the solution, in standard errors
        gn = cov @ (jw.T @ r)
        if not weighted:
            gn = gn / jnp.where(chi2 > 0, chi2, 1.0)
        proj = project(p + gn) - p
        step_se = jnp.max(jnp.abs(proj) / jnp.where(se > 0, se, 1.0)) if n else 0.0
        return (p, se, chi2, npts, rank_ok, step_se, iters), state

    def node_stage(values, y, w2):
        """Distant tables: the scales by exact NNLS at every node, the best node:
        (s0, u0)."""
        nodes = values.reshape((-1,) + values.shape[d:])  # (N, M, q + 1)
        n_nodes, m = nodes.shape[0], nodes.shape[1]
        bq, c = nodes[..., :q], nodes[..., q]
        # as matrix products over the configurations (M): (P, M) @ (M, ...)
        prods = jnp.einsum("nmi,nmj->mnij", bq, bq).reshape(m, -1)
        gram = (w2 @ prods).reshape(-1, n_nodes, q, q)
        wy = w2 * y
        vb = jnp.transpose(bq, (1, 0, 2)).reshape(m, -1)
        vc = jnp.transpose(bq * c[..., None], (1, 0, 2)).reshape(m, -1)
        rhs = (wy @ vb - w2 @ vc).reshape(-1, n_nodes, q)
        yy = (wy * y).sum(-1)[:, None] - 2 * wy @ c.T + w2 @ (c * c).T
        s_all, cost = _nnls_small(gram, rhs, yy, q, jnp)
        # 2. the best node
        best = jnp.argmin(cost, axis=1)
        s0 = jnp.take_along_axis(s_all, best[:, None, None], axis=1)[:, 0, :]
        if d:
            u0 = jnp.stack(jnp.unravel_index(best, sizes), axis=1).astype(float)
        else:
            u0 = jnp.zeros((y.shape[0], 0))
        return s0, u0

    def near_nodes(values, fu, y, w2):
        """Near-field tables, one pixel: the scales by exact NNLS at every node of the
        nearest field node's columns, the best node: (s0, u0) - a starting point; the
        iterations then use the pixel's own interpolated columns."""
        ix = jnp.clip(jnp.round(fu[0]), 0, values.shape[0] - 1).astype(jnp.int64)
        iy = jnp.clip(jnp.round(fu[1]), 0, values.shape[1] - 1).astype(jnp.int64)
        nodes = values[ix, iy]
        nodes = nodes.reshape((-1,) + nodes.shape[d:])  # (N, M, q + 1)
        bq, c = nodes[..., :q], nodes[..., q]
        wy_ = w2 * y
        gram = jnp.einsum("nmi,m,nmj->nij", bq, w2, bq)
        rhs = jnp.einsum("nmi,m->ni", bq, wy_) - jnp.einsum("nmi,nm->ni", bq, w2 * c)
        yy = wy_ @ y - 2 * c @ wy_ + (c * c) @ w2
        s_all, cost = _nnls_small(gram, rhs, yy, q, jnp)
        best = jnp.argmin(cost)
        s0 = s_all[best]
        u0 = (jnp.stack(jnp.unravel_index(best, sizes)).astype(float) if d
              else jnp.zeros((0,)))
        return s0, u0

    def batch(values, coef, y, w2, fu=None):
        # 1. every node: the scales by exact NNLS, from the weighted normal equations;
        # 2. the best node
        if near:  # per pixel, NEAR_GROUP pixels at a time (memory: their node values)
            group = lambda a: a.reshape((-1, NEAR_GROUP) + a.shape[1:])  # noqa: E731
            s0, u0 = jax.lax.map(
                lambda args: jax.vmap(near_nodes, in_axes=(None, 0, 0, 0))(values, *args),
                (group(fu), group(y), group(w2)))
            s0, u0 = (a.reshape((y.shape[0],) + a.shape[2:]) for a in (s0, u0))
        else:
            s0, u0 = node_stage(values, y, w2)
            fu = jnp.zeros((y.shape[0], 0))
        # 3. Levenberg-Marquardt on the spline, FIRST_ITERATIONS at most
        state = jax.vmap(initial, in_axes=(None, 0, 0, 0, 0, 0))(coef, fu, u0, s0, y, w2)
        return jax.vmap(one_pixel, in_axes=(None, 0, 0, 0, 0, None))(
            coef, fu, y, w2, state, min(FIRST_ITERATIONS, ITERATIONS))

    def resume(coef, y, w2, state, fu=None):
        # the pixels still running after FIRST_ITERATIONS, gathered from several batches
        if fu is None:
            fu = jnp.zeros((y.shape[0], 0))
        return jax.vmap(one_pixel, in_axes=(None, 0, 0, 0, 0, None))(coef, fu, y, w2, state,
                                                                     ITERATIONS)

    fns = (jax.jit(batch), jax.jit(resume))
    _SOLVERS[key] = fns
    return fns


def _dispatch(tables, count, call, done):
    """``count`` items in batches of BATCH (the last padded by repeating its last item):
    ``call(indices, device, (values, coef) on the device)`` for each batch, round the CPU
    devices (one core each, veil._jax) without waiting, at most IN_FLIGHT per device
    pending; ``done(start, stop, result)`` in order. Every batch is the same computation
    on BATCH items whichever device runs it."""
    from .._jax import jax

    devices = jax.devices()
    on_device = {}
    pending = []
    for b, start in enumerate(range(0, count, BATCH)):
        stop = min(start + BATCH, count)
        idx = np.minimum(np.arange(start, start + BATCH), stop - 1)
        dev = devices[b % len(devices)]
        if dev not in on_device:
            on_device[dev] = tuple(jax.device_put(a, dev) for a in tables.solver_arrays)
        pending.append((start, stop, call(idx, dev, on_device[dev])))
        if len(pending) >= IN_FLIGHT * len(devices):
            done(*pending.pop(0))
    while pending:
        done(*pending.pop(0))


def warm_up(tables: MapTables, noise=None) -> None:
    """Compile both parts of the solver of ``tables`` on every CPU device (on dark pixels,
    which stop at once), so that no later call waits for a compilation."""
    from .._jax import jax

    near = tables.near is not None
    first, rest = _solver(len(tables.free_scales), len(tables.axes),
                          tuple(a.count for a in tables.axes), noise is not None, near)
    y = np.zeros((BATCH, tables.n_configs))
    extra = (np.zeros((BATCH, 2)),) if near else ()
    with _CALL_LOCK:
        for dev in jax.devices():
            values, coef = (jax.device_put(a, dev) for a in tables.solver_arrays)
            y_dev, w2_dev = jax.device_put(y, dev), jax.device_put(np.ones_like(y), dev)
            fu = tuple(jax.device_put(a, dev) for a in extra)
            _, state = first(values, coef, y_dev, w2_dev, *fu)
            jax.block_until_ready(rest(coef, y_dev, w2_dev, state, *fu))


@dataclass
class PixelFits:
    """Per-pixel results (flat arrays over pixels): ``params`` (P, N) every BRDF parameter,
    ``stderr`` (P, N) (0 where fixed or not reported), ``chi2`` (N,), ``n_points`` (N,),
    ``status`` (N,) uint8 (:data:`STATUS`), ``iterations`` (N,) Levenberg-Marquardt
    iterations the pixel took (at most :data:`ITERATIONS`)."""

    params: np.ndarray
    stderr: np.ndarray
    chi2: np.ndarray
    n_points: np.ndarray
    status: np.ndarray
    iterations: np.ndarray


def solve_pixels(tables: MapTables, y: np.ndarray, valid: np.ndarray,
                 noise=None, pixels=None) -> PixelFits:
    """Fit every pixel: ``y`` (N, M) values, ``valid`` (N, M) usable samples (saturated,
    clipped and masked ones False), ``noise`` None (unweighted) or (relative, absolute):
    sigma = sqrt((relative * value)^2 + absolute^2). Near-field tables need ``pixels``
    (x (N,), y (N,)): each pixel's position in the full photo."""
    from .._jax import jax

    near = tables.near is not None
    if near:
        if pixels is None:
            raise FitError("near-field tables: give each pixel's position (pixels=(x, y))")
        fu = tables.field_coords(*pixels)
        if len(fu) != len(y):
            raise FitError(f"{len(fu)} pixel positions for {len(y)} pixels")
    y = np.asarray(y, dtype=float)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(y)
    n_pix, m = y.shape
    if m != tables.n_configs:
        raise FitError(f"{m} values per pixel but the tables have {tables.n_configs} "
                       f"configurations")
    y = np.where(valid, y, 0.0)
    if noise is None:
        w2 = valid.astype(float)
    else:
        rel, ab = noise
        sigma2 = (rel * y) ** 2 + ab ** 2
        w2 = np.where(valid & (sigma2 > 0), 1.0 / np.where(sigma2 > 0, sigma2, 1.0), 0.0)
    q, d = len(tables.free_scales), len(tables.axes)
    sizes = tuple(a.count for a in tables.axes)
    first, rest = _solver(q, d, sizes, noise is not None, near)
    n = q + d
    out_p = np.zeros((n_pix, n))
    out_se = np.zeros((n_pix, n))
    out_chi2 = np.zeros(n_pix)
    out_np = np.zeros(n_pix, dtype=np.int64)
    out_rank = np.zeros(n_pix, dtype=bool)
    out_step = np.zeros(n_pix)
    out_it = np.zeros(n_pix, dtype=np.int32)
    slow_pixels, slow_states = [], []

    def store(where, outs):
        p, se, chi2, npts, rank_ok, step, iters = outs
        out_p[where], out_se[where], out_chi2[where] = p, se, chi2
        out_np[where], out_rank[where], out_step[where], out_it[where] = (npts, rank_ok,
                                                                          step, iters)

    def first_done(start, stop, result):
        outs, state = result
        k = stop - start
        store(slice(start, stop), [np.asarray(a)[:k] for a in outs])
        state = [np.asarray(a)[:k] for a in state]
        slow = ~state[-1] & (state[0] >= FIRST_ITERATIONS)
        if slow.any():
            slow_pixels.append(np.arange(start, stop)[slow])
            slow_states.append([a[slow] for a in state])

    def at(idx, dev):  # near field: the pixels' field coordinates (none otherwise)
        return (jax.device_put(fu[idx], dev),) if near else ()

    with _CALL_LOCK:
        _dispatch(tables, n_pix, lambda idx, dev, tab: first(*tab, jax.device_put(y[idx], dev),
                                                            jax.device_put(w2[idx], dev),
                                                            *at(idx, dev)),
                  first_done)
        if slow_pixels:  # the rest of the iterations for the slow pixels of every batch
            where = np.concatenate(slow_pixels)
            states = [np.concatenate(parts) for parts in zip(*slow_states)]
            _dispatch(tables, len(where),
                      lambda idx, dev, tab: rest(tab[1], jax.device_put(y[where[idx]], dev),
                                                 jax.device_put(w2[where[idx]], dev),
                                                 tuple(jax.device_put(a[idx], dev) for a in states),
                                                 *at(where[idx], dev)),
                      lambda start, stop, result: store(
                          where[start:stop], [np.asarray(a)[:stop - start] for a in result[0]]))
    # status, worst first
    status = np.full(n_pix, CONVERGED, dtype=np.uint8)
    status[out_step > STEP_TOL] = NOT_CONVERGED
    if d:
        u = out_p[:, q:]
        hi = np.array([a.count - 1 for a in tables.axes], dtype=float)
        at_edge = np.any((u <= 1e-9) | (u >= hi - 1e-9), axis=1)
        status[at_edge] = EDGE
    signal = np.any((y > 0) & valid, axis=1)
    scale_zero = np.any(out_p[:, :q] <= 0, axis=1) if q else np.zeros(n_pix, bool)
    status[~out_rank | scale_zero | ~signal] = UNDETERMINED
    status[out_np <= n] = FEW_POINTS
    status[~valid.any(axis=1)] = MASKED
    bad = ~np.all(np.isfinite(out_p), axis=1) | ~np.all(np.isfinite(out_se), axis=1) \
        | ~np.isfinite(out_chi2)
    status[bad & (status == CONVERGED)] = UNDETERMINED
    # physical parameters
    n_all = len(tables.names)
    params = np.repeat(tables.base[:, None], n_pix, axis=1)
    stderr = np.zeros((n_all, n_pix))
    for c, i in enumerate(tables.free_scales):
        params[i] = out_p[:, c]
        stderr[i] = out_se[:, c]
    for c, a in enumerate(tables.axes):
        u = out_p[:, q + c]
        phys = a.physical(u)
        params[a.index] = phys
        stderr[a.index] = out_se[:, q + c] * a.step * (phys if a.log else 1.0)
    reported = status == CONVERGED
    good_numbers = np.all(np.isfinite(params), axis=0) & np.all(np.isfinite(stderr), axis=0)
    params = np.where(good_numbers[None, :], params, tables.base[:, None])
    stderr = np.where((reported & good_numbers)[None, :], stderr, 0.0)
    chi2 = np.where(np.isfinite(out_chi2) & (status != MASKED) & (status != FEW_POINTS),
                    out_chi2, 0.0)
    return PixelFits(params, stderr, chi2, out_np.astype(np.int32), status, out_it)


__all__ = ["STATUS", "Axis", "MapTables", "build_tables", "solve_pixels", "warm_up", "PixelFits",
           "parse_grid", "make_axes"]
