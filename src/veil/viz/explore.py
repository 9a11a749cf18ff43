"""What ``veil explore`` shows, without the page: its state, its controls as read from the
model declarations, and every curve, lobe and image it draws (docs/explore.md).

The page itself (:mod:`veil.viz.explore_page`) only lays these out; everything here is
numpy in, numpy out, so that the tests can check the numbers without a browser.

- :class:`State`: the BRDF and the medium (family, parameters, options), the incidence
  angle, psi and the curve's axis; its JSON file (format ``veil.explore/1``) is what the
  page's "share" button writes and what ``veil explore STATE.json`` reopens.
- :func:`slider_spec`: one slider per declared parameter (log10 of the value for
  ``log_scale`` parameters, bounds from the declaration).
- :class:`Curves`: the in-plane curves with and without the medium at fixed configurations,
  compiled once (``Forward``), re-evaluated at each new parameter vector.
- :func:`transmission_lobe`, :func:`polar_lobe`: the lobes; the lit sphere:
  :mod:`veil.viz.explore_sphere`.
- :class:`FitView`: a fit result and its data: points with error bars, the fitted model, an
  uncertainty band drawn from the fit's covariance, residuals, the parameters with stderr.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..models import PRESETS, Model, default_class, model_class
from ..models import names as family_names
from .explore_sphere import LIVE_ACCURACY, REFINED_ACCURACY, sphere, sphere_colour

if TYPE_CHECKING:
    from concurrent.futures import Future

#: Value of the "format" key of a state file.
FORMAT = "veil.explore/1"
#: The two axes a curve can run along (docs/model.md sec. 1).
CURVES = ("incidence", "goniometer")
#: Largest polar angle (deg) of a curve's configurations.
MAX_ANGLE = 89.0
#: Decades a log slider spans on each side of its value when a bound is open-ended.
LOG_SPAN = 3.0
#: Configurations of every curve's engine (a curve has at most 287 points; the rest repeat
#: its last): one compiled program for both axes and every angle.
CURVE_SIZE = 320
#: Steps of a slider over its range.
SLIDER_STEPS = 400


# --------------------------------------------------------------------------------------
# controls from the declarations
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SliderSpec:
    """One slider: the declared parameter ``name`` moves over [start, end] in slider units
    (log10 of the value when ``log``), in steps of ``step``."""

    name: str
    label: str
    start: float
    end: float
    step: float
    log: bool
    doc: str
    unit: str

    def to_slider(self, value: float) -> float:
        """The slider position of a parameter value (clipped to the range; a log slider's
        left end for 0)."""
        if self.log and not value > 0:
            return self.start
        x = math.log10(value) if self.log else float(value)
        return min(max(x, self.start), self.end)

    def to_value(self, x: float) -> float:
        return 10.0 ** float(x) if self.log else float(x)


def slider_spec(cls, name: str, value: float) -> SliderSpec:
    """The slider of parameter ``name`` of family ``cls`` around ``value``: bounds from the
    declaration (open ones kept off by a step), log10 units for ``log_scale`` parameters,
    whose open-ended bounds are replaced by :data:`LOG_SPAN` decades around the value."""
    p = cls.param(name)
    value = float(value)
    if p.log_scale:
        ref = value if value > 0 else (p.start if p.start and p.start > 0 else 1.0)
        lo = math.log10(ref) - LOG_SPAN
        hi = math.log10(ref) + LOG_SPAN
        if p.lower > 0:
            lo = max(lo, math.log10(p.lower))
        if math.isfinite(p.upper):
            hi = min(hi, math.log10(p.upper))
        step = (hi - lo) / SLIDER_STEPS
        if p.lower > 0 and p.lower_open:
            lo += step
        if math.isfinite(p.upper) and p.upper_open:
            hi -= step
        label = f"log10 {name}"
    else:
        span = 10.0 * max(1.0, abs(value))
        lo = p.lower if math.isfinite(p.lower) else min(value, 0.0) - span
        hi = p.upper if math.isfinite(p.upper) else max(value, 0.0) + span
        step = (hi - lo) / SLIDER_STEPS
        if p.lower_open:
            lo += step
        if p.upper_open:
            hi -= step
        label = name
    unit = f" [{p.unit}]" if p.unit else ""
    return SliderSpec(
        name=name,
        label=f"{label}{unit}",
        start=lo,
        end=hi,
        step=step,
        log=p.log_scale,
        doc=p.doc,
        unit=p.unit,
    )


def presets_of(cls) -> dict:
    """{preset name: model} of the presets of family ``cls`` (the paper's objects, media)."""
    return {k: m for k, m in PRESETS.items() if type(m) is cls}


def families(kind: str) -> list[str]:
    """Registered family names of ``kind``."""
    return family_names(kind)


# --------------------------------------------------------------------------------------
# the state
# --------------------------------------------------------------------------------------
def _entry(model) -> dict | None:
    if model is None:
        return None
    return {
        "model": model.NAME,
        "params": {k: float(v) for k, v in model.as_dict().items()},
        "options": dict(model.options()),
    }


def _model(entry, kind: str, where: str):
    if entry is None:
        if kind == "medium":
            return None
        raise InputError(f"{where}: a BRDF is required")
    if (
        not isinstance(entry, dict)
        or not isinstance(entry.get("model"), str)
        or not isinstance(entry.get("params"), dict)
    ):
        raise InputError(f"{where}: expected an object with keys 'model' and 'params'")
    cls = model_class(entry["model"], kind)
    options = entry.get("options") or {}
    if not isinstance(options, dict):
        raise InputError(f"{where}: 'options' must be an object")
    try:
        params = {k: float(v) for k, v in entry["params"].items()}
    except (TypeError, ValueError):
        raise InputError(f"{where}: every parameter must be a number") from None
    try:
        return cls.from_params(params, options)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


@dataclass
class State:
    """What the page shows: models, angles (degrees) and the files it was opened with."""

    brdf: Model
    medium: Model | None
    theta_i: float = 45.0
    psi: float = 60.0
    curve: str = "incidence"
    results: list = field(default_factory=list)
    data: str | None = None
    black: str | None = None
    #: Results fitted over several channels (docs/channels.md): {channel: (brdf, medium)},
    #: and the channel the controls edit, whose models are ``brdf`` and ``medium``.
    channels: dict | None = None
    channel: str | None = None

    def __post_init__(self):
        for name, lo, hi in (("theta_i", 0.0, MAX_ANGLE), ("psi", 0.0, 2 * MAX_ANGLE - 2.0)):
            v = getattr(self, name)
            if (
                not isinstance(v, (int, float))
                or isinstance(v, bool)
                or not math.isfinite(v)
                or not lo <= v <= hi
            ):
                raise InputError(f"{name} = {v!r}: expected degrees in [{lo:g}, {hi:g}]")
            setattr(self, name, float(v))
        if self.curve not in CURVES:
            raise InputError(f"curve = {self.curve!r}; expected one of {', '.join(CURVES)}")
        if self.channels is not None:
            if not isinstance(self.channels, dict) or not self.channels:
                raise InputError("channels: expected {channel: (brdf, medium)}, at least one")
            self.channels = {str(c): tuple(v) for c, v in self.channels.items()}
            self.channel = str(self.channel or next(iter(self.channels)))
            if self.channel not in self.channels:
                raise InputError(
                    f"channel {self.channel!r}: the state has channels {', '.join(self.channels)}"
                )
            self.channels[self.channel] = (self.brdf, self.medium)

    @classmethod
    def default(cls) -> State:
        """The paper's default families at their first presets (their starting values when
        a family has no preset)."""
        models = []
        for kind in ("brdf", "medium"):
            family = default_class(kind)
            found = presets_of(family)
            models.append(next(iter(found.values())) if found else family.template())
        return cls(models[0], models[1])

    def with_model(self, model, kind: str) -> State:
        """The state with ``model`` as the edited channel's model of ``kind``; in the other
        channels the parameters declared shared across channels follow it (the same family
        and options), those per channel keep their values."""
        if self.channels is None:
            return State(**{**self.__dict__, kind: model})
        k = 0 if kind == "brdf" else 1
        channels = {}
        for c, pair in self.channels.items():
            mine = model if c == self.channel else _follow(pair[k], model)
            channels[c] = (mine, pair[1]) if k == 0 else (pair[0], mine)
        return State(**{**self.__dict__, kind: model, "channels": channels})

    def with_channel(self, channel: str) -> State:
        """The state whose controls edit ``channel``."""
        brdf, medium = self.channels[channel] if self.channels else (self.brdf, self.medium)
        return State(**{**self.__dict__, "brdf": brdf, "medium": medium, "channel": channel})

    # -- files --------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = {
            "format": FORMAT,
            "brdf": _entry(self.brdf),
            "medium": _entry(self.medium),
            "theta_i": self.theta_i,
            "psi": self.psi,
            "curve": self.curve,
            "results": [os.fspath(r) for r in self.results],
            "data": None if self.data is None else os.fspath(self.data),
            "black": None if self.black is None else os.fspath(self.black),
        }
        if self.channels is not None:
            out["channel"] = self.channel
            out["channels"] = {
                c: {"brdf": _entry(b), "medium": _entry(m)} for c, (b, m) in self.channels.items()
            }
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"

    def save(self, path) -> None:
        from ..io import write_text_atomic

        write_text_atomic(path, self.to_json())

    @classmethod
    def from_dict(cls, data, source: str = "the state") -> State:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise InputError(
                f"{source}: not a veil explore state (expected key 'format' = {FORMAT!r})"
            )
        brdf = _model(data.get("brdf"), "brdf", f"{source}, key 'brdf'")
        medium = _model(data.get("medium"), "medium", f"{source}, key 'medium'")
        results = data.get("results") or []
        if not isinstance(results, list) or not all(isinstance(r, str) for r in results):
            raise InputError(f"{source}: key 'results' must be a list of file names")
        for key in ("data", "black"):
            if data.get(key) is not None and not isinstance(data[key], str):
                raise InputError(f"{source}: key {key!r} must be a file name or null")
        channels = _channels_entry(data.get("channels"), source)
        try:
            return cls(
                brdf,
                medium,
                theta_i=data.get("theta_i", 45.0),
                psi=data.get("psi", 60.0),
                curve=data.get("curve", "incidence"),
                results=results,
                data=data.get("data"),
                black=data.get("black"),
                channels=channels,
                channel=data.get("channel"),
            )
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path) -> State:
        from ..fitting.result import read_json

        return cls.from_dict(read_json(path), os.fspath(path))


