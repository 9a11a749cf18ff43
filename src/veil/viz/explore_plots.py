"""The plots of the ``veil explore`` page (:mod:`veil.viz.explore_page`) and their named
data sources: the curves, the polar and transmission lobes, the lit sphere, the state
(:class:`Views`), and the data panel of a fit result (:class:`FitPlots`).

Every plotted data source has a name ``veil-...`` (see :data:`SOURCES`) so that tests can
read the plotted numbers back from the browser (``Bokeh.documents[0].get_model_by_name``).
"""

from __future__ import annotations

import os

import numpy as np
from bokeh.models import ColumnDataSource, DataRange1d, LinearAxis
from bokeh.models.annotations import Whisker
from bokeh.plotting import figure

from . import explore as ex
from . import explore_fits as fits
from .explore_colour import ChannelLines

#: Names of the plotted data sources (the page's readable contract with its tests).
SOURCES = {
    "medium": "veil-curve-medium",  # x, y: apparent reflectance along the curve
    "clear": "veil-curve-clear",  # x, y: f_r along the curve
    "polar": "veil-polar",  # x, y (and the clear lobe x0, y0)
    "transmission": "veil-transmission",  # x, y: f_t lobe
    "sphere": "veil-sphere",  # image, accuracy
    "state": "veil-state",  # key, value: the page's state, flattened
    "data": "veil-fit-data",
    "fit": "veil-fit-model",
    "residuals": "veil-fit-residuals",
}
#: The sources of the main views (the fit panels have their own).
VIEW_SOURCES = ("medium", "clear", "polar", "transmission", "sphere", "state")
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")


def _state_columns(state: ex.State) -> dict:
    keys, values = [], []
    for kind in ("brdf", "medium"):
        model = getattr(state, kind)
        keys.append(f"{kind}.model")
        values.append("" if model is None else model.NAME)
        if model is None:
            continue
        for k, v in model.as_dict().items():
            keys.append(f"{kind}.{k}")
            values.append(repr(float(v)))
        for k, v in model.options().items():
            keys.append(f"{kind}.option.{k}")
            values.append(str(v))
    for k in ("theta_i", "psi", "curve"):
        keys.append(k)
        values.append(str(getattr(state, k)))
    return {"key": keys, "value": values}


