"""Two model families registered only in the tests, to prove the registry: everything veil
does with a model - the engine, the three fits, the joint fit, the diagnostics, result
files and the command line - must work for them from their declarations alone.

- ``lambertian-test``: a Lambertian surface, f_r = rho cos(theta_i) / pi (no lobe);
- ``fisher-test``: a medium whose single scattering has a von Mises-Fisher lobe,
  f_t = Td + Tt p(kappa, gamma), p = kappa exp(-kappa (1 - cos gamma)) / (2 pi (1 - e^-2kappa)),
  and no boundary (no Fresnel factors).

Imported by the tests directly or through ``VEIL_PLUGINS=veil_test_models`` (with this
folder on PYTHONPATH) for the command line in a subprocess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from veil._jax import jnp
from veil.models import BRDF, Medium, Param, register


@register
@dataclass(frozen=True)
class LambertianTest(BRDF):
    """f_r = rho cos(theta_i) / pi."""

    rho: float

    NAME = "lambertian-test"
    LABEL = "Lambertian surface (test-only model)"
    HAS_LOBE = False
    SCALES = {"separable": "rho"}
    PARAMS = (Param("rho", 0.0, math.inf, "albedo, relative units", log_scale=True, start=1.0,
                    channels="per-channel"),)

    @staticmethod
    def separable(v, cos_i, cos_r, aux=None):
        return [(v[0] * jnp.maximum(cos_i, 0.0) / math.pi, jnp.ones_like(cos_r))]


@register
@dataclass(frozen=True)
class FisherTest(Medium):
    """f_t = Td + Tt p(kappa), a von Mises-Fisher lobe, no Fresnel factors."""

    Td: float
    Tt: float
    kappa: float

    NAME = "fisher-test"
    LABEL = "isotropic + von Mises-Fisher single scattering (test-only model)"
    SCALES = {"iso": "Td", "lobe": "Tt"}
    PARAMS = (
        Param("Td", 0.0, math.inf, "isotropic coefficient", log_scale=True, start=1e-3,
              channels="per-channel"),
        Param("Tt", 0.0, math.inf, "lobe coefficient", log_scale=True, start=0.1,
              channels="per-channel"),
        Param("kappa", 0.5, 1e5, "concentration of the lobe", log_scale=True, start=100.0,
              share="per-medium", channels="shared"),
    )
    START = {"medium": {"kappa": (10.0, 30.0, 100.0, 300.0, 1000.0, 3000.0)}}

    @staticmethod
    def iso(v):
        return v[0]

    @staticmethod
    def lobe_weight(v):
        return v[1]

    def factor_first(self, v, cos_a):
        return 1.0 + 0.0 * cos_a

    def factor_second(self, v, cos_b):
        return 1.0 + 0.0 * cos_b

    @staticmethod
    def phase(v, one_minus_mu, aux=None):
        k = v[2]
        return k * jnp.exp(-k * one_minus_mu) / (2.0 * math.pi * -jnp.expm1(-2.0 * k))

    @staticmethod
    def phase_cone_fraction(v, one_minus_mu, aux=None):
        k = v[2]
        return jnp.expm1(-k * one_minus_mu) / jnp.expm1(-2.0 * k)

    @staticmethod
    def phase_inverse_cone_fraction(v, frac, aux=None):
        k = v[2]
        return -jnp.log1p(frac * jnp.expm1(-2.0 * k)) / k
