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
:mod:`veil.fitting.model_error`).
"""

from __future__ import annotations

import warnings
from typing import cast

import numpy as np

from ..data.measurements import RowNames
from ..engine.evaluator import ApparentModel, DirectModel
from ..engine.quadrature import RULES
from ..errors import FitError, InputError
from ..models import BRDF, Medium, Model, default_class, model_class
from ..models.base import VARIANT_OPTION
from . import model_error as discrepancy
from .channel_fit import fit_channels
from .channel_steps import fit_through
from .given import as_given, check_options
from .problem import ITERATION_ACCURACY, Problem, check_accuracy, session_problem
from .propagation import check_method, describe
from .reported_uncertainty import model_floor, reported
from .result import FitResult, model_entry
from .session_data import FitData, channels_of, prepare
from .solver import as_fixed, check_fixed, check_max_nfev, run, summarize
from .start_values import step_starts

#: Least-squares runs started from the best distinct grid points, by step.
STARTS = {"reference": 3, "direct": 3, "medium": 2, "target": 2}
#: The fit role (starting grid of the model's declaration) of each step.
ROLE = {"reference": "reference", "direct": "reference", "medium": "medium",
        "target": "target"}


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
    options = dict(options or {})
    if variant is not None:
        options[VARIANT_OPTION] = variant
    return options


def _fixed_slots(problem: Problem, cls, fixed: dict, what: str) -> dict:
    """{slot name: value} for ``fixed`` given in ``cls``'s own parameter names."""
    out = {}
    for name, value in fixed.items():
        if name not in cls.param_names():
            raise FitError(f"cannot fix {name!r} in the {what} fit: {cls.NAME} has parameters "
                           f"{', '.join(cls.param_names())}")
        check_fixed(name, value, cls.param(name), cls.__name__)
        out[cls.param(name).key] = float(value)
    return out


def _freed(cls, free, what: str) -> set:
    """Names of held parameters (``Param.held``) that ``free`` asks to fit."""
    free = set(free or ())
    unknown = [n for n in free if n not in cls.param_names()]
    if unknown:
        raise FitError(f"cannot free {', '.join(map(repr, unknown))} in the {what} fit: "
                       f"{cls.NAME} has parameters {', '.join(cls.param_names())}")
    return free


def _prepare_engine(problem, cls, given, given_result, accuracy: str,
                    propagation: str) -> None:
    """Everything a fit through a medium will compile (or load), side by side: derivatives
    in the fitted model's parameters, and in the given model's to propagate its covariance
    (not with ``propagation`` "off")."""
    block = problem.blocks[0]
    propagates = (propagation != "off" and given_result is not None
                  and given_result.covariance(total=True) is not None)
    wrt = [(cls.KIND,)] + ([(type(given).KIND,)] if propagates else [])
    block.model(ITERATION_ACCURACY).prepare(values=True, jacobians=wrt)
    if accuracy != ITERATION_ACCURACY:
        block.model(accuracy).prepare(values=True)


def prefetch(data: FitData, *, brdf_model=None, brdf_options=None, medium_model=None,
             medium_options=None, variant: str | None = None,
             accuracy: str = "default") -> None:
    """Start compiling (or loading) in the background the engine programs that steps 1 and 2
    run at ``data``'s configurations (values and both models' derivatives at the iterations'
    rule, values at ``accuracy``), so that a first run compiles them while step 0 fits the
    clear reference. A model or option the steps will refuse is left to them to report."""
    try:
        brdf = _template(_family(brdf_model, "brdf"), dict(brdf_options or {}))
        medium = _template(_family(medium_model, "medium"), _options(medium_options, variant))
    except (InputError, FitError):
        return
    rules = [ITERATION_ACCURACY] + ([accuracy] if accuracy != ITERATION_ACCURACY else [])
    for rule in rules:
        model = ApparentModel(cast(BRDF, brdf), cast(Medium, medium), data.angles, RULES[rule])
        model.prepare(values=True, jacobians=[("medium",), ("brdf",)] if rule == rules[0] else [])


