"""Tests of the independent physical-model reference (tests/reference_physical.py) itself:
closed forms, identities, two independent routes to each 2-D term, and Mitsuba 3's own BSDF
evaluation (skipped where the ``mitsuba`` package cannot be imported).

Numbers quoted in docs/physics.md come from these checks.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import reference_physical as rp

DEG = math.pi / 180.0


# ----------------------------------------------------------------------------------------
# Fresnel
# ----------------------------------------------------------------------------------------

def _conductor_real_form(c, n, k):
    """Textbook real-arithmetic conductor Fresnel (a^2 + b^2 form), written independently."""
    s2 = 1.0 - c * c
    t = n * n - k * k - s2
    a2b2 = np.sqrt(t * t + 4 * n * n * k * k)
    a = np.sqrt(0.5 * (a2b2 + t))
    rs = (a2b2 + c * c - 2 * a * c) / (a2b2 + c * c + 2 * a * c)
    rp_ = rs * (a2b2 * c * c - 2 * a * c * s2 + s2 * s2) / (a2b2 * c * c + 2 * a * c * s2 + s2 * s2)
    return 0.5 * (rs + rp_)


def test_conductor_fresnel_closed_forms():
    c = np.linspace(0.0, 1.0, 101)
    for n, k in ((0.2, 3.0), (1.5, 0.0), (2.7, 3.3), (0.05, 4.2)):
        f = rp.fresnel_conductor(c, n, k)
        assert np.allclose(f, _conductor_real_form(c, n, k), rtol=1e-12, atol=1e-14)
        assert f[-1] == pytest.approx(((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k), rel=1e-12)
        assert f[0] == pytest.approx(1.0, abs=1e-12)  # grazing
    assert np.allclose(rp.fresnel_conductor(c, 1.5, 0.0), rp.fresnel_dielectric(c, 1.5), atol=1e-14)
    assert np.allclose(rp.fresnel_schlick(c, 0.04)[[0, -1]], [1.0, 0.04])


# ----------------------------------------------------------------------------------------
# Microfacet pieces and the rough interface
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_smith_normalization_of_visible_normals(dist):
    """Int G1(v) (v.m)+ D(m) dm = cos(theta_v): the exact G1 makes D_v a probability density."""
    mu = np.array([1.0, 0.9, 0.6, 0.3, 0.1, 0.01])
    for alpha in (0.02, 0.2, 0.8):
        assert np.abs(rp.visible_normal_norm(mu, alpha, dist) - 1.0).max() < 1e-8


def test_rational_g1_is_within_walters_bound():
    a = np.logspace(-3, 1.5, 2000)
    ex = rp._g1_of_a(a, "beckmann", "exact")
    ra = rp._g1_of_a(a, "beckmann", "rational")
    assert np.abs(ra / ex - 1).max() < 4e-3


@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_white_furnace_of_the_specular_lobe(dist):
    """F = 1, ks = 1: the Smith lobe's albedo is <= 1, ~1 for small alpha at normal incidence."""
    mu = np.array([1.0, 0.7, 0.4, 0.1])
    for alpha in (0.01, 0.1, 0.3, 0.7):
        e = rp.microfacet_albedo(mu, alpha, dist)
        assert np.all(e <= 1.0 + 1e-9) and np.all(e > 0.5)
    # GGX: the facets steeper than 45 deg (fraction alpha^2 / (1 + alpha^2)) reflect below the horizon
    assert rp.microfacet_albedo(1.0, 0.01, dist)[0] > 1.0 - 1.2e-4


def test_furnace_against_brute_force_monte_carlo():
    """The visible-normal quadrature vs a plain estimator over outgoing directions."""
    rng = np.random.default_rng(7)
    n = 1_000_000
    for dist, alpha, th in (("ggx", 0.6, 0.0), ("beckmann", 0.3, 60.0)):
        v = rp.direction(th, 0.0)
        z, ph = rng.random(n), 2 * math.pi * rng.random(n)
        r = np.sqrt(1 - z * z)
        w = np.stack([r * np.cos(ph), r * np.sin(ph), z], -1)
        h = rp._normalize(w + v)
        f = (rp.microfacet_D(h[:, 2], alpha, dist) * rp.smith_g1(v[None], h, alpha, dist)
             * rp.smith_g1(w, h, alpha, dist) / (4 * v[2]) * 2 * math.pi)
        est, se = f.mean(), f.std() / math.sqrt(n)
        assert abs(rp.microfacet_albedo(math.cos(th * DEG), alpha, dist)[0] - est) < 5 * se


