"""The steps of the two-step method (docs/model.md sec. 7; docs/fitting.md), each a
:class:`veil.fitting.problem.Problem` of one session solved by :mod:`veil.fitting.solver`:

- step 0, :func:`fit_reference`: the reference object's f_r from clear-medium data, directly
  (no integral); :func:`fit_direct` is the same fit of a target measured without the medium;
- step 1, :func:`fit_medium`: the medium from the reference object in the medium, its f_r
  held fixed;
- step 2, :func:`fit_target`: the target's f_r from the target in the medium, f_t held fixed.

The BRDF family and the medium model are any registered ones (``brdf_model=``,
``medium_model=``; default the paper's, docs/model.md sec. 2-3). Every fit minimizes
sum(((model - value) / sigma)^2) (plain squared error without a sigma column). Starting
values never come from the caller: the model's starting grid with the scale parameters
solved exactly at each point gives several starts; the best fit among them wins
(:mod:`veil.fitting.start_values`). A fit that propagates its given model's covariance
(when that came from a fit) reports ``stderr_total``. A weighted fit whose residuals exceed
the noise (reduced chi-square above the test's limit), or through a model that declares its
own error (``Model.MODEL_ERROR_FLOOR``), adds a relative model error to its covariance
(``model_error=``: "correlated" by default, "independent", or "off";
:mod:`veil.fitting.model_error`). One step's solve: :mod:`veil.fitting.step_fit`.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from ..data.measurements import RowNames
from ..engine.evaluator import ApparentModel, DirectModel, check_progress
from ..engine.quadrature import RULES
from ..errors import FitError, InputError, as_flag
from ..models import BRDF, Medium, Model, default_class, model_class
from ..models.base import VARIANT_OPTION
from . import model_error as discrepancy
from .arguments import as_names, as_options, as_start
from .channel_fit import fit_channels
from .channel_steps import fit_through
from .given import as_given, check_options
from .problem import ITERATION_ACCURACY, check_accuracy
from .propagation import check_method
from .result import FitResult
from .session_data import FitData, channels_of, prepare
from .solver import as_fixed, began_at_grid, check_max_nfev, check_start_family
from .step_fit import MISFIT_CHI2, ROLE, STARTS, MisfitWarning, fit_step, warn_misfit


def _family(name, kind: str):
    return default_class(kind) if name is None else model_class(name, kind)


def _template(cls, options: dict) -> Model:
    """The family's model at its starting values with ``options`` (a FitError otherwise)."""
    try:
        return cls.template(**options)
    except InputError as exc:
        raise FitError(str(exc)) from None


def _options(options, variant) -> dict:
    """Options as given, the ``variant`` shortcut of the medium's Fresnel factor added."""
    options = as_options(options)
    if variant is not None:
        options[VARIANT_OPTION] = variant
    return options


def _freed(cls, free, what: str) -> set:
    """Names of held parameters (``Param.held``) that ``free`` asks to fit."""
    free = set(as_names(free, "free") or ())
    unknown = [n for n in free if n not in cls.param_names()]
    if unknown:
        raise FitError(
            f"cannot free {', '.join(map(repr, unknown))} in the {what} fit: "
            f"{cls.NAME} has parameters {', '.join(cls.param_names())}"
        )
    return free


def prefetch(
    data: FitData,
    *,
    brdf_model=None,
    brdf_options=None,
    medium_model=None,
    medium_options=None,
    variant: str | None = None,
    accuracy: str = "default",
) -> None:
    """Start compiling (or loading) in the background the engine programs that steps 1 and 2
    run at ``data``'s configurations (values and both models' derivatives at the iterations'
    rule, values at ``accuracy``), so that a first run compiles them while step 0 fits the
    clear reference. A model or option the steps will refuse is left to them to report."""
    try:
        brdf = _template(_family(brdf_model, "brdf"), as_options(brdf_options, "brdf_options"))
        medium = _template(_family(medium_model, "medium"), _options(medium_options, variant))
    except (InputError, FitError):
        return
    rules = [ITERATION_ACCURACY] + ([accuracy] if accuracy != ITERATION_ACCURACY else [])
    for rule in rules:
        model = ApparentModel(cast(BRDF, brdf), cast(Medium, medium), data.angles, RULES[rule])
        model.prepare(values=True, jacobians=[("medium",), ("brdf",)] if rule == rules[0] else [])


