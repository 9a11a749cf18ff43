"""The Zarr store of ``veil fit maps`` (docs/maps.md): its layout and markers, the lock that
keeps a second writer out, the check that finds a damaged store, and the readers.

A store holds the maps (:data:`MAPS`), the staged photos while it is partial, and markers
under ``.veil/``: ``staged`` once the photos are in, one file per finished tile, and
``complete`` when every tile is. Stores made since issue 33 write every chunk, also one
equal to the fill value (attribute ``chunks: "all"``), so that a missing chunk file is
damage and not an empty tile.

One writer at a time: :func:`store_lock` holds a file lock (:mod:`filelock`, the kernel's
``flock``) on a hidden file beside the store, ``.NAME.veil-lock``, which names the process
holding it (it stays beside the store, empty, and is removed with a store that a failed
first run did not leave). The kernel releases the lock of a process that dies, however it
dies, so a lock left by a killed run is taken over by the next run, which says so.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._extras import require
from ..errors import InputError, MissingFileError, UnwritableError
from ..io import as_path, forget_temporary, register_temporary, write_error
from .status import CONVERGED, MASKED, STATUS

if TYPE_CHECKING:
    import zarr

    from .tables import MapTables

FORMAT = "veil.maps/1"
MAPS = ("params", "stderr", "chi2_reduced", "n_points", "status")
#: The maps with a channel axis of a store over several channels (docs/maps-channels.md):
#: the parameters declared per channel, (parameter, channel, y, x).
CHANNEL_MAPS = ("channel_params", "channel_stderr")
#: The maps of a store with the model's error (docs/maps-model-error.md): the relative
#: error s and its correlation length ell per channel (channel or 1, y, x), the standard
#: errors of the noise alone; over channels also those of the parameters per channel.
ERROR_MAPS = ("model_error", "model_error_length", "stderr_noise")
CHANNEL_ERROR_MAPS = ("channel_stderr_noise",)
#: The maps of a store with the medium's uncertainty propagated (docs/maps-medium-error.md):
#: the medium's part of the standard errors alone, of the shared parameters and per channel.
MEDIUM_MAPS = ("stderr_medium",)
CHANNEL_MEDIUM_MAPS = ("channel_stderr_medium",)
#: What status 1 means for a pixel inside the mask.
FAILED_MASKED = "no usable photo (saturated or clipped in every photo)"
LOCK_SUFFIX = ".veil-lock"


class StoreBusyError(InputError):
    """A maps store that another process is writing."""


class DamagedStoreError(InputError):
    """A maps store whose arrays, chunks or markers disagree."""


# --------------------------------------------------------------------------------------
# layout and markers
# --------------------------------------------------------------------------------------
def marker_dir(store) -> Path:
    return Path(store) / ".veil"


def tile_marker(store, iy: int, ix: int) -> Path:
    return marker_dir(store) / "tiles" / f"{iy}_{ix}"


def is_complete(store) -> bool:
    return (marker_dir(store) / "complete").is_file()


def tiles(shape, tile: int) -> list:
    h, w = shape
    return [(iy, ix) for iy in range(math.ceil(h / tile)) for ix in range(math.ceil(w / tile))]


def not_a_store(store) -> InputError:
    """The error for an output path that holds something other than a veil maps store."""
    return InputError(f"{store} exists and is not a veil maps store; give a new path, or remove it")


def check_store_path(store) -> None:
    """A store is a folder: any other file at ``store``, or a folder that is no veil maps
    store, is refused (:func:`not_a_store`) before anything is read or computed (and before
    its lock file is made beside it). A folder without the store's attributes whose lock
    file is there may be a store another run is making: the lock decides."""
    if os.path.islink(store):
        raise InputError(
            f"{store} is a symbolic link: give the maps store's own path (a store is not "
            f"written through a link)"
        )
    if os.path.lexists(store) and not os.path.isdir(store):
        raise not_a_store(store)
    if os.path.isdir(store) and not lock_path(store).exists() and store_info(store) is None:
        raise not_a_store(store)


def store_info(store) -> dict | None:
    """The store's veil attributes, or None when ``store`` is not a veil maps store."""
    zarr = require("zarr", "a maps store")
    try:
        group = zarr.open_group(os.fspath(store), mode="r")
        info = dict(group.attrs).get("veil_maps")
    except Exception:
        return None
    return info if isinstance(info, dict) and info.get("format") == FORMAT else None


