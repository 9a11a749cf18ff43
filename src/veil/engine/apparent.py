"""Public entry points of the forward model: ``apparent`` (docs/model.md eq. 1) and ``reflectance``.

Angles are in degrees and broadcast like numpy arrays; results are numpy arrays.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np

from .._jax import jax, jnp
from ..errors import InputError, InputTypeError, ParameterError, as_flag
from ..models import BRDF, BTDF, preset
from ..models.channel_model import ChannelModel, channel_member, channels_of
from .angles import check_angles, direction
from .forward import Forward
from .programs import Program, structure_name
from .quadrature import ERROR_FACTOR, FINER, RULES, Rule, check_accuracy  # noqa: F401  (re-exported)


def as_brdf(brdf) -> BRDF:
    model = preset(brdf) if isinstance(brdf, str) else brdf
    if not isinstance(model, BRDF):
        raise InputTypeError(f"expected a BRDF (e.g. veil.BRDF1), got {brdf!r}")
    return model


def as_btdf(medium) -> BTDF:
    model = preset(medium) if isinstance(medium, str) else medium
    if not isinstance(model, BTDF):
        raise InputTypeError(f"expected a BTDF medium (e.g. veil.BTDF1), got {medium!r}")
    return model


def scales_text(model, vector=None) -> str:
    """The ``model``'s scale parameters (``Model.SCALES``: its values are linear in each) and
    their values, "Pd = 1e+40, Ps = 1e+40"; ``vector`` gives values other than its own."""
    values = model.to_vector() if vector is None else np.asarray(vector, dtype=float)
    names = model.param_names()
    return ", ".join(f"{n} = {float(values[names.index(n)]):.4g}" for n in model.SCALES.values())


def overflow_error(what: str, models, vectors=None) -> InputError:
    """The InputError for a result that does not fit in a float64 (above 1.8e308): it names
    the models' scale parameters (:func:`scales_text`) and their values; ``vectors`` gives
    parameter values other than the models' own."""
    named = [
        scales_text(m, None if vectors is None else vectors[k])
        for k, m in enumerate(models)
        if m is not None and m.SCALES
    ]
    return InputError(
        f"{what} overflows float64 (it would exceed 1.8e308) with "
        f"{', '.join(named)}: these coefficients scale it linearly (relative "
        f"units); give them smaller values"
    )


def check_finite(values, what: str, models, vectors=None, terms=None) -> np.ndarray:
    """``values`` if every one is finite. Otherwise an :func:`overflow_error` (the scale
    parameters multiply finite ``terms`` into something beyond float64) or, when the engine's
    own ``terms`` are not finite, a FloatingPointError: that is a bug in veil."""
    values = np.asarray(values)
    if terms is not None and not np.all(np.isfinite(terms)):
        _check_facets(models, vectors)
        raise FloatingPointError(
            f"the engine computed a non-finite term for {what} with "
            f"{', '.join(str(m) for m in models if m is not None)}"
        )
    if not np.all(np.isfinite(values)):
        if terms is None and np.any(np.isnan(values)):
            raise FloatingPointError(
                f"{what} is NaN with {', '.join(str(m) for m in models if m is not None)}"
            )
        raise overflow_error(what, models, vectors)
    return values


#: Smallest facet cumulative over the hemisphere the engine integrates: below it the facet
#: law's density underflows float64 and its grids degenerate.
MIN_FACET_MASS = 1e-280


def _check_facets(models, vectors=None) -> None:
    """ParameterError for a BRDF whose facet distribution is too wide to represent (its
    cumulative over the hemisphere underflows): for Torrance-Sparrow a smoothness n below
    about 1e-140 / deg, whose facet law is flat to 1e-280 and so no different from n =
    1e-100 in any digit."""
    for k, model in enumerate(models):
        cdf = getattr(model, "facet_cdf", None)
        if model is None or cdf is None:
            continue
        v = model.to_vector() if vectors is None else np.asarray(vectors[k], dtype=float)
        mass = float(cdf(jnp.asarray(v, dtype=float), 0.5 * np.pi))
        if not mass >= MIN_FACET_MASS:
            raise ParameterError(
                f"{model if vectors is None else type(model).__name__}: its "
                f"facet distribution is too wide for float64 (cumulative "
                f"{mass:.3g} over the hemisphere, below {MIN_FACET_MASS:g}); "
                f"a facet law this flat gives the same values as a smoothness "
                f"of 1e-100, so give a larger smoothness"
            )


