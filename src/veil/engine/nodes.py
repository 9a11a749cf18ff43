"""The integrator's nodes: direction grids with known densities, the small vector algebra
they are built with, and the models evaluated at several node sets.

Several terms of the integrator (:mod:`veil.engine.integrator`, docs/model.md sec. 5) need
the BRDF's lobe and separable part, or the phase law, at their own nodes. :func:`lobe_at`,
:func:`separable_at` and :func:`phase_grids` evaluate the model at each node set where that
set is used, so that XLA fuses the evaluation into the sum that consumes it. Evaluated once at
the concatenation of the node sets, the programs were 15 to 25 % smaller but their Jacobians
ran 1.3 to 2.5 times slower, their values held in memory with a tangent beside each
(docs/design-notes.md). Only the per-call facet grids share one evaluation.
"""

from __future__ import annotations

import math

import numpy as np

from .._jax import jax, jnp
from ..models.base import BRDF, BTDF
from .quadrature import frame, gauss_legendre_unit, horizon_one_minus_mu, periodic_unit

TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi
FACET_GRADING = 3


def azimuths(n: int, half: bool):
    """Midpoint azimuth nodes in [0, 1) and weights; ``half`` keeps (0, 1/2) with double weight."""
    v, w = periodic_unit(n)
    if half:
        keep = v < 0.5
        return v[keep], 2.0 * w[keep]
    return v, w


def phase_grids(medium: BTDF, vm, maux, specs):
    """Directions about each ``center`` (3,) of ``specs`` = [(center, n_r, n_a, half), ...],
    distributed as the phase lobe truncated at z = 0 (:func:`phase_grid` for each)."""
    return [phase_grid(medium, vm, maux, *spec) for spec in specs]


def phase_grid(medium: BTDF, vm, maux, center, n_r: int, n_a: int, half: bool):
    """Directions about ``center`` (3,) distributed as the phase lobe truncated at z = 0:
    (d (N, 3), unit weights (N,), frac_max (N,), p (N,)), where
    sum(unit * frac_max * f(d)) approximates Int_{z>0} p(center . d) f(d) dd and p is the
    phase density at each node. The horizon depends on the azimuth only: one cone fraction
    per azimuth."""
    x, wx = gauss_legendre_unit(n_r)
    v, wv = azimuths(n_a, half)
    frac_az = medium.phase_cone_fraction(
        vm, horizon_one_minus_mu(center[2], jnp.asarray(np.cos(TWO_PI * v))), maux
    )
    frac_max = frac_az[np.repeat(np.arange(len(v)), n_r)]
    u = jnp.asarray(np.repeat(x[None, :], len(v), 0).ravel())
    omm, p = medium.phase_sample(vm, u * frac_max, maux)
    sg = jnp.sqrt(jnp.maximum(omm * (2.0 - omm), 0.0))
    beta = jnp.asarray(TWO_PI * np.repeat(v, n_r))
    t1, t2 = frame(center)
    d = (1.0 - omm)[:, None] * center + sg[:, None] * (
        jnp.cos(beta)[:, None] * t1 + jnp.sin(beta)[:, None] * t2
    )
    return d, jnp.asarray(np.outer(wv, wx).ravel()), frac_max, p


def phase_ratio(p, q):
    """p / q where q > 0, else 0: a channel's phase ``p`` over the sampling law's density
    ``q`` at the law's nodes (docs/channels.md, "Cost")."""
    ok = q > 0
    return jnp.where(ok, p / jnp.where(ok, q, 1.0), 0.0)


def channel_grid(medium: BTDF, vm, maux, center, grid, own: bool = False):
    """A phase grid about ``center`` drawn from a sampling law (``grid``, as
    :func:`phase_grid` returns it) seen by one channel of phase p (``vm``, ``maux``):
    (d, unit, frac_max * p / q, q), so that sum(unit * frac * f(d)) approximates
    Int p(center . d) f(d) dd, and the last entry stays the density the nodes have (the
    balance weights of the multiple-importance terms use it). ``own``: the law is the
    channel's own phase held constant (docs/engine.md "Derivatives"): p / q is 1 and is
    taken as exactly 1, its derivative dp / q kept, so the values are those of the grid
    drawn at ``vm`` (within rounding)."""
    d, unit, frac, q = grid
    p = medium.phase(vm, half_distance(d, center), maux)
    if own:
        ratio = 1.0 + phase_ratio(p - jax.lax.stop_gradient(p), q)
    else:
        ratio = phase_ratio(p, q)
    # held: XLA would evaluate the phase again inside each sum over the grid's products
    return d, unit, jax.lax.optimization_barrier(frac * ratio), q


