"""Fitted models into renderers (docs/interop.md): each family's declaration
(``RENDERERS`` / ``PROXIES``, :mod:`veil.models.renderers`) says which plugin of a renderer
expresses it; this module picks it, fits the closest family where a renderer has none, and
writes the scene text (Mitsuba 3 XML or dict, pbrt-v4)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..errors import InputError
from ..models import Model, model_class, names
from ..models.renderers import RENDERER_NAMES, Plugin, Setting, Unsupported
from .writers import IDS, mitsuba_dict_source, mitsuba_xml, pbrt_text

#: Output formats of each renderer (the first is the default).
FORMATS = {"mitsuba": ("xml", "dict"), "pbrt": ("pbrt",)}


@dataclass(frozen=True)
class Exported:
    """One model as a renderer plugin: the ``source`` model, the ``model`` the plugin
    stands for (``source`` itself, or the closest model of another family: ``closest``)."""

    source: Model
    model: Model
    plugin: Plugin
    closest: object = None


@dataclass(frozen=True)
class Export:
    renderer: str
    format: str
    text: str
    items: tuple
    comments: tuple

    @property
    def scale(self) -> float:
        """The product of the intensity scales divided out of the models."""
        s = 1.0
        for item in self.items:
            s *= item.plugin.scale
        return s

    def item(self, kind: str) -> Exported | None:
        return next((i for i in self.items if i.model.KIND == kind), None)


def _exporters(renderer: str) -> list[str]:
    return [
        n
        for n in names()
        if renderer in getattr(model_class(n), "RENDERERS", {})
        or renderer in getattr(model_class(n), "PROXIES", {})
    ]


#: The setting of an export that names none (a frozen dataclass: one instance serves all).
DEFAULT_SETTING = Setting()


def check_renderer(renderer: str) -> None:
    if renderer not in RENDERER_NAMES:
        raise InputError(f"renderer {renderer!r}; expected one of {', '.join(RENDERER_NAMES)}")


def plugin(model: Model, renderer: str, setting: Setting = DEFAULT_SETTING) -> Exported:
    """The renderer plugin of ``model`` (module docstring); :class:`Unsupported` (an
    InputError) when the renderer cannot express it."""
    check_renderer(renderer)
    hooks = getattr(type(model), "RENDERERS", {})
    if renderer in hooks:
        made = hooks[renderer](model, setting)
        return Exported(model, model if made.model is None else made.model, made)
    family, options = proxy(model, renderer, setting)
    from .closest import closest

    return from_closest(model, closest(model, family, options), renderer, setting)


def proxy(model: Model, renderer: str, setting: Setting = DEFAULT_SETTING) -> tuple[str, dict]:
    """(family, options) of the closest family that stands for ``model`` in ``renderer``,
    which has no plugin of its own for it (checked to be exportable there before any fit);
    :class:`Unsupported` when there is none."""
    cls = type(model)
    proxies = getattr(cls, "PROXIES", {})
    if renderer in proxies and model.KIND == "brdf":
        family, options = proxies[renderer]
        try:  # fail before fitting when the closest family cannot be exported either
            plugin(model_class(family, "brdf").template(**options), renderer, setting)
        except InputError as exc:
            raise Unsupported(
                f"{model.NAME} has no counterpart in {renderer}, and its closest "
                f"family {family} cannot be exported there either: {exc}"
            ) from None
        return family, dict(options)
    raise Unsupported(
        f"{model.NAME} has no counterpart in {renderer}; the families veil "
        f"exports there are {', '.join(_exporters(renderer)) or 'none'}"
    )


def check_exportable(models, renderer: str, setting: Setting = DEFAULT_SETTING) -> None:
    """:class:`Unsupported` when ``renderer`` can express one of ``models`` neither by a
    plugin of its own nor by its closest family: the cheap checks of every model before the
    closest fit of any (engine work, seconds with its compiling), so that a medium no
    renderer expresses is refused at once beside a BRDF that needs one."""
    for model in models:
        if has_own_plugin(model, renderer):
            plugin(model, renderer, setting)
        else:
            proxy(model, renderer, setting)


def has_own_plugin(model: Model, renderer: str) -> bool:
    """Whether ``renderer`` has a plugin of its own for ``model``'s family."""
    return renderer in getattr(type(model), "RENDERERS", {})


def from_closest(model: Model, fit, renderer: str, setting: Setting = DEFAULT_SETTING) -> Exported:
    """``model`` exported as ``fit`` (a :class:`veil.interop.closest.Closest` of it), the
    fit's sentence first among what the conversion loses."""
    inner = plugin(fit.model, renderer, setting).plugin
    return Exported(
        model, fit.model, dataclasses.replace(inner, lost=(fit.sentence(),) + inner.lost), fit
    )


def _comments(items, renderer: str, source: str) -> list[str]:
    lines = [f"veil export for {renderer}" + (f" of {source}" if source else "")]
    for item in items:
        ident = IDS[item.plugin.kind]
        lines.append(f"{ident}: {item.source}")
        if item.model is not item.source:
            lines.append(f"{ident}: closest {item.model.NAME}: {item.model}")
        for note in item.plugin.lost:
            lines.append(f"{ident}: lost: {note}")
    scale = 1.0
    for item in items:
        scale *= item.plugin.scale
    lines.append(f"veil's value = render under unit irradiance x {scale!r} (intensity scale)")
    return lines


def export(
    models,
    renderer: str = "mitsuba",
    fmt: str | None = None,
    setting: Setting = DEFAULT_SETTING,
    source: str = "",
) -> Export:
    """Scene text for ``models`` (a BRDF and/or a medium) in ``renderer``'s format ``fmt``."""
    fmt = check_format(renderer, fmt)
    models = sorted_models(models)
    check_exportable(models, renderer, setting)
    items = tuple(plugin(m, renderer, setting) for m in models)
    comments = tuple(_comments(items, renderer, source))
    text = scene_text([i.plugin for i in items], comments, renderer, fmt)
    return Export(renderer, fmt, text, items, comments)


def check_format(renderer: str, fmt: str | None) -> str:
    """The output format ``fmt`` of ``renderer`` (None: its default), checked."""
    check_renderer(renderer)
    fmt = fmt or FORMATS[renderer][0]
    if fmt not in FORMATS[renderer]:
        raise InputError(
            f"format {fmt!r} for {renderer}; expected one of {', '.join(FORMATS[renderer])}"
        )
    return fmt


def sorted_models(models) -> list[Model]:
    """The given models (None left out) in the order an export writes them, checked: at
    least one, at most one of each kind."""
    models = [m for m in models if m is not None]
    if not models:
        raise InputError("nothing to export: give a BRDF or a medium")
    kinds = [m.KIND for m in models]
    if len(set(kinds)) != len(kinds):
        raise InputError(f"export takes at most one BRDF and one medium; got {', '.join(kinds)}")
    return sorted(models, key=lambda m: m.KIND)


def scene_text(plugins, comments, renderer: str, fmt: str) -> str:
    """The scene text of ``plugins`` in ``renderer``'s format ``fmt``."""
    if renderer == "pbrt":
        return pbrt_text(plugins, comments)
    if fmt == "dict":
        return mitsuba_dict_source(plugins, comments)
    return mitsuba_xml(plugins, comments)


__all__ = [
    "FORMATS",
    "Export",
    "Exported",
    "export",
    "plugin",
    "proxy",
    "from_closest",
    "has_own_plugin",
    "check_exportable",
    "check_renderer",
    "check_format",
    "sorted_models",
    "scene_text",
]
