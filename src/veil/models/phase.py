"""Henyey-Greenstein phase function (docs/model.md sec. 3): density, cone fraction and inverse.

Everything is written in terms of ``1 - cos(gamma)`` where precision matters: for g = 0.99
the lobe is half a degree wide and ``cos(gamma)`` alone loses the digits.

Every function is finite for every g in (-1, 1), down to 1 - |g| = 1e-16, and every
``1 - cos(gamma)`` in [0, 2]. Two quantities are differences of nearly equal numbers for
some sign of g and are bounded below by their exact minimum, (1 - |g|)^2 and 1 - |g|: the
density's denominator ``1 + g^2 - 2 g mu`` for g < 0 at the backward peak (mu = -1, where
``1 - cos(gamma)`` itself carries an absolute error of 2e-16), and the inverse's
``1 + g - 2 g frac`` for g > 0 as frac -> 1. Without the bound both rounded to zero or
below and gave NaN (1 - |g| <= 1e-8 at grazing angles).
"""

from __future__ import annotations

import math

from .._lazy import jax, jnp

_FOUR_PI = 4.0 * math.pi


def _den(g, one_minus_mu):
    # 1 + g^2 - 2 g mu, written without cancellation near mu = 1; never below its minimum
    # over mu, (1 - |g|)^2 > 0, which rounding reached for g -> -1 near mu = -1.
    return jnp.maximum((1.0 - g) ** 2 + 2.0 * g * one_minus_mu, (1.0 - jnp.abs(g)) ** 2)


def hg_pdf(g, one_minus_mu):
    """p(g, gamma) per steradian, normalized over the sphere (docs/model.md eq. for p)."""
    d = _den(g, one_minus_mu)
    return (1.0 - g * g) / (_FOUR_PI * d * jnp.sqrt(d))


def hg_cone_fraction(g, one_minus_mu):
    """Fraction of the phase function within the cone cos(gamma') >= mu (0 at mu=1, 1 at mu=-1)."""
    s = jnp.sqrt(_den(g, one_minus_mu))
    # (1-g^2)/(2g) (1/(1-g) - 1/s) = (1+g)(s-(1-g)) / (2 g s); regular at g -> 0 via the
    # identity s - (1-g) = 2 g (1-mu) / (s + 1 - g). s >= 1 - |g| > 0 and s + 1 - g > 0.
    return (1.0 + g) * one_minus_mu / (s * (s + 1.0 - g))


def hg_inverse_cone_fraction(g, frac):
    """``1 - cos(gamma)`` of the cone that holds ``frac`` of the phase function."""
    # s = (1 - g^2) / (1 + g - 2 g frac); 1 - mu = (s^2 - (1-g)^2) / (2g)
    #   = (s - (1-g)) (s + (1-g)) / (2g), and s - (1-g) = (1-g) * 2 g frac / (1 + g - 2 g frac).
    # q = 1 + g - 2 g frac >= 1 - |g| > 0 for frac in [0, 1]; rounding reached 0 for g -> 1
    # as frac -> 1
    q = jnp.maximum(1.0 + g - 2.0 * g * frac, 1.0 - jnp.abs(g))
    s = (1.0 - g * g) / q
    return (1.0 - g) * frac * (s + 1.0 - g) / q


# --------------------------------------------------------------------------------------
# mixtures of Henyey-Greenstein lobes, tabulated once per engine call
# --------------------------------------------------------------------------------------
# A mixture sum_k c_k p(g_k) (veil.models.forward_series) is tabulated once per engine call
# (the tables are rebuilt for every call, so they must be cheap: 1.7 ms, against 17 ms for
# the former 8192-node cubic tables with Newton-solved inverse):
# - by x = (1 - cos)^(1/4) (spreads lobes of any width over the table without a logarithm
#   per lookup), MIXTURE_NODES cubic Hermite intervals with the exact slopes, one row of
#   coefficients for G = F / (1 - cos) (F itself grows as x^4 at the peak, which no cubic
#   fits) and p together: the cone fraction F and the density p from one gather;
# - by the sampling coordinate t, F / F_total = 1 - (1 - t^4)^4, the same for x and p at the
#   cone holding a fraction (a phase grid gets its nodes and their densities from one
#   gather); x(t) is solved by Newton steps on the exact F, differentiable in the
#   parameters (the last step by the implicit function theorem); every slope is exact
#   (dp/d(1 - cos) in closed form, dx/dt from dF/dx = 2 pi p 4 x^3);
# - the density alone, for the engine's many point evaluations (the 4D term evaluates it
#   at every reflected direction), on PDF_NODES intervals in x, linear: two scalar gathers.
# Lookups in the engine's large products run apart from them (_apart): XLA does not
# vectorize gathers, and a fusion that holds one loses its vector code altogether.
# With these node counts the interpolation error is below 2e-6 relative for g from -0.5 to
# 0.995 and tau up to 3 (tests/test_model_contract.py,
# test_forward_series_phase_tables_hold_their_accuracy_over_the_parameter_range).
MIXTURE_NODES = 512
PDF_NODES = 8192
_X_MAX = 2.0**0.25


