"""The photos of a map (docs/maps.md): read as ``veil ingest`` reads them (the same reader,
:mod:`veil.data.ingest`), their sizes from the headers before anything is written, the
acquisition they make (:class:`Acquisition`: photos, manifest rows, angles, ROI, mask, black
photos or dark frame), and its staging into the store, one photo at a time."""

from __future__ import annotations

import hashlib
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._extras import require
from ..data.channels import RGB
from ..data.ingest import (
    CHANNELS,
    ROI,
    _linear,
    manifest_photos,
    parse_roi,
    read_photo,
    saturation_level,
)
from ..data.ingest_channels import ALL_RGB, sample_type
from ..errors import InputError, MissingFileError
from ..io import COMMIT, as_path, write_bytes_atomic
from .store import marker_dir


# --------------------------------------------------------------------------------------
# photos
# --------------------------------------------------------------------------------------
def _png_size(path: Path):
    with open(path, "rb") as fh:
        head = fh.read(33)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        raise InputError(f"{path}: not a PNG file (no PNG header)")
    width, height = struct.unpack(">II", head[16:24])
    return int(height), int(width)


def probe_size(path) -> tuple[int, int]:
    """(height, width) of a photo from its header (PNG, TIFF) or by decoding it; for camera
    raw the size of the half-resolution superpixel image."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".png":
        return _png_size(path)
    if suffix in (".tif", ".tiff"):
        shape, axes = _tiff_layout(path)
        return int(shape[axes.index("Y")]), int(shape[axes.index("X")])
    photo = read_photo(path, [])
    h, w = photo.shape[:2]
    return (h // 2, w // 2) if photo.kind == "raw" else (h, w)


def _tiff_layout(path: Path) -> tuple:
    """(shape, axes) of a TIFF's first series, from its header; an InputError naming the
    file if it cannot be read."""
    tifffile = require("tifffile", "reading a TIFF photo")
    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            return series.shape, series.axes
    except Exception as exc:
        raise InputError(f"{path}: cannot read as TIFF ({type(exc).__name__}: {exc})") from None


def is_colour_file(path) -> bool:
    """Whether a photo has colour channels, from its header (PNG, TIFF; camera raw is a
    colour mosaic) or by decoding it."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in _raw_suffixes():
        return True
    if suffix == ".png":
        with open(path, "rb") as fh:
            head = fh.read(26)
        return len(head) == 26 and head[25] in (2, 3, 6)  # RGB, palette, RGBA
    if suffix in (".tif", ".tiff"):
        shape, axes = _tiff_layout(path)
        return "S" in axes and shape[axes.index("S")] >= 3
    return read_photo(path, []).shape[2] >= 3


def stacked_channels(channel) -> tuple[str, ...]:
    """The channels a map over channels reads of each photo: r, g, b for "rgb", those of a
    tuple (each once, of r, g, b); empty for one channel ("gray", "r", ...)."""
    if isinstance(channel, str):
        return RGB if channel == ALL_RGB else ()
    names = tuple(str(c) for c in channel)
    if len(names) < 2 or len(set(names)) != len(names) or not set(names) <= set(RGB):
        raise InputError(
            f"channels {', '.join(names) or '(none)'}: expected two or more of "
            f"{', '.join(RGB)}, each once (or channel={ALL_RGB!r})"
        )
    return names


def _check_colour(paths, rows, channels) -> None:
    """An InputError naming the grey (single-channel) photos of a map over channels."""
    grey = [(p, row) for p, row in zip(paths, rows) if not is_colour_file(p)]
    if grey:
        shown = "; ".join(f"{p} ({row})" for p, row in grey[:5])
        raise InputError(
            f"a map of channels {', '.join(channels)}: {len(grey)} grey (single-channel) "
            f"photo(s), which have no colour channels: {shown}; a map of several channels "
            f"needs colour photos (RGB images or camera raw); a grey stack maps with "
            f"--channel gray"
        )


