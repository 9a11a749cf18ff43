"""Rough plastic: a dielectric microfacet interface over a Lambertian base (docs/model.md sec. 8.2).

    f_r(I, R) = ks F(R.H, eta) D(H) G1(I, H) G1(R, H) / (4 cos theta_r)
              + rho_eff t(cos theta_i) t(cos theta_r) cos theta_i / (pi eta^2)

D is Beckmann's or GGX's distribution of facet normals with RMS slope alpha, G1 Smith's exact
masking for it, F the dielectric Fresnel reflectance of docs/model.md sec. 4 at the relative index
eta (plastic over the surrounding medium: about 1.12 for a plastic in water). t(mu) is the
rough interface's directional transmittance from outside as Mitsuba >= 3 defines it (the
integral over visible normals of (1 - F) G1 of the refracted direction; docs/physics.md sec. 2)
and F_int the cosine-weighted hemispherical reflectance of the interface from inside (relative
index 1/eta, total internal reflection, G1 of the reflected ray),
rho_eff = rho / (1 - F_int) (docs/rough_plastic.md).

t and F_int depend on (alpha, eta) only. :meth:`RoughPlastic.prepare` computes them once per
engine call by a fixed quadrature written in jax.numpy (differentiable, so that fits get exact
Jacobians): t at 48 polar angles whose spacing follows alpha near grazing incidence, read back
by a C2 cubic spline, and F_int as one 3-D integral in the frame of the facet normal. Both are
within 1e-4 of the converged integrals (tests/test_rough_plastic.py).

The microfacet pieces (distributions, Smith G1, the facet law the integrator samples, the
specular lobe) are :mod:`veil.models.microfacet`, shared with
:mod:`veil.models.rough_conductor`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

from .._lazy import jnp, np
from ..errors import ParameterError
from . import fresnel
from .base import BRDF, Option, Param, geometric_grid
from .microfacet import (
    DISTRIBUTION_OPTION,
    HALF_PI,
    SPECULAR_SCALE,
    _safe_div,
    _safe_sqrt,
    check_distribution,
    facet_cdf,
    facet_inverse_cdf,
    facet_weight,
    microfacet_lobe,
    smith_g1,
)
from .renderers import (
    Plugin,
    Value,
    float_value,
    intensity_scale,
    require_ggx_for_pbrt,
)

if TYPE_CHECKING:  # the types only: models import JAX and numpy on first use (veil._lazy)
    from jax import Array
    from numpy import ndarray

# --------------------------------------------------------------------------------------
# the rough interface: t(mu) and F_int by fixed quadrature (docs/rough_plastic.md)
# --------------------------------------------------------------------------------------
#: Polar angles of the t(mu) table: elevation gamma = pi/2 - theta at gamma_j =
#: alpha sinh(x_j asinh(pi / (2 alpha))), x_j uniform: spacing ~alpha near grazing, where t
#: changes on the scale of alpha, and uniform in theta near the normal, where t has a
#: |theta|^3 term (GGX) that a spline in cos theta would not follow.
TABLE_NODES = 48
#: Gauss nodes per radial piece and on the visible arc of the t(mu) integrals.
T_RADIAL, T_AZIMUTH = 16, 8
#: Gauss nodes of the F_int integral: facet slope, angle from the facet normal, azimuth.
F_RADIAL, F_POLAR, F_AZIMUTH = 12, 12, 12
#: Beckmann slopes beyond 6.5 alpha carry exp(-42) of the facets: the integrals stop there.
BECKMANN_END = 6.5


@cache
def _gauss(n: int, smooth: bool = False):
    """Gauss-Legendre nodes and weights on [0, 1]; ``smooth``: through s = 3t^2 - 2t^3, which
    turns square-root end behaviour into a smooth one."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    if smooth:
        x, w = 3 * x * x - 2 * x**3, w * 6 * x * (1 - x)
    return x, w