def create_store(
    store, info: dict, tables: MapTables, shape, tile: int, n_photos: int
) -> zarr.Group:
    """A new store: the maps at their fill values, the stack to stage, the marker folder."""
    zarr = require("zarr", "a maps store")

    group = zarr.open_group(os.fspath(store), mode="w")
    n_par = len(info["params"])
    h, w = shape
    arrays = [
        ("params", (n_par,), "float64"),
        ("stderr", (n_par,), "float64"),
        ("chi2_reduced", (), "float64"),
        ("n_points", (), "int32"),
        ("status", (), "uint8"),
    ]
    channels = len(info.get("channels") or ())
    if channels:
        per = (len(info["channel_params"]), channels)
        arrays += [(name, per, "float64") for name in CHANNEL_MAPS]
    if info.get("model_error"):
        arrays += [(name, _expected_shape(name, info)[:-2], "float64") for name in ERROR_MAPS]
        if channels:
            arrays += [("channel_stderr_noise", per, "float64")]
    if info.get("propagation"):
        arrays += [("stderr_medium", (n_par,), "float64")]
        arrays += [("channel_stderr_medium", per, "float64")] if channels else []
    for name, lead, dtype in arrays:
        group.create_array(
            name,
            shape=lead + (h, w),
            chunks=lead + (tile, tile),
            dtype=dtype,
            fill_value=MASKED if name == "status" else 0,
        )
    group.create_array(
        "stack/values",
        shape=((channels,) if channels else ()) + (n_photos, h, w),
        chunks=((channels,) if channels else ()) + (1, tile, tile),
        dtype="float32",
        fill_value=float("nan"),
    )
    group.attrs["veil_maps"] = dict(info, chunks="all")
    (marker_dir(store) / "tiles").mkdir(parents=True, exist_ok=True)
    return group


# --------------------------------------------------------------------------------------
# one writer at a time
# --------------------------------------------------------------------------------------
def lock_path(store) -> Path:
    store = Path(os.path.abspath(os.fspath(store)))
    return store.parent / f".{store.name}{LOCK_SUFFIX}"


def _holder(path: Path) -> dict | None:
    try:
        text = path.read_text(encoding="utf-8").strip()
        return json.loads(text) if text else None
    except (OSError, ValueError):
        return None


def _describe(holder: dict | None) -> str:
    if not holder:
        return "a process that did not say which"
    started = holder.get("started")
    when = (
        time.strftime(" since %Y-%m-%d %H:%M:%S", time.localtime(started))
        if isinstance(started, (int, float))
        else ""
    )
    return f"process {holder.get('pid')} on {holder.get('host')}{when}"


@contextlib.contextmanager
def store_lock(store, say=None) -> Iterator[None]:
    """Hold the store's lock for the block (module docstring). A store another process holds
    is a :class:`StoreBusyError` naming that process; a lock whose holder died is taken over
    and ``say(message)`` told so."""
    from filelock import FileLock, Timeout

    path = lock_path(store)
    lock = FileLock(os.fspath(path), timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise StoreBusyError(
            f"{store} is being written by another 'veil fit maps' run "
            f"({_describe(_holder(path))}); wait for it to end, or give "
            f"another output path"
        ) from None
    except OSError as exc:
        raise UnwritableError(
            f"cannot lock {store}: cannot write {path} ({exc.strerror or exc})"
        ) from None
    # an interrupted command line removes it (with a store it removes, nothing is left)
    register_temporary(path, "file")
    try:
        stale = _holder(path)
        if stale and stale.get("pid") != os.getpid() and say is not None:
            say(
                f"{store}: took over the lock left by {_describe(stale)}, which ended "
                f"without releasing it (killed?)"
            )
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.time()}
        try:
            with open(path, "r+", encoding="utf-8") as fh:
                fh.truncate()
                fh.write(json.dumps(me))
        except OSError as exc:
            raise write_error(path, exc) from None
        yield
    finally:
        with contextlib.suppress(OSError):
            if os.path.isdir(store):
                with open(path, "r+", encoding="utf-8") as fh:
                    fh.truncate()
            else:  # no store (a failed first run, or a file refused): leave nothing behind
                os.unlink(path)
        forget_temporary(path)
        lock.release()


# --------------------------------------------------------------------------------------
# damage
# --------------------------------------------------------------------------------------
def _expected_shape(name: str, info: dict) -> tuple:
    h, w = info["shape"]
    if name in CHANNEL_MAPS + CHANNEL_ERROR_MAPS + CHANNEL_MEDIUM_MAPS:
        return (len(info["channel_params"]), len(info["channels"]), h, w)
    if name in ("model_error", "model_error_length"):
        return (max(1, len(info.get("channels") or ())), h, w)
    with_params = ("params", "stderr", "stderr_noise", "stderr_medium")
    return (len(info["params"]), h, w) if name in with_params else (h, w)


