"""Tests of veil's model code against docs/model.md sec. 1-4 and the independent tests/reference.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize

import veil
from reference import (
    PRESETS,
    reference_btdf,
    reference_fresnel,
    reference_fresnel_sintan,
    reference_hg,
    reference_reflectance,
)
from veil.engine import angles
from veil.models import fresnel, phase

DET = settings(deadline=None, max_examples=300, derandomize=True)


def _f(x):
    return np.asarray(x, dtype=float)


def _upper_dirs(rng, n, max_theta=89.0):
    th = rng.uniform(0.0, max_theta, n)
    ph = rng.uniform(0.0, 360.0, n)
    return th, ph, _f(angles.direction(th, ph))


# ----------------------------------------------------------------------------------------
# Fresnel (docs/model.md sec. 4)
# ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("eta", [0.75, 1.1, 1.16, 1.33, 1.55, 2.5])
def test_fresnel_normal_incidence(eta):
    assert _f(fresnel.reflectance(1.0, eta)) == pytest.approx(((eta - 1) / (eta + 1)) ** 2,
                                                             rel=1e-13)


@pytest.mark.parametrize("eta", [1.1, 1.3, 1.55, 2.5])
def test_fresnel_grazing_limit(eta):
    assert _f(fresnel.reflectance(0.0, eta)) == pytest.approx(1.0, abs=1e-15)
    # approaches 1 continuously: 1 - F ~ const * cos(theta) near grazing
    c = np.array([1e-5, 1e-6, 1e-7])
    one_minus = 1.0 - _f(fresnel.reflectance(c, eta))
    assert np.all(one_minus > 0)
    assert np.allclose(one_minus[1:] / one_minus[:-1], 0.1, rtol=1e-3)


def test_fresnel_total_internal_reflection():
    eta = 0.75
    crit = math.degrees(math.asin(eta))  # 48.59 deg
    beyond = np.cos(np.radians([crit + 0.01, 50.0, 70.0, 89.9]))
    assert np.all(_f(fresnel.reflectance(beyond, eta)) == 1.0)
    assert np.all(_f(fresnel.transmittance(beyond, eta)) == 0.0)
    below = np.cos(np.radians([0.0, 30.0, crit - 0.5]))
    assert np.all(_f(fresnel.reflectance(below, eta)) < 1.0)
    # just below the critical angle F is close to 1 (continuous at the critical angle)
    assert _f(fresnel.reflectance(math.cos(math.radians(crit - 1e-6)), eta)) > 0.99


def test_fresnel_index_one_is_zero():
    c = np.linspace(0.0, 1.0, 101)[1:]
    assert np.all(_f(fresnel.reflectance(c, 1.0)) == pytest.approx(0.0, abs=1e-15))
    assert np.all(_f(fresnel.transmittance(c, 1.0)) == pytest.approx(1.0, abs=1e-15))


def test_fresnel_index_one_is_zero_at_grazing():
    """docs/model.md sec. 4: eta = 1 gives F = 0, also at cos = 0 (the limit from inside; the
    TIR rule needs eta < 1, so it does not apply)."""
    assert float(_f(fresnel.reflectance(0.0, 1.0))) == 0.0


@pytest.mark.parametrize("eta", [1.13, 1.3, 1.55, 2.0])
def test_fresnel_matches_paper_sin_tan_form(eta):
    """Paper eq. 4 (sin/tan form) away from normal incidence, where it is not 0/0."""
    theta = np.concatenate([np.linspace(0.5, 89.5, 179), [10.0, 45.0, 60.0]])
    ours = _f(fresnel.reflectance(np.cos(np.radians(theta)), eta))
    paper = reference_fresnel_sintan(theta, eta)
    assert np.allclose(ours, paper, rtol=1e-10, atol=1e-15)
    # F_t of the paper's eq. 4 is 1 minus that
    assert np.allclose(_f(fresnel.transmittance(np.cos(np.radians(theta)), eta)), 1 - paper,
                       rtol=1e-12)


@DET
@given(c=st.floats(0.0, 1.0), eta=st.floats(0.2, 5.0))
def test_fresnel_bounds_and_reference(c, eta):
    f = float(_f(fresnel.reflectance(c, eta)))
    assert 0.0 <= f <= 1.0
    assert f == pytest.approx(float(reference_fresnel(c, eta)), rel=1e-12, abs=1e-15)
    assert float(_f(fresnel.transmittance(c, eta))) == pytest.approx(1.0 - f, abs=1e-15)


# ----------------------------------------------------------------------------------------
# Henyey-Greenstein (docs/model.md sec. 3, decision 2)
# ----------------------------------------------------------------------------------------

G_VALUES = [-0.9, -0.3, 0.0, 0.5, 0.88, 0.93, 0.98, 0.99]
BREAKS = [1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 0.5, 1.0, 1.5, 1.9, 1.99]


def _sphere_moment(g, weight):
    """Int over the sphere of p * weight(1 - mu), with x = 1 - mu in [0, 2]."""
    fn = lambda x: float(_f(phase.hg_pdf(g, x))) * weight(x) * 2 * math.pi
    edges = [0.0] + BREAKS + [2.0]
    return sum(integrate.quad(fn, a, b, epsabs=0, epsrel=1e-12, limit=200)[0]
               for a, b in zip(edges[:-1], edges[1:]))


@pytest.mark.parametrize("g", G_VALUES)
def test_hg_normalized_over_sphere(g):
    assert _sphere_moment(g, lambda x: 1.0) == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("g", G_VALUES)
def test_hg_mean_cosine_is_g(g):
    assert _sphere_moment(g, lambda x: 1.0 - x) == pytest.approx(g, abs=1e-9)


@pytest.mark.parametrize("g", G_VALUES)
def test_hg_matches_textbook_form(g):
    gamma = np.radians(np.linspace(0.0, 180.0, 91))
    ours = _f(phase.hg_pdf(g, 1.0 - np.cos(gamma)))
    assert np.allclose(ours, reference_hg(g, np.cos(gamma)), rtol=1e-9)
    if g == 0.0:
        assert np.allclose(ours, 1.0 / (4 * math.pi), rtol=1e-14)


def test_hg_forward_peak_of_paper_media_about_four_per_sr():
    """docs/model.md sec. 3: the three simulated media have T_t p(g, 0) of about 4 per sr."""
    for name in ("BTDF1", "BTDF2", "BTDF3"):
        _, tt, g, _ = PRESETS[name]
        assert 3.5 < tt * float(_f(phase.hg_pdf(g, 0.0))) < 4.5


@pytest.mark.parametrize("g", [-0.7, 0.0, 0.5, 0.93, 0.99])
def test_hg_cone_fraction_is_integral_of_pdf(g):
    for x in (1e-5, 1e-3, 0.1, 1.0, 1.7):
        fn = lambda t: float(_f(phase.hg_pdf(g, t))) * 2 * math.pi
        edges = [0.0] + [b for b in BREAKS if b < x] + [x]
        want = sum(integrate.quad(fn, a, b, epsabs=0, epsrel=1e-12, limit=200)[0]
                   for a, b in zip(edges[:-1], edges[1:]))
        assert float(_f(phase.hg_cone_fraction(g, x))) == pytest.approx(want, rel=1e-9)
    assert float(_f(phase.hg_cone_fraction(g, 0.0))) == 0.0
    assert float(_f(phase.hg_cone_fraction(g, 2.0))) == pytest.approx(1.0, abs=1e-14)


def test_hg_cone_fraction_isotropic_is_half_x():
    x = np.linspace(0.0, 2.0, 21)
    assert np.allclose(_f(phase.hg_cone_fraction(0.0, x)), x / 2, atol=1e-15)
    assert np.allclose(_f(phase.hg_inverse_cone_fraction(0.0, x / 2)), x, atol=1e-15)


@DET
@given(g=st.floats(-0.99, 0.995), frac=st.floats(0.0, 1.0))
def test_hg_inverse_then_cone_fraction(g, frac):
    x = float(_f(phase.hg_inverse_cone_fraction(g, frac)))
    assert -1e-15 <= x <= 2.0 + 1e-12
    assert float(_f(phase.hg_cone_fraction(g, x))) == pytest.approx(frac, rel=1e-10, abs=1e-13)


@DET
@given(g=st.floats(-0.95, 0.995), x=st.floats(1e-9, 1.0))
def test_hg_cone_fraction_then_inverse(g, x):
    # forward hemisphere: the cone fraction is well conditioned there
    frac = float(_f(phase.hg_cone_fraction(g, x)))
    assert 0.0 < frac < 1.0
    assert float(_f(phase.hg_inverse_cone_fraction(g, frac))) == pytest.approx(x, rel=1e-8)


@DET
@given(g=st.floats(-0.99, 0.995), x1=st.floats(0.0, 2.0), x2=st.floats(0.0, 2.0))
def test_hg_cone_fraction_monotone(g, x1, x2):
    lo, hi = sorted((x1, x2))
    assert float(_f(phase.hg_cone_fraction(g, lo))) <= float(_f(phase.hg_cone_fraction(g, hi))) + 1e-15


# ----------------------------------------------------------------------------------------
# Torrance-Sparrow f_r (docs/model.md sec. 2)
# ----------------------------------------------------------------------------------------

BRDFS = {"BRDF1": veil.BRDF1, "BRDF2": veil.BRDF2,
         "rough": veil.TorranceSparrow(Pd=1.17e3, Ps=6.82e4, n=0.20, eta=1.13),
         "acrylic": veil.TorranceSparrow(Pd=2.91e3, Ps=1.34e6, n=0.80, eta=1.16)}


def _tuple(model):
    return tuple(float(v) for v in model.to_vector())


def test_presets_match_model_md():
    for name in PRESETS:
        assert _tuple(getattr(veil, name)) == PRESETS[name]
    assert veil.BTDF1.variant == "paper"


@pytest.mark.parametrize("name", list(BRDFS))
def test_reflectance_matches_reference(name):
    model = BRDFS[name]
    rng = np.random.default_rng(7)
    n = 4000
    ti, tr = rng.uniform(0, 89.9, n), rng.uniform(0, 89.9, n)
    pi_, pr = rng.uniform(0, 360, n), rng.uniform(0, 360, n)
    # half of them close to the mirror direction, where the lobe lives
    near = np.arange(n) < n // 2
    tr[near] = np.clip(ti[near] + rng.normal(0, 3, near.sum()), 0, 89.9)
    pr[near] = pi_[near] + 180 + rng.normal(0, 3, near.sum())
    ours = _f(veil.reflectance(model, ti, tr, pi_, pr))
    ref = reference_reflectance(_tuple(model), ti, pi_, tr, pr)
    assert np.allclose(ours, ref, rtol=1e-10, atol=1e-12 * model.Pd)


@pytest.mark.parametrize("name", list(BRDFS))
@pytest.mark.parametrize("theta", [0.0, 20.0, 45.0, 70.0, 85.0])
def test_reflectance_at_mirror_closed_form(name, theta):
    """At the mirror direction H = z: alpha = 0, theta_i' = theta_i, G = 1."""
    m = BRDFS[name]
    want = m.Pd * math.cos(math.radians(theta)) + m.Ps * float(
        reference_fresnel(math.cos(math.radians(theta)), m.eta)) / math.cos(math.radians(theta))
    assert float(_f(veil.reflectance(m, theta, theta))) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("n, hwhm", [(0.8, 1.0), (0.5, 1.7), (0.2, 4.2)])
