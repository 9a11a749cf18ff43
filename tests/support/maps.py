"""Simulated photo stacks for the reflectance-map tests (docs/maps.md): per-pixel parameter
maps of a BRDF family seen through a medium, rendered by the engine (one evaluation per
distinct parameter vector), written as float32 TIFFs with a manifest."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd
import tifffile

from veil.engine.evaluator import ApparentModel
from veil.engine.quadrature import RULES


def angles_of(configs: pd.DataFrame) -> tuple:
    """The four angle columns (theta_i, phi_i, theta_r, phi_r) as float arrays."""
    return tuple(configs[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r"))


@functools.cache
def _protocol() -> pd.DataFrame:
    """The paper's protocol's configurations, in the order of ``veil.simulate``'s table (the
    simulated values are not used: the table is made once per process)."""
    import veil

    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.0, seed=0)
    return table[["theta_i", "phi_i", "theta_r", "phi_r"]].copy()


def configurations(count: int = 24) -> pd.DataFrame:
    """``count`` in-plane configurations spread over the paper's protocol (psi = 30, 60,
    90 deg), denser near the mirror direction."""
    table = _protocol()
    idx = np.unique(np.linspace(0, len(table) - 1, count).round().astype(int))
    return table.iloc[idx].reset_index(drop=True).copy()


def render(brdf, medium, configs: pd.DataFrame, vectors: np.ndarray) -> np.ndarray:
    """Apparent values (P, M) of the BRDF vectors (P, n_params) at the configurations."""
    angles = tuple(
        configs[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r")
    )
    engine = ApparentModel(brdf, medium, angles, RULES["default"])
    uniq, inverse = np.unique(vectors, axis=0, return_inverse=True)
    # vectors that differ only in scale parameters one after the other: the engine runs
    # its program once for them (it keeps its last terms, which the scales do not enter)
    cls = type(brdf)
    scales = {cls.scale_index(p) for p in cls.SCALES}
    shape = [k for k in range(uniq.shape[1]) if k not in scales]
    order = sorted(range(len(uniq)), key=lambda k: (tuple(uniq[k, shape]), k))
    values = np.empty((len(uniq), len(angles[0])))
    for k in order:
        values[k] = engine.values(uniq[k], medium.to_vector())
    return values[inverse.ravel()]


def write_stack(
    folder, brdf, medium, configs, param_maps: np.ndarray, noise=0.01, seed=0, suffix=".tif"
) -> Path:
    """Photos (one per configuration) of a plate whose BRDF vector at each pixel is
    ``param_maps`` (n_params, H, W); relative Gaussian noise. Returns the manifest path."""
    n, h, w = param_maps.shape
    values = render(brdf, medium, configs, param_maps.reshape(n, -1).T)  # (H*W, M)
    return write_photos(folder, configs, values, (h, w), noise, seed, suffix)


def render_near(
    brdf, medium, configs: pd.DataFrame, param_maps: np.ndarray, geometry, accuracy: str = "fast"
) -> np.ndarray:
    """Apparent values (H*W, M) of a plate seen by a near camera (``geometry``, a
    veil.maps.near.NearGeometry of the full photo ``param_maps`` is): every pixel at
    its own exact angles (collimated light, pinhole camera; docs/maps-geometry.md "Geometry"), one
    engine evaluation per distinct parameter vector over its pixels."""
    n, h, w = param_maps.shape
    angles = tuple(
        configs[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r")
    )
    yy, xx = np.mgrid[0:h, 0:w]
    pix = geometry.angles(angles, xx.ravel(), yy.ravel())  # each (H*W, M)
    vectors = param_maps.reshape(n, -1).T
    uniq, inverse = np.unique(vectors, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    out = np.empty(pix[0].shape)
    for k, v in enumerate(uniq):
        rows = np.flatnonzero(inverse == k)
        sel = tuple(a[rows].ravel() for a in pix)
        engine = ApparentModel(brdf, medium, sel, RULES[accuracy])
        out[rows] = engine.values(v, medium.to_vector()).reshape(len(rows), -1)
    return out


def write_colour_stack(
    folder, brdf, media: dict, configs, param_maps: dict, noise=0.01, seed=0, geometry=None
) -> Path:
    """RGB photos (float32 TIFFs, one per configuration) of a plate whose BRDF vector at
    each pixel is ``param_maps[c]`` (n_params, H, W) in channel c of r, g, b, seen through
    ``media[c]``; relative Gaussian noise. ``geometry`` (a NearGeometry): every pixel at
    its own exact angles (:func:`render_near`). Returns the manifest path."""
    n, h, w = param_maps["r"].shape
    if geometry is None:
        parts = [render(brdf, media[c], configs, param_maps[c].reshape(n, -1).T) for c in "rgb"]
    else:
        parts = [render_near(brdf, media[c], configs, param_maps[c], geometry) for c in "rgb"]
    values = np.stack(parts, axis=-1)  # (H*W, M, 3)
    return write_photos(folder, configs, values, (h, w), noise, seed)


def write_photos(
    folder, configs, values: np.ndarray, shape, noise=0.01, seed=0, suffix=".tif"
) -> Path:
    """Float32 TIFFs of ``values`` (H*W, M), or RGB ones of (H*W, M, 3), with relative
    Gaussian noise, and the manifest."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    h, w = shape
    rng = np.random.default_rng(seed)
    values = values * (1 + noise * rng.standard_normal(values.shape))
    names = []
    for k in range(len(configs)):
        name = f"photo_{k:03d}{suffix}"
        image = values[:, k].reshape((h, w) + values.shape[2:]).astype(np.float32)
        if image.ndim == 3:
            tifffile.imwrite(folder / name, image, photometric="rgb")
        else:
            tifffile.imwrite(folder / name, image)
        names.append(name)
    manifest = configs.assign(file=names)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]]
    path = folder / "manifest.csv"
    manifest.to_csv(path, index=False)
    return path
