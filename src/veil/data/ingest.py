"""From photographs to measurements: the mean of a region of interest in each photo.

One photo is decoded at a time and only its regions of interest are kept. Formats: PNG and
TIFF (8/16-bit integer, float TIFF), JPEG (not linear: warned unless a response curve is
given) and camera raw through LibRaw (rawpy). Conventions, the raw path and the definition of
``gray`` are in docs/ingest.md.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import InputError, MissingFileError
from ..numbers import format_exact
from .ingest_channels import (
    ALL_RGB,
    StackKind,
    channel_table,
    channels_read,
    check_channel_columns,
    excluded_message,
    is_colour,
    photo_balance,
)
from .manifest import (
    ADDED_COLUMNS,
    manifest_photos,
    read_csv_file,
    read_manifest,
    unlisted_photos,
)
from .photo_files import (
    JPEG_SUFFIXES,
    PHOTO_SUFFIXES,
    PNG_SUFFIXES,
    RAW_SUFFIXES,
    TIFF_SUFFIXES,
    Patch,
    Photo,
    read_photo,
)
from .roi import ROI, parse_roi

CHANNELS = ("gray", "r", "g", "b")


class IngestWarning(UserWarning):
    """Something in the photos that the user should know about but that does not stop ingest."""


# -- response curve ------------------------------------------------------------------------


@dataclass(frozen=True)
class Response:
    """A camera response curve: code value -> linear value, interpolated linearly."""

    code: np.ndarray
    linear: np.ndarray
    source: str = "response curve"

    def __call__(self, values: np.ndarray, where: str) -> np.ndarray:
        lo, hi = float(np.min(values)), float(np.max(values))
        if lo < self.code[0] or hi > self.code[-1]:
            bad = lo if lo < self.code[0] else hi
            raise InputError(
                f"{where}: code value {bad:g} is outside the range of "
                f"{self.source}, [{self.code[0]:g}, {self.code[-1]:g}]; the curve "
                f"must cover every code value in the ROIs"
            )
        return np.interp(values, self.code, self.linear)


def load_response(path) -> Response:
    """Read a response CSV: columns ``code`` (strictly increasing) and ``linear``."""
    path = os.fspath(path)
    raw = read_csv_file(
        path,
        f"{path}: the response curve file is empty; expected a header "
        f"'code,linear' and one row per code value",
        dtype=str,
        keep_default_na=False,
        skipinitialspace=True,
        skip_blank_lines=False,
    )
    raw.columns = [str(c).strip() for c in raw.columns]
    missing = [c for c in ("code", "linear") if c not in raw.columns]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(map(repr, missing))}; the "
            f"header has {', '.join(map(repr, raw.columns))}; expected "
            f"'code' (code value in the file) and 'linear' (linear value)"
        )
    kept = ~(raw == "").all(axis=1).to_numpy()  # blank lines
    lines = np.flatnonzero(kept) + 2  # line numbers in the file, header = line 1
    raw = raw[kept]
    if len(raw) < 2:
        raise InputError(f"{path}: a response curve needs at least 2 rows, found {len(raw)}")
    columns = {}
    for col in ("code", "linear"):
        values = np.empty(len(raw))
        for j, cell in enumerate(raw[col].tolist()):
            try:
                values[j] = float(cell)
            except ValueError:
                values[j] = np.nan
            if not math.isfinite(values[j]):
                raise InputError(
                    f"line {lines[j]} of {path}, column {col!r}: {cell!r} is not a finite number"
                )
        columns[col] = values
    code, linear = columns["code"], columns["linear"]
    for j in range(1, len(code)):
        if code[j] <= code[j - 1]:
            raise InputError(
                f"line {lines[j]} of {path}, column 'code': "
                f"{code[j]:g} does not exceed the previous row's {code[j - 1]:g}; "
                f"code values must be strictly increasing"
            )
        if linear[j] < linear[j - 1]:
            raise InputError(
                f"line {lines[j]} of {path}, column 'linear': "
                f"{linear[j]:g} is below the previous row's {linear[j - 1]:g}; a "
                f"response curve must not decrease"
            )
    return Response(code, linear, f"response curve {path}")


# -- reading photos ------------------------------------------------------------------------


def _used(patch: Patch, channel: str) -> np.ndarray:
    """Boolean (h, w, c) or (h, w) mask of the samples ``channel`` reads."""
    if patch.cfa is not None:
        if channel == "gray":
            return np.ones(patch.values.shape, dtype=bool)
        return patch.cfa == "rgb".index(channel)
    mask = np.zeros(patch.values.shape, dtype=bool)
    if channel == "gray":
        mask[...] = True
    else:
        mask[:, :, "rgb".index(channel)] = True
    return mask


def _clip_counts(patch: Patch, channel: str, saturation, floor):
    """(saturated, clipped) pixel counts: a pixel counts if any sample ``channel`` uses does."""
    used = _used(patch, channel)
    counts = []
    for level, above in ((saturation, True), (floor, False)):
        if level is None:
            counts.append(0)
            continue
        hit = (patch.values >= level) if above else (patch.values <= level)
        hit &= used
        counts.append(int(np.count_nonzero(hit if hit.ndim == 2 else hit.any(axis=2))))
    return counts[0], counts[1]


def _linear(patch: Patch, response: Response | None, where: str) -> np.ndarray:
    values = patch.values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        raise InputError(f"{where}: {bad} non-finite sample(s) (NaN or infinity) in the ROI")
    if response is not None:
        values = response(values, where)
    if patch.black is not None:
        values -= patch.black
    return values


def _stats(groups):
    """Mean of the groups' means and its standard error; total sample count."""
    means = [g.mean() for g in groups]
    variances = [g.var(ddof=1) / g.size for g in groups]
    k = len(groups)
    return (
        float(sum(means) / k),
        float(math.sqrt(sum(variances)) / k),
        int(sum(g.size for g in groups)),
    )


