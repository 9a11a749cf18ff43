"""The paper's acquisition protocol (docs/model.md sec. 1 and 7, paper sec. 5.2.1).

Light and camera are fixed at a relative angle psi (30, 60 and 90 deg in the paper) and the
object is rotated by rho; theta_i = psi/2 + rho, theta_r = psi/2 - rho (signed in-plane).
Rotations are dense near the mirror configuration (rho = 0), where the specular peak is,
and coarse elsewhere: ``fine_step`` apart while |rho| <= ``window``, then ``coarse_step``
apart continuing from the last fine rotation, as long as both |theta| < ``limit``.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..engine.angles import from_goniometer, from_signed_inplane
from ..errors import InputError
from ..numbers import format_exact
from .table_angles import _warn_radians

PSI = (30.0, 60.0, 90.0)


def _positive(name: str, value, allow_zero: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} = {value!r} is not a number (degrees)") from None
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise InputError(
            f"{name} = {value!r} deg: expected a finite number {'>= 0' if allow_zero else '> 0'}"
        )
    return v


#: Most configurations a protocol may have (sessions of the paper's protocol have ~40 per
#: psi): a larger request is refused up front with the number it would make.
MAX_CONFIGURATIONS = 100_000


def _count(reach: float, fine_step: float, coarse_step: float, window: float) -> float:
    """How many rotations :func:`rho_values` makes, computed without making them."""
    n_fine = math.floor(window / fine_step + 1e-9)
    fine = min(n_fine, max(math.ceil(reach / fine_step) - 1, 0))
    coarse = max(math.ceil((reach - n_fine * fine_step) / coarse_step) - 1, 0)
    return 1 + 2 * (fine + coarse)


def _checked(psi, fine_step, coarse_step, window, limit) -> tuple:
    """The protocol's numbers checked: (psi, fine_step, coarse_step, window, reach), reach
    being the largest |rho| with both |theta| < limit and window clamped to what it allows."""
    fine_step = _positive("fine_step", fine_step)
    coarse_step = _positive("coarse_step", coarse_step)
    window = _positive("window", window, allow_zero=True)
    limit = _positive("limit", limit)
    if limit > 90:
        raise InputError(f"limit = {format_exact(limit)} deg: polar angles must stay below 90 deg")
    psi = float(psi)
    if not (math.isfinite(psi) and 0 < psi < 180):
        raise InputError(
            f"psi = {format_exact(psi)} deg: expected a relative angle in (0, 180) deg"
        )
    if psi / 2 >= limit:
        raise InputError(
            f"psi = {format_exact(psi)} deg gives no configuration with both |theta| < "
            f"{format_exact(limit)} deg (the mirror configuration has theta = psi/2)"
        )
    reach = limit - psi / 2
    # Fine rotations past reach are never made: a window beyond reach + fine_step makes
    # the same rotations as reach + fine_step (all fine, no coarse), so clamp it there.
    return psi, fine_step, coarse_step, min(window, reach + fine_step), reach


def _check_size(count: float, fine_step: float, coarse_step: float) -> None:
    if count > MAX_CONFIGURATIONS:
        raise InputError(
            f"fine_step = {format_exact(fine_step)} deg, coarse_step = "
            f"{format_exact(coarse_step)} deg "
            f"would make {count:.3g} configurations; at most "
            f"{MAX_CONFIGURATIONS:g} are allowed (the paper's protocol has "
            f"about 40 per psi): use larger steps"
        )


def rho_values(
    psi: float,
    fine_step: float = 1.0,
    coarse_step: float = 5.0,
    window: float = 10.0,
    limit: float = 85.0,
) -> np.ndarray:
    """Ascending rotations rho (deg) of the protocol for one psi (see the module docstring)."""
    psi, fine_step, coarse_step, window, reach = _checked(
        psi, fine_step, coarse_step, window, limit
    )
    _check_size(_count(reach, fine_step, coarse_step, window), fine_step, coarse_step)
    n_fine = int(math.floor(window / fine_step + 1e-9))
    pos = [k * fine_step for k in range(1, n_fine + 1) if k * fine_step < reach]
    last = n_fine * fine_step
    j = 1
    while last + j * coarse_step < reach:
        pos.append(last + j * coarse_step)
        j += 1
    arr = np.array(pos, dtype=float)
    return np.concatenate([-arr[::-1], [0.0], arr])


def protocol(
    psi=PSI,
    fine_step: float = 1.0,
    coarse_step: float = 5.0,
    window: float = 10.0,
    limit: float = 85.0,
) -> pd.DataFrame:
    """Configurations of the paper's protocol: columns psi, rho, theta_i, phi_i, theta_r, phi_r.

    One block per psi (in the given order), rho ascending; angles in degrees, the last four
    columns canonical (unsigned polar angles with azimuths, docs/model.md sec. 1).
    """
    if np.ndim(psi) == 0:
        psi = (psi,)
    psis = []
    for p in psi:
        try:
            psis.append(float(p))
        except (TypeError, ValueError):
            raise InputError(f"psi = {p!r} is not a number (degrees)") from None
    if not psis:
        raise InputError("psi is empty: give at least one relative angle (degrees)")
    if len(set(psis)) != len(psis):
        raise InputError(f"psi = {psis}: a relative angle is repeated")
    _warn_radians({"psi": np.array(psis)}, f"psi = {psis}")
    checked = [_checked(p, fine_step, coarse_step, window, limit) for p in psis]
    _check_size(sum(_count(c[4], *c[1:4]) for c in checked), *checked[0][1:3])
    blocks = []
    for p in psis:
        rho = rho_values(p, fine_step, coarse_step, window, limit)
        blocks.append((np.full(rho.shape, p), rho))
    psi_all = np.concatenate([b[0] for b in blocks])
    rho_all = np.concatenate([b[1] for b in blocks])
    ti, pi_, tr, pr = from_signed_inplane(*from_goniometer(psi_all, rho_all))
    return pd.DataFrame(
        {"psi": psi_all, "rho": rho_all, "theta_i": ti, "phi_i": pi_, "theta_r": tr, "phi_r": pr}
    )


__all__ = ["protocol", "rho_values", "PSI", "MAX_CONFIGURATIONS"]
