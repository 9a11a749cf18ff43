"""Reflectance maps from a photo stack, streamed through Dask into a Zarr store
(docs/maps.md): :func:`fit_maps`.

1. The manifest and the photos are checked as ``veil ingest`` checks them (the same reader,
   :mod:`veil.data.ingest`); photo sizes are read from the headers before anything is
   written, and a scheduler address is connected to first.
2. The tables (:func:`veil.maps.tables.build_tables`) are built once, on the client.
3. The photos are staged one at a time into the store (``stack/values``, float32, one chunk
   per photo and tile; saturated, clipped and masked samples as NaN; dark frame or black
   photos subtracted), so memory holds one photo whatever the stack's size.
4. The staged stack is a dask array in tiles (all photos of a tile together); one task per
   tile solves its pixels (:func:`veil.maps.solve.solve_pixels`) against the shared
   tables and writes its chunks of the maps, then a marker: a tile with its marker is
   complete. A rerun with the same inputs computes only the tiles without one.
5. When every tile is there the store is marked complete (``.veil/complete``), its summary
   written, and the staged stack removed. A store without the marker is partial: readers
   refuse it, a rerun resumes it.

More arguments of :func:`fit_maps`:

- ``grid``: {name: (lo, hi, count)} or ``NAME=LO:HI[:COUNT]`` strings: a nonlinear
  parameter's tabulated range (default: the range of the model's starting grids).
- ``roi``, ``mask``: the region (``X,Y,W,H``) and an image of the photos' size whose nonzero
  pixels are fitted. ``black_photos``: a folder with a black-cloth photo of each manifest
  row (same name), subtracted pixel by pixel; ``black_frame``: one frame subtracted from
  every photo (a dark frame). ``channel``, ``saturation``: as ``veil ingest``; ``channel``
  "rgb" or a tuple of channels maps every channel at once (docs/maps-channels.md).
- ``noise``: None (unweighted fit, standard errors from the residuals) or (relative,
  absolute): sigma = sqrt((relative * value)^2 + absolute^2) per sample. ``model_error``
  "off", "independent" or "correlated": the model's own error in the standard errors of
  weighted maps (docs/maps-model-error.md). ``propagation`` "off" or "linear": the step-1
  medium's covariance in them (docs/maps-medium-error.md; ``seconds["propagation"]`` the
  tables at the moved media).
- ``tile``: tile size in pixels (memory is bounded by it). ``scheduler``: a
  dask.distributed address (default ``$VEIL_DASK_SCHEDULER``; none: local threads,
  ``workers``).
- ``geometry``: (camera distance, pixel pitch on the plate), same units: report the angular
  spread across the field and warn when it exceeds a fifth of the narrowest lobe.
- ``near_field``: with ``geometry``, per-pixel angles (a pinhole camera at that distance
  from the plate centre, collimated light; docs/maps-geometry.md "Geometry") instead of the
  manifest's angles at every pixel, of one channel or of several.
- ``progress(stage, done, total)``, ``log(message)``: reports; the stages ("tables",
  near-field or distant: nodes of the nonlinear axes; "staging photos"; with the
  propagation :data:`MOVED`, once per medium parameter; "solving tiles") each start with
  a call at done 0.
"""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from .._extras import require
from ..data.ingest import IngestWarning
from ..errors import InputError, as_flag
from ..fitting.model_error import given_term
from ..fitting.problem import check_accuracy
from ..fitting.reported_uncertainty import model_floor
from ..io import (
    COMMIT,
    as_path,
    forget_partial,
    forget_temporary,
    register_partial,
    register_temporary,
    write_bytes_atomic,
    write_error,
    write_text_atomic,
)
from ..models import default_class, model_class
from .blur import corrected, prior_maps
from .channels import build_channel_tables, map_media
from .geometry_notes import (
    MapsWarning,
    geometry_notes,
    geometry_notes_of,
    near_geometry,
)
from .grid import parse_grid
from .medium_error import MediumSpread, plan_spread, with_differences
from .model_error import Discrepancy, discrepancy
from .photos import Acquisition, load_acquisition, stage
from .scheduling import SCHEDULER_ENV, client_of, connect, run_distributed, run_local
from .solve import warm_up
from .solve_channels import warm_up_channels
from .status import STATUS
from .store import (
    FORMAT,
    MAPS,
    DamagedStoreError,
    StoreBusyError,
    check_store,
    check_store_path,
    create_store,
    is_complete,
    marker_dir,
    not_a_store,
    open_maps,
    store_info,
    store_lock,
    summarize_maps,
    tile_marker,
)
from .store import tiles as tile_indices
from .tables import MapTables, build_tables
from .tile import solve_tile, store_attributes, store_fingerprint

