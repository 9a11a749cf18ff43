"""``veil export`` of a result fitted over the channels r, g, b: one RGB material (and
medium) for the renderer, and ``--verify`` channel by channel (docs/interop.md, "Colour")."""

from __future__ import annotations

import click

from ._common import UserError, written_kind


def export_rgb(
    loaded,
    target,
    fmt,
    setting,
    output,
    verify,
    psis,
    spp,
    accuracy,
    *,
    medium_spp: int,
    passes: int,
) -> None:
    """Write the colour export of ``loaded`` (a :class:`~veil.cli._result_models.ResultModels`
    of several channels) to ``output``; with ``verify``, render it and compare each channel
    with veil's prediction of that channel."""
    from ..interop.colour import export_colour
    from ..io import write_text_atomic

    models = {
        c: [loaded.brdf[c] if loaded.brdf else None, loaded.medium[c] if loaded.medium else None]
        for c in loaded.channels
    }
    done = export_colour(models, target, fmt, setting, loaded.source)
    write_text_atomic(output, done.text)
    for c in done.channels:
        for item in done.channels[c]:
            if item.closest is not None:
                click.echo(f"channel {c}: {item.closest.sentence()}")
    kinds = ", ".join(i.plugin.type for i in done.channels["r"])
    click.echo(
        f"wrote {written_kind(target, done.format)} to {output} ({kinds}; channels r, g, b as RGB, "
        f"intensity scales "
        + ", ".join(f"{c} {s:.6g}" for c, s in done.scales.items())
        + "); what the conversion loses is written in it as comments",
        err=True,
    )
    if verify:
        _verify_rgb(done, psis, spp, accuracy, medium_spp, passes)


def _verify_rgb(done, psis, spp, accuracy, medium_spp: int, passes: int) -> None:
    """--verify of a colour export: one render, each channel against veil's own curve."""
    from ..data.protocol import protocol
    from ..engine.apparent import apparent, reflectance
    from ..interop.verify import verify_channels
    from ..models.renderers import GEOMETRY_HALF_WIDTH, GEOMETRY_LENGTH

    configs = protocol(psis, fine_step=2.0, coarse_step=10.0)[
        ["theta_i", "theta_r", "phi_i", "phi_r"]
    ].to_numpy()
    if done.item("brdf", "r") is None:
        raise UserError(
            "--verify renders a plate: give a BRDF result too (or a medium result "
            "that names its reference BRDF)"
        )
    materials = {c: done.item("brdf", c) for c in done.channels}
    media = {c: done.item("medium", c) for c in done.channels}
    if media["r"] is None:
        predicted = {c: reflectance(m.model, *configs.T) for c, m in materials.items()}
        checks = verify_channels(done.text, done.scales, predicted, configs, spp or 1)
    else:
        geometry = media["r"].plugin.geometry
        if not geometry:
            raise UserError(
                f"--verify through a medium needs the scene geometry, which the "
                f"{media['r'].model.NAME} export does not give"
            )
        predicted = {
            c: apparent(materials[c].model, media[c].model, *configs.T, accuracy=accuracy)
            for c in done.channels
        }
        scene = {
            "length": geometry[GEOMETRY_LENGTH],
            "half_width": geometry[GEOMETRY_HALF_WIDTH],
            "max_depth": 64,
        }
        checks = verify_channels(
            done.text,
            done.scales,
            predicted,
            configs,
            spp or medium_spp,
            medium=scene,
            passes=passes,
        )
    for c, check in checks.items():
        click.echo(f"channel {c}: {check.sentence()}")
        material = materials[c]
        if material.closest is not None:
            source = reflectance(material.source, *configs.T)
            ratio = check.rendered[check.used] / source[check.used] - 1
            click.echo(
                f"channel {c}: against the {material.source.NAME} result itself: RMS "
                f"relative difference {100 * float((ratio**2).mean() ** 0.5):.3g} %"
            )
    if media["r"] is not None:
        click.echo(
            "(through a medium the two differ by the model's own approximations as "
            "well: docs/interop.md)"
        )


__all__ = ["export_rgb"]
