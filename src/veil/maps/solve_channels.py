"""Per-pixel step 2 over several colour channels at once (docs/maps-channels.md): every
pixel's channels one least-squares problem, the scales per channel and the nonlinear
parameters (roughness, index) shared, against tables with a channel axis
(:func:`veil.maps.channels.build_channel_tables`), distant or near-field (each pixel at
its own field coordinates, as the one-channel solve).

The solve is :mod:`veil.maps.solve`'s, with the parameters (s_1, ..., s_C, theta): each
channel's value is sum_k s_ck B_ck(theta) + C_c(theta), its rows of the Jacobian are
nonzero in its own scales and in theta. Given theta the channels' scales are independent,
so at every node and at every trial point each channel's scales are its exact
non-negative least-squares optimum (the grey solve's variable projection, channel by
channel), and the best node is the one of the least total cost. The iterations, the
stopping rule, the covariance and the status are the one-channel solve's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._jax import jnp
from ..errors import FitError
from ..fitting import least_squares as lsq
from .solve import (
    _SOLVERS,
    _PixelSolver,
    _run,
    _status,
    compiled,
    node_scales,
    pixel_coords,
    warm_up,
    weights,
)
from .status import CONVERGED, FEW_POINTS, MASKED
from .tables import MapTables


class _ChannelSolver(_PixelSolver):
    """:class:`veil.maps.solve._PixelSolver` for ``channels`` channels of ``q`` scales each
    and ``d`` shared axes: the data of a pixel are its channels' values one after the other
    (C * M), its parameters every channel's scales, then the axes. The Jacobian is kept
    compact, (C * M, q + d): each row's derivatives by its own channel's scales and by the
    axes (the others are 0); the normal matrix is assembled from each channel's blocks."""

    def __init__(
        self, channels: int, q: int, d: int, sizes: tuple, weighted: bool, near: bool = False
    ) -> None:
        super().__init__(channels * q, d, sizes, weighted, near)
        self.channels, self.per = channels, q

    def combine(self, b, db, s):
        """(value (C * M,), compact Jacobian (C * M, q + d)) from the basis ``b`` (C, M,
        q + 1) and its derivatives ``db`` (d, C, M, q + 1) at scales ``s`` (C * q,)."""
        c, q = self.channels, self.per
        sc = s.reshape(c, q)
        val = (jnp.einsum("cmk,ck->cm", b[..., :q], sc) + b[..., q]).reshape(-1)
        jac_u = jnp.einsum("acmk,ck->cma", db[..., :q], sc) + jnp.moveaxis(db[..., q], 0, -1)
        return val, jnp.concatenate([b[..., :q], jac_u], axis=-1).reshape(-1, q + self.d)

    def normal(self, jac, w, r):
        """(J^T J, J^T r) over every parameter from the compact Jacobian: each channel's
        block of its scales, their cross terms with the axes, the axes' sum over channels."""
        c, q = self.channels, self.per
        jw = (jac * w[:, None]).reshape(c, -1, q + self.d)
        blocks = jnp.einsum("cmi,cmj->cij", jw, jw)
        gv = jnp.einsum("cmi,cm->ci", jw, r.reshape(c, -1))
        a = jnp.zeros((self.n, self.n))
        for k in range(c):
            own = slice(k * q, (k + 1) * q)
            a = a.at[own, own].set(blocks[k, :q, :q])
            a = a.at[own, c * q :].set(blocks[k, :q, q:])
            a = a.at[c * q :, own].set(blocks[k, q:, :q])
        a = a.at[c * q :, c * q :].set(blocks[:, q:, q:].sum(0))
        return a, jnp.concatenate([gv[:, :q].reshape(-1), gv[:, q:].sum(0)])

    def covariance(self, jac, w, r):
        """(covariance, full rank, J^T r) from the assembled normal matrix
        (:func:`veil.fitting.least_squares.normal_covariance`)."""
        a, g = self.normal(jac, w, r)
        cov, full = lsq.normal_covariance(a, jnp.all(jnp.isfinite(jac * w[:, None])), jnp)
        return cov, full, g

    def refit(self, coef, fu, y, w, p):
        """(p with each channel's scales replaced by their non-negative least-squares
        optimum at its nonlinear parameters, value, Jacobian): the channels' scales are
        independent given theta (module docstring)."""
        c, q = self.channels, self.per
        u = p[self.q :]
        b, db = self.interp(coef, fu, u)
        wc = w.reshape(c, -1)
        bw = b[..., :q] * wc[..., None]
        rw = (y.reshape(c, -1) - b[..., q]) * wc
        gram = jnp.einsum("cmi,cmj->cij", bw, bw)
        rhs = jnp.einsum("cmi,cm->ci", bw, rw)
        s, _ = lsq.nnls_small(gram, rhs, jnp.sum(rw * rw, axis=1), q, jnp)
        s = s.reshape(-1)
        val, jac = self.combine(b, db, s)
        return jnp.concatenate([s, u]), val, jac

    def node_stage(self, values, y, w2):
        """Distant tables, every node: each channel's scales by exact NNLS
        (:func:`veil.maps.solve.node_scales`, the one-channel stage), the node of the least
        total cost, for a batch of pixels (P, C * M): (s0 (P, C * q), u0 (P, d))."""
        return self.nodes_stage(values.reshape((-1,) + values.shape[self.d :]), y, w2)

    def best_node(self, nodes, y, w2):
        """Near-field tables, one pixel (C * M,) at the nodes (N, C, M, q + 1) of its
        nearest field node: :meth:`nodes_stage` of that one pixel, (s0 (C * q,), u0 (d,))."""
        s0, u0 = self.nodes_stage(nodes, y[None], w2[None])
        return s0[0], u0[0]

    def nodes_stage(self, nodes, y, w2):
        """The best node of ``nodes`` (N, C, M, q + 1) for a batch of pixels (P, C * M):
        (s0 (P, C * q), u0 (P, d))."""
        c, q, d = self.channels, self.per, self.d
        nodes = jnp.moveaxis(nodes, 1, 0)  # (C, N, M, q+1)
        m = nodes.shape[2]
        yc = jnp.moveaxis(y.reshape(-1, c, m), 1, 0)
        wc = jnp.moveaxis(w2.reshape(-1, c, m), 1, 0)
        scales, total = [], 0.0
        for k in range(c):
            s_all, cost = node_scales(nodes[k], yc[k], wc[k], q)
            scales.append(s_all)
            total = total + cost
        best = jnp.argmin(total, axis=1)
        s0 = jnp.concatenate(
            [jnp.take_along_axis(s, best[:, None, None], axis=1)[:, 0, :] for s in scales], axis=1
        )
        u0 = (
            jnp.stack(jnp.unravel_index(best, self.sizes), axis=1).astype(float)
            if d
            else jnp.zeros((y.shape[0], 0))
        )
        return s0, u0


