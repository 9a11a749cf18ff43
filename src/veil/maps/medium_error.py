"""The medium's uncertainty in the maps (docs/maps-medium-error.md): every converged pixel's
standard errors with the step-1 medium's covariance propagated to first order, as the single
fits propagate it (docs/uncertainty.md, "Propagation"; :mod:`veil.fitting.propagation`).

A pixel's estimate x solves J_w^T r_w(x, theta) = 0 for the medium's parameters theta held
at the step-1 values, so it moves by S d theta, S = -J_w^+ J_w,theta, and its covariance
gains S Cov_theta S^T (Cov_theta the medium result's total covariance). J_w,theta comes
from tables built once per medium parameter at theta_k + h_k (h_k a tenth of its standard
error, inward at a bound) on the base tables' grids: column k is the change of the pixel's
values at its own solution over h_k. Channels whose media a step
leaves alone have no column there. The estimates do not move; the part is the same in
every pixel of the map to the extent the pixels are alike: an error shared by the map, not
averaged away over pixels.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from .channels import map_media
from .geometry_notes import MapsWarning
from .grid import field_block
from .model_error import at_solution, full_jacobian, solution_rows
from .tables import MapTables, coef_by_channel

if TYPE_CHECKING:
    from .near import FieldGrid

#: The maps' propagation methods: "off" (the noise alone, as before) or "linear".
METHODS = ("off", "linear")
#: How much coarser the field grid of near-field tables' differences is than the tables'
#: own: the medium's effect changes across the field more slowly than the columns do.
COARSE = 3
#: The step h_k of a medium parameter's difference quotient, as a fraction of its standard
#: error: small enough for the derivative (a secant over a whole standard error missed it
#: by up to 14 % for g at 0.93 +- 0.05), large against the tables' rounding.
STEP = 0.1


@dataclass(frozen=True)
class MediumSpread:
    """What the maps propagate: the medium result's parameters that move the map's media
    (``names``, their ``values``), their total ``covariance``, the ``steps`` h_k the tables
    are rebuilt at, the media there (``media``, as :func:`map_media` gives them) and the
    channels each moves (``changed``; "" for a map of one channel); once built
    (:func:`with_differences`), each step's change of the tables' coefficients
    (``differences``, zero in the channels the step leaves alone)."""

    names: tuple[str, ...]
    values: tuple[float, ...]
    steps: tuple[float, ...]
    covariance: np.ndarray
    media: tuple = dataclasses.field(repr=False)
    changed: tuple[tuple[str, ...], ...]
    base: object = dataclasses.field(default=None, repr=False)
    differences: tuple[np.ndarray, ...] = dataclasses.field(default=(), repr=False)


def check_method(method, medium) -> str:
    """``method`` (None: "off") checked against ``medium``: "linear" needs a step-1 result
    with a covariance (an InputError naming what was given otherwise)."""
    method = "off" if method is None else str(method)
    if method not in METHODS:
        raise InputError(f"propagation {method!r}: expected one of {', '.join(METHODS)}")
    if method == "off":
        return method
    if not hasattr(medium, "covariance"):
        raise InputError(
            f"--propagation {method} needs the medium's covariance, and --medium is a medium "
            f"model given by its values; give the JSON file of 'veil fit medium'"
        )
    se = medium.stderr_total if medium.stderr_total is not None else medium.stderr
    lost = [n for n in medium.free if not _finite(se.get(n))]
    if lost or medium.covariance(total=True) is None:
        raise InputError(
            f"--propagation {method}: the medium result's "
            f"{', '.join(lost) or 'covariance'} has no finite standard error (not "
            f"determined); fix it in step 1, or map without propagation"
        )
    return method


def _finite(value) -> bool:
    return value is not None and math.isfinite(float(value))


def _media_key(media) -> dict:
    """{channel or "": the medium's vector} of a map's media (:func:`map_media`)."""
    model, per = media
    items = per.items() if per is not None else [("", model)]
    return {c: tuple(float(v) for v in m.to_vector()) for c, m in items}


def _spec(medium, name: str):
    """The declared parameter of ``medium``'s family that ``name`` is (channel names,
    tau[r], by the result's layout); None for a name of no medium parameter."""
    cls = medium.model_class
    base = name
    for layout in (getattr(medium, "channels", None) or {}).values():
        base = next((p for p, n in layout.items() if n == name), base)
    return cls.param(base) if base in cls.param_names() else None


def _step(spec, value: float, se: float) -> float:
    """h: ``se`` (:data:`STEP` of the standard error) towards the inside of ``spec``'s
    bounds (half the room when less)."""
    up, down = spec.upper - value, value - spec.lower
    if se <= up:
        return se
    if se <= down:
        return -se
    return 0.5 * up if up >= down else -0.5 * down


def plan_spread(method, medium, channel) -> MediumSpread | None:
    """The :class:`MediumSpread` of the step-1 result ``medium`` for a map of ``channel``
    (its tables not built yet), or None with ``method`` "off" (:func:`check_method`)."""
    if check_method(method, medium) == "off":
        return None
    names, cov = medium.covariance(total=True)
    here = map_media(medium, channel)
    base = _media_key(here)
    kept, values, steps, media, changed = [], [], [], [], []
    for k, name in enumerate(names):
        spec, value, se = _spec(medium, name), float(medium.params[name]), math.sqrt(cov[k, k])
        if spec is None or not se > 0:
            continue
        h = _step(spec, value, STEP * se)
        at = dataclasses.replace(medium, params={**medium.params, name: value + h})
        moved = map_media(at, channel)
        which = tuple(c for c, v in _media_key(moved).items() if v != base[c])
        if which and h != 0:
            kept.append(k)
            values.append(value)
            steps.append(h)
            media.append(moved[1] if moved[1] is not None else moved[0])
            changed.append(which)
    _warn_first_order(medium, [names[k] for k in kept], cov[np.ix_(kept, kept)])
    return MediumSpread(
        tuple(names[k] for k in kept),
        tuple(values),
        tuple(steps),
        np.asarray(cov, dtype=float)[np.ix_(kept, kept)],
        tuple(media),
        tuple(changed),
        here[1] if here[1] is not None else here[0],
    )


def _warn_first_order(medium, names, cov) -> None:
    """A :class:`~veil.maps.geometry_notes.MapsWarning` when a medium parameter ``names``
    (those that move the map's media) is uncertain by more than
    :data:`veil.fitting.propagation.RELATIVE_LIMIT` of its scale,
    where the single fits leave the first order for sigma points (the maps keep it)."""
    from ..fitting.propagation import RELATIVE_LIMIT, RELATIVE_MAX, relative_uncertainty

    pairs = [(n, _spec(medium, n), k) for k, n in enumerate(names)]
    pairs = [(n, p, k) for n, p, k in pairs if p is not None]
    if not pairs:
        return
    rows = [k for _, _, k in pairs]
    values = [float(medium.params[n]) for n, _, _ in pairs]
    rel = relative_uncertainty(
        [p for _, p, _ in pairs], values, cov[np.ix_(rows, rows)], [n for n, _, _ in pairs]
    )
    wide = {n: r for n, r in rel.items() if r is None or r > RELATIVE_LIMIT}
    if wide:
        said = ", ".join(
            f"{n} by {r:.2g}" if r is not None and r <= RELATIVE_MAX else f"{n} (at a bound)"
            for n, r in wide.items()
        )
        warnings.warn(
            MapsWarning(
                f"the medium's uncertainty is propagated to first order, which is only "
                f"indicative where a parameter is uncertain by more than {RELATIVE_LIMIT:g} "
                f"of its scale (the value, or the room to a bound): {said}"
            ),
            stacklevel=2,
        )


def with_differences(
    spread: MediumSpread, tables: MapTables, rebuild: Callable, say
) -> MediumSpread:
    """``spread`` with its ``differences``: ``rebuild(media, field=...)`` builds the tables
    through each step's media on ``tables``' grids; near-field tables' differences over a
    field grid :data:`COARSE` times coarser (:func:`coarse_field`, the base medium's tables
    built there once more), interpolated onto the tables' field nodes. ``say`` reports each
    build."""
    order = list(tables.channels) or [""]
    coarse = None if tables.near is None else coarse_field(tables.near)
    base = None
    if coarse is not None:
        say(f"the medium's uncertainty: the differences over a {coarse.describe()}")
        base = rebuild(spread.base, field=coarse)
    diffs = []
    for k, (name, media) in enumerate(zip(spread.names, spread.media)):
        say(
            f"the medium's uncertainty: tables at {name} {spread.values[k]:.6g} "
            f"{spread.steps[k]:+.3g} ({k + 1} of {len(spread.names)})"
        )
        if base is None:
            diff = rebuild(media).coef - tables.coef
        else:
            moved = rebuild(media, field=coarse).values - base.values
            diff = _on_field(moved, coarse, tables)
        for j, c in enumerate(order):  # a channel the step leaves alone: no column
            if c not in spread.changed[k]:
                diff[..., j, :, :] = 0.0
        diffs.append(np.ascontiguousarray(diff))
    return dataclasses.replace(spread, differences=tuple(diffs))


def coarse_field(field: FieldGrid) -> FieldGrid | None:
    """A field grid over ``field``'s region with :data:`COARSE` times fewer nodes per axis
    (at least :data:`veil.maps.near.MIN_NODES`), or None when that is ``field`` itself."""
    from .near import MIN_NODES

    counts = [max(MIN_NODES, math.ceil(len(v) / COARSE)) for v in (field.xs, field.ys)]
    if tuple(counts) == field.shape:
        return None
    xs, ys = (
        tuple(float(v) for v in np.linspace(a[0], a[-1], n))
        for a, n in zip((field.xs, field.ys), counts)
    )
    return dataclasses.replace(field, xs=xs, ys=ys, step_deg=field.step_deg * COARSE)


def _on_field(values, coarse, tables: MapTables) -> np.ndarray:
    """The coefficients of ``tables``' layout of node ``values`` tabulated over the field
    grid ``coarse``: its spline evaluated at ``tables``' field nodes, then fitted there."""
    channels = len(tables.channels)
    spline = coef_by_channel(values, 0, 2, channels)
    fine = tables.near
    assert fine is not None  # near-field tables
    fx, fy = coarse.coords(np.asarray(fine.xs), np.asarray(fine.ys))
    nodes = np.stack(
        [np.stack([field_block(spline, (x, y)) for y in fy]) for x in fx]
    )  # (Kx, Ky, ...) on the tables' field nodes
    field_values = coef_by_channel(nodes, 0, 2, channels)
    return np.array(coef_by_channel(field_values, 2, len(tables.axes), channels))


def record(spread: MediumSpread) -> dict:
    """The store's record of ``spread`` (its attribute ``propagation``)."""
    se = np.sqrt(np.diag(spread.covariance))
    return {
        "method": "linear",
        "parameters": list(spread.names),
        "values": list(spread.values),
        "stderr": [float(s) for s in se],
        "steps": list(spread.steps),
    }


def fingerprint_key(spread: MediumSpread) -> str:
    """What a store's fingerprint takes of ``spread``: its record and covariance."""
    return json.dumps(record(spread) | {"covariance": spread.covariance.tolist()})


def medium_variance(
    tables: MapTables, spread: MediumSpread, fits, y, valid, noise, pixels, basis=None
) -> np.ndarray:
    """(N, n) the diagonal of S Cov_theta S^T (module docstring) of a tile's pixels in the
    solver's coordinates (:func:`veil.maps.model_error.solver_parameters`), zero where a
    pixel did not converge; ``y``, ``valid``, ``noise``, ``pixels`` and ``basis`` as the
    solve took them."""
    _, w2, p, fu, ok = solution_rows(tables, fits, y, valid, noise, pixels, basis)
    out = np.zeros(p.shape)
    idx = np.flatnonzero(ok)
    if not idx.size or not spread.names:
        return out
    w = np.sqrt(w2[idx])
    _, compact = at_solution(tables, fu, p, idx)
    jw = full_jacobian(compact, len(tables.channels), len(tables.free_scales)) * w[:, :, None]
    cols = [
        at_solution(tables, fu, p, idx, coef=d)[0] / h
        for d, h in zip(spread.differences, spread.steps)
    ]
    jt = np.stack(cols, axis=-1) * w[:, :, None]
    norms = np.linalg.norm(jw, axis=1)  # columns equilibrated, as the solver's covariance
    norms = np.where(norms > 0, norms, 1.0)
    sens = -(np.linalg.pinv(jw / norms[:, None, :]) @ jt) / norms[:, :, None]
    out[idx] = np.einsum("pik,kl,pil->pi", sens, spread.covariance, sens)
    return np.maximum(out, 0.0)


__all__ = [
    "METHODS",
    "STEP",
    "COARSE",
    "coarse_field",
    "MediumSpread",
    "check_method",
    "plan_spread",
    "with_differences",
    "record",
    "fingerprint_key",
    "medium_variance",
]