def _step(step: str, data: FitData, fitted: Model, given: Model | None, given_result,
          fixed: dict, accuracy: str, max_nfev, progress, freed=(),
          model_error: str = "off", propagation: str = "auto") -> FitResult:
    """One step: the ``fitted`` model's parameters free (but ``fixed``, and the held ones not
    ``freed``), ``given`` held; unless ``model_error`` is "off" a weighted fit estimates the
    model-discrepancy term of that kind (:mod:`veil.fitting.model_error`); ``propagation``
    is how a given fit's covariance enters (:mod:`veil.fitting.propagation`)."""
    cls = type(fitted)
    brdf, medium = (given, fitted) if cls.KIND == "medium" else (fitted, given)
    clash = [n for n in freed if n in fixed]
    if clash:
        raise FitError(f"{', '.join(clash)} both fixed and freed")
    free = [p.key for p in cls.PARAMS
            if p.name not in fixed and (not p.held or p.name in freed)]
    what = {"reference": "reference (clear medium)", "direct": "target (clear medium)",
            "medium": "medium", "target": "target"}[step]
    if not free:
        raise FitError(f"every parameter of the {what} fit is fixed "
                       f"({', '.join(cls.param_names())}): nothing to fit")
    # by kind: a medium step holds the BRDF given, the others fit the BRDF
    problem = session_problem(None, cast(BRDF, brdf), cast("Medium | None", medium), free=free,
                              data=data, what=what)
    for key, value in _fixed_slots(problem, cls, fixed, what).items():
        problem.values[problem.index(key)] = value
    if data.size <= len(free):
        raise FitError(f"the {what} data have {data.size} point(s) but the fit has "
                       f"{len(free)} free parameter(s) ({', '.join(free)}): need more points "
                       f"than free parameters (fix some with fixed=... / --fix NAME=VALUE, "
                       f"or measure more configurations)")
    if medium is not None:
        _prepare_engine(problem, cls, given, given_result, accuracy, propagation)
    starts, n_grid = step_starts(problem, cls.KIND, ROLE[step], STARTS[step], progress)
    outcome = run(problem, starts, accuracy=accuracy, max_nfev=max_nfev, progress=progress,
                  every=medium is None)
    summary = summarize(problem, outcome)
    x = outcome.solution.x
    own = {p.key: p.name for p in cls.PARAMS}           # slot name -> model's own name
    names = [own[k] for k in cls.keys()]

    def rename(se, corr):
        """(stderr, correlation) in the model's own names."""
        return ({own[k]: se[k] for k in cls.keys()},
                {own[a]: {own[b]: r for b, r in row.items()} for a, row in corr.items()})

    rep = reported(problem, x, summary, outcome.values, kind=model_error, rename=rename,
                   given_result=given_result,
                   given_column=None if given is None
                   else lambda n: problem.index(type(given).param(n).key),
                   propagation=propagation, keep_influence=cls.KIND == "medium",
                   floor=model_floor(brdf, medium))
    media = [m for m in (medium,) if m is not None]
    variant = media[0].options().get(VARIANT_OPTION) if media else None
    stats = dict(outcome.stats, grid_points=n_grid)
    message = summary.message
    if rep.propagation is not None:
        stats["propagation"] = rep.propagation
        note = describe(rep.propagation,
                        f"the {given_result.step or 'given'} fit's covariance")
        message += f"; {note}" if note else ""
    if summary.converged:  # one that did not converge says so (exit status 1)
        warn_misfit(summary.chi2_reduced, data, what)
    return FitResult(model=cls.NAME,
                     params={own[k]: float(x[problem.index(k)]) for k in cls.keys()},
                     stderr=rep.stderr, correlation=rep.correlation,
                     residuals=tuple(float(r) for r in summary.residuals),
                     chi2_reduced=summary.chi2_reduced, rms_relative=summary.rms_relative,
                     n_points=data.size, converged=summary.converged, message=message,
                     variant=variant,
                     fixed={n: float(x[problem.index(cls.param(n).key)]) for n in names
                            if cls.param(n).key not in free},
                     step=step, weighted=data.sigma is not None, accuracy=outcome.accuracy,
                     given=None if given is None else model_entry(given),
                     stderr_total=rep.stderr_total, correlation_total=rep.correlation_total,
                     stats=stats,
                     options=fitted.options(), determined=summary.determined,
                     model_error=rep.model_error)