def _follow(old, model):
    """``old`` (another channel's model) after the edited channel's became ``model``: the
    parameters shared across channels taken from ``model``; ``model`` itself when the
    family changed."""
    if model is None or old is None or type(old) is not type(model):
        return model
    params = old.as_dict()
    for name, sharing in model.channel_sharing().items():
        if sharing == "shared":
            params[name] = getattr(model, name)
    return type(model).from_params(params, model.options())


def _channels_entry(entry, source: str) -> dict | None:
    if entry is None:
        return None
    if not isinstance(entry, dict) or not all(isinstance(v, dict) for v in entry.values()):
        raise InputError(
            f"{source}: key 'channels' must map each channel to an object with "
            f"keys 'brdf' and 'medium'"
        )
    return {
        c: (
            _model(v.get("brdf"), "brdf", f"{source}, channel {c}, key 'brdf'"),
            _model(v.get("medium"), "medium", f"{source}, channel {c}, key 'medium'"),
        )
        for c, v in entry.items()
    }


def is_state_file(path) -> bool:
    """Whether ``path`` holds a state (JSON with format veil.explore/1), not a fit result."""
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError, RecursionError):  # not a state: read as a fit result then
        return False
    return isinstance(data, dict) and data.get("format") == FORMAT


# --------------------------------------------------------------------------------------
# curves
# --------------------------------------------------------------------------------------
def curve_axis(state_or_curve, theta_i: float, psi: float) -> tuple[np.ndarray, str]:
    """The curve's abscissa (deg) and its name: the signed reflection angle at fixed
    incidence, or the goniometer's rotation rho at fixed psi (docs/model.md sec. 1); 1 deg apart,
    0.1 deg apart within 6 deg of the mirror configuration."""
    curve = state_or_curve
    if curve == "incidence":
        lo, hi, mirror, name = -MAX_ANGLE, MAX_ANGLE, theta_i, "theta_r (signed, deg)"
    else:
        half = psi / 2.0
        lo, hi, mirror, name = -(MAX_ANGLE - half), MAX_ANGLE - half, 0.0, "rho (deg)"
    coarse = np.arange(math.ceil(lo), math.floor(hi) + 1.0, 1.0)
    fine = np.round(np.arange(-60, 61) * 0.1 + mirror, 10)
    x = np.unique(np.concatenate([coarse, fine[(fine >= lo) & (fine <= hi)]]))
    return x, name