def half_grid(brdf: BRDF, vb, partner, n_r: int, n_a: int, half: bool):
    """Half vectors distributed by the facet law, truncated per azimuth so that reflecting
    each ``partner`` direction (P, 3) about them stays above the horizon.

    Returns (h (P, N, 3), alpha (P, N), unit weights (N,), y_max (P, N)) where y_max is the
    facet cumulative at the truncation angle of that node's azimuth.
    """
    x, wx = graded_unit(n_r, FACET_GRADING)
    v, wv = azimuths(n_a, half)
    u = jnp.asarray(np.repeat(x[None, :], len(v), 0).ravel())
    phi = jnp.asarray(TWO_PI * np.repeat(v, n_r))
    unit = jnp.asarray(np.outer(wv, wx).ravel())
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    # reflected z = A cos(2 alpha - psi) with psi = atan2(sin(theta_P) cos(dphi), cos(theta_P))
    xs = partner[:, None, 0] * cp[None, :] + partner[:, None, 1] * sp[None, :]
    psi = jnp.arctan2(xs, jnp.maximum(partner[:, None, 2], 1e-300))
    alpha_c = jnp.minimum(0.25 * math.pi + 0.5 * psi, HALF_PI)
    y_max = brdf.facet_cdf(vb, alpha_c)
    alpha = brdf.facet_inverse_cdf(vb, u[None, :] * y_max)
    sa, ca = sincos(alpha)
    h = jnp.stack([sa * cp[None, :], sa * sp[None, :], ca], axis=-1)
    return h, alpha, sa, unit, y_max


def graded_unit(n: int, m: int):
    """Gauss-Legendre in t with u = 1 - (1 - t)^m: the Jacobian's (1 - t)^(m - 1) flattens
    the facet law's far tail, where alpha(u) ~ sqrt(-log(1 - u)) would make a Gauss rule in u
    converge slowly."""
    x, wx = gauss_legendre_unit(n)
    return 1.0 - (1.0 - x) ** m, wx * m * (1.0 - x) ** (m - 1)


_SIN = tuple((-1) ** k / math.factorial(2 * k + 1) for k in range(11))
_COS = tuple((-1) ** k / math.factorial(2 * k) for k in range(12))


def sincos(a):
    """sin and cos of angles in [0, pi/2] by their Taylor series (error < 1e-15): a few
    multiply-adds instead of XLA's much slower transcendental calls on the CPU."""
    z = a * a
    s = _SIN[-1]
    for coef in _SIN[-2::-1]:
        s = s * z + coef
    c = _COS[-1]
    for coef in _COS[-2::-1]:
        c = c * z + coef
    return a * s, c


def _atan_series():
    """Coefficients of atan(t)/t as a polynomial in t^2 on [0, tan(pi/8)^2] (error < 1e-15)."""
    a2 = math.tan(math.pi / 8) ** 2
    z = 0.5 * a2 * (1.0 + np.cos(np.linspace(0.0, math.pi, 400)))
    t = np.sqrt(z)
    f = np.where(t > 0, np.arctan(t) / np.where(t > 0, t, 1.0), 1.0)
    fit = np.polynomial.Chebyshev.fit(z, f, 10, domain=[0.0, a2])
    poly = fit.convert(kind=np.polynomial.Polynomial, domain=[0.0, a2], window=[0.0, a2])
    return tuple(poly.coef)


_ATAN = _atan_series()


def polar_angle(s, c):
    """atan2(s, c) for s >= 0, c >= 0 (sine and cosine of an angle in [0, pi/2]).

    Four times the quarter angle, whose tangent t = tan(alpha/4) <= tan(pi/8) is reached by
    two half-angle steps, atan(t) = t P(t^2): several times faster than XLA's atan2 on the
    CPU, accurate to 1e-15, and smooth (differentiable) at s = 0.
    """
    t1 = s / (1.0 + c)  # tan(alpha / 2) in [0, 1)
    t2 = t1 / (1.0 + jnp.sqrt(1.0 + t1 * t1))  # tan(alpha / 4)
    z = t2 * t2
    acc = _ATAN[-1]
    for coef in _ATAN[-2::-1]:
        acc = acc * z + coef
    return 4.0 * t2 * acc


