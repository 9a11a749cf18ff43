"""The fields of a fit result's JSON (docs/fitting.md "Result files"): models as entries,
the model-discrepancy term, matrices, residuals and statistics, each written and read back
with the checks that name the file and the field."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from typing import Any

import numpy as np

from ..errors import FitError, InputError
from ..models import Model, model_class
from ..numbers import json_float
from .model_error import ModelError
from .solver import covariance_matrix

#: Value of the "format" key of a result file, and the formats this veil reads.
FORMAT = "veil.fit/2"
READABLE = ("veil.fit/1", "veil.joint/1", FORMAT)

#: How far a correlation read back may stray from [-1, 1] or from its transposed entry: the
#: rounding of what veil writes (a diagonal of 1.0000000000000002), not more.
CORRELATION_SLACK = 1e-6
#: The most negative eigenvalue, relative to the largest, that the correlation matrix of a
#: covariance read back may have (rounding; a covariance is positive semidefinite).
PSD_SLACK = 1e-9
#: How deep a result file's JSON may nest (veil writes a handful of levels).
MAX_DEPTH = 64


class _Refused:
    """A number of a JSON file that no veil file holds (NaN, Infinity, out of a float's
    range), kept in place by :func:`loads_checked` to name its key."""

    def __init__(self, text: str, why: str) -> None:
        self.text, self.why = text, why


def _refused_int(s: str):
    digits = len(s.lstrip("-"))
    if digits > sys.float_info.max_10_exp + 1 or abs(n := int(s)) > sys.float_info.max:
        return _Refused(f"an integer of {digits} digits", "too large for a number of a result")
    return n


def _refused_float(s: str):
    x = float(s)
    return x if math.isfinite(x) else _Refused(s, "out of the range of a number")


def _refused_constant(s: str):
    return _Refused(s, "not a finite number (veil writes a missing or non-finite number as null)")


def _object_once(pairs: list) -> Any:
    """A JSON object as a dict; a :class:`_Refused` when it names a key twice (JSON keeps the
    last value, silently: which one was meant is not known)."""
    seen: set = set()
    for key, _ in pairs:
        if key in seen:
            return _Refused(
                f"an object naming {key!r} twice", "veil writes each key once (which was meant?)"
            )
        seen.add(key)
    return dict(pairs)


def loads_checked(text: str, name: str) -> Any:
    """The JSON ``text`` of file ``name``: a FitError naming the file (and the key) for what
    is not JSON, nests more than :data:`MAX_DEPTH` levels, or holds a number veil never
    writes (NaN, Infinity, a number beyond a float's range)."""
    if not text.strip():
        raise FitError(
            f"{name} is empty"
            + (f" (only {len(text)} characters of white space)" if text else "")
            + ": expected a fit result written by veil (veil fit ... -o FILE.json)"
        )
    try:
        data = json.loads(
            text,
            parse_int=_refused_int,
            parse_float=_refused_float,
            parse_constant=_refused_constant,
            object_pairs_hook=_object_once,
        )
    except json.JSONDecodeError as exc:
        raise FitError(
            f"{name}: not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except RecursionError:
        raise FitError(f"{name}: the JSON is nested too deeply; not a veil result") from None
    stack = [(data, "", 0)]
    while stack:
        node, key, depth = stack.pop()
        if isinstance(node, _Refused):
            raise FitError(f"{name}: key '{key or '(top level)'}' = {node.text}: {node.why}")
        if depth > MAX_DEPTH:
            raise FitError(
                f"{name}: the JSON is nested too deeply (more than {MAX_DEPTH} levels); "
                f"not a veil result"
            )
        if isinstance(node, dict):
            items = ((f"{key}.{k}" if key else str(k), v) for k, v in node.items())
        elif isinstance(node, list):
            items = ((f"{key}[{i}]", v) for i, v in enumerate(node))
        else:
            continue
        stack.extend((v, k, depth + 1) for k, v in reversed(list(items)))
    return data


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
    taken from ``params`` through the layout ``channels`` ({channel: {parameter: name}});
    ``channel`` named as a table may name it ("R" for r, "650.0" for 650)."""
    names = channel_layout(channels, channel)
    return cls.from_params({p: params[names[p]] for p in cls.param_names()}, options)


def channel_layout(channels: dict, channel) -> dict:
    """{model parameter: its name in ``params``} of ``channel`` of a fit of several channels
    (the layout ``channels``); ``channel`` named as a table may name it ("R" for r, "650.0"
    for 650); a FitError naming the channels when none or an unknown one is named."""
    from ..data.channels import channel_label

    if channel is not None and str(channel) not in channels:
        channel = channel_label(channel) or channel
    if channel is None or str(channel) not in channels:
        first = next(iter(channels))
        raise FitError(
            f"this result fits channels {', '.join(channels)} at once and its "
            f"model is one channel's: name one (--channel {first} in veil fit "
            f"medium and target, as_model(channel={first!r}) or "
            f"channel={first!r} in Python); the other commands take results of "
            f"one channel" + ("" if channel is None else f" (it has no channel {channel!r})")
        )
    return channels[str(channel)]


def json_kind(value) -> str:
    """What a JSON value is, in JSON's words ("null", "a number", "an array", ...), for
    messages about a file that holds another kind of value than expected."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    return "an array" if isinstance(value, list) else "an object"


def check_channel_names(names, source: str, key: str) -> None:
    """The channels of a result's ``key`` (its ``channels`` layout, a joint fit's
    ``layout.channels``) must be those a measurement table gives (docs/measurements.md,
    "Channels"): r, g, b or wavelengths in nm as the table's labels are written
    (:func:`veil.data.channels.channel_label`: "650", not "650.0"), each once, not both
    kinds. So colour names are at most three; a FitError naming the key otherwise."""
    from ..data.channels import RGB, WAVELENGTH_RANGE, channel_label

    lo, hi = WAVELENGTH_RANGE
    for c in names:
        if not isinstance(c, str) or channel_label(c) != c:
            raise FitError(
                f"{source}: key '{key}' names channel {c!r}, which no measurement table "
                f"gives; expected r, g, b or wavelengths in nm from {lo:g} to {hi:g} "
                f"(written as a table's channel labels are: 650, not 650.0)"
            )
    kinds = {c in RGB for c in names}
    if len(kinds) > 1:
        named = ", ".join(c for c in names if c in RGB)
        nm = next(c for c in names if c not in RGB)
        raise FitError(
            f"{source}: key '{key}' mixes colour channels ({named}) with wavelengths "
            f"({nm}, ...); a measurement table's channels are r, g, b or wavelengths, "
            f"not both, so no fit has both"
        )


def read_channels(data: dict, cls: type[Model], source: str) -> dict | None:
    """The ``channels`` layout of a result file (absent: a fit of one channel), checked:
    each channel maps every parameter of ``cls`` to a name in ``params``, the channels
    those a table gives (:func:`check_channel_names`)."""
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
    check_channel_names(list(channels), source, "channels")
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
    """The keys of every result file that veil writes as one of few values: ``n_points``,
    ``converged``, ``message`` and ``accuracy``."""
    from ..engine.quadrature import RULES

    check_count(data["n_points"], source, "n_points")
    if not isinstance(data["converged"], bool):
        raise FitError(f"{source}: key 'converged' = {data['converged']!r}; expected true or false")
    if not isinstance(data["message"], str):
        raise FitError(
            f"{source}: key 'message' = {data['message']!r} ({json_kind(data['message'])}); "
            f"expected a string (the fit's message)"
        )
    accuracy = data.get("accuracy")
    if accuracy is not None and (not isinstance(accuracy, str) or accuracy not in RULES):
        raise FitError(
            f"{source}: key 'accuracy' = {accuracy!r}; expected one of {', '.join(RULES)} or null"
        )


def check_count(n, source: str, key: str) -> None:
    """A count of points (``n_points``): an integer >= 0; a FitError naming ``key``."""
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n < 2**63:
        raise FitError(f"{source}: key '{key}' = {n!r}; expected an integer >= 0")


def finite_number(v) -> bool:
    """Whether ``v`` is a finite int or float (not a bool, not too large for a float)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def read_number(v, source: str, key: str) -> float | None:
    """A number of a result file: a finite float, or None where the file has null (veil writes
    a missing or non-finite number as null); a FitError naming ``key`` otherwise."""
    if v is None:
        return None
    if not finite_number(v):
        raise FitError(f"{source}: key '{key}' = {v!r}; expected a finite number or null")
    return float(v)


def read_stderr(values: dict, names, source: str, key: str) -> dict:
    """The standard errors ``key`` of a result file over ``names``: each a finite number
    >= 0, or null (not determined, or not free)."""
    out: dict[str, float | None] = {}
    for n in names:
        v = values.get(n)
        if v is not None and (not finite_number(v) or v < 0):
            raise FitError(
                f"{source}: key '{key}.{n}' = {v!r}; expected a standard error: a finite "
                f"number >= 0, or null where it is not determined"
            )
        out[n] = None if v is None else float(v)
    return out


def _read_residuals(data: dict, source: str) -> tuple:
    res = data.get("residuals")
    res = [] if res is None else res  # (an empty list is a list: not `or ()`)
    if not isinstance(res, list):
        raise FitError(f"{source}: key 'residuals' must be a list of numbers")
    return tuple(read_number(r, source, f"residuals[{i}]") for i, r in enumerate(res))


def _read_statistic(value, source: str, key: str) -> float:
    """A fit statistic (chi2_reduced, rms_relative: a sum of squares, never negative) read
    back: nan where the file has null (:func:`veil.numbers.json_float` writes a non-finite
    one as null)."""
    number = read_number(value, source, key)
    if number is not None and number < 0:
        raise FitError(
            f"{source}: key '{key}' = {value!r}; expected a number >= 0 or null (a fit's "
            f"{key} is never negative)"
        )
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
        v, where = noise.get(k), f"model_error.noise_only.{k}"
        if v is None:
            read[k] = None
        elif k.startswith("correlation"):
            read[k] = _read_matrix(v, source, where)
        elif not isinstance(v, dict):
            raise FitError(f"{source}: {where} must be an object or null")
        else:
            read[k] = read_stderr(v, names, source, where)
    return dataclasses.replace(term, noise_only=read)


def _json_matrix(rows: dict) -> dict:
    return {a: {b: json_float(r) for b, r in row.items()} for a, row in rows.items()}


def _read_matrix(rows, source: str, key: str) -> dict:
    """The correlation matrix ``key`` of a result file: each entry a finite number in
    [-1, 1] or null, the same both ways where both are stored."""
    if rows is None:
        return {}
    if not isinstance(rows, dict) or not all(isinstance(r, dict) for r in rows.values()):
        raise FitError(
            f"{source}: key '{key}': a correlation matrix must map names to objects of numbers"
        )
    out = {
        a: {b: read_number(r, source, f"{key}.{a}.{b}") for b, r in row.items()}
        for a, row in rows.items()
    }
    for a, row in out.items():
        for b, r in row.items():
            if r is not None and abs(r) > 1 + CORRELATION_SLACK:
                raise FitError(
                    f"{source}: key '{key}.{a}.{b}' = {r!r}; a correlation must lie in "
                    f"[-1, 1] (or be null)"
                )
            back = out.get(b, {}).get(a)
            if r is not None and back is not None and abs(r - back) > CORRELATION_SLACK:
                raise FitError(
                    f"{source}: key '{key}': {a}.{b} = {r!r} but {b}.{a} = {back!r}; a "
                    f"correlation matrix is symmetric"
                )
    return out


def check_covariance(stderr, correlation, free, source: str, keys: tuple[str, str]) -> None:
    """The covariance veil assembles from ``stderr`` and ``correlation`` over the ``free``
    parameters (:meth:`~veil.fitting.result.FitResult.covariance`) must be positive
    semidefinite: its correlation matrix (where the standard errors are > 0) has no
    eigenvalue below -:data:`PSD_SLACK` times the largest. Nothing to check when a standard
    error is null (veil then uses no covariance)."""
    if stderr is None or any(stderr.get(n) is None for n in free):
        return
    spread = [n for n in free if stderr[n] > 0]
    if len(spread) < 2:
        return
    r = covariance_matrix(dict.fromkeys(spread, 1.0), correlation, spread)
    assert r is not None  # every standard error is given
    eig = np.linalg.eigvalsh((r + r.T) / 2)
    if eig[0] < -PSD_SLACK * max(abs(eig[-1]), abs(eig[0])):
        raise FitError(
            f"{source}: keys '{keys[0]}' and '{keys[1]}' of {', '.join(spread)} do not "
            f"form a covariance (its correlation matrix has eigenvalue {eig[0]:.3g}; a "
            f"covariance has none below 0): not the uncertainties of a fit"
        )