def curve_angles(curve: str, theta_i: float, psi: float, x) -> tuple:
    """Canonical (theta_i, phi_i, theta_r, phi_r) of the abscissae ``x`` of a curve."""
    from ..engine.angles import from_goniometer, from_signed_inplane

    x = np.asarray(x, dtype=float)
    if curve == "incidence":
        ti, tr = np.full_like(x, theta_i), x
    else:
        ti, tr = from_goniometer(psi, x)
    ti, pi_, tr, pr = from_signed_inplane(ti, tr)
    return ti, pi_, tr, pr


class Curves:
    """Apparent reflectance and f_r along one curve, for any parameter values of the
    families of ``brdf`` and ``medium`` (their options fixed): the engine compiles once per
    family, options, accuracy and size, then each call is one evaluation."""

    def __init__(
        self, brdf, medium, curve: str, theta_i: float, psi: float, accuracy: str = LIVE_ACCURACY
    ):
        from ..engine.apparent import RULES
        from ..engine.forward import Forward

        self.key = self.key_of(brdf, medium, curve, theta_i, psi, accuracy)
        self.x, self.xlabel = curve_axis(curve, theta_i, psi)
        self.angles = curve_angles(curve, theta_i, psi, self.x)
        self.accuracy = accuracy
        # every curve has CURVE_SIZE configurations (the last repeated): one compilation
        # serves both axes and every angle
        n = self.x.size
        if n > CURVE_SIZE:
            raise AssertionError(f"a curve of {n} points exceeds CURVE_SIZE = {CURVE_SIZE}")
        idx = np.minimum(np.arange(CURVE_SIZE), n - 1)
        ti, pi_, tr, pr = (a[idx] for a in self.angles)
        self.forward = (
            None if medium is None else Forward(brdf, medium, ti, tr, pi_, pr, RULES[accuracy])
        )

    @staticmethod
    def key_of(brdf, medium, curve, theta_i, psi, accuracy=LIVE_ACCURACY) -> tuple:
        return (
            type(brdf),
            tuple(sorted(brdf.options().items())),
            None if medium is None else type(medium),
            None if medium is None else tuple(sorted(medium.options().items())),
            curve,
            float(theta_i),
            float(psi),
            accuracy,
        )

    def clear(self, brdf) -> np.ndarray:
        """f_r along the curve (docs/model.md sec. 2)."""
        from ..engine.apparent import reflectance

        ti, pi_, tr, pr = self.angles
        return np.asarray(reflectance(brdf, ti, tr, pi_, pr), dtype=float)

    def through(self, brdf, medium) -> np.ndarray | None:
        """The apparent reflectance along the curve (docs/model.md eq. 1); None without medium."""
        if self.forward is None or medium is None:
            return None
        from ..engine.apparent import check_finite

        vb, vm = brdf.to_vector(), medium.to_vector()
        terms = self.forward.terms(vb, vm)[: self.x.size]
        values = self.forward.combine(terms, vb, vm)
        return check_finite(values, "the apparent reflectance", [brdf, medium], terms=terms)