DEFAULT_TILE = 128
#: The progress stage of the tables at the moved media (``propagation``).
MOVED = "tables at the moved media"


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------
@dataclass
class MapsRun:
    """What :func:`fit_maps` did: the store, the tiles computed now and before, the status
    counts over the map, the tables' description, the time of each stage, warnings."""

    store: Path
    tiles_total: int
    tiles_computed: int
    tiles_reused: int
    counts: dict
    tables: str
    seconds: dict
    summary: dict
    notes: list = field(default_factory=list)


def fit_maps(
    photo_dir,
    manifest,
    medium,
    output,
    *,
    brdf_model=None,
    options=None,
    fixed=None,
    free=None,
    grid=None,
    roi=None,
    mask=None,
    black_photos=None,
    black_frame=None,
    channel="gray",
    saturation=None,
    noise=None,
    tile: int = DEFAULT_TILE,
    accuracy: str = "default",
    scheduler=None,
    workers: int = 2,
    progress=None,
    log=None,
    geometry=None,
    near_field: bool = False,
    blur_from=None,
    tables_cache: dict | None = None,
    blur_record: str | None = None,
    model_error: str = "off",
    propagation: str = "off",
) -> MapsRun:
    """Per-pixel step 2 (docs/maps.md): the target's BRDF at every pixel of the photos
    listed in ``manifest`` (as ``veil ingest`` reads it) through ``medium`` (a step-1
    result or a medium model), written to the Zarr store ``output``.

    brdf_model, options, fixed, free : the BRDF family and its options, parameters held
        at values, held parameters to fit (as :func:`veil.fit_target`).
    blur_from, blur_record, tables_cache : the medium's blur (docs/maps-blur.md;
        :func:`veil.maps.blur_rounds.fit_maps_rounds`).
    The others (the grid, region and mask, black photos or frame, noise, model_error and
    propagation, tiles and scheduler, geometry and near field, reports): the module docstring.
    """
    check_accuracy(accuracy)
    near_field = as_flag(near_field, "near_field")
    say, tile, noise = log or (lambda message: None), _tile(tile), check_noise(noise)
    medium_model, media = map_media(medium, channel)  # media: {channel: medium} over channels
    cls = default_class("brdf") if brdf_model is None else model_class(brdf_model, "brdf")
    setting = discrepancy(model_error, noise, model_floor(cls, medium_model), given_term(medium))
    spread = plan_spread(propagation, medium, channel)
    grid_spec = parse_grid(grid, cls) if isinstance(grid, (list, tuple)) else dict(grid or {})
    output = check_output(Path(as_path(output, "output")), blur_from)
    sources = dict(roi=roi, mask=mask, black_photos=black_photos, black_frame=black_frame)
    acq = load_acquisition(photo_dir, manifest, channel=channel, saturation=saturation, **sources)
    near = near_geometry(geometry, near_field, acq)
    prior = None if blur_from is None else prior_maps(blur_from, media or medium_model, near, acq)
    with client_of(scheduler) as client, store_lock(output, say):
        existing = _existing_store(output)
        seconds: dict = {}
        build = dict(fixed=fixed, options=options, free=free, grid=grid_spec)

        def tables_of(media, times=seconds, field=None, stage="tables", cache=tables_cache):
            shown = progress and (lambda done, total: progress(stage, done, total))
            reports = (shown, say, times, cache)
            return _tables(cls, media, acq, build | {"field": field}, accuracy, near, reports)

        tables = tables_of(media or medium_model)
        notes = geometry_notes_of(tables, cls, medium_model, acq, geometry)
        acq, blur = _blur(prior, media or medium_model, acq, tables, tables_of, seconds, say)
        added = (setting, spread)  # the model's error, the medium's uncertainty
        info = store_attributes(acq, tables, cls, noise, tile, accuracy, channel, geometry, added)
        if blur is not None:
            info["blur_from"] = dict(blur, store=blur_record or blur["store"])
        _check_resumable(output, existing, info, (acq, tables, noise, tile))
        job = _Job(output, acq, tables, tile, noise, client, progress, workers, say, seconds, notes)
        rebuild = partial(tables_of, times={}, field=tables.near, stage=MOVED, cache=None)
        return _fill(replace(job, setting=setting, spread=spread, rebuild=rebuild), info, existing)