def _pixels(photo, channel: str, level, where: str, linear=None):
    """(linear values (h, w), unusable (h, w)) of a photo read with one ROI: ``channel`` per
    pixel, unusable where a used sample is at or above ``level`` or at the format's floor.
    Camera raw: 2 x 2 colour-filter blocks as superpixels (gray: mean of R, G, B).
    ``channel`` "rgb" or a tuple of channels: (C, h, w) each, channel by channel what each
    channel alone gives (``linear``: the patch's linear values, computed once for them)."""
    if not isinstance(channel, str) or channel == ALL_RGB:
        linear = _linear(photo.patches[0], None, where)
        parts = [_pixels(photo, c, level, where, linear) for c in stacked_channels(channel)]
        return np.stack([v for v, _ in parts]), np.stack([b for _, b in parts])
    patch = photo.patches[0]
    values = _linear(patch, None, where) if linear is None else linear
    raw = patch.values
    if patch.cfa is not None:
        h, w = values.shape
        h2, w2 = h // 2, w // 2
        vb = values[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2)
        cb = patch.cfa[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2)
        rb = raw[: 2 * h2, : 2 * w2].reshape(h2, 2, w2, 2)
        colours = range(3) if channel == "gray" else ["rgb".index(channel)]
        means, bad = [], np.zeros((h2, w2), dtype=bool)
        for c in colours:
            sel = cb == c
            count = sel.sum(axis=(1, 3))
            if np.any(count == 0):
                raise InputError(
                    f"{where}: a 2 x 2 block of the colour filter has no "
                    f"{'RGB'[c]} photosite; expected a Bayer mosaic"
                )
            means.append((vb * sel).sum(axis=(1, 3)) / count)
            if level is not None:
                bad |= ((rb >= level) & sel).any(axis=(1, 3))
            if photo.floor is not None:
                bad |= ((rb <= photo.floor) & sel).any(axis=(1, 3))
        return sum(means) / len(means), bad
    if channel == "gray":
        out = values.mean(axis=2)
        used = raw
    else:
        k = "rgb".index(channel)
        out = values[:, :, k]
        used = raw[:, :, k : k + 1]
    bad = np.zeros(out.shape, dtype=bool)
    if level is not None:
        bad |= (used >= level).any(axis=2)
    if photo.floor is not None:
        bad |= (used <= photo.floor).any(axis=2)
    return out, bad


def _check_samples(photo, where: str, first: list) -> None:
    """An InputError when ``photo``'s samples differ from those of the first photo read
    (``first``, filled by the first call): code values of another scale in one map."""
    samples = sample_type(photo)
    if not first:
        first.append((samples, where))
    elif samples != first[0][0]:
        raise InputError(
            f"{where}: {samples} samples, but {first[0][1]} has {first[0][0]} samples; "
            f"the photos of a map (and its dark frame or black photos) must have code "
            f"values of one scale (an 8-bit value is 1/257 of the 16-bit one): export "
            f"every photo alike"
        )


def _read_pixels(path, roi: ROI, channel, saturation, where, first: list | None = None):
    """Linear per-pixel values and the unusable samples of ``roi`` of one photo (for raw
    the ROI is in superpixels); with ``first``, its samples checked against the first
    photo's (:func:`_check_samples`)."""
    path = Path(path)
    if path.suffix.lower() in (".jpg", ".jpeg", ".jpe"):
        raise InputError(
            f"{where}: JPEG code values are not linear in radiance; per-pixel "
            f"maps need linear photos (PNG, TIFF or camera raw)"
        )
    scale = 2 if path.suffix.lower() in _raw_suffixes() else 1
    full = ROI(roi.x * scale, roi.y * scale, roi.w * scale, roi.h * scale)
    photo = read_photo(path, [("ROI", full)])
    if first is not None:
        _check_samples(photo, where, first)
    if channel != "gray" and photo.shape[2] == 1 and photo.kind != "raw":
        what = (
            f"channel {channel!r}"
            if channel in CHANNELS
            else f"channels {', '.join(stacked_channels(channel))}"
        )
        raise InputError(f"{where}: a single-channel (gray) image has no {what}; use channel gray")
    level = saturation if saturation is not None else photo.saturation
    return _pixels(photo, channel, level, where)


def _raw_suffixes():
    from ..data.ingest import RAW_SUFFIXES

    return RAW_SUFFIXES


def read_mask(path, shape, roi: ROI) -> np.ndarray:
    """Boolean mask (ROI) from an image of the photos' size: nonzero = fit the pixel."""
    path = Path(path)
    size = probe_size(path) if path.suffix.lower() not in _raw_suffixes() else None
    if size != tuple(shape):
        got = "camera raw" if size is None else f"{size[1]} x {size[0]}"
        raise InputError(
            f"mask {path}: {got} pixels; expected the photos' size "
            f"{shape[1]} x {shape[0]} (nonzero = fit the pixel)"
        )
    photo = read_photo(path, [("ROI", roi)])
    values = photo.patches[0].values
    return np.asarray(np.asarray(values != 0).any(axis=-1) if values.ndim == 3 else values != 0)


