"""The estimate through the medium against the same object measured directly in clear
water (docs/model.md sec. 7; the pipeline's ``--target-clear``): parameter by parameter in
units of their combined standard error, and f_r's curves over the paper's protocol in
relative terms and in units of their own standard error, channel by channel for fits over
several channels (docs/channels.md). The fits against the true models of simulated data
(the pipeline's ``truth=``), channel by channel likewise: :func:`check_truth`,
:func:`true_values`."""

from __future__ import annotations

import math

import numpy as np

from ..data.measurements import CANONICAL
from ..data.protocol import protocol
from ..errors import FitError
from ..fitting.result import FitResult
from ..models import PRESETS, Model
from ..models.channel_model import ChannelModel
from .uncertainty import curve_stderr

#: The steps ``truth=`` gives true models of.
TRUTH_STEPS = ("reference", "medium", "target")


def compare(estimated: FitResult, direct: FitResult) -> dict:
    """Estimated (through the medium; a step-2 or a joint fit) against direct f_r of the same
    object.

    Per parameter: difference and difference / sqrt(se_est^2 + se_direct^2) (the estimate's
    total standard error when it has one); and the rms of f_r_est - f_r_direct over the
    configurations of the paper's protocol (absolute and relative to f_r_direct). The curves
    are compared in units of their own standard error too (the covariances propagated
    through f_r's Jacobian at each configuration): ``fr_max_z`` the largest |difference| /
    se, ``fr_within_2se`` the share of configurations within two standard errors (None
    when an uncertainty is undetermined). Correlated parameters can differ by many of their
    own standard errors while the curves agree: the curves are what the estimate is for.
    """
    rows = {}
    se_est = estimated.stderr_total or estimated.stderr
    named = estimated.target_names()  # a joint fit's by their result names
    for name, ref in direct.params.items():
        key = named[name]
        value = estimated.params[key]
        a, b = se_est.get(key), direct.stderr.get(name)
        combined = math.hypot(a or 0.0, b or 0.0)
        rows[name] = {
            "estimated": value,
            "direct": ref,
            "difference": value - ref,
            "stderr_combined": combined if combined > 0 else None,
            "z": (value - ref) / combined if combined > 0 else None,
        }
    configs = protocol()
    f_est, se_f_est, f_dir, se_f_dir, by_channel = _curves(estimated, direct, configs)
    diff = f_est - f_dir
    out = {
        "params": rows,
        "n_configurations": len(configs),
        **by_channel,
        "rms_fr_difference": float(np.sqrt(np.mean(diff**2))),
        "rms_fr_relative": float(np.sqrt(np.mean((diff / f_dir) ** 2))),
        "max_fr_relative": float(np.max(np.abs(diff / f_dir))),
        "fr_max_z": None,
        "fr_within_2se": None,
    }
    spread = ((estimated.stats or {}).get("selection") or {}).get("spread")
    out["model_spread_rms_relative"] = None
    if spread is not None and len(spread.get("spread", ())) == len(f_est):
        # a close call between families: their curves' BIC-weighted spread widens the
        # estimate's uncertainty (veil.fitting.selection)
        widen = np.asarray(spread["spread"], dtype=float)
        se_f_est = widen if se_f_est is None else np.hypot(se_f_est, widen)
        out["model_spread_rms_relative"] = spread["rms_relative"]
    if se_f_est is not None:
        se = np.hypot(se_f_est, 0.0 if se_f_dir is None else se_f_dir)
        if np.all(se > 0):
            z = np.abs(diff) / se
            out["fr_max_z"] = float(np.max(z))
            out["fr_within_2se"] = float(np.mean(z <= 2.0))
    return out


