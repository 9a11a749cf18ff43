"""Independent brute-force reference for the apparent reflectance (docs/model.md sec. 5, paper eq. 1).

Written from docs/model.md alone, in numpy/scipy, sharing no code with veil's engine
(``veil.engine.integrator``, ``veil.engine.quadrature``) nor with its model code. It is a checker: slow,
simple, and every piece can be verified against another.

Method. With f_t(A, B) = T_d + T_t a(A_z) b(B_z) p(A . B) (docs/model.md sec. 3; a = F_t^2, b = 1
for the "paper" variant, a = b = F_t for "exit") and f_r = P_d cos(theta_I) + f_s (sec. 2),
eq. 1 expands into

    f(I, R) = T_d^2 (2 pi^2 P_d + J_s)                                       [iso-iso]
            + T_d T_t b(R_z) (pi P_d L_R + M_R)                                [iso-lobe]
            + T_d T_t a(I_z) (2 pi P_d L_I + M_I)                              [lobe-iso]
            + T_t^2 a(I_z) b(R_z) (P_d L_I L_R + K)                            [lobe-lobe]

    L_R = Int a(X_z) p(R . X) dX           L_I = Int b(X_z) X_z p(I . X) dX
    M_R = Int a(X_z) S_R(X_z) p(R . X) dX  M_I = Int b(X_z) S_I(X_z) p(I . X) dX
    S_I(theta) = Int f_s(V, W) dW,  S_R(theta) = Int f_s(W, V) dW   (V at polar angle theta)
    J_s = 2 pi Int S_I(theta) sin(theta) dtheta = 2 pi Int S_R(theta) sin(theta) dtheta
    K   = Int Int b(I'_z) p(I . I') f_s(I', R') a(R'_z) p(R' . R) dI' dR'

All integrals are over the upper hemisphere. Everything except K is a one- or
two-dimensional integral done by Gauss-Legendre rules split at every kink (hemisphere cut,
shadowing/masking switch) and checked by doubling the node counts. K, four-dimensional with
three sharp lobes, is estimated by multiple importance sampling (balance heuristic) over
three strategies, each on its own scrambled Sobol point set; independent scrambles give the
standard error.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.stats import qmc

DEG = math.pi / 180.0

#: The paper's presets as tuples, copied from docs/model.md sec. 6 (not from veil).
PRESETS = {
    "BRDF1": (2.00e2, 5.00e5, 0.80, 1.55),
    "BRDF2": (1.00e3, 5.00e5, 0.50, 1.55),
    "BTDF1": (1.00e-3, 0.01, 0.98, 1.3),
    "BTDF2": (1.00e-3, 0.13, 0.93, 1.3),
    "BTDF3": (1.00e-3, 0.38, 0.88, 1.3),
}


# ----------------------------------------------------------------------------------------
# Model pieces (docs/model.md sec. 2-4), numpy
# ----------------------------------------------------------------------------------------

def reference_fresnel(cos_theta, eta):
    """Unpolarized Fresnel reflectance, cosine form of docs/model.md sec. 4 (F = 1 under TIR)."""
    c = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0)
    eta = float(eta)
    if eta == 1.0:  # no interface; also the limit at grazing, where the formula is 0/0
        return np.zeros_like(c)
    k = 1.0 - (1.0 - c * c) / (eta * eta)
    tir = k <= 0.0  # eta < 1 beyond (or at) the critical angle
    ct = np.sqrt(np.where(tir, 1.0, k))
    cs = np.where(tir, 1.0, c)
    rs = (cs - eta * ct) / (cs + eta * ct)
    rp = (eta * cs - ct) / (eta * cs + ct)
    return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def reference_fresnel_sintan(theta_deg, eta):
    """Fresnel reflectance in the paper's sin/tan form (paper eq. 4), for theta in (0, 90) deg."""
    ti = np.asarray(theta_deg, dtype=float) * DEG
    tt = np.arcsin(np.sin(ti) / eta)
    rs = np.sin(ti - tt) ** 2 / np.sin(ti + tt) ** 2
    rp = np.tan(ti - tt) ** 2 / np.tan(ti + tt) ** 2
    return 0.5 * (rs + rp)


