"""``veil models``: the registered model families, read from their declarations."""

from __future__ import annotations

import json

import click


@click.command("models")
@click.option(
    "--kind",
    type=click.Choice(["brdf", "medium"]),
    default=None,
    help="List only BRDF families or only medium models.",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the declarations as JSON (name, kind, parameters, options, presets).",
)
def models_command(kind, as_json):
    """List the model families veil knows: parameters with bounds, units and meaning,
    options, the parameters that scale the model linearly, those a joint fit may share, those
    that take one value per colour channel, the presets, and the model's declared error
    where it has one. Commands choose them with --brdf-model NAME and --medium-model NAME."""
    from ..models import names
    from ..numbers import json_clean

    entries = [_entry(name) for name in names(kind)]
    if as_json:  # unbounded parameters have null bounds
        click.echo(json.dumps(json_clean(entries), indent=2, allow_nan=False))
        return
    _print_tables(entries)


def _entry(name: str) -> dict:
    """The declaration of the family ``name`` as an entry of the list."""
    from ..models import DEFAULTS, PRESETS, model_class

    cls = model_class(name)
    return {
        "name": name,
        "kind": cls.KIND,
        "label": cls.LABEL,
        "default": DEFAULTS[cls.KIND] == name,
        "literal": cls.literal_form(),
        "parameters": [
            {
                "name": p.name,
                "alias": p.alias,
                "lower": p.lower,
                "upper": p.upper,
                "interval": p.interval(),
                "unit": p.unit,
                "meaning": p.doc,
                "log_scale": p.log_scale,
                "scale": p.name in cls.scale_names(),
                "share": p.share,
                "channels": cls.channel_sharing()[p.name],
            }
            for p in cls.PARAMS
        ],
        "options": [
            {"name": o.name, "default": o.default, "choices": list(o.choices), "meaning": o.doc}
            for o in cls.OPTIONS
        ],
        "presets": [k for k, m in PRESETS.items() if type(m) is cls],
        "model_error_floor": None
        if cls.MODEL_ERROR_FLOOR is None
        else {"sigma": cls.MODEL_ERROR_FLOOR[0], "length": cls.MODEL_ERROR_FLOOR[1]},
    }


def _print_tables(entries: list) -> None:
    """The families as tables (rich), their literals, presets, options and declared error."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    for e in entries:
        title = f"{e['name']} ({e['kind']}{', the default' if e['default'] else ''}): {e['label']}"
        table = Table(title=escape(title), title_justify="left")
        for col in ("parameter", "bounds", "unit", "meaning"):
            table.add_column(col)
        for p in e["parameters"]:
            name = p["name"] + (f" ({p['alias']})" if p["alias"] else "")
            notes = []
            if p["scale"]:
                notes.append("linear scale")
            if p["share"]:
                notes.append(f"joint fits: {p['share'].replace('-', ' ')} by default")
            notes.append(
                "one per channel" if p["channels"] == "per-channel" else "shared by the channels"
            )
            meaning = p["meaning"] + (f" [{'; '.join(notes)}]" if notes else "")
            table.add_row(escape(name), p["interval"], escape(p["unit"] or "-"), escape(meaning))
        console.print(table)
        console.print(
            f"  literal: {e['literal']}"
            + (f"; presets: {', '.join(e['presets'])}" if e["presets"] else "")
        )
        for o in e["options"]:
            values = " | ".join(map(str, o["choices"])) or type(o["default"]).__name__
            console.print(
                escape(
                    f"  option --{o['name'].replace('_', '-')}: {values}"
                    f" (default {o['default']}): {o['meaning']}"
                )
            )
        if e["model_error_floor"]:
            f = e["model_error_floor"]
            console.print(
                escape(
                    f"  declared model error: {100 * f['sigma']:g} % relative, "
                    f"correlation length {f['length']:g} deg (the least "
                    f"model-discrepancy term of a weighted fit through it)"
                )
            )
        console.print("")
