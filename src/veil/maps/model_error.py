"""The model's own error in the maps (docs/maps-model-error.md): every converged pixel's
standard errors with the relative model error its residuals show, channel by channel, as a
single fit adds it (docs/uncertainty.md, "The model's own error";
:mod:`veil.fitting.model_error`).

For each pixel and channel c the model's values f (the tables at the pixel's solution) are
off by s_c f d, d a Gaussian process over the configurations with correlation
R = exp(-D / ell). s_c comes from the pixel's own residuals in that channel by the
restricted likelihood (:func:`veil.fitting.model_error.step_term`, with its chi-square test:
s_c = 0 where the residuals show no excess, the model's declared floor and the given
medium's term as in step 2). ell is one number per tile and channel: the length of
:data:`veil.fitting.model_error.LENGTHS` that maximizes the likelihood summed over up to
:data:`SAMPLE` of the tile's converged pixels (each at its own best s), since one pixel's
residuals say little about it. The covariance of the pixel's estimate becomes

    C + sum_c s_c^2 (A_c J_w,c C)^T R_c (A_c J_w,c C),

C the noise's covariance, J_w,c and A_c = diag(f / sigma) the channel's rows
(:func:`veil.fitting.model_error.sandwich`): the channels' errors are independent of each
other. The estimates do not move.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._jax import jax, jnp
from ..errors import FitError, InputError
from ..fitting import least_squares as lsq
from ..fitting.model_error import (
    LENGTHS,
    ModelError,
    check_kind,
    correlation,
    distances,
    length_profile,
    sandwich,
    shows_excess,
    step_term,
)
from .solve import _CALL_LOCK, BATCH, _PixelSolver, pixel_coords, weights
from .solve_channels import _ChannelSolver
from .status import CONVERGED
from .tables import MapTables

#: The converged pixels of a tile (evenly spaced among them) whose summed likelihood
#: chooses the tile's correlation length in each channel.
SAMPLE = 64
_PROGRAMS: dict = {}
#: Tiles inside :func:`one_blas_thread` and the limit they share (the limit is the
#: process's, not a thread's: set by the first tile in, restored by the last out).
_BLAS = threading.Lock()
_INSIDE: list = [0, None]


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """One BLAS thread while the terms are computed: their matrices are of the size of a
    pixel's configurations, where OpenBLAS's threads cost more than they give (an
    eigendecomposition of 108 x 108: 1.3 ms on one thread, 8.8 ms on two beside other
    work; benchmarks/bench_maps_model_error.py), and tiles run side by side on threads."""
    from threadpoolctl import threadpool_limits

    with _BLAS:
        if _INSIDE[0] == 0:
            _INSIDE[1] = threadpool_limits(limits=1, user_api="blas")
        _INSIDE[0] += 1
    try:
        yield
    finally:
        with _BLAS:
            _INSIDE[0] -= 1
            if _INSIDE[0] == 0:
                _INSIDE[1].restore_original_limits()
                _INSIDE[1] = None


@dataclass(frozen=True)
class Discrepancy:
    """What the maps' term is made of: ``kind`` ("independent" or "correlated"), the
    models' declared ``floor`` (s, ell) or None, the given medium's term (``given_sigma``,
    ``given_length``; 0 without one)."""

    kind: str
    floor: tuple | None = None
    given_sigma: float = 0.0
    given_length: float = 0.0


def discrepancy(kind, noise, floor=None, given=None) -> Discrepancy | None:
    """The maps' setting for ``kind`` (None for "off"): an InputError without ``noise``
    (unweighted maps scale their errors by the residuals already); ``given`` the medium
    result's :class:`~veil.fitting.model_error.ModelError` or None."""
    try:
        kind = check_kind(kind) if kind is not None else "off"
    except FitError as exc:
        raise InputError(str(exc)) from None
    if kind == "off":
        return None
    if noise is None:
        raise InputError(
            f"model error {kind!r} needs weighted maps (--noise REL): without the noise "
            f"the standard errors are scaled by each pixel's residuals already"
        )
    return Discrepancy(
        kind,
        None if floor is None else (float(floor[0]), float(floor[1])),
        0.0 if given is None else float(given.sigma),
        0.0 if given is None else float(given.length),
    )


def record(setting: Discrepancy) -> dict:
    """The store's record of ``setting`` (its attribute ``model_error``)."""
    return {
        "kind": setting.kind,
        "floor": None if setting.floor is None else list(setting.floor),
        "given": [setting.given_sigma, setting.given_length],
    }


def fingerprint_key(setting: Discrepancy) -> str:
    """What a store's fingerprint takes of ``setting``: its record, the sample's size and
    the lengths (they change the terms)."""
    import json

    return json.dumps(
        record(setting) | {"sample": SAMPLE, "lengths": list(LENGTHS)}, sort_keys=True
    )


