"""Angle conventions of docs/model.md section 1: directions, signed in-plane angles, goniometer.

All public functions take and return degrees. The light sits at phi = 180 deg and the camera
at phi = 0 deg in the paper's in-plane set-up; a negative in-plane angle means the other side.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def check_angles(theta_i, theta_r, phi_i, phi_r):
    """Broadcast and validate angles (degrees); raise ValueError naming the bad value."""
    arrays = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (theta_i, theta_r, phi_i, phi_r))
    )
    for name, a in zip(("theta_i", "theta_r", "phi_i", "phi_r"), arrays):
        bad = ~np.isfinite(a)
        if bad.any():
            raise InputError(f"{name} = {a[bad].flat[0]!r} is not a finite number")
        if name.startswith("theta"):
            out = (a < 0) | (a >= 90)
            if out.any():
                raise InputError(f"{name} = {a[out].flat[0]:g} deg is outside [0, 90)")
    return arrays


def direction(theta_deg, phi_deg) -> np.ndarray:
    """Unit vector(s) for polar angle ``theta`` and azimuth ``phi`` (degrees), shape (..., 3).

    In numpy: the engine's inputs are made on the host, and each eager JAX operation would
    cost a compilation or a cache lookup in a fresh process (start-up, docs/performance.md).
    """
    t = np.deg2rad(np.asarray(theta_deg, dtype=float))
    p = np.deg2rad(np.asarray(phi_deg, dtype=float))
    st = np.sin(t)
    return np.stack([st * np.cos(p), st * np.sin(p), np.cos(t)], axis=-1)


def from_signed_inplane(theta_i, theta_r):
    """Signed in-plane angles -> (theta_i, phi_i, theta_r, phi_r), degrees.

    Light at phi = 180 deg and camera at phi = 0 deg for non-negative angles; a negative angle
    means |angle| on the other side (phi + 180 deg).
    """
    ti = np.asarray(theta_i, dtype=float)
    tr = np.asarray(theta_r, dtype=float)
    phi_i = np.where(ti < 0, 0.0, 180.0)
    phi_r = np.where(tr < 0, 180.0, 0.0)
    return np.abs(ti), phi_i, np.abs(tr), phi_r


def to_signed_inplane(theta_i, phi_i, theta_r, phi_r, tol=1e-6):
    """Inverse of :func:`from_signed_inplane`; raises ``ValueError`` for out-of-plane rows."""
    ti, pi_, tr, pr = (np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_r, phi_r))

    def distance(phi, target):  # angular distance in degrees, wrap-around safe
        return np.abs(np.mod(phi - target + 180.0, 360.0) - 180.0)

    def side(theta, phi, positive_at):
        on_pos = (distance(phi, positive_at) <= tol) | (theta < tol)
        on_neg = distance(phi, positive_at + 180.0) <= tol
        if not np.all(on_pos | on_neg):
            bad = np.flatnonzero(~(on_pos | on_neg))
            raise InputError(
                f"rows {bad.tolist()} are not in the plane of incidence (phi not 0 or 180 deg)"
            )
        return np.where(on_pos, theta, -theta)

    return side(ti, pi_, 180.0), side(tr, pr, 0.0)


def from_goniometer(psi, rho):
    """Goniometer (psi, rho) -> signed in-plane (theta_i, theta_r): psi/2 + rho, psi/2 - rho."""
    psi = np.asarray(psi, dtype=float)
    rho = np.asarray(rho, dtype=float)
    return psi / 2.0 + rho, psi / 2.0 - rho


def to_goniometer(theta_i, theta_r):
    """Signed in-plane (theta_i, theta_r) -> goniometer (psi, rho)."""
    ti = np.asarray(theta_i, dtype=float)
    tr = np.asarray(theta_r, dtype=float)
    return ti + tr, (ti - tr) / 2.0
