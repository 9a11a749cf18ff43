"""The apparent reflectance of docs/model.md section 5 (paper eq. 1), by deterministic quadrature.

    f(I, R) = Int Int f_t(I, I') f_r(I', R') f_t(R', R) dI' dR'

With f_t = T_d + T_t a(.) b(.) p (:class:`veil.models.base.BTDF`) and
f_r = separable + lobe (:class:`veil.models.base.BRDF`) the product expands into terms of
very different difficulty, each integrated by the cheapest rule that is exact in the limit:

  T_d^2     C0 = Int Int f_r, a constant: albedo table over theta_I', once per call
  T_d T_t   a(I) Int b(I') p(I.I') A(I') dI'     2D phase grid about I, tabulated albedo A
  T_t T_d   b(R) Int a(R') p(R'.R) B(R') dR'     2D phase grid about R, tabulated albedo B
  T_t^2     separable part: products of two 2D phase-grid integrals
  T_t^2     lobe part: a 4D integral of three sharp factors, p(I.I'), the BRDF lobe and
            p(R'.R), by deterministic multiple-importance quadrature: three product grids
            (phase x half vector, half vector x phase, phase x phase), each evaluating the
            integrand times a balance weight, q_k / sum_j q_j, built from the untruncated
            densities of the three maps (any partition of unity is exact; this one makes the
            integrand smooth and bounded in every grid's coordinates).

Phase grids are truncated exactly at the horizon (per azimuth about I or R), and so are the
half-vector grids of the albedo tables (per azimuth, so that the reflected direction stays
above the horizon). The 4D term's half-vector grid is not truncated: where a reflected
direction falls below the horizon its integrand is set to zero, which is a discontinuity
only for an index-matched medium (eta_u = 1); otherwise the Fresnel transmittance and the
shadowing term already take the integrand to zero there. For configurations in the plane of incidence the
integrand is symmetric under y -> -y and only half of the azimuths are evaluated.
"""

from __future__ import annotations

import math

import numpy as np

from .._jax import jax, jnp
from ..models.base import BRDF, BTDF
from .quadrature import Rule, frame, gauss_legendre_unit, horizon_one_minus_mu, periodic_unit

TWO_PI = 2.0 * math.pi
HALF_PI = 0.5 * math.pi
FACET_GRADING = 3
PHASE_GRADING = 1


# --------------------------------------------------------------------------------------
# grids
# --------------------------------------------------------------------------------------
def _azimuths(n: int, half: bool):
    """Midpoint azimuth nodes in [0, 1) and weights; ``half`` keeps (0, 1/2) with double weight."""
    v, w = periodic_unit(n)
    if half:
        keep = v < 0.5
        return v[keep], 2.0 * w[keep]
    return v, w


def _phase_grid(medium: BTDF, vm, maux, center, n_r: int, n_a: int, half: bool,
                grading: int = 1):
    """Directions about ``center`` (3,) distributed as the phase lobe truncated at z = 0.

    Returns (d (N, 3), unit weights (N,), frac_max (N,), p (N,)). sum(unit * frac_max * f(d))
    approximates Int_{z>0} p(center . d) f(d) dd; p is the phase density at each node.
    """
    x, wx = gauss_legendre_unit(n_r)
    if grading > 1:  # more nodes towards the horizon end of the cone fraction
        wx = wx * grading * (1.0 - x) ** (grading - 1)
        x = 1.0 - (1.0 - x) ** grading
    v, wv = _azimuths(n_a, half)
    u = jnp.asarray(np.repeat(x[None, :], len(v), 0).ravel())
    beta = jnp.asarray(TWO_PI * np.repeat(v, n_r))
    unit = jnp.asarray(np.outer(wv, wx).ravel())
    cb, sb = jnp.cos(beta), jnp.sin(beta)
    # the horizon depends on the azimuth only: one cone fraction per azimuth
    cos_az = jnp.asarray(np.cos(TWO_PI * v))
    frac_max = jnp.repeat(medium.phase_cone_fraction(
        vm, horizon_one_minus_mu(center[2], cos_az), maux), n_r)
    omm, p = medium.phase_sample(vm, u * frac_max, maux)
    sg = jnp.sqrt(jnp.maximum(omm * (2.0 - omm), 0.0))
    t1, t2 = frame(center)
    d = ((1.0 - omm)[:, None] * center[None, :]
         + sg[:, None] * (cb[:, None] * t1[None, :] + sb[:, None] * t2[None, :]))
    return d, unit, frac_max, p


