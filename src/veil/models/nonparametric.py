"""The non-parametric BRDF: a non-negative combination of fixed basis functions, for plates that
no parametric family describes (docs/model.md sec. 8.4, docs/nonparametric.md).

    f_r(I, R) = cos theta_i / pi sum_j d_j B_j(x_i, x_r)
              + sum_k sum_m w_km H_m(theta_d) D_k(H) G1_k(I, H) G1_k(R, H) / (4 cos theta_r)

The diffuse basis B_j is the degree-1 Bernstein basis of x = (1 - cos theta)^5 in each direction
(1 - x_i)(1 - x_r), x_i (1 - x_r) + (1 - x_i) x_r, x_i x_r: a Lambertian base with the retro-
and grazing factors of Schlick's and Disney's diffuse. The lobes are Beckmann microfacet lobes at
a fixed ladder of widths alpha_k (``WIDTHS``, a factor sqrt 2 apart), each with a Fresnel curve
piecewise linear in theta_d = angle(R, H) between ``FRESNEL_DEGREES``. Non-negative combinations
of Beckmann widths approximate the completely monotone distributions in tan^2 theta_H (GGX, GTR,
sums of lobes) within the ladder's range. Every coefficient is a linear parameter, so with the
medium held the apparent reflectance is linear in all of them and step 2 is a linear problem
(:mod:`veil.fitting.linear_fit`).

Through a medium the engine evaluates the family one lobe width at a time with
:class:`NonParametricColumn` (``column_groups``; veil.engine.forward.LinearForward), each
width sampled by its own facet law. The family's own facet law, the widths' laws mixed by
the coefficients (inverted by bisection), serves the sampling of independent checks and
the facet half-angle of reports.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .._lazy import jnp
from .base import BRDF, Param
from .microfacet import facet_cdf, facet_inverse_cdf, facet_weight, ndf, smith_g1

if TYPE_CHECKING:  # the type only: models import JAX on first use (veil._lazy)
    from jax import Array

#: The Beckmann widths (RMS slopes) of the lobes: 0.01 to 0.64, a factor sqrt(2) apart.
WIDTHS = tuple(round(0.01 * 2.0 ** (k / 2.0), 6) for k in range(13))
#: The nodes (degrees of theta_d) of each lobe's Fresnel curve, piecewise linear between them.
FRESNEL_DEGREES = (0.0, 30.0, 60.0, 90.0)
FRESNEL_NODES = len(FRESNEL_DEGREES)
#: The diffuse basis: degree-1 Bernstein products in x = (1 - cos theta)^5 of both directions.
DIFFUSE_NAMES = ("d0", "d1", "d2")
#: Share of the family's own facet law spread evenly over the widths, whatever the coefficients.
FACET_FLOOR = 0.02
#: Bisection steps of the facet law's inverse (60 halve pi/2 to below 1e-18).
BISECTIONS = 60


def lobe_name(k: int, m: int) -> str:
    """The parameter of the lobe of width ``WIDTHS[k]`` on Fresnel basis function ``m``."""
    return f"w{k:02d}_{m}"


def _schlick_x(cos):
    """x = (1 - cos)^5 of a cosine clipped to [0, 1]."""
    u = 1.0 - jnp.clip(cos, 0.0, 1.0)
    u2 = u * u
    return u2 * u2 * u


def _hats(cos_d):
    """The piecewise-linear hat functions of FRESNEL_DEGREES at theta_d = acos(cos_d): (..., M)."""
    # arccos has no derivative at 1 (theta_d = 0, wi = wo): held there, 0 beyond 1 - 1e-12
    inside = cos_d < 1.0 - 1e-12
    theta = jnp.where(
        inside, jnp.degrees(jnp.arccos(jnp.where(inside, jnp.maximum(cos_d, 0.0), 0.5))), 0.0
    )[..., None]
    nodes = jnp.asarray(FRESNEL_DEGREES)
    left = jnp.concatenate([nodes[:1] - 1.0, nodes[:-1]])
    right = jnp.concatenate([nodes[1:], nodes[-1:] + 1.0])
    rise = (theta - left) / (nodes - left)
    fall = (right - theta) / (right - nodes)
    return jnp.clip(jnp.minimum(rise, fall), 0.0, 1.0)


def _lobes(widths, weights, wi, wo, h):
    """sum_k sum_m weights[k, m] hat_m(theta_d) D_k G1_k G1_k / (4 cos theta_r): Beckmann
    lobes of ``widths`` (K,) with Fresnel curves ``weights`` (K, M) at unit vectors wi = I,
    wo = R (..., 3), half vector h; zero unless both are above."""
    ci, co, hz = wi[..., 2], wo[..., 2], h[..., 2]
    c = jnp.sum(wo * h, axis=-1)
    ok = (ci > 0) & (co > 0) & (hz > 0) & (c > 0)
    ci_s, co_s = jnp.where(ok, ci, 1.0), jnp.where(ok, co, 1.0)
    fres = jnp.tensordot(_hats(jnp.where(ok, c, 1.0)), weights, axes=([-1], [1]))  # (..., K)
    wi2 = (wi[..., 0] ** 2 + wi[..., 1] ** 2)[..., None]
    wo2 = (wo[..., 0] ** 2 + wo[..., 1] ** 2)[..., None]
    g = smith_g1(ci_s[..., None], wi2, widths) * smith_g1(co_s[..., None], wo2, widths)
    d = ndf(hz[..., None], (h[..., 0] ** 2 + h[..., 1] ** 2)[..., None], widths)
    return jnp.where(ok, jnp.sum(fres * d * g, axis=-1) / (4.0 * co_s), 0.0)


def _diffuse(v, cos_i, cos_r) -> list:
    """The diffuse basis at coefficients v[0:3] as the engine's separable pairs."""
    xi, xr = _schlick_x(cos_i), _schlick_x(cos_r)
    base = jnp.where(cos_i > 0, cos_i / math.pi, 0.0)
    up_r = jnp.where(cos_r > 0, 1.0, 0.0)
    d0, d1, d2 = v[0], v[1], v[2]
    return [
        (base * (d0 * (1.0 - xi) + d1 * xi), up_r * (1.0 - xr)),
        (base * (d1 * (1.0 - xi) + d2 * xi), up_r * xr),
    ]