class Views:
    """The plots and their named data sources; :meth:`draw` puts a state's numbers in."""

    def __init__(self, fit_views=(), channels=None):
        tools = "pan,wheel_zoom,box_zoom,reset,save,hover"
        self.src = {k: ColumnDataSource(name=SOURCES[k]) for k in VIEW_SOURCES}
        self.src["medium"].data = {"x": [], "y": [], "ylog": []}
        self.src["clear"].data = {"x": [], "y": [], "ylog": []}
        self.src["polar"].data = {"x": [], "y": [], "x0": [], "y0": []}
        self.src["transmission"].data = {"x": [], "y": []}
        self.src["sphere"].data = {"image": [np.zeros((2, 2), dtype=np.uint32)], "accuracy": [""]}
        self.src["state"].data = {"key": [], "value": []}
        self._curve_figures(tools)
        self._lobe_figures(tools)
        # the state, readable from the page (not drawn)
        self.state_fig = figure(height=10, width=10, toolbar_location=None, visible=False)
        self.state_fig.scatter(x="value", y="key", source=self.src["state"], visible=False)
        self.fit = [FitPlots(v, k) for k, v in enumerate(fit_views)]
        self.channels = None if channels is None else ChannelLines(self.lin, self.log, channels)

    def _curve_figures(self, tools):
        """The in-plane curve, linear (f_r on its own axis) and log."""
        self.lin = figure(
            title="in-plane curve", height=300, width=460, tools=tools, y_axis_label="f (1/sr)"
        )
        self.log = figure(
            title="in-plane curve (log)",
            height=300,
            width=460,
            tools=tools,
            y_axis_type="log",
            y_axis_label="f (1/sr)",
        )
        # linear: the two curves differ by orders of magnitude, so f_r has its own axis
        through = self.lin.line(
            "x",
            "y",
            source=self.src["medium"],
            line_width=2,
            color=COLORS[0],
            legend_label="through the medium",
        )
        self.lin.y_range = DataRange1d(renderers=[through])
        self.lin.extra_y_ranges = {"clear": DataRange1d()}
        clear = self.lin.line(
            "x",
            "y",
            source=self.src["clear"],
            line_width=1.5,
            color=COLORS[1],
            line_dash="dashed",
            y_range_name="clear",
            legend_label="without medium (right axis)",
        )
        self.lin.extra_y_ranges["clear"].renderers = [clear]
        self.lin.add_layout(
            LinearAxis(
                y_range_name="clear", axis_label="f_r (1/sr)", axis_label_text_color=COLORS[1]
            ),
            "right",
        )
        self.lin.yaxis[0].axis_label_text_color = COLORS[0]
        self.log.line(
            "x",
            "ylog",
            source=self.src["medium"],
            line_width=2,
            color=COLORS[0],
            legend_label="through the medium",
        )
        self.log.line(
            "x",
            "ylog",
            source=self.src["clear"],
            line_width=1.5,
            color=COLORS[1],
            line_dash="dashed",
            legend_label="without medium",
        )
        for fig in (self.lin, self.log):
            fig.legend.location = "top_left"
            fig.legend.click_policy = "hide"

    def _lobe_figures(self, tools):
        """The polar lobes, the medium's transmission lobe and the lit sphere."""
        self.polar = figure(
            title="polar lobe (plane of incidence)",
            height=300,
            width=300,
            match_aspect=True,
            tools=tools,
        )
        self.polar.line("x", "y", source=self.src["polar"], line_width=2, color=COLORS[0])
        self.polar.line("x0", "y0", source=self.src["polar"], color=COLORS[1], line_dash="dashed")
        self.trans = figure(
            title="medium transmission lobe f_t(I, w)",
            height=300,
            width=300,
            match_aspect=True,
            tools=tools,
        )
        self.trans.line("x", "y", source=self.src["transmission"], line_width=2, color=COLORS[2])
        self.sphere = figure(
            title="lit sphere",
            height=300,
            width=300,
            tools="",
            x_range=(0, 1),
            y_range=(0, 1),
            toolbar_location=None,
        )
        self.sphere.image_rgba(image="image", x=0, y=0, dw=1, dh=1, source=self.src["sphere"])
        self.sphere.axis.visible = False
        self.sphere.grid.visible = False

    def draw_curves(self, x, xlabel, through, clear, curve, theta_i, psi) -> None:
        floor = ex.log_floor(through, clear)
        if through is None:
            self.src["medium"].data = {"x": [], "y": [], "ylog": []}
        else:
            self.src["medium"].data = {"x": x, "y": through, "ylog": np.maximum(through, floor)}
        self.src["clear"].data = {"x": x, "y": clear, "ylog": np.maximum(clear, floor)}
        for fig in (self.lin, self.log):
            fig.xaxis.axis_label = xlabel
        main = through if through is not None else clear
        px, py = ex.polar_lobe(x, main, curve, theta_i, psi)
        cx, cy = ex.polar_lobe(x, clear, curve, theta_i, psi)
        top = max(float(np.max(main)), 1e-300)
        ctop = max(float(np.max(clear)), 1e-300)
        self.src["polar"].data = {"x": px / top, "y": py / top, "x0": cx / ctop, "y0": cy / ctop}
        self.polar.title.text = "polar lobes, each to its peak"

    def draw_transmission(self, medium, theta_i) -> None:
        if medium is None:
            self.src["transmission"].data = {"x": [], "y": []}
            self.trans.title.text = "medium transmission lobe: no medium"
            return
        angle, value, _, _ = ex.transmission_lobe(medium, theta_i)
        radius = ex.log_radius(value, ex.LOBE_DECADES)
        rad = np.radians(angle)
        self.src["transmission"].data = {
            "x": radius * np.sin(rad),
            "y": radius * np.cos(rad),
            "angle": angle,
            "f": value,
        }
        self.trans.title.text = (
            f"f_t(I, w): peak {float(np.max(value)):.3g}, log radius ({ex.LOBE_DECADES:g} decades)"
        )

    def draw_sphere(self, image, accuracy) -> None:
        self.src["sphere"].data = {"image": [image], "accuracy": [accuracy]}
        self.sphere.title.text = f"lit sphere ({accuracy} accuracy)"

    def draw_state(self, state) -> None:
        self.src["state"].data = _state_columns(state)


