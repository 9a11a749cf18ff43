"""The medium's blur across the plate (docs/maps-blur.md): the correction that lets a
per-pixel fit see a textured plate through a forward-scattering medium.

A pixel's model (docs/model.md eq. 8.1c) takes the light scattered into its view ray from a
uniform plate: term 2 and 4 weigh f_r(I, R') by J_v (eq. 8.1b), the integral over the
distance t from the plate along the view ray R of e^{-beta t} / R_c, where light arriving
from R' left the plate at

    y = x + t v,   v = R - (mu_R / mu_R') R'                                    (B.1)

(the relation behind J_v's S). On a plate whose reflectance varies, that light carries the
reflectance of y, not of x. With the view side's part of a uniform, endless plate at every
point, S_inf(y) (the model with the plate width endless, less the model with no view-side
scattering, N(y)), the pixel's value is

    f(x) = N(x) + Sum_y K(x - y) S_inf(y),   S_inf = 0 off the mapped region       (B.2)

K the distribution of t v over the orders' phase lobes p(g^k) weighted as in eq. 8.1a and
the factor e^{-beta t} / R_c (:func:`view_kernels`), normalised over the endless plane.
For a uniform matte plate (B.2) is the model's own J_v at every pixel; near an edge it is the
part of the kernel still on the plate (the plate's size per pixel rather than at its
centre); on a textured plate it mixes the neighbours in.

The per-pixel fit keeps its model, f_plate = N + S_plate (the plate's width at its
centre). Its view-side part S_plate weighs f_r by J_v; K weighs the directions by the phase
lobes alone. Scaled to agree with it at the plate centre, (B.2) gives the correction of the
photos at a prior map's parameters (:func:`blur_correction`)

    f(x) - f_plate(x) = S_plate(x) [ Sum_y K(x - y) S_inf(y) / (F_0 S_inf(x)) - 1 ]    (B.3)

F_0 the part of K on the plate seen from its centre (:func:`plate_share`): zero for a
uniform plate at its centre, whatever its BRDF. Refitting from the corrected photos is one
step of a fixed-point iteration (docs/maps-blur.md).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from typing import Any

import numpy as np

from ..errors import InputError
from .status import CONVERGED

#: Quadrature of the kernel (B.2): HG inverse-CDF midpoints in the scattering angle, in the
#: azimuth, and midpoints in t along the view ray; orders whose weight is below
#: KERNEL_ORDER_FLOOR of the first's are left out.
KERNEL_NODES = (64, 48, 32)
KERNEL_ORDER_FLOOR = 1e-5
#: Plate widths (same unit as the path length) of the model without view-side scattering
#: and of the endless plate (docs/model.md sec. 8.1: 1e-100 to 1e100).
NO_VIEW, ENDLESS = 1e-100, 1e100


def _hg_cosines(g: float, n: int) -> np.ndarray:
    """cos(theta) at the n midpoints of the Henyey-Greenstein CDF (inverse CDF)."""
    xi = (np.arange(n) + 0.5) / n
    if abs(g) < 1e-6:
        return 1.0 - 2.0 * xi
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * xi)
    return (1.0 + g * g - s * s) / (2.0 * g)


def _frame(theta_r: float, phi_r: float) -> tuple:
    t, p = math.radians(theta_r), math.radians(phi_r)
    R = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    a = np.array([1.0, 0.0, 0.0]) if abs(R[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(R, a)
    u /= np.linalg.norm(u)
    return R, u, np.cross(R, u)


def _landing(R, u, w, g: float, phis, ts, pitch: float, half: int, n_mu: int) -> tuple:
    """Where the light of one order lands (B.1): (mu_R / mu_R' per direction, the flat
    kernel index of each (direction, t) within ``half`` pixels, that mask)."""
    ct = _hg_cosines(g, n_mu)
    st = np.sqrt(np.clip(1.0 - ct * ct, 0.0, None))
    dirs = (
        ct[:, None, None] * R
        + st[:, None, None] * np.cos(phis)[None, :, None] * u
        + st[:, None, None] * np.sin(phis)[None, :, None] * w
    ).reshape(-1, 3)
    dirs = dirs[dirs[:, 2] > 1e-9]  # light that left the plate
    ratio = R[2] / dirs[:, 2]
    v = R[None, :2] - ratio[:, None] * dirs[:, :2]  # (B.1)
    d = ts[None, :, None] * v[:, None, :]  # (directions, t, 2) on the plate
    col = np.rint(d[..., 0] / pitch).astype(np.int64)
    row = np.rint(-d[..., 1] / pitch).astype(np.int64)  # image rows run down
    inside = (np.abs(col) <= half) & (np.abs(row) <= half)
    side = 2 * half + 1
    return ratio, ((row + half) * side + col + half)[inside], inside


def view_kernels(theta_r, phi_r, media: list, pitch: float, half: int) -> np.ndarray:
    """K of (B.2) for each configuration's view direction (theta_r, phi_r) (M,) and each
    medium of ``media`` (forward-series models with a path length, their orders from
    ``view_lobes``): (C, M, 2 half + 1, 2 half + 1) over image offsets (row, column) of
    pixels of ``pitch``; each sums to the share of the endless plane's kernel within
    ``half`` pixels."""
    n_mu, n_phi, n_t = KERNEL_NODES
    r_c = float(media[0].path_length)
    side = 2 * half + 1
    out = np.zeros((len(media), len(theta_r), side * side))
    phis = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * math.pi
    ts = (np.arange(n_t) + 0.5) / n_t * r_c
    lobes = [m.view_lobes() for m in media]  # (weights, asymmetries, extinction) each
    top = max(max(w) for w, _, _ in lobes)
    orders = [
        k
        for k in range(len(lobes[0][0]))
        if max(w[k] for w, _, _ in lobes) >= KERNEL_ORDER_FLOOR * top
    ]
    for j, (tr, pr) in enumerate(zip(np.ravel(theta_r), np.ravel(phi_r))):
        R, u, w = _frame(float(tr), float(pr))
        totals = np.zeros(len(media))
        for k in orders:
            for g in sorted({a[k] for _, a, _ in lobes}):
                ratio, index, inside = _landing(R, u, w, g, phis, ts, pitch, half, n_mu)
                for c, (weights, asym, sigma_t) in enumerate(lobes):
                    if asym[k] != g:
                        continue
                    beta = sigma_t * (ratio - 1.0)
                    weight = np.exp(-beta[:, None] * ts[None, :]) * weights[k]
                    totals[c] += weight.sum()
                    out[c, j] += np.bincount(index, weights=weight[inside], minlength=side * side)
        out[:, j] /= np.where(totals > 0, totals, 1.0)[:, None]  # no scattering: no kernel
    return out.reshape(len(media), len(theta_r), side, side)


def check_medium(media: list, near: bool) -> None:
    """The blur needs the near-field geometry (``near``: the pixel pitch on the plate) and
    a forward-series medium with its path length and plate width (eq. 8.1b), the same in
    every channel."""
    if not near:
        raise InputError(
            "the medium's blur (--blur-from, --blur-rounds) needs the near-field geometry: give "
            "--near-field with --camera-distance and --pixel-pitch (the pixel pitch places "
            "each pixel on the plate)"
        )
    for m in media:
        lobes = callable(getattr(m, "view_lobes", None))
        if not lobes or not (m.path_length > 0 and m.plate_width > 0):
            raise InputError(
                "the medium's blur (--blur-from, --blur-rounds) needs a forward-series "
                "medium with its path length and plate width (docs/model.md sec. 8.1); this "
                "medium is "
                f"{type(m).NAME}"
                + (
                    f" with path_length {m.path_length:g}, plate_width {m.plate_width:g}"
                    if lobes
                    else ""
                )
            )
    for what, values in (
        ("path lengths", {float(m.path_length) for m in media}),
        ("plate widths", {float(m.plate_width) for m in media}),
    ):
        if len(values) > 1:
            raise InputError(
                f"the medium's blur: the channels' media have different {what} "
                f"({', '.join(f'{x:g}' for x in sorted(values))}); one apparatus has one"
            )


def media_of(medium) -> list:
    """The medium models of ``medium`` (a model, or {channel: model}), in channel order."""
    return list(medium.values()) if isinstance(medium, dict) else [medium]


def with_plate_width(medium, width: float) -> Any:
    """``medium`` (a model, or {channel: model}) with its plate width replaced."""
    if isinstance(medium, dict):
        return {c: dataclasses.replace(m, plate_width=width) for c, m in medium.items()}
    return dataclasses.replace(medium, plate_width=width)


def prior_maps(prior, medium, near, acq) -> tuple:
    """(``prior``, its arrays, :func:`veil.maps.store.open_maps`) of a map the photos are
    corrected from, read before anything is computed: the geometry and the medium (a
    model or {channel: model}) must allow the blur (:func:`check_medium`), the region must
    cover the plate (:func:`check_region`), and the map must be of the same photos (their
    number and manifest), region and channels, with a converged pixel."""
    from .photos import stacked_channels
    from .store import open_maps

    media = media_of(medium)
    check_medium(media, near is not None)
    check_region(acq.roi, near, float(media[0].plate_width))
    maps = open_maps(prior)
    channel = acq.channel if isinstance(acq.channel, str) else ",".join(acq.channel)
    _same(
        prior,
        maps["info"],
        {
            "roi": str(acq.roi),
            "photos": len(acq.paths),
            "manifest": acq.name,
            "channel": channel,
            "channels": list(stacked_channels(acq.channel)) or None,
        },
    )
    if not np.any(maps["status"] == CONVERGED):
        raise InputError(f"--blur-from {prior}: that map has no converged pixel to correct from")
    return prior, maps


def check_region(roi, near, plate_width: float) -> None:
    """The mapped region must cover the plate (the medium's plate width, centred on the
    optical centre): the correction takes the plate's reflectance from the map, and a part
    of the plate outside the region would count as dark."""
    cx, cy = near.centre
    half = 0.5 * plate_width / near.pitch  # in pixels
    lo_x, hi_x, lo_y, hi_y = cx - half, cx + half, cy - half, cy + half
    if (
        roi.x > lo_x + 0.5
        or roi.x + roi.w < hi_x - 0.5
        or roi.y > lo_y + 0.5
        or roi.y + roi.h < hi_y - 0.5
    ):
        raise InputError(
            f"the medium's blur: the region {roi} (x, y, width, height in pixels) does not "
            f"cover the plate, {plate_width:g} wide, which spans pixels {lo_x:g} to {hi_x:g} "
            f"in x and {lo_y:g} to {hi_y:g} in y at a pixel pitch of {near.pitch:g} about "
            f"the optical centre ({cx:g}, {cy:g}); map the whole plate (the correction takes "
            f"every part of the plate's reflectance from the map), or check --pixel-pitch "
            f"and the medium's plate width"
        )


def check_prior(prior, maps: dict, tables) -> None:
    """The prior map refused unless it has the family, free parameters and grid of
    ``tables``."""
    grid = [a.describe() for a in tables.axes]
    _same(
        prior, maps["info"], {"model": tables.model, "free": list(tables.free_names), "grid": grid}
    )


def _same(prior, info: dict, mine: dict) -> None:
    """An InputError naming the first of ``mine`` that the prior map's ``info`` differs in
    (a manifest the same file by another path is the same)."""
    for key in mine:
        theirs = info.get(key)
        if key == "manifest" and isinstance(theirs, str):
            same = os.path.realpath(theirs) == os.path.realpath(mine[key])
        else:
            same = mine[key] == theirs
        if not same:
            raise InputError(
                f"--blur-from {prior}: that map's {key} is {info.get(key)!r}, this one's "
                f"{mine[key]!r}; give a map of the same photos, region, family, free "
                f"parameters and channels"
            )


def _grid_coord(axis, value) -> np.ndarray:
    """Grid coordinate of physical values along a table's axis, held inside the table."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.clip(axis.grid(value), 0.0, axis.count - 1.0)


