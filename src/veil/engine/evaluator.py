"""The one chunked evaluator of the engine: configurations go to the engine in chunks of a
fixed size, the last one padded with its last row, so that the engine compiles once per
model structure, accuracy and chunk size whatever the number of configurations.

- :func:`evaluate`: the apparent reflectance (docs/model.md sec. 5), or f_r alone without a
  medium, at any number of configurations, with progress (simulations, renders, ``veil
  eval``);
- :class:`ApparentModel` and :class:`DirectModel`: values and Jacobians at a session's fixed
  configurations, as a function of the parameter vectors (the fits)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..models import BRDF, BTDF
from . import channel_programs
from .angles import direction
from .apparent import (
    apparent,
    check_finite,
    direct_padded,
    direct_programs,
    reflectance,
    run_direct,
)
from .forward import CHUNK, Forward
from .quadrature import check_accuracy as check_accuracy

#: The models a Jacobian can be taken with respect to (ApparentModel.value_and_jacobian).
WRT = ("brdf", "medium")


def check_progress(progress, name: str = "progress") -> None:
    """An InputError unless ``progress`` (a callback) is None or callable."""
    if progress is not None and not callable(progress):
        raise InputError(f"{name} = {progress!r}: expected a function to call, or None")


def chunks(size: int, chunk: int = CHUNK):
    """(start, stop, indices padded to ``chunk`` with the last row) covering ``size`` rows."""
    for start in range(0, size, chunk):
        stop = min(start + chunk, size)
        yield start, stop, np.minimum(np.arange(start, start + chunk), stop - 1)


def evaluate(
    brdf,
    medium,
    theta_i,
    phi_i,
    theta_r,
    phi_r,
    *,
    accuracy: str = "default",
    chunk: int = CHUNK,
    progress=None,
) -> np.ndarray:
    """Apparent reflectance (docs/model.md eq. 1; f_r alone when ``medium`` is None) at flat
    arrays of angles (degrees), ``chunk`` configurations per engine call;
    ``progress(done, total)`` after each chunk."""
    ti, pi_, tr, pr = (
        np.ravel(np.asarray(a, dtype=float))
        for a in np.broadcast_arrays(theta_i, phi_i, theta_r, phi_r)
    )
    n = ti.size
    if medium is None:
        out = np.asarray(reflectance(brdf, ti, tr, pi_, pr), dtype=float)
        if progress:
            progress(n, n)
        return out
    out = np.empty(n)
    for start, stop, idx in chunks(n, chunk):
        vals = apparent(brdf, medium, ti[idx], tr[idx], pi_[idx], pr[idx], accuracy=accuracy)
        out[start:stop] = np.asarray(vals)[: stop - start]
        if progress:
            progress(stop, n)
    return out


class ApparentModel:
    """Apparent reflectance at the data's configurations, CHUNK at a time (the same shape as
    :func:`veil.simulate`, so both share one compilation per accuracy)."""

    def __init__(self, brdf: BRDF, medium: BTDF, angles, rule):
        self.models = (brdf, medium)
        self.size = len(angles[0])
        self.parts = []
        for start, stop, idx in chunks(self.size):
            ti, pi_, tr, pr = (a[idx] for a in angles)
            self.parts.append((Forward(brdf, medium, ti, tr, pi_, pr, rule), stop - start))
        self.all_b = tuple(range(len(brdf.PARAMS)))
        self.all_m = tuple(range(len(medium.PARAMS)))
        self.values_calls = 0
        self.jacobian_calls = 0

    def prepare(self, values: bool = True, jacobians=(), channels: int = 1) -> list:
        """Compile (or load) in the background what :meth:`values`/:meth:`terms` and
        :meth:`value_and_jacobian` with each ``wrt`` of ``jacobians`` will need (every chunk
        shares one compilation), and :meth:`anticipate` for ``channels`` channels; returns
        the futures of the channels' programs (none where channels run one at a time)."""
        frees = [self._free(wrt) for wrt in jacobians]
        together = channel_programs.prepare(self.parts[0][0], channels, values, frees)
        # channels run together need the one-channel values only where they coincide (the
        # starting grid), and its Jacobians hardly ever: those compile when called
        self.parts[0][0].prepare(values, [] if together else frees)
        return together

    def anticipate(self, vbs, vms, wrt=None) -> None:
        """The channels of one iteration at once (one parameter vector pair per channel):
        their values, or with ``wrt`` their Jacobians, computed by one program and kept for
        the calls of each channel that follow (:mod:`veil.engine.channel_programs`)."""
        free = None if wrt is None else self._free(wrt)
        for f, _ in self.parts:
            if not channel_programs.anticipate(f, vbs, vms, free):
                return

    def _free(self, wrt) -> tuple:
        """(BRDF indices, medium indices) differentiated for ``wrt``, a subset of WRT: every
        parameter of each named model, none of the other (one compiled Jacobian per subset,
        whichever of its parameters a fit holds)."""
        unknown = set(wrt) - set(WRT)
        if unknown:
            raise ValueError(f"wrt = {tuple(wrt)!r}; expected a subset of {WRT}")
        return (self.all_b if "brdf" in wrt else (), self.all_m if "medium" in wrt else ())

    def terms(self, vb, vm) -> np.ndarray:
        """Term matrices (M, 3, 2) with the scale parameters set to 1 (rows T_d^2, T_d T_t,
        T_t^2; columns the BRDF's separable and lobe parts; veil.integrator)."""
        self.values_calls += 1
        terms = np.concatenate([f.terms(vb, vm)[:n] for f, n in self.parts])
        return check_finite(terms, "the apparent reflectance", self.models, [vb, vm], terms)

    def values(self, vb, vm) -> np.ndarray:
        """Apparent reflectance (M,) at parameter vectors ``vb``, ``vm`` (docs/model.md eq. 1)."""
        self.values_calls += 1
        terms = np.concatenate([f.terms(vb, vm)[:n] for f, n in self.parts])
        values = self.parts[0][0].combine(terms, vb, vm)
        return check_finite(values, "the apparent reflectance", self.models, [vb, vm], terms)

    def value_and_jacobian(self, vb, vm, wrt=WRT) -> tuple[np.ndarray, np.ndarray]:
        """Values (M,) and d value / d (every BRDF parameter, every medium parameter), the
        columns of a model not in ``wrt`` NaN (not computed: a fit of one model's parameters
        runs the smaller program of its own derivatives)."""
        self.jacobian_calls += 1
        free_b, free_m = self._free(wrt)
        nb = len(self.all_b)
        cols = list(free_b) + [nb + i for i in free_m]
        vals, jacs = [], []
        for f, n in self.parts:
            v, j = f.value_and_jacobian(vb, vm, free_brdf=free_b, free_medium=free_m)
            full = np.full((n, nb + len(self.all_m)), np.nan)
            full[:, cols] = j[:n]
            vals.append(v[:n])
            jacs.append(full)
        values = check_finite(
            np.concatenate(vals), "the apparent reflectance", self.models, [vb, vm]
        )
        return values, np.concatenate(jacs)


