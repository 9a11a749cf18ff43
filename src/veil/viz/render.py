"""Spheres rendered with a true or an apparent BRDF (paper fig. 12, docs/model.md sec. 1, 5).

Scene: a unit sphere seen by an orthographic camera looking down the z axis (the camera
direction R is +z everywhere), lit by a distant point light from direction L. A visible,
lit point with normal N gets the linear value

    pixel = f(I, R) cos(theta_i),      I = L, both angles measured from N   (paper eq. 1)

where f is the object's own f_r (no medium) or the apparent reflectance of docs/model.md sec. 5.
Unlit points (N . L <= 0) and the background are exactly 0. The image spans [-1.05, 1.05]
sphere radii in x (right) and y (up); the light's azimuth phi is measured from +x towards +y.

The apparent BRDF is isotropic and mirror symmetric, so for one light it depends on N only
through polar coordinates about the half vector H = (L + R)/|L + R|: u = angle(N, H) and
the azimuth w of N about H (w = 0 towards L). The engine is evaluated once on a table in
(u, w) -- dense in u near the specular peak (u = 0), uniform in w over [0, 180] -- and the
image is a bicubic spline of log f over that table. :func:`render` measures the
interpolation error against direct engine evaluations at sampled pixels. The scene's
geometry (normals, angles, the half vector's frame): :mod:`veil.viz.sphere_geometry`; the
(u, w) table and its spline: :mod:`veil.viz.render_table`.
"""

from __future__ import annotations

import io
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from ..engine.apparent import as_brdf, as_btdf
from ..engine.evaluator import check_accuracy
from ..errors import InputError
from .render_table import (
    W_NODES,
    ApparentTable,
    auto_density,
    build_table,
    evaluate,
    peak_width,
    u_nodes,
)
from .sphere_geometry import (
    VIEW,
    half_vector_frame,
    highlight_pixel,
    light_direction,
    local_angles,
    pixel_normals,
    sphere_normals,
)

#: Largest light angle from the view axis (deg) that :func:`render` accepts.
MAX_LIGHT_THETA = 120.0
#: Mid-grey convention of the automatic exposure: the median lit pixel maps to this.
MID_GREY = 0.18
#: The headline interpolation error covers pixels with both polar angles up to this (deg);
#: beyond it (terminator and silhouette, where cos(theta_i) or the projected area vanish)
#: the error is reported separately.
ERROR_ANGLE = 80.0


# --------------------------------------------------------------------------------------
# rendering
# --------------------------------------------------------------------------------------
@dataclass
class Rendering:
    """A rendered sphere: linear image plus what it took and how accurate it is."""

    image: np.ndarray  # linear values, (size, size), 0 outside the lit disk
    brdf: object
    medium: object
    light_theta: float
    light_phi: float
    accuracy: str
    samples: int
    table_nodes: int  # engine evaluations for the table (0: direct f_r)
    checked: int  # pixels compared with direct engine evaluations
    #: max |interp - direct| / direct, checked pixels with both angles <= 80 deg
    max_rel_error: float
    max_rel_error_all: float  # the same over all checked pixels (grazing ones included)
    max_peak_error: float  # max |interp - direct| cos(theta_i) / image maximum, all checked
    seconds: float

    def summary(self) -> str:
        med = "clear" if self.medium is None else str(self.medium)
        s = (
            f"{self.brdf} through {med}: light at theta {self.light_theta:g} deg, "
            f"phi {self.light_phi:g} deg; peak {self.image.max():.4g}"
        )
        if self.table_nodes:
            s += (
                f"; table {self.table_nodes} nodes; interpolation error at {self.checked} "
                f"pixels: {100 * self.max_rel_error:.2g} % (angles <= {ERROR_ANGLE:g} deg), "
                f"{100 * self.max_rel_error_all:.2g} % (all), "
                f"{100 * self.max_peak_error:.2g} % of the peak"
            )
        return s


