"""The result of a fit (docs/model.md sec. 7): :class:`FitResult` (one model: a step of the
two-step method) and :class:`JointResult` (several models: a joint fit), and their JSON file,
key by key in docs/fitting.md. The text report is :mod:`veil.fitting.fit_report`.

Result files carry ``"format": "veil.fit/2"``; files of the earlier formats ("veil.fit/1",
"veil.joint/1") are read as well, and any other format is refused with a clear message
(a file from a newer veil).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, overload

from ..errors import FitError, InputError, MissingFileError, NotAFileError
from ..io import as_path, other_encoding, write_bytes_atomic
from ..models import Model, default_class, model_class
from ..models.base import VARIANT_OPTION
from ..models.channel_model import ChannelModel
from ..numbers import json_float
from .model_error import ModelError
from .result_fields import (
    FORMAT,
    READABLE,
    _json_matrix,
    _json_term,
    channel_layout,
    loads_checked,
    model_entry,
    model_from_entry,
    model_of_channel,
)
from .result_reading import STEPS, fit_fields, joint_fields, target_channels
from .solver import covariance_matrix

if TYPE_CHECKING:
    import numpy as np


@dataclass(frozen=True)
class FitResult:
    """One fitted model (docs/model.md sec. 7): values, uncertainties and goodness of fit.

    ``params`` holds every parameter in the model's order (fixed ones too, see ``fixed``);
    ``stderr`` is None for fixed parameters or when the Jacobian is singular. ``residuals``
    are (value - model) / sigma when ``weighted``, else value - model. ``chi2_reduced`` is
    sum(residuals^2) / (n_points - free parameters); ``rms_relative`` the rms of
    (value - model) / model; ``aic`` and ``bic`` the information criteria of the weighted
    fit. ``converged`` is False when the iterations did not converge or the data do not
    determine the model (``determined`` False; ``message`` says which parameters and why).
    ``options`` are the fitted model's options; ``variant`` the Fresnel variant of the
    medium involved (fitted or given), kept as its own key. ``given`` is the model held fixed
    (the reference BRDF for the medium step, the medium for the target step). ``stderr`` and
    ``correlation`` treat it as exact; ``stderr_total`` and ``correlation_total`` add its own
    uncertainty when it came from a fit (to first order, or through sigma points where it is
    large: ``stats["propagation"]`` says which; docs/fitting.md).
    ``model_error`` is the model-discrepancy term of a weighted fit
    (:class:`veil.fitting.model_error.ModelError`: the relative model error the residuals
    show beyond the noise, or the model's declared one where that is larger, included in
    ``stderr`` and ``stderr_total``); None when the fit
    did not estimate one (unweighted data, an undetermined covariance, or
    ``model_error="off"``).
    ``channels`` is the layout of a fit of several colour channels at once
    (:mod:`veil.fitting.channel_fit`): {channel: {model parameter: its name in ``params``}},
    ``Pd[r]`` for a parameter per channel, ``n`` for one tied across them; None for a fit of
    one channel (``params`` then in the model's own names).
    """

    #: A joint fit (:class:`JointResult`): its report lists the sessions.
    JOINT: ClassVar[bool] = False

    model: str
    params: dict
    stderr: dict
    correlation: dict
    residuals: tuple
    chi2_reduced: float
    rms_relative: float
    n_points: int
    converged: bool
    message: str
    variant: str | None = None
    fixed: dict = field(default_factory=dict)
    step: str | None = None
    weighted: bool = True
    accuracy: str | None = None
    given: dict | None = None
    stderr_total: dict | None = None
    correlation_total: dict | None = None
    stats: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)
    determined: bool = True
    model_error: ModelError | None = None
    channels: dict | None = None

    # -- models ----------------------------------------------------------------------------
    @property
    def model_class(self) -> type[Model]:
        return model_class(self.model)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The channels fitted at once (empty for a fit of one channel)."""
        return tuple(self.channels or ())

    @property
    def kind(self) -> str:
        """ "brdf" or "medium": the kind of the fitted model."""
        return self.model_class.KIND

    @overload
    def as_model(self, channel: str) -> Model: ...
    @overload
    def as_model(self, channel: None = None) -> Model | ChannelModel: ...
    def as_model(self, channel: str | None = None) -> Model | ChannelModel:
        """The fitted model instance (with its options), which ``veil.reflectance`` and
        ``veil.apparent`` evaluate. Of a fit of several channels (``channels``): the model of
        one ``channel``, or without one a :class:`~veil.models.channel_model.ChannelModel`
        of every channel, whose values carry a trailing channel axis in the order of
        ``channel_names`` (``values[..., k]`` is channel k, bit for bit what
        ``as_model(channel=channel_names[k])`` gives). A fit of one channel: its model, as
        before channels existed."""
        if self.channels is not None and channel is None:
            return ChannelModel({c: self.one_model(c) for c in self.channels})
        return self.one_model(channel)

    def one_model(self, channel: str | None = None) -> Model:
        """The model of one channel: the fitted model of a fit of one channel, or of
        ``channel`` of a fit of several (a FitError naming the channels when none is
        named: what needs one model, a fit of one channel or a map, says so)."""
        if self.channels is None:
            if channel is not None:
                raise FitError(
                    f"channel {channel!r}: this result is a fit of one channel; "
                    f"call as_model() without a channel"
                )
            return self.model_class.from_params(self.params, self.options)
        return model_of_channel(self.model_class, self.params, self.channels, channel, self.options)

    def of_channel(self, channel: str | None) -> FitResult:
        """A fit of several channels seen as the fit of ``channel`` alone (what a step of
        one channel holds fixed, its covariance propagated): that channel's parameters and
        the tied ones in the model's own names, with their standard errors and
        correlations; a fit of one channel is itself."""
        if self.channels is None:
            return self
        names = channel_layout(self.channels, channel)
        back = {name: p for p, name in names.items()}

        def own(d):
            return None if d is None else {back[n]: v for n, v in d.items() if n in back}

        def own_rows(c):
            return None if c is None else {back[a]: own(row) for a, row in c.items() if a in back}

        return dataclasses.replace(
            self,
            params={p: self.params[names[p]] for p in self.model_class.param_names()},
            fixed=own(self.fixed) or {},
            stderr=own(self.stderr) or {},
            correlation=own_rows(self.correlation) or {},
            stderr_total=own(self.stderr_total),
            correlation_total=own_rows(self.correlation_total),
            channels=None,
        )

    def given_model(self, channel: str | None = None) -> Model | None:
        """The model the fit held fixed (``given``), or None; of ``channel`` when it is a
        fit of several channels."""
        if not self.given:
            return None
        return model_from_entry(self.given, "the result's 'given' entry", channel)

    @property
    def free(self) -> tuple[str, ...]:
        """Names of the parameters the fit varied (those not held fixed)."""
        return tuple(n for n in self.params if n not in self.fixed)

    @property
    def at_bound(self) -> tuple[str, ...]:
        """Names in ``fixed`` that the user left free and a linear fit's non-negative solve
        holds at their bound 0 (``stats["at_bound"]``, docs/nonparametric.md). A file
        written before that key: the coefficients fixed at 0, when their number is the
        columns' at 0 (``stats["columns"] - stats["active"]``: the user fixed none at 0)."""
        named = self.stats.get("at_bound")
        if isinstance(named, list):
            return tuple(n for n in named if n in self.fixed)
        zero = tuple(n for n, v in self.fixed.items() if v == 0.0)
        columns, active = self.stats.get("columns"), self.stats.get("active")
        if isinstance(columns, int) and isinstance(active, int) and len(zero) == columns - active:
            return zero
        return ()

    def target_names(self) -> dict:
        """{a parameter of the fitted object's model: its name in ``params``}: the same names
        here; a joint fit's target's from its layout."""
        return {n: n for n in self.params}

    @property
    def n_free(self) -> int:
        return len(self.free)

    @property
    def dof(self) -> float:
        """The degrees of freedom the criteria count: the free parameters, or a regularized
        linear fit's effective ones (``stats["effective_dof"]``, docs/nonparametric.md)."""
        return float(self.stats.get("effective_dof", self.n_free))

    @property
    def aic(self) -> float | None:
        """Akaike's criterion chi^2 + 2 k of a weighted fit (None when unweighted)."""
        chi2 = self.chi2_reduced * max(self.n_points - self.dof, 1)
        return chi2 + 2 * self.dof if self.weighted else None

    @property
    def bic(self) -> float | None:
        """The Bayesian criterion chi^2 + k ln N of a weighted fit (None when unweighted)."""
        chi2 = self.chi2_reduced * max(self.n_points - self.dof, 1)
        return chi2 + self.dof * math.log(max(self.n_points, 1)) if self.weighted else None

    def covariance(self, total: bool = True) -> tuple[Sequence[str], np.ndarray] | None:
        """(free names, covariance matrix) from the standard errors and correlations;
        ``total`` prefers the propagated ones. None if the uncertainties are undetermined."""
        se, corr = self.stderr, self.correlation
        if total and self.stderr_total is not None:
            se, corr = self.stderr_total, self.correlation_total or {}
        names = self.free
        cov = covariance_matrix(se, corr, names)
        return None if cov is None else (names, cov)

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The result as a JSON-ready dict (the keys of docs/fitting.md; NaN as null)."""
        return {
            "format": FORMAT,
            "model": self.model,
            "step": self.step,
            "params": {k: float(v) for k, v in self.params.items()},
            "stderr": {k: json_float(v) for k, v in self.stderr.items()},
            "correlation": _json_matrix(self.correlation),
            "chi2_reduced": json_float(self.chi2_reduced),
            "rms_relative": json_float(self.rms_relative),
            "aic": json_float(self.aic),
            "bic": json_float(self.bic),
            "n_points": int(self.n_points),
            "converged": bool(self.converged),
            "determined": bool(self.determined),
            "message": self.message,
            VARIANT_OPTION: self.variant,
            "options": dict(self.options),
            "fixed": {k: float(v) for k, v in self.fixed.items()},
            "weighted": bool(self.weighted),
            "accuracy": self.accuracy,
            "given": self.given,
            "stderr_total": None
            if self.stderr_total is None
            else {k: json_float(v) for k, v in self.stderr_total.items()},
            "correlation_total": None
            if self.correlation_total is None
            else _json_matrix(self.correlation_total),
            "stats": self.stats,
            "residuals": [json_float(r) for r in self.residuals],
            # only when estimated: results without the term keep their earlier bytes
            **({} if self.model_error is None else {"model_error": _json_term(self.model_error)}),
            **({} if self.channels is None else {"channels": self.channels}),
        }

    def to_json(self, path) -> None:
        """Write the result as JSON (keys in docs/fitting.md), atomically."""
        text = json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"
        if os.path.isdir(path):
            raise NotAFileError(f"cannot write {os.fspath(path)}: it is a directory")
        write_bytes_atomic(path, text.encode("utf-8"))

    @classmethod
    def from_dict(cls, data: dict, source: str = "the fit result") -> FitResult:
        """Check and convert a dictionary written by :meth:`to_dict`
        (:func:`veil.fitting.result_reading.fit_fields`); a joint fit's (model "joint") is
        read as the :class:`JointResult` it is."""
        if cls is FitResult and isinstance(data, dict) and data.get("model") == "joint":
            return JointResult.from_dict(data, source)
        return cls(**fit_fields(data, source))

    @classmethod
    def from_json(cls, path) -> FitResult:
        """Read a result written by :meth:`to_json`; errors name the file and the key."""
        return cls.from_dict(read_json(path), os.fspath(path))

    # -- text ------------------------------------------------------------------------------
    def report(self, min_correlation: float = 0.1) -> str:
        """A readable fit report (like lmfit's): statistics, variables, correlations."""
        from .fit_report import fit_report

        return fit_report(self, min_correlation)

    def correlation_lines(self, min_correlation: float, most: int | None = None) -> list[str]:
        """The report's [[Correlations]] section: pairs of free parameters with |r| >=
        ``min_correlation``, strongest first (the ``most`` strongest; all when None)."""
        pairs = []
        for a, b in itertools.combinations(self.free, 2):
            r = self.correlation.get(a, {}).get(b)
            if r is not None and math.isfinite(r) and abs(r) >= min_correlation:
                pairs.append((abs(r), a, b, r))
        if not pairs:
            return []
        lines = [f"[[Correlations]] (unreported correlations are < {min_correlation})"]
        for _, a, b, r in sorted(pairs, key=lambda t: -t[0])[:most]:
            lines.append(f"    C({a}, {b}) = {r:+.4f}")
        return lines

    def __str__(self) -> str:
        return self.report()

    def __repr__(self) -> str:
        """One line: the family, step, first parameters and convergence, and where its
        model is (the dataclass's listed every residual and correlation, and a function
        given a result for a model printed them all)."""
        shown = ", ".join(f"{k}={v:.4g}" for k, v in list(self.params.items())[:6])
        more = f", ... ({len(self.params)} parameters)" if len(self.params) > 6 else ""
        state = "converged" if self.converged else "not converged"
        where = ".as_model()" + (", .brdf(object), .medium(label)" if self.JOINT else "")
        return (
            f"{type(self).__name__}({self.model} fit, step {self.step!r}: {shown}{more}; "
            f"{state}; its model: {where})"
        )


@dataclass(frozen=True, repr=False)
class JointResult(FitResult):
    """A joint fit (docs/model.md sec. 7): a :class:`FitResult` whose ``params`` span several
    models and whose ``layout`` says which: ``models`` {"brdf": family, "medium": family}
    and their ``options``, ``objects`` {object: {model parameter: result name}}, ``media``
    {label: {model parameter (alias): result name}}, ``shared``, ``sessions`` (name,
    object, medium, n_points, chi2, rms_relative each)."""

    JOINT: ClassVar[bool] = True

    layout: dict = field(default_factory=dict)

    # -- models ----------------------------------------------------------------------------
    def _family(self, kind: str):
        name = (self.layout.get("models") or {}).get(kind)
        return default_class(kind) if name is None else model_class(name, kind)

    def _options(self, kind: str) -> dict:
        opts = (self.layout.get("options") or {}).get(kind)
        if opts is not None:
            return dict(opts)
        cls = self._family(kind)
        if VARIANT_OPTION in cls.option_names() and self.variant is not None:
            return {VARIANT_OPTION: self.variant}  # veil.joint/1 files
        return {}

    def maps(self, channel: str | None = None) -> dict:
        """{"objects": {object: {parameter: result name}}, "media": {label: {parameter:
        result name}}}: of the fit, or of ``channel`` of a fit over several channels
        (``layout["channels"]``; a FitError naming them when none is named)."""
        by_channel = self.layout.get("channels")
        if by_channel is None:
            if channel is not None:
                raise FitError(f"channel {channel!r}: this joint fit is of one channel")
            return self.layout
        if channel is None:
            first = next(iter(by_channel))
            raise FitError(
                f"this joint fit fits channels {', '.join(by_channel)} at once: name one "
                f"(--channel {first} at the command line, channel={first!r} in Python)"
            )
        if channel not in by_channel:
            raise FitError(
                f"the joint fit has no channel {channel!r}; its channels are "
                f"{', '.join(by_channel)}"
            )
        return by_channel[channel]

    @property
    def object_labels(self) -> tuple[str, ...]:
        return tuple(self.maps(self._first())["objects"])

    @property
    def media_labels(self) -> tuple[str, ...]:
        return tuple(self.maps(self._first())["media"])

    def object_names(self, obj: str) -> set[str]:
        """Every result name of object ``obj``'s parameters, in every channel."""
        return {
            n
            for c in self.channel_names or (None,)
            for n in self.maps(c)["objects"].get(obj, {}).values()
        }

    def _first(self) -> str | None:
        return next(iter(self.channel_names), None)

    def brdf(self, obj: str = "target", channel: str | None = None) -> Model:
        """The BRDF of object ``obj`` (of ``channel`` of a fit over several channels)."""
        names = self.maps(channel)["objects"].get(obj)
        if names is None:
            raise FitError(
                f"the joint fit has no object {obj!r}; it has {', '.join(self.object_labels)}"
            )
        cls = self._family("brdf")
        return cls.from_params(
            {p.name: self.params[names[p.key]] for p in cls.PARAMS}, self._options("brdf")
        )

    def medium(self, label: str, channel: str | None = None) -> Model:
        """The medium ``label`` (of ``channel`` of a fit over several channels)."""
        names = self.maps(channel)["media"].get(label)
        if names is None:
            raise FitError(
                f"the joint fit has no medium {label!r}; it has "
                f"{', '.join(self.media_labels) or 'none'}"
            )
        cls = self._family("medium")
        return cls.from_params(
            {p.name: self.params[names[p.key]] for p in cls.PARAMS}, self._options("medium")
        )

    @overload
    def as_model(self, channel: str) -> Model: ...
    @overload
    def as_model(self, channel: None = None) -> Model | ChannelModel: ...
    def as_model(self, channel: str | None = None) -> Model | ChannelModel:
        """The target's BRDF (what :meth:`FitResult.as_model` gives for a step-2 fit): of a
        fit over several channels, of ``channel`` or, without one, a
        :class:`~veil.models.channel_model.ChannelModel` of every channel."""
        if self.channels is not None and channel is None:
            return ChannelModel({c: self.brdf("target", c) for c in self.channels})
        return self.one_model(channel)

    def one_model(self, channel: str | None = None) -> Model:
        """The target's BRDF, of ``channel`` of a fit over several channels."""
        return self.brdf("target", channel)

    def target_names(self) -> dict:
        if self.channels is not None:  # the target's names are a step fit's over channels
            return {n: n for names in self.channels.values() for n in names.values()}
        return dict(self.layout["objects"]["target"])

    @property
    def model_class(self) -> type[Model]:
        return self._family("brdf")

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = super().to_dict()
        out["layout"] = self.layout
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "the joint fit result") -> JointResult:
        """Check and convert a dictionary written by :meth:`to_dict`
        (:func:`veil.fitting.result_reading.joint_fields`)."""
        result = cls(**joint_fields(data, source))  # (its errors name the source)
        try:
            for c in result.channel_names or (None,):
                for obj in result.maps(c)["objects"]:
                    result.brdf(obj, c)
                for label in result.maps(c)["media"]:
                    result.medium(label, c)
        except InputError as exc:
            raise FitError(f"{source}: {exc}") from None
        except KeyError as exc:
            raise FitError(
                f"{source}: the layout names parameter {exc} that the model does not have"
            ) from None
        return result


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------
def read_json(path) -> Any:
    """The JSON data of a result file; errors name the file (a missing file, a directory, not
    UTF-8, not JSON, nested too deeply) and the key (NaN, Infinity, a number beyond a
    float's range: none of them a number veil writes)."""
    name = as_path(path, "path")
    try:
        with open(name, encoding="utf-8") as fh:
            text = fh.read()
    except FileNotFoundError:
        raise MissingFileError(f"fit result {name} does not exist") from None
    except IsADirectoryError:
        raise NotAFileError(f"fit result {name} is a directory, not a JSON file") from None
    except UnicodeDecodeError as exc:
        raise FitError(
            other_encoding(name)
            or f"{name} is not UTF-8 text ({exc.reason}); expected a JSON fit result"
        ) from None
    return loads_checked(text, name)


def load_result(path) -> FitResult:
    """Read any veil fit result (a step or a joint fit) from JSON."""
    data = read_json(path)
    if isinstance(data, dict) and data.get("model") == "joint":
        return JointResult.from_dict(data, os.fspath(path))
    return FitResult.from_dict(data, os.fspath(path))


#: How errors name the fit result a role needs, by kind.
RESULTS = {
    "brdf": "a BRDF fit (step 0, 'veil fit reference')",
    "medium": "a medium fit (step 1, 'veil fit medium')",
}


def load_model_result(path, kind: str, option: str) -> FitResult:
    """A result file that must hold a model of ``kind`` ("brdf" or "medium"): a clear
    FitError naming ``option`` when it holds the other kind or a joint fit."""
    result = load_result(path)
    role = option.lstrip("-").replace("-", " ")
    if isinstance(result, JointResult):
        raise FitError(
            f"{option} {os.fspath(path)}: the {role} must be {RESULTS[kind]}; got a "
            f"joint fit result"
        )
    if result.kind != kind:
        raise FitError(
            f"{option} {os.fspath(path)}: the {role} must be {RESULTS[kind]}; got a "
            f"{result.model} result" + (f" of step {result.step!r}" if result.step else "")
        )
    return result


def unfinished(result) -> str | None:
    """What ``result`` (a step's or a joint fit's) is when not all its values are estimates:
    "a fit whose data do not determine every parameter (...)" (``determined`` False: the
    others are estimates) or "a fit that did not converge"; None when it converged."""
    if not getattr(result, "determined", True):
        return "a fit whose data do not determine every parameter (its message says which)"
    if not getattr(result, "converged", True):
        return "a fit that did not converge"
    return None


__all__ = [
    "unfinished",
    "FitResult",
    "JointResult",
    "FORMAT",
    "READABLE",
    "STEPS",
    "RESULTS",
    "model_entry",
    "model_from_entry",
    "read_json",
    "load_result",
    "load_model_result",
    "target_channels",
]
