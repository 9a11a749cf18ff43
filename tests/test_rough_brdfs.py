"""The microfacet families rough-plastic and rough-conductor (docs/model.md sec. 8.2-8.3) against the
independent tests/reference_physical.py (numpy/scipy, written from docs/model.md; docs/physics.md),
at the limits where they have closed forms, and for finiteness over the parameter box.

The engine's side (contract, exact Jacobians, brute force through BTDF2) is in
tests/test_model_contract.py; the comparison with Mitsuba 3 in tests/test_rough_plastic_mitsuba.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import reference_physical as phys
from veil._jax import jax, jnp
from veil.errors import ParameterError
from veil.models import REGISTRY, fresnel
from veil.models import rough_conductor as rc
from veil.models import microfacet as mf
from veil.models import rough_plastic as rp

DISTS = ("beckmann", "ggx")


def _dirs(theta, phi):
    return phys.direction(theta, phi)


def _random_pairs(n, seed, max_theta=89.0):
    rng = np.random.default_rng(seed)
    ti, tr = rng.uniform(0, max_theta, n), rng.uniform(0, max_theta, n)
    pi_, pr = rng.uniform(0, 360, n), rng.uniform(0, 360, n)
    return _dirs(ti, pi_), _dirs(tr, pr)


# --------------------------------------------------------------------------------------
# the rough interface: t(mu) and F_int against converged integrals
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", DISTS)
def test_interface_tables_match_the_reference(dist):
    """t(mu) through veil's table and spline within 5e-5 relative up to 89 deg (measured
    <= 1.7e-5) and 1.5e-3 up to 89.99 deg (GGX at alpha = 0.001 there: 1.1e-3); F_int within
    2e-5 (measured <= 7.5e-6) of tests/reference_physical.py's converged quadratures."""
    th = np.concatenate([np.linspace(0.0, 89.0, 60), [89.5, 89.9, 89.99]])
    mu = np.cos(np.radians(th))
    # compiled once, as the engine's programs trace them (op by op every call compiles)
    make = jax.jit(lambda a, e: rp.interface_tables(a, e, dist))
    lookup = jax.jit(rp.transmittance_lookup)
    for alpha in (0.001, 0.02, 0.2, 1.0):
        for eta in (1.05, 1.5, 3.0):
            tables = make(alpha, eta)
            t = np.asarray(lookup(alpha, tables, jnp.asarray(mu)))
            want = phys.transmittance_lookup(mu, alpha, eta, dist, "exact", "exact")
            err = np.abs(t / want - 1.0)
            assert err[th <= 89.0].max() < 5e-5, (alpha, eta, err.max())
            assert err.max() < 1.5e-3, (alpha, eta, err.max())
            f_int = phys.internal_reflectance(alpha, eta, dist, "exact", "exact")
            assert abs(float(tables[2]) - f_int) < 2e-5, (alpha, eta)


@pytest.mark.parametrize("dist", DISTS)
def test_smooth_interface_limits(dist):
    """alpha -> 0: t(mu) -> 1 - F(mu) away from grazing and F_int -> 1 - (1 - F_ext) / eta^2
    (docs/physics.md sec. 2, from reciprocity), F_ext the smooth hemispherical reflectance."""
    alpha, eta = 1e-3, 1.5
    tables = jax.jit(lambda a, e: rp.interface_tables(a, e, dist))(alpha, eta)  # (compiled once)
    mu = np.linspace(0.3, 1.0, 15)
    t = np.asarray(jax.jit(rp.transmittance_lookup)(alpha, tables, jnp.asarray(mu)))
    assert np.allclose(t, 1.0 - np.asarray(fresnel.reflectance(mu, eta)), atol=2e-4)
    x, w = np.polynomial.legendre.leggauss(400)
    c = 0.5 * (x + 1.0)
    f_ext = float(np.sum(w * c * np.asarray(fresnel.reflectance(c, eta))))  # 2 Int F c dc
    assert float(tables[2]) == pytest.approx(1.0 - (1.0 - f_ext) / eta ** 2, abs=5e-5)


