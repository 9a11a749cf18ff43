"""Independent reference for the physical models of docs/model.md sec. 8 (rough-plastic, rough-conductor,
forward-series medium, finite-plate view weighting J_v).

Written from docs/model.md (and the published formulas it names) alone, in numpy/scipy, sharing no code
with veil (nor with tests/reference.py). It is a checker: slow, simple, every piece verifiable
against another (see tests/test_reference_physical.py; derivations in docs/physics.md).

Conventions (docs/model.md sec. 1): local frame z = surface normal; I points from the surface to the
light, R to the camera; in-plane light at phi = 180 deg, camera at phi = 0; angles in DEGREES at the
public API; f_r includes cos(theta_i) (a pixel value per unit irradiance); integrals are over the
upper hemisphere in solid angle. Vector functions take unit vectors of shape (..., 3).

Public API (stable)
-------------------
BRDFs (angles in degrees, broadcast arrays; 0 unless both directions are above the surface)

    rough_plastic(theta_i, phi_i, theta_r, phi_r, rho, alpha, eta, ks=1.0,
                  distribution="beckmann", nonlinear=False, smith="exact", tables="exact")
    rough_conductor(theta_i, phi_i, theta_r, phi_r, alpha, ks=1.0, n=None, k=None, f0=None,
                    distribution="beckmann", smith="exact")
    make_rough_plastic(...), make_rough_conductor(...)  -> brdf_fn(wi, wo) on unit vectors
        (wi = I, the light; wo = R, the camera), with attribute ``sampling_alpha`` (a width hint
        used only to place quadrature nodes and importance samples, never in the value).

    smith="exact": Smith G1 in closed form (Beckmann erf form, GGX). smith="rational": Beckmann
    G1 by Walter et al. (2007)'s rational approximation, as Mitsuba 3 evaluates it.
    tables="exact": t(mu) and F_int as exact integrals (t interpolated by a verified spline).
    tables="mitsuba": t(mu) linearly interpolated from its values at mu_j = max(1e-6, j/63),
    F_int = (2/64) sum_j mu_j R_int(mu_j), as Mitsuba 3 tabulates them (docs/physics.md).

Rough-interface building blocks (mu = cos theta of the incident direction)

    rough_transmittance(mu, alpha, eta, distribution, smith)     t(mu)
    rough_reflectance(mu, alpha, eta, distribution, smith)       R(mu) (eta < 1: from inside)
    internal_reflectance(alpha, eta, distribution, smith, rule)  F_int (rule "exact"|"mitsuba")
    visible_normal_norm(mu, alpha, distribution)                 Int D_v(m) dm (= 1, Smith)
    microfacet_albedo(mu, alpha, distribution, smith)            F = 1 lobe albedo (furnace)

Fresnel

    fresnel_dielectric(cos_i, eta), fresnel_conductor(cos_i, n, k), fresnel_schlick(cos_i, f0)

Medium forward-series (docs/model.md 8.1)

    series_weights(tau, omega) -> w_k = (omega tau)^k / k!, k = 1..K (tail < 1e-17 of the sum)
    scattered_lobe(tau, omega, g, cos_gamma) -> L = sum_k w_k p(g^k, gamma)   (no e^-tau)
    hg(g, cos_gamma), hg_convolution(g1, g2, gamma_deg) -> (value, err)
    plate_weight(Rp, R, tau, path_length, plate_half_width)      J_v, docs/model.md's closed form
    plate_weight_direct(Rp, R, tau, path_length, plate_half_width, light=None)
                                                                 J_v by direct integration
    plate_weight_lit(Rp, R, light, tau, path_length, plate_half_width)
                                  J_v with the illumination path across the plate (vectorized)
    jv_table(...)                 the rows of docs/physics.md's J_v table
    forward_series_terms(brdf_fn, tau, omega, g, eta_u, theta_i, theta_r, phi_i=180, phi_r=0,
                         variant="paper", path_length=None, plate_half_width=None,
                         n_qmc=2**14, n_rep=8, seed=0, rtol=1e-7) -> dict
    forward_series_apparent(brdf_fn, tau, omega, g, eta_u, theta_i, theta_r, phi_i=180, phi_r=0,
                            variant="paper", path_length=None, plate_half_width=None,
                            n_qmc=2**14, n_rep=8, seed=0, scale=1.0) -> (value, stderr)

    The terms (all include e^{-2 tau} and the Fresnel factors of sec. 3):
      "direct"      delta-delta      a(I) b(I) a(R) b(R) f_r(I, R)                 closed form
      "view"        delta-lobe       a(I) b(I) b(R) Int f_r(I,R') a(R') Lv(R',R) dR'  2-D Gauss
      "illum"       lobe-delta       a(I) a(R) b(R) Int L(I,I') b(I') f_r(I',R) dI'   2-D Gauss
      "lobe_lobe"   lobe-lobe        a(I) b(R) Int Int L b f_r a Lv dI' dR'           4-D QMC+MIS
    with a = F_t^2, b = 1 ("paper") or a = b = F_t ("exit") at eta_u, and Lv = J_v L (J_v = 1
    without geometry). The 2-D terms come with "view_err"/"illum_err" (node-doubling
    differences), the 4-D one with "lobe_lobe_stderr" (independent scrambles);
    "view_mc"/"illum_mc" (+ "_stderr") are the same 2-D terms by an independent QMC estimator.
    path_length = R_c with plate_half_width = None is the infinite plate of the closed form
    (J_v = (1 - e^{-beta R_c})/(beta R_c), not 1); both None: J_v = 1 (no geometry).

Generic quadrature
    sphere_integral(fn, centres, scales, upper=True, ...) -> (value, err): Int fn(X) dX over
    the upper hemisphere (or the sphere) for integrands peaked at a few known centres.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.special import erf
from scipy.stats import qmc

DEG = math.pi / 180.0
SQRT_PI = math.sqrt(math.pi)
MITSUBA_TABLE_RES = 64  # Mitsuba 3: MI_ROUGH_TRANSMITTANCE_RES


# ----------------------------------------------------------------------------------------
# Small helpers
# ----------------------------------------------------------------------------------------

@functools.cache
def _gl01(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@functools.cache
def _ss01(n):
    """GL nodes on [0, 1] through s = 3t^2 - 2t^3 (tames sqrt-type end behaviour)."""
    t, w = _gl01(n)
    return 3 * t * t - 2 * t ** 3, w * 6 * t * (1 - t)


def direction(theta_deg, phi_deg):
    """Unit vector(s) (..., 3) from polar angle and azimuth in degrees."""
    t = np.asarray(theta_deg, float) * DEG
    p = np.asarray(phi_deg, float) * DEG
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a, b):
    return np.sum(a * b, axis=-1)


# ----------------------------------------------------------------------------------------
# Fresnel
# ----------------------------------------------------------------------------------------

def fresnel_dielectric(cos_i, eta):
    """Unpolarized Fresnel reflectance from index 1 into relative index eta (docs/model.md sec. 4).

    cos_i in [0, 1] (clipped). eta < 1 (incidence from the denser side): F = 1 beyond the
    critical angle. eta = 1: F = 0.
    """
    c = np.clip(np.asarray(cos_i, dtype=float), 0.0, 1.0)
    eta = float(eta)
    if eta == 1.0:
        return np.zeros_like(c)
    k = 1.0 - (1.0 - c * c) / (eta * eta)
    tir = k <= 0.0
    ct = np.sqrt(np.where(tir, 1.0, k))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    with np.errstate(invalid="ignore"):
        return np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def fresnel_conductor(cos_i, n, k):
    """Exact unpolarized Fresnel reflectance of a conductor of complex relative index n + i k.

    Complex Snell: w = eta cos_t = sqrt(eta^2 - sin^2) on the branch with Im w >= 0 (a wave
    decaying into the metal); r_s = (c - w)/(c + w), r_p = (eta^2 c - w)/(eta^2 c + w);
    F = (|r_s|^2 + |r_p|^2)/2. k = 0 gives the dielectric formula of docs/model.md sec. 4.
    """
    c = np.clip(np.asarray(cos_i, dtype=float), 0.0, 1.0).astype(complex)
    eta = complex(float(n), float(k))
    w = np.sqrt(eta * eta - (1.0 - c * c))
    w = np.where(w.imag < 0, -w, w)
    rs = (c - w) / (c + w)
    rp = (eta * eta * c - w) / (eta * eta * c + w)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def fresnel_schlick(cos_i, f0):
    """Schlick's approximation F0 + (1 - F0)(1 - c)^5."""
    c = np.clip(np.asarray(cos_i, dtype=float), 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


# ----------------------------------------------------------------------------------------
# Microfacet pieces
# ----------------------------------------------------------------------------------------

def _check_dist(distribution):
    if distribution not in ("beckmann", "ggx"):
        raise ValueError(f"distribution = {distribution!r}; expected 'beckmann' or 'ggx'")


def microfacet_D(cos_h, alpha, distribution="beckmann"):
    """Normal distribution D(H) per steradian of facet normals (docs/model.md 8.2); 0 for cos_h <= 0."""
    _check_dist(distribution)
    c = np.asarray(cos_h, dtype=float)
    ok = c > 0
    c2 = np.where(ok, c * c, 1.0)
    t2 = (1.0 - c2) / c2
    a2 = alpha * alpha
    if distribution == "beckmann":
        d = np.exp(-t2 / a2) / (math.pi * a2 * c2 * c2)
    else:
        d = 1.0 / (math.pi * a2 * c2 * c2 * (1.0 + t2 / a2) ** 2)
    return np.where(ok, d, 0.0)


def _g1_of_a(a, distribution, smith):
    """Smith G1 as a function of a = 1 / (alpha tan theta) >= 0 (a = inf: normal incidence)."""
    a = np.asarray(a, dtype=float)
    if distribution == "ggx":
        with np.errstate(divide="ignore"):
            inv2 = np.where(a > 0, 1.0 / np.where(a > 0, a * a, 1.0), np.inf)
        return 2.0 / (1.0 + np.sqrt(1.0 + inv2))
    if smith == "rational":
        # Walter, Marschner, Li, Torrance (2007), eq. 27: < 0.35 % from the exact form.
        b = np.minimum(a, 1.6)
        return np.where(a >= 1.6, 1.0, (3.535 * b + 2.181 * b * b) / (1.0 + 2.276 * b + 2.577 * b * b))
    if smith != "exact":
        raise ValueError(f"smith = {smith!r}; expected 'exact' or 'rational'")
    big = a > 8.0  # Lambda < 1e-29: G1 = 1 to double precision
    small = a <= 0.0
    aa = np.where(big | small, 1.0, a)
    g = 2.0 / (1.0 + erf(aa) + np.exp(-aa * aa) / (aa * SQRT_PI))
    return np.where(big, 1.0, np.where(small, 0.0, g))


def smith_g1(v, m, alpha, distribution="beckmann", smith="exact"):
    """Smith's masking G1(v, m) for unit vectors v (any side) and facet normals m.

    0 when v sees the back of the facet ((v.m)(v.z) <= 0). GGX ignores ``smith``.
    """
    _check_dist(distribution)
    vz = v[..., 2]
    sxy = np.sqrt(np.clip(v[..., 0] ** 2 + v[..., 1] ** 2, 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(sxy > 0, np.abs(vz) / (alpha * np.where(sxy > 0, sxy, 1.0)), np.inf)
    g = _g1_of_a(a, distribution, smith)
    return np.where(_dot(v, m) * vz > 0, g, 0.0)


# ----------------------------------------------------------------------------------------
# Integrals over visible normals (rough interface tables)
# ----------------------------------------------------------------------------------------

def _vn_integral(theta, alpha, distribution, kind, eta=1.0, smith="exact", n=32):
    """Int D_v(m) h(m) dm for v = (sin theta, 0, cos theta), theta in radians.

    D_v(m) = G1(v) max(0, v.m) D(m) / cos theta (distribution of visible normals, G1(v)
    exact). h by ``kind``: "norm" 1; "T" (1 - F(v.m, eta)) G1(w_t, m), w_t the refracted
    direction (below); "R" F(v.m, eta) G1(w_r, m) [w_r above], w_r the mirror of v about m;
    "R1" the same with F = 1. In slope space s = r (cos phi, sin phi), m = (-s, 1)/|(-s, 1)|:
    (v.m)^+ D(m) dm = (cos theta - r sin theta cos phi)^+ P22(s) d^2 s. r = alpha tan(psi);
    psi is split where a phi cut (visibility, w_r horizon, total internal reflection) enters
    or leaves [0, pi], phi at the cuts; Gauss-Legendre with smoothstep nodes on each piece.
    """
    _check_dist(distribution)
    st, ct = math.sin(theta), math.cos(theta)
    st = max(st, 1e-12)
    rb = [ct / st]
    if kind in ("R", "R1"):
        rb += [(1.0 - st) / ct, (1.0 + st) / ct]
    c_crit = None
    if kind in ("R", "T") and eta < 1.0:
        A = math.asin(eta)
        c_crit = math.cos(A)
        for tm in (theta + A, theta - A, A - theta):
            if 0.0 < tm < 0.5 * math.pi:
                rb.append(math.tan(tm))
    psi_max = 0.5 * math.pi if distribution == "ggx" else math.atan(7.0)
    pb = sorted({0.0, psi_max} | {math.atan(r / alpha) for r in rb if 0.0 < r / alpha < math.tan(psi_max)})
    tq, wq = _ss01(n)
    psi = np.concatenate([lo + (hi - lo) * tq for lo, hi in zip(pb[:-1], pb[1:])])
    wpsi = np.concatenate([(hi - lo) * wq for lo, hi in zip(pb[:-1], pb[1:])])
    u = np.tan(psi)
    if distribution == "beckmann":  # P22 r dr = e^{-u^2} u du / pi, du = (1 + u^2) dpsi
        wr_ = wpsi * np.exp(-u * u) * u * (1 + u * u) / math.pi
    else:  # P22 r dr = sin(psi) cos(psi) dpsi / pi
        wr_ = wpsi * np.sin(psi) * np.cos(psi) / math.pi
    r = alpha * u
    # phi cuts (cos phi thresholds) per radial node
    with np.errstate(divide="ignore", invalid="ignore"):
        cuts = [ct / (st * r)]
        if kind in ("R", "R1"):
            cuts.append(ct * (1.0 - r * r) / (2.0 * r * st))
        if c_crit is not None:
            cuts.append((ct - c_crit * np.sqrt(1.0 + r * r)) / (r * st))
    phis = [np.arccos(np.clip(np.nan_to_num(c, nan=1.0, posinf=1.0, neginf=-1.0), -1.0, 1.0))
            for c in cuts]
    bounds = np.sort(np.stack([np.zeros_like(r)] + phis + [np.full_like(r, math.pi)], axis=-1), axis=-1)
    lo, hi = bounds[:, :-1, None], bounds[:, 1:, None]  # (Nr, P, 1)
    tp, wp = _ss01(n)
    phi = lo + (hi - lo) * tp
    wphi = (hi - lo) * wp
    rr = r[:, None, None]
    sx, sy = rr * np.cos(phi), rr * np.sin(phi)
    proj = ct - st * sx  # (v.m) |(-s, 1)|
    norm = np.sqrt(1.0 + rr * rr)
    m = np.stack([-sx / norm, -sy / norm, np.broadcast_to(1.0 / norm, sx.shape)], axis=-1)
    v = np.array([st, 0.0, ct])
    c = proj / norm
    vis = proj > 0
    if kind == "norm":
        h = np.ones_like(c)
    elif kind == "T":
        F = fresnel_dielectric(c, eta)
        k = 1.0 - (1.0 - c * c) / (eta * eta)
        cos_t = np.sqrt(np.clip(k, 0.0, None))
        wt = -v / eta + ((c / eta) - cos_t)[..., None] * m
        wt = _normalize(wt)
        h = (1.0 - F) * smith_g1(wt, m, alpha, distribution, smith)
        h = np.where(wt[..., 2] < 0, h, 0.0)
    elif kind in ("R", "R1"):
        wr = 2.0 * c[..., None] * m - v
        F = fresnel_dielectric(c, eta) if kind == "R" else 1.0
        h = F * smith_g1(wr, m, alpha, distribution, smith)
        h = np.where(wr[..., 2] > 0, h, 0.0)
    else:
        raise ValueError(kind)
    a_v = ct / (alpha * st)
    g1v = float(_g1_of_a(np.array(a_v), distribution, "exact"))
    inner = 2.0 * np.sum(np.where(vis, proj * h, 0.0) * wphi, axis=(-1, -2))
    return g1v / ct * float(np.sum(inner * wr_))


def _vn(mu, alpha, distribution, kind, eta=1.0, smith="exact", n=32, check=False):
    mu = np.atleast_1d(np.asarray(mu, dtype=float))
    th = np.arccos(np.clip(np.maximum(mu, 1e-6), 0.0, 1.0))
    vals = np.array([_vn_integral(t, alpha, distribution, kind, eta, smith, n) for t in th])
    if check:
        vals2 = np.array([_vn_integral(t, alpha, distribution, kind, eta, smith, 2 * n) for t in th])
        return vals2, np.abs(vals2 - vals)
    return vals


def rough_transmittance(mu, alpha, eta, distribution="beckmann", smith="exact", n=48, check=False):
    """t(mu): Int over visible normals of (1 - F(v.m)) G1(w_t, m), from outside (docs/model.md 8.2).

    mu is clamped to >= 1e-6. ``check=True`` returns (value at 2n nodes, |2n - n| difference).
    """
    return _vn(mu, alpha, distribution, "T", eta, smith, n, check)


def rough_reflectance(mu, alpha, eta, distribution="beckmann", smith="exact", n=48, check=False):
    """R(mu): Int over visible normals of F(v.m, eta) G1(w_r, m) [w_r above] (eta < 1: inside)."""
    return _vn(mu, alpha, distribution, "R", eta, smith, n, check)


def visible_normal_norm(mu, alpha, distribution="beckmann", n=32):
    """Int D_v(m) dm; exactly 1 with the exact Smith G1 (the Smith normalization identity)."""
    return _vn(mu, alpha, distribution, "norm", 1.0, "exact", n)


def microfacet_albedo(mu, alpha, distribution="beckmann", smith="exact", n=32):
    """Directional albedo of the Smith microfacet lobe with F = 1 (white furnace):
    Int D(H) G1(V,H) G1(W,H) / (4 cos theta_V) dW = Int D_v(m) G1(w_r, m) dm <= 1."""
    return _vn(mu, alpha, distribution, "R1", 1.0, smith, n)


@functools.lru_cache(maxsize=64)
def internal_reflectance(alpha, eta, distribution="beckmann", smith="exact", rule="exact", n=48):
    """F_int: cosine-weighted hemispherical reflectance of the rough interface from inside,
    2 Int_0^1 R(mu; 1/eta) mu dmu (rule "exact": Gauss-Legendre split at the critical cosine)
    or (2/64) sum_j mu_j R(mu_j; 1/eta), mu_j = max(1e-6, j/63) (rule "mitsuba", Mitsuba 3's
    estimate of the same integral)."""
    ieta = 1.0 / float(eta)
    if rule == "mitsuba":
        mu = np.maximum(1e-6, np.linspace(0.0, 1.0, MITSUBA_TABLE_RES))
        return float(2.0 * np.mean(mu * rough_reflectance(mu, alpha, ieta, distribution, smith)))
    if rule != "exact":
        raise ValueError(f"rule = {rule!r}")
    brk = [0.0, 1.0]
    if ieta < 1.0:
        brk.insert(1, math.sqrt(1.0 - ieta * ieta))
    tq, wq = _ss01(n)
    total = 0.0
    for lo, hi in zip(brk[:-1], brk[1:]):
        mu = lo + (hi - lo) * tq
        total += float(np.sum((hi - lo) * wq * 2.0 * mu * rough_reflectance(mu, alpha, ieta, distribution, smith, n=32)))
    return total


def _t_grid(alpha):
    """theta grid (deg) for the t(mu) spline: dense towards grazing, spacing ~ alpha/16 there."""
    step = min(0.25, alpha / DEG / 16.0)
    g = np.concatenate([np.linspace(0.0, 60.0, 49), np.linspace(60.0, 84.0, 49),
                        np.arange(84.0, 90.0, max(step, 0.01)), [89.9, 89.95, 89.99, 90.0]])
    return np.unique(g)


@functools.lru_cache(maxsize=64)
def _t_spline(alpha, eta, distribution, smith):
    grid = _t_grid(alpha)
    vals = rough_transmittance(np.cos(grid * DEG), alpha, eta, distribution, smith)
    return CubicSpline(grid, vals)


@functools.lru_cache(maxsize=64)
def _t_mitsuba_nodes(alpha, eta, distribution, smith):
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, MITSUBA_TABLE_RES))
    return rough_transmittance(mu, alpha, eta, distribution, smith)


def transmittance_lookup(mu, alpha, eta, distribution="beckmann", smith="exact", tables="exact"):
    """t(mu) as rough_plastic uses it: verified spline ("exact") or Mitsuba's lerp table."""
    mu = np.clip(np.asarray(mu, dtype=float), 0.0, 1.0)
    key = (float(alpha), float(eta), distribution, smith)
    if tables == "exact":
        return _t_spline(*key)(np.degrees(np.arccos(mu)))
    if tables != "mitsuba":
        raise ValueError(f"tables = {tables!r}; expected 'exact' or 'mitsuba'")
    data = _t_mitsuba_nodes(*key)
    x = mu * (MITSUBA_TABLE_RES - 1)
    idx = np.minimum(x.astype(int), MITSUBA_TABLE_RES - 2)
    w = x - idx
    return (1.0 - w) * data[idx] + w * data[idx + 1]


# ----------------------------------------------------------------------------------------
# BRDFs
# ----------------------------------------------------------------------------------------

def _specular(wi, wo, alpha, distribution, smith, fresnel):
    """F(R.H) D(H) G1(I,H) G1(R,H) / (4 cos theta_r); wi = I, wo = R; 0 unless both above."""
    ci, co = wi[..., 2], wo[..., 2]
    ok = (ci > 0) & (co > 0)
    h = _normalize(wi + wo)
    g = smith_g1(wi, h, alpha, distribution, smith) * smith_g1(wo, h, alpha, distribution, smith)
    val = fresnel(_dot(wo, h)) * microfacet_D(h[..., 2], alpha, distribution) * g
    with np.errstate(divide="ignore", invalid="ignore"):
        val = val / (4.0 * co)
    return np.where(ok, val, 0.0)


def rough_plastic_vec(wi, wo, rho, alpha, eta, ks=1.0, distribution="beckmann", nonlinear=False,
                      smith="exact", tables="exact"):
    """rough-plastic f_r(I, R) of docs/model.md 8.2 on unit vectors wi = I, wo = R (..., 3)."""
    _check_dist(distribution)
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    ci, co = wi[..., 2], wo[..., 2]
    ok = (ci > 0) & (co > 0)
    spec = ks * _specular(wi, wo, alpha, distribution, smith, lambda c: fresnel_dielectric(c, eta))
    fint = internal_reflectance(float(alpha), float(eta), distribution, smith,
                                "mitsuba" if tables == "mitsuba" else "exact")
    rho_eff = rho / (1.0 - (rho * fint if nonlinear else fint))
    ti = transmittance_lookup(np.clip(ci, 0, 1), alpha, eta, distribution, smith, tables)
    to = transmittance_lookup(np.clip(co, 0, 1), alpha, eta, distribution, smith, tables)
    diff = rho_eff * ti * to * ci / (math.pi * eta * eta)
    return np.where(ok, spec + diff, 0.0)


def rough_plastic(theta_i, phi_i, theta_r, phi_r, rho, alpha, eta, ks=1.0, distribution="beckmann",
                  nonlinear=False, smith="exact", tables="exact"):
    """rough-plastic f_r(I, R) (docs/model.md 8.2), angles in degrees (broadcast)."""
    return rough_plastic_vec(direction(theta_i, phi_i), direction(theta_r, phi_r), rho, alpha, eta,
                             ks, distribution, nonlinear, smith, tables)


def _conductor_fresnel(n, k, f0):
    if f0 is not None:
        if n is not None or k is not None:
            raise ValueError("give either (n, k) or f0, not both")
        return lambda c: fresnel_schlick(c, f0)
    if n is None:
        raise ValueError("give (n, k) or f0")
    return lambda c: fresnel_conductor(c, n, 0.0 if k is None else k)


def rough_conductor_vec(wi, wo, alpha, ks=1.0, n=None, k=None, f0=None, distribution="beckmann",
                        smith="exact"):
    """rough-conductor f_r(I, R) of docs/model.md 8.3 on unit vectors (complex index or Schlick F0)."""
    _check_dist(distribution)
    return ks * _specular(np.asarray(wi, float), np.asarray(wo, float), alpha, distribution, smith,
                          _conductor_fresnel(n, k, f0))


def rough_conductor(theta_i, phi_i, theta_r, phi_r, alpha, ks=1.0, n=None, k=None, f0=None,
                    distribution="beckmann", smith="exact"):
    """rough-conductor f_r(I, R) (docs/model.md 8.3), angles in degrees (broadcast)."""
    return rough_conductor_vec(direction(theta_i, phi_i), direction(theta_r, phi_r), alpha, ks, n,
                               k, f0, distribution, smith)


def make_rough_plastic(rho, alpha, eta, ks=1.0, distribution="beckmann", nonlinear=False,
                       smith="exact", tables="exact"):
    """brdf_fn(wi, wo) for :func:`forward_series_apparent` (wi = I, wo = R, unit vectors)."""
    def fn(wi, wo):
        return rough_plastic_vec(wi, wo, rho, alpha, eta, ks, distribution, nonlinear, smith, tables)
    fn.sampling_alpha = float(alpha)
    return fn


def make_rough_conductor(alpha, ks=1.0, n=None, k=None, f0=None, distribution="beckmann",
                         smith="exact"):
    def fn(wi, wo):
        return rough_conductor_vec(wi, wo, alpha, ks, n, k, f0, distribution, smith)
    fn.sampling_alpha = float(alpha)
    return fn


# ----------------------------------------------------------------------------------------
# Henyey-Greenstein and the forward series
# ----------------------------------------------------------------------------------------

def hg(g, cos_gamma):
    """HG phase function with its 1/(4 pi) (docs/model.md sec. 3)."""
    mu = np.asarray(cos_gamma, dtype=float)
    return (1.0 - g * g) / (4.0 * math.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def _hg_x(g, x):
    """HG as a function of x = 1 - cos(gamma) (no cancellation near gamma = 0)."""
    d = (1.0 - g) ** 2 + 2.0 * g * x
    return (1.0 - g * g) / (4.0 * math.pi * d * np.sqrt(d))


def _hg_sample_x(g, u):
    """Inverse of the HG cone fraction P(x): x = (1 - g)^2 u (1 + g + q) / q^2, q = 1 + g - 2 g u."""
    q = 1.0 + g - 2.0 * g * u
    return (1.0 - g) ** 2 * u * (1.0 + g + q) / (q * q)


def series_weights(tau, omega, rel_tail=1e-17):
    """w_k = (omega tau)^k / k!, k = 1..K, with the dropped tail below rel_tail of e^{omega tau}."""
    x = float(omega) * float(tau)
    if x <= 0.0:
        return np.zeros(0)
    w, k, term = [], 1, 1.0
    target = rel_tail * math.exp(x)
    while True:
        term *= x / k
        w.append(term)
        # tail after k is < term * x/(k+1) / (1 - x/(k+2)) once k + 2 > x
        if k + 2 > 2 * x and term * x / (k + 1) * 2 < target:
            break
        k += 1
    return np.array(w)


def scattered_lobe(tau, omega, g, cos_gamma=None, x=None):
    """L = sum_{k>=1} w_k p(g^k, gamma) (docs/model.md 8.1, the bracket without delta and e^{-tau}).
    Give cos_gamma, or x = 1 - cos_gamma (more accurate near gamma = 0)."""
    if x is None:
        x = 1.0 - np.asarray(cos_gamma, dtype=float)
    x = np.asarray(x, dtype=float)
    out = np.zeros_like(x)
    for k, wk in enumerate(series_weights(tau, omega), start=1):
        out = out + wk * _hg_x(g ** k, x)
    return out


# ----------------------------------------------------------------------------------------
# Generic quadrature over the (hemi)sphere for integrands peaked at known centres
# ----------------------------------------------------------------------------------------

def _frame_about(c):
    c = np.asarray(c, float)
    sxy = math.hypot(c[0], c[1])
    if sxy < 1e-12:
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    e1 = np.array([0.0, 0.0, 1.0]) - c[2] * c
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(c, e1)


def _part_nodes(c, eps, upper, n_rad, n_az):
    """Nodes X (N, 3) and weights (N,) for an integral about centre c, radial variable
    s = ln(x + eps), x = 1 - cos(angle to c), split at the horizon's entry/exit; azimuth by the
    trapezoid rule on full circles, smoothstep Gauss-Legendre on the visible arcs."""
    c = np.asarray(c, float)
    e1, e2 = _frame_about(c)
    stc = math.hypot(c[0], c[1])
    if upper:
        pieces = [(0.0, 1.0 - stc, True), (1.0 - stc, 1.0 + stc, False)]
    else:
        pieces = [(0.0, 2.0, True)]
    tq, wq = _ss01(n_rad)
    Xs, Ws = [], []
    for xa, xb, full in pieces:
        if xb - xa <= 1e-15:
            continue
        sa, sb = math.log(xa + eps), math.log(xb + eps)
        s = sa + (sb - sa) * tq
        x = np.clip(np.exp(s) - eps, 0.0, 2.0)
        wx = (sb - sa) * wq * np.exp(s)
        cg = 1.0 - x
        sg = np.sqrt(np.clip(x * (2.0 - x), 0.0, None))
        if full:
            psi = 2 * math.pi * (np.arange(n_az) + 0.5) / n_az
            psi = np.broadcast_to(psi, (x.size, n_az))
            wpsi = np.full((x.size, n_az), 2 * math.pi / n_az)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                arg = np.where(sg * stc > 0, -cg * c[2] / (sg * stc), -1.0)
            pmax = np.arccos(np.clip(arg, -1.0, 1.0))[:, None]
            tp, wp = _ss01(n_az)
            tt = np.concatenate([-tp[::-1], tp])
            ww = np.concatenate([wp[::-1], wp])
            psi = pmax * tt
            wpsi = pmax * ww
        X = (cg[:, None, None] * c + (sg[:, None] * np.cos(psi))[..., None] * e1
             + (sg[:, None] * np.sin(psi))[..., None] * e2)
        Xs.append(X.reshape(-1, 3))
        Ws.append((wx[:, None] * wpsi).reshape(-1))
    return np.concatenate(Xs), np.concatenate(Ws)


def _sphere_once(fn, centres, scales, upper, n_rad, n_az, q):
    total = 0.0
    for j, (c, eps) in enumerate(zip(centres, scales)):
        X, W = _part_nodes(c, eps, upper, n_rad, n_az)
        if upper:
            keep = X[:, 2] > 0
            X, W = X[keep], W[keep]
        X = _normalize(X)
        if len(centres) > 1:
            xj = np.clip(1.0 - X @ np.asarray(c), 0.0, None)
            s = np.zeros(X.shape[0])
            for cc in centres:
                xk = np.clip(1.0 - X @ np.asarray(cc), 0.0, None)
                with np.errstate(divide="ignore", invalid="ignore"):
                    s = s + np.where(xk > 0, (xj / np.where(xk > 0, xk, 1.0)) ** q, np.where(xj > 0, np.inf, 1.0))
            wpart = 1.0 / s
        else:
            wpart = 1.0
        total += float(np.sum(W * wpart * fn(X)))
    return total


def sphere_integral(fn, centres, scales, upper=True, n_rad=32, n_az=32, q=3, rtol=1e-7, atol=0.0,
                    max_level=3):
    """Int fn(X) dX over the upper hemisphere (upper=True) or the sphere; fn vectorized on (N, 3).

    The integrand is split by a partition of unity w_j = x_j^-q / sum_k x_k^-q (x_j = 1 - X.c_j)
    into parts each peaked at one centre c_j only, each integrated in polar coordinates about
    its centre with the radial variable ln(x + scale_j). Node counts double until successive
    results differ by <= rtol |value| + atol (at most ``max_level`` doublings). Returns
    (value, |last difference|).
    """
    cs, ss = [], []
    for c, e in zip(centres, scales):  # merge coincident centres
        c = np.asarray(c, float) / np.linalg.norm(c)
        dup = [i for i, cc in enumerate(cs) if 1.0 - float(cc @ c) < 1e-14]
        if dup:
            ss[dup[0]] = min(ss[dup[0]], e)
        else:
            cs.append(c)
            ss.append(float(e))
    prev = _sphere_once(fn, cs, ss, upper, n_rad, n_az, q)
    err = math.inf
    for _ in range(max_level):
        n_rad, n_az = 2 * n_rad, 2 * n_az
        cur = _sphere_once(fn, cs, ss, upper, n_rad, n_az, q)
        err = abs(cur - prev)
        prev = cur
        if err <= rtol * abs(cur) + atol:
            break
    return prev, err


def hg_convolution(g1, g2, gamma_deg, rtol=1e-10):
    """Int_{S^2} p(g1; A.X) p(g2; X.B) dX for A.B = cos(gamma), by quadrature (-> p(g1 g2; A.B))."""
    A = np.array([0.0, 0.0, 1.0])
    B = direction(gamma_deg, 0.0)
    eps = [max((1 - g) ** 2 / (2 * abs(g)), 1e-12) if g != 0 else 1.0 for g in (g1, g2)]

    def fn(X):
        return _hg_x(g1, 1.0 - X @ A) * _hg_x(g2, 1.0 - X @ B)
    return sphere_integral(fn, [A, B], eps, upper=False, n_rad=48, n_az=48, rtol=rtol, max_level=4)


# ----------------------------------------------------------------------------------------
# Finite-plate view weighting J_v (docs/model.md 8.1; derivation in docs/physics.md)
# ----------------------------------------------------------------------------------------

def _phi1(x):
    """(1 - e^{-x}) / x, 1 at x = 0."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-8
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - 0.5 * x, -np.expm1(-xs) / xs)


def plate_weight(Rp, R, tau, path_length, plate_half_width=None):
    """J_v(R', R) in docs/model.md's closed form (prototype):
    (1 - e^{-beta S}) / (beta R_c), beta = sigma_t (mu_R/mu_R' - 1), sigma_t = tau / R_c,
    S = min(R_c, a / max(|v_x|, |v_y|)), v = R - (mu_R/mu_R') R'. plate_half_width None: a = inf.
    0 where R' is not above the surface."""
    Rp, R = np.asarray(Rp, float), np.asarray(R, float)
    Rc = float(path_length)
    mup = Rp[..., 2]
    ok = mup > 0
    ratio = R[..., 2] / np.where(ok, mup, 1.0)
    beta = (tau / Rc) * (ratio - 1.0)
    if plate_half_width is None:
        S = np.full_like(ratio, Rc)
    else:
        v = R - ratio[..., None] * Rp
        vm = np.maximum(np.abs(v[..., 0]), np.abs(v[..., 1]))
        with np.errstate(divide="ignore"):
            S = np.minimum(Rc, np.where(vm > 0, float(plate_half_width) / np.where(vm > 0, vm, 1.0), np.inf))
    return np.where(ok, (S / Rc) * _phi1(beta * S), 0.0)


def _cylinder_path(Q, d, Rc):
    """Distance from Q (on the plate, z = 0) along d to the cylinder x^2 + z^2 = Rc^2."""
    a2 = d[0] ** 2 + d[2] ** 2
    b = Q[0] * d[0] + Q[2] * d[2]
    cq = Q[0] ** 2 + Q[2] ** 2 - Rc * Rc
    return (-b + math.sqrt(b * b - a2 * cq)) / a2


def plate_weight_direct(Rp, R, tau, path_length, plate_half_width=None, light=None, n=64):
    """J_v by direct single-scattering integration along the view ray (one direction pair).

    A point P = s R (0 <= s <= s_wall, s_wall where the view ray meets the cylinder of radius
    R_c about the y axis) scatters into R light that left the plate along R' from
    Q = P - t R', t = s mu_R / mu_R' (Q.z = 0). Q must lie in the square |x|, |y| <= a (tested
    pointwise; the end of the lit range is located by bisection on that test, not by formula).
    Extra attenuation relative to the straight path: e^{-sigma_t (t + (s_wall - s) - R_c)}.
    light (unit vector I, optional): also weight by the unscattered illumination reaching Q
    relative to the centre, e^{-sigma_t (l(Q) - R_c)}, l(Q) the path from the cylinder wall to
    Q along -I (this is what the closed form assumes uniform). Returns J_v (scalar).
    """
    Rp, R = np.asarray(Rp, float), np.asarray(R, float)
    Rc = float(path_length)
    sig = tau / Rc
    if Rp[2] <= 0:
        return 0.0
    s_wall = _cylinder_path(np.zeros(3), R, Rc)

    def on_plate(s):
        Q = s * R - (s * R[2] / Rp[2]) * Rp
        return plate_half_width is None or (abs(Q[0]) <= plate_half_width and abs(Q[1]) <= plate_half_width)

    if on_plate(s_wall):
        s_end = s_wall
    else:
        lo, hi = 0.0, s_wall
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if on_plate(mid) else (lo, mid)
        s_end = lo
    t, w = _gl01(n)
    total = 0.0
    for a_, b_ in ((0.0, 0.5 * s_end), (0.5 * s_end, s_end)):
        s = a_ + (b_ - a_) * t
        path = s * R[2] / Rp[2] + (s_wall - s)
        f = np.exp(-sig * (path - Rc))
        if light is not None:
            Q = s[:, None] * R - (s * R[2] / Rp[2])[:, None] * Rp
            li = np.array([_cylinder_path(q, np.asarray(light, float), Rc) for q in Q])
            f = f * np.exp(-sig * (li - Rc))
        total += float(np.sum((b_ - a_) * w * f))
    return total / Rc


# ----------------------------------------------------------------------------------------
# The forward-series apparent reflectance
# ----------------------------------------------------------------------------------------

def _fresnel_ab(eta_u, variant):
    if variant not in ("paper", "exit"):
        raise ValueError(f"variant = {variant!r}; expected 'paper' or 'exit'")

    def ft(cz):
        return 1.0 - fresnel_dielectric(np.clip(cz, 0, 1), eta_u)

    def a(cz):
        t = ft(cz)
        return t * t if variant == "paper" else t

    def b(cz):
        return np.ones_like(np.asarray(cz, float)) if variant == "paper" else ft(cz)
    return a, b


def _mirror(v):
    return np.array([-v[0], -v[1], v[2]])


def _lobe_scale(g):
    return (1 - g) ** 2 / (2 * g) if g > 0.05 else 1.0


def _brdf_scale(brdf_fn):
    a = float(getattr(brdf_fn, "sampling_alpha", 0.02))
    return max(0.5 * a * a, 1e-8)


def _view_weight(Rp, R, tau, path_length, plate_half_width):
    if path_length is None:
        if plate_half_width is not None:
            raise ValueError("plate_half_width needs path_length (the cylinder radius R_c)")
        return np.ones(Rp.shape[:-1])
    return plate_weight(Rp, R, tau, path_length, plate_half_width)


def _term_view_gauss(brdf_fn, I, R, tau, omega, g, a, Jargs, rtol):
    """Int f_r(I, X) a(X_z) J_v(X, R) L(X, R) dX by :func:`sphere_integral`."""
    def fn(X):
        return (brdf_fn(np.broadcast_to(I, X.shape), X) * a(X[:, 2])
                * _view_weight(X, R, tau, *Jargs) * scattered_lobe(tau, omega, g, x=1.0 - X @ R))
    return sphere_integral(fn, [R, _mirror(I)], [_lobe_scale(g), _brdf_scale(brdf_fn)], rtol=rtol)


def _term_illum_gauss(brdf_fn, I, R, tau, omega, g, b, rtol):
    """Int L(I, X) b(X_z) f_r(X, R) dX."""
    def fn(X):
        return scattered_lobe(tau, omega, g, x=1.0 - X @ I) * b(X[:, 2]) * brdf_fn(X, np.broadcast_to(R, X.shape))
    return sphere_integral(fn, [I, _mirror(R)], [_lobe_scale(g), _brdf_scale(brdf_fn)], rtol=rtol)


# --- sampling ------------------------------------------------------------------------------

def _frame_t(v):
    helper = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(helper, v)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(v, t1)


def _sample_lobe(tau, omega, g, axis, u0, u1, u2):
    """X ~ L(X . axis) / sum w (order k by u0, then HG(g^k) about axis)."""
    w = series_weights(tau, omega)
    cdf = np.cumsum(w) / np.sum(w)
    k = np.minimum(np.searchsorted(cdf, u0, side="right"), len(w) - 1) + 1
    gk = g ** k.astype(float)
    x = _hg_sample_x(gk, u1)
    sg = np.sqrt(np.clip(x * (2.0 - x), 0.0, None))
    psi = 2 * math.pi * u2
    t1, t2 = _frame_t(axis)
    return ((1.0 - x)[:, None] * axis + (sg * np.cos(psi))[:, None] * t1 + (sg * np.sin(psi))[:, None] * t2)


def _pdf_lobe(tau, omega, g, axis, X):
    return scattered_lobe(tau, omega, g, x=np.clip(1.0 - X @ axis, 0.0, 2.0)) / np.sum(series_weights(tau, omega))


def _sample_ggx_h(alpha, u1, u2):
    """H ~ D_GGX(H) cos(theta_H) (normalized on the hemisphere)."""
    t2 = alpha * alpha * u1 / np.maximum(1.0 - u1, 1e-300)
    ct = 1.0 / np.sqrt(1.0 + t2)
    st = np.sqrt(np.clip(1.0 - ct * ct, 0.0, None))
    ph = 2 * math.pi * u2
    return np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=-1)


def _pdf_mirror(alpha, V, X):
    """Density of X = mirror of V about H ~ D_GGX cos (either orientation of the half vector)."""
    h = _normalize(V + X)
    hz = np.abs(h[..., 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        p = microfacet_D(hz, alpha, "ggx") * hz / (4.0 * np.abs(_dot(V, h)))
    return np.nan_to_num(p, nan=0.0, posinf=0.0)


def _reflect(v, h):
    return 2.0 * _dot(v, h)[..., None] * h - v


def _sample_cosine(u1, u2):
    r, ph = np.sqrt(u1), 2 * math.pi * u2
    return np.stack([r * np.cos(ph), r * np.sin(ph), np.sqrt(np.clip(1 - u1, 0, None))], axis=-1)


def _sampling_alpha(brdf_fn):
    return max(float(getattr(brdf_fn, "sampling_alpha", 0.05)), 1e-3)


def _term_2d_mc(brdf_fn, fixed, centre, tau, omega, g, side, a_or_b, Jfun, n_qmc, n_rep, seed):
    """The 2-D term by QMC, multi-sample MIS (balance) over: X ~ lobe about centre; X = mirror
    of the fixed direction about a GGX facet; X ~ cosine. side "view": f_r(fixed, X); "illum":
    f_r(X, fixed). Returns (mean, stderr) over n_rep independent scrambles."""
    al = _sampling_alpha(brdf_fn)
    m = int(round(math.log2(n_qmc)))
    reps = []
    for child in np.random.SeedSequence(seed).spawn(n_rep):
        est = 0.0
        for strat, sub in enumerate(child.spawn(3)):
            u = qmc.Sobol(3, scramble=True, seed=np.random.default_rng(sub)).random_base2(m)
            if strat == 0:
                X = _sample_lobe(tau, omega, g, centre, u[:, 0], u[:, 1], u[:, 2])
            elif strat == 1:
                X = _reflect(np.broadcast_to(fixed, (u.shape[0], 3)), _sample_ggx_h(al, u[:, 0], u[:, 1]))
            else:
                X = _sample_cosine(u[:, 0], u[:, 1])
            X = X[X[:, 2] > 0]
            X = _normalize(X)
            pdf = (_pdf_lobe(tau, omega, g, centre, X) + _pdf_mirror(al, fixed, X) + X[:, 2] / math.pi)
            L = scattered_lobe(tau, omega, g, x=np.clip(1.0 - X @ centre, 0, 2))
            F = np.broadcast_to(fixed, X.shape)
            if side == "view":
                f = brdf_fn(F, X) * a_or_b(X[:, 2]) * L * Jfun(X)
            else:
                f = brdf_fn(X, F) * a_or_b(X[:, 2]) * L
            est += float(np.sum(f / pdf)) / u.shape[0]
        reps.append(est)
    reps = np.array(reps)
    return float(reps.mean()), float(reps.std(ddof=1) / math.sqrt(n_rep))


def _term_lobe_lobe(brdf_fn, I, R, tau, omega, g, a, b, Jfun, n_qmc, n_rep, seed, batch=1 << 15):
    """Int Int L(I,I') b(I'_z) f_r(I',R') a(R'_z) Lv(R',R) dI' dR' by QMC with MIS (balance)
    over three strategies: (0) I' ~ lobe about I, R' = mirror of I' about a GGX facet;
    (1) R' ~ lobe about R, I' = mirror of R'; (2) both from their lobes. (mean, stderr)."""
    al = _sampling_alpha(brdf_fn)
    m = int(round(math.log2(n_qmc)))
    reps = []
    for child in np.random.SeedSequence(seed).spawn(n_rep):
        est = 0.0
        for strat, sub in enumerate(child.spawn(3)):
            pts = qmc.Sobol(6, scramble=True, seed=np.random.default_rng(sub)).random_base2(m)
            acc = 0.0
            for k0 in range(0, pts.shape[0], batch):
                u = pts[k0:k0 + batch]
                if strat == 0:
                    ip = _sample_lobe(tau, omega, g, I, u[:, 0], u[:, 1], u[:, 2])
                    rp = _reflect(ip, _sample_ggx_h(al, u[:, 3], u[:, 4]))
                elif strat == 1:
                    rp = _sample_lobe(tau, omega, g, R, u[:, 0], u[:, 1], u[:, 2])
                    ip = _reflect(rp, _sample_ggx_h(al, u[:, 3], u[:, 4]))
                else:
                    ip = _sample_lobe(tau, omega, g, I, u[:, 0], u[:, 1], u[:, 2])
                    rp = _sample_lobe(tau, omega, g, R, u[:, 3], u[:, 4], u[:, 5])
                ok = (ip[:, 2] > 0) & (rp[:, 2] > 0)
                ip, rp = _normalize(ip[ok]), _normalize(rp[ok])
                qi, qr = _pdf_lobe(tau, omega, g, I, ip), _pdf_lobe(tau, omega, g, R, rp)
                pm = _pdf_mirror(al, ip, rp)
                pdf = qi * pm + qr * pm + qi * qr
                Li = scattered_lobe(tau, omega, g, x=np.clip(1.0 - ip @ I, 0, 2))
                Lr = scattered_lobe(tau, omega, g, x=np.clip(1.0 - rp @ R, 0, 2))
                f = Li * b(ip[:, 2]) * brdf_fn(ip, rp) * a(rp[:, 2]) * Lr * Jfun(rp)
                acc += float(np.sum(f / pdf))
            est += acc / pts.shape[0]
        reps.append(est)
    reps = np.array(reps)
    return float(reps.mean()), float(reps.std(ddof=1) / math.sqrt(n_rep))


def forward_series_terms(brdf_fn, tau, omega, g, eta_u, theta_i, theta_r, phi_i=180.0, phi_r=0.0,
                         variant="paper", path_length=None, plate_half_width=None, n_qmc=2 ** 14,
                         n_rep=8, seed=0, rtol=1e-7, mc_2d=False):
    """All terms of the forward-series apparent reflectance for one configuration (degrees).

    See the module docstring. mc_2d=True also estimates the two 2-D terms by QMC
    ("view_mc", "illum_mc" with "_stderr"), independently of the Gauss rules.
    """
    if not (0 <= theta_i < 90 and 0 <= theta_r < 90):
        raise ValueError("theta_i and theta_r must be in [0, 90) deg")
    I, R = direction(theta_i, phi_i), direction(theta_r, phi_r)
    a, b = _fresnel_ab(eta_u, variant)
    e2 = math.exp(-2.0 * tau)
    aI, bI, aR, bR = (float(f(z)) for f, z in ((a, I[2]), (b, I[2]), (a, R[2]), (b, R[2])))
    Jargs = (path_length, plate_half_width)

    def Jfun(X):
        return _view_weight(X, R, tau, *Jargs)

    out = {"direct": e2 * aI * bI * aR * bR * float(brdf_fn(I[None], R[None])[0])}
    if omega * tau <= 0.0:
        out.update(view=0.0, view_err=0.0, illum=0.0, illum_err=0.0, lobe_lobe=0.0, lobe_lobe_stderr=0.0)
        if mc_2d:
            out.update(view_mc=0.0, view_mc_stderr=0.0, illum_mc=0.0, illum_mc_stderr=0.0)
    else:
        pv = e2 * aI * bI * bR
        pi_ = e2 * aI * aR * bR
        pl = e2 * aI * bR
        v, ve = _term_view_gauss(brdf_fn, I, R, tau, omega, g, a, Jargs, rtol)
        il, ie = _term_illum_gauss(brdf_fn, I, R, tau, omega, g, b, rtol)
        ll, ls = _term_lobe_lobe(brdf_fn, I, R, tau, omega, g, a, b, Jfun, n_qmc, n_rep, seed)
        out.update(view=pv * v, view_err=pv * ve, illum=pi_ * il, illum_err=pi_ * ie,
                   lobe_lobe=pl * ll, lobe_lobe_stderr=pl * ls)
        if mc_2d:
            vm, vs = _term_2d_mc(brdf_fn, I, R, tau, omega, g, "view", a, Jfun, n_qmc, n_rep, seed + 1)
            im, is_ = _term_2d_mc(brdf_fn, R, I, tau, omega, g, "illum", b, Jfun, n_qmc, n_rep, seed + 2)
            out.update(view_mc=pv * vm, view_mc_stderr=pv * vs, illum_mc=pi_ * im, illum_mc_stderr=pi_ * is_)
    out["value"] = out["direct"] + out["view"] + out["illum"] + out["lobe_lobe"]
    out["stderr"] = math.sqrt(out["lobe_lobe_stderr"] ** 2 + out["view_err"] ** 2 + out["illum_err"] ** 2)
    return out


def forward_series_apparent(brdf_fn, tau, omega, g, eta_u, theta_i, theta_r, phi_i=180.0, phi_r=0.0,
                            variant="paper", path_length=None, plate_half_width=None, n_qmc=2 ** 14,
                            n_rep=8, seed=0, scale=1.0):
    """Apparent reflectance (docs/model.md eq. 1 with the forward-series f_t) and its standard error.

    brdf_fn(wi, wo): vectorized f_r on unit vectors (wi = I light, wo = R camera); scalar
    angles in degrees. path_length = R_c and plate_half_width = a switch on the finite-plate
    weighting J_v of the view-side scattered terms. ``scale``: docs/model.md's overall factor s.
    stderr combines the 4-D term's Monte Carlo error with the 2-D terms' quadrature errors.
    """
    t = forward_series_terms(brdf_fn, tau, omega, g, eta_u, theta_i, theta_r, phi_i, phi_r, variant,
                             path_length, plate_half_width, n_qmc, n_rep, seed)
    return scale * t["value"], scale * t["stderr"]


def plate_weight_lit(Rp, R, light, tau, path_length, plate_half_width, n=32):
    """J_v with the illumination-path variation across the plate (vectorized over Rp (..., 3)).

    (1/R_c) Int_0^S e^{-beta s} e^{-sigma_t (l(Q(s)) - R_c)} ds, Q(s) = s v, l(Q) the path of
    the parallel beam along -light from the cylinder wall to Q. S is the closed form's (equal to
    the bisection of :func:`plate_weight_direct`, see the tests). Used to size what the closed
    form neglects on the direct-illumination x view-lobe term (docs/physics.md).
    """
    Rp, R, Ld = np.asarray(Rp, float), np.asarray(R, float), np.asarray(light, float)
    Rc = float(path_length)
    sig = tau / Rc
    mup = Rp[..., 2]
    ok = mup > 0
    ratio = R[..., 2] / np.where(ok, mup, 1.0)
    v = R - ratio[..., None] * Rp
    vm = np.maximum(np.abs(v[..., 0]), np.abs(v[..., 1]))
    with np.errstate(divide="ignore"):
        S = np.minimum(Rc, np.where(vm > 0, float(plate_half_width) / np.where(vm > 0, vm, 1.0), np.inf))
    beta = sig * (ratio - 1.0)
    t, w = _gl01(n)
    s = S[..., None] * t
    qx = s * v[..., 0][..., None]
    a2 = Ld[0] ** 2 + Ld[2] ** 2
    b = qx * Ld[0]
    li = (-b + np.sqrt(b * b - a2 * (qx * qx - Rc * Rc))) / a2
    f = np.exp(-beta[..., None] * s - sig * (li - Rc))
    return np.where(ok, S * np.sum(w * f, axis=-1) / Rc, 0.0)


def jv_table(thetas_r=(0.0, 30.0, 60.0, 80.0), offsets=(-20.0, -5.0, 5.0, 20.0), taus=(0.5, 1.0, 2.0),
             path_length=15.0, plate_half_width=2.5, theta_light=45.0, out_of_plane=False):
    """Rows comparing J_v's closed form with direct integration (docs/physics.md, table J).

    Camera in-plane at theta_r (phi = 0). R' at theta_r + offset in the same plane (negative:
    past the normal), or (out_of_plane=True) R turned by |offset| about the in-plane axis
    perpendicular to it (R' = cos d R + sin d y). Rows: (theta_r, offset, tau, J closed form,
    J direct, J direct with the illumination path from a light at theta_light (phi = 180),
    J infinite plate).
    """
    rows = []
    for tr in thetas_r:
        R = direction(tr, 0.0)
        L = direction(theta_light, 180.0)
        for off in offsets:
            if out_of_plane:
                d = abs(off) * DEG
                Rp = math.cos(d) * R + math.sin(d) * np.array([0.0, 1.0, 0.0])
            else:
                tp = tr + off
                if abs(tp) >= 90.0:
                    continue
                Rp = direction(abs(tp), 0.0 if tp >= 0 else 180.0)
            for tau in taus:
                jc = float(plate_weight(Rp, R, tau, path_length, plate_half_width))
                jd = plate_weight_direct(Rp, R, tau, path_length, plate_half_width)
                jl = plate_weight_direct(Rp, R, tau, path_length, plate_half_width, light=L)
                ji = float(plate_weight(Rp, R, tau, path_length, None))
                rows.append((tr, off, tau, jc, jd, jl, ji))
    return rows
