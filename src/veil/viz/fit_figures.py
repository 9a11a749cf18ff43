"""Figures of fits: the data with the fitted curves of a step (:func:`fit_figure`, used by
the pipeline and ``veil fit``), and the identifiability diagnostics (:func:`diagnosis_figure`:
the correlation matrix and the profile likelihoods, ``veil diagnose``)."""

from __future__ import annotations

import io
import math

import numpy as np

from ..engine.angles import from_signed_inplane, to_goniometer, to_signed_inplane
from ..fitting import FitResult, model_values
from ..fitting.problem import ITERATION_ACCURACY
from ..io import write_bytes_atomic
from ..models import Model

#: A curve gets a logarithmic axis when its peak exceeds its median by this factor.
LOG_RATIO = 30.0
#: Quadrature of the drawn curves (a few hundred configurations a figure): the fits'
#: iteration rule. It differs from "default" by at most 0.3 % of a curve's maximum for the
#: paper's presets (a pixel at most on these figures) at a tenth of the cost; the fits'
#: numbers stay at the requested accuracy.
CURVE_ACCURACY = ITERATION_ACCURACY
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#6a3d9a", "#8c564b")


# --------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------
#: The title of each step's figure.
STEP_TITLES = {
    "reference": "Step 0: reference object, clear medium (f_r)",
    "medium": "Step 1: reference object through the medium (f_t fitted)",
    "target": "Step 2: target object through the medium (f_r fitted)",
    "direct": "Target object, clear medium: direct fit and estimate",
}


def _goniometer(data):
    """(psi, rho, signed theta_r) of in-plane data, or None if a row is out of the plane."""
    try:
        ti, tr = to_signed_inplane(*data.angles)
    except ValueError:
        return None
    psi, rho = to_goniometer(ti, tr)
    return np.round(psi, 6), rho, tr


def _curve_rho(rho_min, rho_max):
    fine = np.arange(-12.0, 12.0 + 1e-9, 0.5)
    coarse = np.arange(math.floor(rho_min), math.ceil(rho_max) + 1e-9, 2.0)
    rho = np.union1d(fine, coarse)
    return rho[(rho >= rho_min - 1e-9) & (rho <= rho_max + 1e-9)]


