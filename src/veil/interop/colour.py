"""Colour exports (docs/interop.md, "Colour"): a result fitted over the r, g, b channels
(docs/channels.md) as one renderer material and medium with RGB values.

Each channel's model becomes its renderer plugin as in a one-channel export
(:func:`veil.interop.export.plugin`); the three plugins are then merged value by value. A
value the same in every channel (a shared roughness or index) stays one number; a value
that differs is written as the renderer's RGB colour (Mitsuba 3 ``rgb``, or an unbounded
``srgb`` texture above 1; pbrt-v4 ``rgb``, its RGB spectrum) where the plugin takes a colour
(:attr:`veil.models.renderers.Value.colourable`), and is refused elsewhere. A family that a
renderer lacks is fitted by its closest family over the three channels at once, so that
the shared parameters stay shared (:func:`veil.interop.closest.closest_channels`).

Each channel keeps its own intensity scale (by default its specular scale, so that the
interface is physical in every channel and the material's colour is relative to a white
specular reflection): veil's value in channel c is the render's channel c under a white
unit irradiance times the scale of c.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..data.channels import RGB
from ..errors import InputError
from ..models.renderers import Plugin, Setting, Unsupported, Value
from .export import (
    DEFAULT_SETTING,
    Exported,
    check_exportable,
    check_format,
    from_closest,
    has_own_plugin,
    plugin,
    proxy,
    scene_text,
    sorted_models,
)
from .writers import IDS


@dataclass(frozen=True)
class ColourExport:
    """A colour export: the scene ``text`` and, for each channel (r, g, b), the
    :class:`~veil.interop.export.Exported` items its model became (BRDF before medium)."""

    renderer: str
    format: str
    text: str
    channels: dict
    comments: tuple

    def scale(self, channel: str) -> float:
        """The intensity scale of ``channel``: veil's value = render x this."""
        s = 1.0
        for item in self.channels[channel]:
            s *= item.plugin.scale
        return s

    @property
    def scales(self) -> dict:
        return {c: self.scale(c) for c in self.channels}

    def item(self, kind: str, channel: str) -> Exported | None:
        return next((i for i in self.channels[channel] if i.model.KIND == kind), None)

    def plugin(self, kind: str) -> Plugin | None:
        """The merged plugin of ``kind`` ("brdf" or "medium") as written."""
        items = {c: self.item(kind, c) for c in self.channels}
        plugins = {c: i.plugin for c, i in items.items() if i is not None}
        if len(plugins) < len(items):
            return None
        return merge_plugins(plugins, self.renderer)


def rgb_order(channels, source: str = "") -> list[str]:
    """``channels`` as r, g, b (the renderer's red, green, blue), or an InputError naming
    them: a colour export needs exactly those three."""
    names = [str(c) for c in channels]
    if sorted(names) != sorted(RGB) or len(names) != len(RGB):
        where = f"{source}: " if source else ""
        raise InputError(
            f"{where}channels {', '.join(names)}; a colour export writes the "
            f"renderer's RGB and needs exactly the channels {', '.join(RGB)} "
            f"(export one channel with --channel NAME)"
        )
    return list(RGB)


def _merge_value(values: dict, owner: str, renderer: str) -> Value:
    first = next(iter(values.values()))
    if all(v.value == first.value for v in values.values()):
        return first
    listed = ", ".join(f"{c} {v.value!r}" for c, v in values.items())
    if not first.colourable:
        raise Unsupported(
            f"{renderer}'s {owner} takes one {first.name} for every colour, "
            f"but the channels give {listed}: a colour export needs the "
            f"model's corresponding parameter shared across the channels"
        )
    return Value(first.name, "rgb", tuple(float(v.value) for v in values.values()), True)


def _merge_lost(lost: dict) -> tuple:
    """What the channels' conversions lose: a sentence every channel says once, the others
    prefixed with the channels that say them."""
    said: dict[str, list[str]] = {}
    for c, lines in lost.items():
        for line in lines:
            said.setdefault(line, []).append(c)
    return tuple(
        line if len(cs) == len(lost) else f"channel {', '.join(cs)}: {line}"
        for line, cs in said.items()
    )