def prior_parameters(maps: dict, tables) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From a prior map's arrays (:func:`veil.maps.store.open_maps`): (scales (h, w, C, q),
    nonlinear grid coordinates (h, w, d), the pixels used (h, w)), every pixel that did
    not converge given its nearest converged pixel's parameters."""
    from scipy.ndimage import distance_transform_edt

    info = maps["info"]
    shared, per = list(info["params"]), list(info.get("channel_params") or [])
    h, w = maps["status"].shape
    channels = max(1, len(tables.channels))

    def plane(name):
        if name in per:
            return np.moveaxis(maps["channel_params"][per.index(name)], 0, -1)  # (h, w, C)
        return np.repeat(maps["params"][shared.index(name)][..., None], channels, axis=-1)

    scales = np.stack([plane(tables.names[i]) for i in tables.free_scales], axis=-1)
    coords = np.stack(
        [_grid_coord(a, plane(tables.names[a.index])[..., 0]) for a in tables.axes]
        or [np.zeros((h, w))],
        axis=-1,
    )[..., : len(tables.axes)]
    good = (maps["status"] == CONVERGED) & np.all(np.isfinite(scales), axis=(-2, -1))
    good &= np.all(np.isfinite(coords), axis=-1)
    if not good.any():
        raise InputError("the prior map has no converged pixel: nothing to blur")
    nearest = distance_transform_edt(~good, return_distances=False, return_indices=True)
    return scales[nearest[0], nearest[1]], coords[nearest[0], nearest[1]], good