def test_facet_half_width_in_degrees(n, hwhm):
    """docs/model.md sec. 2 / decision 1: alpha in degrees, HWHM ~1.0, 1.7, 4.2 deg for n=.8,.5,.2.

    At normal incidence an in-plane camera at theta_r sees the facet alpha = theta_r / 2.
    """
    m = veil.TorranceSparrow(Pd=0.0, Ps=1.0, n=n, eta=1.5)
    a_half = math.sqrt(math.log(2.0)) / n  # exact HWHM of exp(-(n alpha_deg)^2)
    assert a_half == pytest.approx(hwhm, abs=0.05)
    ratio = float(_f(veil.reflectance(m, 0.0, 2 * a_half)) / _f(veil.reflectance(m, 0.0, 0.0)))
    # remaining factors: F(alpha)/F(0) and 1/cos(theta_r), both within 1 % of 1 here
    expect = 0.5 * float(reference_fresnel(math.cos(math.radians(a_half)), 1.5)
                         / reference_fresnel(1.0, 1.5)) / math.cos(math.radians(2 * a_half))
    assert ratio == pytest.approx(expect, rel=1e-10)
    assert ratio == pytest.approx(0.5, rel=0.02)


def _inplane_peak(fn, lo, hi):
    res = optimize.minimize_scalar(lambda t: -fn(t), bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-7})
    return res.x


