"""The registry: every model family veil knows, by name, and the paper's presets.

Adding a family is one module (a frozen dataclass declaring itself, see
:mod:`veil.models.base`) and one line in :data:`FAMILIES` below; everything else - the
engine, the fits, the joint fit, result files, the command line's ``--brdf-model`` /
``--medium-model`` and ``veil models`` - reads the declaration. Families outside veil
register themselves with :func:`register`, from a module named in the environment variable
``VEIL_PLUGINS`` (comma-separated module names, imported at the first lookup) or an entry
point of group ``veil.models``.
"""

from __future__ import annotations

import importlib
import os
from typing import Any, Literal, overload

from ..errors import InputError, InputTypeError
from .base import BRDF, KINDS, ROLES, Medium, Model, Option
from .forward_series import ForwardSeries
from .henyey_greenstein import HenyeyGreenstein
from .nonparametric import NonParametric
from .rough_conductor import RoughConductor
from .rough_plastic import RoughPlastic
from .torrance_sparrow import TorranceSparrow

#: The families veil ships, one line each.
FAMILIES = (
    TorranceSparrow,
    HenyeyGreenstein,
    ForwardSeries,
    RoughPlastic,
    RoughConductor,
    NonParametric,
)
#: The paper's models: the default family of each kind.
DEFAULTS = {"brdf": TorranceSparrow.NAME, "medium": HenyeyGreenstein.NAME}
#: The ways of choosing the models of an estimation (``veil fit pipeline --models``): the data
#: choose among every candidate, or the paper's models; any other value names a pair.
AUTO, PAPER = "auto", "paper"
MODES = (AUTO, PAPER)
#: Options that describe the apparatus, not the model's shape: given once by the user (the
#: path length, the plate's width, the Fresnel variant of the window), they apply to every
#: candidate that declares them and are never ranked (:func:`candidates`).
APPARATUS_OPTIONS = frozenset({"variant", "path_length", "plate_width"})

REGISTRY: dict[str, type[Model]] = {}
_plugins_loaded = False
_plugin_error: InputError | None = None


def register(cls: type[Model]) -> type[Model]:
    """Add a model family to the registry (usable as a class decorator); its declaration is
    checked here, so a family with an inconsistent declaration never runs; an
    InputTypeError for anything but a subclass of :class:`BRDF` or :class:`Medium`."""
    expected = "expected a model class, a subclass of veil.BRDF or veil.Medium"
    if not isinstance(cls, type):
        shown = repr(cls) if len(repr(cls)) <= 60 else repr(cls)[:57] + "..."
        raise InputTypeError(
            f"register({shown}): {expected}, got {type(cls).__name__} (an object, not a class)"
        )
    if not issubclass(cls, (BRDF, Medium)):
        raise InputTypeError(f"register({cls.__name__}): {expected}; {cls.__name__} is neither")
    name = getattr(cls, "NAME", None)
    if not isinstance(name, str) or not name or name != name.strip().lower():
        raise ValueError(
            f"{cls.__name__}.NAME = {name!r}: a registered model needs a lower-case name"
        )
    if getattr(cls, "KIND", None) not in KINDS:
        raise ValueError(
            f"{cls.__name__}.KIND = {getattr(cls, 'KIND', None)!r}; expected one of {KINDS}"
        )
    if REGISTRY.get(name, cls) is not cls:
        raise ValueError(
            f"a model named {name!r} is already registered ({REGISTRY[name].__name__})"
        )
    names = cls.param_names()
    if not names or len(set(names)) != len(names):
        raise ValueError(f"{cls.__name__}.PARAMS must name each parameter once")
    keys = cls.keys()
    if len(set(keys)) != len(keys):
        raise ValueError(f"{cls.__name__}: parameter aliases clash")
    for part, pname in cls.SCALES.items():
        if pname not in names:
            raise ValueError(f"{cls.__name__}.SCALES[{part!r}] = {pname!r} is not a parameter")
    for role, grid in cls.START.items():
        if role not in ROLES[cls.KIND]:
            raise ValueError(
                f"{cls.__name__}.START has role {role!r}; a {cls.KIND} fit has "
                f"roles {ROLES[cls.KIND]}"
            )
        for pname in grid:
            if pname not in names or pname in cls.SCALES.values():
                raise ValueError(
                    f"{cls.__name__}.START[{role!r}] lists {pname!r}, which is "
                    f"not a parameter other than a scale"
                )
    for p in cls.PARAMS:
        if p.start is None or not p.contains(p.start):
            raise ValueError(
                f"{cls.__name__}: parameter {p.name} needs a start value inside {p.interval()}"
            )
    missing = [m for m in _interface(cls) if _abstract(cls, m)]
    if missing:
        raise ValueError(
            f"{cls.__name__} declares {cls.KIND} parts whose functions it does not "
            f"define: {', '.join(missing)}"
        )
    cls.template()  # the declared options and starting values make a valid model
    REGISTRY[name] = cls
    return cls


