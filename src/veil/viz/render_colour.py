"""Colour spheres (docs/figures.md, "Colour"): the sphere of :mod:`veil.viz.render` under
a BRDF (and a medium) fitted over the channels r, g, b, one image per channel stacked as
the red, green and blue of one linear image.

Each channel is :func:`veil.viz.render.render` of that channel's models: its own table of
the apparent BRDF, its own measured interpolation error. The automatic exposure maps the
median luminance of the lit pixels (Rec. 709 weights of linear sRGB) to 0.18, and a pixel
clips when any of its channels is above white.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..data.channels import RGB
from ..errors import InputError
from .render import MID_GREY, Rendering, render

#: Weights of the luminance of linear sRGB (Rec. 709) in the order r, g, b.
LUMINANCE = (0.2126, 0.7152, 0.0722)


@dataclass
class ColourRendering:
    """A colour sphere: the linear image (size, size, 3) in r, g, b and each channel's
    :class:`~veil.viz.render.Rendering` (its own table and interpolation error)."""

    image: np.ndarray
    channels: dict
    seconds: float

    def summary(self) -> str:
        return "\n".join(f"channel {c}: {r.summary()}" for c, r in self.channels.items())


def render_colour(
    brdfs: dict, media: dict | None = None, light_theta=45.0, light_phi=0.0, size=256, **options
) -> ColourRendering:
    """Render the sphere in colour: ``brdfs`` (and ``media``, or None for clear) map the
    channels r, g, b to their models; ``options`` as :func:`veil.viz.render.render`."""
    names = sorted(str(c) for c in brdfs)
    if names != sorted(RGB) or (media is not None and sorted(media) != sorted(RGB)):
        raise InputError(
            f"a colour render needs the channels {', '.join(RGB)}; got "
            f"{', '.join(str(c) for c in brdfs)} (render one channel with "
            f"--channel NAME)"
        )
    t0 = time.perf_counter()
    channels: dict[str, Rendering] = {}
    for c in RGB:
        channels[c] = render(
            brdfs[c], None if media is None else media[c], light_theta, light_phi, size, **options
        )
    image = np.stack([channels[c].image for c in RGB], axis=-1)
    return ColourRendering(image, channels, time.perf_counter() - t0)


def luminance(image) -> np.ndarray:
    """The luminance of a linear r, g, b image (..., 3)."""
    return np.asarray(image, dtype=float) @ np.asarray(LUMINANCE)


def auto_exposure_colour(image) -> float:
    """Exposure mapping the median luminance of the lit pixels to :data:`MID_GREY`."""
    y = luminance(image)
    lit = y[y > 0]
    return 1.0 if lit.size == 0 else MID_GREY / float(np.median(lit))


def clipping_colour(image, exposure: float, tone: str = "clip") -> tuple[int, float, float]:
    """(pixels with a channel above white, their fraction of the lit pixels, peak in units
    of full scale); nothing clips under the "reinhard" tone curve."""
    img = np.asarray(image)
    n_lit = int(np.count_nonzero(img.max(axis=-1) > 0))
    with np.errstate(over="ignore"):  # an overflowing peak: the caller refuses it
        n_clip = int(np.count_nonzero((exposure * img).max(axis=-1) > 1.0)) if tone == "clip" else 0
        return n_clip, (n_clip / n_lit if n_lit else 0.0), float(exposure * img.max())


__all__ = [
    "ColourRendering",
    "render_colour",
    "luminance",
    "auto_exposure_colour",
    "clipping_colour",
    "LUMINANCE",
]