@pytest.mark.parametrize("name", ["BRDF1", "BRDF2", "rough"])
@pytest.mark.parametrize("theta_i", [0.0, 20.0, 45.0, 70.0])
def test_specular_peak_at_mirror(name, theta_i):
    m = BRDFS[name]
    # coarse scan of the whole plane of incidence (both sides) and azimuth
    tr = np.arange(0.0, 89.0, 0.05)
    diffuse = m.Pd * math.cos(math.radians(theta_i))  # constant in theta_r
    inplane = _f(veil.reflectance(m, theta_i, tr))
    other = _f(veil.reflectance(m, theta_i, tr, 180.0, 180.0))
    if theta_i > 0:  # the light's own side has no highlight
        assert inplane.max() - diffuse > 5 * (other.max() - diffuse)
    peak = tr[np.argmax(inplane)]
    # the lobe's maximum sits at the mirror angle, pushed past it by 1/cos(theta_r) and the
    # rising Fresnel factor, but by less than the lobe's half width in theta_r (2 x facet HWHM)
    width = 2 * math.sqrt(math.log(2.0)) / m.n
    assert theta_i - 0.05 <= peak <= theta_i + (0.05 if theta_i == 0 else width)
    if theta_i == 0.0:
        assert peak == 0.0
        return
    # off-plane azimuths are darker than in-plane at the peak
    for dphi in (1.0, 3.0, 10.0):
        assert _f(veil.reflectance(m, theta_i, peak, 180.0, dphi)) < inplane.max()
    # exact location agrees with an independent maximisation of the reference f_r
    ref = _tuple(m)
    lo, hi = peak - 0.1, min(peak + 0.1, 89.5)
    want = _inplane_peak(lambda t: float(reference_reflectance(ref, theta_i, 180, t, 0)), lo, hi)
    got = _inplane_peak(lambda t: float(_f(veil.reflectance(m, theta_i, t))), lo, hi)
    assert got == pytest.approx(want, abs=1e-4)
    assert want > theta_i  # past the mirror, because of 1/cos(theta_r)


