"""veil.engine.apparent (docs/model.md sec. 5, paper eq. 1) against the independent reference in
tests/reference.py, closed forms, and checks of the reference itself.

Tolerance: 1e-3 relative (veil's documented accuracy for accuracy="default") plus three
standard errors of the reference's Monte Carlo part.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy import integrate

import reference as ref
import veil

TOL = 1e-3
M_LOG2, N_REP = 15, 8  # reference: 2^15 Sobol points x 3 strategies x 8 scrambles

PAIRS = [(b, m) for b in ("BRDF1", "BRDF2") for m in ("BTDF1", "BTDF2", "BTDF3")]
# (theta_i, phi_i, theta_r, phi_r): on the specular peak, 1-3 deg off it, far off, out of plane
CONFIGS = {
    "peak0": (0.0, 180.0, 0.0, 0.0),
    "peak30": (30.0, 180.0, 30.0, 0.0),
    "peak60": (60.0, 180.0, 60.0, 0.0),
    "peak75": (75.0, 180.0, 75.0, 0.0),
    "near+1": (45.0, 180.0, 46.0, 0.0),
    "near+3": (30.0, 180.0, 33.0, 0.0),
    "near-2": (60.0, 180.0, 58.0, 0.0),
    "far": (30.0, 180.0, 60.0, 0.0),
    "far75": (75.0, 180.0, 40.0, 0.0),
    "outofplane": (40.0, 180.0, 40.0, 20.0),
}


@functools.cache
def _veil(brdf, medium, return_error=False):
    """veil.engine.apparent at every CONFIG for one preset pair, one vectorized call."""
    ti, pi_, tr, pr = (np.array(c) for c in zip(*CONFIGS.values()))
    out = veil.apparent(brdf, medium, ti, tr, pi_, pr, return_error=return_error)
    if return_error:
        return dict(zip(CONFIGS, np.asarray(out[0]))), dict(zip(CONFIGS, np.asarray(out[1])))
    return dict(zip(CONFIGS, np.asarray(out)))


@functools.cache
def _ref(brdf, medium, config):
    return ref.reference_apparent(brdf, medium, *CONFIGS[config], m=M_LOG2, n_rep=N_REP)


def _assert_close(got, want, stderr, what):
    err = abs(got / want - 1.0)
    assert err <= TOL + 3 * stderr / abs(want), (
        f"{what}: veil {got:.9g} vs reference {want:.9g} +- {stderr:.2g}: relative error "
        f"{err:.2e} > {TOL:g} + 3 x {stderr / abs(want):.1e}")


# ----------------------------------------------------------------------------------------
# veil against the reference, every preset pair
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("config", list(CONFIGS))
@pytest.mark.parametrize("brdf, medium", PAIRS)
def test_apparent_matches_reference(brdf, medium, config):
    want, se = _ref(brdf, medium, config)
    assert se / want < 3e-4  # the reference is precise enough to judge 1e-3
    _assert_close(float(_veil(brdf, medium)[config]), want, se, f"{brdf} x {medium} {config}")


def _error_report(brdf, medium):
    values, errors = _veil(brdf, medium, return_error=True)
    plain = _veil(brdf, medium)
    rows = {}
    for config in CONFIGS:
        want, se = _ref(brdf, medium, config)
        assert float(values[config]) == pytest.approx(float(plain[config]), rel=1e-12)
        rows[config] = (float(errors[config]) / want, abs(float(values[config]) / want - 1),
                        se / want)
    text = "; ".join(f"{c}: estimate {e:.1e} actual {a:.1e}" for c, (e, a, _) in rows.items())
    return rows, text


@pytest.mark.parametrize("brdf, medium", PAIRS)
def test_error_estimate_covers_actual_error(brdf, medium):
    """return_error=True: the estimate is >= the actual error in most configurations."""
    rows, text = _error_report(brdf, medium)
    covered = sum(e + 2 * s >= a for e, a, s in rows.values())
    assert covered >= 0.75 * len(rows), text


@pytest.mark.parametrize("brdf, medium", PAIRS)
def test_error_estimate_below_tolerance(brdf, medium):
    """return_error=True: the estimate itself certifies the 1e-3 accuracy of "default"."""
    rows, text = _error_report(brdf, medium)
    assert all(e < TOL for e, _, _ in rows.values()), text


@pytest.mark.parametrize("variant_medium", ["BTDF1", "BTDF3"])
def test_exit_variant_matches_reference(variant_medium):
    m = getattr(veil, variant_medium).replace(variant="exit")
    names = ("peak30", "near+3", "far75", "outofplane")
    got = _veil_at(veil.BRDF2, m, [CONFIGS[c] for c in names])
    for k, c in enumerate(names):
        want, se = ref.reference_apparent("BRDF2", variant_medium, *CONFIGS[c], variant="exit",
                                          m=M_LOG2, n_rep=N_REP)
        _assert_close(float(got[k]), want, se, f"BRDF2 x {variant_medium} exit {c}")


# ----------------------------------------------------------------------------------------
# Closed forms and exact low-dimensional cases
# ----------------------------------------------------------------------------------------

ANGLES = [(0.0, 180.0, 0.0, 0.0), (30.0, 180.0, 30.0, 0.0), (30.0, 180.0, 60.0, 0.0),
          (75.0, 180.0, 20.0, 0.0), (50.0, 200.0, 40.0, 30.0)]


def _veil_at(brdf, medium, configs, accuracy="default"):
    ti, pi_, tr, pr = (np.array(c) for c in zip(*configs))
    return np.asarray(veil.apparent(brdf, medium, ti, tr, pi_, pr, accuracy=accuracy))


@functools.cache
def _double_integral_fr(brdf):
    """Int Int f_r dI dR = 2 pi^2 P_d + J_s (J_s independently by two integrand forms)."""
    js_i = ref._spec_total(brdf, "I")
    js_r = ref._spec_total(brdf, "R")
    assert js_i == pytest.approx(js_r, rel=1e-7)
    return 2 * math.pi ** 2 * brdf[0] + js_i


@pytest.mark.parametrize("specular_only", [False, True])
@pytest.mark.parametrize("name", ["BRDF1", "BRDF2"])
def test_no_single_scattering_is_constant(name, specular_only):
    """T_t = 0: f = T_d^2 Int Int f_r, the same for every I and R (P_d = 0 isolates the
    specular double integral J_s, otherwise diluted by the exact 2 pi^2 P_d)."""
    brdf = ref.PRESETS[name]
    if specular_only:
        brdf = (0.0,) + brdf[1:]
    want = 1e-3 ** 2 * _double_integral_fr(brdf)
    got = _veil_at(veil.TorranceSparrow(*brdf),
                   veil.HenyeyGreenstein(Td=1e-3, Tt=0.0, g=0.93, eta=1.3), ANGLES)
    assert np.allclose(got, want, rtol=TOL, atol=0), (got, want)


@pytest.mark.parametrize("name", ["BRDF1", "BRDF2"])
def test_isotropic_index_matched_medium_is_constant(name):
    """g = 0 and eta_u = 1: f_t = T_d + T_t / (4 pi) everywhere, f = f_t^2 Int Int f_r."""
    brdf = ref.PRESETS[name]
    td, tt = 1e-3, 0.38
    want = (td + tt / (4 * math.pi)) ** 2 * _double_integral_fr(brdf)
    # the reference's general route (terms, lobe integrals, MIS) reproduces the constant
    r, se = ref.reference_apparent(brdf, (td, tt, 0.0, 1.0), *ANGLES[3], m=13, n_rep=8)
    assert abs(r - want) < 4 * se + 1e-6 * want, (r, se, want)
    # A broad phase function without Fresnel attenuation exposes the object's grazing
    # Fresnel rise to the 4D term's coarse phase grids: the "default" rule is ~2e-3 off here
    # (its 1e-3 target is for the paper's media, g >= 0.88); "high" meets 1e-3.
    got = _veil_at(name, veil.HenyeyGreenstein(Td=td, Tt=tt, g=0.0, eta=1.0), ANGLES, "high")
    assert np.allclose(got, want, rtol=TOL, atol=0), (got, want)


def test_isotropic_phase_with_fresnel_factors():
    """g = 0, eta_u = 1.3: f_t = T_d + T_t/(4 pi) a(I) b(T) separates; reference per term."""
    med = (1e-3, 0.38, 0.0, 1.3)
    got = _veil_at("BRDF1", veil.HenyeyGreenstein(*med), ANGLES)
    for k, c in enumerate(ANGLES):
        want, se = ref.reference_apparent("BRDF1", med, *c, m=M_LOG2, n_rep=N_REP)
        _assert_close(float(got[k]), want, se, f"BRDF1 x isotropic {c}")


@pytest.mark.parametrize("medium", ["BTDF1", "BTDF2", "BTDF3"])
def test_diffuse_only_object(medium):
    """eta_b = 1: F = 0, no specular lobe. f is then T_d^2 2 pi^2 P_d plus products of the
    two-dimensional HG integrals L_I, L_R, computed deterministically by the reference."""
    brdf = (1e3, 5e5, 0.5, 1.0)
    got = _veil_at(veil.TorranceSparrow(*brdf), medium, ANGLES)
    for k, c in enumerate(ANGLES):
        t = ref.reference_terms(brdf, medium, *c)
        assert t["K"] == 0.0 and t["quad_err"] < 1e-9 * t["value"]
        td, tt, _, _ = ref.PRESETS[medium]
        assert t["iso_iso"] == pytest.approx(td * td * 2 * math.pi ** 2 * brdf[0], rel=1e-14)
        _assert_close(float(got[k]), t["value"], 0.0, f"diffuse x {medium} {c}")


def test_lobe_integrals_closed_form_and_scipy():
    """The reference's 2D HG integrals: hemisphere fraction about the normal has a closed
    form, an oblique case with Fresnel against scipy's dblquad."""
    for g in (0.0, 0.5, 0.93, 0.99, -0.5):
        x = 1.0  # gamma = 90 deg
        d = (1 - g) ** 2 + 2 * g * x
        frac = (1 + g) * x / (math.sqrt(d) * (math.sqrt(d) + 1 - g))
        got = ref._lobe_integral(g, 0.0, lambda z: np.ones_like(z))
        assert got == pytest.approx(frac, rel=1e-12)
    a, _ = ref._fresnel_factors(1.3, "paper")
    g, th = 0.98, math.radians(75.0)
    v = np.array([math.sin(th), 0.0, math.cos(th)])

    def f(t, p):
        w = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
        return (ref.reference_hg(g, float(w @ v)) * float(a(w[2])) * w[2] * math.sin(t))

    want = sum(2 * integrate.dblquad(f, 0, math.pi, lo, hi, epsabs=1e-13, epsrel=1e-10)[0]
               for lo, hi in ((0, th), (th, math.pi / 2)))
    assert ref._lobe_integral(g, th, lambda z: a(z) * z) == pytest.approx(want, rel=1e-8)