# --------------------------------------------------------------------------------------
# f_r with every option (module functions) against the reference
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", DISTS)
@pytest.mark.parametrize("nonlinear", [False, True])
def test_rough_plastic_matches_the_reference_with_every_option(dist, nonlinear):
    wi, wo = _random_pairs(300, 3)
    for rho, alpha, eta, ks in ((0.6, 0.05, 1.5, 1.0), (0.8, 0.3, 1.12, 0.4), (0.3, 0.8, 2.0, 2.0)):
        v = jnp.asarray([rho, alpha, eta, ks])
        got = np.asarray(rp.rough_plastic(v, jnp.asarray(wi), jnp.asarray(wo), dist, nonlinear))
        want = phys.rough_plastic_vec(wi, wo, rho, alpha, eta, ks, dist, nonlinear,
                                      smith="exact", tables="exact")
        assert np.allclose(got, want, rtol=5e-5, atol=0.0), np.max(np.abs(got / want - 1))


def test_family_evaluates_the_module_function_at_its_defaults():
    model = REGISTRY["rough-plastic"](rho=0.7, alpha=0.25, eta=1.3, ks=1.5)
    wi, wo = _random_pairs(50, 4)
    v = jnp.asarray(model.to_vector())
    a = np.asarray(model.evaluate(v, jnp.asarray(wi), jnp.asarray(wo)))
    b = np.asarray(rp.rough_plastic(v, jnp.asarray(wi), jnp.asarray(wo)))
    assert np.allclose(a, b, rtol=1e-13, atol=0.0)


@pytest.mark.parametrize("dist", DISTS)
def test_rough_conductor_matches_the_reference(dist):
    wi, wo = _random_pairs(300, 5)
    for alpha, n, k in ((0.05, 0.2, 3.0), (0.3, 1.5, 0.0), (0.8, 2.7, 3.3), (0.02, 0.5, 0.0)):
        v = jnp.asarray([alpha, n, k, 2.0])
        got = np.asarray(rc.rough_conductor(v, jnp.asarray(wi), jnp.asarray(wo), dist))
        want = phys.rough_conductor_vec(wi, wo, alpha, 2.0, n=n, k=k, distribution=dist)
        assert np.allclose(got, want, rtol=1e-10, atol=1e-14 * np.max(want))


# --------------------------------------------------------------------------------------
# closed forms
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", DISTS)
def test_specular_at_normal_incidence(dist):
    """I = R = z: G1 = 1, D(z) = 1 / (pi alpha^2): f_r = ks F0 / (4 pi alpha^2) + diffuse."""
    z = jnp.asarray([[0.0, 0.0, 1.0]])
    for alpha, eta in ((0.01, 1.12), (0.3, 1.5), (1.0, 3.0)):
        f0 = ((eta - 1) / (eta + 1)) ** 2
        spec = float(rp.rough_plastic(jnp.asarray([0.0, alpha, eta, 1.0]), z, z, dist)[0])
        assert spec == pytest.approx(f0 / (4 * math.pi * alpha ** 2), rel=1e-13)
        tables = rp.interface_tables(alpha, eta, dist)
        t1 = float(rp.transmittance_lookup(alpha, tables, jnp.asarray(1.0)))
        assert t1 == pytest.approx(float(tables[0][-1]), rel=1e-14)   # exactly the last node
        diff = float(rp.rough_plastic(jnp.asarray([0.5, alpha, eta, 0.0]), z, z, dist)[0])
        assert diff == pytest.approx(0.5 / (1 - float(tables[2])) * t1 * t1 / (math.pi * eta ** 2),
                                     rel=1e-13)


@pytest.mark.parametrize("dist", DISTS)
def test_grazing_directions_are_finite_and_continuous(dist):
    """f_r at 90 deg minus 1e-9 is finite, f_r / cos theta_i (reciprocal, finite at grazing
    light) agrees with its value at 90 - 1e-6 deg, and f_r is zero at and beyond the horizon."""
    v = jnp.asarray([0.6, 0.2, 1.12, 1.0])
    for ti, tr, pr in ((30.0, None, 0.0), (None, 30.0, 0.0), (None, None, 0.0), (60.0, None, 90.0)):
        vals = []
        for eps in (1e-9, 1e-6):
            a = 90.0 - eps if ti is None else ti
            b = 90.0 - eps if tr is None else tr
            f = float(rp.rough_plastic(v, jnp.asarray(_dirs(a, 180.0)),
                                       jnp.asarray(_dirs(b, pr)), dist))
            vals.append(f / math.cos(math.radians(a)))
        assert all(math.isfinite(x) for x in vals)
        assert vals[0] == pytest.approx(vals[1], rel=1e-3, abs=1e-9)
    horizon = jnp.asarray([-1.0, 0.0, 0.0])
    assert float(rp.rough_plastic(v, horizon, jnp.asarray(_dirs(20.0, 0.0)), dist)) == 0.0
    assert float(rp.rough_plastic(v, jnp.asarray(_dirs(20.0, 0.0)), -horizon, dist)) == 0.0
    assert float(rp.rough_plastic(v, jnp.asarray(_dirs(20.0, 180.0)),
                                  jnp.asarray(_dirs(95.0, 0.0)), dist)) == 0.0