def _program(tables: MapTables):
    """The jitted (values (N, C * M), compact Jacobian (N, C * M, q + d)) of the tables
    at pixels' solver parameters, made once per shape."""
    c, q, d = len(tables.channels), len(tables.free_scales), len(tables.axes)
    sizes = tuple(a.count for a in tables.axes)
    near = tables.near is not None
    key = (c, q, d, sizes, near)
    with _CALL_LOCK:
        return _PROGRAMS.get(key) or _PROGRAMS.setdefault(key, _made(c, q, d, sizes, near))


def _made(c: int, q: int, d: int, sizes: tuple, near: bool):
    """:func:`_program`'s jitted function for one shape."""
    solver = (
        _ChannelSolver(c, q, d, sizes, True, near) if c else _PixelSolver(q, d, sizes, True, near)
    )

    def columns(coef, fu, p):
        return solver.columns(coef, fu, p[: solver.q], p[solver.q :])

    return jax.jit(jax.vmap(columns, in_axes=(None, 0 if near else None, 0)))


def at_solution(tables: MapTables, fu, p, idx, coef=None) -> tuple:
    """(values (K, C * M), compact Jacobian (K, C * M, q + d)) of the pixels ``idx`` at
    their parameters ``p``, in batches of the solve's size (one program whatever the
    count; the last batch padded), one call at a time as the solve's; of the tables'
    coefficients or of ``coef`` of their shape (the values are linear in them)."""
    run = _program(tables)
    coef = jnp.asarray(tables.coef if coef is None else coef)
    values, jacobians = [], []
    for start in range(0, len(idx), BATCH):
        part = idx[start : start + BATCH]
        rows = np.concatenate([part, np.full(BATCH - len(part), part[0])])
        with _CALL_LOCK:
            v, j = run(coef, None if fu is None else jnp.asarray(fu[rows]), jnp.asarray(p[rows]))
            values.append(np.asarray(v)[: len(part)])
            jacobians.append(np.asarray(j)[: len(part)])
    return np.concatenate(values), np.concatenate(jacobians)


def full_jacobian(compact: np.ndarray, channels: int, q: int) -> np.ndarray:
    """(N, C * M, C * q + d) from the compact (N, C * M, q + d): each channel's rows have
    its own scales' columns."""
    n, rows, width = compact.shape
    if channels <= 1:
        return compact
    m, d = rows // channels, width - q
    full = np.zeros((n, rows, channels * q + d))
    for c in range(channels):
        full[:, c * m : (c + 1) * m, c * q : (c + 1) * q] = compact[:, c * m : (c + 1) * m, :q]
    full[:, :, channels * q :] = compact[:, :, q:]
    return full


def _pixel_angles(tables: MapTables, pixels, i: int) -> tuple:
    """The canonical angles of pixel ``i``'s configurations (near field: its own)."""
    if tables.near is None:
        return tuple(np.asarray(a, dtype=float) for a in tables.angles)
    return tables.near.geometry.angles(tables.angles, pixels[0][i], pixels[1][i])


def pixel_terms(tables: MapTables, y, w2, p, fu, pixels, ok, setting: Discrepancy) -> tuple:
    """The term of every pixel (module docstring): (s (C', N), ell (C', N), standard
    errors (N, n) of the solver's parameters with it), for ``y`` and ``w2`` (N, C * M)
    the values and squared weights the solve used, ``p`` (N, n) its parameters in the
    solver's coordinates, ``fu`` the near field's pixel coordinates (else None),
    ``pixels`` their positions, ``ok`` the converged pixels; zeros elsewhere."""
    channels, q = max(1, len(tables.channels)), len(tables.free_scales)
    m = tables.n_configs
    n_pix, n = p.shape
    sigma, length = np.zeros((channels, n_pix)), np.zeros((channels, n_pix))
    se = np.zeros((n_pix, n))
    idx = np.flatnonzero(ok)
    if not idx.size:
        return sigma, length, se
    f, compact = at_solution(tables, fu, p, idx)
    jac = full_jacobian(compact, len(tables.channels), q)
    w = np.sqrt(w2[idx])
    r, a = (y[idx] - f) * w, f * w
    jw = jac * w[:, :, None]
    axes = list(range(channels * q, n))
    parts = [
        (slice(c * m, (c + 1) * m), list(range(c * q, (c + 1) * q)) + axes) for c in range(channels)
    ]
    with one_blas_thread():
        _terms(tables, pixels, idx, (r, a, f, w, jw), parts, setting, (sigma, length, se))
    return sigma, length, se