def map_names(info: dict) -> tuple:
    """The arrays of a store: :data:`MAPS`, :data:`CHANNEL_MAPS` over channels, with the
    model's error :data:`ERROR_MAPS` (and :data:`CHANNEL_ERROR_MAPS` over channels), with
    the medium's uncertainty :data:`MEDIUM_MAPS` (and :data:`CHANNEL_MEDIUM_MAPS`)."""
    channels = bool(info.get("channels"))
    names = MAPS + (CHANNEL_MAPS if channels else ())
    if info.get("model_error"):
        names += ERROR_MAPS + (CHANNEL_ERROR_MAPS if channels else ())
    if info.get("propagation"):
        names += MEDIUM_MAPS + (CHANNEL_MEDIUM_MAPS if channels else ())
    return names


def _missing_chunks(arr, where: Path, limit: int = 3) -> list:
    grid = [range(math.ceil(s / c)) for s, c in zip(arr.shape, arr.chunks)]
    import itertools

    out = []
    for index in itertools.product(*grid):
        if not where.joinpath("c", *map(str, index)).is_file():
            out.append("/".join(["c", *map(str, index)]))
            if len(out) >= limit:
                break
    return out


def _is_int(x, low: int = 0) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= low


def _attribute_problem(info: dict) -> str | None:
    """What is wrong with a store's ``veil_maps`` attributes for its readers, or None."""
    params, free = info.get("params"), info.get("free")
    wrong = _channel_problem(info)
    if wrong:
        return wrong
    per = info.get("channel_params") or []
    if not (
        isinstance(params, list) and (params or per) and all(isinstance(p, str) for p in params)
    ):
        return "have no list of parameter names ('params')"
    params = params + per
    if not (
        isinstance(free, list)
        and all(isinstance(p, str) for p in free)
        and set(free) <= set(params)
    ):
        return "have no list of fitted parameters among 'params' ('free')"
    fixed = info.get("fixed_values")
    if not (
        isinstance(fixed, dict)
        and all(
            isinstance(fixed.get(p), (int, float))
            and not isinstance(fixed.get(p), bool)
            and math.isfinite(fixed[p])
            for p in params
            if p not in free
        )
    ):
        return "have no finite value of each held parameter ('fixed_values')"
    shape = info.get("shape")
    if not (isinstance(shape, list) and len(shape) == 2 and all(_is_int(n, 1) for n in shape)):
        return "have no shape of two pixel counts ('shape')"
    if not _is_int(info.get("tile"), 1) or not _is_int(info.get("outside_mask", 0)):
        return "have no tile size ('tile') or count of pixels outside the mask"
    if (
        not _is_int(info.get("photos"), 1)
        or not isinstance(info.get("model"), str)
        or not (
            isinstance(info.get("medium"), dict) and isinstance(info["medium"].get("model"), str)
        )
    ):
        return "do not name the photos' count, the model and the medium"
    if not isinstance(info.get("units", {}), dict) or not isinstance(
        info.get("geometry") or {}, dict
    ):
        return "have units or a geometry that are not records"
    term = info.get("model_error")
    if term is not None and not (isinstance(term, dict) and isinstance(term.get("kind"), str)):
        return "have a model error ('model_error') that is not a record with its kind"
    spread = info.get("propagation")
    if spread is not None and not (
        isinstance(spread, dict) and isinstance(spread.get("parameters"), list)
    ):
        return "have a propagation ('propagation') that is not a record of its parameters"
    return None


def _channel_problem(info: dict) -> str | None:
    """What is wrong with the channels of a store's attributes, or None (a store of one
    channel has none)."""
    channels, per = info.get("channels"), info.get("channel_params")
    if channels is None and per is None:
        return None
    if not (
        isinstance(channels, list)
        and len(channels) >= 2
        and all(isinstance(c, str) for c in channels)
        and isinstance(per, list)
        and per
        and all(isinstance(p, str) for p in per)
    ):
        return "have no lists of channels and of parameters per channel ('channel_params')"
    return None


