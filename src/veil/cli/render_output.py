"""What ``veil render`` writes and prints: the image files, the lines after the render's
summary, and the render of results fitted over the channels r, g, b (each channel's sphere
as the red, green and blue of one RGB image, :mod:`veil.viz.render_colour`,
docs/figures.md)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, fields

import click

from .._lazy import np


def check_linear_range(image, linear_path, given: str) -> None:
    """A UserError when the linear values do not fit the --linear file's float32 (docs/
    figures.md): a value above its largest (3.4e38; it would be written as inf) or a peak
    below its smallest normal value (1.2e-38; the image would be written as zeros and
    subnormals). ``given`` names the coefficients that scale the image and their options."""
    from ._errors import UserError

    largest, tiny = float(np.finfo(np.float32).max), float(np.finfo(np.float32).tiny)
    finite = np.abs(image[np.isfinite(image)])
    peak = float(finite.max()) if finite.size else 0.0
    if peak > largest:
        where = f"above float32's largest value ({largest:.3g}; they would be written as inf)"
        how = "smaller"
    elif 0.0 < peak < tiny:
        where = f"below float32's smallest normal value ({tiny:.3g}; they would be lost)"
        how = "larger"
    else:
        return
    raise UserError(
        f"--linear {linear_path}: the linear values reach {peak:.3g}, {where}, and the "
        f".npy file holds float32; the image is linear in {given}: give {how} coefficients "
        f"or leave out --linear"
    )


def write_images(output, png: bytes, linear_path, image) -> None:
    """The PNG and, when asked, the linear values (float32 .npy; :func:`check_linear_range`
    says whether they fit): both files or neither."""
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


@dataclass(frozen=True)
class RenderSettings:
    """``veil render``'s options for the render and its files (its --help)."""

    light_theta: float
    light_phi: float
    size: int
    exposure: float | None
    tone: str
    samples: int
    accuracy: str
    check: bool
    linear_path: str | None
    output: str
    quiet: bool
    brdf: str
    medium: str

    @classmethod
    def of(cls, params: dict) -> RenderSettings:
        """The settings among a command's parameters (click's ``Context.params``)."""
        return cls(**{f.name: params[f.name] for f in fields(cls)})

    def render_arguments(self) -> tuple[tuple, dict]:
        """The arguments after the models of :func:`veil.viz.render.render` and
        :func:`veil.viz.render_colour.render_colour`."""
        return (self.light_theta, self.light_phi, self.size), {
            "accuracy": self.accuracy,
            "samples": self.samples,
            "check": self.check,
            "progress": not self.quiet,
        }

    def models_text(self, models: dict) -> str:
        """The coefficients that scale the image and the options that gave them: "Pd = 1e+40,
        Ps = 1e+40 (--brdf 1e40,1e40,0.8,1.5, --medium none)"; ``models`` {channel: (BRDF,
        medium or None)}, channel None for a grey render."""
        from ..engine.apparent import scales_text

        named: list[str] = []
        for channel, pair in models.items():
            for model in pair:
                if model is None or not model.SCALES:
                    continue
                for text in scales_text(model).split(", "):
                    named.append(text if channel is None else f"{text} ({channel})")
        given = f"--brdf {self.brdf}, --medium {self.medium}"
        if not named:
            return f"the coefficients of the models ({given})"
        return f"{', '.join(dict.fromkeys(named))} ({given})"

    def text(self, brdf: str, medium: str, pixel: str, exposure: float) -> dict:
        """The PNG's text chunks."""
        return {
            "veil:brdf": brdf,
            "veil:medium": medium,
            "veil:light": f"theta {self.light_theta:g} deg, phi {self.light_phi:g} deg",
            "veil:pixel": pixel,
            "veil:exposure": f"{exposure:.6g}",
            "veil:tone": self.tone,
        }


def write_and_report(
    settings: RenderSettings, result, exposure: float, auto_rule, clipped, text: dict, models
) -> None:
    """The tone-mapped PNG (and the linear values) written, the render's summary and what
    follows it printed; ``auto_rule`` says how an automatic exposure was chosen (None: it
    was given); ``models`` {channel: (BRDF, medium)} rendered (channel None: grey)."""
    from ..viz.render import png_bytes, tone_map
    from ._errors import UserError

    if not math.isfinite(clipped[2]):  # exposure x peak beyond float64
        raise UserError(
            f"--exposure {exposure:g} times the image's peak {float(result.image.max()):.4g} "
            f"is beyond the range of float64 (1.8e308): give a smaller --exposure"
        )
    if settings.linear_path is not None:
        check_linear_range(result.image, settings.linear_path, settings.models_text(models))
    png = png_bytes(tone_map(result.image, exposure, settings.tone), text)
    write_images(settings.output, png, settings.linear_path, result.image)
    click.echo(result.summary())
    how = "given" if auto_rule is None else f"automatic: {auto_rule}"
    report(
        f"exposure {exposure:.6g} ({how})",
        settings.tone,
        clipped,
        settings.output,
        settings.linear_path,
        result.seconds,
    )


def render_rgb(brdfs, media, settings: RenderSettings) -> None:
    """Render, tone-map and write the colour sphere (an RGB PNG; the linear values as a
    (size, size, 3) float32 .npy with --linear), and print what ``veil render`` prints."""
    from ..viz.render_colour import auto_exposure_colour, clipping_colour, render_colour

    args, kwargs = settings.render_arguments()
    result = render_colour(brdfs, media, *args, **kwargs)
    auto = settings.exposure is None
    exposure = (
        auto_exposure_colour(result.image) if settings.exposure is None else settings.exposure
    )
    clipped = clipping_colour(result.image, exposure, settings.tone)
    text = settings.text(
        "; ".join(f"{c}: {m}" for c, m in brdfs.items()),
        "clear" if media is None else "; ".join(f"{c}: {m}" for c, m in media.items()),
        "r, g, b: f(I,R) cos(theta_i) of each channel's model, linear, then exposure, tone "
        "curve, sRGB",
        exposure,
    )
    rule = "median lit luminance -> 0.18" if auto else None
    pairs = {c: (b, None if media is None else media.get(c)) for c, b in brdfs.items()}
    write_and_report(settings, result, exposure, rule, clipped, text, pairs)


__all__ = [
    "RenderSettings",
    "render_rgb",
    "write_and_report",
    "write_images",
    "report",
    "check_linear_range",
]
