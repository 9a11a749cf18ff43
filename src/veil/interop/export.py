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

    def item(self, kind: str):
        return next((i for i in self.items if i.model.KIND == kind), None)


def _exporters(renderer: str) -> list[str]:
    return [n for n in names() if renderer in getattr(model_class(n), "RENDERERS", {})
            or renderer in getattr(model_class(n), "PROXIES", {})]


#: The setting of an export that names none (a frozen dataclass: one instance serves all).
DEFAULT_SETTING = Setting()

def check_renderer(renderer: str) -> None:
    if renderer not in RENDERER_NAMES:
        raise InputError(f"renderer {renderer!r}; expected one of {', '.join(RENDERER_NAMES)}")


def plugin(model: Model, renderer: str, setting: Setting = DEFAULT_SETTING) -> Exported:
    """The renderer plugin of ``model`` (module docstring); :class:`Unsupported` (an
    InputError) when the renderer cannot express it."""
    check_renderer(renderer)
    cls = type(model)
    hooks = getattr(cls, "RENDERERS", {})
    proxies = getattr(cls, "PROXIES", {})
    if renderer in hooks:
        made = hooks[renderer](model, setting)
        return Exported(model, model if made.model is None else made.model, made)
    if renderer in proxies and model.KIND == "brdf":
        from .closest import closest

        family, options = proxies[renderer]
        try:  # fail before fitting when the closest family cannot be exported either
            plugin(model_class(family, "brdf").template(**options), renderer, setting)
        except InputError as exc:
            raise Unsupported(f"{model.NAME} has no counterpart in {renderer}, and its closest "
                              f"family {family} cannot be exported there either: {exc}") from None
        fit = closest(model, family, options)
        inner = plugin(fit.model, renderer, setting).plugin
        return Exported(model, fit.model,
                        dataclasses.replace(inner, lost=(fit.sentence(),) + inner.lost), fit)
    raise Unsupported(f"{model.NAME} has no counterpart in {renderer}; the families veil "
                      f"exports there are {', '.join(_exporters(renderer)) or 'none'}")


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


def export(models, renderer: str = "mitsuba", fmt: str | None = None,
           setting: Setting = DEFAULT_SETTING, source: str = "") -> Export:
    """Scene text for ``models`` (a BRDF and/or a medium) in ``renderer``'s format ``fmt``."""
    check_renderer(renderer)
    fmt = fmt or FORMATS[renderer][0]
    if fmt not in FORMATS[renderer]:
        raise InputError(f"format {fmt!r} for {renderer}; expected one of "
                         f"{', '.join(FORMATS[renderer])}")
    models = [m for m in models if m is not None]
    if not models:
        raise InputError("nothing to export: give a BRDF or a medium")
    kinds = [m.KIND for m in models]
    if len(set(kinds)) != len(kinds):
        raise InputError(f"export takes at most one BRDF and one medium; got {', '.join(kinds)}")
    items = tuple(plugin(m, renderer, setting) for m in sorted(models, key=lambda m: m.KIND))
    comments = tuple(_comments(items, renderer, source))
    plugins = [i.plugin for i in items]
    if renderer == "pbrt":
        text = pbrt_text(plugins, comments)
    elif fmt == "dict":
        text = mitsuba_dict_source(plugins, comments)
    else:
        text = mitsuba_xml(plugins, comments)
    return Export(renderer, fmt, text, items, comments)


__all__ = ["FORMATS", "Export", "Exported", "export", "plugin", "check_renderer"]