def predicted(tables, scales, coords, batch: int = 4096) -> np.ndarray:
    """The tables' values at every pixel of the ROI: (C, M, h, w) for the pixels'
    ``scales`` (h, w, C, q) and nonlinear grid ``coords`` (h, w, d) (near-field tables)."""
    from .._jax import jax, jnp
    from .grid import interp_near

    d = len(tables.axes)
    x0, y0, tw, th = tables.near.roi
    rows, cols = np.mgrid[0:th, 0:tw]
    fu = tables.field_coords(x0 + cols.ravel(), y0 + rows.ravel())
    coef = jnp.asarray(tables.coef)
    one_channel = not tables.channels

    def value(f, u, s):
        basis = interp_near(coef, f, u, d)[0]  # (C, M, q + 1) or (M, q + 1)
        if one_channel:
            basis = basis[None]
        return jnp.einsum("cmq,cq->cm", basis[..., :-1], s) + basis[..., -1]

    run = jax.jit(jax.vmap(value))
    s = scales.reshape(th * tw, *scales.shape[2:])
    u = coords.reshape(th * tw, d)
    out = [
        np.asarray(run(fu[a : a + batch], u[a : a + batch], s[a : a + batch]))
        for a in range(0, th * tw, batch)
    ]
    values = np.concatenate(out)  # (pixels, C, M)
    return np.moveaxis(values, 0, -1).reshape(values.shape[1], values.shape[2], th, tw)


