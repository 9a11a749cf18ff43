"""What ``veil render`` writes and prints: the image files, the lines after the render's
summary, and the render of results fitted over the channels r, g, b (each channel's sphere
as the red, green and blue of one RGB image, :mod:`veil.viz.render_colour`,
docs/figures.md)."""

from __future__ import annotations

import io

import click

from .._lazy import np


def write_images(output, png: bytes, linear_path, image) -> None:
    """The PNG and, when asked, the linear values (float32 .npy): both files or neither."""
    from ..io import write_many_atomic

    files = {output: png}
    if linear_path is not None:
        buf = io.BytesIO()
        np.save(buf, image.astype(np.float32))
        files[linear_path] = buf.getvalue()
    write_many_atomic(files)


def report(exposure: str, tone: str, clipped, output, linear_path, seconds: float) -> None:
    """The lines after the render's summary: exposure and tone, clipping, files written."""
    n_clip, frac, peak_fs = clipped
    click.echo(f"{exposure}, tone curve {tone}; peak = {peak_fs:.3g} x full scale")
    if tone == "clip":
        if n_clip:
            click.echo(
                f"highlights clip: {n_clip} pixels ({100 * frac:.2g} % of the lit ones) "
                f"are above white"
            )
        else:
            click.echo("nothing clips")
    click.echo(
        f"wrote {output}" + (f" and {linear_path}" if linear_path else "") + f" in {seconds:.1f} s"
    )


def render_rgb(
    brdfs,
    media,
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
) -> None:
    """Render, tone-map and write the colour sphere (an RGB PNG; the linear values as a
    (size, size, 3) float32 .npy with --linear), and print what ``veil render`` prints."""
    from ..viz.render import png_bytes, tone_map
    from ..viz.render_colour import auto_exposure_colour, clipping_colour, render_colour

    result = render_colour(
        brdfs,
        media,
        light_theta,
        light_phi,
        size,
        accuracy=accuracy,
        samples=samples,
        check=check,
        progress=not quiet,
    )
    auto = exposure is None
    exp_used = auto_exposure_colour(result.image) if auto else exposure
    clipped = clipping_colour(result.image, exp_used, tone)
    text = {
        "veil:brdf": "; ".join(f"{c}: {m}" for c, m in brdfs.items()),
        "veil:medium": "clear"
        if media is None
        else "; ".join(f"{c}: {m}" for c, m in media.items()),
        "veil:light": f"theta {light_theta:g} deg, phi {light_phi:g} deg",
        "veil:pixel": "r, g, b: f(I,R) cos(theta_i) of each channel's model, linear, "
        "then exposure, tone curve, sRGB",
        "veil:exposure": f"{exp_used:.6g}",
        "veil:tone": tone,
    }
    write_images(
        output, png_bytes(tone_map(result.image, exp_used, tone), text), linear_path, result.image
    )
    click.echo(result.summary())
    how = "automatic: median lit luminance -> 0.18" if auto else "given"
    report(f"exposure {exp_used:.6g} ({how})", tone, clipped, output, linear_path, result.seconds)


__all__ = ["render_rgb", "write_images", "report"]
