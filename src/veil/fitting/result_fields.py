"""The fields of a fit result's JSON (docs/fitting.md "Result files"): models as entries,
the model-discrepancy term, matrices, residuals and statistics, each written and read back
with the checks that name the file and the field."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from ..errors import FitError, InputError
from ..models import Model, model_class
from ..numbers import from_json_float, json_float
from .model_error import ModelError

#: Value of the "format" key of a result file, and the formats this veil reads.
FORMAT = "veil.fit/2"
READABLE = ("veil.fit/1", "veil.joint/1", FORMAT)


def model_entry(model: Model) -> dict:
    """{"model": name, "params": {...}, options...}: how a result file names a model (its
    "given" key)."""
    return {"model": model.NAME, "params": model.as_dict(), **model.options()}


def model_from_entry(entry, where: str, channel: str | None = None) -> Model:
    """The model of a :func:`model_entry` dict; a FitError naming ``where`` otherwise. An
    entry of a fit of several channels (its ``channels`` layout, the ``given`` key of a step
    through a medium over channels) gives the model of ``channel``."""
    if not isinstance(entry, dict) or "model" not in entry or "params" not in entry:
        raise FitError(f"{where}: expected an object with keys 'model' and 'params'")
    if not isinstance(entry["model"], str) or not isinstance(entry["params"], dict):
        raise FitError(f"{where}: 'model' must be a name and 'params' an object")
    try:
        cls = model_class(entry["model"])
        options = {k: entry[k] for k in cls.option_names() if k in entry}
        if entry.get("channels") is not None:
            layout = read_channels(entry, cls, where)
            assert layout is not None  # checked above
            return model_of_channel(cls, entry["params"], layout, channel, options)
        return cls.from_params(entry["params"], options)
    except InputError as exc:
        raise FitError(f"{where}: {exc}") from None


def check_given(entry, where: str) -> None:
    """A result's ``given`` key checked (None passes): every channel's model of an entry of
    several channels."""
    if entry is None:
        return
    channels = entry.get("channels") if isinstance(entry, dict) else None
    for c in channels or (None,):
        model_from_entry(entry, where, c)


def model_of_channel(
    cls: type[Model], params: dict, channels: dict, channel, options: dict
) -> Model:
    """The one-channel model of ``channel`` of a fit of several channels: its parameters
    taken from ``params`` through the layout ``channels`` ({channel: {parameter: name}})."""
    if channel is None or str(channel) not in channels:
        first = next(iter(channels))
        raise FitError(
            f"this result fits channels {', '.join(channels)} at once and its "
            f"model is one channel's: name one (--channel {first} in veil fit "
            f"medium and target, as_model(channel={first!r}) or "
            f"channel={first!r} in Python); the other commands take results of "
            f"one channel" + ("" if channel is None else f" (it has no channel {channel!r})")
        )
    names = channels[str(channel)]
    return cls.from_params({p: params[names[p]] for p in cls.param_names()}, options)


def read_channels(data: dict, cls: type[Model], source: str) -> dict | None:
    """The ``channels`` layout of a result file (absent: a fit of one channel), checked:
    each channel maps every parameter of ``cls`` to a name in ``params``."""
    channels = data.get("channels")
    if channels is None:
        return None
    names = set(cls.param_names())
    if (
        not isinstance(channels, dict)
        or not channels
        or not all(
            isinstance(m, dict) and set(m) == names and all(isinstance(v, str) for v in m.values())
            for m in channels.values()
        )
    ):
        raise FitError(
            f"{source}: key 'channels' must map each channel to an object naming "
            f"every parameter of {cls.NAME} ({', '.join(cls.param_names())})"
        )
    return {str(c): dict(m) for c, m in channels.items()}


def _check_format(data: dict, source: str) -> None:
    fmt = data.get("format")
    if fmt is not None and fmt not in READABLE:
        raise FitError(
            f"{source}: key 'format' = {fmt!r}: this veil reads result files of "
            f"format {', '.join(READABLE)}; the file was written by another "
            f"(newer?) version of veil"
        )


def _check_common(data: dict, source: str) -> None:
    n = data["n_points"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise FitError(f"{source}: key 'n_points' = {n!r}; expected an integer >= 0")
    if not isinstance(data["converged"], bool):
        raise FitError(f"{source}: key 'converged' = {data['converged']!r}; expected true or false")


def _read_residuals(data: dict, source: str) -> tuple:
    res = data.get("residuals") or ()
    if not isinstance(res, list):
        raise FitError(f"{source}: key 'residuals' must be a list of numbers")
    return tuple(from_json_float(r, source) for r in res)


def _read_statistic(value, source: str) -> float:
    """A fit statistic (chi2_reduced, rms_relative) read back: nan where the file has null
    (:func:`veil.numbers.json_float` writes a non-finite one as null)."""
    number = from_json_float(value, source)
    return math.nan if number is None else number


def _read_stats(data: dict, source: str) -> dict:
    stats = data.get("stats") or {}
    if not isinstance(stats, dict):
        raise FitError(f"{source}: key 'stats' must be an object")
    return stats


def _json_term(term: ModelError) -> dict:
    out = term.to_dict()
    noise = out["noise_only"]
    if noise is not None:
        out["noise_only"] = {
            k: None
            if v is None
            else (
                _json_matrix(v)
                if k.startswith("correlation")
                else {n: json_float(x) for n, x in v.items()}
            )
            for k, v in noise.items()
        }
    return out


def _read_term(data, names, source: str) -> ModelError | None:
    """The ``model_error`` entry of a result file (absent in files of earlier veils)."""
    if data is None:
        return None
    term = ModelError.from_dict(data, source)
    noise = term.noise_only
    if noise is None:
        return term
    keys = ("stderr", "correlation", "stderr_total", "correlation_total")
    if set(noise) - set(keys) or not isinstance(noise.get("stderr"), dict):
        raise FitError(f"{source}: model_error.noise_only must hold {', '.join(keys)}")
    read: dict[str, Any] = {}
    for k in keys:
        v = noise.get(k)
        if v is None:
            read[k] = None
        elif k.startswith("correlation"):
            read[k] = _read_matrix(v, source)
        elif not isinstance(v, dict):
            raise FitError(f"{source}: model_error.noise_only.{k} must be an object or null")
        else:
            read[k] = {n: from_json_float(v.get(n), source) for n in names}
    return dataclasses.replace(term, noise_only=read)


def _json_matrix(rows: dict) -> dict:
    return {a: {b: json_float(r) for b, r in row.items()} for a, row in rows.items()}


def _read_matrix(rows, source: str) -> dict:
    if rows is None:
        return {}
    if not isinstance(rows, dict) or not all(isinstance(r, dict) for r in rows.values()):
        raise FitError(f"{source}: a correlation matrix must map names to objects of numbers")
    return {a: {b: from_json_float(r, source) for b, r in row.items()} for a, row in rows.items()}