#: A weighted fit whose reduced chi-square exceeds this misses its data by about ten
#: standard deviations on average: a systematic error in the data, not noise.
MISFIT_CHI2 = 100.0


class MisfitWarning(UserWarning):
    """A fit that converged but describes its data far worse than their sigma says."""


def warn_misfit(chi2_reduced: float, data: FitData, what: str) -> None:
    """Warn (:class:`MisfitWarning`) when a weighted fit's reduced chi-square exceeds
    :data:`MISFIT_CHI2` (called for converged fits), pointing to the black cloth: glow left
    in the data (no black session subtracted) or a wrong one is the usual cause; negative
    values say so."""
    if data.sigma is None or not chi2_reduced > MISFIT_CHI2:
        return
    negative = int(np.count_nonzero(data.y < 0))
    seen = (f"; {negative} of {data.size} values are negative" if negative else "")
    cause = ("check the black-cloth session subtracted (same configurations, same medium) "
             "and the sigma column" if data.black else
             "no black-cloth session was subtracted: measure the medium with the black cloth "
             "(docs/measurements.md) and give it with --black (black=...)")
    warnings.warn(f"the {what} fit's reduced chi-square is {chi2_reduced:.4g}: the model "
                  f"misses the data by about {np.sqrt(chi2_reduced):.3g} standard deviations "
                  f"on average{seen}; {cause}", MisfitWarning, stacklevel=4)