def test_reflectance_clear_medium_is_apparent_with_none():
    ti, tr = np.array([10.0, 30.0, 60.0]), np.array([10.0, 33.0, 20.0])
    assert np.array_equal(_f(veil.apparent(veil.BRDF1, None, ti, tr)),
                          _f(veil.reflectance(veil.BRDF1, ti, tr)))


@pytest.mark.parametrize("bad", [90.0, 95.0, -1.0, float("nan"), float("inf")])
def test_reflectance_rejects_bad_angles(bad):
    with pytest.raises(ValueError, match="theta_r"):
        veil.reflectance(veil.BRDF1, 30.0, bad)
    with pytest.raises(ValueError, match="theta_i"):
        veil.reflectance(veil.BRDF1, bad, 30.0)


# ----------------------------------------------------------------------------------------
# BTDF f_t (docs/model.md sec. 3, decision 3)
# ----------------------------------------------------------------------------------------

def _ft(model, wa, wb):
    return _f(model.evaluate(model.to_vector(), wa, wb))


@pytest.mark.parametrize("variant", ["paper", "exit"])
@pytest.mark.parametrize("name", ["BTDF1", "BTDF2", "BTDF3"])
def test_btdf_matches_reference(name, variant):
    model = getattr(veil, name).replace(variant=variant)
    rng = np.random.default_rng(11)
    ta, pa, wa = _upper_dirs(rng, 3000)
    tb, pb, wb = _upper_dirs(rng, 3000)
    # half of the pairs inside the forward lobe
    k = 1500
    tb[:k] = np.clip(ta[:k] + rng.normal(0, 2, k), 0, 89)
    pb[:k] = pa[:k] + rng.normal(0, 2, k)
    wb = _f(angles.direction(tb, pb))
    ref = reference_btdf(_tuple(model), ta, pa, tb, pb, variant=variant)
    assert np.allclose(_ft(model, wa, wb), ref, rtol=1e-9)


