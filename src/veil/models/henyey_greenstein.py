"""The paper's medium: isotropic multiple scattering plus Henyey-Greenstein single scattering
seen through Fresnel transmittance at the medium's faces (docs/model.md sec. 3, paper eq. 2-4)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from . import fresnel, phase
from .base import Medium, Option, Param
from .renderers import Unsupported

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    from jax import Array

VARIANTS = ("paper", "exit")


def _no_renderer(model, setting):
    raise Unsupported(
        f"the paper's medium ({HenyeyGreenstein.NAME}) has no counterpart in a renderer: its "
        f"f_t = Td + Tt p(g) has no unscattered beam and its Td, Tt are relative units, not "
        f"an extinction coefficient and an albedo, so no homogeneous medium reproduces it. "
        f"Fit the physical medium to the same data instead (veil fit medium "
        f"--medium-model forward-series ...) and export that"
    )


@dataclass(frozen=True)
class HenyeyGreenstein(Medium):
    """BTDF (T_d, T_t, g, eta): f_t = T_d + T_t p(g, gamma) x Fresnel transmittances.

    Td       isotropic (multiple scattering) coefficient, relative units
    Tt       single-scattering coefficient, relative units
    g        Henyey-Greenstein asymmetry, in (-1, 1); near 1 is a narrow forward lobe
    eta      relative refractive index of the medium's faces
    variant  "paper": F_t(theta_I)^2 (docs/model.md decision 3, the default);
             "exit": F_t(theta_I) F_t(theta_T), reciprocal.
    """

    Td: float
    Tt: float
    g: float
    eta: float
    variant: str = "paper"

    NAME = "henyey-greenstein"
    LABEL = "the paper's medium: isotropic + Henyey-Greenstein single scattering (sec. 3)"
    SCALES = {"iso": "Td", "lobe": "Tt"}
    PARAMS = (
        Param(
            "Td",
            0.0,
            math.inf,
            "isotropic multiple-scattering coefficient, relative units",
            log_scale=True,
            start=1e-3,
            channels="per-channel",
        ),
        Param(
            "Tt",
            0.0,
            math.inf,
            "single-scattering coefficient, relative units",
            log_scale=True,
            start=0.1,
            channels="per-channel",
        ),
        Param(
            "g",
            -1.0,
            1.0,
            "Henyey-Greenstein asymmetry parameter",
            lower_open=True,
            upper_open=True,
            start=0.9,
            share="per-medium",
            error_scale="bound",
            channels="shared",
        ),
        Param(
            "eta",
            0.0,
            10.0,
            "relative refractive index of the medium",
            lower_open=True,
            start=1.33,
            alias="eta_u",
            share="shared",
            channels="shared",
        ),
    )
    OPTIONS = (
        Option(
            "variant",
            "paper",
            "Fresnel factor: paper = F_t(theta_in)^2, exit = "
            "F_t(theta_in) F_t(theta_out) (docs/model.md sec. 3)",
            VARIANTS,
        ),
    )
    #: Starting grid of a medium fit (step 1): g from broad to narrow lobes, water's index.
    START = {"medium": {"g": (0.5, 0.7, 0.8, 0.88, 0.93, 0.96, 0.98, 0.99, 0.995), "eta": (1.33,)}}
    #: No renderer has this medium (veil.models.renderers): a clear refusal for each.
    RENDERERS = {"mitsuba": _no_renderer, "pbrt": _no_renderer}

    @staticmethod
    def iso(v) -> Array:
        return v[0]

    @staticmethod
    def lobe_weight(v) -> Array:
        return v[1]

    def factor_first(self, v, cos_a) -> Array:
        return fresnel.boundary_first(cos_a, v[3], self.variant)

    def factor_second(self, v, cos_b) -> Array:
        return fresnel.boundary_second(cos_b, v[3], self.variant)

    @staticmethod
    def phase(v, one_minus_mu, aux=None) -> Array:
        return phase.hg_pdf(v[2], one_minus_mu)

    @staticmethod
    def phase_cone_fraction(v, one_minus_mu, aux=None) -> Array:
        return phase.hg_cone_fraction(v[2], one_minus_mu)

    @staticmethod
    def phase_inverse_cone_fraction(v, frac, aux=None) -> Array:
        return phase.hg_inverse_cone_fraction(v[2], frac)