def dot3(a, b):
    """a . b over the last axis, written out (XLA fuses it; a reduction it would not)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def reflect(d, h):
    return 2.0 * dot3(d, h)[..., None] * h - d


def half_distance(a, b):
    """1 - a.b for unit vectors, without cancellation."""
    return 0.5 * (
        (a[..., 0] - b[..., 0]) ** 2 + (a[..., 1] - b[..., 1]) ** 2 + (a[..., 2] - b[..., 2]) ** 2
    )


def facet_grids(brdf: BRDF, vb, shapes):
    """Half vectors by the untruncated facet law for each (n_r, n_a, half) of ``shapes``, in
    one evaluation of the facet law: per grid (h (1, N, 3), alpha, unit weights, density per
    steradian (1, N)); ``half`` keeps the azimuths in (0, pi) with double weight (for
    integrands symmetric under y -> -y). Once per engine call: sin and cos by XLA."""
    nodes = []
    for n_r, n_a, half in shapes:
        x, wx = graded_unit(n_r, FACET_GRADING)
        v, wv = azimuths(n_a, half)
        nodes.append((np.tile(x, len(v)), TWO_PI * np.repeat(v, n_r), np.outer(wv, wx).ravel()))
    y_full = brdf.facet_cdf(vb, HALF_PI)
    alpha = brdf.facet_inverse_cdf(vb, jnp.asarray(np.concatenate([n[0] for n in nodes])) * y_full)
    phi = jnp.asarray(np.concatenate([n[1] for n in nodes]))
    sa, ca = jnp.sin(alpha), jnp.cos(alpha)
    h = jnp.stack([sa * jnp.cos(phi), sa * jnp.sin(phi), ca], axis=-1)
    qh = brdf.facet_weight(vb, alpha, sa) / y_full
    out, start = [], 0
    for x, _, unit in nodes:
        part = slice(start, start + x.size)
        out.append((h[None, part], alpha[None, part], jnp.asarray(unit)[None], qh[None, part]))
        start += x.size
    return out


def polar(h):
    """(alpha, sin alpha) of unit vectors h (..., 3): the angle from the normal, smooth at 0."""
    s2 = h[..., 0] ** 2 + h[..., 1] ** 2
    sin_a = jnp.where(s2 > 0, jnp.sqrt(jnp.where(s2 > 0, s2, 1.0)), 0.0)
    return polar_angle(sin_a, h[..., 2]), sin_a


def normalized(s):
    """s / |s| over the last axis (a zero vector stays finite)."""
    return s / jnp.sqrt(jnp.maximum(dot3(s, s), 1e-300))[..., None]


def lobe_at(brdf: BRDF, vb, requests):
    """``brdf.lobe`` at the nodes of each of several node sets.

    ``requests`` is a list of (wi, wo, h, alpha): unit vectors (..., 3) and angles (...)
    that broadcast together; returns one array per request, of its broadcast shape."""
    out = []
    for wi, wo, h, alpha in requests:
        shape = tuple(jnp.broadcast_shapes(wi.shape[:-1], wo.shape[:-1], h.shape[:-1], alpha.shape))
        out.append(jnp.broadcast_to(brdf.lobe(vb, wi, wo, h, alpha), shape))
    return out


def separable_at(brdf: BRDF, vb, aux, cos_i, cos_r):
    """``brdf.separable`` for lists of cosine arrays taken pairwise (``cos_i[j]`` with
    ``cos_r[j]``, of one shape): returns (s, t), s[k][j] = s_k at cos_i[j], t[k][j] = t_k at
    cos_r[j]."""
    per_pair = [
        brdf.separable(vb, jnp.asarray(ci), jnp.asarray(cr), aux) for ci, cr in zip(cos_i, cos_r)
    ]
    s = [
        [jnp.broadcast_to(pair[k][0], np.shape(ci)) for pair, ci in zip(per_pair, cos_i)]
        for k in range(len(per_pair[0]))
    ]
    t = [
        [jnp.broadcast_to(pair[k][1], np.shape(cr)) for pair, cr in zip(per_pair, cos_r)]
        for k in range(len(per_pair[0]))
    ]
    return s, t
