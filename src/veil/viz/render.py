"""Spheres rendered with a true or an apparent BRDF (paper fig. 12, MODEL.md sec. 1, 5).

Scene: a unit sphere seen by an orthographic camera looking down the z axis (the camera
direction R is +z everywhere), lit by a distant point light from direction L. A visible,
lit point with normal N gets the linear value

    pixel = f(I, R) cos(theta_i),      I = L, both angles measured from N   (paper eq. 1)

where f is the object's own f_r (no medium) or the apparent reflectance of MODEL.md sec. 5.
Unlit points (N . L <= 0) and the background are exactly 0. The image spans [-1.05, 1.05]
sphere radii in x (right) and y (up); the light's azimuth phi is measured from +x towards +y.

The apparent BRDF is isotropic and mirror symmetric, so for one light it depends on N only
through polar coordinates about the half vector H = (L + R)/|L + R|: u = angle(N, H) and
the azimuth w of N about H (w = 0 towards L). The engine is evaluated once on a table in
(u, w) -- dense in u near the specular peak (u = 0), uniform in w over [0, 180] -- and the
image is a bicubic spline of log f over that table. :func:`render` measures the
interpolation error against direct engine evaluations at sampled pixels.
"""

from __future__ import annotations

import io
import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..errors import InputError
from ..engine.apparent import RULES, as_brdf, as_btdf
from ..engine.evaluator import evaluate as chunked

#: Half width of the view in sphere radii (orthographic camera; a 5 % margin around the rim).
VIEW = 1.05
#: Largest light angle from the view axis (deg) that :func:`render` accepts.
MAX_LIGHT_THETA = 120.0
#: Configurations per engine call. Every call has this shape, so the engine compiles once.
CHUNK = 256
#: Polar angles of table nodes beyond this (degrees) are evaluated at this angle: nodes
#: outside the lit, visible region continue the table smoothly instead of being invalid.
THETA_CLAMP = 89.9
#: Nodes of the w (azimuth about H) axis over [0, 180] degrees.
W_NODES = 19
#: Mid-grey convention of the automatic exposure: the median lit pixel maps to this.
MID_GREY = 0.18
#: The headline interpolation error covers pixels with both polar angles up to this (deg);
#: beyond it (terminator and silhouette, where cos(theta_i) or the projected area vanish)
#: the error is reported separately.
ERROR_ANGLE = 80.0


# --------------------------------------------------------------------------------------
# engine access
# --------------------------------------------------------------------------------------
def evaluate(brdf, medium, theta_i, theta_r, dphi, *, accuracy="fast", progress=None):
    """f at flat arrays of (theta_i, theta_r, phi_r - phi_i) in degrees (MODEL.md sec. 5),
    through the engine's chunked evaluator in chunks of :data:`CHUNK` configurations.
    ``progress(k)`` is called after each chunk with the number of configurations it did.
    ``medium=None`` is f_r."""
    ti, tr, dp = (np.ravel(np.asarray(a, dtype=float))
                  for a in np.broadcast_arrays(theta_i, theta_r, dphi))
    last = [0]

    def step(done, total):
        if progress:
            progress(done - last[0])
        last[0] = done

    return chunked(brdf, medium, ti, 0.0, tr, dp, accuracy=accuracy, chunk=CHUNK,
                   progress=step)


# --------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------
def light_direction(theta, phi):
    """World direction of a distant light at polar ``theta`` from the view axis, azimuth phi."""
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def half_vector_frame(light):
    """(H, e1, e2): H = (L + V)/|L + V| with V = +z, e1 perpendicular to H towards L."""
    view = np.array([0.0, 0.0, 1.0])
    h = light + view
    h /= np.linalg.norm(h)
    e1 = light - np.dot(light, h) * h
    if np.linalg.norm(e1) < 1e-12:  # light along the view axis: any e1 will do
        e1 = np.array([1.0, 0.0, 0.0]) - h[0] * h
    e1 /= np.linalg.norm(e1)
    return h, e1, np.cross(h, e1)


def local_angles(normal, light):
    """(theta_i, theta_r, phi_r - phi_i) in degrees for normals (..., 3), camera at +z.

    Polar angles are unclamped (> 90 where the point is unlit or not visible).
    """
    n = np.asarray(normal, dtype=float)
    cl = n @ light
    cv = n[..., 2]
    lt = light - cl[..., None] * n
    vt = np.array([0.0, 0.0, 1.0]) - cv[..., None] * n
    nl, nv = np.linalg.norm(lt, axis=-1), np.linalg.norm(vt, axis=-1)
    ok = (nl > 1e-12) & (nv > 1e-12)
    cos_d = np.where(ok, np.sum(lt * vt, axis=-1) / np.where(ok, nl * nv, 1.0), -1.0)
    return (np.degrees(np.arccos(np.clip(cl, -1, 1))), np.degrees(np.arccos(np.clip(cv, -1, 1))),
            np.degrees(np.arccos(np.clip(cos_d, -1, 1))))


