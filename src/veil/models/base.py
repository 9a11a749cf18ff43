"""What every model declares, and what everything above ``models/`` reads from it.

A model is a frozen dataclass whose float fields are its parameters (in declaration order)
and whose other fields are static options (for example the medium's Fresnel ``variant``).
The class declares

- ``NAME`` (registry key), ``KIND`` ("brdf" or "medium"), ``LABEL`` (one line for people);
- ``PARAMS``: one :class:`Param` per parameter - bounds, unit, meaning, the fit coordinate
  (``log_scale``), a neutral starting value, the name it takes next to another model's
  parameters (``alias``), whether media of a joint fit may share it (``share``), whether it
  takes one value per colour channel or one for all channels (``channels``) and how its
  relative uncertainty is judged (``error_scale``);
- ``OPTIONS``: one :class:`Option` per option (default and allowed values);
- ``SCALES``: the parameters that scale one part of the model linearly (the engine computes
  the parts with them set to 1, and the fits solve them exactly for starting values);
- ``START``: grids of starting values over the other parameters, by fit role ("reference",
  "target" for a BRDF; "medium" for a medium).

Construction validates every value, so an invalid model cannot exist. The engine and the
fits never touch parameter values of instances inside JAX code: they work on the parameter
*vector* (:meth:`Model.to_vector`) and the methods of a template of the model (which read its
options only), so one compiled function serves every parameter value.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Self

from .._lazy import np
from ..errors import InputTypeError, ParameterError

if TYPE_CHECKING:  # the types only: models import JAX and numpy on first use (veil._lazy)
    from jax import Array
    from numpy import ndarray

KINDS = ("brdf", "medium")
#: Fit roles whose starting grids a model declares, by kind.
ROLES = {"brdf": ("reference", "target"), "medium": ("medium",)}
SHARING = (None, "shared", "per-medium")
#: How a parameter spans the channels of a multi-channel table (docs/measurements.md,
#: "Channels"): one value per channel, or one value tied across the channels. None (not
#: declared) means a scale parameter per channel and any other shared.
CHANNEL_SHARING = (None, "per-channel", "shared")
#: The option that result files also keep under their own top-level key "variant" (the
#: medium's Fresnel variant, docs/model.md sec. 3), and commands offer as ``--variant``.
VARIANT_OPTION = "variant"
ERROR_SCALES = ("value", "bound")


def geometric_grid(lower: float, upper: float, n: int, digits: int = 4) -> tuple:
    """``n`` values from ``lower`` to ``upper`` in geometric progression, rounded to
    ``digits`` decimals: a starting grid for a scale-like parameter (plain Python, so that
    declarations import without numpy)."""
    return tuple(round(lower * (upper / lower) ** (k / (n - 1)), digits) for k in range(n))


@dataclass(frozen=True)
class Param:
    """One declared parameter (module docstring).

    name, lower, upper, doc, unit : the parameter and its physical bounds (open or closed).
    log_scale : a positive scale factor, fitted as its logarithm.
    start : a neutral value where fits start when no grid or data says otherwise.
    alias : its name next to the other model's parameters, when the plain name would clash
        (the paper medium's index ``eta`` is ``eta_u`` beside the BRDF's ``eta``).
    share : in a joint fit over several media, None = always one value per medium,
        "shared" = one value for all media unless declared otherwise, "per-medium" = one per
        medium unless declared shared.
    channels : in a fit of several colour channels at once, "per-channel" = one value per
        channel (albedos, scales, a medium's optical depth and albedo), "shared" = one value
        tied across the channels (roughness, index, g); None = undeclared (a scale per
        channel, any other shared; :meth:`Model.channel_sharing`).
    error_scale : a relative uncertainty is stderr / |value| ("value") or stderr / the
        distance to the nearer bound ("bound": g's lobe width scales with 1 - |g|).
    held : fits hold it at ``start`` unless asked to free it (``free=``, ``--free``).
    """

    name: str
    lower: float
    upper: float
    doc: str
    unit: str = ""
    lower_open: bool = False
    upper_open: bool = False
    log_scale: bool = False
    start: float | None = None
    alias: str | None = None
    share: str | None = None
    channels: str | None = None
    error_scale: str = "value"
    held: bool = False

    def __post_init__(self) -> None:
        if self.share not in SHARING:
            raise ValueError(
                f"Param {self.name}: share = {self.share!r}; expected one of {SHARING}"
            )
        if self.channels not in CHANNEL_SHARING:
            raise ValueError(
                f"Param {self.name}: channels = {self.channels!r}; expected one of "
                f"{CHANNEL_SHARING}"
            )
        if self.error_scale not in ERROR_SCALES:
            raise ValueError(f"Param {self.name}: error_scale = {self.error_scale!r}")

    @property
    def key(self) -> str:
        """The parameter's name next to the other model's (``alias`` or ``name``)."""
        return self.alias or self.name

    def check(self, value: float, owner: str) -> None:
        if not isinstance(value, numbers.Real) or isinstance(value, bool):
            raise InputTypeError(f"{owner}.{self.name} must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ParameterError(f"{owner}.{self.name} = {v!r} is not a finite number")
        if not self.contains(v):
            raise ParameterError(
                f"{owner}.{self.name} = {v:g} is outside {self.interval()} ({self.doc})"
            )

    def contains(self, v: float) -> bool:
        lo_bad = v <= self.lower if self.lower_open else v < self.lower
        hi_bad = v >= self.upper if self.upper_open else v > self.upper
        return not (lo_bad or hi_bad)

    def interval(self) -> str:
        lo = "(" if self.lower_open else "["
        hi = ")" if self.upper_open else "]"
        return f"{lo}{self.lower:g}, {self.upper:g}{hi}"

    def relative_error(self, value: float, stderr) -> float:
        """stderr relative to the value or to the distance to the nearer bound
        (``error_scale``); inf when undetermined."""
        if stderr is None or not math.isfinite(stderr):
            return math.inf
        if self.error_scale == "bound":
            room = min(value - self.lower, self.upper - value)
            return stderr / max(room, 1e-12)
        return stderr / abs(value) if value != 0 else math.inf


@dataclass(frozen=True)
class Option:
    """One declared option: its name, default, allowed values (empty: any of the default's
    type) and a one-line meaning."""

    name: str
    default: object
    doc: str
    choices: tuple = ()

    def check(self, value, owner: str) -> None:
        if self.choices and value not in self.choices:
            raise ParameterError(
                f"{owner}.{self.name} = {value!r}; expected one of "
                f"{', '.join(map(str, self.choices))} ({self.doc})"
            )
        if not self.choices and not isinstance(value, type(self.default)):
            raise InputTypeError(
                f"{owner}.{self.name} = {value!r}; expected a "
                f"{type(self.default).__name__} ({self.doc})"
            )


class Model:
    """Base of every model dataclass (module docstring)."""

    NAME: ClassVar[str]
    KIND: ClassVar[str]
    LABEL: ClassVar[str] = ""
    PARAMS: ClassVar[tuple[Param, ...]]
    OPTIONS: ClassVar[tuple[Option, ...]] = ()
    #: Parameters that only scale one part of the model linearly, by part name
    #: (BRDF parts: "separable", "lobe"; medium parts: "iso", "lobe").
    SCALES: ClassVar[dict[str, str]] = {}
    #: Starting grids {role: {parameter: values}} over the parameters that are not scales.
    START: ClassVar[dict[str, dict[str, tuple]]] = {}
    #: The model's own relative error against physics where it is known (s, ell in degrees):
    #: a floor on the model-discrepancy term of every weighted fit through the model
    #: (veil.fitting.model_error), which the data of one session may be too few to show.
    #: None: no floor (the term comes from the residuals alone).
    MODEL_ERROR_FLOOR: ClassVar[tuple[float, float] | None] = None
    #: Every parameter enters the model linearly: a step fit solves them as one regularized
    #: linear problem (veil.fitting.linear_fit; the family then defines ``columns()`` and
    #: ``lobe_grid()``, docs/nonparametric.md), and iterative fits hold them.
    LINEAR: ClassVar[bool] = False
    if TYPE_CHECKING:  # every concrete model is a dataclass (what dataclasses.replace needs)
        __dataclass_fields__: ClassVar[dict[str, Any]]

    def __post_init__(self) -> None:
        owner = type(self).__name__
        for p in self.PARAMS:
            value = getattr(self, p.name)
            p.check(value, owner)
            object.__setattr__(self, p.name, float(value))
        for o in self.OPTIONS:
            o.check(getattr(self, o.name), owner)

    # -- the declaration -------------------------------------------------------------------
    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        return tuple(p.name for p in cls.PARAMS)

    @classmethod
    def param(cls, name: str) -> Param:
        """The declared parameter ``name`` (its own name or its alias)."""
        for p in cls.PARAMS:
            if name in (p.name, p.alias):
                return p
        raise ParameterError(
            f"{cls.NAME} has no parameter {name!r}; its parameters are "
            f"{', '.join(cls.param_names())}"
        )

    @classmethod
    def index(cls, name: str) -> int:
        return cls.PARAMS.index(cls.param(name))

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """Parameter names next to another model's (aliases where declared)."""
        return tuple(p.key for p in cls.PARAMS)

    @classmethod
    def scale_index(cls, part: str) -> int | None:
        name = cls.SCALES.get(part)
        return None if name is None else cls.param_names().index(name)

    @classmethod
    def scale_names(cls) -> tuple[str, ...]:
        return tuple(cls.SCALES.values())

    @classmethod
    def channel_sharing(cls) -> dict[str, str]:
        """{parameter name: "per-channel" or "shared"} across the channels of a multi-channel
        fit, as declared (``Param.channels``); an undeclared parameter is per channel when it
        is a scale (``SCALES``, ``GAIN``) and shared otherwise."""
        scales = set(cls.scale_names()) | {getattr(cls, "GAIN", None)} - {None}
        return {
            p.name: p.channels or ("per-channel" if p.name in scales else "shared")
            for p in cls.PARAMS
        }

    @classmethod
    def option_names(cls) -> tuple[str, ...]:
        return tuple(o.name for o in cls.OPTIONS)

    @classmethod
    def default_options(cls) -> dict:
        return {o.name: o.default for o in cls.OPTIONS}

    @classmethod
    def same_model(cls, options: dict) -> dict:
        """``options`` (every declared one) written the one way of the model they make: two
        sets whose models give equal values map to equal dicts, so model selection fits
        that model once (docs/choosing-models.md). As given unless a family declares
        otherwise."""
        return dict(options)

    @classmethod
    def start_grid(cls, role: str) -> dict:
        """{parameter: values} of the starting grid of a fit in ``role`` (may be empty)."""
        return dict(cls.START.get(role, {}))

    @classmethod
    def template(cls, **options) -> Self:
        """An instance at the declared starting values: it fixes the code path (class and
        options) of an engine whose parameters are passed as vectors."""
        return cls.from_params({p.name: p.start for p in cls.PARAMS}, options)

    @classmethod
    def from_params(cls, params: dict, options: dict | None = None) -> Self:
        """An instance from {name: value} (every parameter) and options (defaults for the
        rest); unknown or missing names are a ParameterError naming the declared ones."""
        names = cls.param_names()
        missing = [n for n in names if n not in params]
        unknown = [n for n in params if n not in names]
        if missing or unknown:
            raise ParameterError(
                f"{cls.NAME} takes parameters {', '.join(names)}"
                + (f"; missing {', '.join(missing)}" if missing else "")
                + (f"; unknown {', '.join(unknown)}" if unknown else "")
            )
        options = dict(options or {})
        bad = [k for k in options if k not in cls.option_names()]
        if bad:
            raise ParameterError(
                f"{cls.NAME} has no option {bad[0]!r}"
                + (
                    f"; its options are {', '.join(cls.option_names())}"
                    if cls.OPTIONS
                    else "; it takes no options"
                )
            )
        return cls(**{n: params[n] for n in names}, **{**cls.default_options(), **options})

    @classmethod
    def literal_form(cls) -> str:
        """How a literal parameter list is written, e.g. ``PD,PS,N,ETA``."""
        return ",".join(n.upper() for n in cls.param_names())

    # -- an instance -----------------------------------------------------------------------
    def shape_values(self) -> dict:
        """The parameters that tell two models of the family apart in a legend: neither
        scales nor shared by media (the paper's medium: g)."""
        scales = set(self.scale_names())
        return {
            p.name: getattr(self, p.name)
            for p in self.PARAMS
            if p.name not in scales and p.share != "shared"
        }

    def to_vector(self) -> ndarray:
        return np.array([getattr(self, p.name) for p in self.PARAMS], dtype=float)

    def options(self) -> dict:
        """Static (non-parameter) fields, e.g. ``{"variant": "paper"}``."""
        return {o.name: getattr(self, o.name) for o in self.OPTIONS}

    def with_vector(self, vector) -> Self:
        vector = np.asarray(vector, float)
        if vector.shape != (len(self.PARAMS),):
            raise ParameterError(
                f"{type(self).__name__} vector has shape {vector.shape}; "
                f"expected ({len(self.PARAMS)},) for "
                f"{', '.join(self.param_names())}"
            )
        values = dict(zip(self.param_names(), (float(x) for x in vector)))
        return dataclasses.replace(self, **values)

    def replace(self, **changes) -> Self:
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return {p.name: getattr(self, p.name) for p in self.PARAMS}

    def structure(self) -> tuple:
        """Hashable identity of the model's code path (class and static options)."""
        return (type(self),) + tuple(sorted(self.options().items()))

    def __str__(self) -> str:
        vals = ", ".join(f"{p.name}={getattr(self, p.name):.6g}" for p in self.PARAMS)
        opts = "".join(f", {k}={v!r}" for k, v in self.options().items())
        return f"{type(self).__name__}({vals}{opts})"


class BRDF(Model):
    """A surface reflection model f_r(I, R) split for the integrator (docs/model.md sec. 5).

    f_r = sum_k s_k(cos theta_I) t_k(cos theta_R) + lobe(I, R). The separable part is
    integrated as products of one-direction integrals; the lobe declares the radial law of
    its half vectors (``facet_*``), which the integrator uses as a change of variables.
    A model without a lobe sets ``HAS_LOBE = False`` and need not define the lobe's
    functions.
    """

    KIND = "brdf"
    HAS_LOBE: ClassVar[bool] = True

    def prepare(self, v) -> Any:
        """Tables the model needs at parameter vector ``v`` (computed once per engine call and
        passed to :meth:`separable` as ``aux``); None by default."""
        return None

    def separable(self, v, cos_i, cos_r, aux=None) -> list:  # pragma: no cover - interface
        """List of (s_k(cos_i), t_k(cos_r)) pairs (arrays broadcast against the inputs);
        ``aux`` is what :meth:`prepare` returned."""
        raise NotImplementedError

    def lobe(self, v, wi, wo, h, alpha=None) -> Array:  # pragma: no cover - interface
        """The non-separable part at unit vectors wi, wo with half vector h (shape (..., 3));
        ``alpha`` (angle of h from the normal) may be passed when already known."""
        raise NotImplementedError

    # The lobe's half vectors are distributed about the normal by a radial law in alpha
    # (angle of H from z), uniform in azimuth; the integrator truncates it at the horizon.
    def facet_cdf(self, v, alpha) -> Array:  # pragma: no cover - interface
        """Increasing cumulative of the radial law, 0 at alpha = 0 (any positive scale)."""
        raise NotImplementedError

    def facet_inverse_cdf(self, v, y) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def facet_weight(self, v, alpha, sin_alpha=None) -> Array:  # pragma: no cover - interface
        """d facet_cdf / d alpha / (2 pi sin alpha): density per steradian, cdf units
        (``sin_alpha`` may be passed when known)."""
        raise NotImplementedError

    def facet_half_angle(self) -> float:
        """The angle (deg) of the cone about the normal that holds half of the lobe's half
        vectors (sqrt(ln 2)/n for the paper's Torrance-Sparrow: its facet HWHM); inf without
        a lobe."""
        if not self.HAS_LOBE:
            return math.inf
        v = self.to_vector()
        top = float(self.facet_cdf(v, 0.5 * math.pi))
        return math.degrees(float(self.facet_inverse_cdf(v, 0.5 * top)))

    def evaluate(self, v, wi, wo) -> Array:
        """Full f_r(wi, wo) at parameter vector ``v`` with this instance's options, zero
        unless both directions are in the upper hemisphere."""
        from .._jax import jnp

        ci, co = wi[..., 2], wo[..., 2]
        total = 0.0 * ci
        if self.HAS_LOBE:
            s = wi + wo
            h = s / jnp.linalg.norm(s, axis=-1, keepdims=True)
            total = self.lobe(v, wi, wo, h)
        for a, b in self.separable(v, ci, co, self.prepare(v)):
            total = total + a * b
        return jnp.where((ci > 0) & (co > 0), total, 0.0)


#: The jitted phase function of each medium structure (class and options), for the scalar
#: searches of :meth:`Medium.lobe_half_width`: evaluated eagerly, a phase law built on
#: ``jax.lax.cond`` would be compiled again at every call.
_PHASE_PROGRAMS: dict = {}


def _compiled_phase(medium: Medium) -> Any:
    """``medium.phase`` jitted once per structure (its options fix the code path; the
    parameters come in the vector)."""
    key = medium.structure()
    program = _PHASE_PROGRAMS.get(key)
    if program is None:
        from .._jax import jax

        program = _PHASE_PROGRAMS[key] = jax.jit(medium.phase)
    return program


_KERNEL_PROGRAMS: dict = {}


def compiled_kernel(medium: Medium) -> Any:
    """``medium.kernel`` jitted once per structure: one compilation where its eager
    evaluation compiles each of its operations (a hundred for forward-series' phase table,
    about 10 s in a fresh process; veil.data.simulate's black-cloth glow)."""
    key = medium.structure()
    program = _KERNEL_PROGRAMS.get(key)
    if program is None:
        from .._jax import jax

        program = _KERNEL_PROGRAMS[key] = jax.jit(medium.kernel)
    return program


class Medium(Model):
    """A medium's transmission f_t(A, B) from direction A on the source side to B on the
    object side (docs/model.md sec. 3, 8.1), a sum of components:

    - "delta": the unscattered beam, weight(v) delta(A, B) a(A) b(B);
    - "iso": direction-independent (multiple) scattering, weight(v), no boundary factors;
    - "lobe": scattered light, weight(v) a(A) b(B) p(A . B) with p a normalized,
      rotationally symmetric phase function about the unscattered direction;

    ``COMPONENTS`` lists the medium's in that order (the paper's: iso and lobe). a and b
    (``factor_first``, ``factor_second``) are the boundary (Fresnel) factors, functions of
    the polar angles of the first and second argument. ``SCALES`` names the parameters that
    scale a component's weight linearly and ``GAIN`` one that scales the whole apparent
    value; the engine computes everything with them at 1. ``view_weight`` (None: 1) weights
    the lobe on the view side, f_t(R', R), by a function of R' and R (a finite plate).
    """

    KIND = "medium"
    COMPONENTS: ClassVar[tuple[str, ...]] = ("iso", "lobe")
    GAIN: ClassVar[str | None] = None
    #: Relative accuracy of the phase functions when they are tabulated (0: closed forms).
    TABLE_ACCURACY: ClassVar[float] = 0.0

    @classmethod
    def has(cls, component: str) -> bool:
        return component in cls.COMPONENTS

    def weight(self, v, component: str) -> Array:
        """The weight of ``component`` at parameter vector ``v``."""
        return {"delta": self.delta_weight, "iso": self.iso, "lobe": self.lobe_weight}[component](v)

    def delta_weight(self, v) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def iso(self, v) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def lobe_weight(self, v) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def factor_first(self, v, cos_a) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def factor_second(self, v, cos_b) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def prepare(self, v) -> Any:
        """Tables the lobe needs at parameter vector ``v``, computed once per engine call and
        passed to the phase functions as ``aux``; None by default."""
        return None

    def sampling_law(self, vs) -> tuple | None:
        """(v, aux) of one phase law whose grids serve the channels of ``vs`` (C, n) that
        differ in non-scale parameters (veil.engine.integrator.apparent_terms_channels);
        None: each channel runs the engine on its own."""
        return None

    def phase(self, v, one_minus_mu, aux=None) -> Array:  # pragma: no cover - interface
        raise NotImplementedError

    def phase_cone_fraction(self, v, one_minus_mu, aux=None) -> Array:  # pragma: no cover
        raise NotImplementedError

    def phase_inverse_cone_fraction(self, v, frac, aux=None) -> Array:  # pragma: no cover
        raise NotImplementedError

    def phase_sample(self, v, frac, aux=None) -> tuple:
        """(1 - cos, p) at the cone holding ``frac`` of the phase function: the sampling map
        and the density at its nodes together (a tabulated phase function reads both from
        one table row); by default ``phase_inverse_cone_fraction`` then ``phase``."""
        omm = self.phase_inverse_cone_fraction(v, frac, aux)
        return omm, self.phase(v, omm, aux)

    #: Whether ``view_weight`` weights the view-side lobe (a static property of the options).
    def has_view_weight(self) -> bool:
        return False

    def view_weight(self, v, r_prime, r) -> Array:
        """Weight of the view-side lobe f_t(R', R) at unit vectors R' (..., 3), R (3,)."""
        return 1.0 + 0.0 * r_prime[..., 2]

    def concentrated(self, factor: float) -> Self:
        """The medium at ``factor`` times its concentration (acquisition design, more or less
        of the scattering substance): by default every scale parameter times ``factor``."""
        return self.replace(**{n: getattr(self, n) * factor for n in self.scale_names()})

    def without_iso(self) -> Self:
        """The medium with its isotropic part switched off (its scale at 0)."""
        name = self.SCALES.get("iso")
        return self if name is None else self.replace(**{name: 0.0})

    def iso_scale(self) -> float:
        """The weight of the isotropic part (the paper's T_d; 0 without one)."""
        return float(self.iso(self.to_vector())) if self.has("iso") else 0.0

    def lobe_scale(self) -> float:
        """The weight of the scattered lobe (the paper's T_t; 0 without a lobe)."""
        return float(self.lobe_weight(self.to_vector())) if self.has("lobe") else 0.0

    def lobe_half_width(self) -> float:
        """Half width at half maximum (deg) of the phase lobe (inf without a lobe)."""
        if not self.has("lobe"):
            return math.inf
        v = np.asarray(self.to_vector(), dtype=float)
        phase = _compiled_phase(self)
        half = 0.5 * float(phase(v, 0.0))
        lo, hi = 0.0, 2.0  # 1 - cos(gamma): the phase falls from lo to beyond hi
        if float(phase(v, hi)) >= half:
            return 180.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if float(phase(v, mid)) > half else (lo, mid)
        return math.degrees(math.acos(1.0 - 0.5 * (lo + hi)))

    def kernel(self, v, one_minus_mu) -> Array:
        """The scattering kernel without boundary factors, iso + weight p, at deflection
        1 - cos(gamma): what a black cloth sees of the medium (veil.data.simulate)."""
        value = 0.0 * one_minus_mu
        if self.has("iso"):
            value = value + self.iso(v)
        if self.has("lobe"):
            value = value + self.lobe_weight(v) * self.phase(v, one_minus_mu)
        return value

    def evaluate(self, v, wa, wb) -> Array:
        """f_t(wa, wb) for unit vectors without its delta component (a distribution, not a
        function): the iso part plus the lobe with its boundary factors."""
        from .._jax import jnp

        value = 0.0 * wa[..., 2]
        if self.has("iso"):
            value = value + self.iso(v)
        if self.has("lobe"):
            one_minus_mu = jnp.maximum(1.0 - jnp.sum(wa * wb, axis=-1), 0.0)
            value = value + (
                self.lobe_weight(v)
                * self.factor_first(v, wa[..., 2])
                * self.factor_second(v, wb[..., 2])
                * self.phase(v, one_minus_mu)
            )
        return value


#: The former name of :class:`Medium` (a medium's BTDF), kept as the public ``veil.BTDF``.
BTDF = Medium