def corrected(prior: tuple, medium, acq, tables, tables_of) -> tuple:
    """(``acq`` with the correction (B.3) from the map ``prior`` ((path, arrays) of
    :func:`prior_maps`), the store's record of it with the seconds taken): ``medium`` a
    model or {channel: model}, ``tables`` the fit's, ``tables_of(medium)`` the tables of
    another medium (without view-side scattering, of the endless plate)."""
    path, maps = prior
    check_prior(path, maps, tables)
    t0 = time.perf_counter()
    trio = (tables,) + tuple(tables_of(with_plate_width(medium, w)) for w in (NO_VIEW, ENDLESS))
    correction = blur_correction(trio, maps, media_of(medium), tables.near.geometry.pitch)
    record = {
        "store": str(path),
        "fingerprint": maps["info"]["fingerprint"],
        "seconds": time.perf_counter() - t0,
    }
    return dataclasses.replace(acq, correction=correction), record


def plate_share(kernels: np.ndarray, half_width: float, pitch: float) -> np.ndarray:
    """F_0 of (B.3): the part of each kernel (..., 2 half + 1, 2 half + 1) that lands on
    a square plate of ``half_width`` seen from its centre (each pixel's bin weighted by
    the part of it on the plate)."""
    half = kernels.shape[-1] // 2
    a = half_width / pitch
    overlap = np.clip(a + 0.5 - np.abs(np.arange(-half, half + 1)), 0.0, 1.0)
    return np.einsum("...ij,i,j->...", kernels, overlap, overlap)