def reflectance(brdf, theta_i, theta_r, phi_i=180.0, phi_r=0.0) -> np.ndarray:
    """The object's own BRDF f_r (docs/model.md sec. 2) at the given angles (degrees).

    A :class:`~veil.models.ChannelModel` (``as_model()`` of a fit over several channels)
    gives every channel: the angles' broadcast shape plus a trailing axis of its channels,
    in their order, each channel's values those of its own model bit for bit."""
    if isinstance(brdf, ChannelModel):
        return np.stack(
            [reflectance(brdf[c], theta_i, theta_r, phi_i, phi_r) for c in brdf.channels], axis=-1
        )
    model = as_brdf(brdf)
    ti, tr, pi_, pr = check_angles(theta_i, theta_r, phi_i, phi_r)
    shape = np.broadcast(ti, tr, pi_, pr).shape
    ti, tr, pi_, pr = (np.broadcast_to(a, shape).ravel() for a in (ti, tr, pi_, pr))
    if ti.size == 0:
        return np.zeros(shape)
    f, _ = direct_programs(model)
    padded = direct_padded(direction(ti, pi_), direction(tr, pr))
    value = run_direct(f, model.to_vector(), padded, ti.size)
    return check_finite(value.reshape(shape), "the reflectance f_r", [model])


#: The fewest configurations an f_r program (:func:`direct_programs`) is compiled for: a
#: call is padded to DIRECT_CHUNK or the power of two above it, in one call, so that the
#: sessions of up to DIRECT_CHUNK configurations share one program and larger calls have a
#: program per doubling. (In chunks of 256, each call repeats a rough plastic's per-call
#: tables, about 1.3 ms: a 512 x 512 sphere took 19 times as long, a step-0 Jacobian of
#: 1,024 configurations 4 times.)
DIRECT_CHUNK = 256


def direct_padded(wi, wr) -> tuple[np.ndarray, np.ndarray]:
    """Directions (N, 3) padded with their last row to DIRECT_CHUNK rows or the power of two
    above N (no configurations: DIRECT_CHUNK normal directions, for the programs' shapes)."""
    wi, wr = np.asarray(wi, dtype=float), np.asarray(wr, dtype=float)
    n = len(wi)
    if n == 0:
        normal = np.tile([0.0, 0.0, 1.0], (DIRECT_CHUNK, 1))
        return normal, normal.copy()
    size = max(DIRECT_CHUNK, 1 << (n - 1).bit_length())
    idx = np.minimum(np.arange(size), n - 1)
    return wi[idx], wr[idx]


def run_direct(fn, v, padded, size: int) -> np.ndarray:
    """``fn(v, wi, wr)`` (an f_r program) at the directions of :func:`direct_padded`, cut to
    ``size`` rows."""
    return np.asarray(fn(np.asarray(v, dtype=float), *padded))[:size]


_DIRECT_FNS: dict = {}


def direct_programs(model) -> tuple:
    """f_r(v, wi, wr) and its Jacobian in v (docs/model.md sec. 2) for a BRDF's structure (class
    and options), as stored engine programs (:class:`veil.engine.programs.Program`)."""
    key = model.structure()
    if key not in _DIRECT_FNS:

        def f(v, wi, wr):
            return model.evaluate(v, wi, wr)

        name = structure_name(key)
        _DIRECT_FNS[key] = (
            Program(
                jax.jit(f), f"f_r | {name}", (type(model),), f"{model.NAME}: f_r (clear medium)"
            ),
            Program(
                jax.jit(jax.jacfwd(f)),
                f"f_r jacobian | {name}",
                (type(model),),
                f"{model.NAME}: f_r and its Jacobian",
            ),
        )
    return _DIRECT_FNS[key]


