"""The closest model of another family: a registered BRDF family fitted to a model's f_r
(docs/interop.md). The exporter uses it for a family that a renderer does not have (the
paper's Torrance-Sparrow -> the renderer's microfacet plastic) and reports the RMS
difference; the fit is veil's own (:func:`veil.fitting.fit_direct`) on noise-free values."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..data.channels import CHANNEL
from ..data.protocol import protocol
from ..engine.apparent import reflectance
from ..errors import InputError
from ..fitting import fit_direct
from ..fitting.session_data import MAGNITUDE
from ..fitting.steps import MisfitWarning
from ..models import BRDF, Model, model_class

#: Relative angles (deg) of the in-plane configurations a closest fit compares: the paper's
#: protocol (dense near the mirror direction) at more light-camera angles.
CLOSEST_PSI = (10.0, 30.0, 60.0, 90.0, 120.0)
#: Relative weight of every configuration in the fit (sigma = this x value): a relative
#: least-squares fit, the peak and the diffuse floor counted alike.
RELATIVE_SIGMA = 0.01


@dataclass(frozen=True)
class Closest:
    """``model`` of family ``family`` fitted to ``source``; ``rms_relative`` is the RMS of
    (model - source) / source over ``n`` configurations, ``max_relative`` the largest."""

    source: Model
    model: Model
    rms_relative: float
    max_relative: float
    n: int
    converged: bool

    def sentence(self) -> str:
        return (
            f"{self.model.NAME} fitted to the {self.source.NAME} result: RMS relative "
            f"difference in f_r {100 * self.rms_relative:.3g} % (largest "
            f"{100 * self.max_relative:.3g} %) over {self.n} in-plane configurations "
            f"(psi {', '.join(f'{p:g}' for p in CLOSEST_PSI)} deg)"
        )


class MagnitudeError(InputError):
    """A BRDF whose f_r a closest fit cannot handle (beyond :data:`MAGNITUDE`): ``reach`` is
    what its f_r reaches, ``params`` {name: value} of the parameters beyond that range
    (those to look at), ``limits`` the range."""

    def __init__(self, message: str, reach: str, params: dict, limits: tuple) -> None:
        super().__init__(message)
        self.reach, self.params, self.limits = reach, params, limits


def configurations() -> pd.DataFrame:
    return protocol(CLOSEST_PSI)


def _angles() -> list:
    table = configurations()
    return [table[c].to_numpy() for c in ("theta_i", "theta_r", "phi_i", "phi_r")]


def _values_text(source: Model) -> str:
    return ", ".join(f"{n} = {v:.6g}" for n, v in zip(source.param_names(), source.to_vector()))


def check_source(source: Model) -> None:
    """What :func:`closest` checks of ``source`` before its fit (a :class:`MagnitudeError`
    for an f_r beyond what it handles): for a caller that names where ``source`` came from."""
    _source_values(source, _angles())


def _source_values(source: Model, angles) -> np.ndarray:
    """f_r of ``source`` at ``angles``, checked for what a closest fit handles."""
    if not isinstance(source, BRDF):
        raise InputError(f"a closest fit needs a BRDF; {source.NAME} is a {source.KIND} model")
    values = reflectance(source, *angles)
    if not np.any(values):  # no rescaling makes a closest fit of nothing
        raise InputError(
            f"{source.NAME}: f_r is 0 at every configuration (every coefficient 0), so there "
            f"is no reflectance to export; a fit gives that to data with no signal above the "
            f"black cloth (its message says so): check the measurements and fit them again"
        )
    lo, hi = MAGNITUDE
    if np.all(np.isfinite(values)) and not lo <= float(np.max(np.abs(values))) <= hi:
        params = dict(zip(source.param_names(), source.to_vector()))
        large = {n: float(v) for n, v in params.items() if v != 0 and not lo <= abs(v) <= hi}
        reach = f"f_r reaches {float(np.max(np.abs(values))):.3g}"
        raise MagnitudeError(
            f"{source.NAME}: {reach}, outside the magnitudes a closest fit handles "
            f"({lo:g} to {hi:g})"
            + (
                f"; parameter(s) {', '.join(f'{n} = {v:.3g}' for n, v in large.items())}"
                if large
                else ""
            )
            + ": rescale the data the result was fitted to",
            reach,
            large,
            (lo, hi),
        )
    if not np.all(values > 0):
        raise InputError(
            f"{source.NAME} ({_values_text(source)}): f_r is not positive at every "
            f"configuration, so the "
            f"relative difference of a closest fit is undefined"
        )
    return values


def _closest_of(source: Model, model: Model, values, angles, converged: bool) -> Closest:
    rel = reflectance(model, *angles) / values - 1.0
    return Closest(
        source,
        model,
        float(np.sqrt(np.mean(rel**2))),
        float(np.max(np.abs(rel))),
        len(values),
        converged,
    )


def closest(source: Model, family: str, options: dict | None = None) -> Closest:
    """The model of ``family`` (with ``options``) closest to the BRDF ``source`` in relative
    least squares over :func:`configurations`."""
    cls = model_class(family, "brdf")
    table = configurations()
    angles = _angles()
    values = _source_values(source, angles)
    data = table[["theta_i", "phi_i", "theta_r", "phi_r"]].copy()
    data["value"] = values
    data["sigma"] = RELATIVE_SIGMA * values
    with warnings.catch_warnings():  # how far the family is from it is said below
        warnings.simplefilter("ignore", MisfitWarning)
        result = fit_direct(data, brdf_model=cls.NAME, options=dict(options or {}))
    return _closest_of(source, result.one_model(), values, angles, bool(result.converged))


def closest_channels(sources: dict, family: str, options: dict | None = None) -> dict:
    """{channel: :class:`Closest`} of the BRDFs ``sources`` ({channel: model}): the model of
    ``family`` closest to every channel at once, one relative least-squares fit over the
    channels (docs/channels.md) with the family's shared parameters tied, so that the
    channels' models differ only where the family declares a parameter per channel."""
    cls = model_class(family, "brdf")
    table = configurations()
    angles = [table[c].to_numpy() for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    values = {c: _source_values(m, angles) for c, m in sources.items()}
    parts = []
    for c, v in values.items():
        part = table[["theta_i", "phi_i", "theta_r", "phi_r"]].copy()
        part[CHANNEL] = c
        part["value"] = v
        part["sigma"] = RELATIVE_SIGMA * v
        parts.append(part)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MisfitWarning)
        result = fit_direct(
            pd.concat(parts, ignore_index=True), brdf_model=cls.NAME, options=dict(options or {})
        )
    return {
        c: _closest_of(m, result.as_model(channel=c), values[c], angles, bool(result.converged))
        for c, m in sources.items()
    }


__all__ = [
    "Closest",
    "MagnitudeError",
    "check_source",
    "closest",
    "closest_channels",
    "configurations",
    "CLOSEST_PSI",
]