def blur_correction(trio: tuple, maps: dict, media: list, pitch: float) -> np.ndarray:
    """(B.3): the correction of the photos, (C, M, h, w), from the tables of the fit,
    without view-side scattering and of the endless plate (``trio``) at the prior map's
    parameters, the view side's part of the endless plate blurred by each channel's
    :func:`view_kernels` (``media`` in the channels' order) about the view direction at the
    plate centre."""
    plate = trio[0]
    scales, coords, _ = prior_parameters(maps, plate)
    f_plate, f_none, f_end = (predicted(t, scales, coords) for t in trio)
    h, w = f_plate.shape[2:]
    geometry = plate.near.geometry
    cx, cy = geometry.centre
    _, _, theta_r, phi_r = geometry.angles(plate.angles, cx - 0.5, cy - 0.5)  # the centre
    half_width = 0.5 * float(media[0].plate_width)
    half = max(h, w, int(math.ceil(half_width / pitch)) + 1)
    x0, y0 = plate.near.roi[:2]
    rows, cols = np.mgrid[0:h, 0:w]
    p = geometry.plate_points(x0 + cols, y0 + rows)
    on_plate = (np.abs(p[..., 0]) <= half_width) & (np.abs(p[..., 1]) <= half_width)
    out = np.empty(f_plate.shape, dtype=np.float32)
    for m in range(f_plate.shape[1]):  # one configuration's kernels at a time
        k = view_kernels(theta_r[m : m + 1], phi_r[m : m + 1], media, pitch, half)
        fp, fn, fe = (f[:, m : m + 1] for f in (f_plate, f_none, f_end))
        share = plate_share(k, half_width, pitch)
        out[:, m : m + 1] = correction_of(fp, fn, fe, k, share, on_plate)
    return out


def correction_of(f_plate, f_none, f_end, kernels, shares, on_plate=None) -> np.ndarray:
    """(B.3) from the model's values (C, M, h, w) with the plate (``f_plate``), without
    view-side scattering (``f_none``) and with an endless plate (``f_end``), the kernels
    (C, M, k, k) and their shares on the plate (C, M) (:func:`plate_share`); pixels off
    ``on_plate`` (h, w) send no light (default: every pixel is on the plate)."""
    from scipy.signal import correlate

    endless = f_end - f_none  # S_inf: the view side's part of an endless plate
    own = f_plate - f_none  # S_plate: the model's, with the plate's width at its centre
    out = np.zeros_like(f_plate)
    for c in range(f_plate.shape[0]):
        for m in range(f_plate.shape[1]):
            source = endless[c, m] if on_plate is None else np.where(on_plate, endless[c, m], 0.0)
            blurred = correlate(source, kernels[c, m], mode="same", method="fft")
            s_inf = endless[c, m]
            ok = s_inf > 1e-12 * max(float(np.abs(s_inf).max()), 1e-300)
            ratio = blurred / np.where(ok, shares[c, m] * s_inf, 1.0)
            out[c, m] = np.where(ok, own[c, m] * (ratio - 1.0), 0.0)
    return out


__all__ = [
    "view_kernels",
    "check_medium",
    "check_prior",
    "prior_maps",
    "corrected",
    "with_plate_width",
    "prior_parameters",
    "predicted",
    "plate_share",
    "blur_correction",
    "correction_of",
]