def test_smooth_limit_of_t_and_F_int():
    eta = 1.5
    mu = np.array([1.0, 0.8, 0.5, 0.3])
    t = rp.rough_transmittance(mu, 0.002, eta)
    assert np.abs(t - (1 - rp.fresnel_dielectric(mu, eta))).max() < 2e-4
    x, w = rp._gl01(400)
    f_ext = 2 * np.sum(w * x * rp.fresnel_dielectric(x, eta))
    smooth_fint = 1 - (1 - f_ext) / eta ** 2   # reciprocity: 1 - F_int = (1 - F_ext) / eta^2
    assert rp.internal_reflectance(0.002, eta, "beckmann") == pytest.approx(smooth_fint, abs=2e-5)


@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_rough_interface_quadrature_converged_and_spline(dist):
    mu = np.array([1.0, 0.77, 0.41, 0.13, 0.02, 1e-6])
    for alpha in (0.02, 0.3):
        _, err = rp.rough_transmittance(mu, alpha, 1.33, dist, check=True)
        assert err.max() < 1e-7
        _, err = rp.rough_reflectance(mu, alpha, 1 / 1.33, dist, check=True)
        assert err.max() < 1e-6
        th = np.linspace(0.3, 89.7, 37)
        direct = rp.rough_transmittance(np.cos(th * DEG), alpha, 1.33, dist)
        assert np.abs(rp.transmittance_lookup(np.cos(th * DEG), alpha, 1.33, dist) - direct).max() < 2e-6
    f1 = rp.internal_reflectance(0.3, 1.33, dist)
    assert rp.internal_reflectance(0.3, 1.33, dist, n=96) == pytest.approx(f1, abs=1e-8)


def test_rough_plastic_structure():
    ti, pi_, tr, pr = np.meshgrid([0, 20, 50, 80], [180, 120], [5, 35, 70], [0, 60], indexing="ij")
    args = dict(alpha=0.15, eta=1.12)
    both = rp.rough_plastic(ti, pi_, tr, pr, 0.4, ks=0.7, **args)
    # reciprocity of f_r / cos(theta_i)
    swap = rp.rough_plastic(tr, pr, ti, pi_, 0.4, ks=0.7, **args)
    assert np.allclose(both / np.cos(ti * DEG), swap / np.cos(tr * DEG), rtol=1e-12)
    # the diffuse part is the stated formula, the specular part a dielectric rough conductor
    diff = rp.rough_plastic(ti, pi_, tr, pr, 0.4, ks=0.0, **args)
    fint = rp.internal_reflectance(0.15, 1.12)
    t = lambda th: rp.transmittance_lookup(np.cos(th * DEG), 0.15, 1.12)
    expect = 0.4 / (1 - fint) * t(ti) * t(tr) * np.cos(ti * DEG) / (math.pi * 1.12 ** 2)
    assert np.allclose(diff, expect, rtol=1e-13)
    nl = rp.rough_plastic(ti, pi_, tr, pr, 0.4, ks=0.0, nonlinear=True, **args)
    assert np.allclose(nl, expect * (1 - fint) / (1 - 0.4 * fint), rtol=1e-13)
    spec = rp.rough_plastic(ti, pi_, tr, pr, 0.0, ks=0.7, **args)
    cond = rp.rough_conductor(ti, pi_, tr, pr, 0.15, ks=0.7, n=1.12, k=0.0)
    assert np.allclose(spec, cond, rtol=1e-12)
    assert rp.rough_plastic(95, 0, 10, 0, 0.4, 0.15, 1.12) == 0.0


# ----------------------------------------------------------------------------------------
# Mitsuba 3
# ----------------------------------------------------------------------------------------

def _mitsuba():
    mi = pytest.importorskip("mitsuba", reason="mitsuba not installed here (pip install mitsuba "
                                               "in a separate venv to run the renderer comparisons)")
    mi.set_variant("scalar_rgb")
    return mi


def _mts_eval(mi, bsdf, I, R):
    """Mitsuba convention: si.wi = the camera direction R, wo = the light direction I; eval()
    includes cos(theta_o) = cos(theta_I), exactly our f_r(I, R)."""
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*R)
    return float(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*I))[0])


_SWEEP = [(ti, tr, pr) for ti in (0, 20, 45, 70, 85) for tr in (0, 10, 30, 60, 80, 88) for pr in (0, 90, 170)]