@cache
def _spline_matrix(n: int) -> ndarray:
    """Second derivatives of the not-a-knot cubic spline through values at 0..n-1 (unit
    spacing), as a matrix applied to the values."""
    a = np.zeros((n, n))
    b = np.zeros((n, n))
    for i in range(1, n - 1):
        a[i, i - 1 : i + 2] = (1.0, 4.0, 1.0)
        b[i, i - 1 : i + 2] = (6.0, -12.0, 6.0)
    a[0, :3] = (1.0, -2.0, 1.0)  # not-a-knot: the third derivative is continuous at
    a[-1, -3:] = (1.0, -2.0, 1.0)  # the second and the last but one knot
    return np.linalg.solve(a, b)


def _pieces(breaks, x, w):
    """Nodes and weights of one rule (x, w on [0, 1]) on each piece between consecutive
    ``breaks`` (arrays of one shape S), concatenated on a new last axis: (S..., P n)."""
    nodes = [lo[..., None] + (hi - lo)[..., None] * x for lo, hi in zip(breaks[:-1], breaks[1:])]
    weights = [(hi - lo)[..., None] * w for lo, hi in zip(breaks[:-1], breaks[1:])]
    return jnp.concatenate(nodes, axis=-1), jnp.concatenate(weights, axis=-1)


def _slopes(alpha, cot_theta, distribution, n, tail_break):
    """Facet slopes r = tan theta_m (shape (K, N)) and weights of the slope law's cumulative
    u (dN = du dphi / 2 pi), split where r = ``cot_theta`` (K,) and, for GGX, at
    r = ``tail_break`` (its heavy tail changes on that scale)."""
    zero = jnp.zeros_like(cot_theta)
    if distribution == "ggx":  # beta = atan(r / alpha), u = sin^2 beta
        x, w = _gauss(n, smooth=True)
        bc = jnp.arctan(cot_theta / alpha)
        bt = jnp.arctan(tail_break / alpha) + zero
        beta, wb = _pieces([zero, jnp.minimum(bc, bt), jnp.maximum(bc, bt), zero + HALF_PI], x, w)
        beta = jnp.minimum(beta, HALF_PI - 1e-12)
        return alpha * jnp.tan(beta), wb * jnp.sin(2.0 * beta)
    x, w = _gauss(n)  # rho = r / alpha, u = 1 - exp(-rho^2)
    rc = jnp.minimum(cot_theta / alpha, BECKMANN_END)
    rho, wr = _pieces([zero, rc, zero + BECKMANN_END], x, w)
    return alpha * rho, wr * 2.0 * rho * jnp.exp(-rho * rho)


def transmittance_at(
    alpha, eta, mu, distribution="beckmann", n_radial=T_RADIAL, n_azimuth=T_AZIMUTH
):
    """t(mu) for an array of incidence cosines ``mu`` (K,) in [0, 1], by quadrature over the
    visible normals in slope space (s = r (cos phi, sin phi); (v.m)^+ D(m) dm =
    (cos theta - r sin theta cos phi)^+ dN): r split where the visibility cut enters, phi
    over the visible arc; normalized by the same rule's integral of D_v (exactly 1 with the
    exact G1), which also makes grazing incidence (mu = 0) finite."""
    ct = jnp.clip(mu, 0.0, 1.0)
    st = _safe_sqrt(1.0 - ct * ct)
    cot = jnp.minimum(_safe_div(ct, st, 1e150), 1e150)
    r, wr = _slopes(alpha, cot, distribution, n_radial, 1.0)  # (K, N)
    y, wy = _gauss(n_azimuth)
    k = _safe_div(ct[:, None], st[:, None] * r, 2.0)  # cos phi_c
    cut = k < 1.0
    phic = jnp.where(cut, jnp.arccos(jnp.where(cut, k, 0.0)), 0.0)  # visible: phi > phi_c
    span = math.pi - phic
    phi = phic[..., None] + span[..., None] * y  # (K, N, A)
    wphi = span[..., None] * wy
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    rr = r[..., None]
    stt, ctt = st[:, None, None], ct[:, None, None]
    proj = jnp.maximum(ctt - rr * stt * cp, 0.0)  # (v.m) / cos theta_m
    inv_norm = 1.0 / jnp.sqrt(1.0 + rr * rr)  # cos theta_m
    c = proj * inv_norm  # v.m
    f = fresnel.reflectance(c, eta)
    cos_t = jnp.sqrt(jnp.maximum(1.0 - (1.0 - c * c) / (eta * eta), 0.0))
    kk = c / eta - cos_t  # w_t = -v / eta + kk m
    mx, my, mz = -rr * cp * inv_norm, -rr * sp * inv_norm, inv_norm
    wtx = -stt / eta + kk * mx
    wty = kk * my
    wtz = -ctt / eta + kk * mz
    below = wtz < 0.0  # the refracted ray goes down
    g = smith_g1(jnp.where(below, -wtz, 0.0), wtx * wtx + wty * wty, alpha, distribution)
    h = jnp.where(below, (1.0 - f) * g, 0.0)
    weight = wr[..., None] * wphi * proj
    return jnp.sum(weight * h, axis=(1, 2)) / jnp.sum(weight, axis=(1, 2))


