"""Photos decoded to their regions of interest (docs/ingest.md): PNG and JPEG, TIFF (8/16-bit
integer, float) and camera raw through LibRaw (rawpy), one photo at a time, only its ROIs
kept (:func:`read_photo`)."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require
from ..errors import InputError, MissingFileError, UnwritableError
from .roi import ROI

PNG_SUFFIXES = frozenset({".png"})
JPEG_SUFFIXES = frozenset({".jpg", ".jpeg", ".jpe"})
TIFF_SUFFIXES = frozenset({".tif", ".tiff"})
RAW_SUFFIXES = frozenset(
    {
        ".3fr",
        ".ari",
        ".arw",
        ".bay",
        ".cr2",
        ".cr3",
        ".crw",
        ".dcr",
        ".dng",
        ".erf",
        ".fff",
        ".iiq",
        ".k25",
        ".kdc",
        ".mef",
        ".mos",
        ".mrw",
        ".nef",
        ".nrw",
        ".orf",
        ".pef",
        ".raf",
        ".raw",
        ".rw2",
        ".rwl",
        ".sr2",
        ".srf",
        ".srw",
        ".x3f",
    }
)
PHOTO_SUFFIXES = PNG_SUFFIXES | JPEG_SUFFIXES | TIFF_SUFFIXES | RAW_SUFFIXES


@dataclass
class Patch:
    """The code values of one ROI as stored in the file, plus what is needed to read them."""

    values: np.ndarray  # (h, w, c) for images, (h, w) for a raw mosaic
    cfa: np.ndarray | None = None  # raw mosaic: 0, 1, 2 = R, G, B per photosite
    black: np.ndarray | None = None  # raw mosaic: black level per photosite


@dataclass
class Photo:
    """One decoded photo reduced to its ROIs."""

    path: Path
    kind: str  # "png", "jpeg", "tiff", "raw"
    shape: tuple  # (height, width, channels); channels = 1 for a raw mosaic
    saturation: float | None  # the format's maximum code value (None: float data)
    floor: float | None  # code value of pixels clipped from below (None: float data)
    patches: list
    #: camera raw: the camera's as-shot white-balance multipliers of R, G, B scaled so that
    #: G is 1 (LibRaw's camera_whitebalance; never applied); None when it recorded none
    white_balance: tuple | None = None

    @property
    def dtype(self) -> np.dtype:
        return self.patches[0].values.dtype


def _check_roi(roi: ROI, name: str, height: int, width: int, path: Path) -> None:
    if roi.x + roi.w > width or roi.y + roi.h > height:
        raise InputError(
            f"{path}: {name} {roi} (x {roi.x}..{roi.x + roi.w - 1}, y "
            f"{roi.y}..{roi.y + roi.h - 1}) lies outside the image, which is "
            f"{width} x {height} pixels (x 0..{width - 1}, y 0..{height - 1})"
        )


def _int_limits(dtype: np.dtype):
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        return float(info.max), float(info.min)
    if dtype.kind == "f":
        return None, None
    raise InputError(
        f"unsupported sample type {dtype}; expected unsigned/signed integer or float samples"
    )


def _image_patches(path: Path, kind: str, image: np.ndarray, rois) -> Photo:
    """Crop ``rois`` out of an (H, W), (H, W, C) image; alpha channels are dropped."""
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in (1, 2, 3, 4):
        raise InputError(
            f"{path}: unsupported image layout {image.shape}; expected a gray or "
            f"RGB image (height x width [x channels])"
        )
    channels = 1 if image.shape[2] in (1, 2) else 3  # 2 = gray + alpha, 4 = RGB + alpha
    height, width = image.shape[:2]
    try:
        saturation, floor = _int_limits(image.dtype)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    patches = []
    for name, roi in rois:
        _check_roi(roi, name, height, width, path)
        rows, cols = roi.slices
        patches.append(Patch(np.array(image[rows, cols, :channels])))
    return Photo(path, kind, (height, width, channels), saturation, floor, patches)


def _read_png_jpeg(path: Path, kind: str, rois) -> Photo:
    imagecodecs = require("imagecodecs", f"reading a {kind.upper()} photo")

    data = path.read_bytes()
    try:
        image = imagecodecs.png_decode(data) if kind == "png" else imagecodecs.jpeg8_decode(data)
    except Exception as exc:  # imagecodecs raises its own error classes per codec
        raise InputError(f"{path}: cannot decode as {kind.upper()} ({exc})") from None
    del data
    return _image_patches(path, kind, image, rois)


#: TIFF photometric interpretations whose samples are not gray or R, G, B values.
_NOT_LINEAR_TIFF = {
    "MINISWHITE": "gray inverted, 0 is white",
    "SEPARATED": "ink separations such as CMYK, not R, G, B",
    "CIELAB": "L*a*b* colour, not R, G, B",
    "ICCLAB": "L*a*b* colour, not R, G, B",
    "ITULAB": "L*a*b* colour, not R, G, B",
}


def _read_tiff(path: Path, rois) -> Photo:
    tifffile = require("tifffile", "reading a TIFF photo")

    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            page = series.pages[0]
            if page is not None and page.photometric == tifffile.PHOTOMETRIC.PALETTE:
                raise InputError(
                    f"{path}: palette (indexed colour) TIFF; expected gray or RGB samples"
                )
            photometric = getattr(getattr(page, "photometric", None), "name", "")
            if photometric in _NOT_LINEAR_TIFF:
                raise InputError(
                    f"{path}: TIFF of photometric interpretation "
                    f"{photometric} ({_NOT_LINEAR_TIFF[photometric]}); "
                    f"expected gray (min-is-black) or RGB samples: convert the photo"
                )
            axes = series.axes
            if axes not in ("YX", "YXS", "SYX"):
                raise InputError(
                    f"{path}: TIFF holds an array with axes {axes!r} and shape "
                    f"{series.shape}; expected one gray or RGB image"
                )
            memmappable = page is not None and page.is_memmappable and len(tif.series) == 1
            image = None if memmappable else series.asarray()
        if memmappable:  # uncompressed: read only the ROIs' rows, read-only mapping
            image = tifffile.memmap(path, mode="r")
    except InputError:
        raise
    except Exception as exc:
        raise InputError(
            f"{path}: cannot read as TIFF ({type(exc).__name__}: {exc}); "
            f"expected a complete TIFF file holding one gray or RGB image (is "
            f"the photo truncated, or not a TIFF?)"
        ) from None
    assert image is not None  # read above, or mapped
    if axes == "SYX":
        image = np.moveaxis(image, 0, -1)
    return _image_patches(path, "tiff", image, rois)


def _read_raw(path: Path, rois) -> Photo:
    rawpy = require("rawpy", "reading a camera raw photo")

    try:
        raw = rawpy.imread(os.fspath(path))
    except (rawpy.LibRawError, OSError) as exc:
        raise InputError(f"{path}: cannot read as camera raw with LibRaw ({exc})") from None
    with raw:
        if raw.raw_type != rawpy.RawType.Flat:
            raise InputError(
                f"{path}: raw data are not a colour-filter mosaic (LibRaw raw "
                f"type {raw.raw_type.name}); convert it to a linear 16-bit TIFF"
            )
        desc = raw.color_desc.decode("ascii", "replace")
        if any(c not in "RGB" for c in desc):
            raise InputError(
                f"{path}: colour filter colours {desc!r} are not R, G, B; only "
                f"RGB mosaics are supported"
            )
        colour_of_index = np.array(["RGB".index(c) for c in desc])
        black_of_index = np.asarray(raw.black_level_per_channel, dtype=float)
        mosaic = raw.raw_image_visible
        indices = raw.raw_colors_visible
        height, width = mosaic.shape
        patches = []
        for name, roi in rois:
            _check_roi(roi, name, height, width, path)
            rows, cols = roi.slices
            index = np.array(indices[rows, cols])
            patches.append(
                Patch(np.array(mosaic[rows, cols]), colour_of_index[index], black_of_index[index])
            )
        saturation = float(raw.white_level)
        balance = _white_balance(desc, raw.camera_whitebalance)
    return Photo(path, "raw", (height, width, 1), saturation, 0.0, patches, balance)


def _white_balance(desc: str, multipliers) -> tuple | None:
    """The as-shot multipliers of R, G, B (the first of each colour in ``desc``) over G's;
    None when any is missing, zero or not finite (a camera that recorded none)."""
    values = np.asarray(multipliers, dtype=float)
    try:
        r, g, b = (float(values[desc.index(c)]) for c in "RGB")
    except (ValueError, IndexError):
        return None
    if not all(math.isfinite(x) and x > 0 for x in (r, g, b)):
        return None
    return (r / g, 1.0, b / g)


def read_photo(path, rois) -> Photo:
    """Decode ``path`` and keep only ``rois`` (a list of ``(name, ROI)``) as code values."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    try:
        if suffix in PNG_SUFFIXES:
            return _read_png_jpeg(path, "png", rois)
        if suffix in JPEG_SUFFIXES:
            return _read_png_jpeg(path, "jpeg", rois)
        if suffix in TIFF_SUFFIXES:
            return _read_tiff(path, rois)
        if suffix in RAW_SUFFIXES:
            return _read_raw(path, rois)
    except PermissionError:
        raise UnwritableError(f"{path}: permission denied") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    raise InputError(
        f"{path}: unsupported file type {suffix or '(no suffix)'!r}; supported: "
        f"PNG, TIFF, JPEG and camera raw ({', '.join(sorted(RAW_SUFFIXES))})"
    )


# -- statistics ----------------------------------------------------------------------------


__all__ = ["read_photo"]