def _check_args(size, light_theta, light_phi, samples, accuracy):
    for name, v in (("light_theta", light_theta), ("light_phi", light_phi)):
        if not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
            raise InputError(f"{name} = {v!r} is not a finite number (degrees)")
    if not 0.0 <= light_theta <= MAX_LIGHT_THETA:
        raise InputError(
            f"light_theta = {light_theta:g} deg is outside [0, {MAX_LIGHT_THETA:g}]"
            f" (a light further behind the sphere lights only a thin crescent at "
            f"grazing angles, where the table is not reliable)"
        )
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or not 8 <= size <= 4096:
        raise InputError(f"size = {size!r} must be an integer in [8, 4096] pixels")
    if (
        not isinstance(samples, (int, np.integer))
        or isinstance(samples, bool)
        or not 1 <= samples <= 8
    ):
        raise InputError(f"samples = {samples!r} must be an integer in [1, 8] per pixel axis")
    check_accuracy(accuracy)


# --------------------------------------------------------------------------------------
# memory
# --------------------------------------------------------------------------------------
#: Subpixels shaded at a time: the image is rendered in bands of pixel rows holding at most
#: this many samples, so the working memory does not grow with --samples or --size.
PIXEL_CHUNK = 1 << 19
#: Bytes per subpixel of a band (normals, angles, masks, table look-up): about 60 measured,
#: twice that for the estimate.
BAND_BYTES_PER_SUBPIXEL = 120
#: Bytes per image pixel of the whole command (the linear image, its mask, the exposure,
#: clipping count and tone mapping of ``veil render``, the PNG): about 30 measured.
BYTES_PER_PIXEL = 36
#: What a process running the engine holds besides (Python, JAX, numpy, the compiled
#: engine): 404 MiB measured for a 256 px render.
BASE_BYTES = 480 << 20
# Measured peaks of `veil render --brdf BRDF1 --medium BTDF3` (/usr/bin/time, max RSS):
# 256 px 0.41 GB, 4096 px 0.92 GB with 1 or with 8 x 8 samples; estimates 0.49, 1.17 GB.


