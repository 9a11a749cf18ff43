"""A result file's data checked, key by key, and turned into the fields of a
:class:`~veil.fitting.result.FitResult` (:func:`fit_fields`) or a
:class:`~veil.fitting.result.JointResult` (:func:`joint_fields`); errors name the file and
the key (docs/fitting.md lists the keys)."""

from __future__ import annotations

from ..errors import FitError, InputError
from ..models import model_class
from ..models import names as family_names
from ..models.base import VARIANT_OPTION
from .result_fields import (
    _check_common,
    _check_format,
    _read_matrix,
    _read_residuals,
    _read_statistic,
    _read_stats,
    _read_term,
    check_channel_names,
    check_count,
    check_covariance,
    check_given,
    finite_number,
    json_kind,
    model_of_channel,
    read_channels,
    read_stderr,
)

#: The steps of the two-step method (docs/model.md sec. 7); results may also say "direct".
STEPS = ("reference", "medium", "target")
#: The kind of model ("brdf" or "medium") each step fits: step 0 and a clear-water fit
#: ("direct") the object's f_r, step 1 the medium, step 2 the target's f_r.
STEP_KINDS = {"reference": "brdf", "medium": "medium", "target": "brdf", "direct": "brdf"}

#: The keys of every result file, a step's (after "model") and a joint fit's (before "layout").
_KEYS = (
    "params",
    "stderr",
    "correlation",
    "chi2_reduced",
    "rms_relative",
    "n_points",
    "converged",
    "message",
    VARIANT_OPTION,
)


def _model_class_of(name, source: str):
    """The family a result file names, or a FitError naming the file."""
    if not isinstance(name, str):
        raise FitError(f"{source}: key 'model' = {name!r}; expected a model name")
    try:
        return model_class(name)
    except InputError:
        raise FitError(
            f"{source}: key 'model' = {name!r} is not a known model ({', '.join(family_names())})"
        ) from None


def _variant_of(data: dict, source: str):
    """The result's variant: one of the registered families' variants, or None."""
    variant = data[VARIANT_OPTION]
    known = sorted(
        {
            str(choice)
            for family in map(model_class, family_names())
            for o in family.OPTIONS
            if o.name == VARIANT_OPTION
            for choice in o.choices
        }
    )
    if variant is not None and variant not in known:
        raise FitError(
            f"{source}: key 'variant' = {variant!r}; expected one of {', '.join(known)} or null"
        )
    return variant


def _common_fields(data: dict, names, fixed: dict, source: str) -> dict:
    """The fields every result file has (``names``: the parameters its stderr covers,
    ``fixed`` those held fixed), their covariances checked (:func:`_check_covariances`)."""
    _check_common(data, source)
    for key in ("stderr_total", "correlation_total"):
        if data.get(key) is not None and not isinstance(data[key], dict):
            raise FitError(f"{source}: key {key!r} must be an object or null")
    total = data.get("stderr_total")
    fields = dict(
        stderr=read_stderr(data["stderr"], names, source, "stderr"),
        correlation=_read_matrix(data["correlation"], source, "correlation"),
        residuals=_read_residuals(data, source),
        chi2_reduced=_read_statistic(data["chi2_reduced"], source, "chi2_reduced"),
        rms_relative=_read_statistic(data["rms_relative"], source, "rms_relative"),
        n_points=int(data["n_points"]),
        converged=data["converged"],
        message=str(data["message"]),
        weighted=bool(data.get("weighted", True)),
        accuracy=data.get("accuracy"),
        stats=_read_stats(data, source),
        determined=bool(data.get("determined", True)),
        stderr_total=None if total is None else read_stderr(total, names, source, "stderr_total"),
        correlation_total=None
        if data.get("correlation_total") is None
        else _read_matrix(data["correlation_total"], source, "correlation_total"),
        model_error=_read_term(data.get("model_error"), list(names), source),
    )
    _check_covariances(fields, [n for n in names if n not in fixed], source)
    return fields


def _check_covariances(fields: dict, free: list, source: str) -> None:
    """Each pair of standard errors and correlations of a result (``stderr`` and
    ``correlation``, the totals, those of ``model_error.noise_only``) forms a covariance of
    the ``free`` parameters (:func:`veil.fitting.result_fields.check_covariance`)."""
    noise = fields["model_error"].noise_only if fields["model_error"] is not None else None
    for where, part in (("", fields), ("model_error.noise_only.", noise or {})):
        for se, corr in (("stderr", "correlation"), ("stderr_total", "correlation_total")):
            if part.get(se) is not None:
                keys = (f"{where}{se}", f"{where}{corr}")
                check_covariance(part[se], part.get(corr) or {}, free, source, keys)


