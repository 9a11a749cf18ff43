"""The physical medium ``forward-series`` (docs/model.md sec. 8.1): the unscattered beam plus the
orders of forward scattering along one pass of optical depth tau,

    f_t(I, T) = e^{-tau} [ delta(I, T) + sum_{k>=1} (omega tau)^k / k! p(g^k; I.T) ] a(I) b(T),

p the Henyey-Greenstein phase function (sec. 3), a and b the Fresnel factors of sec. 3 at the
boundary index eta_u (eta_u = 1: no boundary). The k-fold spherical convolution of p(g) is
p(g^k) (its Legendre moments are g^l), so the series is exact for forward scattering along a
path of fixed optical depth when the path-length differences of scattered light are
neglected (docs/physics.md sec. 4).

The engine sees two components: the delta with weight e^{-tau}, and the scattered lobe with
weight e^{-tau} (e^{omega tau} - 1) and the normalized phase function
sum_k c_k p(g^k), c_k = (omega tau)^k / k! / (e^{omega tau} - 1), summed over ORDERS orders
(the weight left beyond them is below 1e-6 of the lobe's for tau up to the bound). Its cone
density, cone fraction and the inverse of the cone fraction are tabulated once per engine
call with their exact slopes and read by cubic Hermite interpolation, one table row per
lookup (veil.models.phase, mixture_*; relative accuracy TABLE_ACCURACY).

Set-up geometry (options, from the apparatus, not fitted; one length unit): with the path
length R_c of one pass (``path_length``) and the plate's width 2a (``plate_width``) the
scattered light on the view side is weighted by J_v(R', R) = (1 - e^{-beta S})/(beta R_c),
beta = sigma_t (mu_R/mu_R' - 1), sigma_t = tau/R_c, S = min(R_c, a / max(|v_x|, |v_y|)),
v = R - (mu_R/mu_R') R': the fraction of the scattering depths along the camera's ray whose
light left the plate (exact for single scattering, docs/physics.md sec. 5). Without a plate
width the plate is infinite (S = R_c); without a path length J_v = 1 (the series alone).

Order weights (option ``orders``): "poisson" (default) as above; "light-side" weights the lobe's
order k by the path factor M_k(tau, g) of the light side in the lab's cylinder
(docs/physics-orders.md sec. 8, ``path_factors``) and the view weight by the ratio that keeps the
view side the Poisson series times J_v; "view-side" keeps the lobe Poisson and weights the view
side's order k by the landing factor lambda_k(g; R_c, a, theta_r) (``landing_factors``: a
path that wandered lands where its whole lateral drift puts it, not where its last direction
back-projects); "cylinder" does both. Measured (docs/validity-orders.md): "light-side" alone
moves the fitted tau at tau = 1 from 1.121 to 1.162; "cylinder" brings it to 1.050 (5 cm plate),
1.038 (10 cm plate), 1.034 (R_c 10 cm), the estimate vs truth better there (0.21 -> 0.19 %,
0.94 -> 0.76 %, 0.61 -> 0.46 %), 0.08 -> 0.14 % at tau = 0.5. Experimental (default off).

An overall intensity factor s (held at 1 unless a fit frees it) covers medium sessions whose
exposure differs from the clear-water session's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .._lazy import jnp
from . import fresnel, phase
from .base import Medium, Option, Param
from .renderers import GEOMETRY_HALF_WIDTH, GEOMETRY_LENGTH, Plugin, Unsupported, Value, float_value

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    from jax import Array

VARIANTS = ("paper", "exit")
#: Weights of the orders: "poisson" (docs/model.md 8.1 as written); "light-side" (the light
#: side's orders with the cylinder's path factors M_k, docs/physics-orders.md sec. 8, the view
#: side Poisson x J_v);
#: "view-side" (the light side Poisson, the view side's orders with the landing factors lambda_k);
#: "cylinder" (both).
ORDER_WEIGHTS = ("poisson", "cylinder", "light-side", "view-side")
#: Probabilists' Gauss-Hermite rule for the landing factors' mean over the path's depths.
_HERMITE = 12
#: Orders of scattering summed; with tau <= TAU_MAX the weight beyond them is below 1e-6 of
#: the scattered lobe's.
ORDERS = 14
TAU_MAX = 3.0


def _mixture(v):
    """(c_k, g^k) of the normalized scattered lobe, k = 1..ORDERS: c_k = x^k / k! / (e^x - 1)
    with x = omega tau, written as x^(k-1)/k! (a running product) times x / (e^x - 1), so
    that x = 0 gives the single-scattering lobe exactly."""
    tau, omega, g = v[0], v[1], v[2]
    x = omega * tau
    k = jnp.arange(1, ORDERS + 1, dtype=float)
    s = jnp.cumprod(jnp.concatenate([jnp.ones(1), x / k[1:]]))
    r = jnp.where(x > 1e-300, x / jnp.expm1(jnp.where(x > 1e-300, x, 1.0)), 1.0)
    return s * r, jnp.cumprod(jnp.full(ORDERS, g))


def path_factors(tau, g):
    """M_k, k = 1..ORDERS: the cylinder's factor on the Poisson weight of order k of the light
    reaching the plate centre (docs/physics-orders.md sec. 8), M_k = exp(X_k),

        X_k = A_k (1 - tau/(k+1)) - B_k (1 - tau/(k+2)),
        A_k = sum_{m=1..k} (1 - g^m),   B_k = sum_{m=1..k} (k+1-m)/(k+1) (1 - g^m):

    A_k the longer path of the scattered segments (room for the scatterings; their extra
    attenuation is the tau/(k+1) part), B_k the wall's curvature in the plane of incidence
    (the circle of radius R_c shortens the beam's path to a laterally displaced vertex, and
    bounds where the vertices can be). Independent of R_c: the cylinder's shape, not its size."""
    k = jnp.arange(1, ORDERS + 1, dtype=float)
    one_minus = 1.0 - jnp.cumprod(jnp.full(ORDERS, g))  # 1 - g^m, m = 1..ORDERS
    a = jnp.cumsum(one_minus)
    # sum_m (k+1-m)(1 - g^m) = (k+1) A_k - sum_m m (1 - g^m)
    b = a - jnp.cumsum(k * one_minus) / (k + 1.0)
    return jnp.exp(a * (1.0 - tau / (k + 1.0)) - b * (1.0 - tau / (k + 2.0)))