def sphere_normals(size, samples=1):
    """Normals (size*s, size*s, 3) at (sub)pixel centres and the mask of the disk.

    The image spans x, y in [-VIEW, VIEW] (x to the right, y up, row 0 at the top); the unit
    sphere's rim leaves a margin of (VIEW - 1) radii.
    """
    m = size * samples
    c = ((np.arange(m) + 0.5) / m * 2.0 - 1.0) * VIEW
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 < 1.0
    z = np.sqrt(np.where(inside, 1.0 - r2, 0.0))
    return np.stack([x, y, z], axis=-1), inside


def highlight_pixel(size, light_theta, light_phi=0.0):
    """(row, col) (fractional) where the mirror direction puts the highlight: N = H."""
    h, _, _ = half_vector_frame(light_direction(light_theta, light_phi))
    col = (h[0] / VIEW + 1.0) / 2.0 * size - 0.5
    row = (1.0 - h[1] / VIEW) / 2.0 * size - 0.5
    return float(row), float(col)


# --------------------------------------------------------------------------------------
# the (u, w) table
# --------------------------------------------------------------------------------------
def peak_width(brdf, medium) -> float:
    """Rough half width (deg) of the apparent specular peak in u = angle(N, H).

    The facet law's half-mass angle (sqrt(ln 2)/n for Torrance-Sparrow, MODEL.md sec. 2)
    combined with two phase lobes of their half width at half maximum each (rotating N by
    d moves the mirror direction by 2 d); 60 deg where a model has no lobe.
    """
    facet = min(brdf.facet_half_angle(), 60.0)
    if medium is None:
        return facet
    lobe = min(medium.lobe_half_width(), 60.0)
    return math.sqrt(facet ** 2 + 0.5 * lobe ** 2)


def u_nodes(width: float, density: float = 1.0) -> np.ndarray:
    """Table nodes in u (deg): step width/6 up to 5 widths, then growing by 15 % (at most 2 deg)."""
    step = min(max(width / 6.0, 0.02), 1.0) / density
    core = 5.0 * width
    nodes = list(np.arange(0.0, core, step))
    u = nodes[-1]
    while u < 90.0:
        step = min(step * (1.0 + 0.15 / density), 2.0 / density)
        u = min(u + step, 90.0)
        nodes.append(u)
    return np.asarray(nodes)


def auto_density(light_theta: float) -> float:
    """Table density factor for a light at ``light_theta`` (deg): 1 up to 60, 2 from 80."""
    return 1.0 + min(max((light_theta - 60.0) / 20.0, 0.0), 1.0)


@dataclass
class ApparentTable:
    """log f tabulated over (u, w) for one light; call it to interpolate f."""

    u: np.ndarray
    w: np.ndarray
    values: np.ndarray  # f at the (clamped) node configurations, shape (len(u), len(w))
    spline: RectBivariateSpline = field(repr=False)
    floor: float

    @property
    def nodes(self) -> int:
        return self.values.size

    def __call__(self, u, w):
        """f at normals with polar coordinates (u, w) about H, in degrees."""
        return np.exp(self.spline.ev(u, np.abs(w))) - self.floor


def build_table(brdf, medium, light, *, accuracy="fast", density=1.0, progress=None):
    """Evaluate the engine on the (u, w) grid about H and fit the interpolating spline."""
    h, e1, e2 = half_vector_frame(light)
    u = u_nodes(peak_width(brdf, medium), density)
    w = np.linspace(0.0, 180.0, max(5, int(round((W_NODES - 1) * density)) + 1))
    uu, ww = np.meshgrid(np.radians(u), np.radians(w), indexing="ij")
    normal = (np.cos(uu)[..., None] * h
              + np.sin(uu)[..., None] * (np.cos(ww)[..., None] * e1 + np.sin(ww)[..., None] * e2))
    ti, tr, dp = local_angles(normal, light)
    ti, tr = np.minimum(ti, THETA_CLAMP), np.minimum(tr, THETA_CLAMP)
    values = evaluate(brdf, medium, ti, tr, dp, accuracy=accuracy,
                      progress=progress).reshape(uu.shape)
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise RuntimeError("the engine returned a negative or non-finite value on the table")
    floor = max(1e-12 * float(values.max()), 1e-300)
    logv = np.log(values + floor)
    # symmetries: f(u, -w) = f(u, w), f(u, 180 + d) = f(u, 180 - d), f(-u, w) = f(u, 180 - w)
    k = 3
    w_ext = np.concatenate([-w[k:0:-1], w, 360.0 - w[-2:-k - 2:-1]])
    lw = np.concatenate([logv[:, k:0:-1], logv, logv[:, -2:-k - 2:-1]], axis=1)
    u_ext = np.concatenate([-u[k:0:-1], u])
    lu = np.concatenate([lw[k:0:-1, ::-1], lw], axis=0)
    spline = RectBivariateSpline(u_ext, w_ext, lu, kx=3, ky=3, s=0)
    return ApparentTable(u, w, values, spline, floor)


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
    max_rel_error: float  # max |interp - direct| / direct, checked pixels with both angles <= 80 deg
    max_rel_error_all: float  # the same over all checked pixels (grazing ones included)
    max_peak_error: float  # max |interp - direct| cos(theta_i) / image maximum, all checked
    seconds: float

    def summary(self) -> str:
        med = "clear" if self.medium is None else str(self.medium)
        s = (f"{self.brdf} through {med}: light at theta {self.light_theta:g} deg, "
             f"phi {self.light_phi:g} deg; peak {self.image.max():.4g}")
        if self.table_nodes:
            s += (f"; table {self.table_nodes} nodes; interpolation error at {self.checked} "
                  f"pixels: {100 * self.max_rel_error:.2g} % (angles <= {ERROR_ANGLE:g} deg), "
                  f"{100 * self.max_rel_error_all:.2g} % (all), "
                  f"{100 * self.max_peak_error:.2g} % of the peak")
        return s