def _terms(tables, pixels, idx, rows_of, parts, setting: Discrepancy, out) -> None:
    """:func:`pixel_terms`' loop over the converged pixels ``idx``: their weighted residuals,
    scaled values, values, weights and weighted Jacobians (``rows_of``) into ``out`` (s,
    ell, standard errors)."""
    r, a, f, w, jw = rows_of
    sigma, length, se = out
    ells = _tile_lengths(tables, pixels, idx, r, a, jw, w, parts, setting)
    given = (
        ModelError(setting.given_sigma, setting.given_length, setting.given_sigma, None, "", 0.0)
        if setting.given_sigma > 0
        else None
    )
    shared = None if tables.near is not None else _Distances(tables, pixels, idx[0])
    for k, i in enumerate(idx):
        dist = shared or _Distances(tables, pixels, i)
        cov, full = lsq.covariance(jw[k], np)
        terms = []
        try:
            for c, (rows, cols) in enumerate(parts):
                term = step_term(
                    r[k, rows],
                    f[k, rows],
                    w[k, rows],
                    int(np.count_nonzero(w[k, rows])) - len(cols),
                    dist.angles,
                    given=given,
                    kind=setting.kind,
                    weighted_jacobian=jw[k, rows][:, cols],
                    floor=setting.floor,
                    lengths=(ells[c],),
                    dist=lambda d=dist: d.matrix,
                )
                terms.append((rows, term.sigma, term.length))
        except FitError:  # no relative error explains the channel's excess (a = 0)
            continue
        total = cov
        for rows, s, ell in terms:
            if s > 0:
                corr = None if ell == 0 else correlation(dist.matrix, ell)
                total = total + (sandwich(cov, jw[k, rows], a[k, rows], s, corr) - cov)
        stderr = np.sqrt(np.maximum(np.diag(total), 0.0))
        if full and np.all(np.isfinite(stderr)):  # else the noise's errors, no term
            se[i] = stderr
            for c, (_, s, ell) in enumerate(terms):
                sigma[c, i], length[c, i] = s, ell


class _Distances:
    """A pixel's configurations' angles and, when first asked for, their distances D."""

    def __init__(self, tables, pixels, i) -> None:
        self.angles = _pixel_angles(tables, pixels, int(i))
        self._matrix: np.ndarray | None = None

    @property
    def matrix(self) -> np.ndarray:
        if self._matrix is None:
            self._matrix = distances(self.angles)
        return self._matrix


def _tile_lengths(tables, pixels, idx, r, a, jw, w, parts, setting: Discrepancy) -> list:
    """Each channel's ell for the tile: 0 for an independent term, else the length whose
    likelihood summed over up to :data:`SAMPLE` converged pixels whose residuals in the
    channel show an excess (evenly spaced among them) is the largest
    (:data:`~veil.fitting.model_error.LENGTHS`; the first when none does, and then no pixel
    has a term of its own)."""
    if setting.kind != "correlated":
        return [0.0] * len(parts)
    ells = []
    for rows, cols in parts:
        dof = np.count_nonzero(w[:, rows], axis=1) - len(cols)
        excess = np.flatnonzero([shows_excess(r[k, rows], dof[k]) for k in range(len(idx))])
        take = np.linspace(0, len(excess) - 1, min(SAMPLE, len(excess))).round().astype(int)
        total = np.zeros(len(LENGTHS))
        for k in excess[np.unique(take)]:
            dist = distances(_pixel_angles(tables, pixels, int(idx[k])))
            nll = length_profile(
                r[k, rows], a[k, rows], int(dof[k]), dist, LENGTHS, jw[k, rows][:, cols]
            )
            if nll is not None:
                total += nll
        ells.append(float(LENGTHS[int(np.argmin(total))]))
    return ells


def solver_parameters(tables: MapTables, fits) -> np.ndarray:
    """(N, n) the solver's parameters of a tile's fits (:class:`veil.maps.solve.PixelFits`
    or :class:`veil.maps.solve_channels.ChannelFits`): the scales, channel after channel,
    then the axes' grid coordinates."""
    per = getattr(fits, "channel_params", None)
    return _solver_order(tables, fits, per, fits.params, lambda a, v, phys: a.grid(v))


def solver_stderr(tables: MapTables, fits) -> np.ndarray:
    """(N, n) the standard errors of :func:`solver_parameters` (0 where not reported)."""
    per = getattr(fits, "channel_stderr", None)
    return _solver_order(
        tables, fits, per, fits.stderr, lambda a, se, phys: se / a.physical_stderr(1.0, phys)
    )


