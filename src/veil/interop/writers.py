"""Writing :class:`veil.models.renderers.Plugin` objects out: Mitsuba 3 XML, the equivalent
Python dict (``mitsuba.load_dict``), and pbrt-v4 scene text. Nothing here knows a model
family: the plugins' names and values come from the families' declarations."""

from __future__ import annotations

import pprint

from ..models.renderers import Plugin

#: Scene ids of what an export declares, by plugin kind.
IDS = {"bsdf": "veil_material", "material": "veil_material", "medium": "veil_medium"}
BOUNDARY_ID = "veil_boundary"
#: pbrt spectra given as one constant: its value at these two wavelengths (nm).
PBRT_WAVELENGTHS = (200, 900)


def number(x: float) -> str:
    """The shortest text that reads back as the same float (deterministic)."""
    text = repr(float(x))
    return "0" if text == "-0.0" else text


def _comment(text: str) -> str:
    # an XML comment may not contain "--"
    while "--" in text:
        text = text.replace("--", "- -")
    return text


def _rgb_text(values, sep: str) -> str:
    return sep.join(number(x) for x in values)


def _unbounded(v) -> bool:
    """An (r, g, b) value with a component above 1: Mitsuba's plain ``rgb`` is a
    reflectance (refused above 1), so it is written as an unbounded ``srgb`` texture."""
    return isinstance(v.value, tuple) and max(v.value) > 1.0


def _xml_value(v) -> str:
    if isinstance(v.value, tuple):
        if _unbounded(v):
            return (
                f'<texture type="srgb" name="{v.name}"><rgb name="color" '
                f'value="{_rgb_text(v.value, ", ")}"/><boolean name="unbounded" '
                f'value="true"/></texture>'
            )
        return f'<rgb name="{v.name}" value="{_rgb_text(v.value, ", ")}"/>'
    if v.kind == "boolean":
        return f'<boolean name="{v.name}" value="{"true" if v.value else "false"}"/>'
    if v.kind == "string":
        return f'<string name="{v.name}" value="{v.value}"/>'
    if v.kind == "rgb":
        return f'<rgb name="{v.name}" value="{number(v.value)}"/>'
    return f'<float name="{v.name}" value="{number(v.value)}"/>'


def _xml_plugin(p: Plugin, ident: str | None, indent: int) -> list[str]:
    pad = " " * indent
    head = f'{pad}<{p.kind} type="{p.type}"' + (f' id="{ident}"' if ident else "") + ">"
    lines = [head]
    lines += [f"{pad}    {_xml_value(v)}" for v in p.values]
    for child in p.children:
        lines += _xml_plugin(child, None, indent + 4)
    lines.append(f"{pad}</{p.kind}>")
    return lines


def mitsuba_xml(plugins, comments) -> str:
    """A Mitsuba 3 scene fragment declaring each plugin under its id (:data:`IDS`)."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>']
    lines += [f"<!-- {_comment(c)} -->" for c in comments]
    lines.append('<scene version="3.0.0">')
    for p in plugins:
        lines += _xml_plugin(p, IDS[p.kind], 4)
        for extra in p.extra:
            lines += _xml_plugin(extra, BOUNDARY_ID, 4)
    lines.append("</scene>")
    return "\n".join(lines) + "\n"


def _dict_plugin(p: Plugin) -> dict:
    out: dict[str, object] = {"type": p.type}
    for v in p.values:
        if isinstance(v.value, tuple):
            out[v.name] = (
                {"type": "srgb", "color": list(v.value), "unbounded": True}
                if _unbounded(v)
                else {"type": "rgb", "value": list(v.value)}
            )
        else:
            out[v.name] = v.value
    for child in p.children:
        out[child.kind] = _dict_plugin(child)
    return out


def mitsuba_dict(plugins) -> dict:
    """The Python dict of :func:`mitsuba_xml` (for ``mitsuba.load_dict``)."""
    scene: dict[str, object] = {"type": "scene"}
    for p in plugins:
        scene[IDS[p.kind]] = _dict_plugin(p)
        for extra in p.extra:
            scene[BOUNDARY_ID] = _dict_plugin(extra)
    return scene


def mitsuba_dict_source(plugins, comments) -> str:
    """Python source defining ``scene`` = :func:`mitsuba_dict` (comments above it)."""
    lines = [f"# {c}" for c in comments]
    lines.append("scene = " + pprint.pformat(mitsuba_dict(plugins), sort_dicts=False, width=96))
    return "\n".join(lines) + "\n"


def _pbrt_value(v) -> str:
    if isinstance(v.value, tuple):  # a colour export: pbrt's RGB spectrum of the value
        return f'"rgb {v.name}" [ {_rgb_text(v.value, " ")} ]'
    if v.kind == "boolean":
        return f'"bool {v.name}" [ {"true" if v.value else "false"} ]'
    if v.kind == "string":
        return f'"string {v.name}" [ "{v.value}" ]'
    if v.kind == "rgb":
        x = number(v.value)
        return f'"rgb {v.name}" [ {x} {x} {x} ]'
    if v.kind == "spectrum":
        x = number(v.value)
        a, b = PBRT_WAVELENGTHS
        return f'"spectrum {v.name}" [ {a} {x} {b} {x} ]'
    return f'"float {v.name}" [ {number(v.value)} ]'


def pbrt_text(plugins, comments) -> str:
    """pbrt-v4 scene text: MakeNamedMaterial / MakeNamedMedium for each plugin."""
    lines = [f"# {c}" for c in comments]
    for p in plugins:
        word = "MakeNamedMaterial" if p.kind == "material" else "MakeNamedMedium"
        lines.append(f'{word} "{IDS[p.kind]}"')
        lines.append(f'    "string type" [ "{p.type}" ]')
        lines += [f"    {_pbrt_value(v)}" for v in p.values]
    return "\n".join(lines) + "\n"


__all__ = [
    "IDS",
    "BOUNDARY_ID",
    "number",
    "mitsuba_xml",
    "mitsuba_dict",
    "mitsuba_dict_source",
    "pbrt_text",
]