def _blur(prior, medium, acq, tables, tables_of, seconds: dict, say) -> tuple:
    """(``acq``, None), or with ``prior`` (:func:`veil.maps.blur.prior_maps`) the
    acquisition corrected for the medium's blur and the store's record of it
    (:func:`veil.maps.blur.corrected`; the two more tables' times not counted as the fit's)."""
    if prior is None:
        return acq, None
    acq, blur = corrected(prior, medium, acq, tables, lambda m: tables_of(m, {}))
    seconds["blur"] = blur.pop("seconds")
    say(f"the medium's blur from {blur['store']}: photos corrected ({seconds['blur']:.1f} s)")
    return acq, blur


def _tile(tile) -> int:
    tile = int(tile)
    if not 8 <= tile <= 4096:
        raise InputError(f"tile size {tile}: expected 8 to 4096 pixels")
    return tile


def check_output(output: Path, blur_from=None) -> Path:
    """``output``, checked before anything is read: its folder exists, it is no file and no
    folder of other things (:func:`veil.maps.store.check_store_path`), and it is not the
    store ``blur_from`` whose blur the map corrects."""
    if not output.parent.exists():
        from ..io import no_directory

        raise InputError(f"cannot write {output}: {no_directory(str(output.parent))}")
    check_store_path(output)
    if blur_from is not None and Path(as_path(blur_from, "blur_from")).resolve() == (
        output.resolve()
    ):
        raise InputError(f"--blur-from {blur_from} is the output: write the map to a new store")
    return output


def _tables(
    cls,
    medium_model,
    acq: Acquisition,
    settings: dict,
    accuracy: str,
    near,
    reports: tuple,
) -> MapTables:
    """The tables of the photos' configurations (:func:`build_tables` with ``settings``;
    over channels ``medium_model`` is {channel: medium}, :func:`veil.maps.channels.
    build_channel_tables`), their time in ``seconds["tables"]``; ``reports``: (progress of
    the stage (done, total) or None, say, seconds, a dict keeping tables by medium or
    None)."""
    shown, say, seconds, cache = reports
    key = (repr(medium_model), accuracy, repr(settings.get("field")))
    if cache is not None and key in cache:
        return cache[key]
    build = build_channel_tables if isinstance(medium_model, dict) else build_tables
    t0 = time.perf_counter()
    tables = build(
        cls,
        medium_model,
        acq.angles,
        roi=acq.roi,
        accuracy=accuracy,
        near=near,
        progress=shown,
        **settings,
    )
    seconds["tables"] = time.perf_counter() - t0
    say(f"tables: {tables.describe()} in {seconds['tables']:.1f} s")
    if cache is not None:
        cache[key] = tables
    return tables


def _existing_store(output: Path) -> dict | None:
    """The attributes of the maps store at ``output`` (None when there is none); an error
    when something else is there."""
    if not output.exists():
        return None
    existing = store_info(output)
    if existing is None:
        raise not_a_store(output)
    return existing


def _check_resumable(output: Path, existing: dict | None, info: dict, inputs: tuple) -> None:
    """An existing store resumes only with the same inputs (its fingerprint), or one written
    before photos were keyed by content with the old key (:func:`store_fingerprint` of
    ``inputs``, legacy)."""
    if existing is None:
        return
    stored = existing.get("fingerprint")
    if stored == info["fingerprint"]:
        return
    acq, tables, noise, tile = inputs
    legacy = store_fingerprint(acq, tables, noise, tile, legacy=True)
    if stored is not None and not {"model_error", "propagation"} & set(info) and stored == legacy:
        return
    raise InputError(
        f"{output} holds maps of another acquisition or other settings (its "
        f"photos' contents, manifest, medium, model, fixed parameters, grid, ROI, mask, "
        f"noise, tile size, blur correction, model error or propagation differ; a store "
        f"written by a "
        f"veil that compared photos by modification time also differs once a photo is "
        f"touched); "
        f"give a new output path to start afresh, or the same inputs to resume it"
    )


