"""Deterministic quadrature rules and the direction grids the integrator is built from.

Every grid maps a unit square to directions with a known density, so that an integral over
directions becomes a plain weighted sum with fixed nodes: smooth in the model parameters and
bit-for-bit repeatable.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

import numpy as np

from .._jax import jnp
from ..errors import InputError

if TYPE_CHECKING:
    from jax import Array


@cache
def gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@cache
def periodic_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint (trapezoidal) rule for a periodic variable on [0, 1)."""
    return (np.arange(n) + 0.5) / n, np.full(n, 1.0 / n)


def frame(center) -> tuple[Array, Array]:
    """Orthonormal frame (t1, t2) about unit vectors ``center`` (..., 3).

    t1 points from ``center`` towards the horizon (down the polar angle), t2 horizontally.
    """
    cz = jnp.clip(center[..., 2], -1.0, 1.0)
    rho = jnp.sqrt(center[..., 0] ** 2 + center[..., 1] ** 2)
    safe = rho > 1e-12
    cphi = jnp.where(safe, center[..., 0] / jnp.where(safe, rho, 1.0), 1.0)
    sphi = jnp.where(safe, center[..., 1] / jnp.where(safe, rho, 1.0), 0.0)
    t1 = jnp.stack([cz * cphi, cz * sphi, -rho], axis=-1)
    t2 = jnp.stack([-sphi, cphi, jnp.zeros_like(cz)], axis=-1)
    return t1, t2


def horizon_one_minus_mu(center_z, cos_beta) -> Array:
    """1 - cos(gamma_max): angular distance from the centre to the horizon along azimuth beta.

    For a centre at polar angle theta, the great circle leaving it at azimuth beta (beta = 0
    towards the horizon) reaches z = 0 at tan(gamma_max) = cos(theta) / (sin(theta) cos(beta)).
    With x = sin(theta) cos(beta) and r = sqrt(cos(theta)^2 + x^2), 1 - cos(gamma_max) =
    1 - x / r, written as cos(theta)^2 / (r (r + x)) where x > 0: near the horizon
    (cos(theta) -> 0) the distance is tiny and 1 - x / r would round it to 0. Finite for
    every centre, including one on the horizon (then 0 or 2).
    """
    z = jnp.maximum(center_z, 0.0)
    st = jnp.sqrt(jnp.maximum(1.0 - z * z, 0.0))
    x = st * cos_beta
    r = jnp.sqrt(z * z + x * x)
    ok = r > 0.0
    r_s = jnp.where(ok, r, 1.0)
    near = z * z / (r_s * (r_s + jnp.abs(x)))  # 1 - |x| / r
    return jnp.where(ok, jnp.where(x > 0.0, near, 2.0 - near), 1.0)


@dataclass(frozen=True)
class Rule:
    """Node counts of the integrator (see :mod:`veil.integrator`).

    phase_radial, phase_azimuth  phase-function grids of the 4D lobe term
    half_radial, half_azimuth    half-vector grids of the 4D lobe term
    dense_radial, dense_azimuth  phase-function grids of the 2D terms
    table, table_radial, table_azimuth  albedo tables: polar angles (odd), half-vector grid
    """

    phase_radial: int = 10
    phase_azimuth: int = 16
    half_radial: int = 6
    half_azimuth: int = 12
    dense_radial: int = 24
    dense_azimuth: int = 32
    table: int = 181
    table_radial: int = 24
    table_azimuth: int = 48

    def __post_init__(self) -> None:
        for name in (
            "phase_radial",
            "phase_azimuth",
            "half_radial",
            "half_azimuth",
            "dense_radial",
            "dense_azimuth",
            "table_radial",
            "table_azimuth",
        ):
            n = getattr(self, name)
            if not isinstance(n, int) or n < 2:
                raise InputError(f"Rule.{name} = {n!r}; expected an integer >= 2")
            if name.endswith("azimuth") and n % 2:
                raise InputError(
                    f"Rule.{name} = {n}; azimuth counts must be even (the "
                    "in-plane symmetry pairs azimuths beta and -beta)"
                )
        if not isinstance(self.table, int) or self.table < 3 or self.table % 2 == 0:
            raise InputError(
                f"Rule.table = {self.table!r}; expected an odd integer >= 3 (Simpson's rule)"
            )

    def scaled(self, factor: float) -> Rule:
        def s(n, lo=2):
            return max(lo, int(round(n * factor)))

        def even(n):
            return 2 * s(n / 2)

        t = s(self.table, 11)
        return Rule(
            s(self.phase_radial),
            even(self.phase_azimuth),
            s(self.half_radial),
            even(self.half_azimuth),
            s(self.dense_radial),
            even(self.dense_azimuth),
            t + (t + 1) % 2,
            s(self.table_radial),
            even(self.table_azimuth),
        )

    @property
    def points_per_config(self) -> int:
        g = self.phase_radial * self.phase_azimuth
        h = self.half_radial * self.half_azimuth
        return 2 * g * h + g * g + 2 * self.dense_radial * self.dense_azimuth


#: Quadrature levels. "default" meets 1e-3 relative error for the paper's presets at both
#: angles < 80 deg (see docs/performance.md).
RULES = {
    "fast": Rule().scaled(0.6),
    "default": Rule(),
    "high": Rule().scaled(2.0),
}
#: The error estimate is twice the difference to a rule with 1.3 times the nodes per
#: dimension: measured against a converged reference it covers the actual error at
#: most configurations and overstates it about twofold (docs/performance.md).
FINER = {name: rule.scaled(1.3) for name, rule in RULES.items()}
ERROR_FACTOR = 2.0


def check_accuracy(accuracy, name: str = "accuracy", error: type[InputError] = InputError) -> None:
    """An ``error`` (an InputError) unless ``accuracy`` names a quadrature rule: one of
    :data:`RULES` ("fast", "default", "high"); ``name`` is the argument it was given as."""
    if not isinstance(accuracy, str) or accuracy not in RULES:
        raise error(f"{name} = {accuracy!r}; expected one of {', '.join(RULES)}")


__all__ = [
    "Rule",
    "RULES",
    "check_accuracy",
    "FINER",
    "ERROR_FACTOR",
    "gauss_legendre_unit",
    "periodic_unit",
    "frame",
    "horizon_one_minus_mu",
]