def _curves(estimated: FitResult, direct: FitResult, configs) -> tuple:
    """(f_est, its se, f_dir, its se, {"channels": {channel: rms relative difference}} or
    {}) over the protocol's ``configs``; of a fit over several channels, channel after
    channel (a standard error None when any channel's is)."""
    angles = tuple(configs[c].to_numpy() for c in CANONICAL)
    if not estimated.channels:
        return (*curve_stderr(estimated, angles), *curve_stderr(direct, angles), {})
    parts = [
        (curve_stderr(estimated, angles, c), curve_stderr(direct, angles, c))
        for c in estimated.channel_names
    ]
    f_est, f_dir = (np.concatenate([p[k][0] for p in parts]) for k in (0, 1))
    se_est, se_dir = (
        None if any(p[k][1] is None for p in parts) else np.concatenate([p[k][1] for p in parts])
        for k in (0, 1)
    )
    rms = {
        c: float(np.sqrt(np.mean(((e[0] - d[0]) / d[0]) ** 2)))
        for c, (e, d) in zip(estimated.channel_names, parts)
    }
    return f_est, se_est, f_dir, se_dir, {"rms_fr_relative_by_channel": rms}


def _model(entry, where: str) -> Model:
    """A true model: a model or a preset's name."""
    if isinstance(entry, str) and entry.upper() in PRESETS:
        return PRESETS[entry.upper()]
    if not isinstance(entry, Model):
        raise FitError(f"{where} = {entry!r}: expected a model or a preset's name")
    return entry


def check_truth(truth, channels: list[str] | None, channel: str | None = None) -> dict | None:
    """``truth=`` of the pipeline checked before any fit: {step: a true model (every
    channel's), or {channel: its model} for tables of several ``channels``}. A step's truth
    is a model or preset, one model for every channel, or per channel a
    :class:`~veil.models.channel_model.ChannelModel` or a dict {channel: model} naming the
    tables' channels (of a fit of one ``channel``, that channel's model is taken)."""
    if truth is None:
        return None
    if not isinstance(truth, dict) or set(truth) - set(TRUTH_STEPS):
        raise FitError(
            f"truth = {truth!r}; expected a dict by step ({', '.join(TRUTH_STEPS)}) of true models"
        )
    out: dict = {}
    for step, entry in truth.items():
        where = f"truth[{step!r}]"
        if entry is None:
            continue
        if isinstance(entry, ChannelModel):
            entry = entry.models
        if not isinstance(entry, dict):
            out[step] = _model(entry, where)
            continue
        models = {str(c): _model(m, f"{where}[{c!r}]") for c, m in entry.items()}
        want = list(channels) if channels is not None else [channel]
        missing = [c for c in want if c not in models]
        extra = [c for c in models if channels is not None and c not in channels]
        if None in want or missing or extra:
            have = "one channel" if channels is None else f"channels {', '.join(channels)}"
            raise FitError(
                f"{where} gives channels {', '.join(models)} but the tables are fitted "
                f"in {have if channel is None else f'channel {channel}'}: give every fitted "
                f"channel's model, or one model for all"
            )
        out[step] = models if channels is not None else models[str(channel)]
    return out


def truth_family(result: FitResult, truth) -> str | None:
    """The family of ``truth`` (a model or {channel: model}) when it is not the fitted one
    (its parameters then have no counterpart in the result), else None."""
    models = truth.values() if isinstance(truth, dict) else [_model(truth, "truth")]
    other = next((m for m in models if type(m) is not result.model_class), None)
    return None if other is None else other.NAME


def true_values(result: FitResult, truth) -> dict[str, float | None]:
    """{result parameter: its true value} of ``truth`` (a model, or {channel: model} as
    :func:`check_truth` gives). Of a fit over several channels channel by channel: a
    parameter per channel against its channel's truth, a tied one against the value every
    channel's truth shares (None when they differ: no one true value). The truth is of
    the fitted family (:func:`truth_family`)."""
    if not result.channels:
        model = _model(truth, "truth")
        return {name: getattr(model, name) for name in result.params}
    found: dict[str, list[float]] = {}
    for c, names in result.channels.items():
        model = truth[c] if isinstance(truth, dict) else truth
        for p, name in names.items():
            found.setdefault(name, []).append(float(getattr(model, p)))
    return {n: v[0] if all(x == v[0] for x in v) else None for n, v in found.items()}


__all__ = ["compare", "check_truth", "true_values", "truth_family", "TRUTH_STEPS"]