#: Each part of a noise model (relative, absolute) is 0 or in this range: its square, the
#: weights' denominator, is then a normal float (a sigma of 1e200 overflowed to an
#: OverflowError; of 1e-160 its weights were 0, every pixel "too few points").
NOISE_RANGE = (1e-150, 1e150)


def check_noise(noise) -> tuple[float, float] | None:
    """``noise`` (RELATIVE or (RELATIVE, ABSOLUTE)) checked: (relative, absolute) or None."""
    if noise is None:
        return None
    rel, ab = (
        (tuple(noise) + (0.0,))[:2] if not isinstance(noise, (int, float)) else (float(noise), 0.0)
    )
    if not (math.isfinite(rel) and math.isfinite(ab) and rel >= 0 and ab >= 0 and rel + ab > 0):
        raise InputError(f"noise {noise!r}: expected RELATIVE[,ABSOLUTE] >= 0, not both 0")
    lo, hi = NOISE_RANGE
    if any(v != 0 and not lo <= v <= hi for v in (rel, ab)):
        raise InputError(
            f"noise {noise!r}: each part 0 or from {lo:g} to {hi:g} (a sigma whose square "
            f"is a float: a weight of 1 / sigma^2)"
        )
    return float(rel), float(ab)


@dataclass
class _Job:
    """What :func:`_fill` works with."""

    output: Path
    acq: Acquisition
    tables: MapTables
    tile: int
    noise: tuple | None
    client: Any
    progress: Callable[[str, int, int], None] | None
    workers: int
    say: Callable[[str], None]
    seconds: dict
    notes: list
    setting: Discrepancy | None = None
    spread: MediumSpread | None = None
    rebuild: Callable[[Any], MapTables] | None = None


#: Errors of the system while writing (no space, a quota, an I/O error, read-only).
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO, errno.EROFS}
RESUME = "a partial maps store: rerun the same command to resume it"


def _fill(job: _Job, info: dict, existing) -> MapsRun:
    """Create (or resume) the store, stage the photos, solve the missing tiles, mark it
    complete. A store this run creates is removed again if the run fails, or is
    interrupted before the photos are staged: a failed run leaves nothing; an interrupted
    one a store that resumes."""
    output, tables = job.output, job.tables
    tiles = tile_indices(tuple(info["shape"]), job.tile)
    new = existing is None
    if not new:
        check_store(output, existing, complete=is_complete(output))
        if is_complete(output):
            job.say(f"{output} is complete (all {len(tiles)} tiles); nothing to compute")
            return MapsRun(
                output,
                len(tiles),
                0,
                len(tiles),
                {},
                tables.describe(),
                job.seconds,
                summarize_maps(output),
                job.notes,
            )
        register_partial(output, RESUME)
    staged = not new
    try:
        if new:
            with COMMIT:  # an interrupt removes the store once it is created, not halfway
                register_temporary(output, "folder")
                create_store(
                    output, info, tables, tuple(info["shape"]), job.tile, len(job.acq.paths)
                )
        t0 = time.perf_counter()
        if not (marker_dir(output) / "staged").is_file():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", IngestWarning)
                stage(output, job.acq, job.progress)
        job.seconds["staging"] = time.perf_counter() - t0
        if new:
            forget_temporary(output)
            register_partial(output, RESUME)
            staged = True
        return _solve(job, tiles)
    except BaseException as exc:
        if new and not (staged and isinstance(exc, KeyboardInterrupt)):
            forget_temporary(output)
            shutil.rmtree(output, ignore_errors=True)
        if (
            isinstance(exc, OSError)
            and not isinstance(exc, InputError)
            and (exc.errno in WRITE_ERRNOS or _inside(exc.filename, output))
        ):
            raise write_error(output, exc) from None
        raise
    finally:
        forget_partial(output)


