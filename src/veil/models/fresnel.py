"""Unpolarized Fresnel reflectance in the cosine form of MODEL.md section 4."""

from __future__ import annotations

from .._jax import jnp


def reflectance(cos_theta, eta):
    """Fresnel reflectance F from index 1 into relative index ``eta`` (MODEL.md sec. 4).

    ``cos_theta`` is the cosine of the incidence angle (clipped to [0, 1]). Finite at normal
    incidence, F = 1 under total internal reflection (eta < 1, sin(theta) > eta), F = 0 for
    eta = 1. Differentiable everywhere except at the critical angle itself.
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    eta = jnp.asarray(eta, dtype=c.dtype)
    k = 1.0 - (1.0 - c * c) / (eta * eta)
    tir = k < 0.0
    # grazing incidence on a matched index (c = 0, k = 0) is 0/0: no interface, F = 0
    matched = (k == 0.0) & (c == 0.0)
    bad = tir | matched
    cos_t = jnp.sqrt(jnp.where(bad, 1.0, k))
    c_s = jnp.where(bad, 1.0, c)
    rs = (c_s - eta * cos_t) / (c_s + eta * cos_t)
    rp = (eta * c_s - cos_t) / (eta * c_s + cos_t)
    f = 0.5 * (rs * rs + rp * rp)
    return jnp.where(tir, 1.0, jnp.where(matched, 0.0, f))


def transmittance(cos_theta, eta):
    """Fresnel transmittance F_t = 1 - F (MODEL.md sec. 4)."""
    return 1.0 - reflectance(cos_theta, eta)