def test_conductor_fresnel_exact():
    c = np.linspace(0.0, 1.0, 201)
    for n, k in ((0.2, 3.0), (1.5, 0.0), (2.7, 3.3), (0.05, 0.0), (0.7, 0.0), (1e-3, 20.0)):
        got = np.asarray(rc.conductor_reflectance(jnp.asarray(c), n, k))
        assert np.allclose(got, phys.fresnel_conductor(c, n, k), rtol=1e-12, atol=1e-15)
        f0 = ((n - 1) ** 2 + k ** 2) / ((n + 1) ** 2 + k ** 2)
        assert got[-1] == pytest.approx(f0, rel=1e-13)
        assert got[0] == pytest.approx(1.0, abs=1e-15)
        if k == 0.0:  # the dielectric formula of docs/model.md sec. 4, total reflection for n < 1
            assert np.allclose(got, np.asarray(fresnel.reflectance(c, n)), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("dist", DISTS)
def test_conductor_with_a_real_index_is_the_plastic_lobe(dist):
    wi, wo = _random_pairs(100, 6)
    wi, wo = jnp.asarray(wi), jnp.asarray(wo)
    a = rc.rough_conductor(jnp.asarray([0.2, 1.4, 0.0, 0.7]), wi, wo, dist)
    b = rp.rough_plastic(jnp.asarray([0.0, 0.2, 1.4, 0.7]), wi, wo, dist)
    assert np.allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=0.0)


# --------------------------------------------------------------------------------------
# finite values and derivatives over the whole parameter box, up to 90 deg - 1e-9
# --------------------------------------------------------------------------------------
_EDGE_THETAS = (0.0, 1e-7, 30.0, 75.0, 89.9, 90.0 - 1e-9)


def _edge_pairs():
    th = np.array(_EDGE_THETAS)
    ti, tr = np.meshgrid(th, th)
    wi = _dirs(ti.ravel(), 180.0)
    wo = np.concatenate([_dirs(tr.ravel(), 0.0), _dirs(tr.ravel(), 90.0)])
    return jnp.asarray(np.concatenate([wi, wi])), jnp.asarray(wo)


@pytest.mark.parametrize("dist", DISTS)
def test_rough_plastic_finite_with_finite_derivatives_on_the_box(dist):
    wi, wo = _edge_pairs()
    f = jax.jit(lambda v: rp.rough_plastic(v, wi, wo, dist))
    jf = jax.jit(jax.jacfwd(lambda v: rp.rough_plastic(v, wi, wo, dist)))
    for alpha in (1e-3, 0.1, 1.0):
        for eta in (1.0 + 1e-9, 1.12, 3.0):
            for rho, ks in ((0.0, 0.0), (1.0, 1.0), (1e6, 1e6)):
                v = jnp.asarray([rho, alpha, eta, ks])
                assert np.all(np.isfinite(np.asarray(f(v)))), (alpha, eta, rho, ks)
                assert np.all(np.isfinite(np.asarray(jf(v)))), (alpha, eta, rho, ks)


@pytest.mark.parametrize("dist", DISTS)
def test_rough_conductor_finite_with_finite_derivatives_on_the_box(dist):
    wi, wo = _edge_pairs()
    f = jax.jit(lambda v: rc.rough_conductor(v, wi, wo, dist))
    jf = jax.jit(jax.jacfwd(lambda v: rc.rough_conductor(v, wi, wo, dist)))
    for alpha in (1e-3, 0.1, 1.0):
        for n, k in ((1e-9, 0.0), (0.5, 0.0), (1.0, 0.0), (10.0, 0.0), (1e-9, 20.0), (10.0, 20.0),
                     (1.0, 3.0)):
            v = jnp.asarray([alpha, n, k, 1.0])
            assert np.all(np.isfinite(np.asarray(f(v)))), (alpha, n, k)
            assert np.all(np.isfinite(np.asarray(jf(v)))), (alpha, n, k)


