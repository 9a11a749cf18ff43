"""Simulated measurement sessions (docs/model.md sec. 7) following the paper's protocol.

``simulate`` evaluates value = apparent(brdf, medium) + glow at the configurations of
:func:`veil.protocol.protocol` and adds relative Gaussian noise: value_noisy = value (1 + noise z),
z ~ N(0, 1) from ``numpy.random.default_rng(seed)``; ``sigma`` = noise * value.

The medium's glow (what a black cloth measures: light scattered by the medium towards the
camera without reaching the object) is not part of docs/model.md. veil's model, a choice of this
module (docs/measurements.md):

    glow(I, R) = glow_level * f_std * s(I, R) / s(I0, R0)
    s(I, R)    = iso + lobe_weight * p(gamma),   cos(gamma) = -I . R

the medium's isotropic coefficient (T_d) plus single back-scattering by its phase lobe
(T_t p(g, gamma)), gamma being the angle between the light's travel direction (-I) and the
view direction R; no Fresnel factors (the paper's cylinder makes both crossings normal). The
glow depends on the medium (and the light) only, as a real black cloth's does: ``f_std`` is
the noise-free apparent value of a fixed standard object, the paper's reference object
(BRDF2, :data:`GLOW_STANDARD`), through the same medium at the off-peak reference
configuration I0 = (0 deg, 180 deg), R0 = (60 deg, 0 deg) (psi = 60, rho = -30). So
``glow_level`` = 0.03 makes the glow 3 % of the reference object's signal there, and every
object simulated in one medium gets the same glow: one black cloth serves them all. In a
goniometer session I . R = cos(psi): the glow is constant within each psi. A clear medium
has no glow.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from ..engine.angles import direction
from ..engine.apparent import as_brdf, as_btdf, scales_text
from ..engine.evaluator import CHUNK, check_accuracy, check_progress, evaluate
from ..errors import InputError, as_flag
from ..models.base import compiled_kernel
from .protocol import PSI, protocol

if TYPE_CHECKING:
    import pandas as pd

#: The glow's reference configuration (theta_i, phi_i, theta_r, phi_r), degrees.
GLOW_REFERENCE = (0.0, 180.0, 60.0, 0.0)
GLOW_LEVEL = 0.03
#: The standard object whose signal through the medium sets the glow's scale (the paper's
#: reference object, table 2).
GLOW_STANDARD = "BRDF2"


def glow_shape(medium, theta_i, phi_i, theta_r, phi_r) -> np.ndarray:
    """s(I, R) = iso + lobe_weight * p(gamma), cos(gamma) = -I . R (module docstring): the
    medium's scattering kernel (:meth:`veil.models.Medium.kernel`)."""
    m = as_btdf(medium)
    v = m.to_vector()
    wi = np.asarray(direction(theta_i, phi_i))
    wr = np.asarray(direction(theta_r, phi_r))
    one_minus_mu = np.maximum(1.0 + np.sum(wi * wr, axis=-1), 0.0)  # 1 - cos(gamma)
    return np.asarray(compiled_kernel(m)(v, one_minus_mu), dtype=float)


@lru_cache(maxsize=64)
def glow_scale(medium, accuracy: str = "default") -> float:
    """f_std: the standard object's (:data:`GLOW_STANDARD`) noise-free apparent value
    through ``medium`` at :data:`GLOW_REFERENCE` (module docstring), evaluated as simulate
    evaluates (one CHUNK-sized call, so it shares simulate's compilation)."""
    from ..models import PRESETS

    angles = [np.full(1, a) for a in GLOW_REFERENCE]
    return float(_evaluate(PRESETS[GLOW_STANDARD], as_btdf(medium), angles, accuracy, None)[0])


def _evaluate(brdf, medium, angles, accuracy, progress):
    """Noise-free apparent values at canonical angles (the engine's chunked evaluator)."""
    ti, pi_, tr, pr = angles
    return evaluate(brdf, medium, ti, pi_, tr, pr, accuracy=accuracy, progress=progress)


