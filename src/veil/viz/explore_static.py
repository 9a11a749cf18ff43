"""`veil explore --static` (docs/explore.md): the page of :mod:`veil.viz.explore_page` with
its states precomputed over one parameter's slider, saved as one file that needs no server."""

from __future__ import annotations

from typing import Any

import numpy as np
import panel as pn

from ..errors import InputError
from . import explore as ex
from .explore_page import SPHERE_SIZE
from .explore_plots import Views


def grid_values(spec: ex.SliderSpec, value: float, points: int) -> list[float]:
    """``points`` parameter values over the slider's range (log-spaced for log sliders),
    the current value among them."""
    xs = np.linspace(spec.start, spec.end, points)
    xs[int(np.argmin(np.abs(xs - spec.to_slider(value))))] = spec.to_slider(value)
    return [float(f"{spec.to_value(x):.6g}") for x in xs]


def static_page(
    state: ex.State, param: str, points: int, fit_views=(), progress=None
) -> tuple[pn.Column, list[float]]:
    """A self-contained page (no server): the curves, lobes and sphere precomputed for
    ``points`` values of one parameter (``kind.name`` or a name unique to one model),
    switched by a slider (Panel embeds every state in the page)."""
    kind, cls, name = _find_param(state, param)
    model = getattr(state, kind)
    spec = ex.slider_spec(cls, name, getattr(model, name))
    values = grid_values(spec, getattr(model, name), points)
    frames: dict[Any, dict[str, Any]] = {}
    views = Views(fit_views)
    for k, v in enumerate(values):
        m = model.replace(**{name: v})
        st = state.with_model(m, kind)
        curves = ex.Curves(st.brdf, st.medium, st.curve, st.theta_i, st.psi)
        through, clear = curves.through(st.brdf, st.medium), curves.clear(st.brdf)
        image, _ = ex.sphere(st.brdf, st.medium, st.theta_i, SPHERE_SIZE, ex.LIVE_ACCURACY)
        views.draw_curves(curves.x, curves.xlabel, through, clear, st.curve, st.theta_i, st.psi)
        views.draw_transmission(st.medium, st.theta_i)
        views.draw_sphere(image, ex.LIVE_ACCURACY)
        views.draw_state(st)
        for plots in views.fit:
            plots.draw_current(st.brdf, st.medium)
        frames[v] = {key: dict(src.data) for key, src in views.src.items()}
        frames[v]["_fit"] = [(dict(p.src_now.data), dict(p.src_res.data)) for p in views.fit]
        if progress:
            progress(k + 1, len(values))
    slider = pn.widgets.DiscreteSlider(
        label=f"{kind} {name}",
        options=values,
        value=values[int(np.argmin([abs(x - getattr(model, name)) for x in values]))],
    )

    def apply(value):
        frame = frames[value]
        for key, src in views.src.items():
            src.data = frame[key]
        for p, (now, res) in zip(views.fit, frame["_fit"]):
            p.src_now.data, p.src_res.data = now, res

    slider.param.watch(lambda event: apply(event.new), "value")
    apply(slider.value)
    other = "; ".join(
        f"{m.NAME}: " + ", ".join(f"{k} = {v:.4g}" for k, v in m.as_dict().items())
        for m in (state.brdf, state.medium)
        if m is not None
    )
    header = pn.pane.Markdown(
        f"### veil explore (static page)\n{other}\n\nincidence {state.theta_i:g} deg, psi "
        f"{state.psi:g} deg, curve: {state.curve}. The slider switches between precomputed "
        f"states of **{name}** ({kind}); run `veil explore` for every control."
    )
    body = pn.Column(
        header,
        slider,
        pn.Row(pn.pane.Bokeh(views.lin), pn.pane.Bokeh(views.log)),
        pn.Row(pn.pane.Bokeh(views.polar), pn.pane.Bokeh(views.trans), pn.pane.Bokeh(views.sphere)),
        pn.pane.Bokeh(views.state_fig),
    )
    for plots in views.fit:
        body.append(
            pn.Row(
                pn.Column(pn.pane.Bokeh(plots.fig), pn.pane.Bokeh(plots.res)),
                pn.pane.Markdown(plots.table(), width=300),
            )
        )
    return body, values


def _find_param(state: ex.State, param: str):
    """(kind, family, declared name) of ``param``: "brdf.NAME", "medium.NAME" or a name (or
    alias) of exactly one of the two models."""
    kinds = [k for k in ("brdf", "medium") if getattr(state, k) is not None]
    head, dot, tail = param.partition(".")
    if dot and head in kinds:
        kinds, param = [head], tail
    found = []
    for kind in kinds:
        cls = type(getattr(state, kind))
        try:
            found.append((kind, cls, cls.param(param).name))
        except InputError:
            pass
    if len(found) == 1:
        return found[0]
    known = [f"{k}.{n}" for k in kinds for n in type(getattr(state, k)).param_names()]
    if not found:
        raise InputError(
            f"--param {param!r} is not a parameter of the page's models; known: {', '.join(known)}"
        )
    raise InputError(
        f"--param {param!r} names a parameter of both models: write "
        f"{' or '.join(f'{k}.{param}' for k, _, _ in found)}"
    )


def save_static(body, path) -> None:
    """Write the self-contained page (every resource inline) atomically."""
    import io as _io

    from bokeh.resources import INLINE

    from ..io import write_text_atomic

    buffer = _io.StringIO()
    body.save(
        buffer,
        embed=True,
        resources=INLINE,
        title="veil explore",
        max_states=10000,
        max_opts=10000,
        progress=False,
    )
    write_text_atomic(path, buffer.getvalue())


__all__ = ["grid_values", "static_page", "save_static"]