def _half_grid(brdf: type[BRDF], vb, partner, n_r: int, n_a: int, half: bool):
    """Half vectors distributed by the facet law, truncated per azimuth so that reflecting
    each ``partner`` direction (P, 3) about them stays above the horizon.

    Returns (h (P, N, 3), alpha (P, N), unit weights (N,), y_max (P, N)) where y_max is the
    facet cumulative at the truncation angle of that node's azimuth.
    """
    x, wx = _graded_unit(n_r, FACET_GRADING)
    v, wv = _azimuths(n_a, half)
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


def _graded_unit(n: int, m: int):
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
    return tuple(fit.convert(kind=np.polynomial.Polynomial, domain=[0.0, a2], window=[0.0, a2]).coef)


_ATAN = _atan_series()


def polar_angle(s, c):
    """atan2(s, c) for s >= 0, c >= 0 (sine and cosine of an angle in [0, pi/2]).

    Four times the quarter angle, whose tangent t = tan(alpha/4) <= tan(pi/8) is reached by
    two half-angle steps, atan(t) = t P(t^2): several times faster than XLA's atan2 on the
    CPU, accurate to 1e-15, and smooth (differentiable) at s = 0.
    """
    t1 = s / (1.0 + c)                      # tan(alpha / 2) in [0, 1)
    t2 = t1 / (1.0 + jnp.sqrt(1.0 + t1 * t1))  # tan(alpha / 4)
    z = t2 * t2
    acc = _ATAN[-1]
    for coef in _ATAN[-2::-1]:
        acc = acc * z + coef
    return 4.0 * t2 * acc


def dot3(a, b):
    """a . b over the last axis, written out (XLA fuses it; a reduction it would not)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _reflect(d, h):
    return 2.0 * dot3(d, h)[..., None] * h - d


def _half_distance(a, b):
    """1 - a.b for unit vectors, without cancellation."""
    return 0.5 * ((a[..., 0] - b[..., 0]) ** 2 + (a[..., 1] - b[..., 1]) ** 2
                  + (a[..., 2] - b[..., 2]) ** 2)


# --------------------------------------------------------------------------------------
# albedo tables of the lobe (once per call)
# --------------------------------------------------------------------------------------
def _table_thetas(rule: Rule):
    """Table nodes theta = pi/2 (1 - (1 - v)^2), v uniform: twice as dense at the horizon,
    where the lobe's albedo rises steeply with the Fresnel factor."""
    v = np.linspace(0.0, 1.0, rule.table)
    return HALF_PI * (1.0 - (1.0 - v) ** 2)


def _table_coordinate(theta):
    return 1.0 - jnp.sqrt(jnp.maximum(1.0 - theta / HALF_PI, 0.0))


def _lobe_albedo_tables(brdf, vb, rule: Rule):
    """A(theta) = Int lobe(I', R') dR' and B(theta) = Int lobe(I', R') dI' on a theta grid."""
    th = np.minimum(_table_thetas(rule), HALF_PI - 1e-7)  # the limit at the horizon
    d = jnp.asarray(np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=-1))
    h, alpha, _, unit, y_max = _half_grid(brdf, vb, d, rule.table_radial, rule.table_azimuth, True)
    other = _reflect(d[:, None, :], h)
    din = jnp.broadcast_to(d[:, None, :], other.shape)
    c = jnp.sum(din * h, axis=-1)
    jac = unit[None, :] * 4.0 * c * y_max / brdf.facet_weight(vb, alpha)
    a_tab = jnp.sum(jac * brdf.lobe(vb, din, other, h, alpha), axis=-1)
    b_tab = jnp.sum(jac * brdf.lobe(vb, other, din, h, alpha), axis=-1)
    return a_tab, b_tab