def channel_solver(tables: MapTables, weighted: bool) -> tuple:
    """(the first and rest functions of :func:`veil.maps.solve.compiled`, the number of
    parameters) of the solve of ``tables`` over their channels, made once per shape."""
    c, q, d = len(tables.channels), len(tables.free_scales), len(tables.axes)
    sizes = tuple(a.count for a in tables.axes)
    near = tables.near is not None
    key = ("channels", c, q, d, sizes, weighted) + (("near",) if near else ())
    if key not in _SOLVERS:
        _SOLVERS[key] = compiled(_ChannelSolver(c, q, d, sizes, weighted, near))
    return _SOLVERS[key] + (c * q + d,)


def warm_up_channels(tables: MapTables, noise=None) -> None:
    """:func:`veil.maps.solve.warm_up` of the solve over channels."""
    warm_up(tables, noise, channel_solver(tables, noise is not None))


@dataclass(frozen=True)
class ChannelFits:
    """Per-pixel results of a map over channels (flat arrays over N pixels): ``params``
    (S, N) and ``stderr`` of the parameters shared across the channels (``shared``: their
    indices in the family), ``channel_params`` (Q, C, N) and ``channel_stderr`` of those
    per channel (``per_channel``), and as :class:`veil.maps.solve.PixelFits` ``chi2``,
    ``n_points`` (usable samples of every channel), ``status``, ``iterations``."""

    shared: tuple
    per_channel: tuple
    params: np.ndarray
    stderr: np.ndarray
    channel_params: np.ndarray
    channel_stderr: np.ndarray
    chi2: np.ndarray
    n_points: np.ndarray
    status: np.ndarray
    iterations: np.ndarray


