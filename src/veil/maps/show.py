"""Reflectance maps for people (docs/maps.md): a figure with one panel per fitted parameter,
its standard error and the reduced chi-square (colour bars, units, unconverged pixels
grey), export of every map as float32 TIFF and OpenEXR, and the JSON summary."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np

from .._extras import require
from ..errors import InputError
from ..io import output_folder, write_bytes_atomic, write_text_atomic
from .geometry_notes import MapsWarning
from .status import CONVERGED, STATUS
from .status import FEW_POINTS as STATUS_FEW
from .status import MASKED as STATUS_MASKED
from .store import free_maps, open_maps, summarize_maps

FORMATS = ("tiff", "exr")


def _panels(maps):
    """(title, image, colour-bar label, log scale) of each panel."""
    info = maps["info"]
    ok = maps["status"] == CONVERGED
    units = info.get("units", {})
    out = []
    for name, value, err in free_maps(maps):
        unit = units.get(name.split("[")[0]) or "relative units"
        value = np.where(ok, value, np.nan)
        err = np.where(ok, err, np.nan)
        positive = np.nanmin(value) > 0 if ok.any() else False
        spread = np.nanmax(value) / np.nanmin(value) if positive else 1.0
        out.append((name, value, f"{name} [{unit}]", bool(positive and spread > 30)))
        out.append((f"stderr of {name}", err, f"[{unit}]", False))
    fitted = (maps["status"] != STATUS_MASKED) & (maps["status"] != STATUS_FEW)
    chi = np.where(fitted, maps["chi2_reduced"], np.nan)
    label = (
        "reduced chi-square" if info.get("weighted") else "residual variance [value^2] (unweighted)"
    )
    out.append(
        ("reduced chi-square" if info.get("weighted") else "residual variance", chi, label, False)
    )
    if "model_error" in maps:  # docs/maps-model-error.md: s per channel
        names = info.get("channels") or [""]
        for j, c in enumerate(names):
            title = f"model error s[{c}]" if c else "model error s"
            image = np.where(ok, maps["model_error"][j], np.nan)
            out.append((title, image, "relative model error s", False))
    if "stderr_medium" in maps:  # docs/maps-medium-error.md: its share of each stderr
        parts = free_maps(maps, ("stderr_medium", "channel_stderr_medium"))
        for (name, _, err), (_, _, part) in zip(free_maps(maps), parts):
            share = np.where(ok & (err > 0), part / np.where(err > 0, err, 1.0), np.nan)
            out.append((f"medium's share of stderr of {name}", share, "part / stderr", False))
    return out


def maps_figure(store, path, *, dpi: int = 110) -> Path:
    """One figure of a complete maps store: every free parameter, its standard error, the
    reduced chi-square and the status map (with the model's error its s per channel, with
    the medium's uncertainty its share of each standard error); written atomically as
    PNG/PDF/SVG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import BoundaryNorm, ListedColormap, LogNorm, Normalize

    maps = open_maps(store)
    panels = _panels(maps)
    n = len(panels) + 1
    cols = min(4, n)
    rows = -(-n // cols)
    h, w = maps["status"].shape
    aspect = h / max(w, 1)
    fig, axes = plt.subplots(
        rows, cols, figsize=(4.2 * cols, 3.6 * rows * max(aspect, 0.4)), squeeze=False
    )
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.75")
    for ax, (title, image, label, log) in zip(axes.flat, panels):
        finite = np.isfinite(image)
        norm: Normalize | None = None
        if finite.any():
            lo, hi = np.percentile(image[finite], [1, 99])
            if log:
                norm = LogNorm(max(lo, 1e-300), max(hi, lo * 1.0001))
            elif hi > lo:
                norm = Normalize(lo, hi)
        im = ax.imshow(np.ma.masked_invalid(image), cmap=cmap, norm=norm, interpolation="nearest")
        fig.colorbar(im, ax=ax, label=label, shrink=0.85)
        ax.set_title(title)
        ax.set_xticks([])
        ax.set_yticks([])
    ax = axes.flat[len(panels)]
    colours = ["#2ca02c", "#d9d9d9", "#ff7f0e", "#d62728", "#9467bd", "#8c564b"]
    im = ax.imshow(
        maps["status"],
        cmap=ListedColormap(colours),
        norm=BoundaryNorm(np.arange(len(STATUS) + 1) - 0.5, len(STATUS)),
        interpolation="nearest",
    )
    bar = fig.colorbar(im, ax=ax, ticks=list(STATUS), shrink=0.85)
    bar.ax.set_yticklabels([STATUS[k].split(" (")[0] for k in STATUS], fontsize=7)
    ax.set_title("status (grey in the other panels: not converged)")
    ax.set_xticks([])
    ax.set_yticks([])
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    info = maps["info"]
    geometry = info.get("geometry") or {}
    camera = (
        f", near-field camera at {geometry['camera_distance']:g} (pixel "
        f"{geometry['pixel_pitch']:g})"
        if geometry.get("kind") == "near-field"
        else ""
    )
    fig.suptitle(
        f"{info['model']} through {info['medium']['model']}: {h} x {w} pixels, "
        f"{info['photos']} photos{camera}",
        fontsize=11,
    )
    fig.tight_layout()
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".") or "png"
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
    return path


def _exr_bytes(image: np.ndarray, channels=()) -> bytes:
    """An OpenEXR file of ``image`` (H, W): one channel Y; with ``channels`` (C, H, W), one
    EXR channel per colour channel, named in capitals (R, G, B)."""
    import tempfile

    OpenEXR = require("OpenEXR", "writing an EXR map")

    planes = (
        {
            c.upper(): np.ascontiguousarray(image[k], dtype=np.float32)
            for k, c in enumerate(channels)
        }
        if channels
        else {"Y": np.ascontiguousarray(image, dtype=np.float32)}
    )
    with tempfile.TemporaryDirectory() as tmp:
        name = os.path.join(tmp, "map.exr")
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        with OpenEXR.File(header, planes) as f:
            f.write(name)
        with open(name, "rb") as fh:
            return fh.read()


def _tiff_bytes(image: np.ndarray, channels=()) -> bytes:
    """A float32 TIFF of ``image`` (H, W); with ``channels`` (C, H, W): an RGB image (H, W,
    3) of the channels r, g, b, else the channels as planes (C, H, W) in their order."""
    import io

    tifffile = require("tifffile", "writing a TIFF map")

    buf = io.BytesIO()
    if tuple(channels) == ("r", "g", "b"):
        rgb = np.ascontiguousarray(np.moveaxis(image, 0, -1), dtype=np.float32)
        tifffile.imwrite(buf, rgb, photometric="rgb")
    elif channels:
        planes = np.ascontiguousarray(image, dtype=np.float32)
        tifffile.imwrite(buf, planes, photometric="minisblack", planarconfig="separate")
    else:
        tifffile.imwrite(buf, np.ascontiguousarray(image, dtype=np.float32))
    return buf.getvalue()


def export_maps(store, folder, formats=FORMATS) -> list[Path]:
    """Every map of a complete store as float32 images (``formats``: tiff, exr) in
    ``folder``: NAME, NAME_stderr for each free parameter, chi2_reduced, status (0 =
    converged; docs/maps.md), plus summary.json; with the model's error also model_error
    and NAME_stderr_noise, with the medium's uncertainty NAME_stderr_medium (its part of
    NAME_stderr). Unconverged pixels hold 0 in the value
    maps; the status map says which. A parameter per channel of a map over channels is one
    image of every channel: RGB (EXR channels R, G, B; an RGB TIFF)."""
    bad = [f for f in formats if f not in FORMATS]
    if bad:
        raise InputError(f"export format {bad[0]!r}: expected {', '.join(FORMATS)}")
    maps = open_maps(store)
    info = maps["info"]
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder} exists and is not a directory")
    ok = maps["status"] == CONVERGED
    images: dict = {}
    for k, name in enumerate(info["params"]):
        if name in info["free"]:
            images[name] = (np.where(ok, maps["params"][k], 0.0), ())
            images[f"{name}_stderr"] = (np.where(ok, maps["stderr"][k], 0.0), ())
    channels = tuple(info.get("channels") or ())
    for k, name in enumerate(info.get("channel_params") or ()):
        if name in info["free"]:  # one image of every channel
            images[name] = (np.where(ok, maps["channel_params"][k], 0.0), channels)
            images[f"{name}_stderr"] = (np.where(ok, maps["channel_stderr"][k], 0.0), channels)
    images["chi2_reduced"] = (maps["chi2_reduced"], ())
    images["status"] = (maps["status"].astype(np.float32), ())
    if "model_error" in maps:
        images.update(_error_images(maps, ok))
    if "stderr_medium" in maps:  # docs/maps-medium-error.md
        images.update(_part_images(maps, ok, "medium"))

    images = {name: (_in_float32(name, image), planes) for name, (image, planes) in images.items()}

    def file(name, fmt):
        return f"{name}.{'tif' if fmt == 'tiff' else 'exr'}"

    # one transaction (veil.io.output_folder): a failed or concurrent export never leaves
    # a mix; a rerun replaces the files of the earlier one (those of a format it does not
    # write included)
    owned = [file(n, f) for n in images for f in FORMATS] + ["summary.json"]
    names = []
    with output_folder(folder, owned=owned) as staging:
        for name, (image, planes) in images.items():
            for fmt in formats:
                names.append(file(name, fmt))
                write_bytes_atomic(
                    staging / names[-1],
                    _tiff_bytes(image, planes) if fmt == "tiff" else _exr_bytes(image, planes),
                )
        names.append("summary.json")
        write_text_atomic(
            staging / "summary.json", json.dumps(summarize_maps(store, maps), indent=2) + "\n"
        )
    return [folder / n for n in names]