def _interp_table(table, theta, rule: Rule):
    """Cubic Hermite (Catmull-Rom) interpolation of a table uniform in v (_table_thetas)."""
    k = rule.table
    x = jnp.clip(_table_coordinate(theta) * (k - 1), 0.0, k - 1 - 1e-9)
    i = jnp.floor(x).astype(int)
    t = x - i
    ext = jnp.concatenate([2 * table[:1] - table[1:2], table, 2 * table[-1:] - table[-2:-1]])
    p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
    m1 = 0.5 * (p2 - p0)
    m2 = 0.5 * (p3 - p1)
    t2, t3 = t * t, t * t * t
    return ((2 * t3 - 3 * t2 + 1) * p1 + (t3 - 2 * t2 + t) * m1
            + (-2 * t3 + 3 * t2) * p2 + (t3 - t2) * m2)


def _simpson_weights(k: int, step: float) -> np.ndarray:
    w = np.ones(k)
    w[1:-1:2] = 4.0
    w[2:-1:2] = 2.0
    return w * step / 3.0


def _hemisphere_integral(fn, n=64):
    """Int over the upper hemisphere of fn(cos theta) (isotropic integrand)."""
    x, w = gauss_legendre_unit(n)
    return TWO_PI * jnp.sum(jnp.asarray(w) * fn(jnp.asarray(x)))


def _shared(brdf, rule, vb):
    """Per-call quantities that do not depend on the configuration: the BRDF's own tables
    (``prepare``), the albedo tables of its lobe and the hemisphere integrals of its
    separable factors."""
    aux = brdf.prepare(vb)
    if brdf.HAS_LOBE:
        a_tab, b_tab = _lobe_albedo_tables(brdf, vb, rule)
    else:
        a_tab = b_tab = jnp.zeros(rule.table)
    n_sep = len(brdf.separable(vb, jnp.zeros(1), jnp.zeros(1), aux))
    s_int = [_hemisphere_integral(lambda c, k=k: brdf.separable(vb, c, c, aux)[k][0])
             for k in range(n_sep)]
    t_int = [_hemisphere_integral(lambda c, k=k: brdf.separable(vb, c, c, aux)[k][1])
             for k in range(n_sep)]
    th = _table_thetas(rule)
    v = np.linspace(0.0, 1.0, rule.table)
    sw = jnp.asarray(_simpson_weights(rule.table, v[1]) * np.sin(th) * math.pi * (1.0 - v))
    c0_sep = sum(s * t for s, t in zip(s_int, t_int)) + 0.0 * jnp.sum(a_tab)
    c0_lobe = TWO_PI * jnp.sum(sw * a_tab)
    return c0_sep, c0_lobe, a_tab, b_tab, s_int, t_int, aux


# --------------------------------------------------------------------------------------
# one configuration
# --------------------------------------------------------------------------------------
def _facet_grid(brdf: type[BRDF], vb, n_r: int, n_a: int, half: bool = False):
    """Half vectors by the untruncated facet law, shaped (1, N, 3), with alpha, unit weights
    and density per steradian (1, N); ``half`` keeps the azimuths in (0, pi) with double
    weight (for integrands symmetric under y -> -y)."""
    x, wx = _graded_unit(n_r, FACET_GRADING)
    v, wv = _azimuths(n_a, half)
    y_full = brdf.facet_cdf(vb, HALF_PI)
    alpha = brdf.facet_inverse_cdf(vb, jnp.asarray(np.tile(x, len(v))) * y_full)
    phi = jnp.asarray(TWO_PI * np.repeat(v, n_r))
    sa, ca = sincos(alpha)
    h = jnp.stack([sa * jnp.cos(phi), sa * jnp.sin(phi), ca], axis=-1)
    qh = brdf.facet_weight(vb, alpha, sa) / y_full
    unit = jnp.asarray(np.outer(wv, wx).ravel())
    return h[None], alpha[None], unit[None], qh[None]


