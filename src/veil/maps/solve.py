"""Per-pixel step 2 (docs/maps.md): the target's BRDF at every pixel of a photo stack,
through a fixed medium, at fixed configurations.

For a fixed medium and fixed configurations the apparent value (docs/model.md eq. 1) is linear
in the BRDF's scale parameters (``SCALES``): with the engine's term matrices
(:meth:`veil.engine.evaluator.ApparentModel.terms`, rows combined with the medium's row
weights, :func:`veil.engine.integrator.row_scales`) it is

    f(theta, s) = sum_k s_k B_k(theta) + C(theta)

with B_k the columns of the parts whose scale is free and C the parts whose weight is known
(a fixed scale, or a part without a scale). :class:`veil.maps.tables.MapTables` tabulates B
and C over a regular grid of the free nonlinear parameters theta (in their fit coordinates:
logarithms for ``log_scale`` parameters) once per acquisition, and keeps the tensor-product
cubic B-spline that interpolates them (not-a-knot ends, C2, exact derivatives).
:func:`solve_pixels` then fits every pixel against the tables, vectorized in JAX:

1. at every grid node the scales by exact non-negative least squares (closed form for up to
   two scales: every active set is tried);
2. the best node;
3. Levenberg-Marquardt in (scales, theta) on the B-spline, a fixed number of iterations,
   then an undamped Gauss-Newton step whose size, in standard errors, decides convergence.

Every pixel gets its parameters, standard errors, reduced chi-square, number of points and
a status (:data:`STATUS`); a pixel is reported converged only when the final step is below
:data:`STEP_TOL` standard errors, no scale is at zero, the Jacobian has full rank and no
nonlinear parameter sits at the edge of the table.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from .._jax import jax, jnp
from ..errors import FitError
from ..fitting import least_squares as lsq
from .grid import interp, interp_near
from .status import CONVERGED, EDGE, FEW_POINTS, MASKED, NOT_CONVERGED, STATUS, UNDETERMINED
from .tables import MapTables

#: Convergence: the last undamped step, in standard errors, below this in every parameter
#: (the full fit's own tolerance leaves it within about 1 % of a standard error).
STEP_TOL = 1e-2
#: Levenberg-Marquardt iterations from the best node, at most: a pixel stops (its state
#: frozen) once its Gauss-Newton step over the parameters not held at a bound is below
#: :data:`LM_TOL` standard errors, and a batch once all its pixels have stopped.
ITERATIONS = 20
#: Iterations in a batch's first call: the pixels still running then (a few per cent) are
#: gathered from all batches of the call into full batches of their own for the rest, so
#: that a few slow pixels do not hold up the whole batch.
FIRST_ITERATIONS = 4
#: Stopping tolerance of the iterations, in standard errors (half of :data:`STEP_TOL`, so
#: that a stopped pixel passes the final convergence test).
LM_TOL = 5e-3
#: Pixels per solver call: every call has this shape, so results do not depend on how
#: pixels are grouped into tiles or workers (bit for bit).
BATCH = 512
#: Batches dispatched to a device and not yet collected, at most.
IN_FLIGHT = 2
#: Near-field tables: pixels whose node values the node stage holds at once (a divisor of
#: BATCH; their node values are NEAR_GROUP x nodes x configurations x columns).
NEAR_GROUP = 32

_SOLVERS: dict = {}
#: One solver call at a time per process: concurrent first calls of a jitted function from
#: several threads (dask's threaded scheduler) were seen to deadlock, and XLA already uses
#: every core inside one call.
_CALL_LOCK = threading.Lock()


class _PixelSolver:
    """The per-pixel solve for q scales and d axes of ``sizes`` nodes (``weighted``: data
    with noise weights; ``near``: tables with two field axes first, each pixel at its own
    field coordinates, docs/maps.md "Geometry"). Its functions are of one pixel (or a batch:
    :meth:`start` and :meth:`resume`, which :func:`compiled` compiles). The step and the
    rules - damping, bounds, stopping, covariance and rank - are those of
    :mod:`veil.fitting.least_squares` (:func:`~veil.fitting.least_squares.lm_step`, the
    single fits' step too)."""

    def __init__(self, q: int, d: int, sizes: tuple, weighted: bool, near: bool) -> None:
        self.q, self.d, self.sizes, self.weighted, self.near = q, d, sizes, weighted, near
        self.n = q + d
        self.top = jnp.asarray([float(k - 1) for k in sizes])
        self.lo = jnp.zeros(self.n)
        self.hi = jnp.concatenate([jnp.full(q, jnp.inf), self.top]) if d else jnp.full(q, jnp.inf)
        self.span = self.hi - self.lo  # each parameter's range (a scale's unbounded)

    def interp(self, coef, fu, u):
        if self.near:
            return interp_near(coef, fu, u, self.d)
        return interp(coef, u, self.d)

    def columns(self, coef, fu, s, u):
        """(value, Jacobian) at scales ``s`` and grid coordinates ``u``."""
        return self.combine(*self.interp(coef, fu, u), s)

    def combine(self, b, db, s):
        """(value, Jacobian) from the basis ``b`` and its derivatives ``db`` at scales ``s``."""
        q = self.q
        val = b[:, :q] @ s + b[:, q]
        jac_u = (
            jnp.einsum("amk,k->ma", db[..., :q], s) + db[..., q].T
            if self.d
            else jnp.zeros((b.shape[0], 0))
        )
        return val, jnp.concatenate([b[:, :q], jac_u], axis=1)

    def initial(self, coef, fu, u0, s0, y, w2):
        """The iterations' state at the best node: (iterations, p, lambda, cost, value,
        Jacobian, stopped)."""
        p0 = jnp.concatenate([s0, u0])
        v0, j0 = self.columns(coef, fu, s0, u0)
        r0 = (y - v0) * jnp.sqrt(w2)
        # typed (not weak) scalars: the state a batch returns is then the state the
        # gathered slow pixels come back with (numpy), and one resume program serves both
        return (
            jnp.asarray(0, dtype=jnp.int64),
            p0,
            jnp.asarray(lsq.DAMPING_START, dtype=jnp.float64),
            r0 @ r0,
            v0,
            j0,
            jnp.asarray(False, dtype=bool),
        )

    def refit(self, coef, fu, y, w, p):
        """(p with its scales replaced by their non-negative least-squares optimum at its
        nonlinear parameters, value, Jacobian): the model is linear in the scales, so every
        trial point of the iterations lies on the valley floor s*(theta) (variable
        projection), where a curved valley between a scale and a roughness would otherwise
        make the steps creep."""
        q, u = self.q, p[self.q :]
        b, db = self.interp(coef, fu, u)
        bw = b[:, :q] * w[:, None]
        rw = (y - b[:, q]) * w
        s, _ = lsq.nnls_small(bw.T @ bw, bw.T @ rw, rw @ rw, q, jnp)
        val, jac = self.combine(b, db, s)
        return jnp.concatenate([s, u]), val, jac

    def iterate(self, coef, fu, y, w, state):
        """One Levenberg-Marquardt iteration of a pixel (one evaluation of the spline), by
        :func:`veil.fitting.least_squares.lm_step` and ``lm_accept`` (the damping by the
        gain, the actual decrease over the predicted one, as the single fits'); a pixel whose
        reduced Gauss-Newton step is below LM_TOL standard errors is frozen."""
        it, p, lam, cost, val, jac, _ = state
        r = (y - val) * w
        a, g = self.normal(jac, w, r)
        variance = 1.0 if self.weighted else cost / self.dof(w)
        a, g = self.without_silent_axes(a, g, variance)
        proposed, dec = lsq.lm_step(p, a, g, lam, self.lo, self.hi, jnp)
        now = lsq.stopped(dec, LM_TOL, variance, (y * w) @ (y * w), jnp)
        trial, tval, tjac = self.refit(coef, fu, y, w, proposed)
        tr = (y - tval) * w
        tcost = tr @ tr
        step = proposed - p  # its decrease as the linear model predicts it: the damping's gain
        better, lam = lsq.lm_accept(cost, tcost, lam, now, jnp, 2 * g @ step - step @ a @ step)
        return (
            it + jnp.where(now, 0, 1),
            jnp.where(better, trial, p),
            lam,
            jnp.where(better, tcost, cost),
            jnp.where(better, tval, val),
            jnp.where(better, tjac, jac),
            now,
        )

    def without_silent_axes(self, a, g, variance):
        """(a, g) with the axes that cannot move the model by LM_TOL standard errors over
        their whole tabulated range (at the pixel's scales: a lobe of zero height has no
        width) held as a bound holds a parameter: no step, no part of the stopping rule's
        decrease. Their columns are rounding noise; its ratio to itself would otherwise
        predict a decrease that no step finds, and the pixel would spend every iteration
        there."""
        if not self.d:
            return a, g
        silent = jnp.diag(a) * self.span**2 < LM_TOL**2 * variance
        pair = silent[:, None] | silent[None, :]
        return jnp.where(pair, jnp.eye(self.n), a), jnp.where(silent, 0.0, g)

    def normal(self, jac, w, r):
        """(J^T J, J^T r) of the weighted Jacobian ``jac`` times ``w`` and residuals ``r``."""
        jw = jac * w[:, None]
        return jw.T @ jw, jw.T @ r

    def covariance(self, jac, w, r):
        """(covariance, full rank, J^T r) of the weighted Jacobian
        (:func:`veil.fitting.least_squares.covariance`)."""
        jw = jac * w[:, None]
        cov, rank_ok = lsq.covariance(jw, jnp)
        return cov, rank_ok, jw.T @ r

    def dof(self, w):
        return jnp.maximum(jnp.sum(w > 0) - self.n, 1)

    def one_pixel(self, coef, fu, y, w2, state, limit):
        """Iterations from ``state`` until the pixel stops or has had ``limit``, then its
        statistics: (results, state)."""
        w = jnp.sqrt(w2)
        # under vmap the loop runs while any pixel of the batch runs; a frozen pixel's
        # state is selected unchanged (and the body leaves it unchanged too)
        state = jax.lax.while_loop(
            lambda st: (st[0] < limit) & ~st[-1], lambda st: self.iterate(coef, fu, y, w, st), state
        )
        iters, p, _, _, val, jac, _ = state
        r = (y - val) * w
        cov, rank_ok, jtr = self.covariance(jac, w, r)
        chi2 = lsq.residual_variance(r, jnp.sum(w2 > 0) - self.n, jnp)
        if not self.weighted:
            cov = cov * chi2
        se = jnp.sqrt(jnp.maximum(jnp.diag(cov), 0.0))
        # the undamped Gauss-Newton step from the solution, in standard errors
        gn = cov @ jtr
        if not self.weighted:
            gn = gn / jnp.where(chi2 > 0, chi2, 1.0)
        proj = lsq.project(p + gn, self.lo, self.hi, jnp) - p
        step_se = lsq.step_in_stderr(proj, se, jnp)
        return (p, se, chi2, jnp.sum(w2 > 0), rank_ok, step_se, iters), state

    def best_node(self, nodes, y, w2):
        """The scales by exact NNLS at every node (N, M, q + 1) of one pixel, the best node:
        (s0, u0)."""
        q = self.q
        bq, c = nodes[..., :q], nodes[..., q]
        wy = w2 * y
        gram = jnp.einsum("nmi,m,nmj->nij", bq, w2, bq)
        rhs = jnp.einsum("nmi,m->ni", bq, wy) - jnp.einsum("nmi,nm->ni", bq, w2 * c)
        yy = wy @ y - 2 * c @ wy + (c * c) @ w2
        s_all, cost = lsq.nnls_small(gram, rhs, yy, q, jnp)
        best = jnp.argmin(cost)
        u0 = (
            jnp.stack(jnp.unravel_index(best, self.sizes)).astype(float)
            if self.d
            else jnp.zeros((0,))
        )
        return s_all[best], u0

    def node_stage(self, values, y, w2):
        """Distant tables: the scales by exact NNLS at every node, the best node, for a
        batch of pixels as matrix products over the configurations: (s0, u0)."""
        q, d = self.q, self.d
        nodes = values.reshape((-1,) + values.shape[d:])  # (N, M, q + 1)
        s_all, cost = node_scales(nodes, y, w2, q)
        best = jnp.argmin(cost, axis=1)
        s0 = jnp.take_along_axis(s_all, best[:, None, None], axis=1)[:, 0, :]
        if d:
            u0 = jnp.stack(jnp.unravel_index(best, self.sizes), axis=1).astype(float)
        else:
            u0 = jnp.zeros((y.shape[0], 0))
        return s0, u0

    def near_nodes(self, values, fu, y, w2):
        """Near-field tables, one pixel: the best node of the nearest field node's columns -
        a starting point; the iterations then use the pixel's own interpolated columns."""
        ix = jnp.clip(jnp.round(fu[0]), 0, values.shape[0] - 1).astype(jnp.int64)
        iy = jnp.clip(jnp.round(fu[1]), 0, values.shape[1] - 1).astype(jnp.int64)
        nodes = values[ix, iy]
        return self.best_node(nodes.reshape((-1,) + nodes.shape[self.d :]), y, w2)

    def start(self, values, coef, y, w2, fu=None):
        """1. every node: the scales by exact NNLS; 2. the best node: the iterations' state
        there, for a batch of pixels."""
        if self.near:  # per pixel, NEAR_GROUP pixels at a time (memory: their node values)

            def group(a):
                return a.reshape((-1, NEAR_GROUP) + a.shape[1:])

            s0, u0 = jax.lax.map(
                lambda args: jax.vmap(self.near_nodes, in_axes=(None, 0, 0, 0))(values, *args),
                (group(fu), group(y), group(w2)),
            )
            s0, u0 = (a.reshape((y.shape[0],) + a.shape[2:]) for a in (s0, u0))
        else:
            s0, u0 = self.node_stage(values, y, w2)
            fu = jnp.zeros((y.shape[0], 0))
        return jax.vmap(self.initial, in_axes=(None, 0, 0, 0, 0, 0))(coef, fu, u0, s0, y, w2)

    def resume(self, coef, y, w2, state, limit, fu=None):
        """Levenberg-Marquardt on the spline from ``state`` until each pixel stops or has
        had ``limit`` iterations (a number the program takes, not part of it), then the
        statistics: (results, state)."""
        if fu is None:
            fu = jnp.zeros((y.shape[0], 0))
        return jax.vmap(self.one_pixel, in_axes=(None, 0, 0, 0, 0, None))(
            coef, fu, y, w2, state, limit
        )

    def batch(self, values, coef, y, w2, fu=None):
        """:meth:`start`, then FIRST_ITERATIONS at most of :meth:`resume` (as one function;
        :func:`compiled` runs them as two programs)."""
        state = self.start(values, coef, y, w2, fu)
        return self.resume(coef, y, w2, state, min(FIRST_ITERATIONS, ITERATIONS), fu)


def compiled(solver) -> tuple:
    """(first, rest) of a solver: ``first(values, coef, y, w2, *fu)`` a batch's start and
    its first iterations, ``rest(coef, y, w2, state, *fu)`` the gathered slow pixels' other
    iterations. Two programs: the start and the iterations, whose limit is an input, so the
    first iterations and the rest are one program (compiled once, not twice)."""
    start, iterations = jax.jit(solver.start), jax.jit(solver.resume)
    first_limit = np.int64(min(FIRST_ITERATIONS, ITERATIONS))

    def first(values, coef, y, w2, *fu):
        return iterations(coef, y, w2, start(values, coef, y, w2, *fu), first_limit, *fu)

    def rest(coef, y, w2, state, *fu):
        return iterations(coef, y, w2, state, np.int64(ITERATIONS), *fu)

    return first, rest


def node_scales(nodes, y, w2, q: int) -> tuple:
    """The scales by exact NNLS at every node (N, M, q + 1) for a batch of pixels ``y``
    (P, M) with weights ``w2``, as matrix products over the configurations: (scales (P, N,
    q), costs (P, N))."""
    n_nodes, m = nodes.shape[0], nodes.shape[1]
    bq, c = nodes[..., :q], nodes[..., q]
    # (P, M) @ (M, ...)
    prods = jnp.einsum("nmi,nmj->mnij", bq, bq).reshape(m, -1)
    gram = (w2 @ prods).reshape(-1, n_nodes, q, q)
    wy = w2 * y
    vb = jnp.transpose(bq, (1, 0, 2)).reshape(m, -1)
    vc = jnp.transpose(bq * c[..., None], (1, 0, 2)).reshape(m, -1)
    rhs = (wy @ vb - w2 @ vc).reshape(-1, n_nodes, q)
    yy = (wy * y).sum(-1)[:, None] - 2 * wy @ c.T + w2 @ (c * c).T
    return lsq.nnls_small(gram, rhs, yy, q, jnp)


def _solver(q: int, d: int, sizes: tuple, weighted: bool, near: bool = False):
    """The (first, rest) pair of :class:`_PixelSolver` (:func:`compiled`), made once per
    shape."""
    key = (q, d, sizes, weighted) + ((True,) if near else ())
    if key not in _SOLVERS:
        _SOLVERS[key] = compiled(_PixelSolver(q, d, sizes, weighted, near))
    return _SOLVERS[key]


def _dispatch(tables, count, call, done):
    """``count`` items in batches of BATCH (the last padded by repeating its last item):
    ``call(indices, device, (values, coef) on the device)`` for each batch, round the CPU
    devices (one core each, veil._jax) without waiting, at most IN_FLIGHT per device
    pending; ``done(start, stop, result)`` in order. Every batch is the same computation
    on BATCH items whichever device runs it."""
    devices = jax.devices()
    on_device = {}
    pending = []
    for b, start in enumerate(range(0, count, BATCH)):
        stop = min(start + BATCH, count)
        idx = np.minimum(np.arange(start, start + BATCH), stop - 1)
        dev = devices[b % len(devices)]
        if dev not in on_device:
            on_device[dev] = tuple(jax.device_put(a, dev) for a in tables.solver_arrays)
        pending.append((start, stop, call(idx, dev, on_device[dev])))
        if len(pending) >= IN_FLIGHT * len(devices):
            done(*pending.pop(0))
    while pending:
        done(*pending.pop(0))


def warm_up(tables: MapTables, noise=None, solver=None) -> None:
    """Compile both parts of the solver of ``tables`` on every CPU device (on dark pixels,
    which stop at once), so that no later call waits for a compilation (``solver``: as
    :func:`_run`'s)."""
    near = tables.near is not None
    first, rest = (
        _solver(
            len(tables.free_scales),
            len(tables.axes),
            tuple(a.count for a in tables.axes),
            noise is not None,
            near,
        )
        if solver is None
        else solver[:2]
    )
    y = np.zeros((BATCH, tables.n_configs * (len(tables.channels) or 1)))
    extra = (np.zeros((BATCH, 2)),) if near else ()
    with _CALL_LOCK:
        for dev in jax.devices():
            values, coef = (jax.device_put(a, dev) for a in tables.solver_arrays)
            y_dev, w2_dev = jax.device_put(y, dev), jax.device_put(np.ones_like(y), dev)
            fu = tuple(jax.device_put(a, dev) for a in extra)
            _, state = first(values, coef, y_dev, w2_dev, *fu)
            jax.block_until_ready(rest(coef, y_dev, w2_dev, state, *fu))


@dataclass
class PixelFits:
    """Per-pixel results (flat arrays over pixels): ``params`` (P, N) every BRDF parameter,
    ``stderr`` (P, N) (0 where fixed or not reported), ``chi2`` (N,), ``n_points`` (N,),
    ``status`` (N,) uint8 (:data:`STATUS`), ``iterations`` (N,) Levenberg-Marquardt
    iterations the pixel took (at most :data:`ITERATIONS`)."""

    params: np.ndarray
    stderr: np.ndarray
    chi2: np.ndarray
    n_points: np.ndarray
    status: np.ndarray
    iterations: np.ndarray


def solve_pixels(
    tables: MapTables, y: np.ndarray, valid: np.ndarray, noise=None, pixels=None, basis=None
) -> PixelFits:
    """Fit every pixel: ``y`` (N, M) values, ``valid`` (N, M) usable samples (saturated,
    clipped and masked ones False), ``noise`` None (unweighted) or (relative, absolute):
    sigma = sqrt((relative * value)^2 + absolute^2), the value ``basis``'s (N, M) where
    given (the model's at a first solution, :func:`weights`), else the sample's.
    Near-field tables need ``pixels`` (x (N,), y (N,)): each pixel's position in the full
    photo."""
    fu = pixel_coords(tables, pixels, len(y))
    y, valid, w2 = weights(tables, y, valid, noise, basis)
    out = _run(tables, y, w2, fu, noise is not None)
    status = _status(tables, out, y, valid)
    return _physical(tables, out, status)


def pixel_coords(tables: MapTables, pixels, count: int) -> np.ndarray | None:
    """The field-grid coordinates (N, 2) of ``pixels`` (x (N,), y (N,)) of the full photo
    for near-field tables (a FitError without them, or with another number than ``count``);
    None for distant tables."""
    if tables.near is None:
        return None
    if pixels is None:
        raise FitError("near-field tables: give each pixel's position (pixels=(x, y))")
    fu = tables.field_coords(*pixels)
    if len(fu) != count:
        raise FitError(f"{len(fu)} pixel positions for {count} pixels")
    return fu


def has_relative_noise(noise) -> bool:
    """Whether a noise model (None or (relative, absolute)) has a relative part: then a map
    solves its pixels twice, the second time with the noise of the model's values
    (docs/maps-noise.md)."""
    return noise is not None and noise[0] > 0


def weights(tables: MapTables, y, valid, noise, basis=None) -> tuple:
    """(values, usable samples, squared weights) of pixels ``y`` (N, M): unusable samples
    (not ``valid`` or not finite) at 0 with weight 0; ``noise`` as :func:`solve_pixels`',
    its relative part of ``basis`` (N, M) where given. Of the samples themselves, the
    weights favour the samples that noise pulled low, and a scale comes out low by about
    twice the relative variance (2 % at 10 % noise); of the model's values at a first
    solution, whose error moves every weight by one factor, they are unbiased
    (docs/maps-noise.md)."""
    y = np.asarray(y, dtype=float)
    valid = np.asarray(valid, dtype=bool) & np.isfinite(y)
    if y.shape[1] != tables.n_configs:
        raise FitError(
            f"{y.shape[1]} values per pixel but the tables have {tables.n_configs} configurations"
        )
    y = np.where(valid, y, 0.0)
    if noise is None:
        w2 = valid.astype(float)
    else:
        rel, ab = noise
        of = y if basis is None else np.asarray(basis, dtype=float).reshape(y.shape)
        sigma2 = (rel * of) ** 2 + ab**2
        w2 = np.where(valid & (sigma2 > 0), 1.0 / np.where(sigma2 > 0, sigma2, 1.0), 0.0)
    return y, valid, w2


def _run(tables: MapTables, y, w2, fu, weighted: bool, solver=None) -> dict:
    """The solver's outputs for every pixel: p, se, chi2, npts, rank_ok, step, iters (flat
    arrays over pixels). Pixels still running after FIRST_ITERATIONS are gathered from
    every batch into full batches of their own for the rest. ``solver``: (first, rest,
    parameters) of another solver than the tables' one-channel one (maps over channels)."""
    if solver is None:
        q, d = len(tables.free_scales), len(tables.axes)
        sizes = tuple(a.count for a in tables.axes)
        solver = _solver(q, d, sizes, weighted, fu is not None) + (q + d,)
    first, rest, n = solver
    n_pix = len(y)
    out = {
        "p": np.zeros((n_pix, n)),
        "se": np.zeros((n_pix, n)),
        "chi2": np.zeros(n_pix),
        "npts": np.zeros(n_pix, dtype=np.int64),
        "rank_ok": np.zeros(n_pix, dtype=bool),
        "step": np.zeros(n_pix),
        "iters": np.zeros(n_pix, dtype=np.int32),
    }
    slow_pixels, slow_states = [], []

    def store(where, outs):
        for name, value in zip(out, outs):
            out[name][where] = value

    def first_done(start, stop, result):
        outs, state = result
        k = stop - start
        store(slice(start, stop), [np.asarray(a)[:k] for a in outs])
        state = [np.asarray(a)[:k] for a in state]
        slow = ~state[-1] & (state[0] >= FIRST_ITERATIONS)
        if slow.any():
            slow_pixels.append(np.arange(start, stop)[slow])
            slow_states.append([a[slow] for a in state])

    def put(dev, *arrays):
        return tuple(jax.device_put(a, dev) for a in arrays)

    def at(idx, dev):  # near field: the pixels' field coordinates (none otherwise)
        return put(dev, fu[idx]) if fu is not None else ()

    with _CALL_LOCK:
        _dispatch(
            tables,
            n_pix,
            lambda idx, dev, tab: first(*tab, *put(dev, y[idx], w2[idx]), *at(idx, dev)),
            first_done,
        )
        if slow_pixels:  # the rest of the iterations for the slow pixels of every batch
            where = np.concatenate(slow_pixels)
            states = [np.concatenate(parts) for parts in zip(*slow_states)]
            _dispatch(
                tables,
                len(where),
                lambda idx, dev, tab: rest(
                    tab[1],
                    *put(dev, y[where[idx]], w2[where[idx]]),
                    put(dev, *[a[idx] for a in states]),
                    *at(where[idx], dev),
                ),
                lambda start, stop, result: store(
                    where[start:stop], [np.asarray(a)[: stop - start] for a in result[0]]
                ),
            )
    return out


def _status(tables: MapTables, out: dict, y, valid, q: int | None = None) -> np.ndarray:
    """Each pixel's status (:data:`STATUS`), the worst that applies (``q``: the number of
    free scales, by default the tables')."""
    q = len(tables.free_scales) if q is None else q
    d = len(tables.axes)
    n_pix = len(y)
    status = np.full(n_pix, CONVERGED, dtype=np.uint8)
    status[out["step"] > STEP_TOL] = NOT_CONVERGED
    if d:
        top = np.array([a.count - 1 for a in tables.axes], dtype=float)
        low, high = lsq.at_bounds(out["p"][:, q:], 0.0, top, 1e-9)
        status[np.any(low | high, axis=1)] = EDGE
    signal = np.any((y > 0) & valid, axis=1)
    scale_zero = np.any(out["p"][:, :q] <= 0, axis=1) if q else np.zeros(n_pix, bool)
    status[~out["rank_ok"] | scale_zero | ~signal] = UNDETERMINED
    status[out["npts"] <= q + d] = FEW_POINTS
    status[~valid.any(axis=1)] = MASKED
    bad = (
        ~np.all(np.isfinite(out["p"]), axis=1)
        | ~np.all(np.isfinite(out["se"]), axis=1)
        | ~np.isfinite(out["chi2"])
    )
    status[bad & (status == CONVERGED)] = UNDETERMINED
    return status


def _physical(tables: MapTables, out: dict, status) -> PixelFits:
    """The pixels' results in physical parameters (standard errors where converged)."""
    q = len(tables.free_scales)
    n_pix = len(status)
    params = np.repeat(tables.base[:, None], n_pix, axis=1)
    stderr = np.zeros((len(tables.names), n_pix))
    for c, i in enumerate(tables.free_scales):
        params[i] = out["p"][:, c]
        stderr[i] = out["se"][:, c]
    for c, a in enumerate(tables.axes):
        phys = a.physical(out["p"][:, q + c])
        params[a.index] = phys
        stderr[a.index] = a.physical_stderr(out["se"][:, q + c], phys)
    reported = status == CONVERGED
    good_numbers = np.all(np.isfinite(params), axis=0) & np.all(np.isfinite(stderr), axis=0)
    params = np.where(good_numbers[None, :], params, tables.base[:, None])
    stderr = np.where((reported & good_numbers)[None, :], stderr, 0.0)
    chi2 = np.where(
        np.isfinite(out["chi2"]) & (status != MASKED) & (status != FEW_POINTS), out["chi2"], 0.0
    )
    return PixelFits(params, stderr, chi2, out["npts"].astype(np.int32), status, out["iters"])


__all__ = [
    "STATUS",
    "CONVERGED",
    "MASKED",
    "FEW_POINTS",
    "UNDETERMINED",
    "EDGE",
    "NOT_CONVERGED",
    "solve_pixels",
    "node_scales",
    "weights",
    "has_relative_noise",
    "pixel_coords",
    "warm_up",
    "PixelFits",
]