def check_store(store, info: dict, complete: bool) -> None:
    """Raise :class:`DamagedStoreError` (naming the part) when the store's arrays, chunks or
    markers disagree: an array whose metadata cannot be read or whose shape is not the
    store's, a chunk file missing from a complete store that writes every chunk, a
    complete store without the marker of one of its tiles."""
    zarr = require("zarr", "a maps store")

    store = Path(store)

    def damaged(part: str) -> DamagedStoreError:
        return DamagedStoreError(
            f"{store} is damaged: {part}; it cannot be read or resumed "
            f"- remove it and run 'veil fit maps' again"
        )

    wrong = _attribute_problem(info)
    if wrong:
        raise damaged(f"its attributes (zarr.json, veil_maps) {wrong}")
    shape, tile = tuple(info["shape"]), info["tile"]
    for name in map_names(info):
        try:
            arr = zarr.open_array(os.fspath(store / name), mode="r")
        except Exception as exc:
            raise damaged(
                f"array {name} ({name}/zarr.json) cannot be read ({type(exc).__name__}: {exc})"
            ) from None
        if tuple(arr.shape) != _expected_shape(name, info):
            raise damaged(
                f"array {name} has shape {tuple(arr.shape)}, expected {_expected_shape(name, info)}"
            )
        if complete and info.get("chunks") == "all":
            gone = _missing_chunks(arr, store / name)
            if gone:
                raise damaged(
                    f"array {name} lacks chunk file(s) {', '.join(gone)} (their "
                    f"pixels would read as {arr.fill_value})"
                )
    if complete:
        lost = [t for t in tiles(shape, tile) if not tile_marker(store, *t).is_file()]
        if lost:
            raise damaged(
                f"it is marked complete but {len(lost)} tile marker(s) are missing "
                f"(.veil/tiles/{lost[0][0]}_{lost[0][1]})"
            )


# --------------------------------------------------------------------------------------
# readers
# --------------------------------------------------------------------------------------
def _read(group, name: str, store) -> np.ndarray:
    try:
        return np.asarray(group[name][:])
    except Exception as exc:
        raise DamagedStoreError(
            f"{store} is damaged: array {name} cannot be read "
            f"({type(exc).__name__}: {exc}); remove it and run 'veil fit "
            f"maps' again"
        ) from None


def open_maps(store) -> dict:
    """The maps of a complete, undamaged store as numpy arrays plus its attributes."""
    zarr = require("zarr", "a maps store")

    store = Path(as_path(store, "store"))
    if not store.exists():
        raise MissingFileError(f"{store}: no such maps store")
    info = store_info(store)
    if info is None:
        raise InputError(f"{store} is not a veil maps store (made by 'veil fit maps')")
    if not is_complete(store):
        raise InputError(
            f"{store} is a partial maps store (an interrupted run, or one still "
            f"running); rerun 'veil fit maps' with the same inputs to finish it"
        )
    check_store(store, info, complete=True)
    group = zarr.open_group(os.fspath(store), mode="r")
    out: dict[str, Any] = {name: _read(group, name, store) for name in map_names(info)}
    out["info"] = info
    return out


def summarize_maps(store, maps: dict | None = None) -> dict:
    """Medians and percentiles of each map over the converged pixels, the count and
    fraction of pixels by status, and the pixels that were to be fitted but were not:
    ``failed`` (their number) and ``failed_by_status`` ({"CODE: meaning": count}), every
    status but 0 except the pixels outside the mask (``outside_mask``)."""
    maps = maps if maps is not None else open_maps(store)
    info = maps["info"]
    status = maps["status"]
    ok = status == CONVERGED
    total = int(status.size)
    counts = {STATUS[k].split(" (")[0]: int(np.count_nonzero(status == k)) for k in STATUS}
    # pixels the user left out (outside --mask) are status 1 without having failed
    outside = int(info.get("outside_mask", 0))
    failed = {}
    for k in STATUS:
        if k == CONVERGED:
            continue
        n = int(np.count_nonzero(status == k)) - (outside if k == MASKED else 0)
        if n > 0:
            failed[f"{k}: " + (FAILED_MASKED if k == MASKED else STATUS[k].split(" (")[0])] = n
    out = {
        "pixels": total,
        "converged": int(np.count_nonzero(ok)),
        "status_counts": counts,
        "outside_mask": outside,
        "failed": int(sum(failed.values())),
        "failed_by_status": failed,
        "undetermined_fraction": float(np.count_nonzero(status == 3) / total),
        "geometry": info.get("geometry", {"kind": "distant"}),
        "not_converged_fraction": float(np.count_nonzero(~ok) / total),
        "params": {},
    }
    for k, name in enumerate(info["params"]):
        out["params"][name] = _entry(info, name, maps["params"][k], maps["stderr"][k], ok)
    out["params"].update(_channel_entries(maps, ok))
    if ok.any():
        pct = np.percentile(maps["chi2_reduced"][ok], [5, 50, 95])
        out["chi2_reduced"] = {"p05": float(pct[0]), "median": float(pct[1]), "p95": float(pct[2])}
    if info.get("model_error"):
        out["model_error"] = _error_entry(maps, ok)
    if info.get("propagation"):
        out["propagation"] = _medium_entry(maps, ok)
    return out


