"""Measured BRDFs in the MERL binary format (Matusik et al. 2003), the isotropic measured
BRDFs of the field (docs/interop.md).

Layout: three int32 (little-endian) dimensions, 90, 90, 180 (theta_h, theta_d, phi_d), then
3 x 90 x 90 x 180 float64 values, the red, green and blue channels one after the other, each
indexed as ``phi_d + 180 (theta_d + 90 theta_h)``. A channel's value times its scale
(:data:`SCALES`: 1/1500, 1.15/1500, 1.66/1500) is the BRDF in 1/sr, without the cosine.
Indices (the reference code's, ``BRDFRead.cpp``):

- theta_h: int(sqrt(theta_h / (pi/2) x 90 x 90)), clamped to [0, 89] (0 for theta_h <= 0):
  the half-angle axis is denser near the normal;
- theta_d: int(theta_d / (pi/2) x 90), clamped to [0, 89];
- phi_d: phi_d + pi when negative (reciprocity), then int(phi_d / pi x 180), clamped to
  [0, 179].

theta_d and phi_d are the polar and azimuthal angles of the light in the frame of the half
vector (Rusinkiewicz's coordinates). veil's f_r includes cos theta_i (docs/model.md sec. 1), so
:func:`reflectance` returns the table value times cos theta_i. Lookups are nearest-cell,
as the reference code's.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError, MissingFileError, NotAFileError
from .protocol import PSI, protocol

DIMS = (90, 90, 180)
HEADER_BYTES = 12
N_CELLS = DIMS[0] * DIMS[1] * DIMS[2]
FILE_BYTES = HEADER_BYTES + 3 * N_CELLS * 8
CHANNELS = ("r", "g", "b")
SCALES = {"r": 1.0 / 1500.0, "g": 1.15 / 1500.0, "b": 1.66 / 1500.0}
#: In-plane configurations ("inplane" sampling): theta_i 0..85 and signed theta_r -85..85 deg.
INPLANE_STEP = 5.0
INPLANE_LIMIT = 85.0
SAMPLINGS = ("protocol", "inplane")


class MerlError(InputError):
    """A MERL file that is not one (size, dimensions, values)."""


@dataclass(frozen=True)
class MerlBRDF:
    """One MERL file: ``data`` of shape (3, 90, 90, 180), raw (before the channel scales)."""

    path: str
    data: np.ndarray

    def channel(self, name: str) -> np.ndarray:
        if name not in CHANNELS:
            raise InputError(f"channel {name!r}; expected one of {', '.join(CHANNELS)}")
        return self.data[CHANNELS.index(name)] * SCALES[name]


def read_merl(path) -> MerlBRDF:
    """Read and check a MERL binary file (module docstring); a MerlError names the file and
    what is wrong (size, dimensions, non-finite values)."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as fh:
            raw = fh.read(FILE_BYTES + 1)
    except FileNotFoundError:
        raise MissingFileError(f"MERL file {name} does not exist") from None
    except IsADirectoryError:
        raise NotAFileError(f"MERL file {name} is a directory") from None
    if len(raw) < HEADER_BYTES:
        raise MerlError(
            f"{name}: {len(raw)} bytes; a MERL file starts with three int32 "
            f"dimensions {DIMS} and has {FILE_BYTES} bytes in all"
        )
    dims = tuple(int(d) for d in np.frombuffer(raw[:HEADER_BYTES], dtype="<i4"))
    if dims != DIMS:
        raise MerlError(
            f"{name}: dimensions {dims}; a MERL file has {DIMS} (theta_h, theta_d, phi_d)"
        )
    if len(raw) != FILE_BYTES:
        size = len(raw) if len(raw) <= FILE_BYTES else f"more than {FILE_BYTES}"
        raise MerlError(
            f"{name}: {size} "
            f"bytes; a MERL file of dimensions {DIMS} has exactly {FILE_BYTES} "
            f"(12 header bytes + 3 channels x {N_CELLS} float64)"
        )
    data = np.frombuffer(raw[HEADER_BYTES:], dtype="<f8").reshape((3,) + DIMS)
    bad = ~np.isfinite(data)
    if bad.any():
        c, h, d, p = (int(x[0]) for x in np.nonzero(bad))
        raise MerlError(
            f"{name}: {int(bad.sum())} values are not finite numbers, the first in "
            f"channel {CHANNELS[c]} at index (theta_h {h}, theta_d {d}, phi_d {p})"
        )
    return MerlBRDF(name, data.copy())


