"""The report of the reproduced simulation experiment (paper sec. 5.1; docs/model.md sec. 5, 6).

One list of blocks (headings, paragraphs, tables, figures) is written twice: as Markdown
(``report.md``, figures linked) and as a self-contained HTML page (``report.html``, figures
embedded as base64 PNG). The figures' captions are templates in report_captions.toml.
Every number and every verdict in the text is computed from the
:class:`veil.figures.Experiment`; nothing is copied from the paper.
"""

from __future__ import annotations

import base64
import functools
import html
import math
import os
import re
import tomllib
from importlib import resources

import numpy as np

from .. import __version__
from ..numbers import format_number
from .figures import Experiment, curve_metrics, lobe_data, transmission_data
from .render import ERROR_ANGLE, MID_GREY, VIEW


def _num(x) -> str:
    """Numbers of the reproduce report: three significant digits."""
    return format_number(x, 3)


def _deg(x) -> str:
    return "n/a" if math.isnan(x) else f"{x:.1f}°"


def _iso(medium) -> float:
    return float(medium.iso(medium.to_vector()))


def _trend(values) -> str:
    d = np.diff(np.asarray(values, float))
    if np.all(d > 0):
        return "increases"
    if np.all(d < 0):
        return "decreases"
    return "does not change monotonically"


# --------------------------------------------------------------------------------------
# content
# --------------------------------------------------------------------------------------
@functools.cache
def _captions() -> dict:
    """{"fig9": caption template, ...}: the figures' captions, prose kept as data."""
    text = resources.files(__package__).joinpath("report_captions.toml").read_text("utf-8")
    return tomllib.loads(text)


def _figure(files: dict, number: int, **fields) -> tuple:
    """The block of fig. ``number``: its PNG (``files["figN"]``) and its caption, whose
    template's fields are ``fields``."""
    key = f"fig{number}"
    return ("img", files[key], f"fig. {number}", _captions()[key].format(**fields))


def build_blocks(exp: Experiment, files: dict) -> list:
    """The report as blocks: ("h1"|"h2"|"p", text), ("ul", items), ("table", head, rows),
    ("img", file name, alt text, caption). ``files`` maps "fig9".."fig12" to PNG names."""
    media = sorted(exp.media, key=lambda m: exp.media[m].lobe_half_width())  # broadening
    blocks: list[tuple] = [
        ("h1", "The paper's simulation experiment, reproduced"),
        (
            "p",
            'Baba, Mukaigawa and Yagi, "BRDF Estimation Considering Scatterings of '
            'Illumination and Reflection", section 5.1 (figs. 9-12), recomputed from the '
            f"presets of docs/model.md section 6 with veil {__version__} "
            f"(`veil reproduce`). "
            f'Angles in degrees. Curves use the "{exp.accuracy}" quadrature; the '
            f'spheres use the "{exp.render_accuracy}" quadrature on an interpolated '
            f"table (see fig. 12).",
        ),
    ]

    blocks += _parameter_blocks(exp, media, files)
    blocks += _fig9_blocks(exp, media, files)
    blocks += _fig10_blocks(exp, media, files)
    blocks += _fig11_blocks(exp, media, files)
    blocks += _fig12_blocks(exp, media, files)
    blocks.append(("h2", "Observations"))
    blocks.append(("ul", _observations(exp, media)))
    return blocks


