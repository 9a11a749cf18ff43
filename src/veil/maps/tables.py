"""The tables of a per-pixel fit (docs/maps.md): the basis columns of the apparent value at
every node of the grid of the free nonlinear parameters, built once per acquisition through
the engine, and their B-spline coefficients; near-field tables add two axes of plate points
(docs/maps-geometry.md "Geometry"), tables over channels one of channels (docs/maps-channels.md):
:func:`tabulate` builds all four kinds."""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..engine.integrator import BRDF_PARTS, row_scales, unit_scale_indices
from ..errors import FitError
from .grid import _jnp, bspline_inverse, field_block, interp, interp_near, make_axes, parse_grid

if TYPE_CHECKING:
    from .near import FieldGrid


@dataclass
class MapTables:
    """Basis columns of the apparent value at a grid of the nonlinear parameters.

    ``values``: (K_1, ..., K_d, M, q + 1) node values: the q free scales' columns, then the
    known part C. ``coef``: the same with each axis replaced by its K + 2 B-spline
    coefficients. ``base``: the BRDF vector (fixed and held values; the free ones are
    overwritten per pixel). ``free_scales``: indices of the free scale parameters, in column
    order. ``axes``: the nonlinear axes.
    """

    model: str
    options: dict
    names: tuple
    base: np.ndarray
    free_scales: tuple
    axes: list
    values: np.ndarray
    coef: np.ndarray
    fixed: dict
    medium: dict
    accuracy: str
    angles: tuple = field(repr=False, default=())
    #: near-field tables (docs/maps-geometry.md "Geometry"): the field grid (a
    #: :class:`veil.maps.near.FieldGrid`), None for distant light and camera. Then
    #: ``values`` and ``coef`` have two leading axes more (the grid's x and y nodes);
    #: ``field_error`` is the largest interpolation error measured against exact per-pixel
    #: columns (relative to each column's maximum).
    near: FieldGrid | None = None
    field_error: float = float("nan")
    #: colour channels fitted at once (docs/maps-channels.md), empty for one channel.
    #: Then ``values`` and ``coef`` have a channel axis before the configurations'
    #: ((K_1, ..., K_d, C, M, q + 1)): each channel's columns through its own medium, the
    #: free scales per channel (``free_scales`` are then each channel's) and the nonlinear
    #: axes shared; near-field tables over channels have the two field axes first
    #: ((Kx, Ky, K_1, ..., K_d, C, M, q + 1)).
    channels: tuple = ()

    @property
    def n_free(self) -> int:
        return len(self.free_scales) + len(self.axes)

    @property
    def n_configs(self) -> int:
        return self.values.shape[-2]

    @property
    def solver_arrays(self) -> tuple:
        """(node values, spline coefficients) the solver runs on."""
        return self.values, self.coef

    def field_coords(self, x, y) -> np.ndarray:
        """(N, 2) field-grid coordinates of pixels (x, y) of the full photo (near field)."""
        if self.near is None:
            raise FitError("distant tables have no field grid: no pixel coordinates")
        fx, fy = self.near.coords(np.ravel(x), np.ravel(y))
        return np.stack([fx, fy], axis=1)

    @property
    def free_names(self) -> tuple:
        idx = list(self.free_scales) + [a.index for a in self.axes]
        return tuple(self.names[i] for i in idx)

    def fingerprint(self) -> str:
        """Hash of everything the tables depend on (and of the tables themselves)."""
        h = hashlib.sha256()
        h.update(
            repr(
                (
                    self.model,
                    sorted(self.options.items()),
                    self.names,
                    self.base.tolist(),
                    self.free_scales,
                    [a.__dict__ for a in self.axes],
                    sorted(self.fixed.items()),
                    self.medium,
                    self.accuracy,
                )
            ).encode()
        )
        for a in self.angles:
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        if self.near is not None:  # (distant tables hash as they always did)
            h.update(repr(self.near.as_dict()).encode())
        if self.channels:  # (tables of one channel hash as they always did)
            h.update(repr(self.channels).encode())
        h.update(np.ascontiguousarray(self.values).tobytes())
        return h.hexdigest()

    def describe(self) -> str:
        grid = "; ".join(a.describe() for a in self.axes) or "no nonlinear parameter"
        nodes = int(np.prod([a.count for a in self.axes])) if self.axes else 1
        text = (
            f"{self.model}: free {', '.join(self.free_names)}; table {grid}; {nodes} "
            f"node(s) x {self.n_configs} configurations ({self.accuracy} quadrature)"
        )
        if self.near is not None:
            text += (
                f"; {self.near.describe()}, interpolation error "
                f"{self.field_error:.2g} of a column's maximum"
            )
        if self.channels:
            text += f"; channels {', '.join(self.channels)}"
        return text

    def basis(self, node_values: dict, pixel=None) -> np.ndarray:
        """(M, q + 1) columns at physical values of the nonlinear parameters, by the
        spline (numpy; for checks); near-field tables at ``pixel`` (x, y) of the photo."""
        jnp = _jnp()
        u = np.array([a.grid(node_values[a.name]) for a in self.axes])
        if self.near is None:
            b, _ = interp(jnp.asarray(self.coef), jnp.asarray(u), len(self.axes))
        else:
            fu = self.field_coords(*pixel)[0]
            b, _ = interp_near(
                jnp.asarray(self.coef), jnp.asarray(fu), jnp.asarray(u), len(self.axes)
            )
        return np.asarray(b)


