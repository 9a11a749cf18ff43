"""Unpolarized Fresnel reflectance in the cosine form of docs/model.md section 4."""

from __future__ import annotations

from .._lazy import jnp


def reflectance(cos_theta, eta):
    """Fresnel reflectance F from index 1 into relative index ``eta`` (docs/model.md sec. 4).

    ``cos_theta`` is the cosine of the incidence angle (clipped to [0, 1]). Finite at normal
    incidence, F = 1 under total internal reflection (eta < 1, sin(theta) > eta), F = 0 for
    eta = 1 at every angle, grazing included. Differentiable everywhere except at the
    critical angle itself.
    """
    c = jnp.clip(cos_theta, 0.0, 1.0)
    eta = jnp.asarray(eta, dtype=c.dtype)
    e2 = eta * eta
    # kn = eta^2 cos(theta_t)^2 = eta^2 - 1 + c^2, written without cancellation (near grazing
    # incidence on a matched index 1 - c^2 rounds to 1 and cos(theta_t) to 0, which made F
    # jump from 0 to 1) and without dividing by eta (0/0 at normal incidence for tiny eta)
    kn = (eta - 1.0) * (eta + 1.0) + c * c
    tir = kn < 0.0
    # grazing incidence on a matched index (c = 0, kn = 0) is 0/0: no interface, F = 0
    matched = (kn == 0.0) & (c == 0.0)
    bad = tir | matched
    t = jnp.sqrt(jnp.where(bad, 1.0, kn))  # eta cos(theta_t)
    c_s = jnp.where(bad, 1.0, c)
    rs = (c_s - t) / (c_s + t)
    den_p = e2 * c_s + t  # 0 only if eta^2 underflows at normal incidence: F -> 1 there
    rp = jnp.where(den_p > 0.0, (e2 * c_s - t) / jnp.where(den_p > 0.0, den_p, 1.0), -1.0)
    f = 0.5 * (rs * rs + rp * rp)
    return jnp.where(tir, 1.0, jnp.where(matched, 0.0, f))


def transmittance(cos_theta, eta):
    """Fresnel transmittance F_t = 1 - F (docs/model.md sec. 4)."""
    return 1.0 - reflectance(cos_theta, eta)


def boundary_first(cos_a, eta, variant: str):
    """The boundary factor a(A) of a medium's transmission (docs/model.md sec. 3): F_t^2 for the
    paper's variant, F_t for "exit"."""
    t = transmittance(cos_a, eta)
    return t * t if variant == "paper" else t


def boundary_second(cos_b, eta, variant: str):
    """The boundary factor b(B) (docs/model.md sec. 3): 1 for the paper's variant, F_t for
    "exit"."""
    if variant == "paper":
        return 1.0 + 0.0 * cos_b
    return transmittance(cos_b, eta)