def internal_reflectance(
    alpha, eta, distribution="beckmann", n_radial=F_RADIAL, n_polar=F_POLAR, n_azimuth=F_AZIMUTH
):
    """F_int = 2 Int_0^1 mu R(mu; 1/eta) dmu: the cosine-weighted hemispherical reflectance of
    the rough interface seen from inside (Fresnel at 1/eta with total internal reflection,
    Smith G1 of both rays). Integrated in the frame of the facet normal m,

        F_int = (1/pi) Int D(m) dm Int (v.m) F(v.m) G1(v) G1(w_r) [v, w_r above] dv,

    v at angle chi from m and azimuth psi about it, so that total internal reflection is the
    cut chi = asin(1/eta) and the horizons are |cos psi| < cot chi cot theta_m."""
    inv = 1.0 / eta
    chi_c = jnp.arcsin(inv)
    cot_c = jnp.sqrt(eta * eta - 1.0)  # tan(pi/2 - chi_c)
    if distribution == "ggx":
        x, w = _gauss(n_radial)
        bb = jnp.arctan(cot_c / alpha)
        beta, wm = _pieces([jnp.zeros(()), bb, jnp.asarray(HALF_PI)], x, w)
        beta = jnp.minimum(beta, HALF_PI - 1e-12)
        tm = alpha * jnp.tan(beta)
        wm = wm * jnp.sin(2.0 * beta)
    else:
        x, w = _gauss(n_radial)
        rb = jnp.minimum(cot_c / alpha, BECKMANN_END)
        rho, wm = _pieces([jnp.zeros(()), rb, jnp.asarray(BECKMANN_END)], x, w)
        tm = alpha * rho
        wm = wm * 2.0 * rho * jnp.exp(-rho * rho)
    cm = 1.0 / jnp.sqrt(1.0 + tm * tm)
    sm = tm * cm
    wm = wm / cm  # D(m) dm = du dphi_m / (2 pi cos theta_m)
    chi_k = HALF_PI - jnp.arctan(tm)  # where the horizons start to cut
    lo, hi = jnp.minimum(chi_c, chi_k), jnp.maximum(chi_c, chi_k)
    zero = jnp.zeros_like(chi_k)
    xc, wc = _gauss(n_polar, smooth=True)
    chi, wchi = _pieces([zero, lo, hi, zero + HALF_PI], xc, wc)  # (M, 3 n)
    cchi, schi = jnp.cos(chi), jnp.sin(chi)
    wchi = wchi * schi * cchi * fresnel.reflectance(cchi, inv)
    kk = _safe_div(cchi * cm[:, None], schi * sm[:, None], 2.0)  # cot chi cot theta_m
    cut = kk < 1.0
    psi0 = jnp.where(cut, jnp.arccos(jnp.where(cut, kk, 0.0)), 0.0)
    xp, wp = _gauss(n_azimuth)
    span = HALF_PI - psi0
    psi = psi0[..., None] + span[..., None] * xp
    wpsi = 4.0 * span[..., None] * wp  # four symmetric quarters of the circle
    a = (cchi * cm[:, None])[..., None]
    b = (schi * sm[:, None])[..., None]
    cps = jnp.cos(psi)
    vz = jnp.clip(a - b * cps, 0.0, 1.0)
    wz = jnp.clip(a + b * cps, 0.0, 1.0)
    g = smith_g1(vz, 1.0 - vz * vz, alpha, distribution) * smith_g1(
        wz, 1.0 - wz * wz, alpha, distribution
    )
    inner = jnp.sum(wpsi * g, axis=-1)
    return jnp.sum(wm[:, None] * wchi * inner) / math.pi