@overload
def apparent(
    brdf,
    medium,
    theta_i,
    theta_r,
    phi_i=...,
    phi_r=...,
    *,
    accuracy: str = ...,
    return_error: Literal[False] = ...,
) -> np.ndarray: ...
@overload
def apparent(
    brdf,
    medium,
    theta_i,
    theta_r,
    phi_i=...,
    phi_r=...,
    *,
    accuracy: str = ...,
    return_error: Literal[True],
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def apparent(
    brdf,
    medium,
    theta_i,
    theta_r,
    phi_i=...,
    phi_r=...,
    *,
    accuracy: str = ...,
    return_error: bool = ...,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]: ...
def apparent(
    brdf,
    medium,
    theta_i,
    theta_r,
    phi_i=180.0,
    phi_r=0.0,
    *,
    accuracy: str = "default",
    return_error: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Apparent reflectance f(I, R) of ``brdf`` seen through ``medium`` (docs/model.md eq. 1).

    Parameters
    ----------
    brdf, medium : model instances or preset names ("BRDF1", "BTDF2", ...). ``medium=None``
        means a clear medium and returns :func:`reflectance`.
    theta_i, theta_r, phi_i, phi_r : angles in degrees, numpy-broadcast. Polar angles in
        [0, 90); defaults put light and camera in the plane of incidence on opposite sides.
    accuracy : "fast", "default" or "high" quadrature.
    return_error : also return an error estimate (absolute): twice the difference to the
        same quadrature with 1.3 times the nodes per dimension (costs about three times the
        evaluation itself).

    Colour: ``brdf`` or ``medium`` (or both) may be a :class:`~veil.models.ChannelModel`
    (``as_model()`` of a fit over several channels; both of the same channels). The values
    (and errors) then have a trailing axis of its channels, in their order; a model of one
    channel beside it is every channel's. Each channel's values are bit for bit those of
    its one-channel models; the channels share one set of configurations, and those whose
    parameters differ only in their scales one run of the quadrature.
    """
    check_accuracy(accuracy)
    return_error = as_flag(return_error, "return_error")
    if medium is None:
        value = reflectance(brdf, theta_i, theta_r, phi_i, phi_r)
        return (value, np.zeros_like(value)) if return_error else value
    channels = channels_of(brdf, medium)
    if channels is not None:
        return _apparent_channels(
            brdf, medium, channels, (theta_i, theta_r, phi_i, phi_r), accuracy, return_error
        )
    b, m = as_brdf(brdf), as_btdf(medium)
    ti, tr, pi_, pr = check_angles(theta_i, theta_r, phi_i, phi_r)
    shape = ti.shape
    vb, vm = b.to_vector(), m.to_vector()

    def evaluate(forward):
        terms = forward.terms(vb, vm)
        value = forward.combine(terms, vb, vm).reshape(shape)
        return check_finite(value, "the apparent reflectance", [b, m], terms=terms)

    fine = None
    if return_error:  # its program loads (or compiles) on a worker thread meanwhile
        fine = Forward(b, m, ti, tr, pi_, pr, FINER[accuracy])
        fine.prepare(values=True)
    value = evaluate(Forward(b, m, ti, tr, pi_, pr, RULES[accuracy]))
    if not return_error:
        return value
    finer = evaluate(fine)
    error = ERROR_FACTOR * np.abs(value - finer)
    return value, check_finite(error, "the error estimate of the apparent reflectance", [b, m])


def _apparent_channels(brdf, medium, channels, angles, accuracy: str, return_error: bool):
    """:func:`apparent` of every channel (its docstring, "Colour"): one :class:`Forward` of
    the configurations for all of them, whose programs run once for consecutive channels
    that differ only in scale parameters (``Forward.terms`` keeps its last term matrices)."""
    pairs = {
        c: (as_brdf(channel_member(brdf, c)), as_btdf(channel_member(medium, c))) for c in channels
    }
    ti, tr, pi_, pr = check_angles(*angles)
    shape = ti.shape
    b0, m0 = pairs[channels[0]]

    def evaluate(forward):
        out = []
        for c in channels:
            b, m = pairs[c]
            vb, vm = b.to_vector(), m.to_vector()
            terms = forward.terms(vb, vm)
            value = forward.combine(terms, vb, vm).reshape(shape)
            out.append(
                check_finite(value, f"the apparent reflectance of channel {c}", [b, m], terms=terms)
            )
        return np.stack(out, axis=-1)

    fine = None
    if return_error:
        fine = Forward(b0, m0, ti, tr, pi_, pr, FINER[accuracy])
        fine.prepare(values=True)
    value = evaluate(Forward(b0, m0, ti, tr, pi_, pr, RULES[accuracy]))
    if not return_error:
        return value
    error = ERROR_FACTOR * np.abs(value - evaluate(fine))
    return value, check_finite(error, "the error estimate of the apparent reflectance", [b0, m0])