class DirectModel:
    """f_r at the data's configurations (docs/model.md sec. 2), padded as the f_r programs
    are (:func:`veil.engine.apparent.direct_padded`: one compilation for every session of up
    to 256 configurations)."""

    def __init__(self, model, angles):
        self.model = model  # a BRDF instance: its options select the code path
        self.size = len(angles[0])
        ti, pi_, tr, pr = angles
        self.padded = direct_padded(direction(ti, pi_), direction(tr, pr))
        self.values_calls = 0
        self.jacobian_calls = 0

    def values(self, v) -> np.ndarray:
        """f_r (M,) at the BRDF parameter vector ``v``."""
        self.values_calls += 1
        f, _ = direct_programs(self.model)
        values = run_direct(f, v, self.padded, self.size)
        return check_finite(values, "the reflectance f_r", [self.model], [v])

    def value_and_jacobian(self, v) -> tuple[np.ndarray, np.ndarray]:
        """f_r (M,) and its Jacobian (M, len(v)) with respect to ``v``."""
        self.jacobian_calls += 1
        f, jf = direct_programs(self.model)
        values = run_direct(f, v, self.padded, self.size)
        return (
            check_finite(values, "the reflectance f_r", [self.model], [v]),
            run_direct(jf, v, self.padded, self.size),
        )


__all__ = ["ApparentModel", "DirectModel"]