def _in_float32(name: str, image: np.ndarray) -> np.ndarray:
    """``image`` within float32's range, as the files hold it: a value beyond (a reduced
    chi-square of a noise far below the data's) is written as float32's largest of its sign,
    not as an infinity, with a MapsWarning naming the map; the store keeps the value."""
    top = float(np.finfo(np.float32).max)
    image = np.asarray(image, dtype=float)
    big = np.abs(image) > top
    if big.any():
        warnings.warn(
            MapsWarning(
                f"{name}: {int(np.count_nonzero(big))} pixel(s) beyond float32's range "
                f"(largest {float(np.max(np.abs(image[big]))):.4g}) written as {top:.4g}, "
                f"float32's largest; the store keeps the values"
            ),
            stacklevel=3,
        )
        image = np.clip(image, -top, top)
    return image


def _error_images(maps: dict, ok) -> dict:
    """A store with the model's error (docs/maps-model-error.md): ``model_error`` (s; RGB
    over channels) and NAME_stderr_noise, the standard errors of the noise alone, for each
    free parameter."""
    channels = tuple(maps["info"].get("channels") or ())
    s = maps["model_error"] if channels else maps["model_error"][0]
    return {"model_error": (np.where(ok, s, 0.0), channels)} | _part_images(maps, ok, "noise")


def _part_images(maps: dict, ok, part: str) -> dict:
    """NAME_stderr_PART of each free parameter: the part (``noise``, ``medium``) of its
    standard errors a store holds (``stderr_PART``, over channels ``channel_stderr_PART``)."""
    info = maps["info"]
    channels = tuple(info.get("channels") or ())
    images = {}
    for k, name in enumerate(info["params"]):
        if name in info["free"]:
            images[f"{name}_stderr_{part}"] = (np.where(ok, maps[f"stderr_{part}"][k], 0.0), ())
    for k, name in enumerate(info.get("channel_params") or ()):
        if name in info["free"]:
            image = np.where(ok, maps[f"channel_stderr_{part}"][k], 0.0)
            images[f"{name}_stderr_{part}"] = (image, channels)
    return images


__all__ = ["maps_figure", "export_maps", "FORMATS"]