def reference_hg(g, cos_gamma):
    """Henyey-Greenstein phase function p(g, gamma) with its 1/(4 pi) (docs/model.md sec. 3, dec. 2)."""
    mu = np.asarray(cos_gamma, dtype=float)
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def _hg_x(g, x):
    """p(g, gamma) as a function of x = 1 - cos(gamma) (no cancellation near gamma = 0)."""
    d = (1.0 - g) ** 2 + 2.0 * g * x
    return (1.0 - g * g) / (4.0 * math.pi * d * np.sqrt(d))


def _hg_sample_x(g, u):
    """x = 1 - cos(gamma) whose HG cone (gamma' <= gamma) holds the fraction u.

    The cone fraction is P(x) = (1 - g^2)/(2g) (1/(1 - g) - 1/sqrt((1 - g)^2 + 2 g x));
    solving for x and removing the 0/0 at g = 0 gives the form below.
    """
    q = 1.0 + g - 2.0 * g * u
    s = (1.0 - g * g) / q
    return (1.0 - g) * u * (s + 1.0 - g) / q


def _params(model):
    """A preset name (docs/model.md sec. 6) or a 4-tuple -> tuple of 4 floats."""
    if isinstance(model, str):
        model = PRESETS[model.upper()]
    vals = tuple(float(v) for v in model)
    if len(vals) != 4:
        raise ValueError(f"expected 4 parameters, got {model!r}")
    return vals


def _fresnel_factors(medium_eta, variant):
    if variant not in ("paper", "exit"):
        raise ValueError(f"variant = {variant!r}; expected 'paper' or 'exit'")

    def a(cz):
        t = 1.0 - reference_fresnel(cz, medium_eta)
        return t * t if variant == "paper" else t

    def b(cz):
        if variant == "paper":
            return np.ones_like(np.asarray(cz, dtype=float))
        return 1.0 - reference_fresnel(cz, medium_eta)

    return a, b