def _apart(fn, vm, *args):
    """fn(*args) computed apart from the surrounding expression (not fused into it): a
    conditional on a value known only at run time keeps its branch a computation of its own
    (taken whenever the medium's parameters are finite; otherwise the result is NaN, as it
    would be anyway)."""
    return jax.lax.cond(jnp.all(jnp.isfinite(vm)), fn,
                        lambda *a: jax.tree.map(lambda z: jnp.full_like(z, jnp.nan), fn(*a)),
                        *args)


def _view_weight(medium, vm, r_prime, wr):
    """The medium's weight of its view-side lobe at R' (..., 3) for the camera at R, or 1."""
    if not medium.has_view_weight():
        return 1.0
    # apart: XLA would fuse it into the consumers of the grid's weights, the 4D products,
    # and evaluate it again at every node of them
    return _apart(lambda a, b: medium.view_weight(vm, a, b), vm, r_prime, wr)


def _lobe_lobe(brdf, medium, vb, vm, maux, wi, wr, rule: Rule, half: bool):
    """Int Int b(I') p(I.I') lobe(I', R') a(R') J(R') p(R'.R) dI' dR' (balanced MIS
    quadrature), J the view-side weight of the medium (1 without one)."""
    n_r, n_a = rule.phase_radial, rule.phase_azimuth
    gi, ui, fi, pi_ = _phase_grid(medium, vm, maux, wi, n_r, n_a, half, PHASE_GRADING)   # I' about I
    gr, ur, fr, pr = _phase_grid(medium, vm, maux, wr, n_r, n_a, False, PHASE_GRADING)   # R' about R
    bi = medium.factor_second(vm, gi[:, 2])
    ar = medium.factor_first(vm, gr[:, 2]) * _view_weight(medium, vm, gr, wr)
    if half:  # component B needs only half of the R' azimuths (C pairs half I' with all R')
        grb, urb, frb, prb = _phase_grid(medium, vm, maux, wr, n_r, n_a, True, PHASE_GRADING)
        arb = medium.factor_first(vm, grb[:, 2]) * _view_weight(medium, vm, grb, wr)
    else:
        grb, urb, frb, prb, arb = gr, ur, fr, pr, ar

    def balanced(p_i, p_r, c, q_h, lobe):
        """lobe p_i p_r / (q_A + q_B + q_C) with the untruncated densities (balance rule)."""
        den = q_h * (p_i + p_r) / (4.0 * c) + p_i * p_r
        ok = (c > 0) & (den > 0)
        return jnp.where(ok, lobe * p_i * p_r / jnp.where(ok, den, 1.0), 0.0)

    # A: I' on the phase grid about I, H on the facet grid, R' = refl(I') (zero below the
    # horizon, where the integrand already vanishes with a(R') and the shadowing term)
    h, alpha, uh, qh = _facet_grid(brdf, vb, rule.half_radial, rule.half_azimuth)
    i2 = gi[:, None, :]
    r2 = _reflect(i2, h)
    c = dot3(i2, h)
    p_r = medium.phase(vm, _half_distance(r2, wr), maux)
    val = balanced(pi_[:, None], p_r, c, qh, brdf.lobe(vb, i2, r2, h, alpha))
    val = val * medium.factor_first(vm, r2[..., 2]) * bi[:, None]
    if medium.has_view_weight():
        val = val * medium.view_weight(vm, r2, wr)
    total = jnp.sum(ui * fi * jnp.sum(uh * val, axis=-1))

    # B: R' on the phase grid about R, H on the facet grid, I' = refl(R')
    r2 = grb[:, None, :]
    i2 = _reflect(r2, h)
    c = dot3(r2, h)
    p_i = medium.phase(vm, _half_distance(i2, wi), maux)
    val = balanced(p_i, prb[:, None], c, qh, brdf.lobe(vb, i2, r2, h, alpha))
    val = val * arb[:, None] * medium.factor_second(vm, i2[..., 2])
    total = total + jnp.sum(urb * frb * jnp.sum(uh * val, axis=-1))

    # C: I' and R' on their phase grids, H their half vector
    i2 = gi[:, None, :]
    r2 = gr[None, :, :]
    s = i2 + r2
    hh = s / jnp.sqrt(jnp.maximum(dot3(s, s), 1e-300))[..., None]
    s2 = hh[..., 0] ** 2 + hh[..., 1] ** 2
    sin_c = jnp.where(s2 > 0, jnp.sqrt(jnp.where(s2 > 0, s2, 1.0)), 0.0)
    alpha_c = polar_angle(sin_c, hh[..., 2])
    c = dot3(i2, hh)
    q_h = brdf.facet_weight(vb, alpha_c, sin_c) / brdf.facet_cdf(vb, HALF_PI)
    val = balanced(pi_[:, None], pr[None, :], c, q_h, brdf.lobe(vb, i2, r2, hh, alpha_c))
    val = val * bi[:, None] * ar[None, :]
    total = total + jnp.sum((ui * fi)[:, None] * (ur * fr)[None, :] * val)
    return total