# --------------------------------------------------------------------------------------
# the steps
# --------------------------------------------------------------------------------------
def fit_reference(table, *, fixed=None, black=None, max_nfev=None, progress=None,
                  brdf_model=None, options=None, free=None, model_error=None,
                  channel: str | None = None) -> FitResult:
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
    """
    return fit_direct(table, fixed=fixed, black=black, max_nfev=max_nfev, progress=progress,
                      step="reference", brdf_model=brdf_model, options=options, free=free,
                      model_error=model_error, channel=channel)


def fit_direct(table, *, fixed=None, black=None, max_nfev=None, progress=None,
               step: str = "direct", brdf_model=None, options=None, free=None,
               model_error=None, channel: str | None = None) -> FitResult:
    """f_r fitted to clear-medium data (docs/model.md sec. 2); ``step`` labels the result
    ("reference" for step 0, "direct" for a target measured without the medium);
    ``channel`` as :func:`fit_reference`."""
    check_max_nfev(max_nfev)
    model_error = discrepancy.check_kind(model_error)
    if step not in ("reference", "direct"):
        raise FitError(f"step = {step!r}; a clear-water fit is step 'reference' or 'direct'")
    cls = _family(brdf_model, "brdf")
    fitted = _template(cls, dict(options or {}))
    what = "reference" if step == "reference" else "target"
    if channel is None:
        table, channels = channels_of(table, f"{what} (clear medium)")
        if channels is not None and len(channels) > 1:
            return fit_channels(table, black, cast(BRDF, fitted), channels, step=step,
                                what=f"{what} (clear medium)", fixed=as_fixed(fixed),
                                freed=_freed(cls, free, what), max_nfev=max_nfev,
                                progress=progress, model_error=model_error,
                                starts=STARTS[step])
    data = prepare(table, black, f"{what} (clear medium)", channel=channel)
    return _step(step, data, fitted, None, None, as_fixed(fixed), ITERATION_ACCURACY,
                 max_nfev, progress, _freed(cls, free, what), model_error)


def fit_medium(table, reference, *, fixed=None, black=None, variant: str | None = None,
               accuracy: str = "default", max_nfev=None, progress=None, medium_model=None,
               options=None, free=None, model_error=None, propagation=None,
               channel: str | None = None) -> FitResult:
    """Step 1 (docs/model.md sec. 7): fit the medium, the reference's f_r fixed.

    table : the reference object measured in the medium (DataFrame or CSV path).
    reference : the step-0 :class:`FitResult` or a BRDF model.
    medium_model, options : the medium family (default the paper's Henyey-Greenstein
        medium) and its options; ``variant`` is the shortcut for the Fresnel variant
        ("paper" or "exit", docs/model.md sec. 3).
    free : names of parameters the family holds by default to fit too (the physical
        medium's intensity factor ``s``).
    accuracy : quadrature of the reported result ("fast", "default", "high"); iterations
        run at "fast" and are polished at this accuracy.
    model_error : as :func:`fit_reference`; a step-1 term is also used by step 2 (the
        same medium model on the target's data).
    propagation : how the given fit's covariance enters ``stderr_total``: "auto" (the
        default, None), "linear" or "sigma-points" (:mod:`veil.fitting.propagation`).
    channel : the one channel of a multi-channel table to fit; the reference of a fit of
        several channels gives its model of that channel. None fits every channel at once
        (:mod:`veil.fitting.channel_steps`): the medium's parameters declared per channel
        one per channel, the others tied, each channel through the reference's model of
        that channel (a fit over the same channels; a BRDF model is every channel's).
    Other arguments as :func:`fit_reference`.
    """
    check_accuracy(accuracy)
    check_max_nfev(max_nfev)
    model_error = discrepancy.check_kind(model_error)
    propagation = check_method(propagation)
    cls = _family(medium_model, "medium")
    fitted = _template(cls, _options(options, variant))
    what = "reference (in the medium)"
    several = _several(table, black, channel, what)
    if several is not None:
        return fit_through("medium", several, fitted, reference, fixed=as_fixed(fixed),
                           freed=_freed(cls, free, "medium"), accuracy=accuracy,
                           max_nfev=max_nfev, progress=progress, model_error=model_error,
                           propagation=propagation, starts=STARTS["medium"],
                           role="the reference", source=_source(several))
    reference = _of_channel(reference, channel)
    brdf = as_given(reference, "brdf", "the reference")
    data = prepare(table, black, "reference (in the medium)", channel)
    return _step("medium", data, fitted, brdf,
                 reference if isinstance(reference, FitResult) else None, as_fixed(fixed),
                 accuracy, max_nfev, progress, _freed(cls, free, "medium"), model_error,
                 propagation)


def fit_target(table, medium, *, fixed=None, black=None, variant: str | None = None,
               accuracy: str = "default", max_nfev=None, progress=None, brdf_model=None,
               options=None, free=None, model_error=None, propagation=None,
               channel: str | None = None) -> FitResult:
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
    check_accuracy(accuracy)
    check_max_nfev(max_nfev)
    model_error = discrepancy.check_kind(model_error)
    propagation = check_method(propagation)
    cls = _family(brdf_model, "brdf")
    fitted = _template(cls, dict(options or {}))
    several = _several(table, black, channel, "target (in the medium)")
    if several is not None:
        model_m = _given_of(medium, next(iter(several)))
        if isinstance(model_m, Model):
            check_options(model_m, _options(None, variant), "the medium")
        return fit_through("target", several, fitted, medium, fixed=as_fixed(fixed),
                           freed=_freed(cls, free, "target"), accuracy=accuracy,
                           max_nfev=max_nfev, progress=progress, model_error=model_error,
                           propagation=propagation, starts=STARTS["target"],
                           role="the medium", source=_source(several))
    model_m = as_given(_of_channel(medium, channel), "medium", "the medium")
    check_options(model_m, _options(None, variant), "the medium")
    data = prepare(table, black, "target (in the medium)", channel)
    return _step("target", data, fitted, model_m,
                 medium if isinstance(medium, FitResult) else None, as_fixed(fixed),
                 accuracy, max_nfev, progress, _freed(cls, free, "target"), model_error,
                 propagation)


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
        return given.as_model(channel=channel if channel in given.channels
                              else next(iter(given.channels)))
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
    model = result_or_model.one_model() if isinstance(result_or_model, FitResult) \
        else result_or_model
    angles = tuple(np.asarray(a, dtype=float) for a in angles)
    if other is None:
        return DirectModel(model, angles).values(model.to_vector())
    if isinstance(other, FitResult):
        other = other.one_model()
    brdf, medium = (model, other) if model.KIND == "brdf" else (other, model)
    engine = ApparentModel(cast(BRDF, brdf), cast(Medium, medium), angles, RULES[accuracy])
    return engine.values(brdf.to_vector(), medium.to_vector())


__all__ = ["fit_reference", "fit_direct", "fit_medium", "fit_target", "model_values",
           "STARTS", "ROLE"]

__all__ += ["MisfitWarning", "MISFIT_CHI2", "warn_misfit"]