def _dir(theta_deg, phi_deg):
    t, p = np.asarray(theta_deg, float) * DEG, np.asarray(phi_deg, float) * DEG
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _fs_vec(Ps, n, eta_b, wi, wo):
    """Specular part of f_r (docs/model.md sec. 2) for unit vectors (..., 3); 0 outside Omega+."""
    ci, co = wi[..., 2], wo[..., 2]
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    cp = np.sum(wi * h, axis=-1)  # cos(theta_i'), facet incidence
    ca = h[..., 2]
    alpha = np.arctan2(np.hypot(h[..., 0], h[..., 1]), ca)
    ok = (ci > 0) & (co > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # F G D / cos(theta_r), with G / cos(theta_r) written to stay finite at grazing.
        g_over = np.minimum(np.minimum(1.0 / co, 2.0 * ca / cp), 2.0 * ca * ci / (cp * co))
        val = Ps * reference_fresnel(cp, eta_b) * np.exp(-(n * alpha / DEG) ** 2) * g_over
    return np.where(ok, val, 0.0)


def reference_reflectance(brdf, theta_i, phi_i, theta_r, phi_r):
    """Torrance-Sparrow f_r(I, R) of docs/model.md sec. 2; brdf = (Pd, Ps, n, eta_b), degrees."""
    Pd, Ps, n, eta_b = _params(brdf)
    wi, wo = _dir(theta_i, phi_i), _dir(theta_r, phi_r)
    ok = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(ok, Pd * wi[..., 2], 0.0) + _fs_vec(Ps, n, eta_b, wi, wo)


def reference_btdf(medium, theta_i, phi_i, theta_t, phi_t, variant="paper"):
    """f_t(I, T) of docs/model.md sec. 3; medium = (Td, Tt, g, eta_u); I, T outward, degrees."""
    Td, Tt, g, eta_u = _params(medium)
    a, b = _fresnel_factors(eta_u, variant)
    wi, wt = _dir(theta_i, phi_i), _dir(theta_t, phi_t)
    x = 0.5 * np.sum((wi - wt) ** 2, axis=-1)
    return Td + Tt * a(wi[..., 2]) * b(wt[..., 2]) * _hg_x(g, x)


# ----------------------------------------------------------------------------------------
# Deterministic low-dimensional pieces
# ----------------------------------------------------------------------------------------

@functools.cache
def _gl01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def _smoothstep_nodes(n):
    """GL nodes on [0, 1] pushed through s = 3t^2 - 2t^3 (removes sqrt end singularities)."""
    t, w = _gl01(n)
    return 3 * t * t - 2 * t ** 3, w * 6 * t * (1 - t)


def _k1_arg(th, alpha):
    """cos(phi) at which 2 cos(alpha) W_z = V . H (one switch of the shadowing min)."""
    st, ct = np.sin(th), np.cos(th)
    sa, ca = np.sin(alpha), np.cos(alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        return ct * ca * (1 - 2 * (ca * ca - sa * sa)) / (st * sa * (4 * ca * ca - 1))


def _alpha_breaks(th, amax, ngrid=2000):
    """alpha where a phi breakpoint of :func:`_spec_S` enters or leaves [0, pi], per theta.

    There the inner phi integral has a square-root singularity; splitting alpha at these
    points (with smoothstep nodes) restores fast convergence. Closed forms for the
    hemisphere cut (alpha = (90 - theta)/2, 45 + theta/2) and the V-side switch
    (alpha = 90 - theta); the W-side switch is located by bisection.
    """
    th = th[:, None]
    cands = [0.25 * math.pi - 0.5 * th, 0.25 * math.pi + 0.5 * th, 0.5 * math.pi - th]
    ag = np.linspace(amax * 1e-4, amax, ngrid)[None, :]
    for target in (-1.0, 1.0):
        v = np.nan_to_num(_k1_arg(th, ag) - target, nan=0.0)
        sc = np.signbit(v[:, :-1]) != np.signbit(v[:, 1:])
        for _ in range(2):
            has = sc.any(axis=1)
            j = np.argmax(sc, axis=1)
            lo, hi = ag[0, j], ag[0, j + 1]
            flo = np.nan_to_num(_k1_arg(th[:, 0], lo) - target)
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                fm = np.nan_to_num(_k1_arg(th[:, 0], mid) - target)
                same = np.signbit(fm) == np.signbit(flo)
                lo, flo = np.where(same, mid, lo), np.where(same, fm, flo)
                hi = np.where(same, hi, mid)
            cands.append(np.where(has, 0.5 * (lo + hi), amax)[:, None])
            sc[np.arange(sc.shape[0]), j] = False
    c = np.concatenate(cands, axis=1)
    c = np.where((c > 0) & (c < amax), c, amax)
    return np.sort(np.concatenate([np.zeros_like(th), c, np.full_like(th, amax)], axis=1), axis=1)


def _spec_S(brdf, theta, mode, na=48, nphi=32):
    """S_I (mode "I") or S_R (mode "R") at polar angles ``theta`` (radians), see module doc.

    Half-vector coordinates H = (alpha, phi) about the normal, W the mirror of V about H,
    dW = 4 (V . H) dH. phi is split at the hemisphere cut W_z = 0 and at both switches of
    the shadowing/masking min; alpha is split where those enter the phi range and runs to
    where exp(-(n alpha_deg)^2) < 1e-19. ``na`` nodes per alpha piece, ``nphi`` per phi piece.
    """
    _, Ps, n, eta_b = (float(v) for v in brdf)
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    c = n / DEG
    amax = min(0.5 * math.pi, math.sqrt(44.0) / c)
    ta, wa = _smoothstep_nodes(na)
    tp, wp = _gl01(nphi)
    out = np.empty_like(theta)
    for k0 in range(0, theta.size, 16):
        th = theta[k0:k0 + 16, None]
        br = _alpha_breaks(th[:, 0], amax)  # (T, P+1)
        alo, ahi = br[:, :-1, None], br[:, 1:, None]
        alpha = (alo + (ahi - alo) * ta).reshape(th.shape[0], -1)  # (T, A)
        wal = ((ahi - alo) * wa).reshape(th.shape[0], -1) * np.sin(alpha) * np.exp(-(c * alpha) ** 2)
        st, ct = np.sin(th), np.cos(th)
        sa, ca = np.sin(alpha), np.cos(alpha)
        s2a, c2a = 2 * sa * ca, ca * ca - sa * sa
        with np.errstate(divide="ignore", invalid="ignore"):
            cut = np.arccos(np.clip(np.nan_to_num(-ct * c2a / (st * s2a), nan=-1.0, posinf=1.0,
                                                  neginf=-1.0), -1.0, 1.0))
            k1 = np.arccos(np.clip(np.nan_to_num(_k1_arg(th, alpha), nan=1.0, posinf=1.0,
                                                 neginf=-1.0), -1.0, 1.0))
            k2 = np.arccos(np.clip(np.nan_to_num(ct * ca / (st * sa), nan=1.0, posinf=1.0,
                                                 neginf=-1.0), -1.0, 1.0))
        bounds = np.sort(np.stack([np.zeros_like(cut), np.minimum(k1, cut), np.minimum(k2, cut), cut],
                                  axis=-1), axis=-1)  # (T, A, 4)
        lo, hi = bounds[..., :-1, None], bounds[..., 1:, None]  # (T, A, 3, 1)
        phi = lo + (hi - lo) * tp
        wphi = (hi - lo) * wp
        st4, ct4 = st[..., None, None], ct[..., None, None]
        sa4, ca4 = sa[..., None, None], ca[..., None, None]
        cp = st4 * sa4 * np.cos(phi) + ct4 * ca4
        wz = 2 * cp * ca4 - ct4
        with np.errstate(divide="ignore", invalid="ignore"):
            if mode == "I":
                gv = np.minimum(np.minimum(1.0 / wz, 2 * ca4 / cp), 2 * ca4 * ct4 / (cp * wz))
            elif mode == "R":
                gv = np.minimum(np.minimum(1.0 / ct4, 2 * ca4 / cp), 2 * ca4 * wz / (cp * ct4))
            else:
                raise ValueError(mode)
            f = Ps * reference_fresnel(cp, eta_b) * gv * 4 * cp
        f = np.where((wz > 0) & (cp > 0), f, 0.0)
        inner = 2.0 * np.sum(f * wphi, axis=(-1, -2))  # phi in [0, pi], doubled
        out[k0:k0 + 16] = np.sum(inner * wal, axis=-1)
    return out


@functools.lru_cache(maxsize=16)
def _spec_tables(brdf):
    """Cubic splines of S_I and S_R in theta (deg), denser towards grazing (error < 1e-7)."""
    grid = np.unique(np.concatenate([np.arange(0.0, 70.0, 0.5), np.arange(70.0, 89.0, 0.1),
                                     np.arange(89.0, 90.0, 0.005), [90.0]]))
    si = _spec_S(brdf, grid * DEG, "I", na=24, nphi=24)
    sr = _spec_S(brdf, grid * DEG, "R", na=24, nphi=24)
    return CubicSpline(grid, si), CubicSpline(grid, sr)


def _spec_interp(brdf, mode, cz):
    if float(brdf[1]) == 0.0:
        return np.zeros_like(cz)
    spl_i, spl_r = _spec_tables(tuple(float(v) for v in brdf))
    th = np.degrees(np.arccos(np.clip(cz, 0.0, 1.0)))
    return (spl_i if mode == "I" else spl_r)(th)


@functools.lru_cache(maxsize=64)
def _spec_total(brdf, mode="I", n=200):
    """J_s = Int Int f_s dI dR = 2 pi Int S(theta) sin(theta) dtheta, S computed directly."""
    if float(brdf[1]) == 0.0:
        return 0.0
    total = 0.0
    for lo, hi in ((0.0, 60.0), (60.0, 80.0), (80.0, 87.0), (87.0, 90.0)):
        t, w = _gl01(n // 4)
        th = (lo + (hi - lo) * t) * DEG
        total += 2 * math.pi * np.sum(w * (hi - lo) * DEG * np.sin(th) * _spec_S(brdf, th, mode))
    return float(total)


def _lobe_integral(g, theta_v, hfun, ns=96, npsi=64):
    """Int_{Omega+} p(g, V . X) h(X_z) dX for V at polar angle theta_v (radians).

    X about V: x = 1 - cos(gamma) and azimuth psi, X_z = cos(gamma) cos(theta_v) + sin(gamma)
    sin(theta_v) cos(psi). The x range is split where the hemisphere cut starts (gamma = 90 -
    theta_v) and ends (gamma = 90 + theta_v); psi runs exactly over the visible arc. For g
    away from 0 the variable s = ln((1 - g)^2 + 2 g x) makes p dx = (1+g)(1-g)/(8 pi g) e^{-s/2} ds.
    """
    st, ct = math.sin(theta_v), math.cos(theta_v)
    pieces = [(0.0, 1.0 - st, True), (1.0 - st, 1.0 + st, False)]
    tu, wu = _smoothstep_nodes(ns)
    total = 0.0
    for xa, xb, full in pieces:
        if xb <= xa:
            continue
        if abs(g) > 1e-3:
            sa_, sb_ = (math.log((1 - g) ** 2 + 2 * g * xa), math.log((1 - g) ** 2 + 2 * g * xb))
            s = sa_ + (sb_ - sa_) * tu
            x = (np.exp(s) - (1 - g) ** 2) / (2 * g)
            wx = (sb_ - sa_) * wu * (1 - g * g) / (8 * math.pi * g) * np.exp(-0.5 * s)
        else:
            x = xa + (xb - xa) * tu
            wx = (xb - xa) * wu * _hg_x(g, x)
        x = np.clip(x, 0.0, 2.0)
        mu = 1.0 - x
        sg = np.sqrt(np.clip(x * (2.0 - x), 0.0, None))
        # psi nodes crowd towards the horizon end, where h(X_z) may vary fast (S_I -> 0).
        tp, wp = _gl01(npsi) if full else _smoothstep_nodes(npsi)
        if full:
            pmax = np.full_like(x, math.pi)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                arg = np.where(sg * st > 0, -mu * ct / (sg * st), -1.0)
            pmax = np.arccos(np.clip(arg, -1.0, 1.0))
        psi = pmax[:, None] * tp[None, :]
        xz = np.clip(mu[:, None] * ct + sg[:, None] * st * np.cos(psi), 0.0, 1.0)
        inner = 2.0 * pmax * np.sum(wp * hfun(xz), axis=-1)
        total += float(np.sum(wx * inner))
    return total


def _lobe_with_check(g, theta_v, hfun, ns, npsi):
    v1 = _lobe_integral(g, theta_v, hfun, ns, npsi)
    v2 = _lobe_integral(g, theta_v, hfun, 2 * ns, 2 * npsi)
    return v2, abs(v2 - v1)


# ----------------------------------------------------------------------------------------
# The four-dimensional lobe-lobe specular integral K: MIS with scrambled Sobol points
# ----------------------------------------------------------------------------------------

def _frame(v):
    """Orthonormal t1, t2 with v (3,) as third axis."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(helper, v)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(v, t1)


def _sample_hg(g, axis, u1, u2):
    x = _hg_sample_x(g, u1)
    sg = np.sqrt(np.clip(x * (2.0 - x), 0.0, None))
    psi = 2 * math.pi * u2
    t1, t2 = _frame(axis)
    return ((1.0 - x)[:, None] * axis + (sg * np.cos(psi))[:, None] * t1
            + (sg * np.sin(psi))[:, None] * t2)


def _facet_c_z(n):
    c = n / DEG
    return c, -math.expm1(-(c * 0.5 * math.pi) ** 2)


def _sample_h(n, u1, u2):
    """H with alpha density 2 c^2 alpha exp(-c^2 alpha^2) / Z on [0, pi/2], uniform azimuth."""
    c, z = _facet_c_z(n)
    alpha = np.sqrt(-np.log1p(-u1 * z)) / c
    ph = 2 * math.pi * u2
    sa = np.sin(alpha)
    return np.stack([sa * np.cos(ph), sa * np.sin(ph), np.cos(alpha)], axis=-1)


def _pdf_h(n, h):
    """Density per steradian of :func:`_sample_h`."""
    c, z = _facet_c_z(n)
    sa = np.hypot(h[..., 0], h[..., 1])
    alpha = np.arctan2(sa, h[..., 2])
    ratio = np.where(alpha > 1e-12, alpha / np.where(alpha > 1e-12, sa, 1.0), 1.0)
    return c * c * ratio * np.exp(-(c * alpha) ** 2) / (math.pi * z)


def _reflect(v, h):
    return 2.0 * np.sum(v * h, axis=-1, keepdims=True) * h - v


def _k_batch(brdf, medium, variant, wi, wr, u, strategy, weighting="balance"):
    """Sum over one batch of f / (p1 + p2 + p3) for points u (N, 4) of one strategy.

    ``weighting="single"`` returns the sum of f / p_strategy instead (the strategy alone,
    also unbiased: every strategy covers the whole support; used to cross-check MIS).
    """
    _, Ps, n, eta_b = (float(v) for v in brdf)
    _, _, g, eta_u = (float(v) for v in medium)
    a, b = _fresnel_factors(eta_u, variant)
    if strategy == 0:      # I' ~ HG about I, H ~ facets, R' = mirror of I'
        ip = _sample_hg(g, wi, u[:, 0], u[:, 1])
        rp = _reflect(ip, _sample_h(n, u[:, 2], u[:, 3]))
    elif strategy == 1:    # R' ~ HG about R, H ~ facets, I' = mirror of R'
        rp = _sample_hg(g, wr, u[:, 0], u[:, 1])
        ip = _reflect(rp, _sample_h(n, u[:, 2], u[:, 3]))
    else:                  # both from their HG lobes
        ip = _sample_hg(g, wi, u[:, 0], u[:, 1])
        rp = _sample_hg(g, wr, u[:, 2], u[:, 3])
    ok = (ip[:, 2] > 0) & (rp[:, 2] > 0)
    ip, rp = ip[ok], rp[ok]
    ip /= np.linalg.norm(ip, axis=-1, keepdims=True)
    rp /= np.linalg.norm(rp, axis=-1, keepdims=True)
    xi = 0.5 * np.sum((ip - wi) ** 2, axis=-1)
    xr = 0.5 * np.sum((rp - wr) ** 2, axis=-1)
    hi_, hr_ = _hg_x(g, xi), _hg_x(g, xr)
    h = ip + rp
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    jac = _pdf_h(n, h) / (4.0 * np.sum(ip * h, axis=-1))
    pdfs = (hi_ * jac, hr_ * jac, hi_ * hr_)
    pdf = pdfs[0] + pdfs[1] + pdfs[2] if weighting == "balance" else pdfs[strategy]
    f = b(ip[:, 2]) * a(rp[:, 2]) * hi_ * hr_ * _fs_vec(Ps, n, eta_b, ip, rp)
    return float(np.sum(f / pdf))


def _k_mis(brdf, medium, variant, wi, wr, m, n_rep, seed, batch=1 << 16, only=None):
    """K by MIS over three strategies, 2^m scrambled Sobol points each, n_rep scrambles.

    ``only=k`` uses strategy k alone (no MIS), an independent unbiased estimate of K.
    """
    ss = np.random.SeedSequence(seed)
    reps = []
    for child in ss.spawn(n_rep):
        est = 0.0
        for strategy, sub in enumerate(child.spawn(3)):
            if only is not None and strategy != only:
                continue
            sob = qmc.Sobol(4, scramble=True, seed=np.random.default_rng(sub))
            pts = sob.random_base2(m)
            acc = 0.0
            for k0 in range(0, pts.shape[0], batch):
                acc += _k_batch(brdf, medium, variant, wi, wr, pts[k0:k0 + batch], strategy,
                                "balance" if only is None else "single")
            est += acc / pts.shape[0]
        reps.append(est)
    reps = np.array(reps)
    return float(reps.mean()), float(reps.std(ddof=1) / math.sqrt(n_rep)) if n_rep > 1 else math.inf


def _sample_cosine(u1, u2):
    r, ph = np.sqrt(u1), 2 * math.pi * u2
    return np.stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(np.clip(1 - u1, 0, None))], axis=-1)


def naive_apparent(brdf, medium, theta_i, phi_i, theta_r, phi_r, variant="paper", *,
                   m=18, n_rep=8, seed=0):
    """Eq. 1 by one plain 4D estimator of the full integrand, no expansion (cross-check).

    I' from an even mixture of the cosine density and the HG lobe about I; R' given I' from
    an even mixture of uniform, the HG lobe about R and the mirror of I' about a facet
    normal. Much noisier than :func:`reference_apparent`; returns (value, stderr).
    """
    Pd, Ps, n, eta_b = _params(brdf)
    Td, Tt, g, eta_u = _params(medium)
    a, b = _fresnel_factors(eta_u, variant)
    wi, wr = _dir(theta_i, phi_i), _dir(theta_r, phi_r)
    reps = []
    for child in np.random.SeedSequence(seed).spawn(n_rep):
        u = qmc.Sobol(7, scramble=True, seed=np.random.default_rng(child)).random_base2(m)
        ip = np.where((u[:, 0] < 0.5)[:, None], _sample_cosine(u[:, 1], u[:, 2]),
                      _sample_hg(g, wi, u[:, 1], u[:, 2]))
        k = np.minimum((u[:, 3] * 3).astype(int), 2)
        uni = np.stack([np.sqrt(1 - u[:, 5] ** 2) * np.cos(2 * math.pi * u[:, 4]),
                        np.sqrt(1 - u[:, 5] ** 2) * np.sin(2 * math.pi * u[:, 4]), u[:, 5]], -1)
        rp = np.where((k == 0)[:, None], uni, np.where((k == 1)[:, None],
                      _sample_hg(g, wr, u[:, 4], u[:, 5]),
                      _reflect(ip, _sample_h(n, u[:, 4], u[:, 5]))))
        ok = (ip[:, 2] > 0) & (rp[:, 2] > 0)
        ip, rp = ip[ok], rp[ok]
        ip /= np.linalg.norm(ip, axis=-1, keepdims=True)
        rp /= np.linalg.norm(rp, axis=-1, keepdims=True)
        hi_ = _hg_x(g, 0.5 * np.sum((ip - wi) ** 2, -1))
        hr_ = _hg_x(g, 0.5 * np.sum((rp - wr) ** 2, -1))
        h = ip + rp
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        q_i = 0.5 * ip[:, 2] / math.pi + 0.5 * hi_
        q_r = (1 / (2 * math.pi) + hr_ + _pdf_h(n, h) / (4 * np.sum(ip * h, -1))) / 3
        fti = Td + Tt * a(wi[2]) * b(ip[:, 2]) * hi_
        ftr = Td + Tt * a(rp[:, 2]) * b(wr[2]) * hr_
        fr = Pd * ip[:, 2] + _fs_vec(Ps, n, eta_b, ip, rp)
        reps.append(np.sum(fti * fr * ftr / (q_i * q_r)) / u.shape[0])
    reps = np.array(reps)
    return float(reps.mean()), float(reps.std(ddof=1) / math.sqrt(n_rep))


# ----------------------------------------------------------------------------------------
# Public entry points
# ----------------------------------------------------------------------------------------

def reference_terms(brdf, medium, theta_i, phi_i, theta_r, phi_r, variant="paper", *,
                    m=16, n_rep=16, seed=0, ns=64, npsi=48):
    """All pieces of the expansion in the module docstring for ONE configuration (degrees).

    Returns a dict: the four terms ("iso_iso", "iso_lobe", "lobe_iso", "lobe_lobe"), the
    building blocks (J_s, L_I, L_R, M_I, M_R, K), "value", and the error budget
    "stderr_K" (Monte Carlo, of K times its prefactor) and "quad_err" (deterministic parts,
    node-doubling differences).
    """
    brdf, medium = _params(brdf), _params(medium)
    Pd, Ps, n, eta_b = brdf
    Td, Tt, g, eta_u = medium
    a, b = _fresnel_factors(eta_u, variant)
    wi, wr = _dir(theta_i, phi_i), _dir(theta_r, phi_r)
    if not (0 <= theta_i < 90 and 0 <= theta_r < 90):
        raise ValueError("theta_i and theta_r must be in [0, 90) deg")
    ti, tr = theta_i * DEG, theta_r * DEG
    aI, bR = float(a(wi[2])), float(b(wr[2]))
    spec = Ps > 0 and eta_b != 1.0  # eta_b = 1: F = 0, no specular part at all

    js = _spec_total(brdf) if spec else 0.0
    js_err = abs(js - _spec_total(brdf, n=100)) if spec else 0.0
    L_R, eLR = _lobe_with_check(g, tr, a, ns, npsi)
    L_I, eLI = _lobe_with_check(g, ti, lambda z: b(z) * z, ns, npsi)
    if spec:
        M_R, eMR = _lobe_with_check(g, tr, lambda z: a(z) * _spec_interp(brdf, "R", z), ns, npsi)
        M_I, eMI = _lobe_with_check(g, ti, lambda z: b(z) * _spec_interp(brdf, "I", z), ns, npsi)
        if Tt > 0:
            K, sK = _k_mis(brdf, medium, variant, wi, wr, m, n_rep, seed)
        else:
            K, sK = 0.0, 0.0
    else:
        M_R = eMR = M_I = eMI = K = sK = 0.0

    t0 = Td * Td * (2 * math.pi ** 2 * Pd + js)
    t1 = Td * Tt * bR * (math.pi * Pd * L_R + M_R)
    t2 = Td * Tt * aI * (2 * math.pi * Pd * L_I + M_I)
    t3 = Tt * Tt * aI * bR * (Pd * L_I * L_R + K)
    quad = (Td * Td * js_err + Td * Tt * bR * (math.pi * Pd * eLR + eMR)
            + Td * Tt * aI * (2 * math.pi * Pd * eLI + eMI)
            + Tt * Tt * aI * bR * Pd * (eLI * L_R + L_I * eLR))
    return {"iso_iso": t0, "iso_lobe": t1, "lobe_iso": t2, "lobe_lobe": t3,
            "J_s": js, "L_I": L_I, "L_R": L_R, "M_I": M_I, "M_R": M_R, "K": K,
            "value": t0 + t1 + t2 + t3, "stderr_K": Tt * Tt * aI * bR * sK, "quad_err": quad}


def reference_apparent(brdf, medium, theta_i, phi_i, theta_r, phi_r, variant="paper", *,
                       m=16, n_rep=16, seed=0):
    """Apparent reflectance f(I, R) of docs/model.md sec. 5 and its standard error.

    brdf = (Pd, Ps, n, eta_b), medium = (Td, Tt, g, eta_u), angles in degrees (scalars or
    small arrays, broadcast). ``m``: 2^m Sobol points per strategy and scramble; ``n_rep``
    scrambles. The standard error combines the Monte Carlo error of K with the deterministic
    quadrature's node-doubling difference.
    """
    args = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in
                                 (theta_i, phi_i, theta_r, phi_r)))
    shape = args[0].shape
    vals, errs = [], []
    for ti, pi_, tr, pr in zip(*(x.ravel() for x in args)):
        t = reference_terms(brdf, medium, float(ti), float(pi_), float(tr), float(pr), variant,
                            m=m, n_rep=n_rep, seed=seed)
        vals.append(t["value"])
        errs.append(math.hypot(t["stderr_K"], t["quad_err"]))
    if shape == ():
        return vals[0], errs[0]
    return np.array(vals).reshape(shape), np.array(errs).reshape(shape)