def _rectangle_fraction(s, aa, bb):
    """P(s): the fraction of a 2-D Cauchy distribution of scale s (density
    s / (2 pi (s^2 + rho^2)^{3/2})) inside the rectangle |x| < aa, |y| < bb: the solid angle of
    the rectangle seen from the distance s on its axis over 2 pi."""
    s = jnp.maximum(s, 1e-12 * bb)
    return (2.0 / math.pi) * jnp.arctan(aa * bb / (s * jnp.sqrt(s * s + aa * aa + bb * bb)))


def _rectangle_potential(aa, bb, z):
    """F(aa, bb, z) = Int_0^aa Int_0^bb (x^2 + y^2 + z^2)^{-1/2} dx dy (z > 0)."""
    d = jnp.sqrt(aa * aa + bb * bb + z * z)
    return (
        aa * jnp.log((bb + d) / jnp.sqrt(aa * aa + z * z))
        + bb * jnp.log((aa + d) / jnp.sqrt(bb * bb + z * z))
        - z * jnp.arctan(aa * bb / (z * d))
    )


def landing_factors(g, path_length, half_width, mu_r):
    """lambda_k, k = 1..ORDERS: the fraction of the order-k paths seen by the camera (at
    cos theta_r = mu_r) that left the square plate of half-width a, over the fraction that J_v
    predicts (docs/physics-orders.md sec. 8). Small angles: the HG(g^j) directions are 2-D Cauchy
    distributed with scale b_j = (1 - g^j)/g^{j/2} (and convolve as a Cauchy random walk), so
    a path with segment depths Delta_j (uniform spacings of R_c) is displaced at the plate by a
    2-D Cauchy variable of scale S = sum_j Delta_j b_j, J_v's straight back-projection by one of
    scale t b_k, t uniform on [0, R_c]. The plate seen along R is the rectangle a mu_r x a;

        lambda_k = E[P(S)] / E_t[P(t b_k)],

    P the rectangle's fraction of the Cauchy distribution (``_rectangle_fraction``); the
    denominator in closed form (1/R_c b_k) Int_0^{R_c b_k} P = 4 (F(0) - F(R_c b_k)) / (2 pi
    R_c b_k) (``_rectangle_potential``), the numerator over a Gaussian with S's exact mean and
    variance (Dirichlet moments of the spacings; 12-point Gauss-Hermite). lambda_1 = 1 exactly
    (J_v is exact for single scattering); lambda_k <= 1 (clipped: beyond the small-angle
    regime, g well below 0.8, the ratio is not meaningful). Independent of tau (the
    attenuation stays J_v's)."""
    g = jnp.clip(g, 1e-3, 1.0 - 1e-12)
    k = jnp.arange(1, ORDERS + 1, dtype=float)
    gk = jnp.cumprod(jnp.full(ORDERS, g))
    b = (1.0 - gk) / jnp.sqrt(gk)  # b_j, j = 1..ORDERS
    rc, aa, bb = path_length, half_width * jnp.maximum(mu_r, 1e-6), half_width
    # S = sum_{j<=k} Delta_j b_j, (Delta_0 .. Delta_k) ~ R_c Dirichlet(1, ..., 1)
    s1 = jnp.cumsum(b)
    s2 = jnp.cumsum(b * b)
    mean = rc * s1 / (k + 1.0)
    var = rc * rc * ((s2 + s1 * s1) / ((k + 1.0) * (k + 2.0)) - s1 * s1 / (k + 1.0) ** 2)
    x, w = _hermite_rule()
    nodes = mean[:, None] + jnp.sqrt(jnp.maximum(var, 0.0))[:, None] * x
    real = jnp.sum(w * _rectangle_fraction(jnp.maximum(nodes, 0.0), aa, bb), axis=-1)
    z = rc * b
    zs = jnp.maximum(z, 1e-9 * bb)
    d0 = jnp.sqrt(aa * aa + bb * bb)
    f0 = aa * jnp.log((bb + d0) / aa) + bb * jnp.log((aa + d0) / bb)
    straight = 4.0 * (f0 - _rectangle_potential(aa, bb, zs)) / (2.0 * math.pi * zs)
    # at most 1: for scales far beyond the plate (g small, where the small-angle model does not
    # hold) the ratio of two tails grows as R_c b_k / E[S]^2 (a sum's tail against a uniform
    # depth's) and would be meaningless
    ratio = jnp.minimum(jnp.where(z > 1e-9 * bb, real / straight, 1.0), 1.0)
    return jnp.where(k == 1.0, 1.0, ratio)


