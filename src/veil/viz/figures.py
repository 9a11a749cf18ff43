"""The paper's simulation experiment (section 5.1, figs. 9-12) as data and matplotlib figures.

* fig. 9: the reflection lobes f_r of the objects for 45 deg incidence (docs/model.md sec. 2);
* fig. 10: the transmission lobes f_t of the media for 45 deg incidence (docs/model.md sec. 3);
* fig. 11: observed value f(I, R) against reflection angle, each object under each medium and
  in a clear medium (docs/model.md sec. 5, in-plane set-up of sec. 1);
* fig. 12: spheres rendered with the true and the apparent BRDFs (:mod:`veil.render`).

:func:`run_experiment` computes everything (deterministically) into an :class:`Experiment`;
the ``fig*`` functions draw it; :func:`save_figure` writes PNG/PDF/SVG atomically.
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..engine.angles import direction
from ..engine.apparent import RULES, as_brdf, as_btdf, reflectance
from ..errors import InputError
from ..io import write_bytes_atomic
from ..models import PRESETS, Model
from .render import Rendering, auto_exposure, clipping, evaluate, highlight_pixel, render, tone_map

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Figure formats :func:`save_figure` writes, by file suffix.
FORMATS = ("png", "pdf", "svg")
#: Colours: the clear medium is red as in the paper's fig. 11; media from light to dark.
CLEAR_COLOR = "#d62728"
MEDIUM_COLORS = ("#1f77b4", "#2ca02c", "#6a3d9a", "#ff7f0e", "#8c564b", "#17becf")
BRDF_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e")
STYLE = {"font.size": 10, "axes.titlesize": 10.5, "axes.labelsize": 10, "legend.fontsize": 9,
         "xtick.labelsize": 9, "ytick.labelsize": 9, "figure.dpi": 100,
         "svg.hashsalt": "veil", "pdf.compression": 6}


# --------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------
def figure_format(path) -> str:
    """The format of ``path`` from its suffix; ValueError for anything but png/pdf/svg."""
    ext = os.path.splitext(os.fspath(path))[1].lower().lstrip(".")
    if ext not in FORMATS:
        raise InputError(f"cannot tell the figure format of {os.fspath(path)!r}: use a file "
                         f"name ending in {', '.join('.' + f for f in FORMATS)}")
    return ext


def figure_bytes(fig, fmt: str, dpi=150) -> bytes:
    """The figure encoded as ``fmt``, without time stamps (deterministic output)."""
    buf = io.BytesIO()
    meta = {"png": {"Software": None}, "pdf": {"CreationDate": None, "ModDate": None},
            "svg": {"Date": None}}[fmt]
    fig.savefig(buf, format=fmt, dpi=dpi, metadata=meta)
    return buf.getvalue()


def save_figure(fig, path, dpi=150) -> None:
    """Save a matplotlib figure atomically; the format follows the suffix (png, pdf, svg)."""
    write_bytes_atomic(path, figure_bytes(fig, figure_format(path), dpi))


def _style():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.rc_context(STYLE), plt


def _name(model) -> str:
    """Preset name if the model is one (plus its non-default options), else its values."""
    defaults = model.default_options()
    extra = "".join(f", {v}" for k, v in model.options().items() if v != defaults[k])
    for key, value in PRESETS.items():
        if type(value) is type(model) and value.replace(**model.options()) == model:
            return key + extra
    vals = " ".join(f"{p.name}={getattr(model, p.name):.3g}" for p in model.PARAMS)
    return vals + extra


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
        return self.right - self.left


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
    return CurveMetrics(peak, float(theta[k]), left, right,
                        float(np.interp(off_angle, theta, values)), off_angle)


@dataclass
class Curve:
    brdf: Model
    medium: Model | None  # None: clear medium
    theta_i: float
    theta_r: np.ndarray
    values: np.ndarray
    metrics: CurveMetrics


def inplane_curve(brdf, medium, theta_i=45.0, theta_r=None, *, accuracy="default",
                  progress=None) -> Curve:
    """f(I, R) in the plane of incidence, light at theta_i, camera at theta_r on the mirror side."""
    b = as_brdf(brdf)
    m = None if medium is None else as_btdf(medium)
    tr = reflection_angles(theta_i) if theta_r is None else np.asarray(theta_r, float)
    values = evaluate(b, m, np.full(tr.shape, float(theta_i)), tr, np.full(tr.shape, 180.0),
                      accuracy=accuracy, progress=progress)
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
    return SphereStats(float(img.max()), (int(k[0]), int(k[1])), (round(row, 2), round(col, 2)),
                       float(np.median(lit)), int(np.count_nonzero(img >= 0.5 * img.max())),
                       exposure, n_clip, frac)


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


def run_experiment(brdfs=("BRDF1", "BRDF2"), media=("BTDF1", "BTDF2", "BTDF3"), *, theta_i=45.0,
                   light_theta=45.0, size=256, accuracy="default", render_accuracy="fast",
                   check=64, progress=None) -> Experiment:
    """Compute the curves (fig. 11) and renders (fig. 12) of the experiment.

    ``progress(message, done, total)`` is called as the work advances (optional).
    """
    for name, acc in (("accuracy", accuracy), ("render_accuracy", render_accuracy)):
        if acc not in RULES:
            raise InputError(f"{name} = {acc!r}; expected one of {', '.join(RULES)}")
    exp = Experiment({b if isinstance(b, str) else _name(b): as_brdf(b) for b in brdfs},
                     {m if isinstance(m, str) else _name(m): as_btdf(m) for m in media},
                     float(theta_i), float(light_theta), int(size), accuracy, render_accuracy)
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
            exp.single_only[key] = float(evaluate(b, m.without_iso(), theta_i, off, 180.0,
                                                  accuracy=accuracy)[0])
        done += 1
    for key in keys:
        b, m = exp.brdfs[key[0]], exp.media.get(key[1])
        if progress:
            progress(f"fig. 12 sphere {key[0]} x {key[1]}", done, total)
        exp.renders[key] = render(b, m, light_theta, 0.0, size, accuracy=render_accuracy,
                                  check=check)
        exp.stats[key] = sphere_stats(exp.renders[key])
        done += 1
    if progress:
        progress("done", done, total)
    return exp


# --------------------------------------------------------------------------------------
# polar helpers (log radius)
# --------------------------------------------------------------------------------------
def _decades(values, most=6):
    """(lo, hi) decades for a log radius: the smallest value sits a little outside the origin."""
    v = np.asarray(values)
    v = v[v > 0]
    hi = math.ceil(math.log10(v.max()) + 1e-9)
    lo = math.floor(math.log10(v.min()) - 0.3)
    return max(lo, hi - most), hi


def _log_radius(values, lo):
    return np.clip(np.log10(np.maximum(values, 1e-300)) - lo, 0.0, None)


def _setup_log_polar(ax, lo, hi, zero="N", direction=-1, unit=""):
    ax.set_theta_zero_location(zero)
    ax.set_theta_direction(direction)
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    ax.set_rlim(0, hi - lo)
    ticks = list(range(1, hi - lo + 1))
    step = 1 if len(ticks) <= 4 else 2  # label every other ring when they would crowd
    ax.set_rticks(ticks)
    ax.set_yticklabels([f"$10^{{{lo + t}}}$" if (hi - lo - t) % step == 0 else "" for t in ticks],
                       fontsize=8)
    ax.set_rlabel_position(-75)
    ax.set_thetagrids(range(-90, 91, 30), [f"{a}°" for a in range(-90, 91, 30)])
    ax.grid(True, alpha=0.4)


# --------------------------------------------------------------------------------------
# fig. 9: reflection lobes
# --------------------------------------------------------------------------------------
def _mirror_cut(theta_i, s_deg):
    """Directions R(s) = cos s M + sin s y through the mirror direction M, out of the plane."""
    t = math.radians(theta_i)
    m = np.array([math.sin(t), 0.0, math.cos(t)])
    s = np.radians(np.asarray(s_deg, float))
    r = np.cos(s)[:, None] * m + np.sin(s)[:, None] * np.array([0.0, 1.0, 0.0])
    theta = np.degrees(np.arccos(np.clip(r[:, 2], -1, 1)))
    phi = np.degrees(np.arctan2(r[:, 1], r[:, 0]))
    return theta, phi


def lobe_data(brdf, theta_i=45.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """f_r in the plane of incidence (signed theta_r) and out of it (angle s from the mirror)."""
    b = as_brdf(brdf)
    t_in = np.unique(np.concatenate([np.linspace(-89.5, 89.5, 359),
                                     np.arange(theta_i - 15, theta_i + 15.001, 0.05)]))
    t_in = t_in[np.abs(t_in) < 89.9]
    f_in = reflectance(b, theta_i, np.abs(t_in), 180.0, np.where(t_in < 0, 180.0, 0.0))
    s = np.unique(np.concatenate([np.linspace(-89.5, 89.5, 359), np.arange(-15, 15.001, 0.05)]))
    th, ph = _mirror_cut(theta_i, s)
    ok = th < 89.9
    f_out = reflectance(b, theta_i, th[ok], 180.0, ph[ok])
    return t_in, f_in, s[ok], f_out


def _legend_columns(handles) -> int:
    return 2 if all(len(h.get_label()) <= 22 for h in handles) and len(handles) > 1 else 1


def _three_panels(plt):
    fig = plt.figure(figsize=(13.0, 4.3))
    ax1 = fig.add_axes([0.01, 0.10, 0.30, 0.72], projection="polar")
    ax2 = fig.add_axes([0.33, 0.10, 0.30, 0.72], projection="polar")
    ax3 = fig.add_axes([0.70, 0.30, 0.28, 0.56])
    return fig, ax1, ax2, ax3


def fig9(brdfs=("BRDF1", "BRDF2"), theta_i=45.0, labels=None) -> Figure:
    """Reflection lobes f_r for incidence theta_i: in plane, out of plane, close-up (log)."""
    ctx, plt = _style()
    with ctx:
        fig, ax1, ax2, ax3 = _three_panels(plt)
        data = [lobe_data(b, theta_i) for b in brdfs]
        lo, hi = _decades(np.concatenate([np.concatenate([d[1], d[3]]) for d in data]))
        handles = []
        for k, (b, (t_in, f_in, s, f_out)) in enumerate(zip(brdfs, data)):
            name = labels[k] if labels else _name(as_brdf(b))
            c = BRDF_COLORS[k % len(BRDF_COLORS)]
            (line,) = ax1.plot(np.radians(t_in), _log_radius(f_in, lo), color=c, lw=1.4, label=name)
            handles.append(line)
            ax2.plot(np.radians(s), _log_radius(f_out, lo), color=c, lw=1.4)
            near = np.abs(t_in - theta_i) <= 15
            ax3.semilogy(t_in[near] - theta_i, f_in[near], color=c, lw=1.6)
            near = np.abs(s) <= 15
            ax3.semilogy(s[near], f_out[near], color=c, lw=1.2, ls="--")
        for ax in (ax1, ax2):
            _setup_log_polar(ax, lo, hi)
        r_top = hi - lo
        ax1.annotate("", xy=(0, 0), xytext=(math.radians(-theta_i), r_top),
                     arrowprops=dict(arrowstyle="->", color="0.3", lw=1.2))
        ax1.text(math.radians(-theta_i + 7), r_top * 0.8, "light", color="0.3", ha="center")
        ax1.plot([math.radians(theta_i)] * 2, [0, r_top], color="0.5", lw=0.8, ls=":")
        ax1.set_title("(a) in the plane of incidence\nangle = signed reflection angle θ_r", pad=4)
        ax2.set_title("(b) out of the plane, through the mirror direction\n"
                      "angle = from the mirror direction", pad=4)
        floor = min(float(np.min(d[1])) for d in data)
        ax3.set_ylim(bottom=10 ** math.floor(math.log10(floor)))
        ax3.set_xlabel("angle from the mirror direction [deg]")
        ax3.set_ylabel("f_r [1/sr] (log scale)")
        ax3.set_title("(c) close-up: solid in the plane,\ndashed out of the plane")
        ax3.set_xlim(-15, 15)
        ax3.grid(True, which="major", alpha=0.3)
        fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.84, 0.0),
                   ncol=_legend_columns(handles), frameon=False,
                   title=f"incidence {theta_i:g}°, radius: f_r [1/sr], log")
    return fig


# --------------------------------------------------------------------------------------
# fig. 10: transmission lobes
# --------------------------------------------------------------------------------------
def transmission_data(medium,
                      theta_i=45.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """f_t(I, T) against the propagation direction -T of the transmitted light.

    In the plane: beta = signed angle of -T from the downward vertical (beta = theta_i is the
    unscattered continuation of the incident ray). Out of the plane: angle s of -T from -I,
    perpendicular to the plane of incidence.
    """
    m = as_btdf(medium)
    v = m.to_vector()
    wi = np.asarray(direction(theta_i, 180.0))
    beta = np.unique(np.concatenate([np.linspace(-89.5, 89.5, 359),
                                     np.arange(theta_i - 20, min(theta_i + 20, 89.9), 0.05)]))
    beta = beta[np.abs(beta) < 89.9]
    b = np.radians(beta)
    t = np.stack([-np.sin(b), np.zeros_like(b), np.cos(b)], axis=-1)  # T = -(propagation)
    f_in = np.asarray(m.evaluate(v, np.broadcast_to(wi, t.shape), t))
    s = np.unique(np.concatenate([np.linspace(-89.5, 89.5, 359), np.arange(-20, 20.001, 0.05)]))
    sr = np.radians(s)
    t2 = np.cos(sr)[:, None] * wi + np.sin(sr)[:, None] * np.array([0.0, 1.0, 0.0])
    ok = t2[:, 2] > math.cos(math.radians(89.9))
    f_out = np.asarray(m.evaluate(v, np.broadcast_to(wi, t2[ok].shape), t2[ok]))
    return beta, f_in, s[ok], f_out


def fig10(media=("BTDF1", "BTDF2", "BTDF3"), theta_i=45.0, labels=None) -> Figure:
    """Transmission lobes f_t for incidence theta_i: in plane, out of plane, close-up (log)."""
    ctx, plt = _style()
    with ctx:
        fig, ax1, ax2, ax3 = _three_panels(plt)
        data = [transmission_data(m, theta_i) for m in media]
        lo, hi = _decades(np.concatenate([np.concatenate([d[1], d[3]]) for d in data]))
        handles = []
        differ = False
        for k, (m, (beta, f_in, s, f_out)) in enumerate(zip(media, data)):
            model = as_btdf(m)
            name = labels[k] if labels else _name(model)
            shape = model.shape_values()
            if not all(f"{k}={v:.3g}" in name for k, v in shape.items()):
                name = f"{name} ({_values(shape)})"
            c = MEDIUM_COLORS[k % len(MEDIUM_COLORS)]
            (line,) = ax1.plot(np.radians(beta), _log_radius(f_in, lo), color=c, lw=1.4, label=name)
            handles.append(line)
            ax2.plot(np.radians(s), _log_radius(f_out, lo), color=c, lw=1.4)
            near = np.abs(beta - theta_i) <= 20
            x_in, y_in = beta[near] - theta_i, f_in[near]
            ax3.semilogy(x_in, y_in, color=c, lw=1.6)
            near = np.abs(s) <= 20
            y_out = np.interp(x_in, s, f_out)
            if np.max(np.abs(y_out / y_in - 1)) > 1e-3:
                differ = True
                ax3.semilogy(s[near], f_out[near], color=c, lw=1.1, ls="--")
        for ax in (ax1, ax2):
            _setup_log_polar(ax, lo, hi, zero="S", direction=1)
        r_top = hi - lo
        ax1.plot([math.radians(theta_i)] * 2, [0, r_top], color="0.5", lw=0.8, ls=":")
        ax1.set_title("(a) in the plane of incidence\n"
                      "angle = travel direction -T from straight down", pad=4)
        ax2.set_title("(b) out of the plane\nangle = travel direction -T from the unscattered -I",
                      pad=4)
        ax3.set_xlabel("deflection from the unscattered direction [deg]")
        ax3.set_ylabel("f_t [1/sr] (log scale)")
        ax3.set_title("(c) close-up" + (": solid in the plane, dashed out of it" if differ
                                         else " (in and out of the plane coincide)"))
        ax3.set_xlim(-20, 20)
        ax3.grid(True, which="major", alpha=0.3)
        fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.84, 0.0),
                   ncol=_legend_columns(handles), frameon=False,
                   title=f"incidence {theta_i:g}°, radius: f_t [1/sr], log")
    return fig


# --------------------------------------------------------------------------------------
# fig. 11: observed value against reflection angle
# --------------------------------------------------------------------------------------
SCALES = ("log", "linear", "peak", "tt2")
SCALE_WORDS = {"log": "observed value, log scale",
               "linear": "observed value, linear scale",
               "peak": "each curve divided by its own peak, linear scale",
               "tt2": "observed value divided by T_t² (clear medium as is), log scale"}


SHORT_WORDS = {"log": "observed value f, log scale", "linear": "observed value f",
               "peak": "f divided by its own peak, linear scale",
               "tt2": "f / T_t² (clear medium: f), log scale"}


def _medium_label(curve: Curve, with_brdf=True) -> str:
    head = f"{_name(curve.brdf)}, " if with_brdf else ""
    if curve.medium is None:
        return f"{head}clear medium"
    return f"{head}{_name(curve.medium)} ({_values(curve.medium.shape_values())})"


def _values(values: dict) -> str:
    return ", ".join(f"{k} = {v:g}" for k, v in values.items())


def draw_curves(ax, curves, scale="log", title=None, with_brdf=True) -> None:
    """Observed value against reflection angle on one axis.

    scale: "log" or "linear" (f as is), "peak" (each curve over its own peak, linear) or
    "tt2" (f / T_t^2, log: the medium passes single-scattered light twice, each time with
    weight T_t, so this takes out the media's different strengths; clear medium as is).
    """
    if scale not in SCALES:
        raise InputError(f"scale = {scale!r}; expected one of {', '.join(SCALES)}")
    k_medium = 0
    for curve in curves:
        if curve.medium is None:
            color, lw = CLEAR_COLOR, 1.8
        else:
            color, lw = MEDIUM_COLORS[k_medium % len(MEDIUM_COLORS)], 1.5
            k_medium += 1
        y = curve.values
        if scale == "peak":
            y = y / curve.metrics.peak
        elif scale == "tt2" and curve.medium is not None:
            y = y / curve.medium.lobe_scale() ** 2
        ax.plot(curve.theta_r, y, color=color, lw=lw, label=_medium_label(curve, with_brdf))
    if scale in ("log", "tt2"):
        ax.set_yscale("log")
        ax.set_ylabel("f(I, R) [1/sr], log scale" if scale == "log"
                      else "f(I, R) / T_t² [1/sr], log scale")
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
                draw_curves(axes[i, j], curves, scale,
                            f"({next(letters)}) {b}: {SHORT_WORDS[scale]}", with_brdf=False)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="upper center", ncol=len(labels), frameon=False,
                   bbox_to_anchor=(0.5, 1.0))
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
        fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.1 * len(cols), 4.0 * len(rows)),
                                 squeeze=False)
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
                    clip = (f"highlight clips: {100 * st.clipped_fraction:.2g} % of lit px"
                            if st.clipped else "nothing clips")
                else:
                    clip = f"peak/median {st.contrast:.3g}"
                ax.set_xlabel(f"peak {st.peak:.3g}, median {st.median:.3g} [1/sr]\n"
                              f"exposure {st.exposure:.3g}; {clip}", fontsize=8.5)
        curve = ("x/(1+x) (Reinhard, nothing clips)" if tone == "reinhard"
                 else "linear, clipped at white")
        fig.suptitle(f"Spheres lit from θ = {exp.light_theta:g}° (from the right), orthographic "
                     f"view; pixel = f·cos θ_i; exposure: median lit pixel → 0.18; "
                     f"tone curve {curve}; sRGB", fontsize=10, y=0.995)
        fig.tight_layout(rect=(0, 0, 1, 0.975))
    return fig


__all__ = ["Experiment", "run_experiment", "Curve", "CurveMetrics", "curve_metrics",
           "inplane_curve", "reflection_angles", "lobe_data", "transmission_data", "fig9",
           "fig10", "fig11", "fig12", "fig_curve", "draw_curves", "save_figure", "figure_bytes",
           "figure_format", "write_bytes_atomic", "SphereStats", "sphere_stats",
           "SCALES", "FORMATS"]
