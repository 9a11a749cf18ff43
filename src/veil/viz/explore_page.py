"""The page of ``veil explore`` (docs/explore.md): Panel widgets and Bokeh plots around the
numbers of :mod:`veil.viz.explore`. No JavaScript of veil's own: Panel syncs the widgets
and the plots' data sources with the Python process (server) or embeds precomputed states
(``--static``).

Every plotted data source has a name ``veil-...`` (see :data:`SOURCES`) so that tests can
read the plotted numbers back from the browser (``Bokeh.documents[0].get_model_by_name``).
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractContextManager

import numpy as np
import panel as pn
from bokeh.models import ColumnDataSource, DataRange1d, LinearAxis
from bokeh.models.annotations import Whisker
from bokeh.plotting import figure

from ..errors import InputError
from . import explore as ex
from . import explore_fits as fits
from .explore_colour import ChannelLines, channel_selector, sphere_of

#: Names of the plotted data sources (the page's readable contract with its tests).
SOURCES = {
    "medium": "veil-curve-medium",      # x, y: apparent reflectance along the curve
    "clear": "veil-curve-clear",        # x, y: f_r along the curve
    "polar": "veil-polar",              # x, y (and the clear lobe x0, y0)
    "transmission": "veil-transmission",  # x, y: f_t lobe
    "sphere": "veil-sphere",            # image, accuracy
    "state": "veil-state",              # key, value: the page's state, flattened
    "data": "veil-fit-data",
    "fit": "veil-fit-model",
    "residuals": "veil-fit-residuals",
}
#: The sources of the main views (the fit panels have their own).
VIEW_SOURCES = ("medium", "clear", "polar", "transmission", "sphere", "state")
NONE = "none (clear)"
CUSTOM = "(custom)"
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
          "#17becf")
#: Sphere image size (pixels) of the page.
SPHERE_SIZE = 96
#: Seconds the sliders must rest before the sphere is rendered again, and then before it
#: is refined (the refined render takes several seconds of both cores: it waits for a
#: pause, and a move during the wait cancels it).
SPHERE_DELAY = 0.25
REFINE_DELAY = 1.5


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
        self.src["sphere"].data = {"image": [np.zeros((2, 2), dtype=np.uint32)],
                                   "accuracy": [""]}
        self.src["state"].data = {"key": [], "value": []}
        self.lin = figure(title="in-plane curve", height=300, width=460, tools=tools,
                          y_axis_label="f (1/sr)")
        self.log = figure(title="in-plane curve (log)", height=300, width=460, tools=tools,
                          y_axis_type="log", y_axis_label="f (1/sr)")
        # linear: the two curves differ by orders of magnitude, so f_r has its own axis
        through = self.lin.line("x", "y", source=self.src["medium"], line_width=2,
                                color=COLORS[0], legend_label="through the medium")
        self.lin.y_range = DataRange1d(renderers=[through])
        self.lin.extra_y_ranges = {"clear": DataRange1d()}
        clear = self.lin.line("x", "y", source=self.src["clear"], line_width=1.5,
                              color=COLORS[1], line_dash="dashed", y_range_name="clear",
                              legend_label="without medium (right axis)")
        self.lin.extra_y_ranges["clear"].renderers = [clear]
        self.lin.add_layout(LinearAxis(y_range_name="clear", axis_label="f_r (1/sr)",
                                       axis_label_text_color=COLORS[1]), "right")
        self.lin.yaxis[0].axis_label_text_color = COLORS[0]
        self.log.line("x", "ylog", source=self.src["medium"], line_width=2, color=COLORS[0],
                      legend_label="through the medium")
        self.log.line("x", "ylog", source=self.src["clear"], line_width=1.5, color=COLORS[1],
                      line_dash="dashed", legend_label="without medium")
        for fig in (self.lin, self.log):
            fig.legend.location = "top_left"
            fig.legend.click_policy = "hide"
        self.polar = figure(title="polar lobe (plane of incidence)", height=300, width=300,
                            match_aspect=True, tools=tools)
        self.polar.line("x", "y", source=self.src["polar"], line_width=2, color=COLORS[0])
        self.polar.line("x0", "y0", source=self.src["polar"], color=COLORS[1],
                        line_dash="dashed")
        self.trans = figure(title="medium transmission lobe f_t(I, w)", height=300, width=300,
                            match_aspect=True, tools=tools)
        self.trans.line("x", "y", source=self.src["transmission"], line_width=2,
                        color=COLORS[2])
        self.sphere = figure(title="lit sphere", height=300, width=300, tools="",
                             x_range=(0, 1), y_range=(0, 1), toolbar_location=None)
        self.sphere.image_rgba(image="image", x=0, y=0, dw=1, dh=1, source=self.src["sphere"])
        self.sphere.axis.visible = False
        self.sphere.grid.visible = False
        # the state, readable from the page (not drawn)
        self.state_fig = figure(height=10, width=10, toolbar_location=None, visible=False)
        self.state_fig.scatter(x="value", y="key", source=self.src["state"], visible=False)
        self.fit = [FitPlots(v, k) for k, v in enumerate(fit_views)]
        self.channels = None if channels is None else ChannelLines(self.lin, self.log, channels)

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
        self.src["polar"].data = {"x": px / top, "y": py / top, "x0": cx / ctop,
                                  "y0": cy / ctop}
        self.polar.title.text = "polar lobes, each to its peak"

    def draw_transmission(self, medium, theta_i) -> None:
        if medium is None:
            self.src["transmission"].data = {"x": [], "y": []}
            self.trans.title.text = "medium transmission lobe: no medium"
            return
        angle, value, _, _ = ex.transmission_lobe(medium, theta_i)
        radius = ex.log_radius(value, ex.LOBE_DECADES)
        rad = np.radians(angle)
        self.src["transmission"].data = {"x": radius * np.sin(rad), "y": radius * np.cos(rad),
                                         "angle": angle, "f": value}
        self.trans.title.text = (f"f_t(I, w): peak {float(np.max(value)):.3g}, log radius "
                                 f"({ex.LOBE_DECADES:g} decades)")

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
        o = view.order
        groups = sorted(set(view.group.tolist()))
        color = [COLORS[groups.index(g) % len(COLORS)] for g in view.group[o]]
        sigma = view.data.sigma[o] if view.data.sigma is not None else np.zeros(o.size)
        y = view.data.y[o]
        self.src_data.data = {"x": view.x[o], "y": y, "lower": y - sigma, "upper": y + sigma,
                              "color": color, "group": view.group[o]}
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
        self.src_fit.data = {"xs": xs, "ys": ys, "color": cols,
                             "group": [f"{view.group_label} = {g:g}" for g in groups]}
        self.src_band.data = {"xs": bx, "ys": by, "color": cols[: len(bx)]}
        self.src_res.data = {"x": view.x[o], "r": view.residuals[o], "now": view.residuals[o],
                             "color": color}
        self.groups, self.colors = groups, cols
        r = view.result
        title = f"{os.path.basename(view.source)}: {r.model} ({r.step or 'fit'})"
        self.fig = figure(title=title, height=320, width=620, tools=tools,
                          x_axis_label=view.xlabel, y_axis_label="value")
        if view.band is not None:
            self.fig.patches("xs", "ys", source=self.src_band, color="color", alpha=0.25,
                             line_alpha=0, legend_label="95 % band (fit covariance)")
        self.fig.multi_line("xs", "ys", source=self.src_fit, color="color", line_width=2,
                            legend_label="fitted model")
        self.fig.multi_line("xs", "ys", source=self.src_now, color="black", line_width=1,
                            line_dash="dotted", legend_label="current controls")
        self.fig.scatter("x", "y", source=self.src_data, color="color", size=4,
                         legend_label="data")
        self.fig.add_layout(Whisker(base="x", lower="lower", upper="upper",
                                    source=self.src_data, line_color="gray"))
        self.fig.legend.click_policy = "hide"
        self.res = figure(title="residuals" + (" (weighted)" if r.weighted else ""),
                          height=200, width=620, tools=tools, x_range=self.fig.x_range,
                          x_axis_label=view.xlabel)
        self.res.scatter("x", "r", source=self.src_res, color="color", size=4,
                         legend_label="fit")
        self.res.scatter("x", "now", source=self.src_res, color="black", marker="x", size=4,
                         legend_label="current controls")
        self.res.legend.click_policy = "hide"
        self.points = None  # the current model's engine at the data's configurations

    def table(self) -> str:
        rows = ["| parameter | value | stderr |", "|---|---:|---:|"]
        for row in self.view.param_rows():
            se = ("fixed" if row["fixed"] else "undetermined" if row["stderr"] is None
                  else f"{row['stderr']:.3g}")
            rows.append(f"| {row['parameter']} | {row['value']:.5g} | {se} |")
        r = self.view.result
        rows.append("")
        rows.append(f"chi2 reduced {r.chi2_reduced:.4g}, {r.n_points} points, "
                    f"{'converged' if r.converged else 'NOT converged'}")
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


class Controls:
    """Widgets of one model kind built from the family's declaration: family, preset,
    options, one slider per parameter."""

    def __init__(self, page, kind: str, model):
        self.page, self.kind = page, kind
        names = ex.families(kind)
        options = names + ([NONE] if kind == "medium" else [])
        self.family = pn.widgets.Select(label=f"{'BRDF' if kind == 'brdf' else 'medium'} model",
                                        options=options,
                                        value=NONE if model is None else model.NAME)
        self.family.param.watch(self._on_family, "value")
        self.box = pn.Column(sizing_mode="stretch_width")
        self.model = model
        self._build()

    def _build(self):
        model = self.model
        self.sliders, self.option_widgets = {}, {}
        items = []
        if model is None:
            self.preset = None
            self.box.objects = [pn.pane.Markdown("clear: no medium")]
            return
        cls = type(model)
        presets = ex.presets_of(cls)
        self.preset = pn.widgets.Select(label="preset", options=[CUSTOM] + list(presets),
                                        value=next((k for k, m in presets.items() if m == model),
                                                   CUSTOM))
        self.preset.param.watch(self._on_preset, "value")
        items.append(self.preset)
        for opt in cls.OPTIONS:
            value = getattr(model, opt.name)
            if opt.choices:
                w = pn.widgets.Select(label=opt.name, options={str(c): c for c in opt.choices},
                                      value=value)
            elif isinstance(opt.default, bool):
                w = pn.widgets.Checkbox(label=opt.name, value=value)
            elif isinstance(opt.default, (int, float)):
                w = pn.widgets.FloatInput(label=opt.name, value=float(value))
            else:
                w = pn.widgets.TextInput(label=opt.name, value=str(value))
            w.param.watch(self._on_option, "value")
            self.option_widgets[opt.name] = w
            items.append(w)
        for p in cls.PARAMS:
            spec = ex.slider_spec(cls, p.name, getattr(model, p.name))
            s = pn.widgets.FloatSlider(label=spec.label, start=spec.start, end=spec.end,
                                       step=spec.step, value=spec.to_slider(getattr(model, p.name)),
                                       format="0[.]0000", sizing_mode="stretch_width")
            s.param.watch(self._on_slider, "value")
            s.param.watch(self.page.on_rest, "value_throttled")
            self.sliders[p.name] = (s, spec)
            items.append(s)
        self.readout = pn.pane.Markdown(self._readout(), sizing_mode="stretch_width")
        items.append(self.readout)
        self.box.objects = items

    def show(self, model) -> None:
        """Show ``model`` (another channel's, of the same family) without changing it."""
        self.model = model
        self._build()

    def _readout(self) -> str:
        m = self.model
        if m is None:
            return ""
        return ", ".join(f"{k} = {v:.4g}" for k, v in m.as_dict().items())

    def _set(self, model, sphere: bool = False):
        self.model = model
        self.page.model_changed(self.kind, model, sphere)

    def _on_family(self, event):
        if event.new == NONE:
            model = None
        else:
            cls = ex.model_class(event.new, self.kind)
            found = ex.presets_of(cls)
            model = next(iter(found.values())) if found else cls.template()
        self.model = model
        self._build()
        self._set(model, sphere=True)

    def _on_preset(self, event):
        if event.new == CUSTOM or self.page.updating:
            return
        model = ex.presets_of(type(self.model))[event.new]
        self.model = model
        with self.page.hold():
            for name, (s, spec) in self.sliders.items():
                s.value = spec.to_slider(getattr(model, name))
        self.readout.object = self._readout()
        self._set(model, sphere=True)

    def _on_option(self, event):
        options = {k: w.value for k, w in self.option_widgets.items()}
        try:
            model = type(self.model).from_params(self.model.as_dict(), options)
        except InputError as exc:
            self.page.say(f"**{exc}**")
            return
        self._set(model, sphere=True)

    def _on_slider(self, event):
        if self.page.updating:
            return
        params = {n: spec.to_value(s.value) for n, (s, spec) in self.sliders.items()}
        try:
            model = type(self.model).from_params(params, self.model.options())
        except InputError as exc:
            self.page.say(f"**{exc}**")
            return
        if self.preset is not None and self.preset.value != CUSTOM:
            self.page.updating = True
            try:
                self.preset.value = CUSTOM
            finally:
                self.page.updating = False
        self.readout.object = self._readout()
        self._set(model)


class ExplorePage:
    """The page: controls, views, the fit panels, the share button."""

    def __init__(self, state: ex.State, fit_views=(), share_dir=".", background=True):
        self.state = state
        self.share_dir = os.fspath(share_dir)
        self.updating = False
        self._held = False
        self.curves: ex.Curves | None = None
        self.timings: dict[str, float] = {}
        self.views = Views(fit_views, state.channels)
        self.doc = pn.state.curdoc if background else None
        self._sphere_gen = 0
        self._pending, self._scheduled = (False, False), False
        self._pools = ({a: ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"sphere-{a}")
                        for a in (ex.LIVE_ACCURACY, ex.REFINED_ACCURACY)}
                       if background else None)
        self._lock = threading.Lock()
        self.status = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.brdf = Controls(self, "brdf", state.brdf)
        self.medium = Controls(self, "medium", state.medium)
        self.theta_i = pn.widgets.FloatSlider(label="incidence theta_i (deg)", start=0.0,
                                              end=ex.MAX_ANGLE - 1.0, step=0.5,
                                              value=state.theta_i)
        self.psi = pn.widgets.FloatSlider(label="psi, light-camera angle (deg)", start=0.0,
                                          end=2 * ex.MAX_ANGLE - 2.0, step=0.5, value=state.psi)
        self.curve = pn.widgets.RadioButtonGroup(label="curve", options=list(ex.CURVES),
                                                 value=state.curve)
        for w in (self.theta_i, self.psi, self.curve):
            w.param.watch(self._on_angles, "value")
        self.theta_i.param.watch(self.on_rest, "value_throttled")
        self.channel = None if state.channels is None else channel_selector(self)
        self.share = pn.widgets.Button(label="share: write this state", color="primary")
        self.share.on_click(self._share)
        self.redraw(sphere=False)
        self._sphere_now()
        if background:
            # once the browser has the page, send it the same curves again: the first
            # update a browser applies is its slowest (measured 310-370 ms against 110-135
            # for later ones, docs/explore.md), so it should not be the user's first move
            pn.state.onload(lambda: self.redraw(transmission=False, sphere=False))

    # -- layout ----------------------------------------------------------------------------
    def layout(self) -> pn.Row:
        controls = pn.Column(
            pn.pane.Markdown("### veil explore"),
            *([] if self.channel is None else [pn.pane.Markdown("**channel**"), self.channel]),
            self.brdf.family, self.brdf.box, self.medium.family, self.medium.box,
            pn.pane.Markdown("**angles**"), self.curve, self.theta_i, self.psi,
            self.share, self.status, width=340)
        views = pn.Column(
            pn.Row(pn.pane.Bokeh(self.views.lin), pn.pane.Bokeh(self.views.log)),
            pn.Row(pn.pane.Bokeh(self.views.polar), pn.pane.Bokeh(self.views.trans),
                   pn.pane.Bokeh(self.views.sphere)),
            pn.pane.Bokeh(self.views.state_fig))
        for plots in self.views.fit:
            views.append(pn.Row(pn.Column(pn.pane.Bokeh(plots.fig), pn.pane.Bokeh(plots.res)),
                                pn.pane.Markdown(plots.table(), width=300)))
        return pn.Row(controls, views)

    # -- events ----------------------------------------------------------------------------
    def hold(self) -> AbstractContextManager[None]:
        page = self

        class _Hold:
            def __enter__(self):
                page.updating = True

            def __exit__(self, *exc):
                page.updating = False

        return _Hold()

    def say(self, text: str) -> None:
        self.status.object = text

    def model_changed(self, kind: str, model, sphere: bool = False) -> None:
        """A model changed: redraw the curves now, the sphere when asked (family, preset,
        option; a slider asks when it rests, :meth:`on_rest`)."""
        self.state = self.state.with_model(model, kind)
        self.request_redraw(transmission=(kind == "medium"), sphere=sphere)

    def _on_angles(self, event):
        self.state = ex.State(**{**self.state.__dict__, "theta_i": float(self.theta_i.value),
                                 "psi": float(self.psi.value), "curve": self.curve.value})
        # psi and the curve's axis do not change the sphere; theta_i (its light) does,
        # when that slider rests
        self.request_redraw(transmission=True, sphere=False)

    def on_rest(self, event=None) -> None:
        """Sliders at rest: render the sphere (live accuracy, then refined)."""
        self.schedule_sphere()

    # -- drawing ---------------------------------------------------------------------------
    def request_redraw(self, transmission=True, sphere=False) -> None:
        """Redraw for the latest state: at once without a server; on the server at the
        loop's next turn, so that the values a dragged slider sends in a burst cost one
        redraw, not one each."""
        self._sphere_gen += 1  # the state changed: a pending or running sphere is stale
        if self.doc is None:
            self.redraw(transmission, sphere)
            return
        self._pending = (self._pending[0] or transmission, self._pending[1] or sphere)
        if not self._scheduled:
            self._scheduled = True
            self.doc.add_next_tick_callback(self._flush)

    def _flush(self):
        self._scheduled = False
        transmission, sphere = self._pending
        self._pending = (False, False)
        self.redraw(transmission, sphere)

    def redraw(self, transmission=True, sphere=False) -> None:
        t0 = time.perf_counter()
        s = self.state
        key = ex.Curves.key_of(s.brdf, s.medium, s.curve, s.theta_i, s.psi)
        if self.curves is None or self.curves.key != key:
            self.curves = ex.Curves(s.brdf, s.medium, s.curve, s.theta_i, s.psi)
        try:
            through = self.curves.through(s.brdf, s.medium)
            clear = self.curves.clear(s.brdf)
        except InputError as exc:
            self.say(f"**{exc}**")
            return
        self.views.draw_curves(self.curves.x, self.curves.xlabel, through, clear, s.curve,
                               s.theta_i, s.psi)
        if self.views.channels is not None:
            self.views.channels.draw(self.curves, s.channels)
        if transmission:
            self.views.draw_transmission(s.medium, s.theta_i)
        for plots in self.views.fit:
            plots.draw_current(s.brdf, s.medium)
        self.views.draw_state(s)
        peak = through if through is not None else clear
        self.say(f"peak {float(np.max(peak)):.5g} at {self.curves.x[int(np.argmax(peak))]:g} deg"
                 f" ({(time.perf_counter() - t0) * 1e3:.0f} ms)")
        self.timings["curves"] = time.perf_counter() - t0
        if sphere:
            self.schedule_sphere()

    def _render(self, state, accuracy):
        t0 = time.perf_counter()
        image, _ = sphere_of(state, SPHERE_SIZE, accuracy)
        return image, time.perf_counter() - t0

    def _sphere_now(self):
        image, dt = self._render(self.state, ex.LIVE_ACCURACY)
        self.views.draw_sphere(image, ex.LIVE_ACCURACY)
        self.timings["sphere"] = dt

    def schedule_sphere(self) -> None:
        """Render the sphere at the live accuracy once the sliders rested
        :data:`SPHERE_DELAY` s, then at the refined accuracy after :data:`REFINE_DELAY` s
        more. The waits are timers of the server's loop and a newer state cancels what has
        not started; live and refined renders run on workers of their own, so a live one
        never waits for a refined one (a stale result is dropped)."""
        self._sphere_gen += 1
        gen = self._sphere_gen
        if self._pools is None or self.doc is None:
            self._sphere_now()
            return
        state = self.state

        def render(accuracy):
            if gen != self._sphere_gen:
                return
            try:
                image, dt = self._render(state, accuracy)
            except Exception as exc:
                message = f"**sphere: {exc}**"
                self.doc.add_next_tick_callback(lambda: self.say(message))
                return

            def show():
                if gen != self._sphere_gen:
                    return
                self.views.draw_sphere(image, accuracy)
                self.timings[f"sphere {accuracy}"] = dt
                if accuracy == ex.LIVE_ACCURACY:
                    self.doc.add_timeout_callback(lambda: start(ex.REFINED_ACCURACY),
                                                  int(1e3 * REFINE_DELAY))
            self.doc.add_next_tick_callback(show)

        def start(accuracy):
            if gen == self._sphere_gen:
                self._pools[accuracy].submit(render, accuracy)

        self.doc.add_timeout_callback(lambda: start(ex.LIVE_ACCURACY), int(1e3 * SPHERE_DELAY))

    def _share(self, event) -> None:
        """The share button's callback (panel wants one that returns None)."""
        self.on_share(event)

    def on_share(self, event=None) -> str | None:
        """Write the state as JSON into the share folder; ``veil explore FILE`` reopens it."""
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = os.path.join(self.share_dir, f"veil-explore-{stamp}.json")
        k = 1
        while os.path.exists(path):
            path = os.path.join(self.share_dir, f"veil-explore-{stamp}-{k}.json")
            k += 1
        try:
            self.state.save(path)
        except (InputError, OSError) as exc:
            self.say(f"**could not write the state: {exc}**")
            return None
        self.say(f"wrote {path}; reopen it with `veil explore {path}`")
        return path


__all__ = ["ExplorePage", "Views", "FitPlots", "Controls", "SOURCES"]