def roi_statistics(
    patch: Patch,
    channel: str,
    dark: Patch | None = None,
    response: Response | None = None,
    where: str = "ROI",
) -> tuple[float, float, int]:
    """``(value, sigma, n)`` of one ROI: mean of linear, dark-subtracted ``channel`` values.

    ``gray`` is (R + G + B) / 3, the average of the three channels (for a raw mosaic the
    average of the R, G and B photosites' means); ``sigma`` is the standard error of that mean.
    """
    values = _linear(patch, response, where)
    if dark is not None:
        values = values - _linear(dark, response, where + " (dark frame)")
    if patch.cfa is not None:
        colours = range(3) if channel == "gray" else ["rgb".index(channel)]
        groups = [values[patch.cfa == c] for c in colours]
    elif channel == "gray":
        groups = [values.mean(axis=2).ravel()]
    else:
        groups = [values[:, :, "rgb".index(channel)].ravel()]
    for c, g in zip(("R", "G", "B") if len(groups) == 3 else (channel.upper(),), groups):
        if g.size < 2:
            what = f"{c} photosites" if patch.cfa is not None else "pixels"
            raise InputError(
                f"{where}: only {g.size} {what} in the ROI; at least 2 are needed "
                f"for a standard error - make the ROI larger"
            )
    with np.errstate(over="ignore", invalid="ignore"):
        value, sigma, n = _stats(groups)
    if not (math.isfinite(value) and math.isfinite(sigma)):
        peak = max(float(np.max(np.abs(g))) for g in groups)
        raise InputError(
            f"{where}: the mean or standard error of the samples overflows float64 "
            f"(samples up to {peak:.3g}); rescale the photos' values"
        )
    return value, sigma, n


# -- the manifest --------------------------------------------------------------------------


def _warn(message: str) -> None:
    warnings.warn(message, IngestWarning, stacklevel=3)