def _table_map(alpha):
    """L = asinh(pi / (2 alpha)): the table coordinate of elevation gamma is
    x = asinh(gamma / alpha) / L in [0, 1]."""
    return jnp.arcsinh(HALF_PI / alpha)


def interface_tables(alpha, eta, distribution="beckmann"):
    """(t at the table nodes, their spline's second derivatives, F_int) at (alpha, eta)."""
    x = np.linspace(0.0, 1.0, TABLE_NODES)
    gamma = jnp.minimum(alpha * jnp.sinh(x * _table_map(alpha)), HALF_PI)
    t = transmittance_at(alpha, eta, jnp.sin(gamma), distribution)
    m2 = jnp.asarray(_spline_matrix(TABLE_NODES)) @ t
    return t, m2, internal_reflectance(alpha, eta, distribution)


def transmittance_lookup(alpha, tables, mu):
    """t(mu) from the tables of :func:`interface_tables` (mu in [0, 1])."""
    t, m2 = tables[0], tables[1]
    c = jnp.clip(mu, 0.0, 1.0)
    gamma = jnp.arctan2(c, _safe_sqrt(1.0 - c * c))  # pi/2 - theta
    x = jnp.arcsinh(gamma / alpha) / _table_map(alpha) * (TABLE_NODES - 1)
    i = jnp.clip(jnp.floor(x), 0, TABLE_NODES - 2).astype(int)
    s = x - i
    q = 1.0 - s
    return q * t[i] + s * t[i + 1] + ((q * q * q - q) * m2[i] + (s * s * s - s) * m2[i + 1]) / 6.0


def diffuse_factors(v, tables, cos_i, cos_r, nonlinear=False):
    """(s(cos_i), t(cos_r)): the separable part rho_eff t(mu_i) t(mu_r) mu_i / (pi eta^2)."""
    rho, alpha, eta = v[0], v[1], v[2]
    f_int = tables[2]
    rho_eff = rho / (1.0 - (rho * f_int if nonlinear else f_int))
    up_i, up_r = cos_i > 0, cos_r > 0
    s = jnp.where(
        up_i,
        rho_eff * transmittance_lookup(alpha, tables, cos_i) * cos_i / (math.pi * eta * eta),
        0.0,
    )
    t = jnp.where(up_r, transmittance_lookup(alpha, tables, cos_r), 0.0)
    return s, t


def rough_plastic(v, wi, wo, distribution="beckmann", nonlinear=False):
    """f_r(I, R) of docs/model.md sec. 8.2 at parameter vector v = (rho, alpha, eta, ks) and unit
    vectors wi = I, wo = R (..., 3), with any options: zero unless both are above."""
    check_distribution(distribution)
    alpha, eta = v[1], v[2]
    s = wi + wo
    h = s / jnp.sqrt(jnp.maximum(jnp.sum(s * s, axis=-1, keepdims=True), 1e-300))
    spec = v[3] * microfacet_lobe(
        alpha, wi, wo, h, lambda c: fresnel.reflectance(c, eta), distribution
    )
    a, b = diffuse_factors(
        v, interface_tables(alpha, eta, distribution), wi[..., 2], wo[..., 2], nonlinear
    )
    return jnp.where((wi[..., 2] > 0) & (wo[..., 2] > 0), spec + a * b, 0.0)