# --------------------------------------------------------------------------------------
# the steps
# --------------------------------------------------------------------------------------
def fit_reference(
    table,
    *,
    fixed=None,
    black=None,
    max_nfev=None,
    progress=None,
    brdf_model=None,
    options=None,
    free=None,
    model_error=None,
    channel: str | None = None,
    screen: bool = False,
    start=None,
) -> FitResult:
    """Step 0 (docs/model.md sec. 7): fit the reference's f_r to clear-medium data, directly.

    table : measurement table (DataFrame or CSV path, docs/measurements.md).
    fixed : parameters held at given values, e.g. ``{"eta": 1.5}``.
    black : black-cloth table subtracted first (a clear medium normally has none).
    max_nfev : limit on function evaluations of each least-squares run (None: 100 per free
        parameter).
    progress : called as progress(stage, done, total) while fitting.
    brdf_model, options : the BRDF family (a registered name; default the paper's
        Torrance-Sparrow) and its options.
    free : names of parameters the family holds by default (``Param.held``) to fit too.
    model_error : the model-discrepancy term of a weighted fit: "off", "independent" or
        "correlated" (the default, None; :mod:`veil.fitting.model_error`).
    channel : of a table with a ``channel`` column (docs/measurements.md, "Channels"), the
        one channel to fit; None fits every channel at once, the parameters the family
        declares shared tied across them (:mod:`veil.fitting.channel_fit`; ``fixed`` names
        a parameter of every channel, or one channel's as ``Pd[r]``).
    screen, start : of one channel, a candidate's quick fit (the grid's best start only) to
        rank it; a :class:`FitResult` of this model or {name: value} to start from, the
        grid's other starts run after it (veil.fitting.screening).
    """
    return fit_direct(
        table,
        fixed=fixed,
        black=black,
        max_nfev=max_nfev,
        progress=progress,
        step="reference",
        brdf_model=brdf_model,
        options=options,
        free=free,
        model_error=model_error,
        channel=channel,
        screen=screen,
        start=start,
    )


def fit_direct(
    table,
    *,
    fixed=None,
    black=None,
    max_nfev=None,
    progress=None,
    step: str = "direct",
    brdf_model=None,
    options=None,
    free=None,
    model_error=None,
    channel: str | None = None,
    screen: bool = False,
    start=None,
) -> FitResult:
    """f_r fitted to clear-medium data (docs/model.md sec. 2); ``step`` labels the result
    ("reference" for step 0, "direct" for a target measured without the medium);
    ``channel`` as :func:`fit_reference`; ``screen`` and ``start`` (of one channel) as
    :func:`fit_medium`'s: a quick fit is its grid's best start only."""
    check_max_nfev(max_nfev)
    check_progress(progress)
    as_flag(screen, "screen", FitError)
    model_error = discrepancy.check_kind(model_error)
    if step not in ("reference", "direct"):
        raise FitError(f"step = {step!r}; a clear-water fit is step 'reference' or 'direct'")
    cls = _family(brdf_model, "brdf")
    fitted = _template(cls, as_options(options))
    what = "reference" if step == "reference" else "target"
    if channel is None:
        table, channels = channels_of(table, f"{what} (clear medium)")
        if channels is not None and len(channels) > 1:
            if screen or start is not None:
                raise FitError("screen, start: a clear-water fit of one channel only")
            return fit_channels(
                table,
                black,
                cast(BRDF, fitted),
                channels,
                step=step,
                what=f"{what} (clear medium)",
                fixed=as_fixed(fixed),
                freed=_freed(cls, free, what),
                max_nfev=max_nfev,
                progress=progress,
                model_error=model_error,
                starts=STARTS[step],
            )
    data = prepare(table, black, f"{what} (clear medium)", channel=channel)
    return fit_step(
        step,
        data,
        fitted,
        None,
        None,
        as_fixed(fixed),
        ITERATION_ACCURACY,
        max_nfev,
        progress,
        _freed(cls, free, what),
        model_error,
        screen=screen,
        **_start(start, cls, channel),
    )


