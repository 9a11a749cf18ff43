"""The geometry of the rendered sphere (:mod:`veil.viz.render`): a unit sphere seen by an
orthographic camera looking down the z axis, lit by a distant light; its normals at pixel
centres, the light's direction, the half vector's frame, each normal's local angles."""

from __future__ import annotations

import math

import numpy as np

#: Half width of the view in sphere radii (orthographic camera; a 5 % margin around the rim).
VIEW = 1.05


def light_direction(theta, phi) -> np.ndarray:
    """World direction of a distant light at polar ``theta`` from the view axis, azimuth phi."""
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def half_vector_frame(light) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H, e1, e2): H = (L + V)/|L + V| with V = +z, e1 perpendicular to H towards L."""
    view = np.array([0.0, 0.0, 1.0])
    h = light + view
    h /= np.linalg.norm(h)
    e1 = light - np.dot(light, h) * h
    if np.linalg.norm(e1) < 1e-12:  # light along the view axis: any e1 will do
        e1 = np.array([1.0, 0.0, 0.0]) - h[0] * h
    e1 /= np.linalg.norm(e1)
    return h, e1, np.cross(h, e1)


def local_angles(normal, light) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
    return (
        np.degrees(np.arccos(np.clip(cl, -1, 1))),
        np.degrees(np.arccos(np.clip(cv, -1, 1))),
        np.degrees(np.arccos(np.clip(cos_d, -1, 1))),
    )


def sphere_normals(size, samples=1, rows=None) -> tuple[np.ndarray, np.ndarray]:
    """Normals (size*s, size*s, 3) at (sub)pixel centres and the mask of the disk.

    The image spans x, y in [-VIEW, VIEW] (x to the right, y up, row 0 at the top); the unit
    sphere's rim leaves a margin of (VIEW - 1) radii. ``rows=(first, stop)`` gives only the
    subpixel rows of pixel rows first..stop-1, shape ((stop - first)*s, size*s, 3).
    """
    m = size * samples
    c = ((np.arange(m) + 0.5) / m * 2.0 - 1.0) * VIEW
    r = c if rows is None else c[rows[0] * samples : rows[1] * samples]
    x, y = np.meshgrid(c, -r)
    r2 = x * x + y * y
    inside = r2 < 1.0
    z = np.sqrt(np.where(inside, 1.0 - r2, 0.0))
    return np.stack([x, y, z], axis=-1), inside


def pixel_normals(size, flat_index) -> tuple[np.ndarray, np.ndarray]:
    """Normals (n, 3) at the centres of the pixels with flat indices ``flat_index`` (row-major
    in a size x size image) and whether each is on the disk."""
    row, col = np.divmod(np.asarray(flat_index), size)
    c = lambda k: ((k + 0.5) / size * 2.0 - 1.0) * VIEW  # noqa: E731
    x, y = c(col), -c(row)
    r2 = x * x + y * y
    inside = r2 < 1.0
    return np.stack([x, y, np.sqrt(np.where(inside, 1.0 - r2, 0.0))], axis=-1), inside


def highlight_pixel(size, light_theta, light_phi=0.0) -> tuple[float, float]:
    """(row, col) (fractional) where the mirror direction puts the highlight: N = H."""
    h, _, _ = half_vector_frame(light_direction(light_theta, light_phi))
    col = (h[0] / VIEW + 1.0) / 2.0 * size - 0.5
    row = (1.0 - h[1] / VIEW) / 2.0 * size - 0.5
    return float(row), float(col)


__all__ = [
    "VIEW",
    "light_direction",
    "half_vector_frame",
    "local_angles",
    "sphere_normals",
    "pixel_normals",
    "highlight_pixel",
]