# --------------------------------------------------------------------------------------
# renderers (veil.models.renderers, docs/interop.md)
# --------------------------------------------------------------------------------------
#: What Mitsuba 3.9's roughplastic computes differently (docs/physics.md sec. 2, measured).
MITSUBA_PLASTIC_LOST = (
    "Mitsuba's Beckmann G1 is Walter et al.'s rational approximation (up to 0.35 % per "
    "factor; GGX's is exact in both)",
    "Mitsuba estimates F_int by a 64-node rectangle rule that is 1.3-1.6 % low, so its "
    "diffuse part is up to 2.2 % lower (rho_eff = rho / (1 - F_int)); it reads t(mu) "
    "linearly from a 64-node table",
)


def relative_scales(model, setting, ks_lost: str, diffuse: bool = True):
    """(scale, rho / scale, ks / scale, notes): the intensity scale (default: ks, so that
    the interface is physical) divided out of the relative scales; ``ks_lost`` says what
    becomes of ks / scale != 1 ({ks} is replaced by its value)."""
    scale = intensity_scale(setting, model.ks if model.ks > 0 else 1.0)
    rho = model.rho / scale if diffuse else 0.0
    ks = model.ks / scale
    names = "rho and ks are" if diffuse else "ks is"
    lost = [
        f"veil's {names} relative (light x camera gain): divided by the intensity "
        f"scale {scale:.6g}; a render under unit irradiance times {scale:.6g} is "
        f"veil's value"
    ]
    if abs(ks - 1.0) > 1e-12:
        lost.append(ks_lost.format(ks=f"{ks:.6g}"))
    if rho > 1.0:
        lost.append(
            f"rho / scale = {rho:.6g} > 1 is not a physical albedo (the renderer takes it as given)"
        )
    return scale, rho, ks, lost


def _plastic_mitsuba(model, setting) -> Plugin:
    scale, rho, ks, lost = relative_scales(
        model,
        setting,
        "ks / scale = {ks} != 1 has no physical counterpart: it becomes "
        "Mitsuba's specular_reflectance, a non-physical factor on the specular part",
    )
    return Plugin(
        "bsdf",
        "roughplastic",
        (
            Value("distribution", "string", model.distribution),
            float_value("alpha", model.alpha),
            float_value("int_ior", model.eta * setting.ext_ior),
            float_value("ext_ior", setting.ext_ior),
            float_value("diffuse_reflectance", rho, colour=True),
            float_value("specular_reflectance", ks, colour=True),
            Value("nonlinear", "boolean", bool(model.nonlinear)),
        ),
        lost=tuple(lost) + MITSUBA_PLASTIC_LOST,
        scale=scale,
    )


def _plastic_pbrt(model, setting) -> Plugin:
    require_ggx_for_pbrt(model, RoughPlastic.NAME)
    scale, rho, ks, lost = relative_scales(
        model,
        setting,
        "ks / scale = {ks} is lost: pbrt's coateddiffuse has no specular "
        "factor (the render has ks / scale = 1)",
    )
    lost.append(
        "coateddiffuse is pbrt's closest material, not the same model: it simulates "
        "the light between coat and base stochastically (thickness 0.01, no "
        "absorption), where veil's f_r uses rho / (1 - F_int) "
        + ("(nonlinear: rho / (1 - rho F_int))" if model.nonlinear else "")
    )
    return Plugin(
        "material",
        "coateddiffuse",
        (
            Value("reflectance", "rgb", rho),
            float_value("roughness", model.alpha),
            Value("remaproughness", "boolean", False),
            float_value("eta", model.eta),
        ),
        lost=tuple(lost),
        scale=scale,
    )


# --------------------------------------------------------------------------------------
# the family
# --------------------------------------------------------------------------------------
class MicrofacetFacets:
    """The engine's facet law of a microfacet family (H distributed as D(H) cos theta_H):
    its ``distribution`` option and the roughness at ``ROUGHNESS_INDEX`` of the parameter
    vector."""

    ROUGHNESS_INDEX = 0
    if TYPE_CHECKING:  # the option field of the dataclasses that mix this in
        distribution: str

    def facet_cdf(self, v, alpha) -> Array:
        return facet_cdf(v[self.ROUGHNESS_INDEX], alpha, self.distribution)

    def facet_inverse_cdf(self, v, y) -> Array:
        return facet_inverse_cdf(v[self.ROUGHNESS_INDEX], y, self.distribution)

    def facet_weight(self, v, alpha, sin_alpha=None) -> Array:
        return facet_weight(v[self.ROUGHNESS_INDEX], alpha, sin_alpha, self.distribution)