def test_specular_albedo_against_scipy():
    """One S_I value of the reference against scipy's dblquad in half-vector coordinates."""
    brdf = ref.PRESETS["BRDF2"]
    theta = math.radians(60.0)
    vi = np.array([math.sin(theta), 0.0, math.cos(theta)])

    def f(alpha, phi):
        h = np.array([math.sin(alpha) * math.cos(phi), math.sin(alpha) * math.sin(phi),
                      math.cos(alpha)])
        c = float(vi @ h)
        wo = 2 * c * h - vi
        return float(ref._fs_vec(brdf[1], brdf[2], brdf[3], vi, wo)) * 4 * c * math.sin(alpha)

    amax = math.radians(15.0)  # exp(-(0.5 * 15)^2) ~ 1e-25
    want = 2 * integrate.dblquad(f, 0, math.pi, 0, amax, epsabs=0, epsrel=1e-11)[0]
    assert float(ref._spec_S(brdf, np.array([theta]), "I")[0]) == pytest.approx(want, rel=1e-9)
    assert float(ref._spec_interp(brdf, "I", np.cos(theta))) == pytest.approx(want, rel=1e-7)


# ----------------------------------------------------------------------------------------
# The reference's Monte Carlo part
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("config", ["peak30", "far"])
def test_reference_mis_agrees_with_single_strategies(config):
    """K by the MIS estimator equals K by strategies 1 and 2 alone (each unbiased)."""
    brdf, med = ref.PRESETS["BRDF1"], ref.PRESETS["BTDF2"]
    ti, pi_, tr, pr = CONFIGS[config]
    wi, wr = ref._dir(ti, pi_), ref._dir(tr, pr)
    k, se = ref._k_mis(brdf, med, "paper", wi, wr, 14, 8, seed=1)
    for strategy in (0, 1):
        k1, se1 = ref._k_mis(brdf, med, "paper", wi, wr, 15, 8, seed=2, only=strategy)
        assert abs(k1 - k) < 4 * math.hypot(se, se1) + 1e-4 * k, (strategy, k1, k, se, se1)


