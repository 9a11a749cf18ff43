"""The paper's figs. 9 and 10 (section 5.1): the reflection lobes f_r of the objects and
the transmission lobes f_t of the media for 45 deg incidence, in the plane of incidence,
out of it (log-polar) and close up (docs/model.md sec. 2, 3)."""

from __future__ import annotations

import math
import sys
import warnings
from typing import TYPE_CHECKING

import numpy as np

from ..engine.angles import direction
from ..engine.apparent import as_brdf, as_btdf, check_finite, reflectance
from ..errors import InputError
from .figure_style import BRDF_COLORS, MEDIUM_COLORS, _name, _style, _values

if TYPE_CHECKING:
    from matplotlib.figure import Figure


# --------------------------------------------------------------------------------------
# polar helpers (log radius)
# --------------------------------------------------------------------------------------
#: The decades of the log radius when no lobe of a figure has a positive value.
EMPTY_DECADES = (-1, 1)


def _decades(values, most=6) -> tuple[int, int]:
    """(lo, hi) decades for a log radius: the smallest positive value sits a little outside
    the origin; :data:`EMPTY_DECADES` when no value is positive (nothing to draw on a log
    scale)."""
    v = np.asarray(values, dtype=float)
    v = v[v > 0]
    if v.size == 0:
        return EMPTY_DECADES
    hi = math.ceil(math.log10(v.max()) + 1e-9)
    lo = math.floor(math.log10(v.min()) - 0.3)
    return max(lo, hi - most), hi


def _power(decade: int) -> float:
    """10 ** ``decade`` as a float in the normal float64 range (an axis limit)."""
    return min(max(10.0 ** min(max(decade, -400), 308), sys.float_info.min), sys.float_info.max)


#: The largest value the figures draw: matplotlib's log transforms and tick formatters
#: overflow float64 near its top (1.8e308), margins and ticks included.
PLOT_MAX = 1e250


def check_plottable(values, what: str, models) -> np.ndarray:
    """``values``, or an InputError naming the ``models`` when one is above PLOT_MAX."""
    values = np.asarray(values, dtype=float)
    top = float(np.max(np.abs(values), initial=0.0))
    if top > PLOT_MAX:
        names = ", ".join(str(m) for m in models if m is not None)
        raise InputError(
            f"{what} reaches {top:.3g} with {names}: above {PLOT_MAX:g}, the largest value "
            f"the figures draw; give smaller scale coefficients (the values scale with them)"
        )
    return values


def _close_up_limits(values: list, lo: int, hi: int) -> tuple[float | None, float | None]:
    """(bottom, top) of a log close-up: the decade below the smallest positive of ``values``
    (top left to matplotlib); when that is below the polar panels' decade ``lo`` (a lobe
    that falls to 0 or nearly), the decades ``lo`` to ``hi``, as when no value is positive."""
    v = np.concatenate([np.ravel(x) for x in values]) if values else np.zeros(0)
    v = v[v > 0]
    if v.size and math.floor(math.log10(v.min())) >= lo:
        return _power(math.floor(math.log10(v.min()))), None
    return _power(lo), _power(hi)


def _zero_lobes(ax, names: list, data: list, quantity: str, theta_i: float) -> set:
    """The indices of the lobes whose ``quantity`` is 0 in every direction drawn; they get a
    note on ``ax`` (the close-up) and a warning: a log scale cannot show them."""
    zero = {k for k, d in enumerate(data) if not (np.any(d[1] > 0) or np.any(d[3] > 0))}
    for k in sorted(zero):
        warnings.warn(
            f"{quantity} of {names[k]} is 0 in every direction at incidence {theta_i:g} deg: "
            f"nothing to draw on the figure's log scales",
            UserWarning,
            stacklevel=3,
        )
    if zero and len(zero) == len(names):
        ax.text(
            0.5,
            0.5,
            f"{quantity} = 0 in every direction:\nnothing to draw on a log scale",
            transform=ax.transAxes,
            ha="center",
            va="center",
            color="0.3",
        )
    return zero


def _zero_handle(ax, name: str, quantity: str, color: str):
    """A legend entry (an empty line on ``ax``) for a lobe that is 0 everywhere."""
    (line,) = ax.plot([], [], color=color, lw=1.4, label=f"{name}: {quantity} = 0, not drawn")
    return line