def _parameter_blocks(exp: Experiment, media: list, files: dict) -> list:
    """The parameters of the objects and media, and the geometry."""
    out: list = []
    out.append(("h2", "Parameters"))
    for kind, models in (("object", exp.brdfs), ("medium", exp.media)):
        for family in dict.fromkeys(type(m) for m in models.values()):
            names = [n for n, m in models.items() if type(m) is family]
            if kind == "medium":
                names = [n for n in media if n in names]
            head = [kind] + [p.name + (f" [{p.unit}]" if p.unit else "") for p in family.PARAMS]
            head += list(family.option_names())
            head.append(
                "facet half-mass angle" if kind == "object" else "forward peak of the lobe [1/sr]"
            )
            rows = []
            for n in names:
                m = models[n]
                extra = (
                    _deg(m.facet_half_angle())
                    if kind == "object"
                    else _num(m.lobe_scale() * float(m.phase(m.to_vector(), 0.0)))
                )
                rows.append(
                    [n]
                    + [_num(v) for v in m.as_dict().values()]
                    + [str(v) for v in m.options().values()]
                    + [extra]
                )
            out.append(("table", head, rows))
    out.append(
        (
            "p",
            f"Incidence for figs. 9-11: theta_i = {exp.theta_i:g}°, light and camera "
            "in the plane of incidence on opposite sides of the normal (docs/model.md "
            f"sec. 1). Fig. 12: distant point light at {exp.light_theta:g}° from the "
            f"viewing direction, orthographic camera, {exp.size} x {exp.size} pixels.",
        )
    )
    return out


def _fig9_blocks(exp: Experiment, media: list, files: dict) -> list:
    """Fig. 9: the objects' reflection lobes."""
    out: list = [("h2", "Fig. 9: reflection lobes of the objects")]
    widths = []
    for n, b in exp.brdfs.items():
        t_in, f_in, _, _ = lobe_data(b, exp.theta_i)
        cm = curve_metrics(t_in, f_in)
        widths.append(
            f"{n}: peak {_num(cm.peak)} /sr at theta_r = {cm.peak_angle:.1f}°, full "
            f"width at half maximum {cm.fwhm:.2f}°, diffuse level "
            f"{_num(float(np.interp(0.0, t_in, f_in)))} /sr"
        )
    out.append(_figure(files, 9, theta_i=exp.theta_i))
    out.append(("ul", widths))
    return out


def _fig10_blocks(exp: Experiment, media: list, files: dict) -> list:
    """Fig. 10: the media's transmission lobes."""
    out: list = [("h2", "Fig. 10: transmission lobes of the media")]
    items = []
    for n in media:
        beta, f_in, _, _ = transmission_data(exp.media[n], exp.theta_i)
        cm = curve_metrics(beta, f_in)
        med = exp.media[n]
        shape = ", ".join(f"{k} = {v:g}" for k, v in med.shape_values().items())
        items.append(
            f"{n} ({shape}): peak {_num(cm.peak)} /sr, half width at "
            f"half maximum {cm.fwhm / 2:.2f}°, isotropic floor "
            f"{_num(float(med.iso(med.to_vector())))} /sr"
        )
    out.append(_figure(files, 10, theta_i=exp.theta_i))
    out.append(("ul", items))
    hw = [curve_metrics(*transmission_data(exp.media[n], exp.theta_i)[:2]).fwhm / 2 for n in media]
    out.append(
        (
            "p",
            f"As g falls ({', '.join(media)}) the lobe's half width {_trend(hw)} "
            f"({', '.join(f'{w:.2f}°' for w in hw)}), with the same forward peak: the "
            "transmitted light spreads more, as the paper states.",
        )
    )
    return out


def _fig11_blocks(exp: Experiment, media: list, files: dict) -> list:
    """Fig. 11: the observed value against the reflection angle."""
    out: list = [("h2", "Fig. 11: observed value against reflection angle")]
    out.append(_figure(files, 11, theta_i=exp.theta_i))
    head = [
        "object",
        "medium",
        "peak f [1/sr]",
        "at theta_r",
        "FWHM",
        "f at theta_r = 0° [1/sr]",
        "peak / T_t²",
        "f(0°) / T_t²",
        "peak / f(0°)",
    ]
    rows = []
    for b in exp.brdfs:
        for m in ["clear"] + media:
            cm = exp.curves[(b, m)].metrics
            tt2 = 1.0 if m == "clear" else exp.media[m].lobe_scale() ** 2
            rows.append(
                [
                    b,
                    m,
                    _num(cm.peak),
                    f"{cm.peak_angle:.2f}°",
                    f"{cm.fwhm:.1f}°" if not math.isnan(cm.fwhm) else "n/a",
                    _num(cm.off_peak),
                    _num(cm.peak / tt2),
                    _num(cm.off_peak / tt2),
                    _num(cm.peak / cm.off_peak),
                ]
            )
    out.append(("table", head, rows))
    out.append(
        (
            "p",
            "FWHM: full width at half maximum of the whole curve (diffuse part "
            "included), from linear interpolation between samples 0.25° apart near the "
            'mirror angle (1° elsewhere). "n/a" would mean the curve stays above '
            "half its maximum up to 0° or 89°.",
        )
    )
    return out


