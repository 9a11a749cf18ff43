"""The microfacet pieces of the rough BRDFs (:mod:`veil.models.rough_plastic`,
:mod:`veil.models.rough_conductor`; docs/model.md sec. 8.2-8.3): Beckmann's and GGX's
distributions of facet normals with RMS slope alpha, Smith's exact masking G1 for each, the
facet law the integrator samples and the specular lobe."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from .._lazy import jnp
from ..errors import ParameterError
from .base import Option, Param

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    pass

DISTRIBUTIONS = ("beckmann", "ggx")
#: The microfacet families' specular scale and their distribution option, declared once.
SPECULAR_SCALE = Param(
    "ks",
    0.0,
    math.inf,
    "specular scale, relative units (scale of the lobe)",
    log_scale=True,
    start=1.0,
    channels="per-channel",
)
DISTRIBUTION_OPTION = Option(
    "distribution", "beckmann", "microfacet distribution: beckmann or ggx", DISTRIBUTIONS
)
HALF_PI = 0.5 * math.pi
SQRT_PI = math.sqrt(math.pi)
#: Beckmann's D is set to 0 where tan^2 theta_H / alpha^2 > 200 (exp(-200) = 1.4e-87 of its
#: peak): the tail's values would make subnormal numbers in the engine's products, which the
#: CPU computes about twice as slowly (measured: 576 -> 820 configurations per second).
BECKMANN_CUT = 200.0

# --------------------------------------------------------------------------------------
# microfacet pieces (shared with rough_conductor)
# --------------------------------------------------------------------------------------


def _safe_sqrt(x):
    """sqrt(max(x, 0)) with a finite derivative at 0 (taken as 0 there)."""
    pos = x > 0.0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _safe_div(a, b, fallback):
    """a / b where b > 0, ``fallback`` elsewhere; finite derivatives on both sides."""
    pos = b > 0.0
    return jnp.where(pos, a / jnp.where(pos, b, 1.0), fallback)


def smith_g1(wz, wxy2, alpha, distribution="beckmann"):
    """Smith's exact masking G1 of a direction with |cos theta| = ``wz`` >= 0 and
    sin^2 theta = ``wxy2``, for a facet it sees the front of (the caller checks the side).

    Beckmann: G1 = 2 / (1 + erf(a) + exp(-a^2) / (a sqrt(pi))), a = 1 / (alpha tan theta)
    (exactly 1 for a >= 8, where 1 - G1 < 1e-28); GGX: G1 = 2 / (1 + sqrt(1 + alpha^2
    tan^2 theta)). Zero at grazing (wz = 0) up to 4e-30.
    """
    if distribution == "ggx":
        # 2 / (1 + sqrt(1 + alpha^2 tan^2)) multiplied through by cos theta: finite at wz = 0
        den = wz + jnp.sqrt(wz * wz + alpha * alpha * wxy2)
        ok = den > 0
        return jnp.where(ok, 2.0 * wz / jnp.where(ok, den, 1.0), 1.0)
    from jax.scipy.special import erfc

    from .._jax import jax as _  # noqa: F401 - JAX set up by veil before its submodule

    s = alpha * _safe_sqrt(wxy2)  # alpha sin theta
    # a = cos / (alpha sin), held at 8 (1 - G1 < 1e-28 beyond: G1 = 1 exactly, also at the
    # normal) and at 1e-30 (G1 = 2 sqrt(pi) a to double precision, finite derivatives)
    a = jnp.maximum(wz / jnp.maximum(s, 0.125 * wz), 1e-30)
    # 1 + erf(a) as 2 - erfc(a): the same value, and XLA's erfc is 4x faster on [0, 8]
    return 2.0 / (2.0 - erfc(a) + jnp.exp(-a * a) / (a * SQRT_PI))


def ndf(hz, hxy2, alpha, distribution="beckmann"):
    """D(H) per steradian of facet normals at cos theta_H = ``hz``, sin^2 theta_H = ``hxy2``
    (docs/model.md sec. 8.2); zero for hz <= 0."""
    ok = hz > 0
    hz = jnp.where(ok, hz, 1.0)
    a2 = alpha * alpha
    if distribution == "ggx":
        # 1 / (pi a^2 cos^4 (1 + tan^2 / a^2)^2) = a^2 / (pi (a^2 cos^2 + sin^2)^2)
        d = a2 / (math.pi * (a2 * hz * hz + hxy2) ** 2)
    else:
        h2 = hz * hz
        x = hxy2 / (a2 * h2)  # tan^2 / alpha^2
        ok = ok & (x < BECKMANN_CUT)
        d = jnp.exp(-jnp.where(ok, x, 0.0)) / (math.pi * a2 * h2 * h2)
    return jnp.where(ok, d, 0.0)


def facet_cdf(alpha, theta, distribution="beckmann"):
    """The cumulative of H distributed as D(H) cos theta_H in its polar angle ``theta``:
    Beckmann 1 - exp(-tan^2 / alpha^2), GGX tan^2 / (alpha^2 + tan^2); 1 at pi/2."""
    s, c = jnp.sin(theta), jnp.cos(theta)
    if distribution == "ggx":
        return s * s / (alpha * alpha * c * c + s * s)
    c = jnp.maximum(c, 1e-150)
    return -jnp.expm1(-jnp.minimum((s / (alpha * c)) ** 2, 1e4))


def facet_inverse_cdf(alpha, y, distribution="beckmann"):
    """The polar angle where :func:`facet_cdf` reaches ``y`` in [0, 1]."""
    inside = y < 1.0
    ys = jnp.where(inside, jnp.clip(y, 0.0, 1.0), 0.5)
    if distribution == "ggx":
        theta = jnp.arctan2(alpha * jnp.sqrt(ys), jnp.sqrt(1.0 - ys))
    else:
        theta = jnp.arctan(alpha * _safe_sqrt(-jnp.log1p(-ys)))
    return jnp.where(inside, theta, HALF_PI)


def facet_weight(alpha, theta, sin_theta=None, distribution="beckmann"):
    """D(H) cos theta_H = d facet_cdf / d theta / (2 pi sin theta)."""
    s = jnp.sin(theta) if sin_theta is None else sin_theta
    # cos from sin: no second transcendental call (the engine passes sin); exact enough
    # where the weight matters (relative error of cos ~1e-16 / cos^2)
    c = jnp.cos(theta) if sin_theta is None else _safe_sqrt(1.0 - s * s)
    a2 = alpha * alpha
    if distribution == "ggx":
        return a2 * c / (math.pi * (a2 * c * c + s * s) ** 2)
    x = s * s / (a2 * jnp.maximum(c * c, 1e-200))  # tan^2 / alpha^2 (a _safe_div here
    near = x < BECKMANN_CUT  # makes the engine 30 % slower)
    cs = jnp.where(near, c, 1.0)
    return jnp.where(near, jnp.exp(-jnp.where(near, x, 0.0)) / (math.pi * a2 * cs * cs * cs), 0.0)


def microfacet_lobe(alpha, wi, wo, h, reflectance, distribution="beckmann"):
    """reflectance(R.H) D(H) G1(I, H) G1(R, H) / (4 cos theta_r) at unit vectors wi = I,
    wo = R (..., 3) with half vector h; zero unless both are above the surface."""
    ci, co = wi[..., 2], wo[..., 2]
    hz = h[..., 2]
    c = wo[..., 0] * h[..., 0] + wo[..., 1] * h[..., 1] + wo[..., 2] * h[..., 2]
    ok = (ci > 0) & (co > 0) & (hz > 0) & (c > 0)
    ci_s, co_s = jnp.where(ok, ci, 1.0), jnp.where(ok, co, 1.0)
    g = smith_g1(ci_s, wi[..., 0] ** 2 + wi[..., 1] ** 2, alpha, distribution) * smith_g1(
        co_s, wo[..., 0] ** 2 + wo[..., 1] ** 2, alpha, distribution
    )
    d = ndf(hz, h[..., 0] ** 2 + h[..., 1] ** 2, alpha, distribution)
    f = reflectance(jnp.where(ok, c, 1.0))
    return jnp.where(ok, f * d * g / (4.0 * co_s), 0.0)


def check_distribution(distribution) -> None:
    if distribution not in DISTRIBUTIONS:
        raise ParameterError(
            f"distribution = {distribution!r}; expected one of {', '.join(DISTRIBUTIONS)}"
        )