def _fixed(data: dict, names, source: str) -> dict:
    """The ``fixed`` key of a result file: parameter names to finite numbers."""
    fixed = data.get("fixed") or {}
    if (
        not isinstance(fixed, dict)
        or set(fixed) - set(names)
        or not all(finite_number(v) for v in fixed.values())
    ):
        raise FitError(f"{source}: key 'fixed' must map parameter names to values; got {fixed!r}")
    return {k: float(v) for k, v in fixed.items()}


def _check_keys(data, required: tuple, source: str, what: str, command: str) -> None:
    missing = [k for k in required if k not in data]
    if missing:
        raise FitError(
            f"{source}: missing key(s) {', '.join(missing)}; is this a {what} "
            f"written by veil ({command} -o FILE.json)?"
        )


def _check_numbers(params: dict, source: str) -> None:
    for k, v in params.items():
        if not finite_number(v):
            raise FitError(f"{source}: params.{k} = {v!r} is not a finite number")


def _fit_params(data: dict, source: str):
    """(family, parameter names, channels) of a step's result file, its ``params`` checked
    against them."""
    name = data["model"]
    mcls = _model_class_of(name, source)
    names = mcls.param_names()
    params = data["params"]
    channels = read_channels(data, mcls, source)
    if channels is not None:
        names = tuple(dict.fromkeys(channels[c][p] for p in names for c in channels))
    if not isinstance(params, dict) or list(params) != list(names):
        got = list(params) if isinstance(params, dict) else params
        raise FitError(
            f"{source}: key 'params' must map exactly {', '.join(names)} (in "
            f"this order) for model {name}; got {got!r}"
        )
    _check_numbers(params, source)
    return mcls, names, channels


def _fit_options(data: dict, mcls, variant, source: str) -> dict:
    options = data.get("options")
    if options is None:  # files of format veil.fit/1 keep the variant only
        options = (
            {VARIANT_OPTION: variant}
            if VARIANT_OPTION in mcls.option_names() and variant is not None
            else {}
        )
    if not isinstance(options, dict):
        raise FitError(f"{source}: key 'options' must be an object; got {options!r}")
    return options


def fit_fields(data: dict, source: str) -> dict:
    """The fields of a :class:`~veil.fitting.result.FitResult` from the data of its file
    (written by its ``to_dict``), every key checked; errors name ``source``."""
    if not isinstance(data, dict):
        raise FitError(
            f"{source}: the file holds {json_kind(data)}; expected a JSON object with keys "
            f"model, params, ... (a fit result written by veil: veil fit ... -o FILE.json)"
        )
    _check_format(data, source)
    _check_keys(data, ("model", *_KEYS), source, "fit result", "veil fit ...")
    mcls, names, channels = _fit_params(data, source)
    variant = _variant_of(data, source)
    options = _fit_options(data, mcls, variant, source)
    try:
        values = {k: float(v) for k, v in data["params"].items()}
        model = (
            mcls.from_params(values, options)
            if channels is None
            else model_of_channel(mcls, values, channels, next(iter(channels)), options)
        )
        for c in channels or {}:
            model_of_channel(mcls, values, channels or {}, c, options)
    except InputError as exc:
        raise FitError(f"{source}: {exc}") from None
    given = data.get("given")
    check_given(given, f"{source}: key 'given'")
    stderr = data["stderr"]
    if not isinstance(stderr, dict) or set(stderr) - set(names):
        raise FitError(
            f"{source}: key 'stderr' must map parameter names ({', '.join(names)})"
            f" to numbers or null; got {stderr!r}"
        )
    fixed = _fixed(data, names, source)
    step = _step_of(data, mcls, source)
    return dict(
        _common_fields(data, names, fixed, source),
        model=data["model"],
        params=values,
        variant=variant,
        fixed=fixed,
        step=step,
        given=given,
        options=model.options(),
        channels=channels,
    )


def _step_of(data: dict, mcls, source: str) -> str | None:
    """The result's step: one of :data:`STEP_KINDS` that fits a model of the kind of
    ``mcls`` (a medium's fit is step medium, a BRDF's any other), or None."""
    step = data.get("step")
    if step is not None and (not isinstance(step, str) or step not in STEP_KINDS):
        raise FitError(
            f"{source}: key 'step' = {step!r}; expected one of {', '.join(STEPS)}, direct or null"
        )
    if step is not None and STEP_KINDS[step] != mcls.KIND:
        fitting = [s for s, kind in STEP_KINDS.items() if kind == mcls.KIND]
        raise FitError(
            f"{source}: key 'step' = {step!r}, but step {step} fits a "
            f"{STEP_KINDS[step]} model and key 'model' = {mcls.NAME!r} is a {mcls.KIND} "
            f"model; expected {', '.join(fitting)} or null for a {mcls.KIND} fit"
        )
    return step


