"""The paper's figs. 9 and 10 (section 5.1): the reflection lobes f_r of the objects and
the transmission lobes f_t of the media for 45 deg incidence, in the plane of incidence,
out of it (log-polar) and close up (docs/model.md sec. 2, 3)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..engine.angles import direction
from ..engine.apparent import as_brdf, as_btdf, reflectance
from .figure_style import BRDF_COLORS, MEDIUM_COLORS, _name, _style, _values

if TYPE_CHECKING:
    from matplotlib.figure import Figure


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
    ax.set_yticklabels(
        [f"$10^{{{lo + t}}}$" if (hi - lo - t) % step == 0 else "" for t in ticks], fontsize=8
    )
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
    t_in = np.unique(
        np.concatenate(
            [np.linspace(-89.5, 89.5, 359), np.arange(theta_i - 15, theta_i + 15.001, 0.05)]
        )
    )
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
        ax1.annotate(
            "",
            xy=(0, 0),
            xytext=(math.radians(-theta_i), r_top),
            arrowprops=dict(arrowstyle="->", color="0.3", lw=1.2),
        )
        ax1.text(math.radians(-theta_i + 7), r_top * 0.8, "light", color="0.3", ha="center")
        ax1.plot([math.radians(theta_i)] * 2, [0, r_top], color="0.5", lw=0.8, ls=":")
        ax1.set_title("(a) in the plane of incidence\nangle = signed reflection angle θ_r", pad=4)
        ax2.set_title(
            "(b) out of the plane, through the mirror direction\nangle = from the mirror direction",
            pad=4,
        )
        floor = min(float(np.min(d[1])) for d in data)
        ax3.set_ylim(bottom=10 ** math.floor(math.log10(floor)))
        ax3.set_xlabel("angle from the mirror direction [deg]")
        ax3.set_ylabel("f_r [1/sr] (log scale)")
        ax3.set_title("(c) close-up: solid in the plane,\ndashed out of the plane")
        _close_up_and_legend(
            fig, ax3, handles, 15, f"incidence {theta_i:g}°, radius: f_r [1/sr], log"
        )
    return fig


# --------------------------------------------------------------------------------------
# fig. 10: transmission lobes
# --------------------------------------------------------------------------------------
def transmission_data(
    medium, theta_i=45.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """f_t(I, T) against the propagation direction -T of the transmitted light.

    In the plane: beta = signed angle of -T from the downward vertical (beta = theta_i is the
    unscattered continuation of the incident ray). Out of the plane: angle s of -T from -I,
    perpendicular to the plane of incidence.
    """
    m = as_btdf(medium)
    v = m.to_vector()
    wi = np.asarray(direction(theta_i, 180.0))
    beta = np.unique(
        np.concatenate(
            [np.linspace(-89.5, 89.5, 359), np.arange(theta_i - 20, min(theta_i + 20, 89.9), 0.05)]
        )
    )
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
        ax1.set_title(
            "(a) in the plane of incidence\nangle = travel direction -T from straight down", pad=4
        )
        ax2.set_title(
            "(b) out of the plane\nangle = travel direction -T from the unscattered -I", pad=4
        )
        ax3.set_xlabel("deflection from the unscattered direction [deg]")
        ax3.set_ylabel("f_t [1/sr] (log scale)")
        ax3.set_title(
            "(c) close-up"
            + (
                ": solid in the plane, dashed out of it"
                if differ
                else " (in and out of the plane coincide)"
            )
        )
        _close_up_and_legend(
            fig, ax3, handles, 20, f"incidence {theta_i:g}°, radius: f_t [1/sr], log"
        )
    return fig


def _close_up_and_legend(fig, ax, handles, half_range: float, title: str) -> None:
    """The close-up panel's range (+- ``half_range`` deg) and grid, and the figure's legend
    of ``handles`` below the polar panels under ``title``."""
    ax.set_xlim(-half_range, half_range)
    ax.grid(True, which="major", alpha=0.3)
    fig.legend(
        handles=handles,
        loc="lower center",
        bbox_to_anchor=(0.84, 0.0),
        ncol=_legend_columns(handles),
        frameon=False,
        title=title,
    )


__all__ = ["lobe_data", "transmission_data", "fig9", "fig10"]