def solve_channel_pixels(
    tables: MapTables, y, valid, noise=None, pixels=None, basis=None
) -> ChannelFits:
    """Fit every pixel in every channel at once: ``y`` (N, C, M) values in the tables'
    channels, ``valid`` (N, C, M) usable samples, ``noise``, ``basis`` (N, C, M) and, for
    near-field tables, ``pixels`` (each pixel's position in the full photo) as
    :func:`veil.maps.solve.solve_pixels`'."""
    if not tables.channels:
        raise FitError("tables of one channel: use veil.maps.solve.solve_pixels")
    y = np.asarray(y, dtype=float)
    c = len(tables.channels)
    if y.ndim != 3 or y.shape[1] != c:
        raise FitError(
            f"values of shape {y.shape}: expected (pixels, {c} channels, configurations)"
        )
    n_pix = y.shape[0]
    fu = pixel_coords(tables, pixels, n_pix)
    flat_y, flat_valid, w2 = weights(
        tables,
        y.reshape(n_pix * c, -1),
        np.asarray(valid).reshape(n_pix * c, -1),
        noise,
        None if basis is None else np.reshape(basis, (n_pix * c, -1)),
    )
    flat_y, flat_valid, w2 = (a.reshape(n_pix, -1) for a in (flat_y, flat_valid, w2))
    out = _run(tables, flat_y, w2, fu, noise is not None, channel_solver(tables, noise is not None))
    q = c * len(tables.free_scales)
    status = _status(tables, out, flat_y, flat_valid, q)
    return _physical_channels(tables, out, status)


def _physical_channels(tables: MapTables, out: dict, status) -> ChannelFits:
    """The pixels' results in physical parameters, shared and per channel (standard errors
    where converged)."""
    c, q = len(tables.channels), len(tables.free_scales)
    n_pix = len(status)
    sharing = _sharing(tables)
    params = np.repeat(tables.base[:, None, None], c, axis=1).repeat(n_pix, axis=2)
    stderr = np.zeros((len(tables.names), c, n_pix))
    for k, i in enumerate(tables.free_scales):
        for ch in range(c):
            params[i, ch] = out["p"][:, ch * q + k]
            stderr[i, ch] = out["se"][:, ch * q + k]
    for k, a in enumerate(tables.axes):
        phys = a.physical(out["p"][:, c * q + k])
        params[a.index] = phys
        stderr[a.index] = a.physical_stderr(out["se"][:, c * q + k], phys)
    good = np.all(np.isfinite(params), axis=(0, 1)) & np.all(np.isfinite(stderr), axis=(0, 1))
    params = np.where(good, params, tables.base[:, None, None])
    stderr = np.where(good & (status == CONVERGED), stderr, 0.0)
    chi2 = np.where(
        np.isfinite(out["chi2"]) & (status != MASKED) & (status != FEW_POINTS), out["chi2"], 0.0
    )
    shared = tuple(i for i, s in enumerate(sharing) if s == "shared")
    per = tuple(i for i, s in enumerate(sharing) if s != "shared")
    return ChannelFits(
        shared,
        per,
        params[list(shared), 0],
        stderr[list(shared), 0],
        params[list(per)],
        stderr[list(per)],
        chi2,
        out["npts"].astype(np.int32),
        status,
        out["iters"],
    )


def _sharing(tables: MapTables) -> list[str]:
    """ "shared" or "per-channel" of each parameter of the tables' family, in its order."""
    from ..models import model_class

    sharing = model_class(tables.model, "brdf").channel_sharing()
    return [sharing[n] for n in tables.names]


__all__ = ["ChannelFits", "channel_solver", "solve_channel_pixels", "warm_up_channels"]