def _fig12_blocks(exp: Experiment, media: list, files: dict) -> list:
    """Fig. 12: the spheres, and the rendering's accuracy."""
    out: list = [("h2", "Fig. 12: spheres rendered with the true and the apparent BRDFs")]
    out.append(_figure(files, 12, light_theta=exp.light_theta, mid_grey=MID_GREY, view=VIEW))
    head = [
        "object",
        "medium",
        "peak",
        "median lit",
        "peak / median",
        "pixels >= half peak",
        "brightest pixel (row, col)",
        "mirror prediction",
        "table nodes",
        f"interp. error, angles <= {ERROR_ANGLE:g}°",
        "interp. error, all / of peak",
    ]
    rows = []
    for b in exp.brdfs:
        for m in ["clear"] + media:
            st, r = exp.stats[(b, m)], exp.renders[(b, m)]
            err = "exact (f_r)" if not r.table_nodes else f"{100 * r.max_rel_error:.2g} %"
            err2 = (
                "-"
                if not r.table_nodes
                else f"{100 * r.max_rel_error_all:.2g} % / {100 * r.max_peak_error:.2g} %"
            )
            rows.append(
                [
                    b,
                    m,
                    _num(st.peak),
                    _num(st.median),
                    _num(st.contrast),
                    str(st.half_area),
                    f"({st.peak_pixel[0]}, {st.peak_pixel[1]})",
                    f"({st.mirror_pixel[0]:.1f}, {st.mirror_pixel[1]:.1f})",
                    str(r.table_nodes) if r.table_nodes else "-",
                    err,
                    err2,
                ]
            )
    out.append(("table", head, rows))
    checked = max((r.checked for r in exp.renders.values()), default=0)
    out.append(
        (
            "p",
            "The apparent BRDF is tabulated over the normal's polar coordinates "
            "about the half vector (dense near the specular peak) and interpolated "
            "by a bicubic spline of log f; the error columns compare the interpolated "
            f"value with direct engine evaluations at {checked} pixels per sphere "
            '(half of them among the brightest 10 %). "All" includes pixels within '
            f"{90 - ERROR_ANGLE:g}° of the terminator or the rim, where the pixel "
            'value itself is small; "of peak" is the largest error in units of the '
            "image's peak value.",
        )
    )
    return out