def test_reference_is_deterministic_and_precise():
    a = ref.reference_apparent("BRDF2", "BTDF3", 75.0, 180.0, 75.0, 0.0, m=14, n_rep=8, seed=3)
    b = ref.reference_apparent("BRDF2", "BTDF3", 75.0, 180.0, 75.0, 0.0, m=14, n_rep=8, seed=3)
    assert a == b
    c = ref.reference_apparent("BRDF2", "BTDF3", 75.0, 180.0, 75.0, 0.0, m=14, n_rep=8, seed=4)
    assert c[0] != a[0] and abs(c[0] - a[0]) < 5 * math.hypot(a[1], c[1])


@pytest.mark.slow
@pytest.mark.parametrize("brdf, medium, config", [("BRDF1", "BTDF2", "near+3"),
                                                   ("BRDF2", "BTDF1", "far75")])
def test_reference_expansion_against_plain_estimator(brdf, medium, config):
    """The expansion into terms against one plain 4D estimator of the whole integrand."""
    want, se = _ref(brdf, medium, config)
    got, se2 = ref.naive_apparent(brdf, medium, *CONFIGS[config], m=17, n_rep=8, seed=5)
    assert abs(got - want) < 4 * math.hypot(se, se2) + 2e-4 * want, (got, want, se, se2)