def fit_figure(
    data, result: FitResult, other: Model | None, extra: FitResult | None = None, dpi: int = 120
) -> bytes:
    """PNG: data (markers, sigma bars) and fitted curves against theta_r, one colour per psi,
    over a panel of the relative residuals (data - model) / model with the fit's model-error
    band (+-2 s, when the fit has a term), where a trend in the angles shows. ``other`` is the
    model held fixed (None for f_r alone); ``extra`` adds a dashed f_r curve (the
    through-medium estimate on the direct fit's figure). Out-of-plane data are drawn as model
    against data instead, without the panel.
    """
    from matplotlib.figure import Figure

    gonio = _goniometer(data)
    fig = Figure(figsize=(7.0, 4.6 if gonio is None else 5.8), dpi=dpi)
    if gonio is None:
        ax, res_ax = fig.add_subplot(), None
    else:
        ax, res_ax = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": (3.2, 1.0)})
    accuracy = result.accuracy or "default"
    if gonio is None:
        _model_against_data(ax, data, model_values(result, other, data.angles, accuracy))
    else:
        _curves_and_residuals(fig, ax, res_ax, data, gonio, result, other, extra, accuracy)
    ax.set_title(STEP_TITLES.get(result.step or "", result.model), fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    return buf.getvalue()


def _model_against_data(ax, data, model) -> None:
    """Out-of-plane data: the model's value against the measured one."""
    y = data.y
    ax.plot(model, y, "o", ms=3, color=COLORS[0])
    lo, hi = min(np.min(y), np.min(model)), max(np.max(y), np.max(model))
    if lo > 0:
        ax.set_xscale("log")
        ax.set_yscale("log")
    ax.plot([lo, hi], [lo, hi], "-", color="0.5", lw=1)
    ax.set_xlabel("fitted model value [relative units, 1/sr]")
    ax.set_ylabel("measured value [relative units, 1/sr]")


def _curves_and_residuals(fig, ax, res_ax, data, gonio, result, other, extra, accuracy) -> None:
    """Goniometer data: the data and the fitted curves per psi, the residual panel below."""
    y = data.y
    psi, rho, tr = gonio
    curves = []
    for k, p in enumerate(np.unique(psi)):
        sel = psi == p
        r = _curve_rho(rho[sel].min(), rho[sel].max())
        ti_c, tr_c = p / 2 + r, p / 2 - r
        curves.append((k, p, sel, tr_c, ti_c))
    all_ti = np.concatenate([c[4] for c in curves])
    all_tr = np.concatenate([c[3] for c in curves])
    angles_c = from_signed_inplane(all_ti, all_tr)
    angles_c = (angles_c[0], angles_c[1], angles_c[2], angles_c[3])
    fitted = model_values(result, other, angles_c, CURVE_ACCURACY)
    dashed = model_values(extra, None, angles_c) if extra is not None else None
    from matplotlib.lines import Line2D

    start = 0
    handles = []
    for k, p, sel, tr_c, _ in curves:
        color = COLORS[k % len(COLORS)]
        n = len(tr_c)
        order = np.argsort(tr[sel])
        yerr = data.sigma[sel][order] if data.sigma is not None else None
        ax.errorbar(
            tr[sel][order],
            y[sel][order],
            yerr=yerr,
            fmt="o",
            ms=3,
            color=color,
            elinewidth=0.8,
            capsize=0,
        )
        ax.plot(tr_c, fitted[start : start + n], "-", color=color, lw=1.2)
        if dashed is not None:
            ax.plot(tr_c, dashed[start : start + n], "--", color=color, lw=1.0)
        handles.append(Line2D([], [], color=color, marker="o", ms=3, lw=1.2, label=f"psi = {p:g}°"))
        start += n
    positive = y[y > 0]
    if positive.size and np.max(positive) > LOG_RATIO * np.median(positive):
        ax.set_yscale("log")
        ax.set_ylim(bottom=max(np.min(positive) * 0.5, np.max(positive) * 1e-6))
    ax.set_ylabel("observed value [relative units, 1/sr]")
    _residual_panel(
        res_ax, data, _fitted_values(data, result, other, accuracy), psi, tr, result.model_error
    )
    ax.tick_params(labelbottom=False)
    res_ax.set_title("relative residual (data - model) / model", fontsize=8, loc="left")
    fig.align_ylabels((ax, res_ax))
    handles += [
        Line2D(
            [],
            [],
            color="0.3",
            marker="o",
            ms=3,
            lw=0,
            label="data" + (" (+- sigma)" if data.sigma is not None else ""),
        ),
        Line2D([], [], color="0.3", lw=1.2, label="fitted model"),
    ]
    if dashed is not None:
        handles.append(
            Line2D(
                [],
                [],
                color="0.3",
                lw=1.0,
                ls="--",
                label="f_r estimated through the medium (step 2)",
            )
        )
    ax.legend(handles=handles, fontsize=7.5, loc="best", framealpha=0.8)


#: A model value below this fraction of the session's largest is too small to divide by: its
#: relative residual is not drawn.
TINY_MODEL = 1e-9
#: The residual panel's half-range holds every point but those beyond OUTLIER times this
#: percentile of |residual| (drawn at the edge, as triangles), and at least 4 model-error s.
PANEL_PERCENTILE = 98.0
OUTLIER = 3.0


def _fitted_values(data, result: FitResult, other, accuracy) -> np.ndarray:
    """The fitted model at the data's configurations: from the result's own residuals
    ((value - model) / sigma, or value - model unweighted) when they are this data's, else
    evaluated."""
    r = np.asarray(result.residuals, dtype=float)
    if r.size != data.y.size:
        return model_values(result, other, data.angles, accuracy)
    return data.y - r * (data.sigma if result.weighted and data.sigma is not None else 1.0)


def relative_residuals(y, model, sigma=None):
    """(data - model) / model and its noise sigma / model (None without sigma); NaN (not
    drawn) where the model is not finite, or too small to divide by (below
    :data:`TINY_MODEL` of the largest |model|)."""
    y, model = np.asarray(y, dtype=float), np.asarray(model, dtype=float)
    finite = np.isfinite(model) & np.isfinite(y)
    scale = np.max(np.abs(model[finite])) if finite.any() else 0.0
    ok = finite & (np.abs(model) > TINY_MODEL * scale)
    safe = np.where(ok, model, 1.0)
    rel = np.where(ok, (y - safe) / safe, np.nan)
    err = (
        None
        if sigma is None
        else np.where(ok, np.asarray(sigma, dtype=float) / np.abs(safe), np.nan)
    )
    return rel, err


def residual_panel(rel, sigma_model: float = 0.0):
    """What the residual panel draws, in per cent: (half-range, values clipped to it, the
    mask of clipped points). The half-range holds every |rel| up to :data:`OUTLIER` times
    its :data:`PANEL_PERCENTILE` percentile, and at least 4 model-error s (and 1e-6 %), with
    a 10 % margin: a gross outlier does not flatten the rest."""
    pct = 100.0 * np.asarray(rel, dtype=float)
    shown = np.abs(pct[np.isfinite(pct)])
    core = np.percentile(shown, PANEL_PERCENTILE) if shown.size else 0.0
    kept = shown[shown <= OUTLIER * core]
    half = 1.1 * max(float(kept.max()) if kept.size else 0.0, 400.0 * sigma_model, 1e-6)
    off = np.isfinite(pct) & (np.abs(pct) > half)
    return half, np.where(off, np.sign(pct) * half, pct), off


def _residual_panel(ax, data, model, psi, tr, model_error) -> None:
    rel, err = relative_residuals(data.y, model, data.sigma)
    s = getattr(model_error, "sigma", 0.0) or 0.0
    half, shown, off = residual_panel(rel, s)
    if s > 0:
        ax.axhspan(
            -200.0 * s,
            200.0 * s,
            color="0.85",
            lw=0,
            label=f"model error +-2 s (s = {100 * s:.2g} %)",
        )
    for k, p in enumerate(np.unique(psi)):
        sel, color = psi == p, COLORS[k % len(COLORS)]
        inside = sel & ~off
        ax.errorbar(
            tr[inside],
            shown[inside],
            yerr=None if err is None else 100.0 * err[inside],
            fmt="o",
            ms=2.5,
            color=color,
            elinewidth=0.7,
            capsize=0,
        )
        for sign, marker in ((1.0, "^"), (-1.0, "v")):
            edge = sel & off & (np.sign(shown) == sign)
            if edge.any():
                ax.plot(tr[edge], shown[edge], marker, ms=4, color=color, clip_on=False)
    ax.set_ylim(-half, half)
    ax.axhline(0.0, color="0.4", lw=0.8)
    if s > 0 or off.any():
        if off.any():
            ax.plot([], [], "^", ms=4, color="0.3", label="beyond the panel's range")
        ax.legend(fontsize=7, loc="best", framealpha=0.8)
    ax.set_ylabel("residual [%]", fontsize=9)
    ax.set_xlabel("reflection angle theta_r [deg] (signed, in the plane of incidence)")
    ax.grid(True, which="major", alpha=0.3)
    ax.tick_params(labelsize=8)


# --------------------------------------------------------------------------------------
# the figure
# --------------------------------------------------------------------------------------
def diagnosis_figure(diag, path) -> None:
    """PNG: the correlation matrix and each profile (Delta chi^2 against the held value,
    with the quadratic expected from the standard error); written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = 1 + len(diag.profiles)
    cols = min(panels, 4)  # a grid, at most four panels a row
    rows = -(-panels // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.8 * rows), squeeze=False)
    axes = axes.ravel()
    for ax in axes[panels:]:
        ax.set_visible(False)
    ax = axes[0]
    im = ax.imshow(diag.correlation, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(len(diag.names)), diag.names, rotation=60, fontsize=7)
    ax.set_yticks(range(len(diag.names)), diag.names, fontsize=7)
    ax.set_title("correlation")
    fig.colorbar(im, ax=ax, fraction=0.046)
    for ax, (name, prof) in zip(axes[1:], diag.profiles.items()):
        v = np.array(prof.values)
        ax.plot(v, prof.delta_chi2, "o-", label="profile")
        se = diag.stderr[name]
        fine = np.linspace(v.min(), v.max(), 200)
        ax.plot(
            fine, ((fine - prof.estimate) / se) ** 2, "--", color="gray", label="quadratic (stderr)"
        )
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_ylim(0, max(10.0, min(50.0, max(prof.delta_chi2) * 1.1)))
        ax.set_xlabel(name)
        ax.locator_params(axis="x", nbins=4)
        ax.set_ylabel("Delta chi^2")
        ax.set_title(f"profile of {name}" + (" (flat)" if prof.flat else ""))
        ax.legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


__all__ = ["fit_figure", "diagnosis_figure", "LOG_RATIO", "COLORS"]