@pytest.mark.parametrize("dist", DISTS)
def test_facet_law_is_normalized_and_its_inverse_reaches_the_horizon(dist):
    for alpha in (1e-3, 0.1, 1.0):
        assert float(mf.facet_cdf(alpha, math.pi / 2, dist)) == 1.0
        assert float(mf.facet_inverse_cdf(alpha, 1.0, dist)) == pytest.approx(math.pi / 2)
        assert float(mf.facet_inverse_cdf(alpha, 0.0, dist)) == 0.0
        # D(H) cos theta_H integrates to 1 over the hemisphere: theta = atan(alpha tan beta)
        x, w = np.polynomial.legendre.leggauss(400)
        beta = 0.25 * math.pi * (x + 1.0)
        theta = np.arctan(alpha * np.tan(beta))
        dtheta = alpha / np.cos(beta) ** 2 / (1.0 + (alpha * np.tan(beta)) ** 2)
        d = np.asarray(mf.ndf(jnp.cos(theta), jnp.sin(theta) ** 2, alpha, dist))
        total = 0.25 * math.pi * np.sum(w * 2 * math.pi * np.sin(theta) * np.cos(theta) * d * dtheta)
        assert total == pytest.approx(1.0, rel=1e-9)
        th = np.linspace(0.0, 1.5, 301)
        d = np.asarray(mf.ndf(jnp.cos(th), jnp.sin(th) ** 2, alpha, dist))
        assert np.allclose(d * np.cos(th), np.asarray(mf.facet_weight(alpha, jnp.asarray(th),
                                                                         None, dist)),
                           rtol=1e-12, atol=1e-300)
        # (the reference forms tan^2 = (1 - c^2) / c^2, which cancels near the normal;
        # veil's Beckmann D is 0 beyond tan^2 / alpha^2 = 200, 1.4e-87 of its peak)
        peak = 1.0 / (math.pi * alpha ** 2)
        assert np.allclose(d, phys.microfacet_D(np.cos(th), alpha, dist), rtol=1e-8,
                           atol=1e-86 * peak)


# --------------------------------------------------------------------------------------
# options reach the engine; the one that cannot is refused
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["rough-plastic", "rough-conductor"])
def test_the_distribution_option_reaches_veil_reflectance(name):
    """veil.reflectance (the engine's jitted f_r) with GGX equals the reference's GGX, and
    differs from Beckmann's by far more than the tolerance."""
    import veil

    model = REGISTRY[name].template().replace(alpha=0.2)
    ti, tr = np.array([10.0, 30.0, 60.0]), np.array([40.0, 30.0, 20.0])
    wi = np.stack([-np.sin(np.radians(ti)), 0 * ti, np.cos(np.radians(ti))], axis=1)
    wo = np.stack([np.sin(np.radians(tr)), 0 * tr, np.cos(np.radians(tr))], axis=1)
    for dist in ("beckmann", "ggx"):
        m = model.replace(distribution=dist)
        got = veil.reflectance(m, ti, tr)
        if name == "rough-plastic":
            want = phys.rough_plastic_vec(wi, wo, m.rho, m.alpha, m.eta, m.ks, dist, False,
                                          smith="exact", tables="exact")
        else:
            want = phys.rough_conductor_vec(wi, wo, m.alpha, m.ks, n=m.n, k=m.k,
                                            distribution=dist, smith="exact")
        assert np.allclose(got, want, rtol=5e-5), (dist, got, want)
    other = veil.reflectance(model.replace(distribution="beckmann"), ti, tr)
    assert np.max(np.abs(got / other - 1)) > 0.05


def test_the_nonlinear_diffuse_is_refused_with_the_reason():
    model = REGISTRY["rough-plastic"].template()
    with pytest.raises(ParameterError, match="linearly"):
        model.replace(nonlinear=True)
    with pytest.raises(ParameterError, match="expected one of"):
        model.replace(distribution="phong")


def test_schlick_alternative_matches_the_reference():
    c = np.linspace(0.0, 1.0, 51)
    for f0 in (0.04, 0.5, 0.95):
        assert np.allclose(np.asarray(rc.schlick_reflectance(jnp.asarray(c), f0)),
                           phys.fresnel_schlick(c, f0), rtol=1e-14)