def _template(brdf_cls, fixed: dict, freed: set, options) -> tuple:
    """(the family's model at its starting values with ``options``, its vector with the
    ``fixed`` values), every name and value checked."""
    from ..fitting.solver import check_fixed

    names = brdf_cls.param_names()
    for n in list(fixed) + list(freed):
        if n not in names:
            raise FitError(
                f"{brdf_cls.NAME} has no parameter {n!r}; its parameters are {', '.join(names)}"
            )
    for n, v in fixed.items():
        check_fixed(n, v, brdf_cls.param(n), brdf_cls.__name__)
    try:
        template = brdf_cls.template(**dict(options or {}))
    except (ValueError, TypeError) as exc:
        raise FitError(str(exc)) from None
    base = template.to_vector()
    for n, v in fixed.items():
        base[names.index(n)] = float(v)
    return template, base


def _unknowns(brdf_cls, fixed: dict, freed: set, base) -> tuple:
    """(the free scales, the free nonlinear parameters (indices), the parts of the free
    scales, each part's known weight: 0 for a free scale, else its value)."""
    if brdf_cls.LINEAR:
        raise FitError(
            f"{brdf_cls.NAME} is fitted by linear least squares in a step fit of one session "
            f"and one channel; maps fit another family per pixel (docs/nonparametric.md)"
        )
    free_set = [
        i
        for i, p in enumerate(brdf_cls.PARAMS)
        if p.name not in fixed and (not p.held or p.name in freed)
    ]
    scale_of = {
        brdf_cls.scale_index(part): part
        for part in BRDF_PARTS
        if brdf_cls.scale_index(part) is not None
    }
    free_scales = tuple(i for i in free_set if i in scale_of)
    nonlinear = [i for i in free_set if i not in scale_of]
    if not free_set:
        raise FitError("every parameter of the target is fixed: nothing to fit")
    free_parts = [BRDF_PARTS.index(scale_of[i]) for i in free_scales]
    known_weight = np.ones(len(BRDF_PARTS))
    for k, part in enumerate(BRDF_PARTS):
        i = brdf_cls.scale_index(part)
        if i is not None:
            known_weight[k] = 0.0 if i in free_scales else base[i]
    return free_scales, nonlinear, free_parts, known_weight


def build_tables(
    brdf_cls,
    medium,
    angles,
    *,
    fixed=None,
    options=None,
    free=None,
    grid=None,
    accuracy: str = "default",
    progress=None,
    near=None,
    roi=None,
    field=None,
) -> MapTables:
    """The tables of a per-pixel target fit: ``brdf_cls`` through ``medium`` (a medium
    model) at ``angles`` (theta_i, phi_i, theta_r, phi_r arrays, degrees). ``fixed``,
    ``free`` (held parameters to fit) and ``options`` as :func:`veil.fit_target`;
    ``grid`` {name: (lo, hi, count)} overrides a nonlinear axis; ``progress(done, total)``
    before the first node (done 0) and after each node of the nonlinear axes, near-field
    tables as distant ones. ``near`` (a :class:`veil.maps.near.NearGeometry`) with
    ``roi`` (x, y, w, h of the photo): near-field tables over a grid of plate points
    (:func:`veil.maps.near.field_grid`, docs/maps-geometry.md "Geometry"), or over
    ``field``, a :class:`veil.maps.near.FieldGrid` (another table's, to compare with it)."""
    fixed = dict(fixed or {})
    u, values, coef, angles, near_entries = tabulate(
        brdf_cls, medium, angles, fixed, options, free, grid, accuracy, progress, near, roi, field
    )
    return _tables(brdf_cls, u, medium, values, coef, fixed, accuracy, angles, **near_entries)