def _settings(roi, black_roi, channel: str, saturation, response) -> tuple:
    """(the ROIs, the saturation level, the response) of :func:`ingest`, checked."""
    if channel not in CHANNELS + (ALL_RGB,):
        raise InputError(
            f"channel {channel!r}: expected one of {', '.join(CHANNELS)} or {ALL_RGB} (all three)"
        )
    rois = [("ROI", parse_roi(roi, "ROI"))]
    if black_roi is not None:
        rois.append(("black ROI", parse_roi(black_roi, "black ROI")))
        if rois[0][1].overlaps(rois[1][1]):
            _warn(f"the ROI {rois[0][1]} and the black ROI {rois[1][1]} overlap")
    saturation = saturation_level(saturation)
    if response is not None and not isinstance(response, Response):
        response = load_response(response)
    return rois, saturation, response


def saturation_level(saturation) -> float | None:
    """The saturation level (``--saturation``) checked: None, or a finite code value > 0
    (the format's minimum is 0, so at or below it every sample would count as saturated)."""
    if saturation is None:
        return None
    level = float(saturation)
    if not math.isfinite(level):
        raise InputError(f"saturation level {saturation!r} is not a finite number")
    if level <= 0:
        raise InputError(
            f"saturation level {format_exact(level)} (--saturation): expected a code value "
            f"> 0, in the file's code values, at or above which a sample counts as saturated "
            f"(e.g. 4095 for 12-bit data in a 16-bit file; the default is the format's "
            f"maximum); at {format_exact(level)} every sample would be saturated"
        )
    return level


def ingest(
    photo_dir,
    manifest,
    roi,
    black_roi=None,
    dark=None,
    channel="gray",
    *,
    response=None,
    saturation=None,
    keep_saturated=False,
    progress=None,
) -> pd.DataFrame:
    """One measurement row per photo of ``manifest``: its columns plus the ROI statistics.

    ``roi``/``black_roi``: ``"X,Y,W,H"`` or :class:`ROI`. ``dark``: a dark frame subtracted
    pixel by pixel. ``channel``: ``gray``, ``r``, ``g`` or ``b``; ``rgb`` reads all three at
    once into one table with a ``channel`` column, one row per photo and channel, channel
    after channel (:mod:`veil.data.ingest_channels`; docs/ingest.md). ``response``: CSV path
    or :class:`Response` mapping code values to linear values. ``saturation``: code value at
    or above which a sample is saturated (default: the format's maximum). Photos with
    saturated or clipped (minimum code value) pixels in the ROIs are dropped with a warning
    unless ``keep_saturated``. ``progress(done, total, file)`` is called after each photo.
    Warnings are :class:`IngestWarning`; user errors are ``ValueError`` /
    ``FileNotFoundError``.
    """
    photo_dir = Path(photo_dir)
    if not photo_dir.is_dir():
        raise MissingFileError(f"photo directory {photo_dir}: no such directory")
    rois, saturation, response = _settings(roi, black_roi, channel, saturation, response)
    table, rows, name, paths = manifest_photos(manifest, photo_dir)
    if channel == ALL_RGB:
        check_channel_columns(table, name)
    ignore = set()
    if dark is not None:
        ignore.add(Path(dark).resolve())
        _check_dark_not_listed(dark, rows, table["file"], paths)
    extra = unlisted_photos(photo_dir, {p.resolve() for p in paths}, ignore)
    if extra:
        shown = ", ".join(extra[:10]) + (f" and {len(extra) - 10} more" if len(extra) > 10 else "")
        _warn(
            f"{len(extra)} photo file(s) in {photo_dir} are not in {name} and are ignored: {shown}"
        )

    # the dark frame's hot pixels: any sample counts when every channel is read
    dark_photo = _dark_frame(
        dark, rois, "gray" if channel == ALL_RGB else channel, response, saturation
    )
    keep, results, balances = _read_stack(
        table,
        paths,
        rows,
        rois,
        channel,
        dark,
        dark_photo,
        response,
        saturation,
        keep_saturated,
        progress,
    )
    if not keep:
        raise InputError(
            f"all {len(paths)} photos were excluded for saturated or clipped "
            f"pixels in the ROIs; lower the exposure, move the ROIs, or keep them "
            f"with --keep-saturated"
        )
    order = ["value", "sigma"] + (["black", "black_sigma"] if black_roi is not None else [])
    order += ["saturated", "clipped", "n_pixels"]
    if channel == ALL_RGB:
        return channel_table(table, keep, results, balances, order)
    out = table.iloc[keep].reset_index(drop=True)
    added = pd.DataFrame(results[channel])
    for col in order:
        out[col] = added[col].to_numpy()
    return out


