"""The tables' grid (docs/maps.md): the tabulated nonlinear parameters (:class:`Axis`, from
the model's starting grids or ``--grid NAME=LO:HI[:COUNT]``) and the tensor-product cubic
B-spline over them (not-a-knot ends, C2, exact derivatives) that the per-pixel solve
evaluates, numpy or JAX."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import FitError

if TYPE_CHECKING:
    from jax import Array

#: Grid nodes per nonlinear axis by the number of axes (``grid=`` overrides).
NODES = {1: 48, 2: 24, 3: 12}


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

    def coord(self, value) -> np.ndarray:
        return np.log(value) if self.log else np.asarray(value, dtype=float)

    @property
    def step(self) -> float:
        return float((self.coord(self.hi) - self.coord(self.lo)) / (self.count - 1))

    def nodes(self) -> np.ndarray:
        c = np.linspace(float(self.coord(self.lo)), float(self.coord(self.hi)), self.count)
        return np.exp(c) if self.log else c

    def grid(self, value) -> np.ndarray:
        """Grid coordinate (0 .. count - 1 inside the table) of physical values; the
        inverse of :meth:`physical`."""
        return (np.asarray(self.coord(value)) - float(self.coord(self.lo))) / self.step

    def physical(self, u) -> np.ndarray | Array | float:
        """Physical value at grid coordinate ``u`` (0 .. count - 1); numpy or JAX."""
        c = float(self.coord(self.lo)) + u * self.step
        if self.log:
            return np.exp(c) if isinstance(c, (float, np.ndarray)) else _jnp().exp(c)
        return c

    def physical_stderr(self, se_u, value) -> np.ndarray | float:
        """The standard error of the physical value ``value`` from ``se_u``, that of its
        grid coordinate (first order: d value / du = step, times the value on a log axis)."""
        return se_u * self.step * (value if self.log else 1.0)

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
            raise FitError(
                f"grid {item!r}: {cls.NAME} has no parameter {name!r}; its "
                f"parameters are {', '.join(cls.param_names())}"
            )
        try:
            lo, hi = float(parts[0]), float(parts[1])
            count = int(parts[2]) if len(parts) == 3 else None
        except ValueError:
            raise FitError(f"grid {item!r}: LO and HI must be numbers, COUNT an integer") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise FitError(f"grid {item!r}: expected finite LO < HI")
        if count is not None and not 4 <= count <= 400:
            raise FitError(f"grid {item!r}: COUNT must be between 4 and 400")
        p = cls.param(name)
        for v in (lo, hi):
            if not p.contains(v):
                raise FitError(f"grid {item!r}: {v:g} is outside {name}'s bounds {p.interval()}")
        out[name] = (lo, hi, count)
    return out


def make_axes(cls, free_nonlinear, grid=None) -> list[Axis]:
    """The table's axes over the free nonlinear parameters (indices into ``cls.PARAMS``):
    the range of the model's starting grids (target and reference roles together) unless
    ``grid`` ({name: (lo, hi, count)}) says otherwise."""
    grid = dict(grid or {})
    unknown = [n for n in grid if cls.param_names().index(n) not in free_nonlinear]
    if unknown:
        raise FitError(
            f"grid given for {', '.join(unknown)}, which is not a free nonlinear "
            f"parameter of this fit (a scale, fixed, or held)"
        )
    d = len(free_nonlinear)
    if d > 3:
        raise FitError(
            f"{d} free nonlinear parameters; per-pixel tables handle at most 3: "
            f"fix some with --fix NAME=VALUE"
        )
    axes = []
    for i in free_nonlinear:
        p = cls.PARAMS[i]
        if p.name in grid:
            lo, hi, count = grid[p.name]
        else:
            values = set()
            for role in ("target", "reference"):
                values |= {
                    float(v) for v in cls.start_grid(role).get(p.name, ()) if p.contains(float(v))
                }
            if len(values) < 2:
                raise FitError(
                    f"{cls.NAME}.{p.name}: the model's starting grids give no "
                    f"range to tabulate; fix it (--fix {p.name}=VALUE) or give "
                    f"its range (--grid {p.name}=LO:HI)"
                )
            lo, hi, count = min(values), max(values), None
        if p.log_scale and lo <= 0:
            raise FitError(f"grid of {p.name}: a log-scaled parameter needs LO > 0")
        axes.append(
            Axis(p.name, i, bool(p.log_scale), float(lo), float(hi), int(count or NODES[d]))
        )
    return axes


# --------------------------------------------------------------------------------------
# cubic B-spline interpolation with not-a-knot ends
# --------------------------------------------------------------------------------------
def bspline_inverse(k: int) -> np.ndarray:
    """(k + 2, k) matrix taking node values to the coefficients of the uniform cubic
    B-spline that interpolates them with not-a-knot ends (third derivative continuous at
    the second and the second-last node). Coefficient j is the B-spline centred at node
    j - 1."""
    a = np.zeros((k + 2, k + 2))
    for i in range(k):  # value at node i: (c_i + 4 c_{i+1} + c_{i+2}) / 6
        a[i, i : i + 3] = (1 / 6, 4 / 6, 1 / 6)
    if k >= 4:  # jump of the third derivative at nodes 1 and k - 2: a fourth difference
        a[k, 0:5] = (1, -4, 6, -4, 1)
        a[k + 1, k - 3 : k + 2] = (1, -4, 6, -4, 1)
    else:  # natural ends
        a[k, 0:3] = (1, -2, 1)
        a[k + 1, k - 1 : k + 2] = (1, -2, 1)
    rhs = np.zeros((k + 2, k))
    rhs[:k, :] = np.eye(k)
    return np.linalg.solve(a, rhs)


def spline_weights(t, jnp) -> tuple[np.ndarray | Array, np.ndarray | Array]:
    """Cubic B-spline weights and their derivatives at offset t in [0, 1] of a cell."""
    t2, t3 = t * t, t * t * t
    w = jnp.stack(
        [(1 - t) ** 3 / 6, (3 * t3 - 6 * t2 + 4) / 6, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6]
    )
    dw = jnp.stack([-0.5 * (1 - t) ** 2, (3 * t2 - 4 * t) / 2, (-3 * t2 + 2 * t + 1) / 2, t2 / 2])
    return w, dw


# --------------------------------------------------------------------------------------
# the per-pixel solver (JAX)
# --------------------------------------------------------------------------------------
def interp(coef, u, d) -> tuple[Array, Array]:
    """Basis (M, q + 1) and its derivatives (d, M, q + 1) at grid coordinates ``u`` (d,)."""
    from .._jax import jnp

    if d == 0:
        return coef, jnp.zeros((0,) + coef.shape)
    if d == 1:  # dense weights over every coefficient: a matrix product, no gather
        x = jnp.abs(u[0] - (jnp.arange(coef.shape[0]) - 1.0))
        sign = jnp.sign(u[0] - (jnp.arange(coef.shape[0]) - 1.0))
        inner, outer = x < 1, (x >= 1) & (x < 2)
        w = jnp.where(inner, 2 / 3 - x * x + 0.5 * x**3, jnp.where(outer, (2 - x) ** 3 / 6, 0.0))
        dw = sign * jnp.where(
            inner, -2 * x + 1.5 * x * x, jnp.where(outer, -0.5 * (2 - x) ** 2, 0.0)
        )
        both = jnp.tensordot(jnp.stack([w, dw]), coef, axes=([1], [0]))
        return both[0], both[1:]
    block, ws, dws = spline_block(coef, u, d)
    return contract(block, ws, dws, d)


def spline_block(coef, pos, axes):
    """The (4,) * axes block of cubic B-spline coefficients around grid coordinates ``pos``
    (axes,) and the weights and their slopes along each of those axes."""
    from .._jax import jax, jnp

    sizes = coef.shape[:axes]
    cells, ws, dws = [], [], []
    for a in range(axes):
        i = jnp.clip(jnp.floor(pos[a]), 0, sizes[a] - 4).astype(jnp.int64)
        w, dw = spline_weights(pos[a] - i, jnp)
        cells.append(i)
        ws.append(w)
        dws.append(dw)
    start = tuple(cells) + (0,) * (coef.ndim - axes)
    return jax.lax.dynamic_slice(coef, start, (4,) * axes + coef.shape[axes:]), ws, dws


def contract(block, ws, dws, d):
    """Value and derivatives (d, ...) of a (4,) * d block with its axes' weights."""
    from .._jax import jnp

    letters = "abc"[:d]
    spec = f"{letters}...," + ",".join(letters) + "->..."
    value = jnp.einsum(spec, block, *ws)
    derivs = [
        jnp.einsum(spec, block, *[dws[b] if b == a else ws[b] for b in range(d)]) for a in range(d)
    ]
    return value, jnp.stack(derivs)