def log_floor(*arrays) -> float:
    """The floor of a log plot of the arrays: 1e-6 of their largest value."""
    top = max((float(np.max(a)) for a in arrays if a is not None and np.size(a)), default=1.0)
    return max(top, 1e-300) * 1e-6


#: Decades the log radius of the transmission lobe spans.
LOBE_DECADES = 4.0


def log_radius(values, decades: float = LOBE_DECADES) -> np.ndarray:
    """Radius in [0, 1] of values on a log scale: 1 at their peak, 0 at ``decades`` below
    (and under)."""
    v = np.asarray(values, dtype=float)
    top = max(float(np.max(v)), 1e-300)
    return np.clip(1.0 + np.log10(np.maximum(v, top * 10.0**-decades) / top) / decades, 0.0, 1.0)


def polar_lobe(x, values, curve: str, theta_i: float, psi: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the curve drawn as a lobe in the plane of incidence: the value as the
    distance along the camera direction R (x to the camera's side, y along the normal)."""
    ti, pi_, tr, pr = curve_angles(curve, theta_i, psi, x)
    signed = np.radians(np.where(pr == 0.0, tr, -tr))
    v = np.asarray(values, dtype=float)
    return v * np.sin(signed), v * np.cos(signed)


def transmission_lobe(medium, theta_i: float, points: int = 721) -> tuple:
    """The medium's transmission f_t(I, w) for the light's direction I (polar ``theta_i``,
    azimuth 180 deg) and w through the plane of incidence (docs/model.md sec. 3-4): returns
    (angle of w from the normal, signed, deg; f_t; x; y) with (x, y) the lobe in the plane
    (x towards the camera's side). f_t peaks at w = I: light scattered forward keeps its
    direction."""
    from .._jax import jnp
    from ..engine.angles import direction

    angle = np.linspace(-MAX_ANGLE, MAX_ANGLE, points)
    phi = np.where(angle < 0, 180.0, 0.0)
    wa = direction(theta_i, 180.0)
    wb = direction(np.abs(angle), phi)
    fn = _transmission_fn(type(medium), tuple(sorted(medium.options().items())))
    value = np.asarray(fn(jnp.asarray(medium.to_vector()), wa[None, :], wb), dtype=float)
    if not np.all(np.isfinite(value)):
        raise FloatingPointError(f"the transmission of {medium} is not finite")
    rad = np.radians(angle)
    return angle, value, value * np.sin(rad), value * np.cos(rad)


_TRANSMISSION_FNS: dict = {}


def _transmission_fn(cls, options: tuple):
    """f_t(v, wa, wb) of a medium family with these options, compiled once."""
    key = (cls, options)
    if key not in _TRANSMISSION_FNS:
        from .._jax import jax

        template = cls.template(**dict(options))
        _TRANSMISSION_FNS[key] = jax.jit(template.evaluate)
    return _TRANSMISSION_FNS[key]


def warm_up(state: State, workers: int = 3) -> tuple[list[Future], Future]:
    """Compile in the background what a page of ``state`` needs: the curves, the
    transmission lobe and the sphere at the live accuracy in parallel, then the refined
    sphere. Returns (futures of the live parts, future of the refined sphere)."""
    from concurrent.futures import ThreadPoolExecutor

    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="veil-explore-warm")
    s = state

    def curves():
        c = Curves(s.brdf, s.medium, s.curve, s.theta_i, s.psi)
        c.clear(s.brdf)
        c.through(s.brdf, s.medium)

    live = [pool.submit(curves), pool.submit(sphere, s.brdf, s.medium, s.theta_i)]
    if s.medium is not None:
        live.append(pool.submit(transmission_lobe, s.medium, s.theta_i))

    def refined():
        for f in live:
            f.result()
        sphere(s.brdf, s.medium, s.theta_i, accuracy=REFINED_ACCURACY)

    later = pool.submit(refined)
    pool.shutdown(wait=False)
    return live, later


#: The colour each channel's curves are drawn in: r, g, b, and a wavelength's hue.
CHANNEL_COLOURS = {"r": "#d62728", "g": "#2ca02c", "b": "#1f77b4"}


def channel_colour(channel: str) -> str:
    """The colour of a channel's curves: its own for r, g, b; for a wavelength (nm) a hue
    from violet (400) to red (700), grey outside the visible."""
    if channel in CHANNEL_COLOURS:
        return CHANNEL_COLOURS[channel]
    try:
        nm = float(channel)
    except ValueError:
        return "#7f7f7f"
    if not 380.0 <= nm <= 780.0:
        return "#7f7f7f"
    import colorsys

    hue = 0.75 * (1.0 - (min(max(nm, 400.0), 700.0) - 400.0) / 300.0)
    r, g, b = colorsys.hsv_to_rgb(hue, 0.85, 0.85)
    return f"#{int(255 * r):02x}{int(255 * g):02x}{int(255 * b):02x}"


__all__ = [
    "FORMAT",
    "CURVES",
    "State",
    "channel_colour",
    "sphere_colour",
    "CHANNEL_COLOURS",
    "SliderSpec",
    "slider_spec",
    "presets_of",
    "families",
    "is_state_file",
    "curve_axis",
    "curve_angles",
    "Curves",
    "polar_lobe",
    "transmission_lobe",
    "sphere",
    "warm_up",
    "log_floor",
]