def _read_stack(
    table,
    paths,
    rows,
    rois,
    channel: str,
    dark,
    dark_photo,
    response,
    saturation,
    keep_saturated: bool,
    progress,
):
    """The photos read one at a time: (positions kept, {channel: their rows}, each kept
    photo's white balance (:func:`veil.data.ingest_channels.photo_balance`)); a photo with
    saturated or clipped pixels in any channel read is warned about and, unless
    ``keep_saturated``, left out of every channel."""
    names = channels_read(channel)
    stack = StackKind()
    warned: set[str] = set()
    results: dict[str, list] = {c: [] for c in names}
    keep, balances = [], []
    for i, (path, row_name) in enumerate(zip(paths, rows)):
        photo = read_photo(path, rois)
        where = f"{path} ({row_name})"
        _check_photo(photo, where, channel, response, saturation, dark, dark_photo, warned)
        odd = stack.check(photo, where)
        if odd is not None:
            _warn(odd)
        level = saturation if saturation is not None else photo.saturation
        found = {c: _photo_row(photo, rois, c, level, dark_photo, response, where) for c in names}
        message = excluded_message(where, found, level, photo.floor, keep_saturated)
        if message is not None:
            _warn(message)
        if keep_saturated or message is None:
            keep.append(i)
            for c in names:
                results[c].append(found[c])
            balances.append(photo_balance(photo))
        if progress is not None:
            progress(i + 1, len(paths), str(table["file"].iloc[i]))
        del photo
    return keep, results, balances


def _check_dark_not_listed(dark, rows: list[str], files, paths: list[Path]) -> None:
    """InputError if the dark frame is one of the photos the manifest lists: subtracted from
    itself, that photo would read 0 +- 0, a row no fit can weigh."""
    if not os.path.exists(dark):
        return  # said where the dark frame is read
    for row, file, photo in zip(rows, files, paths):
        if os.path.samefile(photo, dark):
            raise InputError(
                f"dark frame {dark} is the photo {file!r} of {row}; the dark frame is a "
                f"frame of its own (lens capped, same exposure), not one of the photos measured"
            )


def _dark_frame(dark, rois, channel: str, response, saturation) -> Photo | None:
    """The dark frame's ROIs (None without one), its hot pixels warned about."""
    if dark is None:
        return None
    dark_photo = read_photo(dark, rois)
    if dark_photo.kind == "raw" and response is not None:
        raise InputError(
            f"dark frame {dark}: camera raw is already linear; a response "
            f"curve applies to JPEG/PNG/TIFF code values only"
        )
    if channel != "gray" and dark_photo.shape[2] == 1 and dark_photo.kind != "raw":
        raise InputError(
            f"dark frame {dark}: a single-channel (gray) image has no channel {channel!r}; "
            f"a dark frame is of the photos' kind (a colour one for colour photos), or use "
            f"channel gray"
        )
    level = saturation if saturation is not None else dark_photo.saturation
    hot = sum(_clip_counts(p, channel, level, None)[0] for p in dark_photo.patches)
    if hot:
        _warn(f"dark frame {dark}: {hot} saturated pixel(s) in the ROIs (level {level:g})")
    return dark_photo


