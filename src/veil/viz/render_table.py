"""The apparent BRDF of one light tabulated for :func:`veil.viz.render.render`: evaluated
by the engine on a grid in (u, w) about the half vector H (u = angle(N, H), dense near the
specular peak; w the azimuth of N about H, uniform over [0, 180]), and the bicubic spline
of log f over it (the module docstring of :mod:`veil.viz.render`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..engine.evaluator import evaluate as chunked
from .sphere_geometry import half_vector_frame, local_angles

#: Configurations per engine call. Every call has this shape, so the engine compiles once.
CHUNK = 256
#: Polar angles of table nodes beyond this (degrees) are evaluated at this angle: nodes
#: outside the lit, visible region continue the table smoothly instead of being invalid.
THETA_CLAMP = 89.9
#: Nodes of the w (azimuth about H) axis over [0, 180] degrees.
W_NODES = 19


# --------------------------------------------------------------------------------------
# engine access
# --------------------------------------------------------------------------------------
def evaluate(brdf, medium, theta_i, theta_r, dphi, *, accuracy="fast", progress=None) -> np.ndarray:
    """f at flat arrays of (theta_i, theta_r, phi_r - phi_i) in degrees (docs/model.md sec. 5),
    through the engine's chunked evaluator in chunks of :data:`CHUNK` configurations.
    ``progress(k)`` is called after each chunk with the number of configurations it did.
    ``medium=None`` is f_r."""
    ti, tr, dp = (
        np.ravel(np.asarray(a, dtype=float)) for a in np.broadcast_arrays(theta_i, theta_r, dphi)
    )
    last = [0]

    def step(done, total):
        if progress:
            progress(done - last[0])
        last[0] = done

    return chunked(brdf, medium, ti, 0.0, tr, dp, accuracy=accuracy, chunk=CHUNK, progress=step)


# --------------------------------------------------------------------------------------
# the (u, w) table
# --------------------------------------------------------------------------------------
def peak_width(brdf, medium) -> float:
    """Rough half width (deg) of the apparent specular peak in u = angle(N, H).

    The facet law's half-mass angle (sqrt(ln 2)/n for Torrance-Sparrow, docs/model.md sec. 2)
    combined with two phase lobes of their half width at half maximum each (rotating N by
    d moves the mirror direction by 2 d); 60 deg where a model has no lobe.
    """
    facet = min(brdf.facet_half_angle(), 60.0)
    if medium is None:
        return facet
    lobe = min(medium.lobe_half_width(), 60.0)
    return math.sqrt(facet**2 + 0.5 * lobe**2)


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


def build_table(
    brdf, medium, light, *, accuracy="fast", density=1.0, progress=None
) -> ApparentTable:
    """Evaluate the engine on the (u, w) grid about H and fit the interpolating spline."""
    h, e1, e2 = half_vector_frame(light)
    u = u_nodes(peak_width(brdf, medium), density)
    w = np.linspace(0.0, 180.0, max(5, int(round((W_NODES - 1) * density)) + 1))
    uu, ww = np.meshgrid(np.radians(u), np.radians(w), indexing="ij")
    normal = np.cos(uu)[..., None] * h + np.sin(uu)[..., None] * (
        np.cos(ww)[..., None] * e1 + np.sin(ww)[..., None] * e2
    )
    ti, tr, dp = local_angles(normal, light)
    ti, tr = np.minimum(ti, THETA_CLAMP), np.minimum(tr, THETA_CLAMP)
    values = evaluate(brdf, medium, ti, tr, dp, accuracy=accuracy, progress=progress).reshape(
        uu.shape
    )
    if not np.all(np.isfinite(values)) or np.any(values < 0):
        raise RuntimeError("the engine returned a negative or non-finite value on the table")
    floor = max(1e-12 * float(values.max()), 1e-300)
    logv = np.log(values + floor)
    # symmetries: f(u, -w) = f(u, w), f(u, 180 + d) = f(u, 180 - d), f(-u, w) = f(u, 180 - w)
    k = 3
    w_ext = np.concatenate([-w[k:0:-1], w, 360.0 - w[-2 : -k - 2 : -1]])
    lw = np.concatenate([logv[:, k:0:-1], logv, logv[:, -2 : -k - 2 : -1]], axis=1)
    u_ext = np.concatenate([-u[k:0:-1], u])
    lu = np.concatenate([lw[k:0:-1, ::-1], lw], axis=0)
    spline = RectBivariateSpline(u_ext, w_ext, lu, kx=3, ky=3, s=0)
    return ApparentTable(u, w, values, spline, floor)


__all__ = [
    "CHUNK",
    "THETA_CLAMP",
    "W_NODES",
    "evaluate",
    "peak_width",
    "u_nodes",
    "auto_density",
    "ApparentTable",
    "build_table",
]