def _lobe_one_side(brdf, medium, vb, vm, maux, fixed, center, rule: Rule, half: bool,
                   view, grid):
    """The BRDF's lobe against the phase lobe on one side, the other direction fixed:

        view:     Int lobe(F, R') a(R') J(R') p(R'.C) dR'    (F = I, C = R)
        not view: Int p(C.I') b(I') lobe(I', F) dI'          (F = R, C = I)

    by balanced MIS over two grids: the phase grid about C, and half vectors from the facet
    law with the free direction the mirror of F. ``grid`` is the dense phase grid about C
    (:func:`_phase_grid`), shared with the other 2D terms. ``view`` is a boolean array, so
    that both sides run as one computation (:func:`_lobe_sides`)."""
    g, u, f, p = grid

    def lobe(free, h, alpha):
        fixed_b = jnp.broadcast_to(fixed, free.shape)
        return brdf.lobe(vb, jnp.where(view, fixed_b, free), jnp.where(view, free, fixed_b),
                         h, alpha)

    def weight(free):
        z = free[..., 2]
        w = jnp.where(view, medium.factor_first(vm, z), medium.factor_second(vm, z))
        if medium.has_view_weight():
            w = w * jnp.where(view, medium.view_weight(vm, free, center), 1.0)
        return w

    y_full = brdf.facet_cdf(vb, HALF_PI)
    # the phase grid: density of the free direction p, of the facet strategy q_h / (4 c)
    s = g + fixed
    hg = s / jnp.sqrt(jnp.maximum(dot3(s, s), 1e-300))[..., None]
    c = dot3(g, hg)
    s2 = hg[..., 0] ** 2 + hg[..., 1] ** 2
    sin_h = jnp.where(s2 > 0, jnp.sqrt(jnp.where(s2 > 0, s2, 1.0)), 0.0)
    alpha_h = polar_angle(sin_h, hg[..., 2])
    q = jnp.where(hg[..., 2] > 0, brdf.facet_weight(vb, alpha_h, sin_h) / y_full, 0.0)
    q_free = q / (4.0 * jnp.maximum(c, 1e-300))
    ok = (c > 0) & (p + q_free > 0)
    w_phase = jnp.where(ok, p / jnp.where(ok, p + q_free, 1.0), 0.0)
    total = jnp.sum(u * f * w_phase * lobe(g, hg, alpha_h) * weight(g))
    # the facet grid: H by the facet law, free = mirror of the fixed direction
    h, alpha, uh, qh = _facet_grid(brdf, vb, rule.dense_radial, rule.dense_azimuth, half)
    free = _reflect(fixed, h[0])
    c = dot3(fixed, h[0])
    p_free = medium.phase(vm, _half_distance(free, center), maux)
    den = p_free + qh[0] / (4.0 * jnp.maximum(c, 1e-300))
    ok = (c > 0) & (free[..., 2] > 0) & (den > 0)
    val = jnp.where(ok, lobe(free, h[0], alpha[0]) * weight(free) * p_free
                    / jnp.where(ok, den, 1.0), 0.0)
    return total + jnp.sum(uh[0] * val)


