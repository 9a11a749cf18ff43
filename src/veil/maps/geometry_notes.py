"""What a maps run (:func:`veil.maps.run.fit_maps`) knows and says of its geometry: the
near-field geometry of the photos, checked before anything is computed; the notes - the
spread of view directions across the field against the narrowest lobe (a warning when the
distant camera is a poor approximation), or what the near-field tables did - and the
record of the geometry in the store's attributes."""

from __future__ import annotations

import math
import warnings

from ..errors import InputError
from .near import NearGeometry
from .photos import Acquisition
from .tables import MapTables, smoothest_facet


class MapsWarning(UserWarning):
    """Something about a map the user should know that does not stop it."""


def geometry_notes(tables: MapTables, brdf_cls, medium_model, shape, geometry) -> list:
    """The angular spread across the field implied by a camera at ``distance`` with
    ``pitch`` (plate size of a pixel, same units) against the narrowest lobe (the medium's
    phase lobe, the BRDF's facet lobe at the ends of the table); warns when the spread
    exceeds a fifth of it: distant light and camera are then a poor approximation."""
    distance, pitch = (float(g) for g in geometry)
    if not (distance > 0 and pitch > 0 and math.isfinite(distance) and math.isfinite(pitch)):
        raise InputError(
            f"camera distance {distance:g} and pixel pitch {pitch:g} must be positive numbers"
        )
    h, w = shape
    spread = field_spread(shape, distance, pitch)
    widths = {"the medium's phase lobe": medium_model.lobe_half_width()}
    facet = smoothest_facet(brdf_cls, tables.names, tables.base, tables.axes, tables.options)
    if math.isfinite(facet):
        widths["the BRDF's facet lobe (smoothest end of the table)"] = facet
    which, narrow = min(widths.items(), key=lambda kv: kv[1])
    notes = [
        f"geometry: the field ({w} x {h} pixels of {pitch:g} at distance {distance:g}) "
        f"spans {spread:.3g} deg of view direction; narrowest lobe: {which}, "
        f"{narrow:.3g} deg half width"
    ]
    if math.isfinite(narrow) and spread > narrow / 5:
        message = (
            f"the view direction changes by {spread:.3g} deg across the field, more "
            f"than a fifth of {which} ({narrow:.3g} deg): the distant-camera "
            f"approximation (every pixel at the manifest's angles) is poor; map a "
            f"smaller ROI or move the camera further away"
        )
        message += " (or map with per-pixel angles: --near-field)"
        warnings.warn(message, MapsWarning, stacklevel=3)
        notes.append("warning: " + message)
    return notes


def _number(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(
            f"camera distance / pixel pitch {value!r}: expected a positive finite number"
        ) from None


def field_spread(shape, distance, pitch) -> float:
    """Spread of view directions across a field of ``shape`` (h, w) pixels (deg):
    2 atan(diagonal / 2 D)."""
    h, w = shape
    return 2 * math.degrees(math.atan(0.5 * math.hypot(h, w) * pitch / distance))


def near_notes(tables: MapTables, shape) -> list:
    """What the near-field tables did: the spread, the field grid, the interpolation error
    measured against exact per-pixel columns; the distant-camera warning does not apply."""
    grid = tables.near
    if grid is None:
        return []
    g = grid.geometry
    h, w = shape
    spread = field_spread(shape, g.distance, g.pitch)
    return [
        f"geometry: near field - every pixel at its own angles (camera at {g.distance:g} "
        f"from the plate centre, pixel pitch {g.pitch:g}, optical centre "
        f"({g.centre[0]:g}, {g.centre[1]:g}) px); the field ({w} x {h} pixels) spans "
        f"{spread:.3g} deg of view direction; {grid.describe()}; interpolation error "
        f"against exact per-pixel columns {tables.field_error:.2g} of a column's maximum; "
        f"the distant-camera warning does not apply"
    ]


def geometry_record(tables: MapTables, geometry) -> dict:
    """The geometry of a map for its attributes and summary.json."""
    if tables.near is not None:
        g = tables.near.geometry
        return {
            "kind": "near-field",
            **tables.near.as_dict(),
            "spread_deg": field_spread(
                (tables.near.roi[3], tables.near.roi[2]), g.distance, g.pitch
            ),
            "interpolation_error": tables.field_error,
        }
    out: dict[str, str | float] = {"kind": "distant"}
    if geometry is not None:
        out.update(camera_distance=float(geometry[0]), pixel_pitch=float(geometry[1]))
    return out


def near_geometry(geometry, near_field: bool, acq: Acquisition) -> NearGeometry | None:
    """The near-field geometry of the photos (checked before anything is computed; the
    camera distance and pixel pitch are checked even when only the notes use them)."""
    if near_field and geometry is None:
        raise InputError(
            "near-field geometry needs the camera distance and the pixel "
            "pitch (--camera-distance D --pixel-pitch P)"
        )
    if geometry is None:
        return None
    distance, pitch = (_number(g) for g in geometry)
    near = NearGeometry(distance, pitch, tuple(acq.shape))
    if not near_field:
        return None
    near.check_field(acq.angles, acq.roi)
    return near


def geometry_notes_of(tables: MapTables, cls, medium_model, acq: Acquisition, geometry) -> list:
    """The notes of the map's geometry: near field, or the distant camera's spread."""
    shape = (acq.roi.h, acq.roi.w)
    if tables.near is not None:
        return near_notes(tables, shape)
    return [] if geometry is None else geometry_notes(tables, cls, medium_model, shape, geometry)


__all__ = [
    "MapsWarning",
    "geometry_notes",
    "field_spread",
    "near_notes",
    "geometry_record",
    "near_geometry",
    "geometry_notes_of",
]
