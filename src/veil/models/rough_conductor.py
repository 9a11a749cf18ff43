"""Rough conductor: metallic microfacets (docs/model.md sec. 8.3).

    f_r(I, R) = ks F_cond(R.H) D(H) G1(I, H) G1(R, H) / (4 cos theta_r)

with D, G1 and the facet law of :mod:`veil.models.rough_plastic` (Beckmann or GGX, exact
Smith masking) and the exact unpolarized Fresnel reflectance of a conductor of complex
relative index n + i k (docs/physics.md sec. 3). There is no diffuse part.

Why (n, k) and not Schlick's F0. Schlick's form F0 + (1 - F0)(1 - c)^5 has one parameter but
is an approximation that misses the dip real metals' reflectance takes before it rises to 1
at grazing incidence: with 550 nm optical constants in water it is off by up to 4 % (gold,
copper) and 9 to 22 % (aluminium, iron, chromium) between 70 and 85 deg. The complex index is
exact, is what renderers (Mitsuba's ``roughconductor`` eta and k) and tables of optical
constants give, and contains the dielectric case (k = 0: docs/model.md sec. 4). Its cost is
identifiability: with the free scale ks only the angular shape of F shows in the data, one
curve for two parameters, so n and k are strongly correlated in a fit (F0 alone would be
too, with ks, where the data stop short of grazing). Hold them at a known metal's tabulated
values (divided by the surrounding medium's index, 1.33 for water) with ``--fix`` where
possible, leaving alpha and ks to the data. F0 follows from them:
((n - 1)^2 + k^2) / ((n + 1)^2 + k^2); :func:`schlick_reflectance` is kept for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from .._lazy import jnp
from .base import BRDF, Param
from .microfacet import DISTRIBUTION_OPTION, SPECULAR_SCALE, _safe_sqrt, microfacet_lobe
from .renderers import Plugin, Value, float_value, require_ggx_for_pbrt
from .rough_plastic import MicrofacetFacets, relative_scales

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    from jax import Array


def conductor_reflectance(cos_theta, n, k):
    """Unpolarized Fresnel reflectance of a conductor of relative index n + i k at incidence
    cosine ``cos_theta`` (clipped to [0, 1]), in real arithmetic (docs/physics.md sec. 3):

        a^2 + b^2 = sqrt((n^2 - k^2 - s^2)^2 + 4 n^2 k^2),  a^2 = (a^2 + b^2 + n^2 - k^2 - s^2) / 2
        R_s = (a^2 + b^2 + c^2 - 2 a c) / (a^2 + b^2 + c^2 + 2 a c)
        R_p = R_s ((a^2 + b^2) c^2 - 2 a c s^2 + s^4) / ((a^2 + b^2) c^2 + 2 a c s^2 + s^4)

    (s^2 = 1 - c^2). Normal incidence ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2), grazing 1, and
    for k = 0 the dielectric formula of docs/model.md sec. 4 (with total reflection for n < 1)."""
    c = jnp.clip(cos_theta, 0.0, 1.0)
    c2 = c * c
    s2 = 1.0 - c2
    x = n * n - k * k - s2
    ab2 = _safe_sqrt(x * x + 4.0 * n * n * k * k)
    a = _safe_sqrt(0.5 * (ab2 + x))
    num_s = ab2 + c2 - 2.0 * a * c
    den_s = ab2 + c2 + 2.0 * a * c
    ok_s = den_s > 0
    rs = jnp.where(ok_s, num_s / jnp.where(ok_s, den_s, 1.0), 1.0)
    num_p = ab2 * c2 - 2.0 * a * c * s2 + s2 * s2
    den_p = ab2 * c2 + 2.0 * a * c * s2 + s2 * s2
    ok_p = den_p > 0
    rp = rs * jnp.where(ok_p, num_p / jnp.where(ok_p, den_p, 1.0), 1.0)
    return 0.5 * (rs + rp)


def schlick_reflectance(cos_theta, f0):
    """Schlick's approximation F0 + (1 - F0)(1 - c)^5 (the documented alternative)."""
    c = jnp.clip(cos_theta, 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def rough_conductor(v, wi, wo, distribution="beckmann"):
    """f_r(I, R) of docs/model.md sec. 8.3 at v = (alpha, n, k, ks), unit vectors wi = I, wo = R."""
    s = wi + wo
    h = s / jnp.sqrt(jnp.maximum(jnp.sum(s * s, axis=-1, keepdims=True), 1e-300))
    return RoughConductor.template(distribution=distribution)._lobe(v, wi, wo, h)


# -- renderers (veil.models.renderers, docs/interop.md) --------------------------------------
def _conductor_mitsuba(model, setting) -> Plugin:
    scale, _, ks, lost = relative_scales(
        model,
        setting,
        "ks / scale = {ks} != 1 has no physical counterpart: it becomes "
        "Mitsuba's specular_reflectance, a non-physical factor",
        diffuse=False,
    )
    if model.distribution == "beckmann":
        lost.append(
            "Mitsuba's Beckmann G1 is Walter et al.'s rational approximation (up to "
            "0.35 % per factor, 0.5 % on f_r; docs/physics.md sec. 3)"
        )
    lost.append(
        "eta and k are relative to the medium around the surface, as veil's n and k "
        "(Mitsuba's roughconductor has no exterior index)"
    )
    return Plugin(
        "bsdf",
        "roughconductor",
        (
            Value("distribution", "string", model.distribution),
            float_value("alpha", model.alpha),
            float_value("eta", model.n, colour=True),
            float_value("k", model.k, colour=True),
            float_value("specular_reflectance", ks, colour=True),
        ),
        lost=tuple(lost),
        scale=scale,
    )


def _conductor_pbrt(model, setting) -> Plugin:
    require_ggx_for_pbrt(model, RoughConductor.NAME)
    scale, _, ks, lost = relative_scales(
        model,
        setting,
        "ks / scale = {ks} is lost: pbrt's conductor has no specular factor "
        "(the render has ks / scale = 1)",
        diffuse=False,
    )
    lost.append("eta and k are relative to the medium around the surface (constant spectra)")
    return Plugin(
        "material",
        "conductor",
        (
            Value("eta", "spectrum", model.n),
            Value("k", "spectrum", model.k),
            float_value("roughness", model.alpha),
            Value("remaproughness", "boolean", False),
        ),
        lost=tuple(lost),
        scale=scale,
    )


@dataclass(frozen=True)
class RoughConductor(MicrofacetFacets, BRDF):
    """Rough conductor (alpha, n, k, ks): metallic microfacets (docs/model.md sec. 8.3).

    alpha  RMS slope of the facets (Beckmann or GGX)
    n, k   complex refractive index n + i k of the metal relative to the surrounding medium
    ks     scale of the lobe (relative units)
    distribution  "beckmann" (default) or "ggx"
    """

    alpha: float
    n: float
    k: float
    ks: float
    distribution: str = "beckmann"

    NAME = "rough-conductor"
    LABEL = "rough conductor: metallic microfacets, complex index (sec. 8.3)"
    SCALES = {"lobe": "ks"}
    PARAMS = (
        Param(
            "alpha",
            1e-3,
            1.0,
            "RMS slope of the microfacets",
            log_scale=True,
            start=0.1,
            channels="shared",
        ),
        # a metal's colour is its spectral complex index: per channel (docs/model.md 8.3)
        Param(
            "n",
            0.0,
            10.0,
            "real part of the metal's refractive index relative to the surrounding medium",
            lower_open=True,
            start=1.0,
            channels="per-channel",
        ),
        Param(
            "k",
            0.0,
            20.0,
            "imaginary part (extinction coefficient) of the relative index",
            start=3.0,
            channels="per-channel",
        ),
        SPECULAR_SCALE,
    )
    OPTIONS = (DISTRIBUTION_OPTION,)
    #: Starting grids: the roughness widely, a few metals' indices in a clear-water fit; the
    #: index barely shows through a medium, so a target fit starts at one.
    START = {
        "reference": {
            "alpha": (0.02, 0.04, 0.08, 0.15, 0.3, 0.6),
            "n": (0.3, 1.0, 2.5),
            "k": (1.5, 4.0),
        },
        "target": {
            "alpha": (0.02, 0.03, 0.05, 0.08, 0.12, 0.2, 0.3, 0.45, 0.6),
            "n": (1.0,),
            "k": (3.0,),
        },
    }
    HAS_LOBE = True
    #: The renderers' own plugins for it (veil.models.renderers).
    RENDERERS = {"mitsuba": _conductor_mitsuba, "pbrt": _conductor_pbrt}

    def _lobe(self, v, wi, wo, h):
        n, k = v[1], v[2]
        return v[3] * microfacet_lobe(
            v[0], wi, wo, h, lambda c: conductor_reflectance(c, n, k), self.distribution
        )

    # -- the split used by the integrator: no separable part (methods of the instance:
    # they read the distribution option) -----------------------------------------------
    @staticmethod
    def separable(v, cos_i, cos_r, aux=None) -> list:
        return []

    def lobe(self, v, wi, wo, h, alpha=None) -> Array:
        return self._lobe(v, wi, wo, h)
