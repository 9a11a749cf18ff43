"""``veil export``: fitted models into renderers (Mitsuba 3 XML or dict, pbrt-v4), checked by
rendering with Mitsuba (``--verify``), or their predicted curves as a tidy CSV
(docs/interop.md). Heavy imports (JAX, the engine, Mitsuba) stay inside the command."""

from __future__ import annotations

import math
from pathlib import Path

import click

from ._common import (
    FINITE,
    OutputPath,
    UserError,
    accuracy_option,
    check_output_path,
    parse_psi,
    written_kind,
)

IN_FILE = click.Path(exists=True, dir_okay=False, path_type=Path)
TARGETS = ("mitsuba", "pbrt", "csv")
#: Samples per configuration of a --verify render through a medium (clear scenes need 1).
MEDIUM_SPP = 4096
#: Independent passes of a render through a medium (their spread is its standard error).
PASSES = 4
#: Most samples per configuration Mitsuba takes (its sample_count is a 32-bit unsigned).
MAX_SPP = 2**32 - 1


def _positive(name, low: float = 0.0, high: float = math.inf):
    """A callback: None or a finite number > 0 (within [low, high] when given)."""

    def check(ctx, param, value):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise click.BadParameter(f"{value!r}: expected a finite number > 0", param_hint=name)
        if value is not None and not low <= value <= high:
            raise click.BadParameter(
                f"{value!r}: expected a number from {low:g} to {high:g} (the values are "
                f"divided by it)",
                param_hint=name,
            )
        return value

    return check


@click.command("export")
@click.argument("result", type=IN_FILE)
@click.argument("medium_result", metavar="[MEDIUM]", required=False, type=IN_FILE)
@click.option(
    "--to",
    "target",
    required=True,
    type=click.Choice(TARGETS),
    help="mitsuba: a Mitsuba 3 scene fragment; pbrt: a pbrt-v4 material and medium "
    "block; csv: the predicted curves as a tidy table.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=OutputPath(dir_okay=False, path_type=Path),
    help="File to write (atomically).",
)
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["xml", "dict"]),
    default=None,
    help="Mitsuba only: XML (default) or the equivalent Python dict "
    "(mitsuba.load_dict), written as Python source defining 'scene'.",
)
@click.option(
    "--scale",
    type=FINITE,
    default=None,
    callback=_positive("--scale", 1e-300, 1e300),
    help="Intensity scale divided out of the BRDF's relative scales (veil's values "
    "are products with the light and the camera gain). Default: the family's "
    "choice (rough-plastic, rough-conductor: ks, so that the interface is "
    "physical). The file says which scale was used.",
)
@click.option(
    "--ext-ior",
    type=FINITE,
    default=1.0,
    show_default=True,
    callback=_positive("--ext-ior"),
    help="Index of the medium around the surface in the renderer's scene (plugins "
    "that take absolute indices get veil's relative index times this).",
)
@click.option(
    "--path-length",
    type=FINITE,
    default=None,
    callback=_positive("--path-length"),
    help="Length of one pass through the medium in scene units: sigma_t = tau / "
    "length (default: the medium's own path_length option).",
)
@click.option(
    "--verify",
    is_flag=True,
    help="Render the export with Mitsuba 3 (pip install 'veil[mitsuba]') at the "
    "configurations of the paper's protocol and print the RMS difference "
    "from veil's prediction.",
)
@click.option(
    "--psi",
    default="30,60,90",
    show_default=True,
    metavar="DEG,...",
    help="Relative angles of the configurations of --verify and of --to csv.",
)
@click.option(
    "--spp",
    type=click.IntRange(min=1, max=MAX_SPP),
    default=None,
    help=f"Samples per configuration of --verify (default 1 for a surface, "
    f"{MEDIUM_SPP} through a medium; at most {MAX_SPP}, Mitsuba's limit).",
)
@accuracy_option("Quadrature of veil's apparent values (csv, --verify).")
@click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="Export one channel of a result fitted over several (r, g, b or a "
    "wavelength in nm). Without it such a result of the channels r, g, b is "
    'written as one RGB material (docs/interop.md, "Colour").',
)
def export_command(
    result,
    medium_result,
    target,
    output,
    fmt,
    scale,
    ext_ior,
    path_length,
    verify,
    psi,
    spp,
    accuracy,
    channel,
):
    """Write fitted models for a renderer, or their predicted curves as CSV.

    RESULT is a fit result (JSON); the optional MEDIUM a second one of the other kind (a
    target result brings its medium along, a medium result its reference BRDF). A result
    fitted over the channels r, g, b becomes one RGB material (--verify checks each
    channel; --to csv has a channel column); --channel NAME exports one channel. Each model
    family maps onto the renderer's own plugin where there is one (rough-plastic ->
    roughplastic, rough-conductor -> roughconductor, forward-series -> homogeneous medium
    with a Henyey-Greenstein phase function); the paper's Torrance-Sparrow BRDF becomes the
    closest rough-plastic, fitted to it (RMS difference printed and written into the
    file). What each conversion loses is written into the file as comments.

    \b
        veil export target.json medium.json --to mitsuba -o material.xml --verify
        veil export target.json --to pbrt -o material.pbrt
        veil export target.json medium.json --to csv -o curves.csv
    """
    from ..models.renderers import Setting

    psis = parse_psi(psi)
    if verify:
        _verify_configs(psis)  # a bad --psi before anything is written
    check_output_path(output, [result, medium_result])
    if fmt is not None and target != "mitsuba":
        raise UserError(f"--format {fmt} applies to --to mitsuba only")
    if verify and target != "mitsuba":
        raise UserError(
            f"--verify renders with Mitsuba; it applies to --to mitsuba, not --to {target}"
        )
    if verify:
        from ..interop.verify import load_mitsuba

        load_mitsuba()  # a missing Mitsuba is an error before any work
    from ._result_models import result_models

    loaded = result_models(result, medium_result, channel)
    for note in loaded.notes:
        click.echo(note, err=True)
    if target == "csv":
        _csv(loaded, psis, accuracy, output)
        return
    setting = Setting(scale=scale, ext_ior=ext_ior, path_length=path_length)
    _check_brought(loaded, target, setting, output)
    _check_closest(loaded, target)
    if loaded.colour:
        from .export_colour import export_rgb

        export_rgb(
            loaded,
            target,
            fmt,
            setting,
            output,
            verify,
            psis,
            spp,
            accuracy,
            medium_spp=MEDIUM_SPP,
            passes=PASSES,
        )
        return
    _export_one(loaded, target, fmt, setting, output, verify, psis, spp, accuracy)