def _interface(cls) -> list[str]:
    """The functions the engine calls for what the family declares."""
    if cls.KIND == "brdf":
        needed = ["prepare", "separable"]
        if cls.HAS_LOBE:
            needed += ["lobe", "facet_cdf", "facet_inverse_cdf", "facet_weight"]
        return needed
    needed = ["factor_first", "factor_second", "prepare"]
    for comp, fn in (("delta", "delta_weight"), ("iso", "iso"), ("lobe", "lobe_weight")):
        if comp in cls.COMPONENTS:
            needed.append(fn)
    if "lobe" in cls.COMPONENTS:
        needed += ["phase", "phase_cone_fraction", "phase_inverse_cone_fraction"]
    bad = [c for c in cls.COMPONENTS if c not in ("delta", "iso", "lobe")]
    if bad or list(cls.COMPONENTS) != sorted(cls.COMPONENTS, key=("delta", "iso", "lobe").index):
        raise ValueError(
            f"{cls.__name__}.COMPONENTS = {cls.COMPONENTS!r}: expected some of "
            f"delta, iso, lobe in that order"
        )
    return needed


def _abstract(cls, name: str) -> bool:
    """Whether ``name`` is still the interface's stub (raises NotImplementedError)."""
    from .base import BRDF, Medium

    base = BRDF if cls.KIND == "brdf" else Medium
    own = getattr(cls, name)
    stub = base.__dict__.get(name)
    if stub is None:
        return False
    target = stub.__func__ if isinstance(stub, staticmethod) else stub
    return getattr(own, "__func__", own) is target and name not in ("prepare",)


for _cls in FAMILIES:
    register(_cls)


def _load_plugins() -> None:
    """Import the modules of ``VEIL_PLUGINS`` and the ``veil.models`` entry points once; a
    module that cannot be imported makes every later lookup fail with the same error."""
    global _plugins_loaded, _plugin_error
    if _plugin_error is not None:
        raise _plugin_error
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for module in filter(None, (m.strip() for m in os.environ.get("VEIL_PLUGINS", "").split(","))):
        try:
            importlib.import_module(module)
        except Exception as exc:
            _plugin_error = InputError(
                f"VEIL_PLUGINS names module {module!r}, which cannot be "
                f"imported ({type(exc).__name__}: {exc})"
            )
            raise _plugin_error from None
    from importlib.metadata import entry_points

    for ep in entry_points(group="veil.models"):
        try:
            ep.load()
        except Exception as exc:
            _plugin_error = InputError(
                f"the veil.models entry point {ep.name!r} ({ep.value}) "
                f"cannot be loaded ({type(exc).__name__}: {exc})"
            )
            raise _plugin_error from None


def names(kind: str | None = None) -> list[str]:
    """Registered family names (of one kind): BRDFs first, the paper's first of each kind."""
    _load_plugins()
    found = [n for n, c in REGISTRY.items() if kind is None or c.KIND == kind]
    return sorted(
        found, key=lambda n: (KINDS.index(REGISTRY[n].KIND), n not in DEFAULTS.values(), n)
    )


@overload
def model_class(name: str, kind: Literal["brdf"]) -> type[BRDF]: ...
@overload
def model_class(name: str, kind: Literal["medium"]) -> type[Medium]: ...
@overload
def model_class(name: str, kind: str | None = None) -> type[Model]: ...
def model_class(name: str, kind: str | None = None) -> type[Model]:
    """The family registered as ``name`` (of ``kind`` when given); an InputError listing the
    known ones otherwise."""
    _load_plugins()
    what = {"brdf": "BRDF model", "medium": "medium model", None: "model"}[kind]
    if not isinstance(name, str):
        raise InputTypeError(f"{what} name: expected a string, got {name!r}")
    cls = REGISTRY.get(name.strip().lower())
    if cls is None or (kind is not None and cls.KIND != kind):
        hint = ""
        if cls is not None:
            hint = f" ({name!r} is a {cls.KIND} model)"
        raise InputError(f"unknown {what} {name!r}{hint}; known: {', '.join(names(kind))}")
    return cls