def _observations(exp: Experiment, media: list) -> list:
    items = []
    for b in exp.brdfs:
        clear = exp.curves[(b, "clear")].metrics
        ms = [exp.curves[(b, m)].metrics for m in media]
        tt2 = [exp.media[m].lobe_scale() ** 2 for m in media]
        peaks = [c.peak for c in ms]
        norm = [c.peak / t for c, t in zip(ms, tt2)]
        contrast = [c.peak / c.off_peak for c in ms]
        fwhm = [c.fwhm for c in ms]
        off = [c.off_peak / t for c, t in zip(ms, tt2)]
        names = ", ".join(media)
        items.append(
            f"{b}, specular peak as g falls ({names}): in absolute terms it {_trend(peaks)} "
            f"({', '.join(_num(p) for p in peaks)} /sr; clear {_num(clear.peak)}), because T_t "
            f"grows from {exp.media[media[0]].lobe_scale():g} to "
            f"{exp.media[media[-1]].lobe_scale():g}. Relative to "
            f"the medium's strength, peak / T_t² {_trend(norm)} "
            f"({', '.join(_num(p) for p in norm)}; "
            f"clear {_num(clear.peak)}), and relative to the diffuse level, peak / f(0°) "
            f"{_trend(contrast)} ({', '.join(_num(c) for c in contrast)}; clear "
            f'{_num(clear.peak / clear.off_peak)}). The paper\'s "weaker" holds in these '
            f"relative senses."
        )
        items.append(
            f"{b}, width: the full width at half maximum {_trend([clear.fwhm] + fwhm)} from "
            f"{clear.fwhm:.1f}° (clear) to {', '.join(f'{w:.1f}°' for w in fwhm)}: the highlight "
            f"spreads as g falls, as the paper states."
        )
        ratio = [o / clear.off_peak for o in off]
        near = [abs(r - 1) <= 0.2 for r in ratio]
        verdict = (
            "within 20 % of the clear medium's for every medium"
            if all(near)
            else "within 20 % of the clear medium's for "
            + (", ".join(m for m, ok in zip(media, near) if ok) or "no medium")
            + "; "
            + ", ".join(
                f"{m} is {r:.2f} times it" for m, r, ok in zip(media, ratio, near) if not ok
            )
        )
        items.append(
            f"{b}, diffuse part (f at theta_r = 0°, 45° from the mirror direction, over T_t²): "
            f"{', '.join(_num(o) for o in off)} against {_num(clear.off_peak)} /sr in a clear "
            f"medium, i.e. {verdict}."
        )
    return items + _isotropic_observations(exp, media) + _sphere_observations(exp, media)


def _isotropic_observations(exp: Experiment, media: list) -> list:
    """What the isotropic (T_d) terms add off the peak."""
    items = []
    for b in exp.brdfs:
        clear = exp.curves[(b, "clear")].metrics
        parts, ratios, fres = [], [], []
        for m in media:
            med = exp.media[m]
            full = exp.curves[(b, m)].metrics.off_peak
            single = exp.single_only[(b, m)]
            tt2 = med.lobe_scale() ** 2
            ratios.append(single / tt2 / clear.off_peak)
            # the lobe's boundary factors (Fresnel transmittances) on the way in at theta_i
            # and on the way out towards the camera at 0 deg: a(I) b(I) a(R) b(R)
            v = med.to_vector()
            ci = math.cos(math.radians(exp.theta_i))
            fres.append(
                float(
                    med.factor_first(v, ci)
                    * med.factor_second(v, ci)
                    * med.factor_first(v, 1.0)
                    * med.factor_second(v, 1.0)
                )
            )
            parts.append(
                f"{m} {_num(single / tt2)} ({100 * (1 - single / full):.0f} % "
                f"of the full f(0°) comes from the T_d terms)"
            )
        worst = max(abs(1 - r) for r in ratios)
        items.append(
            f"{b}, off the peak with the isotropic term switched off (T_d = 0), f(0°) / T_t² is "
            f"{'; '.join(parts)}, against {_num(clear.off_peak)} in a clear medium: ratios "
            f"{', '.join(f'{r:.3f}' for r in ratios)} (the Fresnel transmittance of the "
            f"medium's faces alone, F_t({exp.theta_i:g}°)² F_t(0°)², gives "
            f"{', '.join(sorted(set(f'{x:.3f}' for x in fres)))}). Without T_d the diffuse part "
            f"stays within {100 * worst:.0f} % of the clear medium's for every medium; where the "
            f"full value departs further, the medium's multiple scattering T_d is the cause "
            f"(T_d / T_t = "
            + ", ".join(f"{_iso(exp.media[m]) / exp.media[m].lobe_scale():.2g}" for m in media)
            + ")."
        )
    return items


