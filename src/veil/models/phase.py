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

from .._jax import jnp

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
