"""``veil render``: one sphere under a true or apparent BRDF (paper fig. 12; see
:mod:`veil.render` and docs/figures.md)."""

from __future__ import annotations

import os

import click

from .._lazy import np
from ._common import (
    FINITE,
    UserError,
    accuracy_option,
    check_file_target,
    model_options,
    options_named,
)


def output_path(path: str, suffixes: tuple, what: str) -> str:
    """Check that ``path`` can be written as ``what`` (suffix and directory); UserError if not."""
    if not path.lower().endswith(suffixes):
        raise UserError(f"{what} {path!r} must end in {' or '.join(suffixes)}")
    check_file_target(path, f"{what} {path!r}", f"{what} {path!r}")
    return path


@click.command("render", short_help="Render a sphere under a true or apparent BRDF.")
@click.option(
    "--brdf",
    required=True,
    help="Object: preset (BRDF1, BRDF2), 'PD,PS,N,ETA', or a BRDF fit result (JSON; "
    "one fitted over the channels r, g, b renders in colour).",
)
@click.option(
    "--medium",
    default="none",
    show_default=True,
    help="Medium: preset (BTDF1..3), 'TD,TT,G,ETA', a medium fit result (JSON), or "
    "'none' for the true BRDF.",
)
@click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="Render one channel of results fitted over several (a grey image); "
    "without it results of the channels r, g, b render in colour.",
)
@click.option(
    "--light-theta",
    type=FINITE,
    default=45.0,
    show_default=True,
    help="Light's polar angle from the viewing direction, degrees, in [0, 120].",
)
@click.option(
    "--light-phi",
    type=FINITE,
    default=0.0,
    show_default=True,
    help="Light's azimuth, degrees (0: from the right, 90: from the top).",
)
@click.option(
    "--size",
    type=int,
    default=256,
    show_default=True,
    help="Image size in pixels, 8 to 4096 (memory grows with its square: about 0.9 GB at 4096).",
)
@click.option(
    "--exposure",
    type=FINITE,
    default=None,
    help="Scale from linear value to display (1 = white). Default: automatic, the "
    "median lit pixel maps to 0.18.",
)
@click.option(
    "--tone",
    type=click.Choice(["clip", "reinhard"]),
    default="clip",
    show_default=True,
    help="clip: linear, clipped at white; reinhard: x/(1+x), never clips.",
)
@click.option(
    "--samples",
    type=int,
    default=1,
    show_default=True,
    help="k x k samples per pixel, 1 to 8 (1: the pixel centre); the time grows "
    "with k^2, the memory does not.",
)
@accuracy_option("Quadrature of the engine.", default="fast")
@click.option(
    "--check",
    type=int,
    default=64,
    show_default=True,
    help="Pixels evaluated directly to measure the interpolation error.",
)
@click.option(
    "--linear",
    "linear_path",
    default=None,
    help="Also save the linear float values (float32) to this .npy file; values beyond "
    "float32's range (1.2e-38 to 3.4e38 at the peak) are refused.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    help="Output PNG (8-bit sRGB: greyscale, or RGB for a colour render).",
)
@click.option("--quiet", is_flag=True, help="No progress display.")
@model_options()
@options_named(
    {
        "light_theta": "--light-theta",
        "light_phi": "--light-phi",
        "size": "--size",
        "samples": "--samples",
    }
)
def render_command(
    brdf,
    medium,
    channel,
    light_theta,
    light_phi,
    size,
    exposure,
    tone,
    samples,
    accuracy,
    check,
    linear_path,
    output,
    quiet,
    models,
):
    """Render a unit sphere lit by a distant point light, seen by an orthographic camera.

    Pixel value = f(I, R) cos(theta_i) at each visible, lit point with the sphere's local
    normal (paper eq. 1), f the object's BRDF or, with --medium, its apparent BRDF through
    the medium. Prints the exposure used, how many pixels clip and the measured
    interpolation error. Results fitted over the channels r, g, b render each channel with
    its own model, as the red, green and blue of an RGB image (docs/figures.md).
    """
    from ..viz.render import check_memory

    b, m, notes = _given_models(brdf, medium, channel, models)
    output_path(output, (".png",), "output")
    if linear_path is not None:
        output_path(linear_path, (".npy",), "--linear file")
        if os.path.abspath(linear_path) == os.path.abspath(output):
            raise UserError("--linear and -o name the same file")
    if exposure is not None and not (np.isfinite(exposure) and exposure > 0):
        raise UserError(f"--exposure {exposure:g} must be a positive number")
    if 8 <= size <= 4096 and 1 <= samples <= 8:  # render() words the range errors
        check_memory(size, samples, names=("--size", "--samples"))
    for note in notes:
        click.echo(note, err=True)
    from .render_output import RenderSettings, render_rgb

    settings = RenderSettings.of(click.get_current_context().params)
    if None not in b:
        render_rgb(b, m, settings)
        return
    _render_grey(b[None], None if m is None else m[None], settings)


def _render_grey(b, m, settings) -> None:
    """One channel's (grey) render: the PNG (and the linear image), what it printed."""
    from ..viz.render import auto_exposure, clipping, render
    from .render_output import write_and_report

    args, kwargs = settings.render_arguments()
    result = render(b, m, *args, **kwargs)
    auto = settings.exposure is None
    exposure = auto_exposure(result.image) if settings.exposure is None else settings.exposure
    clipped = clipping(result.image, exposure, settings.tone)
    text = settings.text(
        str(b),
        "clear" if m is None else str(m),
        "f(I,R) cos(theta_i), linear, then exposure, tone curve, sRGB",
        exposure,
    )
    rule = "median lit pixel -> 0.18" if auto else None
    write_and_report(settings, result, exposure, rule, clipped, text, {None: (b, m)})


def _is_file(text: str) -> bool:
    return os.path.exists(text) or text.lower().endswith(".json")


def _given_models(brdf: str, medium: str, channel, models):
    """({channel: BRDF}, {channel: medium} or None, notes) of --brdf and --medium, presets,
    literals or fit results (docs/channels.md); keyed None for a grey render."""
    files = [t for t in (brdf, medium) if _is_file(t)]
    if not files:
        if channel is not None:
            raise UserError(
                f"--channel {channel}: it names a channel of fit results (JSON); "
                f"--brdf and --medium are presets or literals"
            )
        return {None: models.brdf_model(brdf)}, {None: models.medium_model(medium)}, []
    from ._result_models import result_models

    loaded = result_models(files[0], files[1] if len(files) > 1 else None, channel, given=False)
    keys = loaded.channels
    if _is_file(brdf) and loaded.brdf is None:
        raise UserError(f"--brdf {brdf}: a medium result; expected a BRDF result")
    if _is_file(medium) and loaded.medium is None:
        raise UserError(f"--medium {medium}: a BRDF result; expected a medium result")
    b = loaded.brdf if _is_file(brdf) else dict.fromkeys(keys, models.brdf_model(brdf))
    if _is_file(medium):
        return b, loaded.medium, loaded.notes
    m = models.medium_model(medium)
    return b, None if m is None else dict.fromkeys(keys, m), loaded.notes
