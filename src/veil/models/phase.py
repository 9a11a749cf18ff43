"""Henyey-Greenstein phase function (MODEL.md sec. 3): density, cone fraction and inverse.

Everything is written in terms of ``1 - cos(gamma)`` where precision matters: for g = 0.99
the lobe is half a degree wide and ``cos(gamma)`` alone loses the digits.
"""

from __future__ import annotations

import math

from .._jax import jnp

_FOUR_PI = 4.0 * math.pi


def _den(g, one_minus_mu):
    # 1 + g^2 - 2 g mu, written without cancellation near mu = 1.
    return (1.0 - g) ** 2 + 2.0 * g * one_minus_mu


def hg_pdf(g, one_minus_mu):
    """p(g, gamma) per steradian, normalized over the sphere (MODEL.md eq. for p)."""
    d = _den(g, one_minus_mu)
    return (1.0 - g * g) / (_FOUR_PI * d * jnp.sqrt(d))


def hg_cone_fraction(g, one_minus_mu):
    """Fraction of the phase function within the cone cos(gamma') >= mu (0 at mu=1, 1 at mu=-1)."""
    s = jnp.sqrt(_den(g, one_minus_mu))
    # (1-g^2)/(2g) (1/(1-g) - 1/s) = (1+g)(s-(1-g)) / (2 g s); regular at g -> 0 via the
    # identity s - (1-g) = 2 g (1-mu) / (s + 1 - g).
    return (1.0 + g) * one_minus_mu / (s * (s + 1.0 - g))


def hg_inverse_cone_fraction(g, frac):
    """``1 - cos(gamma)`` of the cone that holds ``frac`` of the phase function."""
    # s = (1 - g^2) / (1 + g - 2 g frac); 1 - mu = (s^2 - (1-g)^2) / (2g)
    #   = (s - (1-g)) (s + (1-g)) / (2g), and s - (1-g) = (1-g) * 2 g frac / (1 + g - 2 g frac).
    q = 1.0 + g - 2.0 * g * frac
    s = (1.0 - g * g) / q
    return (1.0 - g) * frac * (s + 1.0 - g) / q
