"""Angle conventions of docs/model.md section 1: directions, signed in-plane angles, goniometer.

All public functions take and return degrees. The light sits at phi = 180 deg and the camera
at phi = 0 deg in the paper's in-plane set-up; a negative in-plane angle means the other side.
"""

from __future__ import annotations

import numbers

import numpy as np

from ..errors import InputError, InputTypeError

#: The angle arguments of the forward model, in the order :func:`check_angles` takes them.
ANGLE_NAMES = ("theta_i", "theta_r", "phi_i", "phi_r")
_EXPECTED = "expected angles in degrees (a number or an array of numbers)"


def check_angles(theta_i, theta_r, phi_i, phi_r) -> tuple[np.ndarray, ...]:
    """The angles (degrees) as float arrays broadcast to one shape; an InputError naming the
    argument for anything else: no number, a ragged nested list, a value that is not finite,
    a polar angle outside [0, 90), shapes that do not broadcast."""
    arrays = [as_angle_array(a, n) for a, n in zip((theta_i, theta_r, phi_i, phi_r), ANGLE_NAMES)]
    for name, a in zip(ANGLE_NAMES, arrays):
        bad = ~np.isfinite(a)
        if bad.any():
            raise InputError(
                f"{name}{_where(a, bad)} = {float(a[bad].flat[0])!r} is not a finite number; "
                f"{_EXPECTED}"
            )
        if name.startswith("theta"):
            out = (a < 0) | (a >= 90)
            if out.any():
                raise InputError(f"{name} = {a[out].flat[0]:g} deg is outside [0, 90)")
    try:
        return np.broadcast_arrays(*arrays)
    except ValueError:
        raise _shape_error(arrays) from None


def as_angle_array(value, name: str) -> np.ndarray:
    """``value`` (degrees: a number, or a list or array of numbers) as a float array; an
    InputError (an InputTypeError for no number) naming the argument ``name`` otherwise."""
    if value is None or isinstance(value, (str, bytes)):
        raise InputTypeError(f"{name} = {_shown(value)}: {_EXPECTED}, got {type(value).__name__}")
    try:
        a = np.asarray(value)
    except (ValueError, TypeError):  # nested lists of different lengths
        raise InputError(
            f"{name} = {_shown(value)}: nested lists of different lengths; expected a "
            f"number or a rectangular array of numbers (degrees)"
        ) from None
    if a.dtype.kind in "iuf":
        return a.astype(float)
    items = np.asarray(value, dtype=object)
    bad = next((v for v in items.flat if not _is_number(v)), None) if items.size else None
    if bad is None and a.dtype.kind == "O":  # numbers held as objects
        return a.astype(float)
    if bad is None or items.ndim == 0:  # an empty array of no numbers, or one non-number
        raise InputTypeError(f"{name} = {_shown(value)}: {_EXPECTED}, got {_kind(a, value)}")
    raise InputTypeError(
        f"{name} = {_shown(value)}: {_EXPECTED}; it holds {_shown(bad)} ({type(bad).__name__})"
    )


def _is_number(v) -> bool:
    """Whether ``v`` is a real number (no bool, string, complex or None)."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _kind(a: np.ndarray, value) -> str:
    """What ``value`` (as the array ``a``) is, for a message: its type, or its array's dtype."""
    return f"an array of {a.dtype}" if isinstance(value, np.ndarray) else type(value).__name__


def _where(a: np.ndarray, bad: np.ndarray) -> str:
    """The index of the first ``bad`` element of ``a`` ("[2]", "[0, 1]"; "" for a number)."""
    if a.ndim == 0:
        return ""
    return str(list(map(int, np.argwhere(bad)[0])))


def _shape_error(arrays: list[np.ndarray]) -> InputError:
    """The InputError for angles whose shapes do not broadcast: it names the first argument
    that does not fit the ones before it, and every shape."""
    k = next(k for k in range(1, len(arrays)) if not _broadcasts(arrays[: k + 1]))
    before = " and ".join(f"{n} of shape {a.shape}" for n, a in zip(ANGLE_NAMES, arrays[:k]))
    return InputError(
        f"{ANGLE_NAMES[k]} has shape {arrays[k].shape}, which does not broadcast with "
        f"{before}: expected angles of one shape, or of shapes that broadcast together "
        f"(e.g. a number beside an array, or (3, 1) beside (4,))"
    )


def _broadcasts(arrays: list[np.ndarray]) -> bool:
    try:
        np.broadcast_shapes(*(a.shape for a in arrays))
    except ValueError:
        return False
    return True


def _shown(value) -> str:
    """``repr(value)`` on one line, cut to 60 characters."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


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