@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
@pytest.mark.parametrize("nonlinear", [False, True])
def test_rough_plastic_against_mitsuba(dist, nonlinear):
    mi = _mitsuba()
    worst_compat, worst_exact = 0.0, 0.0
    for alpha in (0.05, 0.2, 0.5):
        rho, eta, ks = 0.6, 1.5, 1.0
        b = mi.load_dict({"type": "roughplastic", "distribution": dist, "alpha": alpha,
                          "int_ior": eta, "ext_ior": 1.0, "diffuse_reflectance": rho,
                          "nonlinear": nonlinear})
        for ti, tr, pr in _SWEEP:
            m = _mts_eval(mi, b, rp.direction(ti, 180), rp.direction(tr, pr))
            c = float(rp.rough_plastic(ti, 180, tr, pr, rho, alpha, eta, ks, dist, nonlinear,
                                       smith="rational", tables="mitsuba"))
            e = float(rp.rough_plastic(ti, 180, tr, pr, rho, alpha, eta, ks, dist, nonlinear))
            worst_compat = max(worst_compat, abs(c / m - 1))
            worst_exact = max(worst_exact, abs(e / m - 1))
    assert worst_compat < 1e-3   # measured: <= 1.0e-4 (beckmann), <= 7.4e-4 (ggx)
    assert worst_exact < 3e-2    # measured: <= 2.2e-2 (Mitsuba's F_int rule is ~1.5 % low)


@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_rough_conductor_against_mitsuba(dist):
    mi = _mitsuba()
    worst = {"rational": 0.0, "exact": 0.0}
    for alpha in (0.05, 0.2, 0.5):
        for n, k in ((0.2, 3.0), (1.5, 0.0), (2.7, 3.3)):
            b = mi.load_dict({"type": "roughconductor", "distribution": dist, "alpha": alpha,
                              "eta": n, "k": k})
            for ti, tr, pr in _SWEEP:
                m = _mts_eval(mi, b, rp.direction(ti, 180), rp.direction(tr, pr))
                for smith in worst:
                    r = float(rp.rough_conductor(ti, 180, tr, pr, alpha, n=n, k=k,
                                                 distribution=dist, smith=smith))
                    if m > 1e-6:
                        worst[smith] = max(worst[smith], abs(r / m - 1))
                    else:
                        assert r < 1e-5
    assert worst["rational"] < 1e-3
    if dist == "ggx":
        assert worst["exact"] < 1e-3
    else:
        assert worst["exact"] < 8e-3  # two rational G1 factors, < 0.35 % each


# ----------------------------------------------------------------------------------------
# Forward series
# ----------------------------------------------------------------------------------------

def test_series_weights_and_lobe_normalization():
    for tau, omega in ((0.3, 1.0), (1.0, 0.9), (4.0, 0.98)):
        w = rp.series_weights(tau, omega)
        assert w.sum() == pytest.approx(math.expm1(omega * tau), rel=1e-14)
        v, _ = rp.sphere_integral(lambda X: rp.scattered_lobe(tau, omega, 0.9, X[:, 2]),
                                  [np.array([0.0, 0.0, 1.0])], [rp._lobe_scale(0.9)], upper=False)
        assert v == pytest.approx(math.expm1(omega * tau), rel=1e-10)
    assert rp.series_weights(0.0, 0.9).size == 0


@pytest.mark.parametrize("g1,g2", [(0.9, 0.8), (0.6, -0.4)])
def test_hg_convolution_identity(g1, g2):
    """Int p(g1; A.X) p(g2; X.B) dX = p(g1 g2; A.B) (Legendre moments multiply)."""
    for gam in (0.0, 3.0, 30.0, 90.0, 150.0, 180.0):
        v, err = rp.hg_convolution(g1, g2, gam, rtol=1e-9)
        ex = float(rp.hg(g1 * g2, math.cos(gam * DEG)))
        assert abs(v / ex - 1) < 1e-6 and err < 1e-6 * ex


def _lambert(wi, wo):
    return np.where((wi[..., 2] > 0) & (wo[..., 2] > 0), 0.3 * wi[..., 2], 0.0)


def _hemi_moments(g):
    """2 pi Int_0^1 p(g, mu) dmu (closed form) and 2 pi Int_0^1 p(g, mu) mu dmu (Gauss)."""
    h0 = 0.5 if g == 0 else (1 - g * g) / (2 * g) * (1 / (1 - g) - 1 / math.sqrt(1 + g * g))
    x, w = rp._gl01(400)
    s0, s1 = math.log((1 - g) ** 2 + 1e-300), math.log((1 - g) ** 2 + 2 * g) if g > 0 else 0.0
    if g > 1e-3:
        s = s0 + (s1 - s0) * x
        xx = (np.exp(s) - (1 - g) ** 2) / (2 * g)
        wx = (s1 - s0) * w * np.exp(s) / (2 * g)
    else:
        xx, wx = x, w
    h1 = 2 * math.pi * np.sum(wx * rp._hg_x(g, xx) * (1 - xx))
    return h0, h1