def _hg_pdf_slope(g, one_minus_mu):
    """d p(g) / d(1 - cos gamma) = -3 g (1 - g^2) / (4 pi den^(5/2))."""
    d = _den(g, one_minus_mu)
    return -3.0 * g * (1.0 - g * g) / (_FOUR_PI * d * d * jnp.sqrt(d))


def _terms(c, gk, omm, slope=False):
    """F and p of the mixture at ``omm`` (any shape), and dp/d(1 - cos) with ``slope``."""
    omm = jnp.asarray(omm)[..., None]
    f = jnp.sum(c * hg_cone_fraction(gk, omm), axis=-1)
    p = jnp.sum(c * hg_pdf(gk, omm), axis=-1)
    if not slope:
        return f, p
    return f, p, jnp.sum(c * _hg_pdf_slope(gk, omm), axis=-1)


def _hermite_rows(values, slopes, step):
    """Cubic coefficients (a0, a1, a2, a3) per interval in s in [0, 1) from node values and
    slopes per unit of the coordinate (grid step ``step``)."""
    m = slopes * step
    v0, v1, m0, m1 = values[:-1], values[1:], m[:-1], m[1:]
    return (v0, m0, 3.0 * (v1 - v0) - 2.0 * m0 - m1, 2.0 * (v0 - v1) + m0 + m1)


#: The sampling coordinate t in [0, 1]: F / F_total = 1 - (1 - t^4)^_M. Near the peak
#: F ~ t^4 (x proportional to t); near the backward end 1 - F ~ (1 - t)^_M resolves the
#: broad tail, where a narrow lobe holds little of F over most of the angles.
_M = 4


def _sampling_coordinate(f):
    """t(F / F_total) without cancellation: 1 - (1 - f)^(1/M) = f / ((1 + r)(1 + r^2)),
    r = (1 - f)^(1/4) (M = 4)."""
    r = jnp.sqrt(jnp.sqrt(1.0 - f))
    w = f / ((1.0 + r) * (1.0 + r * r))
    return jnp.sqrt(jnp.sqrt(w))


def mixture_table(c, gk, nodes: int | None = None):
    """Tables of the mixture sum_k c_k p(g_k) (module comment): (rows by x of G = F / (1 -
    cos) and p, rows by t of x and p, F_total); rows are (intervals, 8) cubic coefficients."""
    n = MIXTURE_NODES if nodes is None else nodes
    hx = _X_MAX / n
    x = jnp.linspace(0.0, _X_MAX, n + 1)
    x3 = x**3
    omm = x**4
    f, p, dp = _terms(c, gk, omm, slope=True)
    # G = F / (1 - cos): smooth at the peak, where F itself grows as x^4 (no cubic fits it);
    # dG/dx = 4 (2 pi p - G) / x, 0 at x = 0
    pos = x > 0
    g_val = jnp.where(pos, f / jnp.where(pos, omm, 1.0), 2.0 * math.pi * p)
    g_slope = jnp.where(pos, 4.0 * (2.0 * math.pi * p - g_val) / jnp.where(pos, x, 1.0), 0.0)
    by_x = jnp.stack(
        _hermite_rows(g_val, g_slope, hx) + _hermite_rows(p, dp * 4.0 * x3, hx), axis=-1
    )
    total = f[-1]
    t = jnp.linspace(0.0, 1.0, n + 1)
    t4 = t**4
    target = total * -jnp.expm1(_M * jnp.log1p(-jnp.minimum(t4, 1.0 - 1e-300)))
    target = jnp.where(t4 < 1.0, target, total)
    # start from linear interpolation in the F table, Newton steps on the exact F (in 1 - cos)
    fs, ts = jax.lax.stop_gradient(f), jax.lax.stop_gradient(target)
    xs = jnp.interp(ts, fs, jax.lax.stop_gradient(x))
    cs, gs = jax.lax.stop_gradient(c), jax.lax.stop_gradient(gk)
    om = xs**4
    for _ in range(5):
        fv, pv = _terms(cs, gs, om)
        om = jnp.clip(om - (fv - ts) / jnp.maximum(2.0 * math.pi * pv, 1e-300), 0.0, 2.0)
    om = jax.lax.stop_gradient(om)
    fv, pv = _terms(c, gk, om)
    om = jnp.clip(om - (fv - target) / jnp.maximum(2.0 * math.pi * pv, 1e-300), 0.0, 2.0)
    om = om.at[-1].set(2.0)
    xv = jnp.sqrt(jnp.sqrt(om))
    _, pv, dpv = _terms(c, gk, om, slope=True)
    # dx/dt = F_total M (1 - t^4)^(M - 1) (t / x)^3 / (2 pi p); at t = 0 its limit
    # (F_total M / (2 pi p(0)))^(1/4)
    ok = xv > 0
    ratio = jnp.where(ok, t / jnp.where(ok, xv, 1.0), 0.0)
    dxdt = jnp.where(
        ok,
        total * _M * (1.0 - t4) ** (_M - 1) * ratio**3 / (2.0 * math.pi * pv),
        jnp.sqrt(jnp.sqrt(total * _M / (2.0 * math.pi * pv))),
    )
    by_t = jnp.stack(
        _hermite_rows(xv, dxdt, 1.0 / n) + _hermite_rows(pv, dpv * 4.0 * xv**3 * dxdt, 1.0 / n),
        axis=-1,
    )
    # the density alone, for the engine's many point evaluations: a finer table read by
    # linear interpolation (two scalar gathers; a lookup's cost is the bytes it moves)
    xf = jnp.linspace(0.0, _X_MAX, PDF_NODES + 1)
    _, pf = _terms(c, gk, xf**4)
    return by_x, by_t, total, pf