def _inside(name, folder: Path) -> bool:
    if not name:
        return False
    return os.path.abspath(os.fspath(name)).startswith(os.path.abspath(folder) + os.sep)


def _solve(job: _Job, tiles) -> MapsRun:
    """The tiles without a marker, then the complete marker and the summary."""
    output = job.output
    todo = [t for t in tiles if not tile_marker(output, *t).is_file()]
    reused = len(tiles) - len(todo)
    if reused:
        job.say(
            f"resuming {output}: {reused} of {len(tiles)} tiles already done, computing "
            f"the {len(todo)} missing"
        )
    t0 = time.perf_counter()
    counts = _compute(output, job, todo)
    job.seconds["solve"] = time.perf_counter() - t0 - job.seconds.get("propagation", 0.0)
    missing = [t for t in tiles if not tile_marker(output, *t).is_file()]
    if missing:
        raise RuntimeError(f"{len(missing)} tiles have no marker after the run")
    write_bytes_atomic(marker_dir(output) / "complete", b"complete\n")
    summary = summarize_maps(output)
    write_text_atomic(output / "summary.json", json.dumps(summary, indent=2) + "\n")
    shutil.rmtree(output / "stack", ignore_errors=True)
    return MapsRun(
        output,
        len(tiles),
        len(todo),
        reused,
        counts,
        job.tables.describe(),
        job.seconds,
        summary,
        job.notes,
    )


def _spread(job: _Job) -> MediumSpread | None:
    """The job's medium spread with its tables' differences (built now: tiles are to be
    computed), their time in ``seconds["propagation"]``."""
    if job.spread is None or job.rebuild is None:
        return None
    t0 = time.perf_counter()
    spread = with_differences(job.spread, job.tables, job.rebuild, job.say)
    job.seconds["propagation"] = time.perf_counter() - t0
    return spread


def _compute(store, job: _Job, todo):
    tables, tile, noise, client, progress = (
        job.tables,
        job.tile,
        job.noise,
        job.client,
        job.progress,
    )
    dask = require("dask", "veil maps")
    da = require("dask.array", "veil maps")
    zarr = require("zarr", "a maps store")

    if not todo:
        return {}
    arr = zarr.open_array(os.fspath(Path(store) / "stack" / "values"), mode="r")
    # all photos of a tile (of every channel, over channels: (channels, photos, h, w))
    stack = da.from_array(arr, chunks=arr.shape[:-2] + (tile, tile))
    blocks = stack.to_delayed().reshape(stack.numblocks[-2:])
    added = (job.setting, _spread(job))  # the tables at the moved media: their own stage
    if progress is not None:  # the stage announced before the solver's warm-up and its
        # first tile (one tile: its only report would come at the end)
        progress("solving tiles", 0, len(todo))
    if client is None:  # compile the solver once per device, here, before the threads start
        (warm_up_channels if tables.channels else warm_up)(tables, noise)
    if client is not None:
        [shared, added] = client.scatter([tables, added], broadcast=True, hash=False)
    else:
        shared, added = dask.delayed(tables, pure=True), dask.delayed(added, pure=True)
    solve = dask.delayed(solve_tile, pure=False)
    tasks = [
        solve(
            blocks[iy, ix],
            shared,
            os.fspath(store),
            iy,
            ix,
            tile,
            noise,
            added,
            dask_key_name=f"veil-maps-tile-{iy}-{ix}",
        )
        for iy, ix in todo
    ]
    results = (
        run_distributed(client, tasks, progress)
        if client is not None
        else run_local(tasks, progress, job.workers)
    )
    total = np.sum(results, axis=0)
    return {STATUS[k].split(" (")[0]: int(total[k]) for k in STATUS}


__all__ = [
    "fit_maps",
    "check_output",
    "open_maps",
    "MapsWarning",
    "geometry_notes",
    "summarize_maps",
    "load_acquisition",
    "MapsRun",
    "connect",
    "is_complete",
    "SCHEDULER_ENV",
    "FORMAT",
    "MAPS",
    "StoreBusyError",
    "DamagedStoreError",
]