def interp_near(coef, fu, u, d) -> tuple[Array, Array]:
    """Near-field tables: basis (M, q + 1) at field-grid coordinates ``fu`` (2,) and grid
    coordinates ``u`` (d,), and its derivatives (d, M, q + 1) along the nonlinear axes
    (the pixel's position is not fitted)."""
    from .._jax import jnp

    block, ws, dws = spline_block(coef, jnp.concatenate([fu, u]), d + 2)
    # the field axes first: a (4,) * d block of the pixel's own coefficients
    block = jnp.einsum("ab...,a,b->...", block, ws[0], ws[1])
    if d == 0:
        return block, jnp.zeros((0,) + block.shape)
    return contract(block, ws[2:], dws[2:], d)


def field_block(field_values, fu) -> np.ndarray:
    """Node values (K_1, ..., K_d, M, q + 1) at field-grid coordinates ``fu`` (2,) from the
    field coefficients (numpy; for the tables' own check of the interpolation)."""
    ws = []
    for a in range(2):
        k = field_values.shape[a] - 2
        i = int(np.clip(np.floor(fu[a]), 0, k - 2))
        w, _ = spline_weights(fu[a] - i, np)
        ws.append((i, w))
    (ix, wx), (iy, wy) = ws
    block = field_values[ix : ix + 4, iy : iy + 4]
    return np.einsum("ab...,a,b->...", block, wx, wy)


#: Field-grid check points of the interpolation error (fractions of the grid's cells):


__all__ = [
    "NODES",
    "Axis",
    "parse_grid",
    "make_axes",
    "bspline_inverse",
    "spline_weights",
    "interp",
    "interp_near",
    "field_block",
]
