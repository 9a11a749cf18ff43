"""What every model declares: its parameters, their bounds, and how to become a vector.

A model is a frozen dataclass whose float fields are its parameters (in declaration order)
and whose other fields (for example the BTDF's Fresnel ``variant``) are static options. The
class lists each parameter as a :class:`Param` in ``PARAMS``; construction validates every
value against those bounds, so an invalid parameter set cannot exist.

The integrator and the fits never touch instances inside JAX code: they work on the
parameter *vector* (``to_vector``) and call the class's static functions, so one compiled
function serves every parameter value.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from ..errors import InputError, InputTypeError, ParameterError


@dataclass(frozen=True)
class Param:
    """One declared parameter: name, physical bounds, unit and a one-line meaning."""

    name: str
    lower: float
    upper: float
    doc: str
    unit: str = ""
    lower_open: bool = False
    upper_open: bool = False
    log_scale: bool = False  # positive scale factors: fits work on their logarithm

    def check(self, value: float, owner: str) -> None:
        if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
            raise InputTypeError(f"{owner}.{self.name} must be a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise ParameterError(f"{owner}.{self.name} = {v!r} is not a finite number")
        lo_bad = v <= self.lower if self.lower_open else v < self.lower
        hi_bad = v >= self.upper if self.upper_open else v > self.upper
        if lo_bad or hi_bad:
            raise ParameterError(f"{owner}.{self.name} = {v:g} is outside {self.interval()}"
                             f" ({self.doc})")

    def interval(self) -> str:
        lo = "(" if self.lower_open else "["
        hi = ")" if self.upper_open else "]"
        return f"{lo}{self.lower:g}, {self.upper:g}{hi}"


class Model:
    """Base of every model dataclass. Subclasses set ``NAME``, ``KIND`` and ``PARAMS``."""

    NAME: ClassVar[str]
    KIND: ClassVar[str]  # "brdf" or "btdf"
    PARAMS: ClassVar[tuple[Param, ...]]
    #: Parameters that only scale one part of the model linearly, by part name
    #: (BRDF parts: "separable", "lobe"; BTDF parts: "iso", "lobe"). The integrator computes
    #: the parts with these set to 1, so fits get their derivatives for free.
    SCALES: ClassVar[dict[str, str]] = {}

    @classmethod
    def scale_index(cls, part: str):
        name = cls.SCALES.get(part)
        return None if name is None else cls.param_names().index(name)

    def __post_init__(self) -> None:
        for p in self.PARAMS:
            value = getattr(self, p.name)
            p.check(value, type(self).__name__)
            object.__setattr__(self, p.name, float(value))

    # -- vectors -------------------------------------------------------------------------
    @classmethod
    def param_names(cls) -> tuple[str, ...]:
        return tuple(p.name for p in cls.PARAMS)

    def to_vector(self) -> np.ndarray:
        return np.array([getattr(self, p.name) for p in self.PARAMS], dtype=float)

    def options(self) -> dict:
        """Static (non-parameter) fields, e.g. ``{"variant": "paper"}``."""
        names = set(self.param_names())
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in names}

    def with_vector(self, vector) -> "Model":
        vector = np.asarray(vector, float)
        if vector.shape != (len(self.PARAMS),):
            raise InputError(f"{type(self).__name__} vector has shape {vector.shape}; expected "
                             f"({len(self.PARAMS)},) for {', '.join(self.param_names())}")
        values = dict(zip(self.param_names(), (float(x) for x in vector)))
        return dataclasses.replace(self, **values)

    def replace(self, **changes) -> "Model":
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
    """A surface reflection model f_r(I, R) split for the integrator (MODEL.md sec. 5).

    f_r = sum_k s_k(cos theta_I) t_k(cos theta_R) + lobe(I, R). The separable part is
    integrated as products of one-direction integrals; the lobe declares the radial law of
    its half vectors (``facet_*``), which the integrator uses as a change of variables.
    """

    KIND = "brdf"

    @staticmethod
    def separable(v, cos_i, cos_r):  # pragma: no cover - interface
        """List of (s_k(cos_i), t_k(cos_r)) pairs (arrays broadcast against the inputs)."""
        raise NotImplementedError

    @staticmethod
    def lobe(v, wi, wo, h, alpha=None):  # pragma: no cover - interface
        """The non-separable part at unit vectors wi, wo with half vector h (shape (..., 3));
        ``alpha`` (angle of h from the normal) may be passed when already known."""
        raise NotImplementedError

    # The lobe's half vectors are distributed about the normal by a radial law in alpha
    # (angle of H from z), uniform in azimuth; the integrator truncates it at the horizon.
    @staticmethod
    def facet_cdf(v, alpha):  # pragma: no cover - interface
        """Increasing cumulative of the radial law, 0 at alpha = 0 (any positive scale)."""
        raise NotImplementedError

    @staticmethod
    def facet_inverse_cdf(v, y):  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def facet_weight(v, alpha, sin_alpha=None):  # pragma: no cover - interface
        """d facet_cdf / d alpha / (2 pi sin alpha): density per steradian, cdf units
        (``sin_alpha`` may be passed when known)."""
        raise NotImplementedError

    @classmethod
    def evaluate(cls, v, wi, wo):
        """Full f_r(wi, wo), zero unless both directions are in the upper hemisphere."""
        from .._jax import jnp

        ci, co = wi[..., 2], wo[..., 2]
        s = wi + wo
        h = s / jnp.linalg.norm(s, axis=-1, keepdims=True)
        total = cls.lobe(v, wi, wo, h)
        for a, b in cls.separable(v, ci, co):
            total = total + a * b
        return jnp.where((ci > 0) & (co > 0), total, 0.0)


class BTDF(Model):
    """A medium transmission model f_t(A, B) = iso + weight a(A) b(B) p(A . B).

    ``iso`` is direction independent (multiple scattering), the lobe is a rotationally
    symmetric phase function about the unscattered direction with Fresnel factors a and b
    that depend only on the polar angles of the first and second argument.
    """

    KIND = "btdf"

    @staticmethod
    def iso(v):  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def lobe_weight(v):  # pragma: no cover - interface
        raise NotImplementedError

    def factor_first(self, v, cos_a):  # pragma: no cover - interface
        raise NotImplementedError

    def factor_second(self, v, cos_b):  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def phase(v, one_minus_mu):  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def phase_cone_fraction(v, one_minus_mu):  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def phase_inverse_cone_fraction(v, frac):  # pragma: no cover - interface
        raise NotImplementedError

    def evaluate(self, v, wa, wb):
        """Full f_t(wa, wb) for unit vectors (MODEL.md sec. 3)."""
        from .._jax import jnp

        one_minus_mu = jnp.maximum(1.0 - jnp.sum(wa * wb, axis=-1), 0.0)
        lobe = (self.lobe_weight(v) * self.factor_first(v, wa[..., 2])
                * self.factor_second(v, wb[..., 2]) * self.phase(v, one_minus_mu))
        return self.iso(v) + lobe