def fit_medium(
    table,
    reference,
    *,
    fixed=None,
    black=None,
    variant: str | None = None,
    accuracy: str = "default",
    max_nfev=None,
    progress=None,
    medium_model=None,
    options=None,
    free=None,
    model_error=None,
    propagation=None,
    channel: str | None = None,
    screen: bool = False,
    start=None,
) -> FitResult:
    """Step 1 (docs/model.md sec. 7): fit the medium, the reference's f_r fixed.

    table : the reference object measured in the medium (DataFrame or CSV path).
    reference : the step-0 :class:`FitResult` or a BRDF model.
    medium_model, options : the medium family (default Henyey-Greenstein) and its options;
        ``variant`` the shortcut for the Fresnel variant ("paper" or "exit", sec. 3).
    free : parameters the family holds by default to fit too (the physical medium's ``s``).
    accuracy : of the reported result ("fast", "default", "high"), polished from "fast".
    model_error, propagation : as :func:`fit_reference` (a step-1 term is used by step 2
        too); how the given fit's covariance enters ``stderr_total``: "auto" (the default,
        None), "linear" or "sigma-points" (:mod:`veil.fitting.propagation`).
    channel : the one channel of a multi-channel table to fit (through the reference's
        model of that channel); None fits every channel at once, the medium's per-channel
        parameters one per channel, the others tied (:mod:`veil.fitting.channel_steps`).
    screen, start : a candidate's quick fit to rank it; a :class:`FitResult` of this model
        (of one channel: or {name: value}) to start from, the grid evaluated only if that
        does not convince (veil.fitting.screening). Other arguments as :func:`fit_reference`.
    """
    settings = _settings(accuracy, max_nfev, progress, model_error, propagation, screen)
    cls = _family(medium_model, "medium")
    fitted = _template(cls, _options(options, variant))
    return _through_medium(
        "medium", table, reference, fitted, None, fixed, black, free, channel, start, **settings
    )


def fit_target(
    table,
    medium,
    *,
    fixed=None,
    black=None,
    variant: str | None = None,
    accuracy: str = "default",
    max_nfev=None,
    progress=None,
    brdf_model=None,
    options=None,
    free=None,
    model_error=None,
    propagation=None,
    channel: str | None = None,
    screen: bool = False,
    start=None,
) -> FitResult:
    """Step 2 (docs/model.md sec. 7): fit the target's f_r, the medium fixed.

    table : the target object measured in the medium (DataFrame or CSV path).
    medium : the step-1 :class:`FitResult` or a medium model.
    variant : None uses the medium's; a different value is an error.
    brdf_model, options : the target's BRDF family (default Torrance-Sparrow) and options.
    Other arguments as :func:`fit_medium` (``propagation``: step 1's covariance into
    ``stderr_total``; "auto" uses sigma points where step 1 left a parameter uncertain by
    more than a quarter of its scale, as tau at optical depth 0.1, and at most 3 times it:
    beyond, the first order with a note).
    """
    settings = _settings(accuracy, max_nfev, progress, model_error, propagation, screen)
    cls = _family(brdf_model, "brdf")
    fitted = _template(cls, as_options(options))
    checked = _options(None, variant)  # the variant asked for: the medium's own or none
    return _through_medium(
        "target", table, medium, fitted, checked, fixed, black, free, channel, start, **settings
    )


#: Of a step through the medium: the kind of the model it holds fixed, how errors name
#: that model, and how they name the step's table.
_THROUGH = {
    "medium": ("brdf", "the reference", "reference (in the medium)"),
    "target": ("medium", "the medium", "target (in the medium)"),
}


def _through_medium(
    step: str,
    table,
    given,
    fitted: Model,
    given_options: dict | None,
    fixed,
    black,
    free,
    channel: str | None,
    start,
    **settings,
) -> FitResult:
    """Step 1 (``step`` "medium") or 2 ("target") of ``fitted`` (its family's template)
    through ``given`` held fixed: every channel of a table of several at once, else the one
    ``channel``; ``given_options`` (step 2's) must agree with the given model's own;
    ``settings`` as :func:`_settings` returns them. Other arguments as :func:`fit_medium`."""
    kind, role, what = _THROUGH[step]
    cls = type(fitted)
    several = _several(table, black, channel, what)
    if several is not None:
        if given_options is not None:
            model = _given_of(given, next(iter(several)))
            if isinstance(model, Model):
                check_options(model, given_options, role)
        return fit_through(
            step,
            several,
            fitted,
            given,
            fixed=as_fixed(fixed),
            freed=_freed(cls, free, step),
            starts=STARTS[step],
            role=role,
            source=_source(several),
            start=start,
            **settings,
        )
    one = _of_channel(given, channel)
    model = as_given(one, kind, role)
    if given_options is not None:
        check_options(model, given_options, role)
    data = prepare(table, black, what, channel)
    # the fit whose covariance enters stderr_total: of a fit of several channels, the one
    # channel's part (its parameters and the tied ones)
    given_result = given.of_channel(channel) if isinstance(given, FitResult) else given
    return fit_step(
        step,
        data,
        fitted,
        model,
        given_result if isinstance(given_result, FitResult) else None,
        as_fixed(fixed),
        freed=_freed(cls, free, step),
        **settings,
        **_start(start, cls, channel),
    )