def _hermite_rule():
    import numpy as np

    x, w = np.polynomial.hermite_e.hermegauss(_HERMITE)
    return x, w / math.sqrt(2.0 * math.pi)


def _path_mixture(v):
    """(c_k, g^k, sum_k x^(k-1)/k! M_k) of the light side's lobe with the cylinder's path
    factors M_k (``orders="cylinder"``): c_k proportional to x^k/k! M_k."""
    tau, omega, g = v[0], v[1], v[2]
    x = omega * tau
    k = jnp.arange(1, ORDERS + 1, dtype=float)
    s = jnp.cumprod(jnp.concatenate([jnp.ones(1), x / k[1:]]))  # x^(k-1) / k!
    w = s * path_factors(tau, g)
    total = jnp.sum(w)
    return w / total, jnp.cumprod(jnp.full(ORDERS, g)), total


# -- renderers (veil.models.renderers, docs/interop.md) --------------------------------------
def _geometry(model, setting):
    """(model with the setting's path length, sigma_t, scene geometry)."""
    length = setting.path_length if setting.path_length is not None else model.path_length
    if not length or length <= 0:
        raise Unsupported(
            f"{ForwardSeries.NAME}: a renderer's medium needs an extinction "
            f"coefficient sigma_t = tau / (path length of one pass), and this "
            f"medium has no path_length; give the length in scene units "
            f"(veil export --path-length L)"
        )
    if length != model.path_length:
        width = model.plate_width if model.plate_width <= length * 2 else 0.0
        model = model.replace(path_length=float(length), plate_width=width)
    half = 0.5 * model.plate_width if model.plate_width > 0 else length
    return model, model.tau / length, {GEOMETRY_LENGTH: length, GEOMETRY_HALF_WIDTH: half}