def test_lambertian_closed_forms_of_all_terms():
    tau, omega, g = 1.2, 0.9, 0.85
    w = rp.series_weights(tau, omega)
    H0 = sum(wk * _hemi_moments(g ** k)[0] for k, wk in enumerate(w, 1))
    H1 = sum(wk * _hemi_moments(g ** k)[1] for k, wk in enumerate(w, 1))
    e2 = math.exp(-2 * tau)
    t = rp.forward_series_terms(_lambert, tau, omega, g, 1.0, 0.0, 0.0, n_qmc=2 ** 13, n_rep=8)
    assert t["direct"] == pytest.approx(e2 * 0.3, rel=1e-14)
    assert t["view"] == pytest.approx(e2 * 0.3 * H0, rel=1e-8)
    assert t["illum"] == pytest.approx(e2 * 0.3 * H1, rel=1e-8)
    K = e2 * 0.3 * H0 * H1
    assert abs(t["lobe_lobe"] - K) < 5 * t["lobe_lobe_stderr"] and t["lobe_lobe_stderr"] < 1e-3 * K


_BRDFS = {
    "plastic": rp.make_rough_plastic(0.5, 0.1, 1.12, 1.0, "ggx"),
    "sharp-conductor": rp.make_rough_conductor(0.02, 1.0, n=0.2, k=3.0, distribution="beckmann"),
}


@pytest.mark.parametrize("name,cfg", [
    ("plastic", dict(tau=1.0, omega=0.9, g=0.9, eta_u=1.33, theta_i=60, theta_r=10, variant="exit")),
    ("plastic", dict(tau=2.0, omega=0.95, g=0.97, eta_u=1.0, theta_i=45, theta_r=45,
                     path_length=15.0, plate_half_width=2.5)),
    ("sharp-conductor", dict(tau=0.5, omega=0.98, g=0.99, eta_u=1.3, theta_i=20, theta_r=40)),
])
def test_two_routes_to_the_2d_terms(name, cfg):
    """Gauss rules about the lobe and BRDF peaks vs QMC with MIS (independent scrambles)."""
    t = rp.forward_series_terms(_BRDFS[name], mc_2d=True, n_qmc=2 ** 14, n_rep=8, seed=3, **cfg)
    for key in ("view", "illum"):
        tol = 4.5 * math.hypot(t[key + "_mc_stderr"], t[key + "_err"])
        assert abs(t[key] - t[key + "_mc"]) < tol, (key, t[key], t[key + "_mc"], tol)
        assert t[key + "_mc_stderr"] < 1e-4 * t[key]


def test_tau_zero_and_omega_zero():
    brdf = _BRDFS["plastic"]
    f_r = float(brdf(rp.direction(30, 180)[None], rp.direction(20, 0)[None])[0])
    v, se = rp.forward_series_apparent(brdf, 0.0, 0.9, 0.9, 1.0, 30, 20)
    assert v == f_r and se == 0.0
    for variant in ("paper", "exit"):
        v, se = rp.forward_series_apparent(brdf, 0.7, 0.0, 0.9, 1.33, 30, 20, variant=variant)
        ft = lambda th: 1 - rp.fresnel_dielectric(math.cos(th * DEG), 1.33)
        assert v == pytest.approx(math.exp(-1.4) * ft(30) ** 2 * ft(20) ** 2 * f_r, rel=1e-14)
        assert se == 0.0
    v, _ = rp.forward_series_apparent(brdf, 0.7, 0.0, 0.9, 1.0, 30, 20)
    assert v == pytest.approx(math.exp(-1.4) * f_r, rel=1e-14)


def test_eta_one_means_no_fresnel():
    brdf = _BRDFS["plastic"]
    kw = dict(n_qmc=2 ** 11, n_rep=4, seed=1)
    a = rp.forward_series_terms(brdf, 0.8, 0.9, 0.9, 1.0, 25, 35, variant="paper", **kw)
    b = rp.forward_series_terms(brdf, 0.8, 0.9, 0.9, 1.0, 25, 35, variant="exit", **kw)
    for key in ("direct", "view", "illum", "lobe_lobe"):
        assert a[key] == pytest.approx(b[key], rel=1e-13)