def _check_brought(loaded, target: str, setting, output: Path) -> None:
    """A model the RESULT brought along (the one its fit held fixed; no file of its own
    given) that ``target`` cannot express: an error that says where it came from and what
    to give instead, before any other work of the export."""
    from ..interop.export import check_exportable
    from ..models.renderers import Unsupported

    for kind, path in loaded.brought.items():
        models = loaded.brdf if kind == "brdf" else loaded.medium
        try:
            check_exportable(list(models.values()), target, setting)
        except Unsupported as exc:
            what, how, arg = (
                ("medium", "through", "MEDIUM")
                if kind == "medium"
                else ("reference BRDF", "with", "BRDF")
            )
            name = next(iter(models.values())).NAME
            raise UserError(
                f"{path} stores the {what} it was fitted {how} ({name}), and the export "
                f"takes that {what} along when no {arg} file is given; {exc}. To export "
                f"{path} with a {what} {target} can express, give its result file as the "
                f"second argument: veil export {path} {arg}.json --to {target} -o {output} "
                f"(veil export has no option to leave the stored {what} out)"
            ) from None


def _check_closest(loaded, target: str) -> None:
    """A BRDF that ``target`` has no plugin for is exported as its closest family (the
    family's ``PROXIES``), fitted to its f_r: one whose f_r that fit cannot handle is refused
    here, naming its file and the parameter(s) to look at
    (:func:`veil.interop.closest.check_source`)."""
    from ..errors import InputError
    from ..interop.closest import MagnitudeError, check_source

    for key, model in (loaded.brdf or {}).items():
        if target not in getattr(type(model), "PROXIES", {}):  # its own plugin, or none
            continue
        try:
            check_source(model)
        except MagnitudeError as exc:
            lo, hi = exc.limits
            named = "; ".join(
                f"{loaded.where('brdf', key, n)} = {v:.3g}" for n, v in exc.params.items()
            ) or str(loaded.origin["brdf"][0])
            raise UserError(
                f"{named}: the {model.NAME} model's {exc.reach}, beyond the magnitudes "
                f"({lo:g} to {hi:g}) of the closest fit that exports it to {target}; "
                f"rescale the data the result was fitted to (value and sigma by one factor) "
                f"and fit it again"
            ) from None
        except InputError as exc:
            raise UserError(f"{loaded.origin['brdf'][0]}: {exc}") from None