def test_btdf_unscattered_direction_and_fresnel():
    """gamma = 0 (T = I): f_t = T_d + T_t p(g, 0) F_t(theta)^2 in the paper variant."""
    m = veil.BTDF2
    for theta in (0.0, 30.0, 60.0, 80.0):
        w = _f(angles.direction(theta, 180.0))
        ft = 1.0 - float(reference_fresnel(math.cos(math.radians(theta)), m.eta))
        want = m.Td + m.Tt * float(reference_hg(m.g, 1.0)) * ft * ft
        assert float(_ft(m, w, w)) == pytest.approx(want, rel=1e-12)
        e = m.replace(variant="exit")
        assert float(_ft(e, w, w)) == pytest.approx(want, rel=1e-12)  # same when T = I


def test_btdf_exit_variant_is_reciprocal():
    rng = np.random.default_rng(3)
    _, _, wa = _upper_dirs(rng, 2000)
    _, _, wb = _upper_dirs(rng, 2000)
    for name in ("BTDF1", "BTDF2", "BTDF3"):
        m = getattr(veil, name).replace(variant="exit")
        assert np.allclose(_ft(m, wa, wb), _ft(m, wb, wa), rtol=1e-13, atol=0)


def test_btdf_paper_variant_is_not_reciprocal():
    m = veil.HenyeyGreenstein(Td=0.0, Tt=0.13, g=0.93, eta=1.3)  # lobe only
    wa = _f(angles.direction(10.0, 180.0))
    wb = _f(angles.direction(70.0, 0.0))
    fab, fba = float(_ft(m, wa, wb)), float(_ft(m, wb, wa))
    # ratio is (F_t(10) / F_t(70))^2 exactly
    ta = 1 - float(reference_fresnel(math.cos(math.radians(10)), 1.3))
    tb = 1 - float(reference_fresnel(math.cos(math.radians(70)), 1.3))
    assert fab / fba == pytest.approx((ta / tb) ** 2, rel=1e-12)
    assert abs(fab / fba - 1) > 0.05
    rng = np.random.default_rng(5)
    _, _, u = _upper_dirs(rng, 500)
    _, _, v = _upper_dirs(rng, 500)
    assert not np.allclose(_ft(m, u, v), _ft(m, v, u), rtol=1e-3)


def test_btdf_variant_must_be_known():
    with pytest.raises(ValueError, match="variant"):
        veil.HenyeyGreenstein(Td=1e-3, Tt=0.1, g=0.9, eta=1.3, variant="both")


# ----------------------------------------------------------------------------------------
# Parameter validation
# ----------------------------------------------------------------------------------------

TS_OK = dict(Pd=2e2, Ps=5e5, n=0.8, eta=1.55)
HG_OK = dict(Td=1e-3, Tt=0.13, g=0.93, eta=1.3)

BAD = [
    (veil.TorranceSparrow, TS_OK, "Pd", -1.0),
    (veil.TorranceSparrow, TS_OK, "Ps", -1e-9),
    (veil.TorranceSparrow, TS_OK, "n", 0.0),
    (veil.TorranceSparrow, TS_OK, "n", -0.5),
    (veil.TorranceSparrow, TS_OK, "eta", 0.0),
    (veil.TorranceSparrow, TS_OK, "eta", -1.3),
    (veil.HenyeyGreenstein, HG_OK, "Td", -1e-3),
    (veil.HenyeyGreenstein, HG_OK, "Tt", -0.1),
    (veil.HenyeyGreenstein, HG_OK, "g", 1.0),
    (veil.HenyeyGreenstein, HG_OK, "g", -1.0),
    (veil.HenyeyGreenstein, HG_OK, "g", 1.5),
    (veil.HenyeyGreenstein, HG_OK, "eta", 0.0),
    (veil.HenyeyGreenstein, HG_OK, "eta", -2.0),
]
for _cls, _ok in ((veil.TorranceSparrow, TS_OK), (veil.HenyeyGreenstein, HG_OK)):
    for _name in _ok:
        for _v in (float("nan"), float("inf"), float("-inf")):
            BAD.append((_cls, _ok, _name, _v))


@pytest.mark.parametrize("cls, ok, name, value", BAD,
                         ids=[f"{c.__name__}-{n}-{v}" for c, _, n, v in BAD])
def test_invalid_parameter_raises_naming_it(cls, ok, name, value):
    kwargs = dict(ok, **{name: value})
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        cls(**kwargs)