def _log_close_up(ax, values: list, lo: int, hi: int) -> None:
    """Log y scale on the close-up ``ax`` with :func:`_close_up_limits` of ``values``."""
    bottom, top = _close_up_limits(values, lo, hi)
    ax.set_yscale("log")
    ax.set_ylim(bottom=bottom, top=top)


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
    check_plottable(np.concatenate([f_in, f_out]), "f_r", [b])
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
    """Reflection lobes f_r for incidence theta_i: in plane, out of plane, close-up (log).
    A lobe that is 0 everywhere cannot be drawn on the log scales: its legend entry, a note
    and a warning say so."""
    ctx, plt = _style()
    with ctx:
        fig, ax1, ax2, ax3 = _three_panels(plt)
        data = [lobe_data(b, theta_i) for b in brdfs]
        names = [labels[k] if labels else _name(as_brdf(b)) for k, b in enumerate(brdfs)]
        lo, hi = _decades(np.concatenate([np.concatenate([d[1], d[3]]) for d in data]))
        zero = _zero_lobes(ax3, names, data, "f_r", theta_i)
        handles = []
        for k, (name, (t_in, f_in, s, f_out)) in enumerate(zip(names, data)):
            c = BRDF_COLORS[k % len(BRDF_COLORS)]
            if k in zero:
                handles.append(_zero_handle(ax1, name, "f_r", c))
                continue
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
        _log_close_up(ax3, [d[1] for d in data], lo, hi)
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
    f_in = np.asarray(m.evaluate(v, np.broadcast_to(wi, t.shape), t), dtype=float)
    s = np.unique(np.concatenate([np.linspace(-89.5, 89.5, 359), np.arange(-20, 20.001, 0.05)]))
    sr = np.radians(s)
    t2 = np.cos(sr)[:, None] * wi + np.sin(sr)[:, None] * np.array([0.0, 1.0, 0.0])
    ok = t2[:, 2] > math.cos(math.radians(89.9))
    f_out = np.asarray(m.evaluate(v, np.broadcast_to(wi, t2[ok].shape), t2[ok]), dtype=float)
    check_finite(np.concatenate([f_in, f_out]), "the transmission f_t", [m])
    check_plottable(np.concatenate([f_in, f_out]), "the transmission f_t", [m])
    return beta, f_in, s[ok], f_out


def _medium_names(media, labels) -> list:
    """The legend names of ``media``: ``labels`` or the model's name, plus its shape values
    when the name does not show them."""
    names = []
    for k, m in enumerate(media):
        model = as_btdf(m)
        name = labels[k] if labels else _name(model)
        shape = model.shape_values()
        if not all(f"{p}={v:.3g}" in name for p, v in shape.items()):
            name = f"{name} ({_values(shape)})"
        names.append(name)
    return names


def _differ(y_in, y_out) -> bool:
    """Whether two curves differ by more than 1e-3 relative to ``y_in`` anywhere."""
    return bool(np.any(np.abs(y_out - y_in) > 1e-3 * np.abs(y_in)))


def fig10(media=("BTDF1", "BTDF2", "BTDF3"), theta_i=45.0, labels=None) -> Figure:
    """Transmission lobes f_t for incidence theta_i: in plane, out of plane, close-up (log).
    A lobe that is 0 everywhere cannot be drawn on the log scales: its legend entry, a note
    and a warning say so."""
    ctx, plt = _style()
    with ctx:
        fig, ax1, ax2, ax3 = _three_panels(plt)
        data = [transmission_data(m, theta_i) for m in media]
        names = _medium_names(media, labels)
        lo, hi = _decades(np.concatenate([np.concatenate([d[1], d[3]]) for d in data]))
        zero = _zero_lobes(ax3, names, data, "f_t", theta_i)
        handles = []
        differ = False
        for k, (name, (beta, f_in, s, f_out)) in enumerate(zip(names, data)):
            c = MEDIUM_COLORS[k % len(MEDIUM_COLORS)]
            if k in zero:
                handles.append(_zero_handle(ax1, name, "f_t", c))
                continue
            (line,) = ax1.plot(np.radians(beta), _log_radius(f_in, lo), color=c, lw=1.4, label=name)
            handles.append(line)
            ax2.plot(np.radians(s), _log_radius(f_out, lo), color=c, lw=1.4)
            near = np.abs(beta - theta_i) <= 20
            x_in, y_in = beta[near] - theta_i, f_in[near]
            ax3.semilogy(x_in, y_in, color=c, lw=1.6)
            near = np.abs(s) <= 20
            if _differ(y_in, np.interp(x_in, s, f_out)):
                differ = True
                ax3.semilogy(s[near], f_out[near], color=c, lw=1.1, ls="--")
        if len(zero) == len(data):
            _log_close_up(ax3, [], lo, hi)
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