class FitPlots:
    """The data panel of one fit result: data with error bars over the fitted model and its
    uncertainty band, the model of the current controls, residuals, parameters."""

    def __init__(self, view: fits.FitView, k: int):
        self.view = view
        tools = "pan,wheel_zoom,box_zoom,reset,save,hover"
        suffix = "" if k == 0 else f"-{k}"
        self.src_data = ColumnDataSource(name=SOURCES["data"] + suffix)
        self.src_fit = ColumnDataSource(name=SOURCES["fit"] + suffix)
        self.src_res = ColumnDataSource(name=SOURCES["residuals"] + suffix)
        self.src_band = ColumnDataSource()
        self.src_now = ColumnDataSource()
        self._fill_sources(view)
        self._figures(view, tools)
        self.points = None  # the current model's engine at the data's configurations

    def _fill_sources(self, view):
        """The data with error bars, the fitted model per group and its band, residuals."""
        o = view.order
        groups = sorted(set(view.group.tolist()))
        color = [COLORS[groups.index(g) % len(COLORS)] for g in view.group[o]]
        sigma = view.data.sigma[o] if view.data.sigma is not None else np.zeros(o.size)
        y = view.data.y[o]
        self.src_data.data = {
            "x": view.x[o],
            "y": y,
            "lower": y - sigma,
            "upper": y + sigma,
            "color": color,
            "group": view.group[o],
        }
        xs, ys, bx, by, cols = [], [], [], [], []
        for j, g in enumerate(groups):
            sel = o[view.group[o] == g]
            xs.append(view.x[sel])
            ys.append(view.fitted[sel])
            cols.append(COLORS[j % len(COLORS)])
            if view.band is not None:
                lo, hi = view.band
                bx.append(np.concatenate([view.x[sel], view.x[sel][::-1]]))
                by.append(np.concatenate([lo[sel], hi[sel][::-1]]))
        self.src_fit.data = {
            "xs": xs,
            "ys": ys,
            "color": cols,
            "group": [f"{view.group_label} = {g:g}" for g in groups],
        }
        self.src_band.data = {"xs": bx, "ys": by, "color": cols[: len(bx)]}
        self.src_res.data = {
            "x": view.x[o],
            "r": view.residuals[o],
            "now": view.residuals[o],
            "color": color,
        }
        self.groups, self.colors = groups, cols

    def _figures(self, view, tools):
        """The data over the fitted model (and the current controls'), the residuals."""
        r = view.result
        title = f"{os.path.basename(view.source)}: {r.model} ({r.step or 'fit'})"
        self.fig = figure(
            title=title,
            height=320,
            width=620,
            tools=tools,
            x_axis_label=view.xlabel,
            y_axis_label="value",
        )
        if view.band is not None:
            self.fig.patches(
                "xs",
                "ys",
                source=self.src_band,
                color="color",
                alpha=0.25,
                line_alpha=0,
                legend_label="95 % band (fit covariance)",
            )
        self.fig.multi_line(
            "xs",
            "ys",
            source=self.src_fit,
            color="color",
            line_width=2,
            legend_label="fitted model",
        )
        self.fig.multi_line(
            "xs",
            "ys",
            source=self.src_now,
            color="black",
            line_width=1,
            line_dash="dotted",
            legend_label="current controls",
        )
        self.fig.scatter("x", "y", source=self.src_data, color="color", size=4, legend_label="data")
        self.fig.add_layout(
            Whisker(base="x", lower="lower", upper="upper", source=self.src_data, line_color="gray")
        )
        self.fig.legend.click_policy = "hide"
        self.res = figure(
            title="residuals" + (" (weighted)" if r.weighted else ""),
            height=200,
            width=620,
            tools=tools,
            x_range=self.fig.x_range,
            x_axis_label=view.xlabel,
        )
        self.res.scatter("x", "r", source=self.src_res, color="color", size=4, legend_label="fit")
        self.res.scatter(
            "x",
            "now",
            source=self.src_res,
            color="black",
            marker="x",
            size=4,
            legend_label="current controls",
        )
        self.res.legend.click_policy = "hide"

    def table(self) -> str:
        rows = ["| parameter | value | stderr |", "|---|---:|---:|"]
        for row in self.view.param_rows():
            se = (
                "fixed"
                if row["fixed"]
                else "undetermined"
                if row["stderr"] is None
                else f"{row['stderr']:.3g}"
            )
            rows.append(f"| {row['parameter']} | {row['value']:.5g} | {se} |")
        r = self.view.result
        rows.append("")
        rows.append(
            f"chi2 reduced {r.chi2_reduced:.4g}, {r.n_points} points, "
            f"{'converged' if r.converged else 'NOT converged'}"
        )
        rows += fits.ranking_lines(r)
        return "\n".join(rows)

    def draw_current(self, brdf, medium) -> None:
        """The model of the current controls at the data's configurations."""
        view = self.view
        values = view.model_values(brdf, medium)
        o = view.order
        xs, ys = [], []
        for g in self.groups:
            sel = o[view.group[o] == g]
            xs.append(view.x[sel])
            ys.append(values[sel])
        self.src_now.data = {"xs": xs, "ys": ys}
        w = view.data.w if view.result.weighted else 1.0
        now = ((view.data.y - values) * w)[o]
        self.src_res.data = {**self.src_res.data, "now": now}


__all__ = ["Views", "FitPlots", "SOURCES", "VIEW_SOURCES", "COLORS"]
