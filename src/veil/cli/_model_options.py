"""The model options of the command line: the families and the options they declare
(``--brdf-model``, ``--medium-model``, ``--variant``, ..., :class:`ModelChoice`), ``--models``,
the model-discrepancy term and the propagation (``--model-error``, ``--propagation``) and
``--fix NAME=VALUE`` parsed against the declared parameters."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import click

from ..errors import InputError
from ._errors import UserError
from ._floats import FINITE

if TYPE_CHECKING:  # the type only: the command line imports the models when it needs them
    from ..models.base import Model


@dataclass(frozen=True)
class ModelChoice:
    """The model families and options a command was given (``--brdf-model``,
    ``--medium-model`` and the options the families declare, e.g. ``--variant``); parses
    preset names and literal parameter lists into models of those families."""

    brdf: type[Model]
    medium: type[Model]
    brdf_options: dict
    medium_options: dict
    explicit: frozenset = frozenset()
    #: ``fit pipeline --models``: veil.models.AUTO, PAPER or "pinned" (a FAMILY+MEDIUM pair,
    #: in ``brdf`` and ``medium``); None when the command has no --models (the paper's).
    mode: str | None = None
    #: The kinds whose family is ``auto`` (``--brdf-model auto`` of the single fits): every
    #: registered family of that kind is fitted and ranked (veil.fitting.selection).
    ranked: frozenset = frozenset()

    def parse(self, text: str, kind: str, option: str):
        """A preset name or a literal list of the family's parameters (in declared order);
        for a medium, "none" means clear water (None)."""
        from ..models import PRESETS

        cls = self.brdf if kind == "brdf" else self.medium
        options = self.brdf_options if kind == "brdf" else self.medium_options
        text = text.strip()
        if kind == "medium" and text.lower() == "none":
            return None
        parts = [s.strip() for s in text.split(",")]
        if len(parts) == 1 and not (len(cls.PARAMS) == 1 and _is_number(text)):
            model = PRESETS.get(text.upper())
            word = "BRDF" if kind == "brdf" else "BTDF"
            if model is not None and model.KIND != kind:
                raise UserError(
                    f"{option}: {text!r} is not a {word} preset (it is a {model.KIND} model)"
                )
            if model is None:
                known = [k for k, m in PRESETS.items() if m.KIND == kind]
                raise UserError(
                    f"{option}: {word} {text!r} is neither a preset name "
                    f"({', '.join(known)}) nor a literal {cls.literal_form()} "
                    f"({cls.NAME}; see veil models)"
                )
            if type(model) is not cls:
                if f"{kind}-model" in self.explicit:
                    raise UserError(
                        f"{option} {text}: the preset is a {model.NAME} model, not "
                        f"{cls.NAME} (--{kind}-model)"
                    )
                cls = type(model)
            try:
                return model.replace(
                    **{k: v for k, v in options.items() if k in cls.option_names()}
                )
            except InputError as exc:
                raise UserError(f"{option} {text}: {exc}") from None
        if len(parts) != len(cls.PARAMS):
            raise UserError(
                f"{option} literal {text!r} must have {len(cls.PARAMS)} numbers: "
                f"{cls.literal_form()} ({cls.NAME})"
            )
        values = {}
        for prm, s in zip(cls.PARAMS, parts):
            try:
                values[prm.name] = float(s)
            except ValueError:
                raise UserError(
                    f"{option}: parameter {prm.name} = {s!r} is not a number (form "
                    f"{cls.literal_form()})"
                ) from None
        try:
            return cls.from_params(values, options)
        except InputError as exc:
            raise UserError(f"{option} {text!r}: {exc}") from None

    def brdf_model(self, text: str, option: str = "--brdf"):
        return self.parse(text, "brdf", option)

    def medium_model(self, text: str, option: str = "--medium"):
        return self.parse(text, "medium", option)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class ModelName(click.ParamType):
    """A registered family of one kind, looked up when the command line is parsed (so that
    families registered after the command was built are accepted too)."""

    name = "NAME"

    def __init__(self, kind: str, auto: bool = False):
        self.kind = kind
        self.auto = auto  # "auto" (every registered family ranked) accepted too

    def convert(self, value, param, ctx):
        from ..models import AUTO, names

        try:
            known = names(self.kind)
        except InputError as exc:
            self.fail(str(exc), param, ctx)
        name = str(value).strip().lower()
        if self.auto and name == AUTO:
            return name
        if name not in known:
            self.fail(
                f"{value!r} is not a registered {self.kind} model; known: "
                f"{', '.join(known)} ('veil models' lists them)",
                param,
                ctx,
            )
        return name


def _option_flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def model_error_choice(default: str, help: str):
    """``--model-error`` over the kinds of veil.fitting.model_error (KINDS; not imported:
    help stays free of the fitting stack; tests/test_model_error.py checks they agree)."""
    return click.option(
        "--model-error",
        "model_error",
        type=click.Choice(["off", "independent", "correlated"]),
        default=default,
        show_default=True,
        help=help,
    )


# the fits' default is veil.fitting.model_error.DEFAULT (checked as above)
model_error_option = model_error_choice(
    "correlated",
    "The model-discrepancy term of a weighted fit whose reduced chi-square exceeds "
    "1 + 2 sqrt(2/dof): a relative model error estimated from the residuals and added "
    "to the covariance (the estimates are not moved); 'correlated' lets the likelihood "
    "choose a correlation length over the angles (docs/validity.md), 'independent' "
    "takes none. Step 2 uses step 1's when larger and counts the error the two share; "
    "a joint fit estimates its own over all its sessions.",
)


# the methods of veil.fitting.propagation (METHODS; not imported, as above;
# tests/test_propagation.py checks they agree)
propagation_option = click.option(
    "--propagation",
    "propagation",
    type=click.Choice(["auto", "linear", "sigma-points", "off"]),
    default="auto",
    show_default=True,
    help="How the previous step's uncertainty (a joint fit: the media's) enters the total "
    "standard errors: 'linear' (first order), 'sigma-points' (the fit repeated at 2n "
    "points of that covariance, in coordinates where it is relative), 'auto' the latter "
    "where a parameter is uncertain by more than 0.25 of its scale (tau at optical "
    "depth 0.1) and at most 3 (beyond, it is not determined: first order, noted; so too "
    "for a fit that did not converge; docs/fitting.md); 'off' reports the fit's own "
    "standard errors only, faster.",
)


def model_options(kinds=("brdf", "medium"), auto_kinds=()):
    """Click options for the model families of ``kinds`` and every option the registered
    families of those kinds declare; the command receives them as ``models``
    (a :class:`ModelChoice`). The family options of ``auto_kinds`` also take ``auto``."""
    from ..models import AUTO, DEFAULTS, names, registry

    def known(kind):
        """The registered names; without the plugins when they cannot be loaded (the
        command then fails with that error when it looks a model up)."""
        try:
            return names(kind)
        except InputError:
            return sorted(n for n, c in registry.REGISTRY.items() if c.KIND == kind)

    def decorate(fn):
        declared: dict = {}
        for kind in kinds:
            for name in known(kind):
                for opt in registry.REGISTRY[name].OPTIONS:
                    declared.setdefault(opt.name, []).append((kind, name, opt))

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            chosen = {}
            explicit = set()
            mode, pair = _models_mode(kwargs.get("model_spec"), kwargs.get("compare"))
            ranked = frozenset(k for k in kinds if kwargs.get(f"{k}_model") == AUTO)
            for kind in kinds:
                value = kwargs.pop(f"{kind}_model", None)
                value = None if value == AUTO else value
                if value is not None:
                    explicit.add(f"{kind}-model")
                    if kwargs.get("model_spec") is not None or mode is not None:
                        raise UserError(
                            f"--{kind}-model with --models "
                            f"{kwargs.get('model_spec') or 'auto'}: give one of "
                            f"the two (--models FAMILY+MEDIUM pins a pair)"
                        )
                chosen[kind] = registry.model_class(value or pair.get(kind) or DEFAULTS[kind], kind)
            opts = _option_values(
                declared, chosen, kinds, kwargs, mode == registry.AUTO or bool(ranked)
            )
            kwargs["models"] = ModelChoice(
                chosen.get("brdf", registry.default_class("brdf")),
                chosen.get("medium", registry.default_class("medium")),
                opts["brdf"],
                opts["medium"],
                frozenset(explicit),
                mode,
                ranked,
            )
            return fn(*args, **kwargs)

        return _with_options(wrapper, declared, kinds, auto_kinds, known)

    return decorate


def _declared_flags(wrapper, declared: dict):
    """``wrapper`` with one click option per declared model option (its values, its
    families' docs and defaults in the help); a number is finite (no family's means nan
    or inf: forward-series says "infinite" with 0)."""
    for oname, users in reversed(list(declared.items())):
        choices = sorted({str(c) for _, _, o in users for c in o.choices})
        docs = "; ".join(f"{n}: {o.doc}" for _, n, o in users)
        numeric = all(
            isinstance(o.default, (int, float)) and not isinstance(o.default, bool)
            for _, _, o in users
        )
        kind = click.Choice(choices) if choices else (FINITE if numeric else str)
        defaults = ", ".join(str(o.default) for _, _, o in users)
        wrapper = click.option(
            _option_flag(oname),
            oname,
            default=None,
            type=kind,
            help=f"Option of the model ({docs}); default: the model's ({defaults}).",
        )(wrapper)
    return wrapper


def family_options(fn):
    """Click options for every option a registered family declares, without a choice of
    family (``veil warmup``); the command receives ``family_options``, ({option: value}
    for the BRDF families, the same for the media), each given option converted for the
    families that declare it."""
    from ..models import names, registry

    declared: dict = {}
    for kind in ("brdf", "medium"):
        try:
            known = names(kind)
        except InputError:  # the plugins cannot be loaded: the command says so when it runs
            known = sorted(n for n, c in registry.REGISTRY.items() if c.KIND == kind)
        for name in known:
            for opt in registry.REGISTRY[name].OPTIONS:
                declared.setdefault(opt.name, []).append((kind, name, opt))

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        opts = _option_values(declared, {}, ("brdf", "medium"), kwargs, True)
        kwargs["family_options"] = (opts["brdf"], opts["medium"])
        return fn(*args, **kwargs)

    return _declared_flags(wrapper, declared)


def _with_options(wrapper, declared: dict, kinds, auto_kinds, known):
    """``wrapper`` with the click options: one per declared model option (its values, its
    families' docs and defaults in the help), and ``--brdf-model`` / ``--medium-model``."""
    from ..models import AUTO, DEFAULTS

    wrapper = _declared_flags(wrapper, declared)
    for kind in reversed(kinds):
        word = "BRDF family of the objects" if kind == "brdf" else "medium model"
        auto = (
            f"; {AUTO}: every registered family fitted and ranked by BIC, the best one kept"
            if kind in auto_kinds
            else ""
        )
        wrapper = click.option(
            f"--{kind}-model",
            f"{kind}_model",
            default=None,
            type=ModelName(kind, kind in auto_kinds),
            metavar="NAME",
            help=f"The {word} (default {DEFAULTS[kind]}, the paper's; "
            f"'veil models' lists them: "
            f"{', '.join(known(kind))}{auto}).",
        )(wrapper)
    return wrapper


def _option_values(declared: dict, chosen: dict, kinds, kwargs: dict, auto: bool) -> dict:
    """{kind: {option: value}} of the model options given (popped from ``kwargs``), each
    to the chosen families that declare it; with ``auto`` (fit pipeline --models auto) to
    every candidate that declares it (veil.fitting.selection). An option no chosen family
    declares is a UserError."""
    opts: dict[str, dict] = {"brdf": {}, "medium": {}}
    for oname in declared:
        value = kwargs.pop(oname, None)
        if value is None:
            continue
        if auto:
            for kind, _, opt in declared[oname]:
                opts[kind][oname] = _convert(value, opt)
            continue
        targets = [k for k in kinds if oname in chosen[k].option_names()]
        if not targets:
            users = sorted({n for _, n, _ in declared[oname]})
            raise UserError(
                f"{_option_flag(oname)} applies to the model(s) "
                f"{', '.join(users)}, not to "
                f"{' / '.join(chosen[k].NAME for k in kinds)}"
            )
        for k in targets:
            opt = next(o for o in chosen[k].OPTIONS if o.name == oname)
            opts[k][oname] = _convert(value, opt)
    return opts


def _models_mode(spec, compare) -> tuple[str | None, dict]:
    """(AUTO | PAPER | "pinned", {kind: family}) of ``--models`` (``compare``: AUTO; None
    without either); a UserError (exit 2) listing the registered families for an unknown
    one."""
    if spec is None and not compare:
        return None, {}
    from ..fitting.selection import parse_models
    from ..models import AUTO

    try:
        mode = parse_models(AUTO if spec is None else spec)
    except InputError as exc:
        raise UserError(f"--models: {exc}") from None
    if compare and mode != AUTO:
        raise UserError(
            f"--compare writes out the ranking of --models auto; leave --models {spec} out"
        )
    if isinstance(mode, tuple):
        return "pinned", {"brdf": mode[0], "medium": mode[1]}
    return mode, {}


def _convert(value: str, opt):
    """A command-line option value in the type of the option's default."""
    kind = type(opt.default)
    if kind is bool:
        return str(value).lower() in ("1", "true", "yes", "on")
    if kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            raise UserError(f"{_option_flag(opt.name)} {value!r}: expected a number") from None
    return value


def fix_value(option: str, item: str, name: str, text: str, fixed: dict) -> float:
    """The VALUE ``text`` of the ``NAME=VALUE`` ``item`` of ``option`` (``--fix``): a finite
    number, and ``name`` not in ``fixed`` yet, or a UserError saying which."""
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"{option} {item!r}: {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise UserError(f"{option} {item!r}: {text.strip()!r} is not a finite number")
    if name in fixed:
        raise UserError(f"{option}: {name} is fixed twice")
    return value


def parse_fix(items, cls, option="--fix") -> dict:
    """``NAME=VALUE`` strings -> {name: value}, names and values checked against ``cls``'s
    declared parameters."""
    fixed: dict[str, float] = {}
    names = cls.param_names()
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UserError(
                f"{option} {item!r}: expected NAME=VALUE, e.g. {names[-1]}=1.5 "
                f"(parameters of {cls.NAME}: {', '.join(names)})"
            )
        if name not in names:
            raise UserError(
                f"{option} {item!r}: {cls.NAME} has no parameter {name!r}; "
                f"its parameters are {', '.join(names)}"
            )
        value = fix_value(option, item, name, text, fixed)
        try:
            cls.param(name).check(value, cls.__name__)
        except ValueError as exc:
            raise UserError(f"{option} {item!r}: {exc}") from None
        fixed[name] = value
    return fixed