def _solver_order(tables: MapTables, fits, per_values, values, axis) -> np.ndarray:
    """``per_values`` (the parameters per channel's arrays) and ``values`` (the others')
    in the solver's order, each axis's through ``axis(axis, value, physical value)``."""
    if tables.channels:
        per, shared = list(fits.per_channel), list(fits.shared)
        scales = [
            per_values[per.index(i), c]
            for c in range(len(tables.channels))
            for i in tables.free_scales
        ]
        rows = [shared.index(a.index) for a in tables.axes]
    else:
        scales = [values[i] for i in tables.free_scales]
        rows = [a.index for a in tables.axes]
    axes = [axis(a, values[r], fits.params[r]) for r, a in zip(rows, tables.axes)]
    return np.stack(scales + axes, axis=1)


def solution_rows(tables: MapTables, fits, y, valid, noise, pixels, basis=None) -> tuple:
    """What a tile's fits are evaluated with after the solve: (values (N, C * M), squared
    weights (N, C * M), the solver's parameters (N, n), the near field's pixel coordinates
    or None, the converged pixels), ``y``, ``valid``, ``noise``, ``pixels`` and ``basis``
    as the solve took them ((N, M), over channels (N, C, M))."""
    n_pix = len(fits.status)
    flat = (n_pix * len(tables.channels), -1) if tables.channels else (n_pix, -1)
    of = None if basis is None else np.reshape(basis, flat)
    yf, _, w2 = weights(tables, np.reshape(y, flat), np.reshape(valid, flat), noise, of)
    fu = pixel_coords(tables, pixels, n_pix)
    p = solver_parameters(tables, fits)
    return yf.reshape(n_pix, -1), w2.reshape(n_pix, -1), p, fu, fits.status == CONVERGED


def with_term(
    tables: MapTables, fits, y, valid, noise, pixels, setting: Discrepancy, basis=None
) -> tuple:
    """(``fits`` with every converged pixel's standard errors including its term, where it
    has one; s (C', N); ell (C', N)), ``y`` and ``valid`` a tile's values as its solve
    took them ((N, M), over channels (N, C, M)), ``pixels`` their positions (near field),
    ``basis`` the values its noise was taken of (:func:`noise_basis`)."""
    yf, w2, p, fu, ok = solution_rows(tables, fits, y, valid, noise, pixels, basis)
    sigma, length, se = pixel_terms(tables, yf, w2, p, fu, pixels, ok, setting)
    moved = ok & np.any(sigma > 0, axis=0)
    return with_solver_stderr(tables, fits, se, moved), sigma, length


def noise_basis(tables: MapTables, fits, y, pixels) -> np.ndarray:
    """The values a weighted solve takes its relative noise of (docs/maps-noise.md),
    shaped as ``y``: the model's at each converged pixel's solution (``fits``), where
    positive, and the samples ``y`` elsewhere."""
    y = np.asarray(y, dtype=float)
    n_pix = len(fits.status)
    out = y.reshape(n_pix, -1).copy()
    idx = np.flatnonzero(fits.status == CONVERGED)
    if idx.size:
        values, _ = at_solution(
            tables, pixel_coords(tables, pixels, n_pix), solver_parameters(tables, fits), idx
        )
        good = np.isfinite(values) & (values > 0)
        out[idx] = np.where(good, values, out[idx])
    return out.reshape(y.shape)


def with_solver_stderr(tables: MapTables, fits, se, moved) -> Any:
    """``fits`` with the standard errors of the pixels ``moved`` (a mask) replaced by
    ``se`` (N, n), those of :func:`solver_parameters`, in the fits' units (the axes'
    through :meth:`veil.maps.grid.Axis.physical_stderr`)."""
    q = len(tables.free_scales)
    stderr = np.array(fits.stderr, copy=True)
    if tables.channels:
        per, shared = list(fits.per_channel), list(fits.shared)
        channel_stderr = np.array(fits.channel_stderr, copy=True)
        for c in range(len(tables.channels)):
            for k, i in enumerate(tables.free_scales):
                channel_stderr[per.index(i), c, moved] = se[moved, c * q + k]
        rows = [shared.index(a.index) for a in tables.axes]
        first = len(tables.channels) * q
    else:
        for k, i in enumerate(tables.free_scales):
            stderr[i, moved] = se[moved, k]
        rows, first = [a.index for a in tables.axes], q
    for k, (row, a) in enumerate(zip(rows, tables.axes)):
        phys = fits.params[row, moved]
        stderr[row, moved] = a.physical_stderr(se[moved, first + k], phys)
    out = dataclasses.replace(fits, stderr=stderr)
    if tables.channels:
        out = dataclasses.replace(out, channel_stderr=channel_stderr)
    return out


__all__ = [
    "SAMPLE",
    "Discrepancy",
    "discrepancy",
    "record",
    "fingerprint_key",
    "one_blas_thread",
    "pixel_terms",
    "at_solution",
    "solution_rows",
    "noise_basis",
    "full_jacobian",
    "solver_parameters",
    "solver_stderr",
    "with_term",
    "with_solver_stderr",
]