def _medium_entry(maps: dict, ok) -> dict:
    """The summary of the medium's uncertainty: the medium's parameters and, per map
    parameter (free ones, per channel ``rho[r]``), the median over the converged pixels of
    its part of the standard error and of that part's share of the standard error."""
    entry: dict = {"parameters": list(maps["info"]["propagation"]["parameters"]), "maps": {}}
    parts = free_maps(maps, ("stderr_medium", "channel_stderr_medium"))
    for (name, _, total), (_, _, part) in zip(free_maps(maps), parts):
        if ok.any():
            share = np.divide(
                part[ok], total[ok], out=np.zeros(part[ok].shape), where=total[ok] > 0
            )
            entry["maps"][name] = {
                "median_stderr_medium": float(np.median(part[ok])),
                "median_share": float(np.median(share)),
            }
    return entry


def free_maps(maps: dict, keys=("stderr", "channel_stderr")) -> list:
    """(name, values, standard errors) of every free parameter's map; over channels each
    channel's map of a parameter per channel is one, named ``NAME[channel]``. ``keys``:
    the arrays taken as the standard errors (a part of them: ``stderr_medium``, ...)."""
    info = maps["info"]
    out = [
        (name, maps["params"][k], maps[keys[0]][k])
        for k, name in enumerate(info["params"])
        if name in info["free"]
    ]
    for k, name in enumerate(info.get("channel_params") or ()):
        if name in info["free"]:
            out += [
                (f"{name}[{c}]", maps["channel_params"][k, j], maps[keys[1]][k, j])
                for j, c in enumerate(info["channels"])
            ]
    return out


def _error_entry(maps: dict, ok) -> dict:
    """The summary of the model's error: its kind and, per channel, the share of converged
    pixels with a term, the median s over those and the lengths ell used."""
    info = maps["info"]
    names = info.get("channels") or [info.get("channel", "gray")]
    entry: dict = {"kind": info["model_error"]["kind"], "channels": {}}
    for c, name in enumerate(names):
        s, ell = maps["model_error"][c][ok], maps["model_error_length"][c][ok]
        on = s > 0
        entry["channels"][name] = {
            "share_with_term": float(np.mean(on)) if s.size else 0.0,
            "median_sigma": float(np.median(s[on])) if on.any() else 0.0,
            "lengths": sorted({float(v) for v in ell[on]}),
        }
    return entry


def _entry(info: dict, name: str, values, stderr, ok) -> dict:
    """The summary of one map: its percentiles and median standard error over the
    converged pixels ``ok`` (a free parameter), or its value (a fixed one)."""
    entry: dict[str, float | bool] = {"free": name in info["free"]}
    if name in info["free"] and ok.any():
        pct = np.percentile(values[ok], [5, 25, 50, 75, 95])
        entry.update(
            median=float(pct[2]),
            p05=float(pct[0]),
            p25=float(pct[1]),
            p75=float(pct[3]),
            p95=float(pct[4]),
            median_stderr=float(np.median(stderr[ok])),
        )
    elif name not in info["free"]:
        entry["value"] = float(info["fixed_values"][name])
    return entry


def _channel_entries(maps: dict, ok) -> dict:
    """The summaries of the maps per channel, named as the fits over channels name their
    parameters (``Pd[r]``); none for a store of one channel."""
    info = maps["info"]
    out = {}
    for k, name in enumerate(info.get("channel_params") or ()):
        for c, channel in enumerate(info["channels"]):
            out[f"{name}[{channel}]"] = _entry(
                info, name, maps["channel_params"][k, c], maps["channel_stderr"][k, c], ok
            )
    return out


__all__ = [
    "FORMAT",
    "MAPS",
    "CHANNEL_MAPS",
    "ERROR_MAPS",
    "CHANNEL_ERROR_MAPS",
    "MEDIUM_MAPS",
    "CHANNEL_MEDIUM_MAPS",
    "map_names",
    "free_maps",
    "FAILED_MASKED",
    "StoreBusyError",
    "DamagedStoreError",
    "is_complete",
    "store_info",
    "create_store",
    "store_lock",
    "lock_path",
    "check_store",
    "open_maps",
    "summarize_maps",
    "tiles",
    "tile_marker",
    "marker_dir",
]