def tabulate(
    brdf_cls,
    medium,
    angles,
    fixed: dict,
    options,
    free,
    grid,
    accuracy,
    progress,
    near,
    roi,
    field=None,
) -> tuple:
    """What :func:`build_tables` tabulates: (the unknowns, the node values, their
    coefficients, the angles as float arrays, {"near": the field grid, "field_error": its
    error} of near-field tables or {}). ``medium``: a medium model, or {channel: medium
    model} (:func:`veil.maps.channels.build_channel_tables`: a channel axis before the
    configurations', each channel's columns and coefficients bit for bit its own tables')."""
    freed = set(free or ())
    names = brdf_cls.param_names()
    template, base = _template(brdf_cls, fixed, freed, options)
    free_scales, nonlinear, free_parts, known_weight = _unknowns(brdf_cls, fixed, freed, base)
    axes = make_axes(brdf_cls, nonlinear, parse_grid([], brdf_cls) | dict(grid or {}))
    angles = tuple(np.ascontiguousarray(a, dtype=float) for a in angles)
    u = _Unknowns(template, names, base, free_scales, axes, free_parts, known_weight)
    if near is not None:
        values, coef, fgrid, error = build_near(
            brdf_cls, medium, angles, u, accuracy, progress, near, roi, field
        )
        return u, values, coef, angles, {"near": fgrid, "field_error": error}
    columns = column_source(u, medium, angles, accuracy)
    channels = len(medium) if isinstance(medium, dict) else 0
    shape = tuple(a.count for a in axes)
    lead = (channels,) if channels else ()  # the channel axis, before the configurations'
    values = np.empty(shape + lead + (len(angles[0]), len(free_scales) + 1))
    total = int(np.prod(shape)) if shape else 1
    if progress is not None:  # the stage announced before its first node
        progress(0, total)
    for done, (combo, vb) in enumerate(_nodes(axes, base)):
        values[combo] = columns(vb)
        if progress is not None:
            progress(done + 1, total)
    coef = np.ascontiguousarray(coef_by_channel(values, 0, len(axes), channels))
    return u, values, coef, angles, {}


def engine_key(medium) -> tuple:
    """What a medium's term matrices depend on: its family, options and its vector with
    the scales at 1 (media of the same key differ only in their row weights)."""
    v = np.array(medium.to_vector(), dtype=float)
    for i in unit_scale_indices(medium):
        v[i] = 1.0
    return (type(medium).NAME, repr(sorted(medium.options().items())), v.tobytes())


def column_source(u: _Unknowns, medium, angles, accuracy: str) -> Callable[[Any], np.ndarray]:
    """The function of a BRDF vector giving the basis columns at ``angles``: (M, q + 1)
    through ``medium``, a medium model; (C, M, q + 1) through each of ``medium`` {channel:
    medium model} in its order, the engine evaluated once per group of channels whose media
    differ only in scales (their term matrices are the same, :func:`engine_key`), each
    such channel's columns bit for bit those of its medium alone; groups of a medium that
    declares a sampling law evaluated together by the channels' program
    (:mod:`veil.engine.channel_programs`: within the rule's error of each alone)."""
    from ..engine.channel_programs import shares_nodes
    from ..engine.evaluator import ApparentModel
    from ..engine.quadrature import RULES

    q = len(u.free_scales)
    if not isinstance(medium, dict):
        engine = ApparentModel(u.template, medium, angles, RULES[accuracy])
        vm = medium.to_vector()
        rows = row_scales(type(medium), vm)
        return lambda vb: _columns(engine, vb, vm, rows, u.free_parts, u.known_weight, q)
    channels = list(medium)
    groups: dict[tuple, list[int]] = {}
    for k, c in enumerate(channels):
        groups.setdefault(engine_key(medium[c]), []).append(k)
    firsts = [medium[channels[ks[0]]] for ks in groups.values()]
    together = len(groups) > 1 and shares_nodes(firsts[0]) and len({k[:2] for k in groups}) == 1
    one = ApparentModel(u.template, firsts[0], angles, RULES[accuracy]) if together else None
    engines = [
        (one or ApparentModel(u.template, first, angles, RULES[accuracy]), ks)
        for first, ks in zip(firsts, groups.values())
    ]
    rows = [row_scales(type(medium[c]), medium[c].to_vector()) for c in channels]

    def columns(vb):
        out = np.empty((len(channels), len(angles[0]), q + 1))
        if one is not None:  # every group's terms by one run of the channels' program
            # (every channel announced, as a fit does: one program per number of channels)
            one.anticipate([vb] * len(channels), [medium[c].to_vector() for c in channels])
        for engine, ks in engines:
            terms = engine.terms(vb, medium[channels[ks[0]]].to_vector())  # the scales at 1
            for k in ks:
                out[k] = columns_of_terms(terms, rows[k], u.free_parts, u.known_weight, q)
        return out

    return columns