def _check_args(size, light_theta, light_phi, samples, accuracy):
    for name, v in (("light_theta", light_theta), ("light_phi", light_phi)):
        if not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
            raise InputError(f"{name} = {v!r} is not a finite number (degrees)")
    if not 0.0 <= light_theta <= MAX_LIGHT_THETA:
        raise InputError(f"light_theta = {light_theta:g} deg is outside [0, {MAX_LIGHT_THETA:g}]"
                         f" (a light further behind the sphere lights only a thin crescent at "
                         f"grazing angles, where the table is not reliable)")
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or not 8 <= size <= 4096:
        raise InputError(f"size = {size!r} must be an integer in [8, 4096] pixels")
    if not isinstance(samples, (int, np.integer)) or isinstance(samples, bool) or not 1 <= samples <= 8:
        raise InputError(f"samples = {samples!r} must be an integer in [1, 8] per pixel axis")
    if accuracy not in RULES:
        raise InputError(f"accuracy = {accuracy!r}; expected one of {', '.join(RULES)}")


def _check_pixels(values, lit, count, rng_seed=20110901):
    """Deterministic pixel sample: half among the brightest 10 % of lit pixels, half uniform."""
    idx = np.flatnonzero(lit)
    if idx.size == 0 or count <= 0:
        return idx[:0]
    rng = np.random.default_rng(rng_seed)
    bright = idx[values.ravel()[idx] >= np.quantile(values.ravel()[idx], 0.9)]
    top = idx[np.argmax(values.ravel()[idx])]
    n_b = min(bright.size, count // 2)
    pick = [np.array([top]), rng.choice(bright, n_b, replace=False),
            rng.choice(idx, min(idx.size, count - n_b - 1), replace=False)]
    return np.unique(np.concatenate(pick))[:max(count, 1)]


def render(brdf, medium=None, light_theta=45.0, light_phi=0.0, size=256, *, accuracy="fast",
           samples=1, check=64, density=1.0, progress=False) -> Rendering:
    """Render the sphere (module docstring) and measure the interpolation error.

    brdf, medium : models or preset names; ``medium=None`` renders the true f_r directly.
    light_theta, light_phi : light direction in degrees (polar angle from the view axis).
    size : image width and height in pixels; samples : k x k samples per pixel (1: centre).
    check : pixels re-evaluated with the engine directly to measure the interpolation error.
    density : table refinement factor (1 is the default grid). Lights more than 60 deg from
        the view get up to twice the density (:func:`auto_density`): the lit, visible part of
        the table shrinks towards grazing angles there.
    """
    _check_args(size, light_theta, light_phi, samples, accuracy)
    b = as_brdf(brdf)
    m = None if medium is None else as_btdf(medium)
    if not (isinstance(check, (int, np.integer)) and 0 <= check <= 4096):
        raise InputError(f"check = {check!r} must be an integer in [0, 4096] pixels")
    if not (isinstance(density, (int, float)) and 0.25 <= density <= 8):
        raise InputError(f"density = {density!r} must be in [0.25, 8]")
    t0 = time.perf_counter()
    density = density * auto_density(float(light_theta))
    light = light_direction(float(light_theta), float(light_phi))
    normal, inside = sphere_normals(size, samples)
    ti, tr, dp = local_angles(normal, light)
    cos_i = normal @ light
    lit = inside & (cos_i > 0.0)

    with _Progress(progress, f"rendering {size}x{size}") as bar:
        if m is None:
            f = np.zeros(lit.shape)
            f[lit] = evaluate(b, None, ti[lit], tr[lit], dp[lit])
            table = None
        else:
            h, e1, e2 = half_vector_frame(light)
            u = np.degrees(np.arccos(np.clip(normal @ h, -1.0, 1.0)))
            w = np.degrees(np.arctan2(normal @ e2, normal @ e1))
            n_table = len(u_nodes(peak_width(b, m), density)) * max(5, int(round((W_NODES - 1) * density)) + 1)
            bar.start(n_table + (check if check else 0))
            table = build_table(b, m, light, accuracy=accuracy, density=density, progress=bar.advance)
            f = np.zeros(lit.shape)
            f[lit] = table(u[lit], w[lit])
        linear = np.where(lit, f * np.where(lit, cos_i, 0.0), 0.0)
        image = linear.reshape(size, samples, size, samples).mean(axis=(1, 3)) if samples > 1 else linear

        max_rel = max_rel_all = max_peak = 0.0
        checked = 0
        if table is not None and check:
            pick = _check_pixels(linear, lit, check)
            checked = pick.size
            direct = evaluate(b, m, ti.ravel()[pick], tr.ravel()[pick], dp.ravel()[pick],
                              accuracy=accuracy, progress=bar.advance)
            interp = f.ravel()[pick]
            rel = np.abs(interp - direct) / direct
            inner = np.maximum(ti.ravel()[pick], tr.ravel()[pick]) <= ERROR_ANGLE
            max_rel = float(rel[inner].max()) if inner.any() else 0.0
            max_rel_all = float(rel.max())
            diff = np.abs(interp - direct) * cos_i.ravel()[pick]
            max_peak = float(np.max(diff) / max(linear.max(), 1e-300))
    return Rendering(image=image, brdf=b, medium=m, light_theta=float(light_theta),
                     light_phi=float(light_phi), accuracy=accuracy, samples=int(samples),
                     table_nodes=0 if table is None else table.nodes, checked=checked,
                     max_rel_error=max_rel, max_rel_error_all=max_rel_all,
                     max_peak_error=max_peak,
                     seconds=time.perf_counter() - t0)


def render_sphere(brdf, medium=None, light_theta=45.0, light_phi=0.0, size=256, *,
                  accuracy="fast", samples=1, progress=False) -> np.ndarray:
    """Linear image (size, size) of the sphere under ``brdf`` seen through ``medium``.

    See :func:`render` (which also reports the interpolation error) and the module docstring.
    """
    return render(brdf, medium, light_theta, light_phi, size, accuracy=accuracy,
                  samples=samples, check=0, progress=progress).image


class _Progress:
    """A rich progress bar on stderr when ``enabled``; a no-op otherwise."""

    def __init__(self, enabled, label):
        self.enabled, self.label = enabled, label
        self._p = self._task = None

    def __enter__(self):
        if self.enabled:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn)
            self._p = Progress(TextColumn("{task.description}"), BarColumn(),
                               MofNCompleteColumn(), TimeElapsedColumn(),
                               console=Console(stderr=True), transient=True)
            self._p.__enter__()
        return self

    def start(self, total):
        if self._p is not None:
            self._task = self._p.add_task(f"{self.label}: engine evaluations", total=total)

    def advance(self, k):
        if self._p is not None and self._task is not None:
            self._p.advance(self._task, k)

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