def _row(rows, u):
    """The row of the interval holding u (in units of the grid step) and s in [0, 1)."""
    u = jnp.clip(u, 0.0, rows.shape[0] * (1.0 - 1e-12))
    j = jnp.floor(u).astype(jnp.int32)
    return jnp.take(rows, j, axis=0, mode="clip"), u - j


def _cubic(r, s, k):
    return ((r[..., k + 3] * s + r[..., k + 2]) * s + r[..., k + 1]) * s + r[..., k]


def _x_index(table, one_minus_mu):
    n = table[0].shape[0]
    return jnp.sqrt(jnp.sqrt(jnp.clip(one_minus_mu, 0.0, 2.0))) * (n / _X_MAX)


def mixture_pdf_and_cone_fraction(table, one_minus_mu):
    """(p, F) of a tabulated mixture at 1 - cos, from one table row."""
    omm = jnp.clip(one_minus_mu, 0.0, 2.0)
    r, s = _row(table[0], _x_index(table, omm))
    return _cubic(r, s, 4), omm * _cubic(r, s, 0)


def mixture_cone_fraction(table, one_minus_mu):
    """F(1 - cos) of a tabulated mixture."""
    return mixture_pdf_and_cone_fraction(table, one_minus_mu)[1]


def _apart(fn, table, x):
    """fn(table, x) as a computation of its own: XLA's CPU backend emits a fusion that holds
    a gather as a scalar loop, so a table lookup fused into the engine's large elementwise
    products would take all of them out of vector code (measured: half the engine's speed).
    A conditional on a value known only at run time (the table's total, positive for every
    valid parameter vector) keeps its branch out of the surrounding fusions; the other branch
    gives NaN (a NaN table would give NaN anyway)."""
    return jax.lax.cond(
        table[2] > 0,
        fn,
        lambda t, y: jax.tree.map(lambda z: jnp.full_like(z, jnp.nan), fn(t, y)),
        table,
        x,
    )


def _lerp(table, u):
    pf = table[3]
    j = jnp.floor(u).astype(jnp.int32)
    a = jnp.take(pf, j, mode="clip")
    b = jnp.take(pf, j + 1, mode="clip")
    return a + (u - j) * (b - a)


def mixture_pdf(table, one_minus_mu):
    """The tabulated mixture's density per steradian (linear in x on the fine table)."""
    n = table[3].shape[0] - 1
    u = jnp.clip(
        jnp.sqrt(jnp.sqrt(jnp.clip(one_minus_mu, 0.0, 2.0))) * (n / _X_MAX), 0.0, n * (1.0 - 1e-12)
    )
    return _apart(_lerp, table, u)  # the index in vector code, the lookup apart


def mixture_inverse_with_pdf(table, frac):
    """(1 - cos, p) at the cone holding ``frac`` of a tabulated mixture, from one row."""
    return _apart(_inverse_with_pdf, table, frac)


def _inverse_with_pdf(table, frac):
    by_t, total = table[1], table[2]
    t = _sampling_coordinate(jnp.clip(jnp.asarray(frac) / total, 0.0, 1.0))
    r, s = _row(by_t, t * by_t.shape[0])
    x = _cubic(r, s, 0)
    x2 = x * x
    return x2 * x2, _cubic(r, s, 4)


def mixture_inverse_cone_fraction(table, frac):
    """1 - cos of the cone holding ``frac`` of a tabulated mixture (the inverse table)."""
    return mixture_inverse_with_pdf(table, frac)[0]