def ranked_options(cls: type[Model]) -> tuple[Option, ...]:
    """The options of ``cls`` whose every value is a candidate of its own: those with a finite
    set of allowed values that do not describe the apparatus (:data:`APPARATUS_OPTIONS`)."""
    return tuple(o for o in cls.OPTIONS if o.choices and o.name not in APPARATUS_OPTIONS)


def candidates(kind: str, pinned: dict[str, Any] | None = None) -> list[tuple[str, dict[str, Any]]]:
    """Every registered family of ``kind`` with every combination of its ranked options
    (:func:`ranked_options`), as (name, {option: value}), in :func:`names` order (the
    paper's first) and the declared order of the values (the default first). ``pinned``
    {option: value} keeps, for the families that declare an option, that value only."""
    if kind not in KINDS:
        raise InputError(f"kind = {kind!r}; expected one of {', '.join(KINDS)}")
    pinned = dict(pinned or {})
    out: list[tuple[str, dict[str, Any]]] = []
    for name in names(kind):
        cls = REGISTRY[name]
        combos: list[dict[str, Any]] = [{}]
        for opt in ranked_options(cls):
            if opt.name in pinned:
                values = [pinned[opt.name]]
            else:
                values = [opt.default] + [v for v in opt.choices if v != opt.default]
            combos = [dict(c, **{opt.name: v}) for c in combos for v in values]
        out += [(name, c) for c in combos]
    return out


@overload
def default_class(kind: Literal["brdf"]) -> type[BRDF]: ...
@overload
def default_class(kind: Literal["medium"]) -> type[Medium]: ...
@overload
def default_class(kind: str) -> type[Model]: ...
def default_class(kind: str) -> type[Model]:
    """The paper's model of ``kind`` ("brdf" or "medium")."""
    return REGISTRY[DEFAULTS[kind]]


#: The paper's simulated objects (Table 2) and media (Table 3), docs/model.md sec. 6.
PRESETS: dict[str, Model] = {
    "BRDF1": TorranceSparrow(Pd=2.00e2, Ps=5.00e5, n=0.80, eta=1.55),
    "BRDF2": TorranceSparrow(Pd=1.00e3, Ps=5.00e5, n=0.50, eta=1.55),
    "BTDF1": HenyeyGreenstein(Td=1.00e-3, Tt=0.01, g=0.98, eta=1.3),
    "BTDF2": HenyeyGreenstein(Td=1.00e-3, Tt=0.13, g=0.93, eta=1.3),
    "BTDF3": HenyeyGreenstein(Td=1.00e-3, Tt=0.38, g=0.88, eta=1.3),
}


def preset(name: str, kind: str | None = None) -> Model:
    """A preset model by name (case-insensitive), of ``kind`` ("brdf" or "medium") when
    given; an InputError listing the presets (of that kind), or the kinds."""
    if kind is not None and kind not in KINDS:
        raise InputError(
            f"preset kind = {kind!r}; expected one of {', '.join(map(repr, KINDS))}, or "
            f"None for any kind"
        )
    model = PRESETS.get(name.upper()) if isinstance(name, str) else None
    if model is None or (kind is not None and model.KIND != kind):
        known = [k for k, m in PRESETS.items() if kind is None or m.KIND == kind]
        hint = f" ({name!r} is a {model.KIND} preset)" if model is not None else ""
        of = f" {kind}" if kind is not None else ""
        raise InputError(f"unknown{of} preset {name!r}{hint}; known: {', '.join(known)}")
    return model


__all__ = [
    "REGISTRY",
    "FAMILIES",
    "DEFAULTS",
    "AUTO",
    "PAPER",
    "MODES",
    "APPARATUS_OPTIONS",
    "PRESETS",
    "register",
    "names",
    "model_class",
    "default_class",
    "ranked_options",
    "candidates",
    "preset",
]