def _rotate(v, axis, angle):
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    axis = np.broadcast_to(np.asarray(axis, dtype=float), v.shape)
    dot = np.sum(axis * v, axis=-1, keepdims=True)
    return v * c + axis * dot * (1.0 - c) + np.cross(axis, v) * s


def half_diff(wi, wo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(theta_h, theta_d, phi_d) in radians of unit vectors ``wi`` (light), ``wo`` (view)."""
    wi, wo = np.asarray(wi, dtype=float), np.asarray(wo, dtype=float)
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    tmp = _rotate(wi, (0.0, 0.0, 1.0), -phi_h)
    diff = _rotate(tmp, (0.0, 1.0, 0.0), -theta_h)
    theta_d = np.arccos(np.clip(diff[..., 2], -1.0, 1.0))
    phi_d = np.arctan2(diff[..., 1], diff[..., 0])
    return theta_h, theta_d, phi_d


def indices(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table cell (theta_h, theta_d, phi_d indices) of half/difference angles (radians),
    as the reference code computes it (module docstring)."""
    theta_h = np.asarray(theta_h, dtype=float)
    deg = theta_h / (0.5 * math.pi) * 90.0
    ih = np.where(theta_h <= 0, 0, np.floor(np.sqrt(np.maximum(deg, 0.0) * 90.0)))
    ih = np.clip(ih, 0, DIMS[0] - 1).astype(int)
    idd = np.clip(np.floor(np.asarray(theta_d) / (0.5 * math.pi) * 90.0), 0, DIMS[1] - 1)
    phi = np.where(np.asarray(phi_d) < 0, np.asarray(phi_d) + math.pi, phi_d)
    ip = np.clip(np.floor(phi / math.pi * 180.0), 0, DIMS[2] - 1)
    return ih, idd.astype(int), ip.astype(int)


def reflectance(
    brdf: MerlBRDF, channel: str, theta_i, theta_r, phi_i=180.0, phi_r=0.0
) -> np.ndarray:
    """f_r = table value x cos theta_i (veil's convention) at the given angles (degrees);
    a MerlError when a needed cell is negative (unmeasured)."""
    from ..engine.angles import check_angles, direction

    ti, tr, pi_, pr = check_angles(theta_i, theta_r, phi_i, phi_r)
    wi, wo = np.asarray(direction(ti, pi_)), np.asarray(direction(tr, pr))
    ih, idd, ip = indices(*half_diff(wi, wo))
    table = brdf.channel(channel)
    values = table[ih, idd, ip]
    neg = values < 0
    if np.any(neg):
        k = int(np.flatnonzero(neg.ravel())[0])
        raise MerlError(
            f"{brdf.path}: negative value {values.ravel()[k]:g} in channel "
            f"{channel} at index (theta_h {ih.ravel()[k]}, theta_d "
            f"{idd.ravel()[k]}, phi_d {ip.ravel()[k]}), needed at theta_i "
            f"{np.ravel(ti)[k]:g}, theta_r {np.ravel(tr)[k]:g} deg; a BRDF "
            f"table must hold values >= 0 (negative marks unmeasured cells)"
        )
    return values * np.cos(np.deg2rad(ti))


def configurations(sampling: str = "protocol", psi=PSI) -> pd.DataFrame:
    """Where a MERL BRDF is sampled: the paper's protocol, or every in-plane configuration
    on a 5-degree grid (theta_i 0..85, signed theta_r -85..85), as a measurement table's
    angle columns (full form)."""
    if sampling == "protocol":
        return protocol(psi)[["psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r"]]
    if sampling != "inplane":
        raise InputError(f"sampling {sampling!r}; expected one of {', '.join(SAMPLINGS)}")
    from ..engine.angles import from_signed_inplane

    n = int(round(INPLANE_LIMIT / INPLANE_STEP))
    ti = np.arange(0, n + 1) * INPLANE_STEP
    tr = np.arange(-n, n + 1) * INPLANE_STEP
    a, b = np.meshgrid(ti, tr, indexing="ij")
    t_i, p_i, t_r, p_r = from_signed_inplane(a.ravel(), b.ravel())
    return pd.DataFrame({"theta_i": t_i, "phi_i": p_i, "theta_r": t_r, "phi_r": p_r})


def measurement_table(
    brdf: MerlBRDF, channel: str, sampling: str = "protocol", relative_sigma: float = 0.01
) -> pd.DataFrame:
    """A measurement table (docs/measurements.md) of the MERL BRDF's f_r at
    :func:`configurations`, sigma = ``relative_sigma`` x value (a relative fit); cells where
    the BRDF is 0 get the smallest positive sigma of the table."""
    table = configurations(sampling).copy()
    values = reflectance(
        brdf,
        channel,
        table["theta_i"].to_numpy(),
        table["theta_r"].to_numpy(),
        table["phi_i"].to_numpy(),
        table["phi_r"].to_numpy(),
    )
    if not np.any(values > 0):
        raise MerlError(f"{brdf.path}: channel {channel} is 0 at every configuration")
    sigma = relative_sigma * values
    sigma = np.where(sigma > 0, sigma, np.min(sigma[sigma > 0]))
    table["value"] = values
    table["sigma"] = sigma
    table.attrs["veil_name"] = f"the table sampled from {brdf.path}"
    return table


def channels_table(
    brdf: MerlBRDF, channels=CHANNELS, sampling: str = "protocol", relative_sigma: float = 0.01
) -> pd.DataFrame:
    """A measurement table of several channels of the MERL BRDF (docs/measurements.md,
    "Channels"): :func:`measurement_table` of each channel, channel after channel, with a
    ``channel`` column before ``value`` and ``sigma``; a fit of it fits the channels at once
    (docs/channels.md)."""
    from .channels import CHANNEL

    names = [str(c) for c in channels]
    unknown = [c for c in names if c not in CHANNELS]
    if unknown or not names or len(set(names)) != len(names):
        raise InputError(
            f"{brdf.path}: channels {', '.join(names) or 'none'}; a MERL file has "
            f"the channels {', '.join(CHANNELS)} (each at most once)"
        )
    parts = []
    for c in names:
        part = measurement_table(brdf, c, sampling, relative_sigma)
        part.insert(len(part.columns) - 2, CHANNEL, c)
        parts.append(part)
    table = pd.concat(parts, ignore_index=True)
    table.attrs["veil_name"] = f"the table sampled from {brdf.path}"
    return table


def write_merl(path, data) -> None:
    """Write raw channel data of shape (3, 90, 90, 180) as a MERL file (atomically)."""
    from ..io import write_bytes_atomic

    data = np.asarray(data, dtype="<f8")
    if data.shape != (3,) + DIMS:
        raise InputError(f"MERL data has shape {data.shape}; expected {(3,) + DIMS}")
    write_bytes_atomic(path, np.asarray(DIMS, dtype="<i4").tobytes() + data.tobytes())


__all__ = [
    "MerlBRDF",
    "MerlError",
    "read_merl",
    "write_merl",
    "half_diff",
    "indices",
    "reflectance",
    "configurations",
    "measurement_table",
    "channels_table",
    "DIMS",
    "SCALES",
    "CHANNELS",
    "SAMPLINGS",
]