def merge_plugins(per: dict, renderer: str) -> Plugin:
    """One plugin from the channels' plugins ({channel: Plugin} in r, g, b order) of one
    model family (module docstring); its ``scale`` is 1 (each channel keeps its own)."""
    first = next(iter(per.values()))
    for c, p in per.items():
        if (p.kind, p.type, [v.name for v in p.values], len(p.children), len(p.extra)) != (
            first.kind,
            first.type,
            [v.name for v in first.values],
            len(first.children),
            len(first.extra),
        ):
            raise Unsupported(
                f"channel {c} exports as {renderer}'s {p.type}, channel "
                f"{next(iter(per))} as {first.type}: one material needs one "
                f"plugin"
            )
        if p.geometry != first.geometry:
            raise Unsupported(
                f"channel {c}'s scene geometry {p.geometry} differs from "
                f"{first.geometry}: a colour export needs one geometry"
            )
    values = tuple(
        _merge_value({c: p.values[k] for c, p in per.items()}, first.type, renderer)
        for k in range(len(first.values))
    )
    children = tuple(
        merge_plugins({c: p.children[k] for c, p in per.items()}, renderer)
        for k in range(len(first.children))
    )
    extra = tuple(
        merge_plugins({c: p.extra[k] for c, p in per.items()}, renderer)
        for k in range(len(first.extra))
    )
    return dataclasses.replace(
        first,
        values=values,
        children=children,
        extra=extra,
        lost=_merge_lost({c: p.lost for c, p in per.items()}),
        scale=1.0,
        model=None,
    )


def _brdf_items(brdfs: dict, renderer: str, setting: Setting) -> dict:
    """{channel: Exported} of the channels' BRDFs; a family the renderer lacks is fitted
    by its closest family over every channel at once."""
    first = next(iter(brdfs.values()))
    if has_own_plugin(first, renderer):
        return {c: plugin(m, renderer, setting) for c, m in brdfs.items()}
    family, options = proxy(first, renderer, setting)
    from .closest import closest_channels

    fits = closest_channels(brdfs, family, options)
    return {c: from_closest(m, fits[c], renderer, setting) for c, m in brdfs.items()}


def _comments(channels: dict, renderer: str, source: str) -> list[str]:
    lines = [
        f"veil colour export for {renderer}"
        + (f" of {source}" if source else "")
        + f": channels {', '.join(channels)} as the renderer's red, green and blue"
    ]
    for c, items in channels.items():
        for item in items:
            ident = IDS[item.plugin.kind]
            lines.append(f"{ident} [{c}]: {item.source}")
            if item.model is not item.source:
                lines.append(f"{ident} [{c}]: closest {item.model.NAME}: {item.model}")
    scales = {}
    for c, items in channels.items():
        s = 1.0
        for item in items:
            s *= item.plugin.scale
        scales[c] = s
    lines.append(
        "veil's value in channel c = the render's channel c under a white unit "
        "irradiance x the intensity scale of c: "
        + ", ".join(f"{c} {s!r}" for c, s in scales.items())
    )
    return lines


def export_colour(
    models: dict,
    renderer: str = "mitsuba",
    fmt: str | None = None,
    setting: Setting = DEFAULT_SETTING,
    source: str = "",
) -> ColourExport:
    """Scene text of ``models`` ({channel: [BRDF and/or medium]}, channels r, g, b) in
    ``renderer``'s format ``fmt`` (module docstring)."""
    fmt = check_format(renderer, fmt)
    order = rgb_order(models, source)
    per = {c: sorted_models(models[c]) for c in order}
    kinds = {c: [m.KIND for m in ms] for c, ms in per.items()}
    if len({tuple(k) for k in kinds.values()}) != 1:
        raise InputError(
            "every channel needs the same models (a BRDF and/or a medium); got "
            + "; ".join(f"{c}: {', '.join(k)}" for c, k in kinds.items())
        )
    for c in order:
        check_exportable(per[c], renderer, setting)
    items: dict[str, list[Exported]] = {c: [] for c in order}
    for k, kind in enumerate(kinds[order[0]]):
        of_kind = {c: per[c][k] for c in order}
        if kind == "brdf":
            made = _brdf_items(of_kind, renderer, setting)
        else:
            made = {c: plugin(m, renderer, setting) for c, m in of_kind.items()}
        for c in order:
            items[c].append(made[c])
    channels = {c: tuple(items[c]) for c in order}
    comments = [*_comments(channels, renderer, source)]
    plugins = []
    for k in range(len(kinds[order[0]])):
        merged = merge_plugins({c: channels[c][k].plugin for c in order}, renderer)
        comments += [f"{IDS[merged.kind]}: lost: {note}" for note in merged.lost]
        plugins.append(merged)
    text = scene_text(plugins, tuple(comments), renderer, fmt)
    return ColourExport(renderer, fmt, text, channels, tuple(comments))


__all__ = ["ColourExport", "export_colour", "merge_plugins", "rgb_order"]