def _check_maps(layout, source: str, where: str = "layout") -> list[str]:
    """The ``objects`` and ``media`` maps of a joint result's layout (or of one channel's
    entry, ``where``) checked; the names they give."""
    if not isinstance(layout, dict) or not {"objects", "media"} <= set(layout):
        raise FitError(f"{source}: key '{where}' must hold 'objects' and 'media'")
    for part in ("objects", "media"):
        entries = layout[part]
        if not isinstance(entries, dict) or not all(
            isinstance(m, dict) and all(isinstance(v, str) for v in m.values())
            for m in entries.values()
        ):
            raise FitError(
                f"{source}: {where}.{part} must map each {part[:-1]} to an object of "
                f"parameter names"
            )
    return [n for part in ("objects", "media") for m in layout[part].values() for n in m.values()]


def _check_layout(layout, params, source: str) -> None:
    """A joint result's layout: objects and media to their parameters' names in ``params``
    (of each channel, ``layout["channels"]``, for a fit over several)."""
    by_channel = layout.get("channels") if isinstance(layout, dict) else None
    if by_channel is None:
        named = _check_maps(layout, source)
    else:
        if not isinstance(by_channel, dict) or not by_channel:
            raise FitError(f"{source}: layout.channels must map each channel to its layout")
        check_channel_names(list(by_channel), source, "layout.channels")
        named = [
            n
            for c, maps in by_channel.items()
            for n in _check_maps(maps, source, f"layout.channels.{c}")
        ]
    for part in ("models", "options"):
        if layout.get(part) is not None and not isinstance(layout[part], dict):
            raise FitError(f"{source}: layout.{part} must be an object")
    _check_sessions(layout.get("sessions"), source)
    if not isinstance(params, dict):
        raise FitError(f"{source}: key 'params' must map names to numbers")
    absent = [n for n in dict.fromkeys(named) if n not in params]
    if absent:
        raise FitError(
            f"{source}: layout names parameter(s) {', '.join(absent)} missing from 'params'"
        )


def _check_sessions(sessions, source: str) -> None:
    """A joint result's ``layout.sessions`` (absent in files of earlier veils): a list of
    objects, each with its count of points (``n_points``) an integer >= 0."""
    if sessions is None:
        return
    if not isinstance(sessions, list) or not all(isinstance(s, dict) for s in sessions):
        raise FitError(f"{source}: layout.sessions must be a list of objects, one per session")
    for k, session in enumerate(sessions):
        if "n_points" in session:
            check_count(session["n_points"], source, f"layout.sessions[{k}].n_points")


def target_channels(layout: dict) -> dict | None:
    """A joint fit's ``channels`` ({channel: {parameter: the target's result name}}) from
    its layout; None for a fit of one channel."""
    by_channel = layout.get("channels")
    if by_channel is None:
        return None
    return {c: dict(maps["objects"]["target"]) for c, maps in by_channel.items()}


def joint_fields(data: dict, source: str) -> dict:
    """The fields of a :class:`~veil.fitting.result.JointResult` from the data of its file,
    every key checked; errors name ``source``."""
    if not isinstance(data, dict):
        raise FitError(
            f"{source}: the file holds {json_kind(data)}; expected a JSON object with keys "
            f"model, params, layout, ... (a joint fit result: veil fit joint -o FILE.json)"
        )
    if data.get("model") != "joint":
        raise FitError(f"{source}: not a joint fit result (expected key 'model' = 'joint')")
    _check_format(data, source)
    _check_keys(data, (*_KEYS, "layout"), source, "joint fit result", "veil fit joint")
    params = data["params"]
    _check_layout(data["layout"], params, source)
    _check_numbers(params, source)
    if not isinstance(data["stderr"], dict):
        raise FitError(f"{source}: key 'stderr' must map names to numbers or null")
    fixed = _fixed(data, list(params), source)
    return dict(
        _common_fields(data, list(params), fixed, source),
        model="joint",
        params={k: float(v) for k, v in params.items()},
        variant=data[VARIANT_OPTION],
        fixed=fixed,
        step="joint",
        given=data.get("given"),
        layout=data["layout"],
        channels=target_channels(data["layout"]),
    )


__all__ = ["STEPS", "STEP_KINDS", "fit_fields", "joint_fields", "target_channels"]