def simulate(
    brdf,
    medium,
    psi=PSI,
    noise: float = 0.01,
    seed: int = 0,
    black: bool = False,
    *,
    fine_step: float = 1.0,
    coarse_step: float = 5.0,
    window: float = 10.0,
    limit: float = 85.0,
    glow: float = GLOW_LEVEL,
    accuracy: str = "default",
    progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame | tuple[pd.DataFrame, pd.DataFrame]:
    """Simulated goniometer session of ``brdf`` through ``medium`` (docs/model.md sec. 7).

    brdf, medium : models or preset names; ``medium=None`` is clear water (no integral,
        no glow). Several colour channels at once: ``brdf`` a dict {channel: (brdf,
        medium)} and ``medium`` None (:func:`simulate_channels`).
    psi, fine_step, coarse_step, window, limit : the protocol (:func:`veil.protocol.protocol`),
        degrees.
    noise : relative standard deviation of the Gaussian noise (>= 0); ``sigma`` = noise * value.
    seed : seed of ``numpy.random.default_rng``; the object's noise is drawn first, then the
        black cloth's, so the object table does not depend on ``black``.
    black : also return the medium-only (black cloth) table, same configurations, own noise.
    glow : glow level, a fraction of the standard object's (BRDF2's) signal through the
        same medium at the reference configuration (module docstring): the same glow for
        every object in a medium; 0 switches the glow off.
    accuracy : quadrature level of :func:`veil.apparent`.
    progress : called as progress(done, total) while configurations are evaluated.

    Returns a DataFrame with columns psi, rho, theta_i, phi_i, theta_r, phi_r, value, sigma
    (or a pair (table, black_table) when ``black``). Values beyond float64 (a huge noise,
    glow or object) raise a :class:`SimulatedOverflowError` (an InputError) naming the
    argument to change.
    """
    pairs = _pairs(brdf, medium)
    noise, glow = _check_noise(noise, glow, seed, accuracy)
    check_progress(progress)
    black = as_flag(black, "black")
    table = protocol(psi, fine_step=fine_step, coarse_step=coarse_step, window=window, limit=limit)
    n, size = len(table), len(table) * len(pairs)
    parts = []
    for k, (brdf, medium) in enumerate(pairs.values()):
        step = None if progress is None else (lambda done, total, k=k: progress(k * n + done, size))
        parts.append(_session(brdf, medium, table, glow, accuracy, step))
    exact = np.concatenate([p[0] for p in parts])
    glow_values = np.concatenate([p[1] for p in parts])
    rng = np.random.default_rng(seed)
    z_object = rng.standard_normal(size)
    z_black = rng.standard_normal(size)
    rows = _channel_rows(table, list(pairs))
    out, cloth = rows.copy(), rows.copy()
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is named below
        out["value"] = exact + noise * exact * z_object
        out["sigma"] = noise * np.abs(exact)
        cloth["value"] = glow_values + noise * glow_values * z_black
        cloth["sigma"] = noise * glow_values
    # the object's values are mostly its own, or mostly the medium's glow
    source = "glow" if np.max(glow_values) > 0.5 * np.max(np.abs(exact)) else "brdf"
    brdfs = {c: as_brdf(b) for c, (b, _) in pairs.items()}
    _check_noisy(out, exact, noise, source, brdfs, glow)
    if black:
        _check_noisy(cloth, glow_values, noise, "glow", brdfs, glow)
    return (out, cloth) if black else out


class SimulatedOverflowError(InputError):
    """Simulated values beyond float64 (above 1.8e308): ``argument`` names the argument of
    :func:`simulate` to change ("brdf", "noise" or "glow"), ``detail`` says why (the
    message is "ARGUMENT = VALUE: DETAIL"; the command line names its option instead)."""

    def __init__(self, argument: str, shown: str, detail: str):
        super().__init__(f"{argument} = {shown}: {detail}")
        self.argument = argument
        self.detail = detail


def _scales_text(brdfs: dict) -> str:
    """The scale parameters of the BRDFs ``brdfs`` {channel: BRDF} (``Model.SCALES``: the
    values are linear in each): "Pd = 1e+40, Ps = 1e+40" for the one channel keyed None,
    else "channel g: Pd = 1e+40, Ps = 1" per channel."""
    parts = [
        scales_text(m) if c is None else f"channel {c}: {scales_text(m)}" for c, m in brdfs.items()
    ]
    return "; ".join(parts)


def _check_noisy(frame, exact, noise: float, source: str, brdfs: dict, glow: float) -> None:
    """A :class:`SimulatedOverflowError` when a value or sigma of ``frame`` (noise-free values
    ``exact`` with relative noise ``noise``) overflows float64: blamed on ``noise`` when it is
    above 1 and the noise-free values lie far below the top (below 1e300; the noise made
    them overflow), else on the ``source`` of the values: the object
    ("brdf", ``brdfs`` {channel: BRDF}, the channels' rows one after the other) or the
    medium's glow ("glow", its level ``glow``)."""
    bad = ~(np.isfinite(frame["value"].to_numpy()) & np.isfinite(frame["sigma"].to_numpy()))
    if not bad.any():
        return
    peak = float(np.max(np.abs(exact)))
    overflow = (
        f"the simulated values, value (1 + noise z) with z standard normal, overflow float64 "
        f"(they would exceed 1.8e308): the noise-free values reach {peak:.3g}"
    )
    if noise > 1 and peak < 1e300:
        raise SimulatedOverflowError(
            "noise",
            f"{noise:g}",
            f"{overflow}; give a smaller noise (a relative standard deviation: 0.01 is 1 %)",
        )
    if source == "glow":
        raise SimulatedOverflowError(
            "glow", f"{glow:g}", f"{overflow} with noise = {noise:g}; give a smaller glow"
        )
    channels = list(brdfs)
    n = len(frame) // len(channels)
    blamed = {channels[k]: brdfs[channels[k]] for k in np.unique(np.flatnonzero(bad) // n)}
    raise SimulatedOverflowError(
        "brdf",
        "; ".join(dict.fromkeys(str(b) for b in blamed.values())),
        f"{overflow} with noise = {noise:g}; give the object smaller coefficients "
        f"({_scales_text(blamed)}; they scale its values linearly)",
    )


def _pairs(brdf, medium) -> dict:
    """{channel: (brdf, medium)} of :func:`simulate`'s first two arguments; the channel of a
    single pair is None (a table without a channel column)."""
    if not isinstance(brdf, dict):
        return {None: (as_brdf(brdf), None if medium is None else as_btdf(medium))}
    if not brdf or medium is not None:
        raise InputError(
            "channels: expected a dict {channel: (brdf, medium)} with at least one channel "
            "(and no separate medium)"
        )
    _check_channel_names(list(brdf))
    for c, pair in brdf.items():
        if not isinstance(pair, (tuple, list)) or len(pair) != 2:
            raise InputError(f"channels[{c!r}] = {pair!r}: expected a pair (brdf, medium)")
    return brdf


def _check_channel_names(names: list) -> None:
    """An InputError unless every name is a channel a table may hold (docs/measurements.md,
    "Channels": r, g, b or a wavelength in nm), each once, not both kinds."""
    from .channels import RGB, WAVELENGTH_RANGE, channel_label

    labels = [channel_label(c) for c in names]
    lo, hi = WAVELENGTH_RANGE
    for c, label in zip(names, labels):
        if label is None:
            raise InputError(
                f"channels: {c!r} is not a channel; expected r, g or b, or a wavelength "
                f"in nm from {lo:g} to {hi:g}"
            )
    twice = [c for c, label in zip(names, labels) if labels.count(label) > 1]
    if twice:
        raise InputError(f"channels: {', '.join(map(repr, twice))} name one channel")
    if len({label in RGB for label in labels}) > 1:
        raise InputError(
            f"channels: {', '.join(map(repr, names))} mix colour channels and "
            f"wavelengths; a table's channels are r, g, b or wavelengths, not both"
        )


def _channel_rows(table: pd.DataFrame, channels: list) -> pd.DataFrame:
    """The protocol's ``table`` once per channel, with a ``channel`` column (the table itself
    for the one unnamed channel of a single pair)."""
    if channels == [None]:
        return table
    import pandas as pd

    from .channels import CHANNEL

    rows = pd.concat([table] * len(channels), ignore_index=True)
    rows[CHANNEL] = np.repeat(np.array(channels, dtype=object), len(table))
    return rows


def _check_noise(noise, glow, seed, accuracy) -> tuple[float, float]:
    """(noise, glow) as floats; an InputError for a noise or glow level, a seed or an
    accuracy out of place. Numpy's numbers are numbers (a float32 noise too)."""
    for name, val in (("noise", noise), ("glow", glow)):
        if (
            isinstance(val, (bool, np.bool_))
            or not isinstance(val, (int, float, np.integer, np.floating))
            or not math.isfinite(val)
            or val < 0
        ):
            raise InputError(f"{name} = {val!r}: expected a finite number >= 0 (relative)")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed = {seed!r}: expected an integer >= 0")
    check_accuracy(accuracy)
    return float(noise), float(glow)


def _session(
    brdf, medium, table: pd.DataFrame, glow: float, accuracy: str, progress
) -> tuple[np.ndarray, np.ndarray]:
    """(noise-free value, glow) at the configurations of the protocol ``table``: the apparent
    reflectance plus the medium's glow (module docstring)."""
    brdf = as_brdf(brdf)
    if medium is not None:
        medium = as_btdf(medium)
    n = len(table)
    angles = [table[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r")]
    truth = _evaluate(brdf, medium, angles, accuracy, progress)
    if medium is None or glow == 0:
        glow_values = np.zeros(n)
    else:
        shape = glow_shape(medium, *angles)
        scale = glow_scale(medium, accuracy)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is named below
            glow_values = glow * scale * shape / glow_shape(medium, *GLOW_REFERENCE)
        if not np.all(np.isfinite(glow_values)):
            raise SimulatedOverflowError(
                "glow",
                f"{glow:g}",
                f"the medium's glow overflows float64 (it would exceed 1.8e308): it is glow "
                f"times the standard object's ({GLOW_STANDARD}'s) signal through the medium, "
                f"{scale:.3g} at the reference configuration; give a smaller glow (a "
                f"fraction of that signal: 0.03 is 3 %)",
            )
    with np.errstate(over="ignore"):
        total = truth + glow_values
    if not np.all(np.isfinite(total)):
        raise SimulatedOverflowError(
            "brdf",
            str(brdf),
            f"the object's values ({float(np.max(np.abs(truth))):.3g}) plus the medium's "
            f"glow ({float(np.max(glow_values)):.3g}, glow = {glow:g}) overflow float64 (they "
            f"would exceed 1.8e308); give the object smaller coefficients "
            f"({_scales_text({None: brdf})}; they scale its values linearly) or a smaller glow",
        )
    return total, glow_values


def simulate_channels(
    channels: dict, *args, **options
) -> pd.DataFrame | tuple[pd.DataFrame, pd.DataFrame]:
    """A simulated session of several colour channels (docs/measurements.md, "Channels"):
    ``channels`` maps each channel (``"r"``, ``"g"``, ``"b"`` or a wavelength in nm) to its
    (brdf, medium) pair, as :func:`simulate` takes them. The table has the protocol's
    configurations once per channel, channel after channel, with a ``channel`` column
    before ``value`` and ``sigma``. The noise is drawn from one generator: every channel's
    object noise first (in the order given), then every channel's black cloth. ``args`` and
    ``options`` are :func:`simulate`'s after its first two (psi, noise, seed, black, the
    protocol, glow, accuracy, progress): this is ``simulate(channels, None, *args,
    **options)``.
    """
    if not isinstance(channels, dict):
        raise InputError(
            "channels: expected a dict {channel: (brdf, medium)} with at least one channel"
        )
    return simulate(channels, None, *args, **options)


__all__ = [
    "simulate",
    "simulate_channels",
    "SimulatedOverflowError",
    "glow_shape",
    "glow_scale",
    "CHUNK",
    "GLOW_REFERENCE",
    "GLOW_LEVEL",
    "GLOW_STANDARD",
]