def srgb_encode(x):
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
    if not (isinstance(exposure, (int, float, np.floating)) and math.isfinite(exposure)
            and exposure > 0):
        raise InputError(f"exposure = {exposure!r} must be a positive number")
    if tone not in TONES:
        raise InputError(f"tone = {tone!r}; expected one of {', '.join(TONES)}")
    x = exposure * np.asarray(linear, dtype=float)
    if tone == "reinhard":
        x = x / (1.0 + x)
    return np.round(255.0 * srgb_encode(x)).astype(np.uint8)


def clipping(linear, exposure, tone="clip"):
    """(clipped pixels, their fraction of the lit pixels, peak in units of full scale).

    Nothing clips under the "reinhard" tone curve.
    """
    lin = np.asarray(linear)
    n_lit = int(np.count_nonzero(lin > 0))
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
    Image.fromarray(np.ascontiguousarray(image_u8, dtype=np.uint8)).save(buf, format="png",
                                                                         pnginfo=info)
    return buf.getvalue()


__all__ = ["render", "render_sphere", "Rendering", "evaluate", "auto_exposure", "tone_map",
           "clipping", "srgb_encode", "highlight_pixel", "build_table", "ApparentTable",
           "local_angles", "light_direction", "half_vector_frame", "sphere_normals", "png_bytes",
           "TONES"]
