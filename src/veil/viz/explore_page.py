"""The page of ``veil explore`` (docs/explore.md): Panel widgets and Bokeh plots around the
numbers of :mod:`veil.viz.explore`. No JavaScript of veil's own: Panel syncs the widgets
and the plots' data sources with the Python process (server) or embeds precomputed states
(``--static``).

The plots and their named data sources (:data:`SOURCES`, read back by the tests):
:mod:`veil.viz.explore_plots`.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractContextManager

import numpy as np
import panel as pn

from ..errors import InputError
from . import explore as ex
from .explore_colour import channel_selector, sphere_of
from .explore_plots import SOURCES, FitPlots, Views

NONE = "none (clear)"
CUSTOM = "(custom)"
#: Sphere image size (pixels) of the page.
SPHERE_SIZE = 96
#: Seconds the sliders must rest before the sphere is rendered again, and then before it
#: is refined (the refined render takes several seconds of both cores: it waits for a
#: pause, and a move during the wait cancels it).
SPHERE_DELAY = 0.25
REFINE_DELAY = 1.5


class Controls:
    """Widgets of one model kind built from the family's declaration: family, preset,
    options, one slider per parameter."""

    def __init__(self, page, kind: str, model):
        self.page, self.kind = page, kind
        names = ex.families(kind)
        options = names + ([NONE] if kind == "medium" else [])
        self.family = pn.widgets.Select(
            label=f"{'BRDF' if kind == 'brdf' else 'medium'} model",
            options=options,
            value=NONE if model is None else model.NAME,
        )
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
        self.preset = pn.widgets.Select(
            label="preset",
            options=[CUSTOM] + list(presets),
            value=next((k for k, m in presets.items() if m == model), CUSTOM),
        )
        self.preset.param.watch(self._on_preset, "value")
        items.append(self.preset)
        for opt in cls.OPTIONS:
            value = getattr(model, opt.name)
            if opt.choices:
                w = pn.widgets.Select(
                    label=opt.name, options={str(c): c for c in opt.choices}, value=value
                )
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
            s = pn.widgets.FloatSlider(
                label=spec.label,
                start=spec.start,
                end=spec.end,
                step=spec.step,
                value=spec.to_slider(getattr(model, p.name)),
                format="0[.]0000",
                sizing_mode="stretch_width",
            )
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
        self._pools = (
            {
                a: ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"sphere-{a}")
                for a in (ex.LIVE_ACCURACY, ex.REFINED_ACCURACY)
            }
            if background
            else None
        )
        self._lock = threading.Lock()
        self.status = pn.pane.Markdown("", sizing_mode="stretch_width")
        self.brdf = Controls(self, "brdf", state.brdf)
        self.medium = Controls(self, "medium", state.medium)
        self.theta_i = pn.widgets.FloatSlider(
            label="incidence theta_i (deg)",
            start=0.0,
            end=ex.MAX_ANGLE - 1.0,
            step=0.5,
            value=state.theta_i,
        )
        self.psi = pn.widgets.FloatSlider(
            label="psi, light-camera angle (deg)",
            start=0.0,
            end=2 * ex.MAX_ANGLE - 2.0,
            step=0.5,
            value=state.psi,
        )
        self.curve = pn.widgets.RadioButtonGroup(
            label="curve", options=list(ex.CURVES), value=state.curve
        )
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
            self.brdf.family,
            self.brdf.box,
            self.medium.family,
            self.medium.box,
            pn.pane.Markdown("**angles**"),
            self.curve,
            self.theta_i,
            self.psi,
            self.share,
            self.status,
            width=340,
        )
        views = pn.Column(
            pn.Row(pn.pane.Bokeh(self.views.lin), pn.pane.Bokeh(self.views.log)),
            pn.Row(
                pn.pane.Bokeh(self.views.polar),
                pn.pane.Bokeh(self.views.trans),
                pn.pane.Bokeh(self.views.sphere),
            ),
            pn.pane.Bokeh(self.views.state_fig),
        )
        for plots in self.views.fit:
            views.append(
                pn.Row(
                    pn.Column(pn.pane.Bokeh(plots.fig), pn.pane.Bokeh(plots.res)),
                    pn.pane.Markdown(plots.table(), width=300),
                )
            )
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
        self.state = ex.State(
            **{
                **self.state.__dict__,
                "theta_i": float(self.theta_i.value),
                "psi": float(self.psi.value),
                "curve": self.curve.value,
            }
        )
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
        self.views.draw_curves(
            self.curves.x, self.curves.xlabel, through, clear, s.curve, s.theta_i, s.psi
        )
        if self.views.channels is not None:
            self.views.channels.draw(self.curves, s.channels)
        if transmission:
            self.views.draw_transmission(s.medium, s.theta_i)
        for plots in self.views.fit:
            plots.draw_current(s.brdf, s.medium)
        self.views.draw_state(s)
        peak = through if through is not None else clear
        self.say(
            f"peak {float(np.max(peak)):.5g} at {self.curves.x[int(np.argmax(peak))]:g} deg"
            f" ({(time.perf_counter() - t0) * 1e3:.0f} ms)"
        )
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
                    self.doc.add_timeout_callback(
                        lambda: start(ex.REFINED_ACCURACY), int(1e3 * REFINE_DELAY)
                    )

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
