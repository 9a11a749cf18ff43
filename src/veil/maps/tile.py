"""One tile of a map (docs/maps.md "Streaming, tiles, Dask and resuming"): its pixels solved
against the tables and written into their chunks of the store, then its marker; and the
attributes of the store the tiles are written to (``veil_maps``, docs/maps.md "Store
layout"), with the fingerprint of the inputs. A map over channels (docs/channels.md
"Maps") solves every channel of a pixel at once and writes the maps per channel with their
channel axis."""

from __future__ import annotations

import hashlib
import os

import numpy as np

from .._extras import require
from ..io import write_bytes_atomic
from .geometry_notes import geometry_record
from .solve import solve_pixels
from .solve_channels import solve_channel_pixels
from .status import STATUS
from .store import FORMAT, tile_marker
from .tables import MapTables


def solve_tile(block, tables: MapTables, store, iy, ix, tile, noise) -> np.ndarray:
    """One tile: (photos, th, tw) values ((channels, photos, th, tw) over channels) -> its
    chunks of the maps, then its marker; the count of its pixels by status."""
    zarr = require("zarr", "a maps store")

    block = np.asarray(block, dtype=np.float64)
    th, tw = block.shape[-2:]
    group = zarr.open_group(os.fspath(store), mode="r+")

    def array(name):  # every chunk written, also one of fill values (veil.maps.store)
        return group[name].with_config({"write_empty_chunks": True})

    ys, xs = slice(iy * tile, iy * tile + th), slice(ix * tile, ix * tile + tw)
    if tables.channels:
        res = _solve_channels(block, tables, iy, ix, tile, noise)
        for name, values in (
            ("channel_params", res.channel_params),
            ("channel_stderr", res.channel_stderr),
        ):
            array(name)[:, :, ys, xs] = values.reshape(values.shape[:2] + (th, tw))
    else:
        res = _solve_one(block, tables, iy, ix, tile, noise)
    n_par = res.params.shape[0]
    array("params")[:, ys, xs] = res.params.reshape(n_par, th, tw)
    array("stderr")[:, ys, xs] = res.stderr.reshape(n_par, th, tw)
    array("chi2_reduced")[ys, xs] = res.chi2.reshape(th, tw)
    array("n_points")[ys, xs] = res.n_points.reshape(th, tw)
    array("status")[ys, xs] = res.status.reshape(th, tw)
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


def _solve_one(block, tables: MapTables, iy, ix, tile, noise):
    """The pixels of a tile of one channel (:func:`veil.maps.solve.solve_pixels`)."""
    m, th, tw = block.shape
    y = block.reshape(m, th * tw).T
    valid = np.isfinite(y)
    pixels = _tile_pixels(tables, iy, ix, tile, th, tw)
    return solve_pixels(tables, np.where(valid, y, 0.0), valid, noise, pixels=pixels)


def _solve_channels(block, tables: MapTables, iy, ix, tile, noise):
    """The pixels of a tile over channels (:func:`veil.maps.solve_channels.
    solve_channel_pixels`)."""
    c, m, th, tw = block.shape
    y = np.moveaxis(block.reshape(c, m, th * tw), -1, 0)  # (pixels, channels, photos)
    valid = np.isfinite(y)
    pixels = _tile_pixels(tables, iy, ix, tile, th, tw)
    return solve_channel_pixels(tables, np.where(valid, y, 0.0), valid, noise, pixels=pixels)


def store_fingerprint(acq, tables: MapTables, noise, tile, legacy: bool = False) -> str:
    """The digest of a store's inputs (its attribute ``fingerprint``): the acquisition's
    (:meth:`veil.maps.photos.Acquisition.fingerprint`, ``legacy`` as there), the tables',
    the noise and the tile size."""
    key = acq.fingerprint(legacy=legacy) + tables.fingerprint() + repr((noise, tile))
    return hashlib.sha256(key.encode()).hexdigest()


def store_attributes(acq, tables: MapTables, cls, noise, tile, accuracy, channel, geometry) -> dict:
    """The store's attributes (``veil_maps``), with the fingerprint of its inputs; over
    channels the parameters shared (``params``) and per channel (``channel_params``) and the
    ``channels``."""
    fingerprint = store_fingerprint(acq, tables, noise, tile)
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
        "status_codes": {str(k): v for k, v in STATUS.items()},
        "grid": [a.describe() for a in tables.axes],
        "manifest": acq.name,
        "outside_mask": int(np.count_nonzero(~acq.mask)) if acq.mask is not None else 0,
        "geometry": geometry_record(tables, geometry),
    }
    if tables.channels:
        sharing = cls.channel_sharing()
        info["params"] = [n for n in tables.names if sharing[n] == "shared"]
        info["channel_params"] = [n for n in tables.names if sharing[n] != "shared"]
        info["channels"] = list(tables.channels)
    return info


__all__ = ["solve_tile", "store_attributes", "store_fingerprint"]