def _params() -> tuple[Param, ...]:
    doc = (
        "diffuse coefficient on (1-x_i)(1-x_r)",
        "diffuse coefficient on x_i(1-x_r) + (1-x_i)x_r",
        "diffuse coefficient on x_i x_r",
    )
    out = [
        Param(
            n,
            0.0,
            math.inf,
            f"{d}, x = (1 - cos)^5 (relative units)",
            start=0.5 if j == 0 else 0.0,
            channels="per-channel",
        )
        for j, (n, d) in enumerate(zip(DIFFUSE_NAMES, doc))
    ]
    for k, alpha in enumerate(WIDTHS):
        for m in range(FRESNEL_NODES):
            basis = f"the hat at theta_d = {FRESNEL_DEGREES[m]:g} deg"
            out.append(
                Param(
                    lobe_name(k, m),
                    0.0,
                    math.inf,
                    f"weight of the Beckmann lobe of width {alpha:g} times {basis} "
                    f"(relative units)",
                    start=0.0,
                    channels="per-channel",
                )
            )
    return tuple(out)


class _Declaration(BRDF):
    """What the generated dataclass :class:`NonParametric` inherits (module docstring)."""

    NAME = "nonparametric"
    LABEL = "non-parametric: a non-negative sum of microfacet lobes over widths, and a diffuse base"
    PARAMS = _params()
    #: every parameter is linear: step fits solve them as one linear problem
    LINEAR = True
    START = {"reference": {}, "target": {}}
    N_DIFFUSE = len(DIFFUSE_NAMES)
    #: No renderer takes this table: the exporter fits the closest GGX rough plastic to it
    #: and writes that, with the RMS difference (veil.interop.closest).
    PROXIES = {
        "mitsuba": ("rough-plastic", {"distribution": "ggx"}),
        "pbrt": ("rough-plastic", {"distribution": "ggx"}),
    }

    @classmethod
    def lobe_slices(cls) -> tuple[int, int]:
        """(first index, count) of the lobe coefficients in the parameter vector."""
        return cls.N_DIFFUSE, len(WIDTHS) * FRESNEL_NODES

    @classmethod
    def lobe_grid(cls) -> list[list[str]]:
        """The lobe coefficients' names as a (widths, Fresnel nodes) grid."""
        return [[lobe_name(k, m) for m in range(FRESNEL_NODES)] for k in range(len(WIDTHS))]

    def prepare(self, v) -> Any:
        return None

    def separable(self, v, cos_i, cos_r, aux=None) -> list:
        return _diffuse(v, cos_i, cos_r)

    @classmethod
    def column_groups(cls) -> list[tuple[tuple[float, ...], dict[int, int]]]:
        """The coefficients that share one sampling law, as the column model's vectors: per
        lobe width (the diffuse basis with the first), (the column model's vector with the
        width set and every coefficient 0, {index here: index in the column model})."""
        first, _ = cls.lobe_slices()
        out = []
        for k, alpha in enumerate(WIDTHS):
            where = {first + k * FRESNEL_NODES + m: 4 + m for m in range(FRESNEL_NODES)}
            if k == 0:
                where.update({j: j for j in range(len(DIFFUSE_NAMES))})
            out.append(((0.0, 0.0, 0.0, alpha) + (0.0,) * FRESNEL_NODES, where))
        return out

    @classmethod
    def columns(cls) -> tuple[type[BRDF], dict[str, tuple[float, ...]]]:
        """(the column model, {parameter: the column model's vector that is its basis
        function}): the engine's columns of a linear fit, one lobe width at a time."""
        out: dict[str, tuple[float, ...]] = {}
        for j, name in enumerate(DIFFUSE_NAMES):
            out[name] = (
                tuple(1.0 if i == j else 0.0 for i in range(3)) + (0.1,) + (0.0,) * FRESNEL_NODES
            )
        for k, alpha in enumerate(WIDTHS):
            for m in range(FRESNEL_NODES):
                hat = tuple(1.0 if i == m else 0.0 for i in range(FRESNEL_NODES))
                out[lobe_name(k, m)] = (0.0, 0.0, 0.0, alpha) + hat
        return NonParametricColumn, out

    def _weights(self, v):
        """The lobe coefficients as (K, M)."""
        first, count = self.lobe_slices()
        return jnp.reshape(v[first : first + count], (len(WIDTHS), FRESNEL_NODES))

    def lobe(self, v, wi, wo, h, alpha=None) -> Array:
        return _lobes(jnp.asarray(WIDTHS), self._weights(v), wi, wo, h)

    # -- the facet law: the widths' laws mixed by the lobe coefficients -------------------
    def _mixture(self, v):
        """Each width's share of the engine's half vectors: its coefficients' sum, with
        FACET_FLOOR spread evenly (equal shares without any lobe)."""
        mass = jnp.sum(jnp.maximum(self._weights(v), 0.0), axis=1)
        total = jnp.sum(mass)
        even = jnp.full(len(WIDTHS), 1.0 / len(WIDTHS))
        share = jnp.where(total > 0, mass / jnp.where(total > 0, total, 1.0), even)
        return (1.0 - FACET_FLOOR) * share + FACET_FLOOR * even

    def facet_cdf(self, v, alpha) -> Array:
        widths = jnp.asarray(WIDTHS)
        return jnp.sum(self._mixture(v) * facet_cdf(widths, jnp.asarray(alpha)[..., None]), axis=-1)

    def facet_weight(self, v, alpha, sin_alpha=None) -> Array:
        widths = jnp.asarray(WIDTHS)
        a = jnp.asarray(alpha)[..., None]
        s = None if sin_alpha is None else jnp.asarray(sin_alpha)[..., None]
        return jnp.sum(self._mixture(v) * facet_weight(widths, a, s), axis=-1)

    def facet_inverse_cdf(self, v, y) -> Array:
        from .._jax import jax

        y = jnp.clip(jnp.asarray(y, dtype=float), 0.0, 1.0)

        def step(_, bracket):
            lo, hi = bracket
            mid = 0.5 * (lo + hi)
            below = self.facet_cdf(v, mid) < y
            return jnp.where(below, mid, lo), jnp.where(below, hi, mid)

        lo, hi = jax.lax.fori_loop(
            0, BISECTIONS, step, (jnp.zeros_like(y), jnp.full_like(y, 0.5 * math.pi))
        )
        return jnp.where(y >= 1.0, 0.5 * math.pi, 0.5 * (lo + hi))