def _medium_lost(model, renderer: str) -> list:
    lost = [
        "the series neglects path-length differences of scattered light (docs/physics.md "
        "sec. 4); the renderer path-traces the actual geometry, so the medium must fill "
        "the set-up's geometry (a cylinder of radius path_length about the plate) for the "
        "two to agree"
    ]
    if model.eta_u != 1.0:
        lost.append(
            f"the boundary (eta_u = {model.eta_u:.6g}) is exported as a dielectric "
            f"interface; veil's Fresnel factors ({model.variant} variant, docs/model.md "
            f"sec. 3) only approximate its refraction"
        )
    if model.s != 1.0:
        lost.append(
            f"the intensity factor s = {model.s:.6g} is not part of the medium: "
            f"multiply the render by it"
        )
    return lost


def _series_mitsuba(model, setting) -> Plugin:
    model, sigma_t, geometry = _geometry(model, setting)
    extra: tuple[Plugin, ...] = ()
    if model.eta_u != 1.0:
        extra = (
            Plugin(
                "bsdf",
                "dielectric",
                (float_value("int_ior", model.eta_u), float_value("ext_ior", 1.0)),
            ),
        )
    return Plugin(
        "medium",
        "homogeneous",
        (
            float_value("sigma_t", sigma_t, colour=True),
            float_value("albedo", model.omega, colour=True),
        ),
        children=(Plugin("phase", "hg", (float_value("g", model.g),)),),
        lost=tuple(_medium_lost(model, "Mitsuba")),
        scale=model.s,
        extra=extra,
        geometry=geometry,
        model=model,
    )


def _series_pbrt(model, setting) -> Plugin:
    model, sigma_t, geometry = _geometry(model, setting)
    lost = _medium_lost(model, "pbrt")
    if model.eta_u != 1.0:
        lost[1] = (
            f"the boundary (eta_u = {model.eta_u:.6g}) needs a dielectric interface "
            f'shape in the pbrt scene (Material "dielectric" "float eta" '
            f"{model.eta_u:.6g}); it is not written here"
        )
    return Plugin(
        "medium",
        "homogeneous",
        (
            Value("sigma_a", "rgb", (1.0 - model.omega) * sigma_t),
            Value("sigma_s", "rgb", model.omega * sigma_t),
            float_value("scale", 1.0),
            float_value("g", model.g),
        ),
        lost=tuple(lost),
        scale=model.s,
        geometry=geometry,
        model=model,
    )


#: A given path length or plate width lies in this range (any unit): J_v divides tau by
#: R_c, multiplies it by ratios of direction cosines up to 1e12 and compares a / R_c with
#: them; the landing factors square a and R_c times scales up to 1e21. Outside it float64
#: overflows or underflows there (R_c = 1e308 alone dropped the scattered light); inside,
#: J_v depends on a / R_c alone (tests/test_tools_extremes.py).
LENGTH_RANGE = (1e-100, 1e100)