# --------------------------------------------------------------------------------------
# the acquisition
# --------------------------------------------------------------------------------------
@dataclass
class Acquisition:
    """What the maps are fitted from: photos in manifest order, their configurations,
    what is subtracted, the region and the mask."""

    paths: list
    blacks: list | None
    dark: Path | None
    angles: tuple
    shape: tuple  # (height, width) of every photo
    roi: ROI
    mask: np.ndarray | None
    channel: str
    saturation: float | None
    rows: list
    name: str
    #: subtracted from the photos after the black: the medium's blur correction
    #: (docs/maps-blur.md), (channels, photos, h, w) over the ROI, or None.
    correction: np.ndarray | None = None

    def fingerprint(self, legacy: bool = False) -> str:
        """A digest of what the maps are fitted from: each photo's content (its size and
        the SHA-256 of its bytes, in manifest order; a photo touched but not changed
        keeps it), the angles, region, mask, channel and saturation level. ``legacy``: the
        key of stores written before, which took each photo's path, size and modification
        time instead of its content."""
        h = hashlib.sha256()
        files = list(self.paths) + list(self.blacks or []) + ([self.dark] if self.dark else [])
        for p in files:
            if legacy:
                st = os.stat(p)
                h.update(f"{os.path.abspath(p)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
            else:
                h.update(f"{_content_key(p)}\n".encode())
        for a in self.angles:
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        h.update(repr((self.shape, str(self.roi), self.channel, self.saturation)).encode())
        if self.mask is not None:
            h.update(np.packbits(self.mask).tobytes())
        if self.correction is not None:  # (stores without one hash as they always did)
            h.update(b"blur" + np.ascontiguousarray(self.correction).tobytes())
        return h.hexdigest()


def _content_key(path) -> str:
    """``SIZE|SHA256`` of a file's bytes (an InputError naming a file that cannot be read)."""
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            return f"{size}|{hashlib.file_digest(fh, 'sha256').hexdigest()}"
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _black_photos(black_photos, table, rows: list, name: str) -> list[Path]:
    """The black photo of each manifest row: the file of the same name in ``black_photos``
    (a MissingFileError naming the rows without one)."""
    bdir = Path(black_photos)
    if not bdir.is_dir():
        raise MissingFileError(f"black photo directory {bdir}: no such directory")
    blacks = [bdir / f for f in table["file"]]
    gone = [(row, f) for row, f, p in zip(rows, table["file"], blacks) if not p.is_file()]
    if gone:
        shown = "; ".join(f"{f!r} ({row})" for row, f in gone[:10])
        raise MissingFileError(
            f"black photos: {len(gone)} photo(s) of {name} have no "
            f"black photo of the same name in {bdir}: {shown}"
        )
    return blacks


def _common_size(paths, rows, blacks, dark, name: str) -> tuple[int, int]:
    """The size (h, w) every photo, black photo and the black frame share (read from their
    headers), or an InputError naming the first that differs."""
    shape: tuple[int, int] | None = None
    first = None
    for p, row in zip(
        list(paths) + list(blacks or []) + ([dark] if dark else []),
        list(rows)
        + [f"black photo of {r}" for r in (rows if blacks else [])]
        + (["the black frame"] if dark else []),
    ):
        size = probe_size(p)
        if shape is None:
            shape, first = size, p
        elif size != shape and shape is not None:
            raise InputError(
                f"{p} ({row}): {size[1]} x {size[0]} pixels, but {first} is "
                f"{shape[1]} x {shape[0]}; every photo of a map must have the "
                f"same size"
            )
    if shape is None:
        raise InputError(f"{name}: no photo")
    return shape


def load_acquisition(
    photo_dir,
    manifest,
    *,
    roi=None,
    mask=None,
    black_photos=None,
    black_frame=None,
    channel="gray",
    saturation=None,
) -> Acquisition:
    """Check the inputs of :func:`fit_maps` and read what is cheap (no photo decoded but the
    mask and raw headers)."""
    from ..data.measurements import canonical_angles
    from ..fitting.session_data import CANONICAL

    photo_dir = Path(as_path(photo_dir, "photo_dir"))
    if not photo_dir.is_dir():
        raise MissingFileError(f"photo directory {photo_dir}: no such directory")
    if isinstance(channel, str) and channel not in CHANNELS + (ALL_RGB,):
        raise InputError(
            f"channel {channel!r}: expected one of {', '.join(CHANNELS)} or {ALL_RGB} (all three)"
        )
    if not isinstance(channel, str):
        channel = tuple(stacked_channels(channel))
    if black_photos is not None and black_frame is not None:
        raise InputError("give black photos (one per manifest row) or one black frame, not both")
    saturation = saturation_level(saturation)
    table, rows, name, paths = manifest_photos(manifest, photo_dir)
    jpeg = [
        (row, f)
        for row, f in zip(rows, table["file"])
        if Path(f).suffix.lower() in (".jpg", ".jpeg", ".jpe")
    ]
    if jpeg:
        raise InputError(
            f"{name}: {jpeg[0][1]!r} ({jpeg[0][0]}) is a JPEG; JPEG code values "
            f"are not linear in radiance, and per-pixel maps need linear photos "
            f"(PNG, TIFF or camera raw)"
        )
    blacks = None if black_photos is None else _black_photos(black_photos, table, rows, name)
    dark = None
    if black_frame is not None:
        dark = Path(black_frame)
        if not dark.is_file():
            raise MissingFileError(f"black frame {dark}: no such file")
    canon = canonical_angles(table.assign(value=0.0))
    angles = tuple(canon[c].to_numpy(dtype=float) for c in CANONICAL)
    shape = _common_size(paths, rows, blacks, dark, name)
    if stacked_channels(channel):
        _check_colour(
            list(paths) + list(blacks or []) + ([dark] if dark else []),
            list(rows)
            + [f"black photo of {r}" for r in (rows if blacks else [])]
            + (["the black frame"] if dark else []),
            stacked_channels(channel),
        )
    if roi is None:
        roi = ROI(0, 0, shape[1], shape[0])
    else:
        roi = parse_roi(roi, "ROI")
        if roi.x + roi.w > shape[1] or roi.y + roi.h > shape[0]:
            raise InputError(
                f"ROI {roi} lies outside the photos, which are {shape[1]} x {shape[0]} pixels"
            )
    mask_arr = read_mask(mask, shape, roi) if mask is not None else None
    if mask_arr is not None and not mask_arr.any():
        raise InputError(f"mask {mask}: no nonzero pixel inside the ROI {roi}; nothing to fit")
    if len(paths) < 2:
        raise InputError(
            f"{name}: {len(paths)} photo; a map needs more photos than free parameters"
        )
    return Acquisition(
        paths, blacks, dark, angles, shape, roi, mask_arr, channel, saturation, rows, name
    )


def _check_float32(values, bad, where: str, subtracted: bool) -> None:
    """An InputError when a usable value is beyond float32's range: the stack holds float32,
    where it would be an infinity, read as an unusable sample ("saturated or clipped")."""
    top = float(np.finfo(np.float32).max)
    big = np.abs(np.where(bad, 0.0, values)) > top
    if big.any():
        largest = float(np.max(np.abs(values[big])))
        raise InputError(
            f"{where}: {int(np.count_nonzero(big))} value(s) "
            + ("after the black's subtraction " if subtracted else "")
            + f"beyond float32's range (largest {largest:.4g}, at most {top:.4g}); the maps "
            f"keep the photos as float32: give them in smaller units"
        )


def stage(store, acq: Acquisition, progress=None) -> None:
    """Photos (minus dark frame or black photos) into ``stack/values``, one at a time;
    ``progress(stage, done, total)`` before the first (done 0) and after each."""
    zarr = require("zarr", "a maps store")

    arr = zarr.open_array(os.fspath(Path(store) / "stack" / "values"), mode="r+").with_config(
        {"write_empty_chunks": True}
    )
    roi = acq.roi
    dark = None
    first: list = []  # the first photo's samples (:func:`_check_samples`)
    if acq.dark is not None:
        dark = _read_pixels(
            acq.dark, roi, acq.channel, acq.saturation, f"black frame {acq.dark}", first
        )
    if progress is not None:
        progress("staging photos", 0, len(acq.paths))
    for k, (path, row) in enumerate(zip(acq.paths, acq.rows)):
        where = f"{path} ({row})"
        values, bad = _read_pixels(path, roi, acq.channel, acq.saturation, where, first)
        if not np.all(np.isfinite(values)):
            raise InputError(f"{where}: non-finite samples (NaN or infinity)")
        if dark is not None:
            values = values - dark[0]
            bad = bad | dark[1]
        if acq.blacks is not None:
            bv, bb = _read_pixels(
                acq.blacks[k],
                roi,
                acq.channel,
                acq.saturation,
                f"black photo {acq.blacks[k]} ({row})",
                first,
            )
            values = values - bv
            bad = bad | bb
        if acq.correction is not None:  # (channels, photos, h, w)
            values = values - (acq.correction[:, k] if values.ndim == 3 else acq.correction[0, k])
        if acq.mask is not None:
            bad = bad | ~acq.mask
        _check_float32(values, bad, where, acq.dark is not None or acq.blacks is not None)
        staged = np.where(bad, np.nan, values).astype(np.float32)
        with COMMIT:  # an interrupt removes a new store between two photos, not within one
            if stacked_channels(acq.channel):  # the stack of channels: (channels, photos, h, w)
                arr[:, k] = staged
            else:
                arr[k] = staged
        if progress is not None:
            progress("staging photos", k + 1, len(acq.paths))
    write_bytes_atomic(marker_dir(store) / "staged", b"staged\n")


__all__ = [
    "probe_size",
    "is_colour_file",
    "stacked_channels",
    "read_mask",
    "Acquisition",
    "load_acquisition",
    "stage",
]