def _lobe_sides(brdf, medium, vb, vm, maux, wi, wr, rule: Rule, half: bool, grid_i, grid_r):
    """(:func:`_lobe_one_side` on the view side, on the light side) as one vmapped
    computation: the program holds the lobe, the phase function and the medium's factors
    once, not twice (a smaller program compiles faster; docs/performance.md)."""
    grids = jax.tree.map(lambda a, b: jnp.stack([a, b]), tuple(grid_r), tuple(grid_i))

    def side(fixed, center, view, grid):
        return _lobe_one_side(brdf, medium, vb, vm, maux, fixed, center, rule, half, view,
                              grid)

    both = jax.vmap(side)(jnp.stack([wi, wr]), jnp.stack([wr, wi]), jnp.array([True, False]),
                          grids)
    return both[0], both[1]


def pairs(medium_cls) -> list[tuple[str, str]]:
    """The medium's rows: unordered pairs of its components (light side, view side), in
    the order of ``COMPONENTS``; a row collects both orders of a mixed pair."""
    comps = medium_cls.COMPONENTS
    return [(a, b) for i, a in enumerate(comps) for b in comps[i:]]


def _one_config(brdf, medium, rule, half, vb, vm, shared, maux, wi, wr):
    """Term matrix E (rows, 2) of one configuration with the scale parameters set to 1.

    Rows: the medium's component pairs (:func:`pairs`: for the paper's medium T_d^2,
    T_d T_t, T_t^2), each with its components' weights; columns: the separable and lobe
    parts of f_r.
    """
    c0_sep, c0_lobe, a_tab, b_tab, s_int, t_int, aux = shared
    zero = 0.0 * c0_sep
    comps = medium.COMPONENTS
    a_i = medium.factor_first(vm, wi[2])      # a(I): the light's way into the medium
    b_i = medium.factor_second(vm, wi[2])     # b(I): the unscattered beam leaving it
    a_r = medium.factor_first(vm, wr[2])      # a(R): the unscattered view ray entering
    b_r = medium.factor_second(vm, wr[2])     # b(R): leaving towards the camera
    rows = {}

    def albedo(theta, table):
        return _interp_table(table, theta, rule) if brdf.HAS_LOBE else zero

    if "iso" in comps:
        rows[("iso", "iso")] = (c0_sep, c0_lobe)
    if "lobe" in comps:
        # 2D terms on a dense phase grid about I (I') and about R (R')
        grid_i = _phase_grid(medium, vm, maux, wi, rule.dense_radial, rule.dense_azimuth, half)
        grid_r = _phase_grid(medium, vm, maux, wr, rule.dense_radial, rule.dense_azimuth, half)
        gi, ui, fi, _ = grid_i
        gr, ur, fr, _ = grid_r
        wgi = ui * fi * medium.factor_second(vm, gi[:, 2])
        wgr = ur * fr * medium.factor_first(vm, gr[:, 2]) * _view_weight(medium, vm, gr, wr)
        seps_i = brdf.separable(vb, gi[:, 2], gi[:, 2], aux)
        seps_r = brdf.separable(vb, gr[:, 2], gr[:, 2], aux)
        ti = jnp.arccos(jnp.clip(gi[:, 2], -1.0, 1.0))
        tr = jnp.arccos(jnp.clip(gr[:, 2], -1.0, 1.0))
        if "iso" in comps:
            # light lobe x view iso: a(I) Int b(I') p A(I'); light iso x view lobe: b(R) Int a J p B
            mixed_sep = (a_i * jnp.sum(wgi * sum(s * tk for (s, _), tk in zip(seps_i, t_int)))
                         + b_r * jnp.sum(wgr * sum(t * sk for (_, t), sk in zip(seps_r, s_int))))
            mixed_lobe = (a_i * jnp.sum(wgi * albedo(ti, a_tab))
                          + b_r * jnp.sum(wgr * albedo(tr, b_tab)))
            rows[("iso", "lobe")] = (mixed_sep, mixed_lobe)
        sep = sum(jnp.sum(wgi * s) * jnp.sum(wgr * t) for (s, _), (_, t) in zip(seps_i, seps_r))
        lobe = (_lobe_lobe(brdf, medium, vb, vm, maux, wi, wr, rule, half) if brdf.HAS_LOBE
                else zero)
        rows[("lobe", "lobe")] = (a_i * b_r * sep, a_i * b_r * lobe)
    if "delta" in comps:
        dl, dv = a_i * b_i, a_r * b_r
        seps = brdf.separable(vb, wi[2], wr[2], aux)
        f_sep = sum(s * t for s, t in seps) + zero
        if brdf.HAS_LOBE:
            s = wi + wr
            f_lobe = brdf.lobe(vb, wi, wr, s / jnp.sqrt(dot3(s, s)))
        else:
            f_lobe = zero
        rows[("delta", "delta")] = (dl * dv * f_sep, dl * dv * f_lobe)
        if "iso" in comps:  # the unscattered beam on one side, the iso part on the other
            sep_i, sep_r = brdf.separable(vb, wi[2], wi[2], aux), brdf.separable(vb, wr[2], wr[2], aux)
            iso_sep = (dl * sum(s * tk for (s, _), tk in zip(sep_i, t_int))
                       + dv * sum(t * sk for (_, t), sk in zip(sep_r, s_int)))
            iso_lobe = (dl * albedo(jnp.arccos(jnp.clip(wi[2], -1.0, 1.0)), a_tab)
                        + dv * albedo(jnp.arccos(jnp.clip(wr[2], -1.0, 1.0)), b_tab))
            rows[("delta", "iso")] = (iso_sep + zero, iso_lobe + zero)
        if "lobe" in comps:  # the unscattered beam on one side, the lobe on the other
            sep_fixed_i = brdf.separable(vb, wi[2], wi[2], aux)
            sep_fixed_r = brdf.separable(vb, wr[2], wr[2], aux)
            d_sep = (dl * b_r * sum(s * jnp.sum(wgr * t)
                                    for (s, _), (_, t) in zip(sep_fixed_i, seps_r))
                     + dv * a_i * sum(t * jnp.sum(wgi * s)
                                      for (_, t), (s, _) in zip(sep_fixed_r, seps_i)))
            if brdf.HAS_LOBE:
                view_side, light_side = _lobe_sides(brdf, medium, vb, vm, maux, wi, wr, rule,
                                                    half, grid_i, grid_r)
                d_lobe = dl * b_r * view_side + dv * a_i * light_side
            else:
                d_lobe = zero
            rows[("delta", "lobe")] = (d_sep + zero, d_lobe + zero)
    out = []
    for a, b in pairs(medium):
        sep_v, lobe_v = rows[(a, b)] if (a, b) in rows else rows[(b, a)]
        w = medium.weight(vm, a) * medium.weight(vm, b)
        out.append(jnp.stack([w * sep_v, w * lobe_v]))
    return jnp.stack(out)