NonParametric = dataclasses.make_dataclass(
    "NonParametric",
    [(p.name, float) for p in _Declaration.PARAMS],
    bases=(_Declaration,),
    frozen=True,
)
NonParametric.__module__ = __name__
NonParametric.__doc__ = (
    "The non-parametric BRDF (module docstring): diffuse coefficients d0-d2 and lobe weights "
    "wKK_M (width WIDTHS[KK], Fresnel basis M), all non-negative and linear."
)


@dataclass(frozen=True)
class NonParametricColumn(BRDF):
    """One basis function of :class:`NonParametric` at a time, for the engine's columns
    (:mod:`veil.fitting.linear_fit`): the diffuse basis (d0-d2) and one lobe of width
    ``alpha`` with Fresnel node weights f0-f3, sampled by that width's own facet law. Not a
    registered family: :meth:`NonParametric.columns` says which vector makes which column."""

    d0: float
    d1: float
    d2: float
    alpha: float
    f0: float
    f1: float
    f2: float
    f3: float

    NAME = "nonparametric-column"
    PARAMS = (
        tuple(_params()[:3])
        + (Param("alpha", 1e-3, 1.0, "Beckmann width of the lobe", start=0.1),)
        + tuple(
            Param(
                f"f{m}",
                0.0,
                math.inf,
                f"lobe weight at theta_d = {FRESNEL_DEGREES[m]:g} deg",
                start=0.0,
            )
            for m in range(FRESNEL_NODES)
        )
    )

    def separable(self, v, cos_i, cos_r, aux=None) -> list:
        return _diffuse(v, cos_i, cos_r)

    def lobe(self, v, wi, wo, h, alpha=None) -> Array:
        return _lobes(v[3:4], v[None, 4 : 4 + FRESNEL_NODES], wi, wo, h)

    def facet_cdf(self, v, alpha) -> Array:
        return facet_cdf(v[3], alpha)

    def facet_inverse_cdf(self, v, y) -> Array:
        return facet_inverse_cdf(v[3], y)

    def facet_weight(self, v, alpha, sin_alpha=None) -> Array:
        return facet_weight(v[3], alpha, sin_alpha)


def lobe_table() -> list[tuple[str, float, int]]:
    """(parameter, width, Fresnel basis index) of every lobe coefficient, in order."""
    return [(lobe_name(k, m), a, m) for k, a in enumerate(WIDTHS) for m in range(FRESNEL_NODES)]


__all__ = [
    "NonParametric",
    "NonParametricColumn",
    "WIDTHS",
    "FRESNEL_NODES",
    "lobe_name",
    "lobe_table",
]