def _sphere_observations(exp: Experiment, media: list) -> list:
    """The spheres of fig. 12: the highlight's area, contrast and position."""
    items = []
    for b in exp.brdfs:
        areas = [exp.stats[(b, k)].half_area for k in ["clear"] + media]
        con = [exp.stats[(b, k)].contrast for k in ["clear"] + media]
        pos = [exp.stats[(b, k)] for k in ["clear"] + media]
        off = max(
            math.hypot(s.peak_pixel[0] - s.mirror_pixel[0], s.peak_pixel[1] - s.mirror_pixel[1])
            for s in pos
        )
        items.append(
            f"{b} spheres (fig. 12, clear then {', '.join(media)}): the area at or above half "
            f"the peak {_trend(areas)} ({', '.join(map(str, areas))} pixels) and the peak over "
            f"the median lit pixel {_trend(con)} ({', '.join(_num(c) for c in con)}): the "
            f"highlight grows wider and weaker as g falls. The brightest pixel is at most "
            f"{off:.1f} pixels from where the mirror direction puts it."
        )
    return items


# --------------------------------------------------------------------------------------
# output
# --------------------------------------------------------------------------------------
def to_markdown(blocks) -> str:
    out = []
    for b in blocks:
        kind = b[0]
        if kind == "h1":
            out.append(f"# {b[1]}\n")
        elif kind == "h2":
            out.append(f"## {b[1]}\n")
        elif kind == "p":
            out.append(f"{b[1]}\n")
        elif kind == "ul":
            out.append("".join(f"- {item}\n" for item in b[1]))
        elif kind == "table":
            head, rows = b[1], b[2]
            lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
            lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
            out.append("\n".join(lines) + "\n")
        elif kind == "img":
            out.append(f"![{b[2]}]({b[1]})\n\n*{b[3]}*\n")
    return "\n".join(out)


def _inline(text: str) -> str:
    """HTML-escape, then render `code` spans."""
    parts = re.split(r"(`[^`]*`)", text)
    return "".join(
        f"<code>{html.escape(p[1:-1])}</code>"
        if p.startswith("`") and p.endswith("`")
        else html.escape(p)
        for p in parts
    )


_CSS = (
    "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;"
    "line-height:1.45;color:#222}table{border-collapse:collapse;margin:1em 0;font-size:0.9em}"
    "td,th{border:1px solid #bbb;padding:0.25em 0.5em;text-align:right}"
    "th{background:#eee}td:first-child,td:nth-child(2){text-align:left}"
    "figure{margin:1.5em 0}img{max-width:100%}figcaption{font-size:0.92em;color:#444}"
    "code{background:#f3f3f3;padding:0 0.2em}"
)


def to_html(blocks, directory) -> str:
    """Self-contained HTML: figures read from ``directory`` and embedded as base64."""
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        "<title>veil: the paper's simulation experiment, reproduced</title>",
        f"<style>{_CSS}</style></head><body>",
    ]
    for b in blocks:
        kind = b[0]
        if kind in ("h1", "h2", "p"):
            out.append(f"<{kind}>{_inline(b[1])}</{kind}>")
        elif kind == "ul":
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in b[1]) + "</ul>")
        elif kind == "table":
            head, rows = b[1], b[2]
            out.append(
                "<table><thead><tr>"
                + "".join(f"<th>{_inline(h)}</th>" for h in head)
                + "</tr></thead><tbody>"
                + "".join(
                    "<tr>" + "".join(f"<td>{_inline(str(c))}</td>" for c in row) + "</tr>"
                    for row in rows
                )
                + "</tbody></table>"
            )
        elif kind == "img":
            with open(os.path.join(directory, b[1]), "rb") as fh:
                data = base64.b64encode(fh.read()).decode("ascii")
            out.append(
                f'<figure><img alt="{html.escape(b[2])}" '
                f'src="data:image/png;base64,{data}">'
                f"<figcaption>{_inline(b[3])}</figcaption></figure>"
            )
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def write_report(exp: Experiment, directory, files: dict) -> tuple[str, str]:
    """Write report.md and report.html into ``directory`` (atomically); return their paths."""
    from .figures import write_bytes_atomic

    blocks = build_blocks(exp, files)
    md = os.path.join(directory, "report.md")
    page = os.path.join(directory, "report.html")
    write_bytes_atomic(md, to_markdown(blocks).encode("utf-8"))
    write_bytes_atomic(page, to_html(blocks, directory).encode("utf-8"))
    return md, page


__all__ = ["build_blocks", "to_markdown", "to_html", "write_report"]