#: The parts of a BRDF (columns of a term matrix), as models name them in ``SCALES``.
BRDF_PARTS = ("separable", "lobe")


def _unit_scales(model, v):
    for part in model.SCALES:
        v = v.at[model.scale_index(part)].set(1.0)
    gain = getattr(model, "GAIN", None)
    if gain is not None:
        v = v.at[model.param_names().index(gain)].set(1.0)
    return v


def _scale(model, v, part):
    i = model.scale_index(part)
    return 1.0 if i is None else v[i]


def _gain(medium_cls, vm):
    return 1.0 if medium_cls.GAIN is None else vm[medium_cls.param_names().index(medium_cls.GAIN)]


def row_scales(medium_cls, vm):
    """The rows' weights from the medium's scale parameters: s_a s_b for each component pair
    (:func:`pairs`; a component without a scale counts 1), times the gain; numpy."""
    vm = np.asarray(vm, dtype=float)
    s = {c: float(_scale(medium_cls, vm, c)) for c in medium_cls.COMPONENTS}
    gain = float(_gain(medium_cls, vm))
    return np.array([s[a] * s[b] * gain for a, b in pairs(medium_cls)])


def row_scale_derivative(medium_cls, vm, index: int) -> np.ndarray:
    """d row_scales / d parameter ``index`` of the medium (a scale or the gain)."""
    vm = np.asarray(vm, dtype=float)
    s = {c: float(_scale(medium_cls, vm, c)) for c in medium_cls.COMPONENTS}
    gain = float(_gain(medium_cls, vm))
    names = medium_cls.param_names()
    if medium_cls.GAIN is not None and names[index] == medium_cls.GAIN:
        return np.array([s[a] * s[b] for a, b in pairs(medium_cls)])
    comp = [c for c, n in medium_cls.SCALES.items() if n == names[index]]
    if not comp:
        raise ValueError(f"{names[index]} is not a scale of {medium_cls.NAME}")
    c = comp[0]
    return np.array([gain * ((s[b] if a == c else 0.0) + (s[a] if b == c else 0.0))
                     for a, b in pairs(medium_cls)])