def _export_one(loaded, target, fmt, setting, output, verify, psis, spp, accuracy) -> None:
    """The renderer's file of one channel's models (and its check by rendering)."""
    from ..interop.export import export
    from ..io import write_text_atomic

    brdf, medium, source = loaded.one("brdf"), loaded.one("medium"), loaded.source
    done = export([brdf, medium], target, fmt, setting, source)
    write_text_atomic(output, done.text)
    for item in done.items:
        if item.closest is not None:
            click.echo(item.closest.sentence())
    click.echo(
        f"wrote {written_kind(target, done.format)} to {output} "
        f"({', '.join(i.plugin.type for i in done.items)}); what the conversion loses "
        f"is written in it as comments",
        err=True,
    )
    if verify:
        _verify(done, brdf, medium, psis, spp, setting, accuracy)


def _csv(loaded, psis, accuracy, output) -> None:
    """--to csv: the predicted curves (a channel column when there are several)."""
    from ..interop.curves import channel_curves, curves, to_csv_text
    from ..io import write_text_atomic

    if loaded.colour:
        frame = channel_curves(loaded.brdf, loaded.medium, psis, accuracy)
    else:
        frame = curves(loaded.one("brdf"), loaded.one("medium"), psis, accuracy)
    write_text_atomic(output, to_csv_text(frame))
    both = loaded.medium is not None
    n = len(loaded.channels)
    click.echo(
        f"wrote {len(frame)} rows ({len(frame) // (2 if both else 1) // n} "
        f"configurations, {'with and without the medium' if both else 'no medium'}"
        + (f", {n} channels" if loaded.colour else "")
        + f") to {output}",
        err=True,
    )


def _verify_configs(psis):
    """The configurations --verify renders: the protocol at ``psis`` (checked)."""
    from ..data.protocol import protocol

    table = protocol(psis, fine_step=2.0, coarse_step=10.0)
    return table[["theta_i", "theta_r", "phi_i", "phi_r"]].to_numpy()


def _verify(done, brdf, medium, psis, spp, setting, accuracy) -> None:
    from ..engine.apparent import apparent, reflectance
    from ..interop.verify import verify
    from ..models.renderers import GEOMETRY_HALF_WIDTH, GEOMETRY_LENGTH

    configs = _verify_configs(psis)
    material = done.item("brdf")
    if material is None:
        raise UserError(
            "--verify renders a plate: give a BRDF result too (or a medium result "
            "that names its reference BRDF)"
        )
    if medium is None:
        predicted = reflectance(material.model, *configs.T)
        check = verify(done.text, done.scale, predicted, configs, spp or 1)
        click.echo(check.sentence())
        if material.closest is not None:
            source = reflectance(material.source, *configs.T)
            ratio = check.rendered[check.used] / source[check.used] - 1
            click.echo(
                f"against the {material.source.NAME} result itself: RMS relative "
                f"difference {100 * float((ratio**2).mean() ** 0.5):.3g} %"
            )
        return
    item = done.item("medium")
    exported, geometry = item.model, item.plugin.geometry
    if not geometry:
        raise UserError(
            f"--verify through a medium needs the scene geometry, which the "
            f"{exported.NAME} export does not give"
        )
    predicted = apparent(material.model, exported, *configs.T, accuracy=accuracy)
    check = verify(
        done.text,
        done.scale,
        predicted,
        configs,
        spp or MEDIUM_SPP,
        passes=PASSES,
        medium={
            "length": geometry[GEOMETRY_LENGTH],
            "half_width": geometry[GEOMETRY_HALF_WIDTH],
            "max_depth": 64,
        },
    )
    click.echo(check.sentence())
    click.echo(
        "(through a medium the two differ by the model's own approximations as well: "
        "docs/interop.md)"
    )
