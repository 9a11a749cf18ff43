"""What every figure of veil shares: the matplotlib style and colours, a model's label,
and the files (PNG, PDF, SVG without time stamps, written atomically)."""

from __future__ import annotations

import io
import os

from ..errors import InputError
from ..io import write_bytes_atomic
from ..models import PRESETS

#: Figure formats :func:`save_figure` writes, by file suffix.
FORMATS = ("png", "pdf", "svg")
#: Colours: the clear medium is red as in the paper's fig. 11; media from light to dark.
CLEAR_COLOR = "#d62728"
MEDIUM_COLORS = ("#1f77b4", "#2ca02c", "#6a3d9a", "#ff7f0e", "#8c564b", "#17becf")
BRDF_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e")
STYLE = {
    "font.size": 10,
    "axes.titlesize": 10.5,
    "axes.labelsize": 10,
    "legend.fontsize": 9,
    "xtick.labelsize": 9,
    "ytick.labelsize": 9,
    "figure.dpi": 100,
    "svg.hashsalt": "veil",
    "pdf.compression": 6,
}


# --------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------
def figure_format(path) -> str:
    """The format of ``path`` from its suffix; ValueError for anything but png/pdf/svg."""
    ext = os.path.splitext(os.fspath(path))[1].lower().lstrip(".")
    if ext not in FORMATS:
        raise InputError(
            f"cannot tell the figure format of {os.fspath(path)!r}: use a file "
            f"name ending in {', '.join('.' + f for f in FORMATS)}"
        )
    return ext


def figure_bytes(fig, fmt: str, dpi=150) -> bytes:
    """The figure encoded as ``fmt``, without time stamps (deterministic output)."""
    buf = io.BytesIO()
    meta = {
        "png": {"Software": None},
        "pdf": {"CreationDate": None, "ModDate": None},
        "svg": {"Date": None},
    }[fmt]
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


def _values(values: dict) -> str:
    return ", ".join(f"{k} = {v:g}" for k, v in values.items())


__all__ = ["FORMATS", "STYLE", "figure_format", "figure_bytes", "save_figure"]