def _nodes(axes, base):
    """(index of the node, BRDF vector there) for every node of the grid of ``axes``."""
    for combo in itertools.product(*[range(a.count) for a in axes]):
        vb = base.copy()
        for a, j in zip(axes, combo):
            vb[a.index] = a.nodes()[j]
        yield combo, vb


def smoothest_facet(brdf_cls, names, base, axes, options) -> float:
    """The BRDF's facet half angle (deg) at the smoothest corner of the table (inf when the
    family has no facet lobe)."""
    corners = itertools.product(*[(a.lo, a.hi) for a in axes]) if axes else [()]
    widths = []
    for corner in corners:
        v = np.array(base, dtype=float)
        for a, value in zip(axes, corner):
            v[a.index] = value
        try:
            model = brdf_cls.from_params(dict(zip(names, v)), options)
            widths.append(model.facet_half_angle())
        except (ValueError, TypeError):
            continue
    return min(widths) if widths else float("inf")


def _columns(engine, vb, vm, rows, free_parts, known_weight, q):
    """(M, q + 1) basis columns of the engine's configurations at BRDF vector ``vb``."""
    return columns_of_terms(engine.terms(vb, vm), rows, free_parts, known_weight, q)


def columns_of_terms(terms, rows, free_parts, known_weight, q) -> np.ndarray:
    """(M, q + 1) basis columns from the term matrices ``terms`` (M, rows, parts; the
    scales at 1) and the medium's row weights ``rows``."""
    cols = np.einsum("mrb,r->mb", terms, rows)
    out = np.empty(cols.shape[:1] + (q + 1,))
    for c, k in enumerate(free_parts):
        out[:, c] = cols[:, k]
    out[:, q] = cols @ known_weight
    return out


def _to_coef(values, axes_first: int, count: int):
    """B-spline coefficients along axes ``axes_first .. axes_first + count - 1``."""
    for ax in range(axes_first, axes_first + count):
        inv = bspline_inverse(values.shape[ax])
        values = np.moveaxis(np.tensordot(inv, values, axes=([1], [ax])), 0, ax)
    return values


def coef_by_channel(values, axes_first: int, count: int, channels: int) -> np.ndarray:
    """:func:`_to_coef` of ``values`` whose third last axis is ``channels`` channels
    (tables over channels), channel by channel: each channel's coefficients bit for bit
    those of its tables alone; of ``values`` of one channel (``channels`` 0) as they are."""
    if not channels:
        return _to_coef(values, axes_first, count)
    parts = [_to_coef(values[..., k, :, :], axes_first, count) for k in range(channels)]
    out = np.empty(parts[0].shape[:-2] + (channels,) + parts[0].shape[-2:])
    for k, one in enumerate(parts):
        out[..., k, :, :] = one
    return out


#: the centres of two opposite corner cells, farthest from the nodes in both axes.
FIELD_CHECKS = ((0.5, 0.5), (-0.5, -0.5))


def _check_pixels(fgrid, near, angles) -> list:
    """The pixels where the field interpolation is checked (:data:`FIELD_CHECKS`: cell
    centres of two opposite corner cells): [((gx, gy), their angles)]."""
    kx, ky = fgrid.shape
    checks = []
    for fx, fy in FIELD_CHECKS:
        gx = fx if fx >= 0 else kx - 1 + fx
        gy = fy if fy >= 0 else ky - 1 + fy
        x = fgrid.xs[0] + gx * (fgrid.xs[-1] - fgrid.xs[0]) / (kx - 1)
        y = fgrid.ys[0] + gy * (fgrid.ys[-1] - fgrid.ys[0]) / (ky - 1)
        checks.append(((gx, gy), near.angles(angles, x, y)))
    return checks


def _field_error(field_values, exact, checks) -> float:
    """The largest error of the field interpolation at the check pixels, relative to each
    column's maximum."""
    error = 0.0
    for k, ((gx, gy), _) in enumerate(checks):
        approx = field_block(field_values, (gx, gy))
        scale = np.max(np.abs(exact[k]), axis=-2, keepdims=True)
        scale = np.where(scale > 0, scale, 1.0)
        error = max(error, float(np.max(np.abs(approx - exact[k]) / scale)))
    return error