def test_valid_edge_parameters_accepted():
    veil.TorranceSparrow(Pd=0.0, Ps=0.0, n=1e-3, eta=1.0)
    veil.HenyeyGreenstein(Td=0.0, Tt=0.0, g=-0.999, eta=1.0)
    veil.HenyeyGreenstein(Td=0.0, Tt=0.0, g=0.999, eta=0.5)


# ----------------------------------------------------------------------------------------
# Angles (docs/model.md sec. 1)
# ----------------------------------------------------------------------------------------

def test_direction_unit_and_upper():
    rng = np.random.default_rng(2)
    th, ph = rng.uniform(0, 89.999, 1000), rng.uniform(-360, 720, 1000)
    w = _f(angles.direction(th, ph))
    assert w.shape == (1000, 3)
    assert np.allclose(np.linalg.norm(w, axis=-1), 1.0, atol=1e-15)
    assert np.allclose(np.degrees(np.arccos(w[:, 2])), th, atol=1e-6)
    assert np.allclose(np.degrees(np.arctan2(w[:, 1], w[:, 0])) % 360, ph % 360, atol=1e-8)
    assert np.allclose(_f(angles.direction(0.0, 123.0)), [0, 0, 1], atol=1e-15)


def test_signed_inplane_conventions():
    # light at phi = 180, camera at phi = 0 for non-negative angles
    ti, pi_, tr, pr = (float(v) for v in angles.from_signed_inplane(30.0, 40.0))
    assert (ti, pi_, tr, pr) == (30.0, 180.0, 40.0, 0.0)
    ti, pi_, tr, pr = (float(v) for v in angles.from_signed_inplane(-20.0, -10.0))
    assert (ti, pi_, tr, pr) == (20.0, 0.0, 10.0, 180.0)
    # equal signed angles are mirror images about the normal
    for t in (0.0, 15.0, 60.0):
        ti, pi_, tr, pr = angles.from_signed_inplane(t, t)
        s = _f(angles.direction(ti, pi_)) + _f(angles.direction(tr, pr))
        assert np.allclose(s[:2], 0.0, atol=1e-15)


@DET
@given(ti=st.floats(-89.9, 89.9), tr=st.floats(-89.9, 89.9))
def test_signed_inplane_round_trip(ti, tr):
    back = angles.to_signed_inplane(*angles.from_signed_inplane(ti, tr))
    # angles within the function's tolerance (1e-6 deg) of the normal may come back unsigned
    assert float(back[0]) == pytest.approx(ti, abs=1e-12 if abs(ti) > 1e-6 else 2e-6)
    assert float(back[1]) == pytest.approx(tr, abs=1e-12 if abs(tr) > 1e-6 else 2e-6)


def test_to_signed_inplane_rejects_out_of_plane():
    with pytest.raises(ValueError, match="plane"):
        angles.to_signed_inplane([30.0, 30.0], [180.0, 180.0], [30.0, 30.0], [0.0, 45.0])


@DET
@given(psi=st.floats(0.0, 170.0), rho=st.floats(-80.0, 80.0))
def test_goniometer_round_trip(psi, rho):
    ti, tr = angles.from_goniometer(psi, rho)
    assert float(ti) == pytest.approx(psi / 2 + rho, abs=1e-12)
    assert float(tr) == pytest.approx(psi / 2 - rho, abs=1e-12)
    p2, r2 = angles.to_goniometer(ti, tr)
    assert float(p2) == pytest.approx(psi, abs=1e-12)
    assert float(r2) == pytest.approx(rho, abs=1e-12)


@pytest.mark.parametrize("psi", [30.0, 60.0, 90.0])
def test_goniometer_angle_between_light_and_camera(psi):
    """psi is the angle between I and R for every rotation rho (docs/model.md sec. 1)."""
    rho = np.linspace(-psi / 2 - 40, psi / 2 + 40, 41)
    ti, tr = angles.from_goniometer(psi, rho)
    ok = (np.abs(ti) < 90) & (np.abs(tr) < 90)
    a, pa, b, pb = angles.from_signed_inplane(ti[ok], tr[ok])
    cosang = np.sum(_f(angles.direction(a, pa)) * _f(angles.direction(b, pb)), axis=-1)
    assert np.allclose(np.degrees(np.arccos(np.clip(cosang, -1, 1))), psi, atol=1e-6)
    # rho = 0 is the mirror configuration
    t0 = angles.from_goniometer(psi, 0.0)
    assert float(t0[0]) == float(t0[1]) == psi / 2
