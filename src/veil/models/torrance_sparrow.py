"""Torrance-Sparrow reflection, the paper's surface model (MODEL.md sec. 2).

f_r = P_d cos(theta_i) + P_s F(theta_i', eta) G(I, R) exp(-(n alpha_deg)^2) / cos(theta_r),
with alpha in degrees (MODEL.md decision 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .._jax import jnp
from .. import fresnel
from .base import BRDF, Param

DEG = 180.0 / math.pi
HALF_PI = 0.5 * math.pi


@dataclass(frozen=True)
class TorranceSparrow(BRDF):
    """Torrance-Sparrow BRDF (P_d, P_s, n, eta): diffuse + specular V-groove microfacets.

    Pd, Ps   diffuse and specular coefficients (products with the source intensity; relative)
    n        surface smoothness: facet slopes ~ exp(-(n alpha_deg)^2); larger is smoother
    eta      relative refractive index of the surface (Fresnel factor of the facets)
    """

    Pd: float
    Ps: float
    n: float
    eta: float

    NAME = "torrance-sparrow"
    PARAMS = (
        Param("Pd", 0.0, math.inf, "diffuse coefficient, relative units", log_scale=True),
        Param("Ps", 0.0, math.inf, "specular coefficient, relative units", log_scale=True),
        Param("n", 0.0, 50.0, "smoothness, 1/deg in exp(-(n alpha_deg)^2)", unit="1/deg",
              lower_open=True, log_scale=True),
        Param("eta", 0.0, 10.0, "relative refractive index of the surface", lower_open=True),
    )

    # -- the split used by the integrator ------------------------------------------------
    @staticmethod
    def separable(v, cos_i, cos_r):
        return [(v[0] * jnp.maximum(cos_i, 0.0), jnp.ones_like(cos_r))]

    @staticmethod
    def lobe(v, wi, wo, h):
        ps, n, eta = v[1], v[2], v[3]
        ci, co = wi[..., 2], wo[..., 2]
        hz = h[..., 2]
        ch = jnp.sum(wi * h, axis=-1)  # cos(theta_i'), the facet incidence angle
        alpha = jnp.arctan2(jnp.sqrt(h[..., 0] ** 2 + h[..., 1] ** 2), hz)
        d = jnp.exp(-(n * DEG * alpha) ** 2)
        ok = (ci > 0) & (co > 0) & (ch > 0)
        ch_s = jnp.where(ok, ch, 1.0)
        co_s = jnp.where(ok, co, 1.0)
        g = jnp.minimum(1.0, jnp.minimum(2.0 * hz * co / ch_s, 2.0 * hz * ci / ch_s))
        f = fresnel.reflectance(ch_s, eta)
        return jnp.where(ok, ps * f * g * d / co_s, 0.0)

    # -- the half-vector map: alpha with density ~ alpha exp(-(c alpha)^2) on [0, pi/2] ----
    @staticmethod
    def _c_and_norm(v):
        c = v[2] * DEG
        z = -jnp.expm1(-(c * HALF_PI) ** 2)
        return c, z

    @classmethod
    def half_vector_map(cls, v, u1, u2):
        c, z = cls._c_and_norm(v)
        alpha = jnp.sqrt(-jnp.log1p(-u1 * z)) / c
        phi = 2.0 * math.pi * u2
        sa = jnp.sin(alpha)
        return jnp.stack([sa * jnp.cos(phi), sa * jnp.sin(phi), jnp.cos(alpha)], axis=-1)

    @classmethod
    def half_vector_density(cls, v, h):
        c, z = cls._c_and_norm(v)
        sa = jnp.sqrt(h[..., 0] ** 2 + h[..., 1] ** 2)
        alpha = jnp.arctan2(sa, h[..., 2])
        # alpha / sin(alpha) -> 1 at alpha = 0
        ratio = jnp.where(alpha > 1e-8, alpha / jnp.where(alpha > 1e-8, sa, 1.0), 1.0)
        dens = c * c * ratio * jnp.exp(-(c * alpha) ** 2) / (math.pi * z)
        return jnp.where((h[..., 2] > 0) & (alpha <= HALF_PI), dens, 0.0)