@dataclass(frozen=True)
class _Unknowns:
    """What :func:`build_tables` worked out of a family and its fixed and free parameters:
    the template model, its parameter names and base vector, the free scales, the nonlinear
    axes, the free parts and the known parts' weight (``_template``, ``_unknowns``)."""

    template: Any
    names: Any
    base: Any
    free_scales: Any
    axes: Any
    free_parts: Any
    known_weight: Any


def build_near(
    brdf_cls, medium, angles, unknowns: _Unknowns, accuracy, progress, near, roi, field=None
) -> tuple:
    """Near-field tables' (values, coefficients, field grid, interpolation error): the
    columns at every node of a grid of plate points and of the nonlinear axes, with the
    pixel's own angles (docs/maps-geometry.md "Geometry"); the field interpolation checked
    against exact columns at :data:`FIELD_CHECKS`. ``medium``: a medium model, or {channel:
    medium model} (tables over channels: a channel axis before the configurations'; the
    field grid follows the narrowest of the channels' lobes, or is ``field``)."""
    from .near import apparent_lobe, field_grid

    u = unknowns
    if roi is None:
        raise FitError("near-field tables need the region of the photo (roi)")
    media = list(medium.values()) if isinstance(medium, dict) else [medium]
    lobe = apparent_lobe(
        smoothest_facet(brdf_cls, u.names, u.base, u.axes, u.template.options()),
        min(m.lobe_half_width() for m in media),
    )
    fgrid = field_grid(near, angles, roi, lobe) if field is None else field
    kx, ky = fgrid.shape
    m = len(angles[0])
    node_angles = tuple(np.ascontiguousarray(a.reshape(-1)) for a in fgrid.node_angles(angles))
    checks = _check_pixels(fgrid, near, angles)
    all_angles = tuple(
        np.concatenate([node_angles[j]] + [c[1][j] for c in checks]) for j in range(4)
    )
    columns = column_source(u, medium, all_angles, accuracy)
    channels = len(medium) if isinstance(medium, dict) else 0
    lead = (channels,) if channels else ()  # the channel axis, before the configurations'
    shape = tuple(a.count for a in u.axes)
    cols_shape = lead + (m, len(u.free_scales) + 1)
    values = np.empty((kx, ky) + shape + cols_shape)
    exact = np.empty((len(checks),) + shape + cols_shape)
    total = int(np.prod(shape)) if shape else 1
    if progress is not None:  # the stage announced before its first node (each node is
        # the engine at every field node's angles: seconds each)
        progress(0, total)
    for done, (combo, vb) in enumerate(_nodes(u.axes, u.base)):
        cols = columns(vb)  # (C,)? (all angles, q + 1): the channels first
        nodes = cols[..., : kx * ky * m, :].reshape(lead + (kx, ky) + cols_shape[-2:])
        at_checks = cols[..., kx * ky * m :, :].reshape(lead + (len(checks),) + cols_shape[-2:])
        values[(slice(None), slice(None)) + combo] = np.moveaxis(nodes, 0, 2) if lead else nodes
        exact[(slice(None),) + combo] = np.moveaxis(at_checks, 0, 1) if lead else at_checks
        if progress is not None:
            progress(done + 1, total)
    field_values = np.ascontiguousarray(coef_by_channel(values, 0, 2, channels))
    coef = np.ascontiguousarray(coef_by_channel(field_values, 2, len(u.axes), channels))
    return values, coef, fgrid, _field_error(field_values, exact, checks)


def _tables(
    brdf_cls, u: _Unknowns, medium, values, coef, fixed, accuracy, angles, **near
) -> MapTables:
    """The :class:`MapTables` of ``values`` and their ``coef`` (``near``: the field grid
    and its error, for near-field tables)."""
    medium_entry = {
        "model": type(medium).NAME,
        "params": medium.as_dict(),
        "options": medium.options(),
    }
    return MapTables(
        brdf_cls.NAME,
        dict(u.template.options()),
        u.names,
        u.base,
        u.free_scales,
        u.axes,
        values,
        coef,
        dict(fixed),
        medium_entry,
        accuracy,
        angles,
        **near,
    )


__all__ = [
    "MapTables",
    "build_tables",
    "build_near",
    "tabulate",
    "column_source",
    "coef_by_channel",
    "columns_of_terms",
    "engine_key",
    "smoothest_facet",
    "FIELD_CHECKS",
]