def test_reciprocity_of_the_exit_variant():
    """Symmetric f_t ("exit"): f(I, R) with f_r equals f(R, I) with the transposed f_r."""
    brdf = _BRDFS["plastic"]

    def brdf_t(wi, wo):
        return brdf(wo, wi)
    brdf_t.sampling_alpha = brdf.sampling_alpha
    kw = dict(n_qmc=2 ** 12, n_rep=8, seed=2)
    for variant in ("exit", "paper"):
        a = rp.forward_series_terms(brdf, 1.0, 0.9, 0.9, 1.33, 50, 15, phi_i=180, phi_r=0, variant=variant, **kw)
        b = rp.forward_series_terms(brdf_t, 1.0, 0.9, 0.9, 1.33, 15, 50, phi_i=0, phi_r=180, variant=variant, **kw)
        same = (a["direct"] == pytest.approx(b["direct"], rel=1e-12)
                and a["view"] == pytest.approx(b["illum"], rel=1e-7)
                and a["illum"] == pytest.approx(b["view"], rel=1e-7)
                and abs(a["lobe_lobe"] - b["lobe_lobe"]) < 5 * math.hypot(a["lobe_lobe_stderr"], b["lobe_lobe_stderr"]))
        assert same == (variant == "exit")


# ----------------------------------------------------------------------------------------
# Finite plate
# ----------------------------------------------------------------------------------------

def test_plate_weight_closed_form_equals_direct_single_scattering():
    rng = np.random.default_rng(3)
    R_dirs = rp.direction(rng.uniform(0, 85, 40), np.zeros(40))
    Rp_dirs = rp.direction(rng.uniform(0, 88, 40), rng.uniform(0, 360, 40))
    for R, Rp in zip(R_dirs, Rp_dirs):
        for tau in (0.3, 1.0, 3.0):
            for a in (2.5, None):
                c = float(rp.plate_weight(Rp, R, tau, 15.0, a))
                d = rp.plate_weight_direct(Rp, R, tau, 15.0, a)
                assert c == pytest.approx(d, rel=1e-12, abs=1e-15)
    # beta -> 0 limit, R' = R, and the infinite plate's independence of R_c
    R = rp.direction(30, 0)
    assert float(rp.plate_weight(R, R, 1.0, 15.0, 2.5)) == pytest.approx(1.0, rel=1e-15)
    Rp = rp.direction(35, 90)
    assert float(rp.plate_weight(Rp, R, 1.0, 15.0, None)) == pytest.approx(
        float(rp.plate_weight(Rp, R, 1.0, 3.0, None)), rel=1e-14)
    # the lit variant, vectorized, against the pointwise direct integral
    L = rp.direction(45, 180)
    Rps = rp.direction(np.array([10.0, 25.0, 35.0, 50.0]), np.array([0.0, 0.0, 30.0, 180.0]))
    lit = rp.plate_weight_lit(Rps, R, L, 1.0, 15.0, 2.5)
    assert np.allclose(lit, [rp.plate_weight_direct(x, R, 1.0, 15.0, 2.5, light=L) for x in Rps], rtol=1e-10)


def test_finite_plate_in_the_apparent_reflectance():
    brdf = _BRDFS["plastic"]
    kw = dict(n_qmc=2 ** 11, n_rep=4, seed=4)
    base = rp.forward_series_terms(brdf, 1.0, 0.95, 0.93, 1.33, 30, 30, **kw)
    inf = rp.forward_series_terms(brdf, 1.0, 0.95, 0.93, 1.33, 30, 30, path_length=15.0, **kw)
    huge = rp.forward_series_terms(brdf, 1.0, 0.95, 0.93, 1.33, 30, 30, path_length=15.0,
                                   plate_half_width=1e9, **kw)
    plate = rp.forward_series_terms(brdf, 1.0, 0.95, 0.93, 1.33, 30, 30, path_length=15.0,
                                    plate_half_width=2.5, **kw)
    for key in ("direct", "illum"):  # the weighting is on the view side only
        assert plate[key] == pytest.approx(base[key], rel=1e-12)
    assert huge["view"] == pytest.approx(inf["view"], rel=1e-9)
    assert plate["view"] < 0.85 * base["view"] and plate["lobe_lobe"] < 0.85 * base["lobe_lobe"]
    with pytest.raises(ValueError):
        rp.forward_series_terms(brdf, 1.0, 0.95, 0.93, 1.33, 30, 30, plate_half_width=2.5, **kw)