#: Ten roughness values from 0.02 to 0.6, geometrically spaced.
_ALPHA_GRID = geometric_grid(0.02, 0.6, 10)


@dataclass(frozen=True)
class RoughPlastic(MicrofacetFacets, BRDF):
    """Rough plastic (rho, alpha, eta, ks): a dielectric microfacet coat over a Lambertian
    base (docs/model.md sec. 8.2).

    rho    diffuse albedo (relative units: the scale of the diffuse part)
    alpha  RMS slope of the coat's facets (Beckmann or GGX)
    eta    relative refractive index of the plastic over the surrounding medium
    ks     specular scale (relative units: the scale of the lobe)
    distribution  "beckmann" (default) or "ggx"
    nonlinear     False: rho_eff = rho / (1 - F_int); True: rho / (1 - rho F_int)

    ``nonlinear = True`` is refused at construction: rho would not be a linear scale of the
    diffuse part, as SCALES declares (the engine solves for the scales linearly).
    """

    rho: float
    alpha: float
    eta: float
    ks: float
    distribution: str = "beckmann"
    nonlinear: bool = False

    NAME = "rough-plastic"
    ROUGHNESS_INDEX = 1  # alpha
    LABEL = "rough plastic: dielectric microfacet coat over a Lambertian base (sec. 8.2)"
    SCALES = {"separable": "rho", "lobe": "ks"}
    PARAMS = (
        Param(
            "rho",
            0.0,
            math.inf,
            "diffuse albedo, relative units (scale of the diffuse part)",
            log_scale=True,
            start=1.0,
            channels="per-channel",
        ),
        Param(
            "alpha",
            1e-3,
            1.0,
            "RMS slope of the coat's microfacets",
            log_scale=True,
            start=0.1,
            channels="shared",
        ),
        Param(
            "eta",
            1.0,
            3.0,
            "refractive index of the plastic relative to the surrounding medium (~1.12 in water)",
            lower_open=True,
            start=1.12,
            error_scale="bound",
            channels="shared",
        ),
        SPECULAR_SCALE,
    )
    OPTIONS = (
        DISTRIBUTION_OPTION,
        Option(
            "nonlinear",
            False,
            "rho_eff = rho / (1 - rho F_int) instead of rho / (1 - F_int)",
            (False, True),
        ),
    )
    #: Starting grids: a clear-water fit (step 0) searches the roughness widely and four
    #: indices; a fit through a medium (step 2) the roughness at a plastic's index in water.
    START = {
        "reference": {"alpha": _ALPHA_GRID, "eta": (1.05, 1.12, 1.3, 1.5)},
        "target": {"alpha": _ALPHA_GRID, "eta": (1.12,)},
    }
    #: The renderers' own plugins for it (veil.models.renderers).
    RENDERERS = {"mitsuba": _plastic_mitsuba, "pbrt": _plastic_pbrt}

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.nonlinear:
            raise ParameterError(
                f"{type(self).__name__}.nonlinear = True is not available: rho / (1 - rho "
                f"F_int) would make rho a non-linear parameter, and the engine solves for the "
                f"declared scale (rho) linearly; use nonlinear = False (rho / (1 - F_int))"
            )

    # -- the split used by the integrator (methods of the instance: they read the
    # distribution option; the engine passes the model's template) ------------------------
    def prepare(self, v) -> Any:
        return interface_tables(v[1], v[2], self.distribution)

    def separable(self, v, cos_i, cos_r, aux=None) -> list:
        tables = self.prepare(v) if aux is None else aux
        return [diffuse_factors(v, tables, cos_i, cos_r)]

    def lobe(self, v, wi, wo, h, alpha=None) -> Array:
        eta = v[2]
        return v[3] * microfacet_lobe(
            v[1], wi, wo, h, lambda c: fresnel.reflectance(c, eta), self.distribution
        )
