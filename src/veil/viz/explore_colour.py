"""The channels of ``veil explore`` (docs/explore.md, "Colour"): results fitted over
several channels (docs/channels.md) draw one curve per channel in its colour
(:func:`veil.viz.explore.channel_colour`), solid through the medium and dashed without,
and a selector says which channel the controls edit. A parameter declared shared across
the channels follows the edited channel in every channel; one declared per channel moves
in the edited channel alone (:meth:`veil.viz.explore.State.with_model`). Of the channels
r, g, b the sphere is rendered in colour (:func:`veil.viz.explore.sphere_colour`).

Each channel's data source is named ``veil-channel-NAME`` (columns x, y, ylog, clear,
clearlog), so that tests read the plotted numbers back as for the other views.
"""

from __future__ import annotations

import numpy as np
import panel as pn
from bokeh.models import ColumnDataSource

from . import explore as ex

#: The channels whose sphere is drawn in colour.
RGB = ("r", "g", "b")


class ChannelLines:
    """One line per channel on the page's linear and log curve plots (``lin`` with its
    right axis "clear" for f_r, ``log``)."""

    def __init__(self, lin, log, channels):
        self.src = {}
        for c in channels:
            src = ColumnDataSource(name=f"veil-channel-{c}")
            src.data = {"x": [], "y": [], "ylog": [], "clear": [], "clearlog": []}
            colour = ex.channel_colour(c)
            through = lin.line(
                "x", "y", source=src, color=colour, line_width=1.5, legend_label=f"channel {c}"
            )
            clear = lin.line(
                "x",
                "clear",
                source=src,
                color=colour,
                line_width=1,
                line_dash="dashed",
                y_range_name="clear",
            )
            lin.y_range.renderers = list(lin.y_range.renderers) + [through]
            extra = lin.extra_y_ranges["clear"]
            extra.renderers = list(extra.renderers) + [clear]
            log.line(
                "x", "ylog", source=src, color=colour, line_width=1.5, legend_label=f"channel {c}"
            )
            log.line("x", "clearlog", source=src, color=colour, line_width=1, line_dash="dashed")
            self.src[c] = src

    def draw(self, curves, channels: dict) -> dict:
        """Each channel's curves ({channel: (brdf, medium)}) through ``curves`` (one
        compiled :class:`~veil.viz.explore.Curves` serves them all: one family); returns
        {channel: (through or None, clear)}."""
        values = {c: (curves.through(b, m), curves.clear(b)) for c, (b, m) in channels.items()}
        floor = ex.log_floor(*[v for pair in values.values() for v in pair if v is not None])
        x = np.asarray(curves.x)
        for c, (through, clear) in values.items():
            y = np.full(x.shape, np.nan) if through is None else through
            self.src[c].data = {
                "x": x,
                "y": y,
                "ylog": np.maximum(y, floor),
                "clear": clear,
                "clearlog": np.maximum(clear, floor),
            }
        return values


def channel_selector(page) -> pn.widgets.RadioButtonGroup:
    """The widget choosing the channel that ``page``'s controls edit."""
    widget = pn.widgets.RadioButtonGroup(
        label="channel", options=list(page.state.channels), value=page.state.channel
    )

    def on_change(event):
        page.state = page.state.with_channel(event.new)
        page.brdf.show(page.state.brdf)
        page.medium.show(page.state.medium)
        page.request_redraw(transmission=True, sphere=False)

    widget.param.watch(on_change, "value")
    return widget


def sphere_of(state, size: int, accuracy: str) -> tuple[np.ndarray, np.ndarray]:
    """(RGBA image, linear image) of the page's sphere: in colour for the channels r, g, b,
    else of the edited channel."""
    if state.channels is not None and sorted(state.channels) == sorted(RGB):
        return ex.sphere_colour(state.channels, state.theta_i, size, accuracy)
    return ex.sphere(state.brdf, state.medium, state.theta_i, size, accuracy)


__all__ = ["ChannelLines", "channel_selector", "sphere_of"]
