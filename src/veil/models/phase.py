"""Henyey-Greenstein phase function (MODEL.md sec. 3): density, cone fraction and inverse.

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

from .._lazyjax import jax, jnp

_FOUR_PI = 4.0 * math.pi


def _den(g, one_minus_mu):
    # 1 + g^2 - 2 g mu, written without cancellation near mu = 1; never below its minimum
    # over mu, (1 - |g|)^2 > 0, which rounding reached for g -> -1 near mu = -1.
    return jnp.maximum((1.0 - g) ** 2 + 2.0 * g * one_minus_mu, (1.0 - jnp.abs(g)) ** 2)


def hg_pdf(g, one_minus_mu):
    """p(g, gamma) per steradian, normalized over the sphere (MODEL.md eq. for p)."""
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
# A mixture sum_k c_k p(g_k) (veil.models.forward_series) is tabulated on fine grids read by
# linear interpolation (two gathers a lookup: XLA does not vectorize gathers, so a lookup
# costs what a few closed-form phase functions cost, and the engine does many):
# - the density p and the cone fraction F on a grid uniform in x = (1 - cos)^(1/4), which
#   spreads lobes of any width over the table without a logarithm per lookup (F as a cubic
#   Hermite with its exact slopes: the engine reads it once per azimuth, not per node);
# - the inverse of F, x as a function of y = (F / F_total)^(1/4) on a uniform grid, its
#   values solved by Newton steps on the exact F and differentiable in the parameters (the
#   last step by the implicit function theorem).
# With MIXTURE_NODES intervals the interpolation error is below 1e-6 relative for g up to
# 0.995 (tests/test_models.py).
MIXTURE_NODES = 8192
_X_MAX = 2.0 ** 0.25
_H = _X_MAX / MIXTURE_NODES


def _terms(c, gk, omm):
    """F, p and dF/d(1 - cos) = 2 pi p of the mixture at ``omm`` (any shape)."""
    omm = jnp.asarray(omm)[..., None]
    f = jnp.sum(c * hg_cone_fraction(gk, omm), axis=-1)
    p = jnp.sum(c * hg_pdf(gk, omm), axis=-1)
    return f, p


def mixture_table(c, gk):
    """Tables of the mixture sum_k c_k p(g_k) (module comment): (cubic coefficients of F on
    the x grid, p on the x grid, x on the y grid, F_total)."""
    x = jnp.linspace(0.0, _X_MAX, MIXTURE_NODES + 1)
    f, p = _terms(c, gk, x ** 4)
    df = 2.0 * math.pi * p * 4.0 * x ** 3 * _H  # dF per interval of the index
    cone = (f[:-1], df[:-1], 3 * (f[1:] - f[:-1]) - 2 * df[:-1] - df[1:],
            2 * (f[:-1] - f[1:]) + df[:-1] + df[1:])
    total = f[-1]
    y = jnp.linspace(0.0, 1.0, MIXTURE_NODES + 1)
    target = total * y ** 4
    # start from linear interpolation in the F table, Newton steps on the exact F (in 1 - cos)
    fs, ts = jax.lax.stop_gradient(f), jax.lax.stop_gradient(target)
    xs = jnp.interp(ts, fs, jax.lax.stop_gradient(x))
    cs, gs = jax.lax.stop_gradient(c), jax.lax.stop_gradient(gk)
    omm = xs ** 4
    for _ in range(3):
        fv, pv = _terms(cs, gs, omm)
        omm = jnp.clip(omm - (fv - ts) / jnp.maximum(2.0 * math.pi * pv, 1e-300), 0.0, 2.0)
    omm = jax.lax.stop_gradient(omm)
    fv, pv = _terms(c, gk, omm)
    omm = jnp.clip(omm - (fv - target) / jnp.maximum(2.0 * math.pi * pv, 1e-300), 0.0, 2.0)
    return cone, p, jnp.sqrt(jnp.sqrt(omm)), total


def _lerp(values, u):
    """Linear interpolation of ``values`` (uniform grid on [0, MIXTURE_NODES]) at u."""
    u = jnp.clip(u, 0.0, MIXTURE_NODES - 1e-9)
    j = jnp.floor(u).astype(jnp.int32)
    flat = j.reshape(-1)
    a = jnp.take(values, flat, mode="clip").reshape(j.shape)
    b = jnp.take(values, flat + 1, mode="clip").reshape(j.shape)
    return a + (u - j) * (b - a)


def _x_index(one_minus_mu):
    return jnp.sqrt(jnp.sqrt(jnp.clip(one_minus_mu, 0.0, 2.0))) / _H


def mixture_cone_fraction(table, one_minus_mu):
    """F(1 - cos) of a tabulated mixture (cubic Hermite, exact slopes at the nodes)."""
    u = jnp.clip(_x_index(one_minus_mu), 0.0, MIXTURE_NODES - 1e-9)
    j = jnp.floor(u).astype(jnp.int32)
    s = u - j
    a0, a1, a2, a3 = (jnp.take(a, j.reshape(-1), mode="clip").reshape(j.shape) for a in table[0])
    return ((a3 * s + a2) * s + a1) * s + a0


def mixture_pdf(table, one_minus_mu):
    """The tabulated mixture's density per steradian."""
    return _lerp(table[1], _x_index(one_minus_mu))


def mixture_inverse_cone_fraction(table, frac):
    """1 - cos of the cone holding ``frac`` of a tabulated mixture (the inverse table)."""
    _, _, x_of_y, total = table
    y = jnp.sqrt(jnp.sqrt(jnp.clip(jnp.asarray(frac) / total, 0.0, 1.0)))
    return _lerp(x_of_y, y * MIXTURE_NODES) ** 4