@dataclass(frozen=True)
class ForwardSeries(Medium):
    """Medium (tau, omega, g, eta_u, s): the unscattered beam plus the orders of forward
    scattering (module docstring).

    tau      optical depth of one pass through the medium
    omega    single-scattering albedo
    g        Henyey-Greenstein asymmetry of one scattering event
    eta_u    index of the medium's boundary (1: no boundary, no Fresnel factors; held at 1
             unless a fit frees it: f_t is not differentiable in eta_u at 1, where total
             internal reflection sets in on one side)
    s        overall intensity factor (held at 1 unless freed)
    variant  Fresnel factors as the paper's medium ("paper" or "exit", docs/model.md sec. 3)
    path_length, plate_width  set-up geometry in one length unit (0: not given)
    """

    tau: float
    omega: float
    g: float
    eta_u: float = 1.0
    s: float = 1.0
    variant: str = "paper"
    path_length: float = 0.0
    plate_width: float = 0.0
    orders: str = "poisson"

    NAME = "forward-series"
    LABEL = "unscattered beam + orders of forward scattering, physical (docs/model.md sec. 8.1)"
    COMPONENTS = ("delta", "lobe")
    GAIN = "s"
    TABLE_ACCURACY = 1e-5
    PARAMS = (
        Param(
            "tau",
            0.0,
            TAU_MAX,
            "optical depth of one pass through the medium",
            start=0.5,
            share="per-medium",
            channels="per-channel",
        ),
        Param(
            "omega",
            0.0,
            1.0,
            "single-scattering albedo",
            start=0.99,
            share="shared",
            channels="per-channel",
        ),
        Param(
            "g",
            0.0,
            1.0,
            "Henyey-Greenstein asymmetry of one scattering event (forward: 0 to 1)",
            upper_open=True,
            start=0.9,
            share="per-medium",
            error_scale="bound",
            channels="shared",
        ),
        Param(
            "eta_u",
            0.0,
            10.0,
            "index of the medium's boundary (1: none; held at 1 "
            "unless freed: an index-matched set-up has none)",
            lower_open=True,
            start=1.0,
            share="shared",
            held=True,
            channels="shared",
        ),
        Param(
            "s",
            0.0,
            math.inf,
            "overall intensity factor (exposure)",
            log_scale=True,
            start=1.0,
            held=True,
            channels="per-channel",
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
        Option("path_length", 0.0, "path length of one pass, R_c (0: not given; then J_v = 1)"),
        Option(
            "plate_width",
            0.0,
            "width 2a of the square plate in the unit of path_length (0: infinite)",
        ),
        Option(
            "orders",
            "poisson",
            "weights of the scattering orders: poisson = "
            "(omega tau)^k/k! on both sides; light-side = the light side's with the "
            "cylinder's path factors M_k(tau, g), the view side's unchanged; view-side = the "
            "view side's with the plate's landing factors lambda_k (docs/physics-orders.md "
            "sec. 8), the light side's unchanged; cylinder = both",
            ORDER_WEIGHTS,
        ),
    )
    #: Against path tracing without a fit (validation/forward_error.py, docs/validity.md) the
    #: series is 0.74 % RMS off at optical depth 0.1, about 0.5 % of it its own (the rest the
    #: renderer's noise), and 1-2.6 % at 0.5-1.5, where the fits' residuals show it. Below
    #: that a session's residuals cannot show it, while the target's parameters can absorb it
    #: (m01: the index and the specular scale 3-4 standard errors off with the true medium).
    MODEL_ERROR_FLOOR = (0.005, 40.0)
    START = {
        "medium": {
            "tau": (0.05, 0.15, 0.3, 0.5, 0.8, 1.2, 1.8),
            "g": (0.8, 0.88, 0.93, 0.96, 0.98),
            "omega": (0.99,),
            "eta_u": (1.33,),
        }
    }
    #: The renderers' own plugins for it (veil.models.renderers).
    RENDERERS = {"mitsuba": _series_mitsuba, "pbrt": _series_pbrt}

    @classmethod
    def same_model(cls, options: dict) -> dict:
        """Without a plate width the view side's landing factors are 1 (``view_weight``):
        "view-side" is "poisson" and "cylinder" is "light-side"."""
        out = dict(options)
        if not out.get("plate_width", 0.0):
            out["orders"] = {"view-side": "poisson", "cylinder": "light-side"}.get(
                out.get("orders", "poisson"), out.get("orders", "poisson")
            )
        return out

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("path_length", "plate_width"):
            value = getattr(self, name)
            if isinstance(value, int) and not isinstance(value, bool):
                object.__setattr__(self, name, float(value))
            if not math.isfinite(getattr(self, name)) or getattr(self, name) < 0:
                from ..errors import ParameterError

                raise ParameterError(
                    f"ForwardSeries.{name} = {value!r}: expected a length >= 0 (0: not given)"
                )
            lo, hi = LENGTH_RANGE
            if getattr(self, name) > 0 and not lo <= getattr(self, name) <= hi:
                from ..errors import ParameterError

                raise ParameterError(
                    f"ForwardSeries.{name} = {value!r}: expected 0 (not given) or a length "
                    f"from {lo:g} to {hi:g} (path_length and plate_width in one unit, any); "
                    f"outside that range the plate's weighting J_v overflows or underflows"
                )
        if self.plate_width > 0 and self.path_length <= 0:
            from ..errors import ParameterError

            raise ParameterError(
                "ForwardSeries.plate_width needs path_length: the plate's "
                "weighting compares its width with the path length"
            )

    # -- components ----------------------------------------------------------------------
    @staticmethod
    def delta_weight(v) -> Array:
        return jnp.exp(-v[0])

    def lobe_weight(self, v) -> Array:
        if self.orders in ("cylinder", "light-side"):
            return jnp.exp(-v[0]) * v[1] * v[0] * _path_mixture(v)[2]
        return jnp.exp(-v[0]) * jnp.expm1(v[1] * v[0])

    def factor_first(self, v, cos_a) -> Array:
        return fresnel.boundary_first(cos_a, v[3], self.variant)

    def factor_second(self, v, cos_b) -> Array:
        return fresnel.boundary_second(cos_b, v[3], self.variant)

    # -- the normalized scattered lobe, tabulated once per engine call --------------------
    def mixture(self, v) -> tuple:
        """(c_k, g_k) of the normalized scattered lobe (module docstring; with
        ``orders="cylinder"`` or "light-side" the light side's weights)."""
        if self.orders in ("cylinder", "light-side"):
            return _path_mixture(v)[:2]
        return _mixture(v)

    def prepare(self, v) -> Any:
        return phase.mixture_table(*self.mixture(v))

    def sampling_law(self, vs) -> tuple:
        """The mean of the channels' scattered lobes (rows of ``vs``), as one mixture of every
        channel's orders: each channel's phase is at most C times its density."""
        parts = [self.mixture(vs[c]) for c in range(vs.shape[0])]
        c = jnp.concatenate([w for w, _ in parts]) / len(parts)
        return jnp.mean(vs, axis=0), phase.mixture_table(c, jnp.concatenate([g for _, g in parts]))

    def phase(self, v, one_minus_mu, aux=None) -> Array:
        return phase.mixture_pdf(self.prepare(v) if aux is None else aux, one_minus_mu)

    def phase_cone_fraction(self, v, one_minus_mu, aux=None) -> Array:
        return phase.mixture_cone_fraction(self.prepare(v) if aux is None else aux, one_minus_mu)

    def phase_inverse_cone_fraction(self, v, frac, aux=None) -> Array:
        return phase.mixture_inverse_cone_fraction(self.prepare(v) if aux is None else aux, frac)

    def phase_sample(self, v, frac, aux=None) -> tuple:
        return phase.mixture_inverse_with_pdf(self.prepare(v) if aux is None else aux, frac)

    # -- the finite plate ----------------------------------------------------------------
    def view_lobes(self) -> tuple[list[float], list[float], float]:
        """The view side's scattered light by order k = 1 .. ORDERS (eq. 8.1a): the weights
        (omega tau)^k / k!, the lobes' asymmetries g^k, and the extinction coefficient
        tau / R_c along the pass (0 without a path length); for the medium's blur across
        a plate (docs/maps-blur.md)."""
        x = float(self.omega * self.tau)
        weights = [x**k / math.factorial(k) for k in range(1, ORDERS + 1)]
        lobes = [float(self.g) ** k for k in range(1, ORDERS + 1)]
        rc = float(self.path_length)
        return weights, lobes, (float(self.tau) / rc if rc > 0 else 0.0)

    def has_view_weight(self) -> bool:
        return self.path_length > 0 or self.orders in ("cylinder", "light-side")

    def view_weight(self, v, r_prime, r) -> Array:
        """J_v(R', R) (module docstring); 1 without a path length. With other ``orders`` than
        "poisson", times sum_k x^k/k! V_k p(g^k) / sum_k x^k/k! M_k p(g^k) at R'.R: M_k the
        weights the lobe carries (1 unless the light side's path factors are in it, "light-side",
        "cylinder"), V_k those the view side should have (the landing factors lambda_k of
        ``landing_factors`` with "view-side" and "cylinder", else 1)."""
        jv = self._plate_weight(v, r_prime, r)
        if self.orders == "poisson":
            return jv
        tau, omega, g = v[0], v[1], v[2]
        k = jnp.arange(1, ORDERS + 1, dtype=float)
        s = jnp.cumprod(jnp.concatenate([jnp.ones(1), omega * tau / k[1:]]))
        gk = jnp.cumprod(jnp.full(ORDERS, g))
        omm = 0.5 * jnp.sum((r_prime - r) ** 2, axis=-1)  # 1 - R'.R without cancellation
        p = phase.hg_pdf(gk, omm[..., None])
        lobe = s * path_factors(tau, g) if self.orders in ("cylinder", "light-side") else s
        view = s
        if self.orders in ("cylinder", "view-side") and self.plate_width > 0:
            view = s * landing_factors(g, self.path_length, 0.5 * self.plate_width, r[2])
        return jv * jnp.sum(view * p, axis=-1) / jnp.sum(lobe * p, axis=-1)

    def _plate_weight(self, v, r_prime, r):
        """J_v(R', R) (module docstring); 1 without a path length."""
        if self.path_length <= 0:
            return 1.0 + 0.0 * r_prime[..., 2]
        rc = self.path_length
        sigma_t = v[0] / rc
        mu_p = jnp.maximum(r_prime[..., 2], 1e-12)
        ratio = r[2] / mu_p
        beta = sigma_t * (ratio - 1.0)
        if self.plate_width > 0:
            a = 0.5 * self.plate_width
            vx = r[0] - ratio * r_prime[..., 0]
            vy = r[1] - ratio * r_prime[..., 1]
            m = jnp.maximum(jnp.abs(vx), jnp.abs(vy))
            depth = jnp.minimum(rc, a / jnp.maximum(m, a / rc))
        else:
            depth = rc + 0.0 * beta
        x = beta * depth
        small = jnp.abs(x) < 1e-6
        xs = jnp.where(small, 1.0, x)
        frac = jnp.where(small, 1.0 - 0.5 * x + x * x / 6.0, -jnp.expm1(-xs) / xs)
        return depth / rc * frac

    def concentrated(self, factor: float) -> ForwardSeries:
        """More or less of the scattering substance: the optical depth times ``factor``."""
        return self.replace(tau=self.tau * factor)
