"""One tile of a map (docs/maps.md "Streaming, tiles, Dask and resuming"): its pixels solved
against the tables and written into their chunks of the store, then its marker; and the
attributes of the store the tiles are written to (``veil_maps``, docs/maps.md "Store
layout"), with the fingerprint of the inputs. A map over channels (docs/channels.md
"Maps") solves every channel of a pixel at once and writes the maps per channel with their
channel axis."""

from __future__ import annotations

import dataclasses
import hashlib
import os
from typing import Any

import numpy as np

from .._extras import require
from ..io import write_bytes_atomic
from .geometry_notes import geometry_record
from .medium_error import fingerprint_key as spread_key
from .medium_error import medium_variance
from .medium_error import record as spread_record
from .model_error import (
    fingerprint_key,
    noise_basis,
    record,
    solver_stderr,
    with_solver_stderr,
    with_term,
)
from .solve import has_relative_noise, solve_pixels
from .solve_channels import solve_channel_pixels
from .status import CONVERGED, STATUS
from .store import FORMAT, tile_marker
from .tables import MapTables


def solve_tile(block, tables: MapTables, store, iy, ix, tile, noise, added=None) -> np.ndarray:
    """One tile: (photos, th, tw) values ((channels, photos, th, tw) over channels) -> its
    chunks of the maps, then its marker; the count of its pixels by status. ``added``:
    what the standard errors take beyond the noise, (the model's error, the medium's
    spread), each or both None (:class:`veil.maps.model_error.Discrepancy`,
    :class:`veil.maps.medium_error.MediumSpread`), or None."""
    zarr = require("zarr", "a maps store")

    block = np.asarray(block, dtype=np.float64)
    th, tw = block.shape[-2:]
    group = zarr.open_group(os.fspath(store), mode="r+")

    def array(name):  # every chunk written, also one of fill values (veil.maps.store)
        return group[name].with_config({"write_empty_chunks": True})

    def put(name, values):  # (..., pixels) into the tile's chunk of a (..., h, w) map
        array(name)[..., ys, xs] = values.reshape(values.shape[:-1] + (th, tw))

    ys, xs = slice(iy * tile, iy * tile + th), slice(ix * tile, ix * tile + tw)
    setting, spread = added or (None, None)
    tile_rows = (*_values(block, tables), _tile_pixels(tables, iy, ix, tile, th, tw))
    res, noise_only, terms, basis = _fits(tile_rows, tables, noise, setting)
    if spread is not None:
        res, medium_part = _with_medium(tile_rows, tables, res, noise, spread, basis)
        put("stderr_medium", medium_part.stderr)
        if tables.channels:
            put("channel_stderr_medium", medium_part.channel_stderr)
    if tables.channels:
        put("channel_params", res.channel_params)
        put("channel_stderr", res.channel_stderr)
    for name, values in (
        ("params", res.params),
        ("stderr", res.stderr),
        ("chi2_reduced", res.chi2),
        ("n_points", res.n_points),
        ("status", res.status),
    ):
        put(name, values)
    if terms is not None:
        put("model_error", terms[0])
        put("model_error_length", terms[1])
        put("stderr_noise", noise_only.stderr)
        if tables.channels:
            put("channel_stderr_noise", noise_only.channel_stderr)
    write_bytes_atomic(tile_marker(store, iy, ix), b"done\n")
    return np.bincount(res.status, minlength=len(STATUS))


def _tile_pixels(tables: MapTables, iy, ix, tile, th, tw):
    """Near-field tables: the positions (x, y) of the tile's pixels in the full photo;
    None for distant tables."""
    if tables.near is None:
        return None
    x0, y0 = tables.near.roi[:2]
    rows, cols = np.mgrid[0:th, 0:tw]
    return ((x0 + ix * tile + cols).ravel(), (y0 + iy * tile + rows).ravel())


def _values(block, tables: MapTables) -> tuple:
    """A tile's (values, usable samples) as its solve takes them: (pixels, photos), over
    channels (pixels, channels, photos); unusable ones at 0."""
    th, tw = block.shape[-2:]
    if tables.channels:
        y = np.moveaxis(block.reshape(block.shape[0], block.shape[1], th * tw), -1, 0)
    else:
        y = block.reshape(block.shape[0], th * tw).T
    valid = np.isfinite(y)
    return np.where(valid, y, 0.0), valid


def _with_medium(tile_rows, tables: MapTables, fits, noise, spread, basis) -> tuple:
    """(``fits`` with the medium's part in every converged pixel's standard errors, the
    fits with that part alone as their standard errors; :mod:`veil.maps.medium_error`);
    ``tile_rows``: the tile's values, usable samples and pixel positions; ``basis`` the
    values the noise was taken of."""
    y, valid, pixels = tile_rows
    var = medium_variance(tables, spread, fits, y, valid, noise, pixels, basis)
    ok = fits.status == CONVERGED
    total = np.sqrt(solver_stderr(tables, fits) ** 2 + var)
    zero = dataclasses.replace(fits, stderr=np.zeros_like(fits.stderr))
    if tables.channels:
        zero = dataclasses.replace(zero, channel_stderr=np.zeros_like(fits.channel_stderr))
    part = with_solver_stderr(tables, zero, np.sqrt(var), ok)
    return with_solver_stderr(tables, fits, total, ok), part


