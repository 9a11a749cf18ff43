"""Torrance-Sparrow reflection, the paper's surface model (docs/model.md sec. 2).

f_r = P_d cos(theta_i) + P_s F(theta_i', eta) G(I, R) exp(-(n alpha_deg)^2) / cos(theta_r),
with alpha in degrees (docs/model.md decision 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from .._lazy import jnp
from . import fresnel
from .base import BRDF, Param, geometric_grid

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    from jax import Array

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
    LABEL = "Torrance-Sparrow, the paper's surface (docs/model.md sec. 2)"
    SCALES = {"separable": "Pd", "lobe": "Ps"}
    PARAMS = (
        Param(
            "Pd",
            0.0,
            math.inf,
            "diffuse coefficient, relative units",
            log_scale=True,
            start=1.0,
            channels="per-channel",
        ),
        Param(
            "Ps",
            0.0,
            math.inf,
            "specular coefficient, relative units",
            log_scale=True,
            start=1.0,
            channels="per-channel",
        ),
        Param(
            "n",
            0.0,
            50.0,
            "smoothness, 1/deg in exp(-(n alpha_deg)^2)",
            unit="1/deg",
            lower_open=True,
            log_scale=True,
            start=0.5,
            channels="shared",
        ),
        Param(
            "eta",
            0.0,
            10.0,
            "relative refractive index of the surface",
            lower_open=True,
            start=1.5,
            channels="shared",
        ),
    )
    #: Starting grids: a clear-water fit (step 0) searches n widely and three indices; a
    #: fit through a medium (step 2) searches n only (the index barely shows there).
    START = {
        "reference": {"n": geometric_grid(0.03, 5.0, 16), "eta": (1.2, 1.5, 2.0)},
        "target": {"n": (0.08, 0.13, 0.2, 0.3, 0.45, 0.65, 0.9, 1.3, 2.0), "eta": (1.5,)},
    }
    #: No renderer has the V-groove Torrance-Sparrow model: the exporter fits this family to
    #: it and exports that, with the RMS difference (veil.models.renderers).
    #: (pbrt-v4 has only GGX microfacets.)
    PROXIES = {"mitsuba": ("rough-plastic", {}), "pbrt": ("rough-plastic", {"distribution": "ggx"})}

    # -- the split used by the integrator ------------------------------------------------
    @staticmethod
    def separable(v, cos_i, cos_r, aux=None) -> list:
        return [(v[0] * jnp.maximum(cos_i, 0.0), jnp.ones_like(cos_r))]

    @staticmethod
    def lobe(v, wi, wo, h, alpha=None) -> Array:
        ps, n, eta = v[1], v[2], v[3]
        ci, co = wi[..., 2], wo[..., 2]
        hz = h[..., 2]
        # cos theta_i'
        ch = wi[..., 0] * h[..., 0] + wi[..., 1] * h[..., 1] + wi[..., 2] * h[..., 2]
        if alpha is None:
            s2 = h[..., 0] ** 2 + h[..., 1] ** 2
            alpha = jnp.where(s2 > 0, jnp.arctan2(jnp.sqrt(jnp.where(s2 > 0, s2, 1.0)), hz), 0.0)
        d = jnp.exp(-((n * DEG * alpha) ** 2))
        ok = (ci > 0) & (co > 0) & (ch > 0)
        ch_s = jnp.where(ok, ch, 1.0)
        co_s = jnp.where(ok, co, 1.0)
        g = jnp.minimum(1.0, 2.0 * hz * jnp.minimum(co, ci) / ch_s)
        f = fresnel.reflectance(ch_s, eta)
        return jnp.where(ok, ps * f * g * d / co_s, 0.0)

    # -- the facet (half-vector) distribution in alpha, for the integrator's maps ---------
    # cumulative  C(alpha) = 1 - exp(-(c alpha)^2),  c = n * 180/pi
    # weight      dC/dalpha / (2 pi sin alpha): density per steradian of H, in C's units
    @staticmethod
    def facet_cdf(v, alpha) -> Array:
        c = v[2] * DEG
        return -jnp.expm1(-((c * alpha) ** 2))

    @staticmethod
    def facet_inverse_cdf(v, y) -> Array:
        c = v[2] * DEG
        return jnp.sqrt(-jnp.log1p(-y)) / c

    @staticmethod
    def facet_weight(v, alpha, sin_alpha=None) -> Array:
        c = v[2] * DEG
        if sin_alpha is None:
            sin_alpha = jnp.sin(alpha)
        big = alpha > 1e-6
        ratio = jnp.where(big, alpha / jnp.where(big, sin_alpha, 1.0), 1.0 + alpha * alpha / 6.0)
        return c * c * ratio * jnp.exp(-((c * alpha) ** 2)) / math.pi