def _check_photo(
    photo: Photo,
    where: str,
    channel: str,
    response,
    saturation,
    dark,
    dark_photo: Photo | None,
    warned: set,
) -> None:
    """A photo's format against the options: JPEG without a response curve and float
    samples without a saturation level are warned about once (``warned``); camera raw with
    a response curve, a missing channel or a dark frame of another kind are errors."""
    path = photo.path
    if photo.kind == "jpeg" and response is None and "jpeg" not in warned:
        warned.add("jpeg")
        _warn(
            f"{path}: JPEG code values are not linear in radiance (gamma/tone curve); "
            f"give a response curve (--response) to linearize them"
        )
    if photo.kind == "raw" and response is not None:
        raise InputError(
            f"{where}: camera raw is already linear; a response curve applies "
            f"to JPEG/PNG/TIFF code values only"
        )
    if photo.saturation is None and saturation is None and "float" not in warned:
        warned.add("float")
        _warn(
            f"{path}: float samples have no format maximum, so saturation is not "
            f"checked; give a saturation level (--saturation) if the data were clipped"
        )
    if channel == ALL_RGB and not is_colour(photo):
        raise InputError(
            f"{where}: a single-channel (gray) image has no colour channels; "
            f"--channel {ALL_RGB} (channel={ALL_RGB!r}) reads colour photos "
            f"(RGB images or camera raw); a stack of grey photos is read with "
            f"channel gray"
        )
    if channel != "gray" and photo.shape[2] == 1 and photo.kind != "raw":
        raise InputError(
            f"{where}: a single-channel (gray) image has no channel {channel!r}; use channel gray"
        )
    if dark_photo is not None and (
        (dark_photo.kind == "raw") != (photo.kind == "raw")
        or dark_photo.shape != photo.shape
        or dark_photo.dtype != photo.dtype
    ):
        raise InputError(
            f"{where}: the dark frame {dark} does not match the photo (dark "
            f"frame {_describe(dark_photo)}, photo {_describe(photo)})"
        )


def _photo_row(
    photo: Photo, rois, channel: str, level, dark_photo: Photo | None, response, where: str
) -> dict:
    """The measurement columns of one photo: value, sigma and n_pixels of the ROI (black,
    black_sigma of the black ROI), saturated and clipped pixel counts."""
    row = {}
    n_saturated = n_clipped = 0
    for k, ((roi_name, _), patch) in enumerate(zip(rois, photo.patches)):
        sat, clip = _clip_counts(patch, channel, level, photo.floor)
        n_saturated += sat
        n_clipped += clip
        dark_patch = dark_photo.patches[k] if dark_photo is not None else None
        value, sigma, n = roi_statistics(
            patch, channel, dark_patch, response, f"{where}, {roi_name}"
        )
        prefix = "value" if k == 0 else "black"
        row[prefix] = value
        row["sigma" if k == 0 else "black_sigma"] = sigma
        if k == 0:
            row["n_pixels"] = n
    row["saturated"] = n_saturated
    row["clipped"] = n_clipped
    return row


def _describe(photo: Photo) -> str:
    height, width, channels = photo.shape
    kind = "raw mosaic" if photo.kind == "raw" else f"{channels}-channel {photo.kind}"
    dtype = photo.dtype
    depth = f"{dtype.itemsize * 8}-bit {'float' if dtype.kind == 'f' else 'integer'}"
    return f"{width} x {height} {depth} {kind}"


__all__ = [
    "ingest",
    "saturation_level",
    "read_manifest",
    "manifest_photos",
    "load_response",
    "Response",
    "roi_statistics",
    "IngestWarning",
    "CHANNELS",
    "ALL_RGB",
    "ADDED_COLUMNS",
    "ROI",
    "parse_roi",
    "read_photo",
    "PHOTO_SUFFIXES",
    "PNG_SUFFIXES",
    "JPEG_SUFFIXES",
    "TIFF_SUFFIXES",
    "RAW_SUFFIXES",
]
