"""The lit sphere of ``veil explore`` (docs/explore.md): rendered by
:func:`veil.viz.render.render` at the live accuracy while the sliders move (a coarser
render table for sharp lobes) and refined when they rest; grey, or in colour from the
channels r, g, b; as an RGBA image for a plot."""

from __future__ import annotations

import numpy as np

#: Quadrature of the live views (the sphere is refined at "default" when the sliders rest).
LIVE_ACCURACY = "fast"
REFINED_ACCURACY = "default"
#: Largest render table of the live sphere (engine configurations): sharp lobes get a
#: coarser table while the sliders move, the refined render has the full one.
LIVE_TABLE_NODES = 1024
#: Table densities tried, in order, for the live sphere.
LIVE_DENSITIES = (1.0, 0.85, 0.7, 0.55)


def table_density(brdf, medium, light_theta: float, accuracy: str) -> float:
    """The render table's density: 1 (render's own) for the refined sphere and whenever the
    table has at most :data:`LIVE_TABLE_NODES` nodes; for a live sphere of a sharper lobe
    the first of :data:`LIVE_DENSITIES` that keeps it under that."""
    from .render_table import W_NODES, auto_density, peak_width, u_nodes

    if accuracy != LIVE_ACCURACY or medium is None:
        return 1.0
    width = peak_width(brdf, medium)
    for density in LIVE_DENSITIES:
        d = density * auto_density(float(light_theta))
        nodes = len(u_nodes(width, d)) * max(5, int(round((W_NODES - 1) * d)) + 1)
        if nodes <= LIVE_TABLE_NODES:
            return density
    return LIVE_DENSITIES[-1]


def sphere(
    brdf, medium, light_theta: float, size: int = 96, accuracy: str = LIVE_ACCURACY
) -> tuple[np.ndarray, np.ndarray]:
    """(RGBA uint32 image (size, size) for a plot, linear image): the lit sphere of
    :func:`veil.viz.render.render` (the render table at ``accuracy``, coarser for sharp
    lobes at the live accuracy: :func:`table_density`), tone-mapped by its automatic
    exposure; rows from the bottom, as plots want them."""
    from .render import auto_exposure, render, tone_map

    theta = min(float(light_theta), 89.0)
    rendering = render(
        brdf,
        medium,
        light_theta=theta,
        size=size,
        accuracy=accuracy,
        check=0,
        density=table_density(brdf, medium, theta, accuracy),
    )
    linear = rendering.image
    grey = tone_map(linear, auto_exposure(linear))  # uint8 (size, size)
    return _rgba(np.repeat(grey[..., None], 3, axis=-1)), linear


def _rgba(rgb) -> np.ndarray:
    """(size, size) uint32 RGBA of a uint8 (size, size, 3) image, rows from the bottom."""
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 255, dtype=np.uint8)], axis=-1)
    return rgba[::-1].copy().view(dtype=np.uint32).reshape(rgb.shape[:2])


def sphere_colour(
    channels: dict, light_theta: float, size: int = 96, accuracy: str = LIVE_ACCURACY
) -> tuple[np.ndarray, np.ndarray]:
    """(RGBA uint32 image, linear (size, size, 3) image): :func:`sphere` of the channels r,
    g, b ({channel: (brdf, medium)}) as one colour image (:mod:`veil.viz.render_colour`),
    tone-mapped by its automatic exposure (the median lit luminance)."""
    from .render import render, tone_map
    from .render_colour import auto_exposure_colour

    theta = min(float(light_theta), 89.0)
    linear = np.stack(
        [
            render(
                b,
                m,
                light_theta=theta,
                size=size,
                accuracy=accuracy,
                check=0,
                density=table_density(b, m, theta, accuracy),
            ).image
            for b, m in (channels[c] for c in ("r", "g", "b"))
        ],
        axis=-1,
    )
    return _rgba(tone_map(linear, auto_exposure_colour(linear))), linear


__all__ = ["LIVE_ACCURACY", "REFINED_ACCURACY", "table_density", "sphere", "sphere_colour"]
