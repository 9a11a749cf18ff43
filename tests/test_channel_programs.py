"""Several colour channels of a forward-series water in one program (docs/channels.md,
"Cost"; veil.engine.channel_programs): phase grids drawn from one sampling law of all the
channels, each channel's phase weighting the shared nodes. Checked against the independent
reference (tests/reference_physical.py), against each channel's own program, and its
Jacobian against finite differences of the same quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest

import reference_physical as rphys
from test_model_contract import _ts_fn, ref_preset
from veil._jax import jax, jnp
from veil.engine import channel_programs, integrator
from veil.engine.angles import direction
from veil.engine.forward import Forward
from veil.engine.quadrature import RULES
from veil.models import REGISTRY

SERIES = REGISTRY["forward-series"]
PLATE = {"path_length": 15.0, "plate_width": 5.0}


def _waters(taus, omegas, g=0.9, **options):
    return [SERIES(tau=t, omega=w, g=g, **options) for t, w in zip(taus, omegas)]


def _anticipated_values(brdf, waters, ti, tr, rule, pi_=180.0, pr=0.0):
    """Each water's apparent reflectance through one Forward whose channels' program ran
    (anticipate), and the Forward."""
    f = Forward(brdf, waters[0], ti, tr, pi_, pr, rule)
    vb = brdf.to_vector()
    vms = [w.to_vector() for w in waters]
    assert channel_programs.anticipate(f, [vb] * len(vms), vms)
    runs = []
    original = f._run
    f._run = lambda fn, *a: runs.append(fn) or original(fn, *a)
    out = [f(vb, vm) for vm in vms]
    assert runs == []  # every channel answered by the channels' program
    return out, f


def test_channels_on_one_law_match_the_independent_reference():
    """Two waters of very different optical depth (0.3 and 1.5; their lobes' order weights
    differ most) through the finite plate, at the default rule, each within the tolerance
    the one-channel engine meets against tests/reference_physical.py
    (test_model_contract.py)."""
    brdf = ref_preset("BRDF2")
    taus, omegas = (0.3, 1.5), (0.95, 0.99)
    waters = _waters(taus, omegas, g=0.88, **PLATE)
    ti, tr = np.array([20.0, 60.0]), np.array([25.0, 10.0])
    got, _ = _anticipated_values(brdf, waters, ti, tr, RULES["default"])
    for c, (tau, omega) in enumerate(zip(taus, omegas)):
        for k in range(ti.size):
            want, se = rphys.forward_series_apparent(
                _ts_fn(brdf),
                tau,
                omega,
                0.88,
                1.0,
                ti[k],
                tr[k],
                path_length=15.0,
                plate_half_width=2.5,
                n_qmc=2**12,
                n_rep=6,
            )
            assert abs(got[c][k] - want) <= 4 * se + 1e-3 * want, (c, k, got[c][k], want, se)


def test_channels_on_one_law_agree_with_each_channel_alone():
    """Rough plastic through three waters (tau 0.45, 0.3, 0.15), in and out of the plane
    of incidence, fast rule: each channel's values within 0.5 % of its own program's
    (measured: at most 0.03 %), and the channels' values differ from each other by far
    more; waters that differ only in scales do not take this path."""
    brdf = REGISTRY["rough-plastic"](rho=0.5, alpha=0.1, eta=1.12, ks=1.0)
    waters = _waters((0.45, 0.3, 0.15), (0.95, 0.97, 0.99), **PLATE)
    th = np.linspace(-80.0, 80.0, 23)
    ti, tr, pr = np.full(th.size, 60.0), np.abs(th), np.where(th < 0, 150.0, 10.0)
    got, f = _anticipated_values(brdf, waters, ti, tr, RULES["fast"], 180.0, pr)
    errors = []
    for c, water in enumerate(waters):
        alone = Forward(brdf, water, ti, tr, 180.0, pr, RULES["fast"])
        errors.append(np.abs(got[c] / alone(brdf.to_vector(), water.to_vector()) - 1))
    print("largest relative difference from each channel's own program:", np.max(errors))
    assert np.max(errors) < 5e-3
    assert np.all(np.abs(got[0] / got[2] - 1) > 3 * np.maximum(errors[0], errors[2]))
    same = [waters[0].to_vector(), waters[0].replace(s=2.0).to_vector()]
    assert not channel_programs.anticipate(f, [brdf.to_vector()] * 2, same)


def _fixed_law_terms(brdf, water, vb, vms, wi, wr, rule):
    """apparent_terms_channels with the sampling law of ``vms`` held (a jitted function of
    the parameters)."""
    bt, mt = integrator.template(brdf), integrator.template(water)
    law = integrator.channel_law(mt, vms)
    return jax.jit(
        lambda b, m: integrator.apparent_terms_channels(bt, mt, rule, b, m, wi, wr, False, law)
    )


@pytest.mark.parametrize("wrt", ["brdf", "medium"])
def test_channels_jacobian_is_the_derivative_of_their_quadrature(wrt):
    """The channels' Jacobian program (forward mode through the shared nodes) against
    central differences of the channels' terms with the sampling law held: each channel's
    derivatives in the shared BRDF's alpha and eta, or in its own tau, omega and the shared
    g, to 1e-5 of the terms (the one-channel program meets 3e-6 against the same
    differences in alpha: the quadrature's tables are not smooth to the differences' step;
    a derivative that missed the law's weights or another channel's tangent is 1e-2 off)."""
    brdf = REGISTRY["rough-plastic"](rho=0.5, alpha=0.15, eta=1.3, ks=1.0)
    waters = _waters((0.6, 0.35), (0.95, 0.99), **PLATE)
    ti, tr, pr = (
        np.array([60.0, 40.0, 30.0]),
        np.array([50.0, 20.0, 70.0]),
        np.array([0.0, 30.0, 90.0]),
    )
    rule = RULES["fast"]
    f = Forward(brdf, waters[0], ti, tr, 180.0, pr, rule)
    vb = np.asarray(brdf.to_vector())
    vms = np.stack([w.to_vector() for w in waters])
    free = ((1, 2), ()) if wrt == "brdf" else ((), (0, 1, 2))
    one, many = channel_programs._programs(f, 2, free)
    terms, jac = (np.asarray(a)[: ti.size] for a in f._run(many, vb, vms))
    wi = jnp.asarray(np.asarray(direction(ti, np.full(3, 180.0))))
    wr = jnp.asarray(np.asarray(direction(tr, pr)))
    g = _fixed_law_terms(brdf, waters[0], vb, vms, wi, wr, rule)
    np.testing.assert_allclose(np.asarray(g(vb, vms)), terms, rtol=1e-12, atol=1e-15)
    scale = np.max(np.abs(terms))
    for k, i in enumerate(free[0] or free[1]):
        h = 1e-6 * max(1.0, abs((vb if wrt == "brdf" else vms[0])[i]))
        if wrt == "brdf":
            up, down = vb.copy(), vb.copy()
            up[i] += h
            down[i] -= h
            diff = (np.asarray(g(up, vms)) - np.asarray(g(down, vms))) / (2 * h)
        else:
            up, down = vms.copy(), vms.copy()
            up[:, i] += h
            down[:, i] -= h
            diff = (np.asarray(g(vb, up)) - np.asarray(g(vb, down))) / (2 * h)
        assert np.max(np.abs(jac[..., k] - diff)) < 1e-5 * scale, (wrt, i)
    assert math.isfinite(scale) and scale > 0