def _start(start, cls, channel: str | None) -> dict:
    """``fit_step``'s start arguments from a fit's ``start``: {name: value} of ``cls`` (a
    result's, of ``channel`` for a result over several channels) and whether it is a fit
    that ran the grid's best start (not one started from a given point: its stats have no
    ``start``); a FitError for a result of another family."""
    if start is None:
        return {}
    if not isinstance(start, FitResult):
        return {"start": as_start(start, cls.param_names(), cls.NAME)}
    check_start_family(start, cls.NAME)
    if start.channels:
        if channel is None:
            raise FitError("start: a fit over several channels; name the channel to fit")
        params = start.one_model(channel).as_dict()
    else:
        params = dict(start.params)
    return {"start": params, "start_ran_best": began_at_grid(start)}


def _settings(accuracy, max_nfev, progress, model_error, propagation, screen) -> dict:
    """The settings of a step through the medium, checked: the keywords that
    :func:`veil.fitting.step_fit.fit_step` and
    :func:`veil.fitting.channel_steps.fit_through` take alike."""
    check_accuracy(accuracy)
    check_max_nfev(max_nfev)
    check_progress(progress)
    model_error, propagation = discrepancy.check_kind(model_error), check_method(propagation)
    as_flag(screen, "screen", FitError)
    return dict(
        accuracy=accuracy,
        max_nfev=max_nfev,
        progress=progress,
        model_error=model_error,
        propagation=propagation,
        screen=screen,
    )


def _several(table, black, channel: str | None, what: str) -> dict[str, FitData] | None:
    """{channel: its data} of a table of several channels when no ``channel`` is chosen (a
    step through the medium then fits them at once, :mod:`veil.fitting.channel_steps`);
    None otherwise (one channel: the step as before)."""
    if channel is not None:
        return None
    loaded, channels = channels_of(table, what)
    if channels is None or len(channels) < 2:
        return None
    return {c: prepare(loaded, black, what, channel=c) for c in channels}


def _source(datas: dict[str, FitData]) -> str:
    """How errors name a table of several channels."""
    return RowNames(next(iter(datas.values())).table).what


def _given_of(given, channel: str):
    """The model of ``channel`` of a given fit of several channels (for the options' check;
    its options are every channel's); anything else as it is."""
    if isinstance(given, FitResult) and given.channels is not None and not given.JOINT:
        return given.as_model(
            channel=channel if channel in given.channels else next(iter(given.channels))
        )
    return given


def _of_channel(result, channel: str | None):
    """A fit of several channels given to a step of one ``channel``: its model of that
    channel (a FitError naming the channels when none is chosen); anything else as it is."""
    if isinstance(result, FitResult) and result.channels is not None:
        return result.one_model(channel)
    return result


def model_values(result_or_model, other, angles, accuracy: str = "default") -> np.ndarray:
    """Values of a fitted model at canonical ``angles``: f_r alone for a BRDF when ``other`` is
    None, else the apparent reflectance with ``other`` (the medium or the BRDF)."""
    model = (
        result_or_model.one_model() if isinstance(result_or_model, FitResult) else result_or_model
    )
    angles = tuple(np.asarray(a, dtype=float) for a in angles)
    if other is None:
        return DirectModel(model, angles).values(model.to_vector())
    if isinstance(other, FitResult):
        other = other.one_model()
    brdf, medium = (model, other) if model.KIND == "brdf" else (other, model)
    engine = ApparentModel(cast(BRDF, brdf), cast(Medium, medium), angles, RULES[accuracy])
    return engine.values(brdf.to_vector(), medium.to_vector())


__all__ = [
    "fit_reference",
    "fit_direct",
    "fit_medium",
    "fit_target",
    "model_values",
    "STARTS",
    "ROLE",
]

__all__ += ["MisfitWarning", "MISFIT_CHI2", "warn_misfit"]
