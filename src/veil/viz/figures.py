"""The paper's simulation experiment (section 5.1, figs. 9-12) as data and matplotlib figures.

* fig. 9: the reflection lobes f_r of the objects for 45 deg incidence (docs/model.md sec. 2);
* fig. 10: the transmission lobes f_t of the media for 45 deg incidence (docs/model.md sec. 3);
* fig. 11: observed value f(I, R) against reflection angle, each object under each medium and
  in a clear medium (docs/model.md sec. 5, in-plane set-up of sec. 1);
* fig. 12: spheres rendered with the true and the apparent BRDFs (:mod:`veil.render`).

:func:`run_experiment` computes everything (deterministically) into an :class:`Experiment`;
the ``fig*`` functions draw it (figs. 9 and 10: :mod:`veil.viz.lobe_figures`);
:func:`save_figure` writes PNG/PDF/SVG atomically (:mod:`veil.viz.figure_style`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..engine.apparent import as_brdf, as_btdf
from ..engine.evaluator import check_accuracy
from ..errors import InputError
from ..io import write_bytes_atomic
from ..models import Model
from .figure_style import (
    CLEAR_COLOR,
    FORMATS,
    MEDIUM_COLORS,
    _name,
    _style,
    _values,
    figure_bytes,
    figure_format,
    save_figure,
)
from .lobe_figures import (
    PLOT_MAX,
    check_plottable,
    fig9,
    fig10,
    lobe_data,
    transmission_data,
)
from .render import Rendering, auto_exposure, clipping, evaluate, highlight_pixel, render, tone_map

if TYPE_CHECKING:
    from matplotlib.figure import Figure


# --------------------------------------------------------------------------------------
# the data
# --------------------------------------------------------------------------------------
def reflection_angles(theta_i=45.0, top=89.0) -> np.ndarray:
    """In-plane reflection angles (deg): every 1 deg on [0, top], every 0.25 deg near the mirror."""
    coarse = np.arange(0.0, top + 1e-9, 1.0)
    fine = np.arange(max(0.0, theta_i - 15.0), min(top, theta_i + 15.0) + 1e-9, 0.25)
    return np.unique(np.round(np.concatenate([coarse, fine]), 6))


@dataclass
class CurveMetrics:
    """Peak, width at half maximum and off-peak level of an in-plane curve (fig. 11)."""

    peak: float
    peak_angle: float  # deg
    left: float  # half-maximum crossings (deg); nan if the curve stays above half maximum
    right: float
    off_peak: float  # value at the off-peak angle
    off_angle: float

    @property
    def fwhm(self) -> float:
        """Full width at half maximum (deg); nan where a crossing is missing (see
        :meth:`fwhm_text`)."""
        return self.right - self.left

    @property
    def zero(self) -> bool:
        """Whether the curve is 0 at every angle (no peak, no width)."""
        return not self.peak > 0

    def fwhm_text(self) -> str:
        """The width for a report: "FWHM 3.20 deg", or why the curve has none."""
        if self.zero:
            return "FWHM not defined (f = 0 at every angle)"
        if math.isfinite(self.fwhm):
            return f"FWHM {self.fwhm:.2f} deg"
        side = {
            (True, True): "on either side of the peak",
            (True, False): "below the peak angle",
            (False, True): "above the peak angle",
        }[(math.isnan(self.left), math.isnan(self.right))]
        return f"FWHM not defined (no half-maximum crossing {side} in the range)"


def curve_metrics(theta, values, off_angle=0.0) -> CurveMetrics:
    """Measure a curve: peak, full width at half maximum (linear crossings), off-peak value."""
    theta, values = np.asarray(theta, float), np.asarray(values, float)
    k = int(np.argmax(values))
    peak, half = float(values[k]), 0.5 * float(values[k])

    def crossing(indices):
        prev = k
        for j in indices:
            if values[j] < half:
                t = (values[prev] - half) / (values[prev] - values[j])
                return float(theta[prev] + t * (theta[j] - theta[prev]))
            prev = j
        return math.nan

    left = crossing(range(k - 1, -1, -1))
    right = crossing(range(k + 1, len(values)))
    return CurveMetrics(
        peak, float(theta[k]), left, right, float(np.interp(off_angle, theta, values)), off_angle
    )


@dataclass
class Curve:
    brdf: Model
    medium: Model | None  # None: clear medium
    theta_i: float
    theta_r: np.ndarray
    values: np.ndarray
    metrics: CurveMetrics


def inplane_curve(
    brdf, medium, theta_i=45.0, theta_r=None, *, accuracy="default", progress=None
) -> Curve:
    """f(I, R) in the plane of incidence, light at theta_i, camera at theta_r on the mirror side."""
    b = as_brdf(brdf)
    m = None if medium is None else as_btdf(medium)
    tr = reflection_angles(theta_i) if theta_r is None else np.asarray(theta_r, float)
    values = evaluate(
        b,
        m,
        np.full(tr.shape, float(theta_i)),
        tr,
        np.full(tr.shape, 180.0),
        accuracy=accuracy,
        progress=progress,
    )
    check_plottable(values, "the curve", [b, m])
    return Curve(b, m, float(theta_i), tr, values, curve_metrics(tr, values))


@dataclass
class SphereStats:
    """What fig. 12 shows, measured on the linear image."""

    peak: float
    peak_pixel: tuple  # (row, col) of the brightest pixel
    mirror_pixel: tuple  # (row, col) where N = H predicts it
    median: float  # median of the lit pixels
    half_area: int  # pixels at or above half the peak value
    exposure: float  # automatic exposure (median lit pixel -> 18 % grey)
    clipped: int  # pixels that would clip under the linear ("clip") tone curve
    clipped_fraction: float

    @property
    def contrast(self) -> float:
        """Peak over the median lit pixel."""
        return self.peak / self.median


def sphere_stats(rendering: Rendering) -> SphereStats:
    """Peak, its pixel and the mirror prediction, median, half-maximum area, exposure."""
    img = rendering.image
    k = np.unravel_index(int(np.argmax(img)), img.shape)
    exposure = auto_exposure(img)
    n_clip, frac, _ = clipping(img, exposure)
    lit = img[img > 0]
    row, col = highlight_pixel(img.shape[0], rendering.light_theta, rendering.light_phi)
    return SphereStats(
        float(img.max()),
        (int(k[0]), int(k[1])),
        (round(row, 2), round(col, 2)),
        float(np.median(lit)),
        int(np.count_nonzero(img >= 0.5 * img.max())),
        exposure,
        n_clip,
        frac,
    )


@dataclass
class Experiment:
    """Everything section 5.1 of the paper shows, for the given objects and media."""

    brdfs: dict  # name -> BRDF model
    media: dict  # name -> medium model
    theta_i: float
    light_theta: float
    size: int
    accuracy: str  # quadrature of the curves (fig. 11)
    render_accuracy: str  # quadrature of the sphere tables (fig. 12)
    curves: dict = field(default_factory=dict)  # (brdf name, medium name or "clear") -> Curve
    renders: dict = field(default_factory=dict)  # same keys -> Rendering
    stats: dict = field(default_factory=dict)  # same keys -> SphereStats
    #: (brdf, medium) -> f at the off-peak angle with the medium's T_d set to 0 (single
    #: scattering only), to tell the isotropic terms' share of the off-peak level
    single_only: dict = field(default_factory=dict)


def run_experiment(
    brdfs=("BRDF1", "BRDF2"),
    media=("BTDF1", "BTDF2", "BTDF3"),
    *,
    theta_i=45.0,
    light_theta=45.0,
    size=256,
    accuracy="default",
    render_accuracy="fast",
    check=64,
    progress=None,
) -> Experiment:
    """Compute the curves (fig. 11) and renders (fig. 12) of the experiment.

    ``progress(message, done, total)`` is called as the work advances (optional).
    """
    for name, acc in (("accuracy", accuracy), ("render_accuracy", render_accuracy)):
        check_accuracy(acc, name)
    exp = Experiment(
        {b if isinstance(b, str) else _name(b): as_brdf(b) for b in brdfs},
        {m if isinstance(m, str) else _name(m): as_btdf(m) for m in media},
        float(theta_i),
        float(light_theta),
        int(size),
        accuracy,
        render_accuracy,
    )
    keys = [(b, "clear") for b in exp.brdfs] + [(b, m) for b in exp.brdfs for m in exp.media]
    total = 2 * len(keys)
    done = 0
    for key in keys:
        b, m = exp.brdfs[key[0]], exp.media.get(key[1])
        if progress:
            progress(f"fig. 11 curve {key[0]} x {key[1]}", done, total)
        exp.curves[key] = inplane_curve(b, m, theta_i, accuracy=accuracy)
        if m is not None:
            off = exp.curves[key].metrics.off_angle
            exp.single_only[key] = float(
                evaluate(b, m.without_iso(), theta_i, off, 180.0, accuracy=accuracy)[0]
            )
        done += 1
    for key in keys:
        b, m = exp.brdfs[key[0]], exp.media.get(key[1])
        if progress:
            progress(f"fig. 12 sphere {key[0]} x {key[1]}", done, total)
        exp.renders[key] = render(
            b, m, light_theta, 0.0, size, accuracy=render_accuracy, check=check
        )
        exp.stats[key] = sphere_stats(exp.renders[key])
        done += 1
    if progress:
        progress("done", done, total)
    return exp


# --------------------------------------------------------------------------------------
# fig. 11: observed value against reflection angle
# --------------------------------------------------------------------------------------
SCALES = ("log", "linear", "peak", "tt2")
SCALE_WORDS = {
    "log": "observed value, log scale",
    "linear": "observed value, linear scale",
    "peak": "each curve divided by its own peak, linear scale",
    "tt2": "observed value divided by T_t² (clear medium as is), log scale",
}


SHORT_WORDS = {
    "log": "observed value f, log scale",
    "linear": "observed value f",
    "peak": "f divided by its own peak, linear scale",
    "tt2": "f / T_t² (clear medium: f), log scale",
}


def _medium_label(curve: Curve, with_brdf=True) -> str:
    head = f"{_name(curve.brdf)}, " if with_brdf else ""
    if curve.medium is None:
        return f"{head}clear medium"
    return f"{head}{_name(curve.medium)} ({_values(curve.medium.shape_values())})"


def _curve_y(curve: Curve, scale: str) -> tuple[np.ndarray | None, str]:
    """The y values of ``curve`` on ``scale``, or None and why it cannot be drawn there (a
    curve that is 0 everywhere has no peak and nothing on a log scale; f / T_t^2 needs
    T_t > 0)."""
    y = curve.values
    if scale == "peak":
        return (None, "f = 0, not drawn") if curve.metrics.zero else (y / curve.metrics.peak, "")
    if scale == "tt2" and curve.medium is not None:
        with np.errstate(over="ignore", under="ignore"):
            tt2 = np.square(np.float64(as_btdf(curve.medium).lobe_scale()))
            y = y / tt2 if tt2 > 0 else y
        if not tt2 > 0:
            return None, "T_t² = 0 (or below float64's range): f / T_t² not drawn"
        if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > PLOT_MAX:
            return None, f"f / T_t² above {PLOT_MAX:g}, not drawn"
    if scale in ("log", "tt2") and not np.any(y > 0):
        return None, "f = 0, not on the log scale"
    return y, ""


def _nothing_drawn(ax, log: bool) -> None:
    """Limits and a note for an axis where no curve could be drawn."""
    if log:
        ax.set_ylim(0.1, 10.0)
    else:
        ax.set_ylim(0, 1.05)
    ax.text(
        0.5,
        0.5,
        "no curve can be drawn on this scale\n(the legend says why)",
        transform=ax.transAxes,
        ha="center",
        va="center",
        color="0.3",
    )


def draw_curves(ax, curves, scale="log", title=None, with_brdf=True) -> None:
    """Observed value against reflection angle on one axis.

    scale: "log" or "linear" (f as is), "peak" (each curve over its own peak, linear) or
    "tt2" (f / T_t^2, log: the medium passes single-scattered light twice, each time with
    weight T_t, so this takes out the media's different strengths; clear medium as is).
    A curve that cannot be drawn on the scale (:func:`_curve_y`) has a legend entry that
    says why.
    """
    if scale not in SCALES:
        raise InputError(f"scale = {scale!r}; expected one of {', '.join(SCALES)}")
    k_medium = 0
    drawn = 0
    for curve in curves:
        if curve.medium is None:
            color, lw = CLEAR_COLOR, 1.8
        else:
            color, lw = MEDIUM_COLORS[k_medium % len(MEDIUM_COLORS)], 1.5
            k_medium += 1
        y, why = _curve_y(curve, scale)
        label = _medium_label(curve, with_brdf)
        if y is None:
            ax.plot([], [], color=color, lw=lw, label=f"{label}: {why}")
            continue
        drawn += 1
        ax.plot(curve.theta_r, y, color=color, lw=lw, label=label)
    if not drawn:
        _nothing_drawn(ax, scale in ("log", "tt2"))
    if scale in ("log", "tt2"):
        ax.set_yscale("log")
        ax.set_ylabel(
            "f(I, R) [1/sr], log scale" if scale == "log" else "f(I, R) / T_t² [1/sr], log scale"
        )
    elif scale == "linear":
        ax.set_ylabel("f(I, R) [1/sr]")
    else:
        ax.set_ylabel("f(I, R) / own peak")
        ax.set_ylim(0, 1.05)
        ax.axhline(0.5, color="0.6", lw=0.8, ls=":")
    theta_i = curves[0].theta_i
    ax.axvline(theta_i, color="0.6", lw=0.8, ls=":")
    ax.set_xlabel(f"reflection angle θ_r [deg]  (incidence {theta_i:g}°, in the plane)")
    ax.set_xlim(0, 90)
    ax.grid(True, which="major", alpha=0.3)
    if title:
        ax.set_title(title)


def fig11(exp: Experiment) -> Figure:
    """Rows: f (log), f / T_t^2 (log), f over its own peak (linear); one column per object."""
    ctx, plt = _style()
    names = list(exp.brdfs)
    rows = ("log", "tt2", "peak")
    with ctx:
        fig, axes = plt.subplots(3, len(names), figsize=(5.6 * len(names), 11.0), squeeze=False)
        letters = iter("abcdefghijkl")
        for i, scale in enumerate(rows):
            for j, b in enumerate(names):
                curves = [exp.curves[(b, "clear")]] + [exp.curves[(b, m)] for m in exp.media]
                draw_curves(
                    axes[i, j],
                    curves,
                    scale,
                    f"({next(letters)}) {b}: {SHORT_WORDS[scale]}",
                    with_brdf=False,
                )
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(
            handles,
            labels,
            loc="upper center",
            ncol=len(labels),
            frameon=False,
            bbox_to_anchor=(0.5, 1.0),
        )
        fig.tight_layout(rect=(0, 0, 1, 0.975))
    return fig


def fig_curve(curves, scale="log") -> Figure:
    """One panel of observed value against reflection angle (``veil plot curve``)."""
    ctx, plt = _style()
    with ctx:
        fig, ax = plt.subplots(figsize=(7.0, 4.8))
        draw_curves(ax, curves, scale, SCALE_WORDS[scale])
        ax.legend(loc="best", frameon=True, framealpha=0.9)
        fig.tight_layout()
    return fig


# --------------------------------------------------------------------------------------
# fig. 12: rendered spheres
# --------------------------------------------------------------------------------------
def fig12(exp: Experiment, tone="reinhard") -> Figure:
    """Rows: objects; columns: clear medium then each medium. Each panel has its own exposure
    (median lit pixel -> 18 % grey) and the tone curve ``tone`` (see :func:`tone_map`)."""
    ctx, plt = _style()
    rows = list(exp.brdfs)
    cols = ["clear"] + list(exp.media)
    with ctx:
        fig, axes = plt.subplots(
            len(rows), len(cols), figsize=(3.1 * len(cols), 4.0 * len(rows)), squeeze=False
        )
        letter = iter("abcdefghijklmnop")
        for i, b in enumerate(rows):
            for j, m in enumerate(cols):
                ax = axes[i, j]
                st = exp.stats[(b, m)]
                img = tone_map(exp.renders[(b, m)].image, st.exposure, tone)
                ax.imshow(img, cmap="gray", vmin=0, vmax=255, interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                what = "true BRDF (clear)" if m == "clear" else f"apparent, {m}"
                ax.set_title(f"({next(letter)}) {b}, {what}")
                if tone == "clip":
                    clip = (
                        f"highlight clips: {100 * st.clipped_fraction:.2g} % of lit px"
                        if st.clipped
                        else "nothing clips"
                    )
                else:
                    clip = f"peak/median {st.contrast:.3g}"
                ax.set_xlabel(
                    f"peak {st.peak:.3g}, median {st.median:.3g} [1/sr]\n"
                    f"exposure {st.exposure:.3g}; {clip}",
                    fontsize=8.5,
                )
        curve = (
            "x/(1+x) (Reinhard, nothing clips)"
            if tone == "reinhard"
            else "linear, clipped at white"
        )
        fig.suptitle(
            f"Spheres lit from θ = {exp.light_theta:g}° (from the right), orthographic "
            f"view; pixel = f·cos θ_i; exposure: median lit pixel → 0.18; "
            f"tone curve {curve}; sRGB",
            fontsize=10,
            y=0.995,
        )
        fig.tight_layout(rect=(0, 0, 1, 0.975))
    return fig


__all__ = [
    "Experiment",
    "run_experiment",
    "Curve",
    "CurveMetrics",
    "curve_metrics",
    "inplane_curve",
    "reflection_angles",
    "lobe_data",
    "transmission_data",
    "fig9",
    "fig10",
    "fig11",
    "fig12",
    "fig_curve",
    "draw_curves",
    "save_figure",
    "figure_bytes",
    "figure_format",
    "write_bytes_atomic",
    "SphereStats",
    "sphere_stats",
    "SCALES",
    "FORMATS",
]