def memory_estimate(size: int, samples: int = 1) -> int:
    """Bytes :func:`render` (and ``veil render``) need at most for a ``size`` image with
    ``samples`` x ``samples`` samples per pixel: the image itself plus one band."""
    per_row = size * samples * samples
    band = min(size, max(1, PIXEL_CHUNK // per_row)) * per_row
    return BASE_BYTES + BYTES_PER_PIXEL * size * size + BAND_BYTES_PER_SUBPIXEL * band


def available_memory() -> int | None:
    """Bytes the machine can give this process now (MemAvailable of /proc/meminfo, else the
    free physical pages), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(size: int, samples: int, names=("size", "samples")) -> None:
    """InputError when :func:`memory_estimate` exceeds :func:`available_memory`; the message
    gives the estimate and the options (``names``) to lower."""
    need, have = memory_estimate(size, samples), available_memory()
    if have is not None and need > have:
        raise InputError(
            f"rendering {size} x {size} pixels with {samples} x {samples} samples "
            f"needs about {need / 2**30:.2f} GiB of memory, more than the "
            f"{have / 2**30:.2f} GiB available: lower {names[0]} (the memory "
            f"grows with its square) or {names[1]}"
        )


def _check_pixels(values, lit, count, rng_seed=20110901):
    """Deterministic pixel sample: half among the brightest 10 % of lit pixels, half uniform."""
    idx = np.flatnonzero(lit)
    if idx.size == 0 or count <= 0:
        return idx[:0]
    rng = np.random.default_rng(rng_seed)
    bright = idx[values.ravel()[idx] >= np.quantile(values.ravel()[idx], 0.9)]
    top = idx[np.argmax(values.ravel()[idx])]
    n_b = min(bright.size, count // 2)
    pick = [
        np.array([top]),
        rng.choice(bright, n_b, replace=False),
        rng.choice(idx, min(idx.size, count - n_b - 1), replace=False),
    ]
    return np.unique(np.concatenate(pick))[: max(count, 1)]


def _uw(normal, frame):
    """Polar coordinates (u, w) in degrees of normals about H (see :class:`ApparentTable`)."""
    h, e1, e2 = frame
    u = np.degrees(np.arccos(np.clip(normal @ h, -1.0, 1.0)))
    return u, np.degrees(np.arctan2(normal @ e2, normal @ e1))


def _shade(b, table, frame, light, normal, inside, padded=None):
    """f and the lit mask at ``normal`` (..., 3): the table's interpolation, or f_r directly
    (evaluated on ``padded`` configurations, so that every band has one shape)."""
    cos_i = normal @ light
    lit = inside & (cos_i > 0.0)
    f = np.zeros(lit.shape)
    if table is None:
        ti, tr, dp = local_angles(normal[lit], light)
        n = ti.size
        if padded and n:
            ti, tr, dp = (np.concatenate([a, np.full(padded - n, 45.0)]) for a in (ti, tr, dp))
        f[lit] = evaluate(b, None, ti, tr, dp)[:n] if n else 0.0
    else:
        u, w = _uw(normal[lit], frame)
        f[lit] = table(u, w)
    return f, lit, cos_i


def _table_errors(
    b, m, table, image, lit_px, check, light, frame, peak: float, accuracy: str, bar
) -> tuple[int, float, float, float]:
    """The table's interpolation error against the engine at ``check`` lit pixels: (pixels
    checked, largest relative error with both angles <= ERROR_ANGLE, over all, in units of
    the image's peak)."""
    size = image.shape[0]
    pick = _check_pixels(image, lit_px, check)
    normal, _ = pixel_normals(size, pick)
    ti, tr, dp = local_angles(normal, light)
    direct = evaluate(b, m, ti, tr, dp, accuracy=accuracy, progress=bar.advance)
    interp = table(*_uw(normal, frame))
    rel = np.abs(interp - direct) / direct
    inner = np.maximum(ti, tr) <= ERROR_ANGLE
    max_rel = float(rel[inner].max()) if inner.any() else 0.0
    diff = np.abs(interp - direct) * (normal @ light)
    return pick.size, max_rel, float(rel.max()), float(np.max(diff) / max(peak, 1e-300))


def _shade_bands(
    b, table, frame, light, size: int, samples: int, rows: int, bar
) -> tuple[np.ndarray, np.ndarray, float]:
    """The image shaded in bands of ``rows`` pixel rows: (linear image, the pixel centres
    on the lit disk, the largest linear sample value)."""
    per_row = size * samples * samples
    image = np.zeros((size, size))
    lit_px = np.zeros((size, size), dtype=bool)  # pixel centres on the lit disk
    peak = 0.0  # largest linear sample value
    for first in range(0, size, rows):
        stop = min(size, first + rows)
        normal, inside = sphere_normals(size, samples, (first, stop))
        f, lit, cos_i = _shade(b, table, frame, light, normal, inside, padded=rows * per_row)
        linear = np.where(lit, f * np.where(lit, cos_i, 0.0), 0.0)
        peak = max(peak, float(linear.max()))
        if samples > 1:
            image[first:stop] = linear.reshape(stop - first, samples, size, samples).mean(
                axis=(1, 3)
            )
            centres, on_disk = pixel_normals(size, np.arange(first * size, stop * size))
            lit_px[first:stop] = (on_disk & (centres @ light > 0.0)).reshape(stop - first, size)
        else:
            image[first:stop], lit_px[first:stop] = linear, lit
        del normal, inside, f, lit, cos_i, linear
        bar.band()
    return image, lit_px, peak


def render(
    brdf,
    medium=None,
    light_theta=45.0,
    light_phi=0.0,
    size=256,
    *,
    accuracy="fast",
    samples=1,
    check=64,
    density=1.0,
    progress=False,
) -> Rendering:
    """Render the sphere (module docstring) and measure the interpolation error.

    brdf, medium : models or preset names; ``medium=None`` renders the true f_r directly.
    light_theta, light_phi : light direction in degrees (polar angle from the view axis).
    size : image width and height in pixels; samples : k x k samples per pixel (1: centre).
    check : pixels re-evaluated with the engine directly at their centres to measure the
        interpolation error.
    density : table refinement factor (1 is the default grid). Lights more than 60 deg from
        the view get up to twice the density (:func:`auto_density`): the lit, visible part of
        the table shrinks towards grazing angles there.

    The image is shaded in bands of at most :data:`PIXEL_CHUNK` samples, so memory grows
    with the image (:func:`memory_estimate`), not with the samples; a size that would not
    fit in the available memory is an InputError saying how much it needs.
    """
    _check_args(size, light_theta, light_phi, samples, accuracy)
    b = as_brdf(brdf)
    m = None if medium is None else as_btdf(medium)
    if not (isinstance(check, (int, np.integer)) and 0 <= check <= 4096):
        raise InputError(f"check = {check!r} must be an integer in [0, 4096] pixels")
    if not (isinstance(density, (int, float)) and 0.25 <= density <= 8):
        raise InputError(f"density = {density!r} must be in [0.25, 8]")
    check_memory(size, samples)
    t0 = time.perf_counter()
    density = density * auto_density(float(light_theta))
    light = light_direction(float(light_theta), float(light_phi))
    frame = half_vector_frame(light)
    per_row = size * samples * samples
    rows = max(1, PIXEL_CHUNK // per_row)  # pixel rows per band
    bands = range(0, size, rows)

    with _Progress(progress, f"rendering {size}x{size}") as bar:
        table = None
        if m is not None:
            n_table = len(u_nodes(peak_width(b, m), density)) * max(
                5, int(round((W_NODES - 1) * density)) + 1
            )
            bar.start(n_table + (check if check else 0), len(bands))
            table = build_table(
                b, m, light, accuracy=accuracy, density=density, progress=bar.advance
            )
        else:
            bar.start(0, len(bands))
        image, lit_px, peak = _shade_bands(b, table, frame, light, size, samples, rows, bar)
        checked, max_rel, max_rel_all, max_peak = 0, 0.0, 0.0, 0.0
        if table is not None and check:
            checked, max_rel, max_rel_all, max_peak = _table_errors(
                b, m, table, image, lit_px, check, light, frame, peak, accuracy, bar
            )
    return Rendering(
        image=image,
        brdf=b,
        medium=m,
        light_theta=float(light_theta),
        light_phi=float(light_phi),
        accuracy=accuracy,
        samples=int(samples),
        table_nodes=0 if table is None else table.nodes,
        checked=checked,
        max_rel_error=max_rel,
        max_rel_error_all=max_rel_all,
        max_peak_error=max_peak,
        seconds=time.perf_counter() - t0,
    )


def render_sphere(
    brdf,
    medium=None,
    light_theta=45.0,
    light_phi=0.0,
    size=256,
    *,
    accuracy="fast",
    samples=1,
    progress=False,
) -> np.ndarray:
    """Linear image (size, size) of the sphere under ``brdf`` seen through ``medium``.

    See :func:`render` (which also reports the interpolation error) and the module docstring.
    """
    return render(
        brdf,
        medium,
        light_theta,
        light_phi,
        size,
        accuracy=accuracy,
        samples=samples,
        check=0,
        progress=progress,
    ).image


class _Progress:
    """A rich progress bar on stderr when ``enabled``; a no-op otherwise. It counts engine
    evaluations (the table, the checked pixels) and the bands of the image."""

    def __init__(self, enabled, label):
        self.enabled, self.label = enabled, label
        self._p = self._task = self._bands = None

    def __enter__(self):
        if self.enabled:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._p = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=Console(stderr=True),
                transient=True,
            )
            self._p.__enter__()
        return self

    def start(self, total, bands=0):
        if self._p is not None:
            if total:
                self._task = self._p.add_task(f"{self.label}: engine evaluations", total=total)
            if bands > 1:
                self._bands = self._p.add_task(f"{self.label}: bands of pixel rows", total=bands)

    def advance(self, k):
        if self._p is not None and self._task is not None:
            self._p.advance(self._task, k)

    def band(self):
        if self._p is not None and self._bands is not None:
            self._p.advance(self._bands, 1)

    def __exit__(self, *exc):
        if self._p is not None:
            self._p.__exit__(*exc)
        return False


# --------------------------------------------------------------------------------------
# tone mapping
# --------------------------------------------------------------------------------------
def auto_exposure(linear) -> float:
    """Exposure that maps the median of the lit (non-zero) pixels to :data:`MID_GREY`."""
    lit = np.asarray(linear)[np.asarray(linear) > 0]
    if lit.size == 0:
        return 1.0
    return MID_GREY / float(np.median(lit))


def srgb_encode(x) -> np.ndarray:
    """The sRGB transfer function for linear values in [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


TONES = ("clip", "reinhard")


def tone_map(linear, exposure, tone="clip") -> np.ndarray:
    """8-bit image of ``exposure * linear``, sRGB-encoded.

    tone "clip": values above 1 clip to white (the pixel scale stays linear below);
    tone "reinhard": x / (1 + x) first (Reinhard's global operator): never clips, compresses
    highlights so that their relative strength stays visible.
    """
    if not (
        isinstance(exposure, (int, float, np.floating)) and math.isfinite(exposure) and exposure > 0
    ):
        raise InputError(f"exposure = {exposure!r} must be a positive number")
    if tone not in TONES:
        raise InputError(f"tone = {tone!r}; expected one of {', '.join(TONES)}")
    linear = np.asarray(linear, dtype=float)
    out = np.empty(linear.shape, dtype=np.uint8)
    flat_in, flat_out = linear.reshape(-1), out.reshape(-1)
    for start in range(0, flat_in.size, PIXEL_CHUNK):  # a few temporaries of a band each
        x = exposure * flat_in[start : start + PIXEL_CHUNK]
        if tone == "reinhard":
            x = x / (1.0 + x)
        flat_out[start : start + PIXEL_CHUNK] = np.round(255.0 * srgb_encode(x))
    return out


def clipping(linear, exposure, tone="clip") -> tuple[int, float, float]:
    """(clipped pixels, their fraction of the lit pixels, peak in units of full scale).

    Nothing clips under the "reinhard" tone curve.
    """
    lin = np.asarray(linear)
    n_lit = int(np.count_nonzero(lin > 0))
    with np.errstate(over="ignore"):  # an overflowing peak: the caller refuses it
        n_clip = int(np.count_nonzero(exposure * lin > 1.0)) if tone == "clip" else 0
        return n_clip, (n_clip / n_lit if n_lit else 0.0), float(exposure * lin.max())


def png_bytes(image_u8, text=None) -> bytes:
    """An 8-bit greyscale PNG (Pillow, matplotlib's image library) with optional text chunks."""
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for key, value in (text or {}).items():
        info.add_text(key, str(value))
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image_u8, dtype=np.uint8)).save(
        buf, format="png", pnginfo=info
    )
    return buf.getvalue()


__all__ = [
    "render",
    "render_sphere",
    "Rendering",
    "evaluate",
    "auto_exposure",
    "tone_map",
    "clipping",
    "srgb_encode",
    "highlight_pixel",
    "build_table",
    "ApparentTable",
    "local_angles",
    "light_direction",
    "half_vector_frame",
    "sphere_normals",
    "png_bytes",
    "TONES",
    "memory_estimate",
    "available_memory",
    "check_memory",
    "pixel_normals",
    "VIEW",
]
