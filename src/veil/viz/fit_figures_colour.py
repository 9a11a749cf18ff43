"""The figure of a fit over several colour channels (docs/channels.md, "Figures"): the
data and the fitted curve of every channel in its colour (:func:`veil.viz.explore.
channel_colour`), one marker and line style per psi, over one panel of the relative
residuals (data - model) / model of every channel. As :func:`veil.viz.fit_figures.
fit_figure` draws a one-channel fit, whose layout and curve sampling it shares."""

from __future__ import annotations

import io

import numpy as np

from ..fitting import FitResult, model_values
from ..models import Model
from .explore import channel_colour
from .fit_figures import (
    CURVE_ACCURACY,
    LOG_RATIO,
    STEP_TITLES,
    _curve_rho,
    _goniometer,
    relative_residuals,
)

#: Marker and line style of each psi (in the order of the psi values).
PSI_STYLES = (("o", "-"), ("s", "--"), ("^", ":"), ("D", "-."), ("v", (0, (5, 1))))


def channel_fit_figure(
    datas: dict, result: FitResult, others: dict, extra: FitResult | None = None, dpi: int = 120
) -> bytes:
    """PNG of ``result``, a fit over the channels of ``datas`` ({channel: FitData}, in-plane
    goniometer data): ``others`` {channel: the model held fixed, None for f_r alone};
    ``extra`` (a result over the same channels) adds each channel's f_r as a thin dotted
    curve (the through-medium estimate on the direct fit's figure)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(7.0, 6.0), dpi=dpi)
    ax, res_ax = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": (3.2, 1.2)})
    handles, positive, shown = [], [], []
    for channel, data in datas.items():
        gonio = _goniometer(data)
        if gonio is None:
            raise ValueError("channel_fit_figure draws in-plane data; a row is out of the plane")
        colour = channel_colour(channel)
        model = result.as_model(channel=channel)
        other = others[channel]
        estimate = None if extra is None else extra.as_model(channel=channel)
        _channel_curves(ax, data, gonio, model, other, estimate, colour)
        fitted = model_values(model, other, data.angles, result.accuracy or "default")
        rel, _ = relative_residuals(data.y, fitted, data.sigma)
        psi, _, tr = gonio
        for k, p in enumerate(np.unique(psi)):
            sel = psi == p
            res_ax.plot(
                tr[sel], 100.0 * rel[sel], PSI_STYLES[k % len(PSI_STYLES)][0], ms=2.5, color=colour
            )
        shown.append(100.0 * rel[np.isfinite(rel)])
        positive.append(data.y[data.y > 0])
        handles.append(Line2D([], [], color=colour, lw=1.5, label=f"channel {channel}"))
    psis = np.unique(_goniometer(next(iter(datas.values())))[0])
    handles += [
        Line2D([], [], color="0.3", marker=m, ls=ls, ms=3, lw=1.0, label=f"psi = {p:g}°")
        for p, (m, ls) in zip(psis, PSI_STYLES)
    ]
    if extra is not None:
        handles.append(
            Line2D(
                [],
                [],
                color="0.3",
                lw=0.8,
                ls=(0, (1, 1)),
                label="f_r estimated through the medium (step 2)",
            )
        )
    _axes(ax, res_ax, np.concatenate(positive), np.concatenate(shown))
    title = STEP_TITLES.get(result.step or "", result.model)
    ax.set_title(f"{title}, channels {', '.join(datas)}", fontsize=10)
    ax.legend(handles=handles, fontsize=7.5, loc="best", framealpha=0.8, ncol=2)
    fig.align_ylabels((ax, res_ax))
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _channel_curves(ax, data, gonio, model: Model, other, estimate, colour: str) -> None:
    """One channel's data (sigma bars) and fitted curves, one style per psi."""
    from ..engine.angles import from_signed_inplane

    psi, rho, tr = gonio
    for k, p in enumerate(np.unique(psi)):
        marker, style = PSI_STYLES[k % len(PSI_STYLES)]
        sel = psi == p
        order = np.argsort(tr[sel])
        yerr = data.sigma[sel][order] if data.sigma is not None else None
        ax.errorbar(
            tr[sel][order],
            data.y[sel][order],
            yerr=yerr,
            fmt=marker,
            ms=3,
            color=colour,
            elinewidth=0.8,
            capsize=0,
            alpha=0.8,
        )
        r = _curve_rho(rho[sel].min(), rho[sel].max())
        angles = from_signed_inplane(p / 2 + r, p / 2 - r)
        ax.plot(
            p / 2 - r,
            model_values(model, other, angles, CURVE_ACCURACY),
            ls=style,
            color=colour,
            lw=1.2,
        )
        if estimate is not None:
            ax.plot(
                p / 2 - r,
                model_values(estimate, None, angles),
                ls=(0, (1, 1)),
                color=colour,
                lw=0.8,
            )


def _axes(ax, res_ax, positive: np.ndarray, residuals_pct: np.ndarray) -> None:
    """Scales, limits and labels of the two panels."""
    if positive.size and positive.max() > LOG_RATIO * np.median(positive):
        ax.set_yscale("log")
        ax.set_ylim(bottom=max(positive.min() * 0.5, positive.max() * 1e-6))
    ax.set_ylabel("observed value [relative units, 1/sr]")
    ax.grid(True, which="major", alpha=0.3)
    ax.tick_params(labelbottom=False)
    if residuals_pct.size:
        half = 1.1 * max(float(np.percentile(np.abs(residuals_pct), 99.0)), 1e-6)
        res_ax.set_ylim(-half, half)
    res_ax.axhline(0.0, color="0.4", lw=0.8)
    res_ax.set_title("relative residual (data - model) / model", fontsize=8, loc="left")
    res_ax.set_ylabel("residual [%]", fontsize=9)
    res_ax.set_xlabel("reflection angle theta_r [deg] (signed, in the plane of incidence)")
    res_ax.grid(True, which="major", alpha=0.3)
    res_ax.tick_params(labelsize=8)


__all__ = ["channel_fit_figure", "PSI_STYLES"]
