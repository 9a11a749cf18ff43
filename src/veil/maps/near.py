"""Near-field geometry of the reflectance maps (docs/maps-geometry.md "Geometry").

Collimated light, a pinhole camera at distance D from the plate centre along each
configuration's view direction, the photos registered to the plate. In the plate's local
frame (docs/model.md sec. 1: z the normal, phi from the x axis) pixel (x, y) of the full photo
(pixel centres at x + 1/2, y + 1/2) is the plate point

    p = ((x + 1/2 - cx) P, -(y + 1/2 - cy) P, 0),   (cx, cy) = (width / 2, height / 2)

(image x along the plate's x axis, towards phi = 0; image rows downwards, the plate's y
axis upwards, so that (x, y, z) stays right-handed). The camera of a configuration with
view direction R = (theta_r, phi_r) sits at C = D R; the pixel sees the plate along
R' = (C - p) / |C - p|, and the light direction I is the manifest's. (theta_i, phi_i,
theta_r', phi_r') go to the engine as any configuration does (docs/model.md sec. 1, 5).

:class:`FieldGrid` is the grid of plate points at which :func:`veil.maps.tables.build_tables`
tabulates the basis columns; a pixel's columns are the tensor-product cubic B-spline over
the grid (and the nonlinear axes) at its position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..engine.angles import direction
from ..errors import InputError

#: Field grid step: this fraction of the narrowest apparent lobe's half width in view
#: direction (:func:`apparent_lobe`), in angle between neighbouring nodes.
STEP_FRACTION = 0.2
#: At least this many nodes per field axis (the cubic spline's not-a-knot ends need 4).
MIN_NODES = 4
#: At most this many field nodes in all (the tables grow with their number).
MAX_NODES = 1024
#: View directions beyond this polar angle (deg) are refused (grazing: the engine wants
#: theta < 90 deg, and the plate is barely seen).
MAX_THETA = 89.0


@dataclass(frozen=True)
class NearGeometry:
    """Camera distance ``distance`` and plate size of a pixel ``pitch`` (same units), the
    full photo's size ``shape`` (height, width): its centre is the optical centre."""

    distance: float
    pitch: float
    shape: tuple

    def __post_init__(self):
        for name in ("distance", "pitch"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                label = "camera distance" if name == "distance" else "pixel pitch"
                raise InputError(f"{label} {v!r}: expected a positive finite number")

    @property
    def centre(self) -> tuple:
        """(cx, cy): the optical centre in pixel coordinates (the full photo's centre)."""
        return (self.shape[1] / 2.0, self.shape[0] / 2.0)

    def plate_points(self, x, y) -> np.ndarray:
        """Plate positions (..., 3) of pixels (x, y) of the full photo (fractional allowed)."""
        cx, cy = self.centre
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        return np.stack(
            [(x + 0.5 - cx) * self.pitch, -(y + 0.5 - cy) * self.pitch, np.zeros_like(x)], axis=-1
        )

    def angles(self, angles, x, y) -> tuple:
        """(theta_i, phi_i, theta_r, phi_r), each (..., M) for pixels (x, y) (...) and the
        configurations ``angles`` (M,) (degrees): the light's unchanged, the view from the
        plate point to the camera."""
        ti, pi_, tr, pr = (np.asarray(a, dtype=float) for a in angles)
        camera = self.distance * direction(tr, pr)  # (M, 3)
        p = self.plate_points(x, y)[..., None, :]  # (..., 1, 3)
        v = camera - p
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        theta = np.degrees(np.arccos(np.clip(v[..., 2], -1.0, 1.0)))
        phi = np.mod(np.degrees(np.arctan2(v[..., 1], v[..., 0])), 360.0)
        # straight down the normal the azimuth is arbitrary: keep the manifest's
        phi = np.where(theta < 1e-9, pr, phi)
        shape = theta.shape
        return (np.broadcast_to(ti, shape).copy(), np.broadcast_to(pi_, shape).copy(), theta, phi)

    def check_field(self, angles, roi) -> None:
        """InputError when a pixel of ``roi`` sees a configuration's camera at or beyond
        :data:`MAX_THETA` from the normal (or behind the plate)."""
        xs = np.array([roi.x, roi.x + roi.w - 1], dtype=float)
        ys = np.array([roi.y, roi.y + roi.h - 1], dtype=float)
        xx, yy = np.meshgrid(xs, ys)
        theta = self.angles(angles, xx, yy)[2]  # (2, 2, M)
        worst = np.unravel_index(np.argmax(theta), theta.shape)
        if theta[worst] >= MAX_THETA:
            m = worst[-1]
            raise InputError(
                f"near-field geometry: pixel ({int(xx[worst[:2]])}, {int(yy[worst[:2]])}) "
                f"sees the camera of manifest row {m + 1} (theta_r "
                f"{float(np.asarray(angles[2])[m]):g} deg) at {theta[worst]:.4g} deg from the "
                f"normal (at most {MAX_THETA:g}): the field ({roi.w} x {roi.h} pixels of "
                f"{self.pitch:g} at distance {self.distance:g}) is larger than the plate "
                f"allows; map a smaller ROI, or check --camera-distance and --pixel-pitch"
            )

    def describe(self) -> str:
        cx, cy = self.centre
        return (
            f"near-field: camera at {self.distance:g} from the plate centre, pixel pitch "
            f"{self.pitch:g}, optical centre ({cx:g}, {cy:g}) px"
        )


def apparent_lobe(facet_deg: float, phase_deg: float) -> float:
    """Half width (deg) of the apparent specular lobe as a function of the view direction:
    the facet lobe seen in R (twice its half angle: turning R by d turns H by d/2), widened
    by a phase lobe on each side of the medium (docs/model.md eq. 1), added in quadrature as
    ``veil render``'s peak width does (viz.render.peak_width, in u = angle(N, H))."""
    facet = min(facet_deg, 60.0)
    lobe = min(phase_deg, 60.0)
    return math.sqrt((2.0 * facet) ** 2 + 2.0 * lobe**2)


@dataclass(frozen=True)
class FieldGrid:
    """Plate points of the near-field tables: ``xs`` (Kx,) and ``ys`` (Ky,) pixel
    coordinates of the full photo (regular, covering the pixels of ``roi`` (x, y, w, h)),
    the step ``step_deg`` they were chosen for and the lobe it came from."""

    geometry: NearGeometry
    roi: tuple
    xs: tuple
    ys: tuple
    step_deg: float
    lobe_deg: float

    @property
    def shape(self) -> tuple:
        return (len(self.xs), len(self.ys))

    def coords(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Grid coordinates (0 .. K - 1 on each axis) of pixels (x, y) of the full photo."""

        def one(v, nodes):
            lo, hi = nodes[0], nodes[-1]
            return (np.asarray(v, dtype=float) - lo) / ((hi - lo) / (len(nodes) - 1))

        return one(x, self.xs), one(y, self.ys)

    def node_angles(self, angles) -> tuple:
        """Angles (Kx, Ky, M) at every node and configuration."""
        xx, yy = np.meshgrid(np.asarray(self.xs), np.asarray(self.ys), indexing="ij")
        return self.geometry.angles(angles, xx, yy)

    def describe(self) -> str:
        return (
            f"field grid {len(self.xs)} x {len(self.ys)} plate points (step "
            f"<= {self.step_deg:.3g} deg of view direction, {self.step_deg / self.lobe_deg:.2g}"
            f" of the {self.lobe_deg:.3g} deg apparent lobe)"
        )

    def as_dict(self) -> dict:
        g = self.geometry
        return {
            "camera_distance": g.distance,
            "pixel_pitch": g.pitch,
            "optical_centre": list(g.centre),
            "photo_shape": list(g.shape),
            "field_nodes": [len(self.xs), len(self.ys)],
            "field_x": [self.xs[0], self.xs[-1]],
            "field_y": [self.ys[0], self.ys[-1]],
            "step_deg": self.step_deg,
            "apparent_lobe_deg": self.lobe_deg,
        }


def field_grid(
    geometry: NearGeometry, angles, roi, lobe_deg: float, fraction: float | None = None
) -> FieldGrid:
    """The regular grid of plate points over ``roi`` (pixel centres) whose neighbouring
    nodes differ in view direction by at most ``fraction`` (default :data:`STEP_FRACTION`)
    x ``lobe_deg`` at every configuration (the rate of change measured on a 9 x 9 probe of
    the field, 10 % margin); at least :data:`MIN_NODES` per axis."""
    fraction = STEP_FRACTION if fraction is None else float(fraction)
    geometry.check_field(angles, roi)
    x0, x1 = float(roi.x), float(roi.x + roi.w - 1)
    y0, y1 = float(roi.y), float(roi.y + roi.h - 1)
    step = fraction * lobe_deg
    px = np.linspace(x0, x1, 9)
    py = np.linspace(y0, y1, 9)
    xx, yy = np.meshgrid(px, py, indexing="ij")
    counts = []
    for axis, (lo, hi) in enumerate(((x0, x1), (y0, y1))):
        extent = hi - lo
        if extent <= 0:
            counts.append(MIN_NODES)
            continue
        h = 0.5  # pixels: the angular rate from a central difference
        dx, dy = (h, 0.0) if axis == 0 else (0.0, h)
        a = geometry.angles(angles, xx - dx, yy - dy)
        b = geometry.angles(angles, xx + dx, yy + dy)
        va = direction(a[2], a[3])
        vb = direction(b[2], b[3])
        rate = np.degrees(np.arccos(np.clip(np.sum(va * vb, axis=-1), -1, 1))).max() / (2 * h)
        counts.append(max(MIN_NODES, int(math.ceil(1.1 * rate * extent / step)) + 1))
    if counts[0] * counts[1] > MAX_NODES:
        raise InputError(
            f"near-field geometry: the field ({roi.w} x {roi.h} pixels of {geometry.pitch:g} "
            f"at distance {geometry.distance:g}) needs {counts[0]} x {counts[1]} field "
            f"nodes to follow a {lobe_deg:.3g} deg lobe (at most {MAX_NODES}); map a "
            f"smaller ROI in several runs"
        )
    xs = tuple(float(v) for v in np.linspace(x0, x1 if x1 > x0 else x0 + 1, counts[0]))
    ys = tuple(float(v) for v in np.linspace(y0, y1 if y1 > y0 else y0 + 1, counts[1]))
    return FieldGrid(
        geometry,
        (int(roi.x), int(roi.y), int(roi.w), int(roi.h)),
        xs,
        ys,
        float(step),
        float(lobe_deg),
    )


__all__ = ["NearGeometry", "FieldGrid", "field_grid", "apparent_lobe", "STEP_FRACTION", "MAX_THETA"]