def _fits(tile_rows, tables: MapTables, noise, setting) -> tuple:
    """The tile's pixels solved (:func:`veil.maps.solve.solve_pixels`, over channels
    :func:`veil.maps.solve_channels.solve_channel_pixels`): (fits, None, None, basis), or
    with a ``setting`` (fits with the model's error, the fits without it, (s, ell) per
    channel and pixel, basis) (:func:`veil.maps.model_error.with_term`); ``tile_rows`` as
    :func:`_with_medium`'s. With a relative noise the pixels are solved twice, the second
    time with the noise of the first solution's values (``basis``,
    :func:`veil.maps.model_error.noise_basis`; docs/maps-noise.md); else basis is None."""
    y, valid, pixels = tile_rows
    solve: Any = solve_channel_pixels if tables.channels else solve_pixels
    res = solve(tables, y, valid, noise, pixels=pixels)
    basis = None
    if has_relative_noise(noise):
        basis = noise_basis(tables, res, y, pixels)
        res = solve(tables, y, valid, noise, pixels=pixels, basis=basis)
    if setting is None:
        return res, None, None, basis
    with_error, sigma, length = with_term(tables, res, y, valid, noise, pixels, setting, basis)
    return with_error, res, (sigma, length), basis


def store_fingerprint(acq, tables: MapTables, noise, tile, legacy: bool = False, added=None) -> str:
    """The digest of a store's inputs (its attribute ``fingerprint``): the acquisition's
    (:meth:`veil.maps.photos.Acquisition.fingerprint`, ``legacy`` as there), the tables',
    the noise, the tile size, the model's error and the medium's spread (``added`` as
    :func:`solve_tile`'s, when there are)."""
    setting, spread = added or (None, None)
    key = acq.fingerprint(legacy=legacy) + tables.fingerprint() + repr((noise, tile))
    if has_relative_noise(noise):  # of the model's values since 2026-12-07
        key += "relative noise of the model's values"
    if setting is not None:
        key += fingerprint_key(setting)
    if spread is not None:
        key += spread_key(spread)
    return hashlib.sha256(key.encode()).hexdigest()


def store_attributes(
    acq, tables: MapTables, cls, noise, tile, accuracy, channel, geometry, added=None
) -> dict:
    """The store's attributes (``veil_maps``), with the fingerprint of its inputs; over
    channels the parameters shared (``params``) and per channel (``channel_params``) and the
    ``channels``; with the model's error its kind, floor and given term (``model_error``),
    with the medium's spread its parameters, values, errors and steps (``propagation``;
    ``added`` as :func:`solve_tile`'s)."""
    setting, spread = added or (None, None)
    fingerprint = store_fingerprint(acq, tables, noise, tile, added=added)
    shape = (acq.roi.h, acq.roi.w)
    info = {
        "format": FORMAT,
        "fingerprint": fingerprint,
        "model": tables.model,
        "options": tables.options,
        "params": list(tables.names),
        "free": list(tables.free_names),
        "fixed_values": {
            n: float(tables.base[i])
            for i, n in enumerate(tables.names)
            if n not in tables.free_names
        },
        "units": {p.name: p.unit for p in cls.PARAMS},
        "medium": tables.medium,
        "accuracy": accuracy,
        "roi": str(acq.roi),
        "shape": list(shape),
        "tile": tile,
        "photos": len(acq.paths),
        "channel": channel if isinstance(channel, str) else ",".join(channel),
        "noise": list(noise) if noise else None,
        "weighted": noise is not None,
        "noise_of": "the model's values at a first solution" if has_relative_noise(noise) else None,
        "status_codes": {str(k): v for k, v in STATUS.items()},
        "grid": [a.describe() for a in tables.axes],
        "manifest": os.path.abspath(acq.name),  # --blur-from compares it from anywhere
        "outside_mask": int(np.count_nonzero(~acq.mask)) if acq.mask is not None else 0,
        "geometry": geometry_record(tables, geometry),
    }
    if tables.channels:
        sharing = cls.channel_sharing()
        info["params"] = [n for n in tables.names if sharing[n] == "shared"]
        info["channel_params"] = [n for n in tables.names if sharing[n] != "shared"]
        info["channels"] = list(tables.channels)
    if setting is not None:
        info["model_error"] = record(setting)
    if spread is not None:
        info["propagation"] = spread_record(spread)
    return info


__all__ = ["solve_tile", "store_attributes", "store_fingerprint"]
