"""The share of the view side's scattered light that lands on a square plate (the medium's
blur, docs/maps-blur.md), computed independently of veil.maps.blur: a midpoint quadrature
over the scattering direction R' (the angle gamma from the view direction R and its
azimuth about R) of the orders' Henyey-Greenstein lobes times the model's own plate weight
J_v (veil.ForwardSeries._plate_weight, docs/model.md eq. 8.1b)."""

from __future__ import annotations

import math

import numpy as np

#: orders of the series summed here (the weights (omega tau)^k / k! of tau <= 1 are below
#: 1e-18 of the first's beyond it)
ORDERS = 20


def hg_pdf(g: float, cos_gamma: np.ndarray) -> np.ndarray:
    """The Henyey-Greenstein density per unit solid angle."""
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * cos_gamma) ** 1.5)


def view_direction(theta_r: float, phi_r: float) -> np.ndarray:
    t, p = math.radians(theta_r), math.radians(phi_r)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def directions(theta_r: float, phi_r: float, n_gamma: int = 3000, n_psi: int = 720):
    """(R, R' (n_gamma, n_psi, 3), cos gamma (n_gamma,), solid angle weights (n_gamma,
    n_psi)): midpoints in s with gamma = pi s^3 (nodes crowd the forward peak: the first is
    at 4e-9 rad, 0.5 deg is node ~290 of 3000) and in the azimuth psi about R."""
    R = view_direction(theta_r, phi_r)
    t, p = math.radians(theta_r), math.radians(phi_r)
    u = np.array([math.cos(t) * math.cos(p), math.cos(t) * math.sin(p), -math.sin(t)])
    w = np.cross(R, u)
    s = (np.arange(n_gamma) + 0.5) / n_gamma
    gamma = math.pi * s**3
    d_gamma = 3.0 * math.pi * s**2 / n_gamma
    psi = (np.arange(n_psi) + 0.5) / n_psi * 2.0 * math.pi
    cg, sg = np.cos(gamma)[:, None, None], np.sin(gamma)[:, None, None]
    rp = cg * R + sg * (np.cos(psi)[None, :, None] * u + np.sin(psi)[None, :, None] * w)
    area = (np.sin(gamma) * d_gamma)[:, None] * (2.0 * math.pi / n_psi)
    return R, rp, np.cos(gamma), np.broadcast_to(area, rp.shape[:2])


def plate_shares(medium, theta_r: float, phi_r: float) -> dict:
    """Shares of the endless plate's view-side weight Sum_k w_k Int p(g^k) J_v,endless dR'
    (mu_R' > 0): ``plate``, the part on the square plate of ``medium.plate_width`` seen
    from its centre (J_v of the plate); ``+x``, ``-x``, ``+y``, ``-y``, that part with the
    landing direction v = R - (mu_R / mu_R') R' (eq. B.1) of that sign along x or y."""
    R, rp, cos_gamma, area = directions(theta_r, phi_r)
    v = medium.to_vector()
    plate = np.asarray(medium._plate_weight(v, rp, R))
    endless = np.asarray(medium.replace(plate_width=1e100)._plate_weight(v, rp, R))
    mu = rp[..., 2]
    up = mu > 0
    ratio = R[2] / np.where(up, mu, 1.0)
    land = {
        "+x": (R[0] - ratio * rp[..., 0]) > 0,
        "-x": (R[0] - ratio * rp[..., 0]) < 0,
        "+y": (R[1] - ratio * rp[..., 1]) > 0,
        "-y": (R[1] - ratio * rp[..., 1]) < 0,
    }
    x = float(medium.omega * medium.tau)
    lobes = (
        sum(
            x**k / math.factorial(k) * hg_pdf(float(medium.g) ** k, cos_gamma)[:, None]
            for k in range(1, ORDERS + 1)
        )
        * area
        * up
    )
    total = float(np.sum(lobes * endless))
    out = {"plate": float(np.sum(lobes * plate)) / total}
    for key, mask in land.items():
        out[key] = float(np.sum(lobes * plate * mask)) / total
    return out


__all__ = ["hg_pdf", "view_direction", "directions", "plate_shares"]