def column_scales(brdf_cls, vb):
    """The BRDF's column weights (separable, lobe) from its scale parameters."""
    return np.array([float(_scale(brdf_cls, vb, part)) for part in BRDF_PARTS])


def combine_terms(brdf_cls, medium_cls, terms, vb, vm):
    """Apparent reflectance from the term matrices (..., rows, 2) and the scale parameters."""
    s = {c: _scale(medium_cls, vm, c) for c in medium_cls.COMPONENTS}
    rows = jnp.stack([s[a] * s[b] * jnp.ones(()) for a, b in pairs(medium_cls)])
    rows = rows * _gain(medium_cls, vm)
    cols = jnp.stack([_scale(brdf_cls, vb, part) * jnp.ones(()) for part in BRDF_PARTS])
    return jnp.einsum("...mb,m,b->...", terms, rows, cols)


def apparent_terms(brdf_template, medium_template, rule, vb, vm, wi, wr, half=False,
                   batch_size=None):
    """Term matrices (M, rows, 2) for unit direction arrays (M, 3); see :func:`_one_config`.

    Pure JAX and differentiable in the non-scale parameters of ``vb`` and ``vm``.
    ``half=True`` is valid only when every configuration lies in the xz plane.
    """
    brdf = brdf_template  # its functions read its options (e.g. a microfacet distribution)
    vb1 = _unit_scales(type(brdf), jnp.asarray(vb))
    vm1 = _unit_scales(type(medium_template), jnp.asarray(vm))
    shared = _shared(brdf, rule, vb1)
    maux = medium_template.prepare(vm1)

    def f(x):
        return _one_config(brdf, medium_template, rule, half, vb1, vm1, shared, maux, x[0],
                           x[1])

    if batch_size is None:  # keep the live intermediate arrays to a few hundred MB
        batch_size = max(1, min(64, 1_500_000 // rule.points_per_config))
    return jax.lax.map(f, (wi, wr), batch_size=batch_size)


_TEMPLATES: dict = {}


def template(model):
    """The cached template instance for a model's structure (static options only)."""
    return _TEMPLATES.setdefault(model.structure(), model)


def template_for(structure):
    """The template instance registered for a model structure (see :func:`template`)."""
    return _TEMPLATES[structure]
