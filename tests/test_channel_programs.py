"""Several colour channels of a forward-series water in one program (docs/channels.md,
"Cost"; veil.engine.channel_programs): phase grids drawn from one sampling law of all the
channels, each channel's phase weighting the shared nodes. Checked against the independent
reference (tests/reference_physical.py), against each channel's own program, and its
Jacobian against finite differences of the same quadrature."""

from __future__ import annotations

import math

import numpy as np

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


#: Off-plane configurations (the full azimuth range: no symmetry).
TI, TR = np.full(9, 60.0), np.array([75.0, 60.0, 45.0, 30.0, 10.0, 20.0, 40.0, 55.0, 70.0])
PR = np.array([0.0, 5.0, 10.0, 30.0, 60.0, 120.0, 160.0, 175.0, 180.0])
#: In-plane configurations (half the azimuths: the programs of tests/test_channels_medium.py)
IN_TR, IN_PR = np.array([80.0, 50.0, 20.0, 5.0, 15.0, 45.0, 75.0]), np.array([180.0] * 3 + [0.0] * 4)


def test_channels_on_one_law_agree_with_each_channel_alone():
    """The paper's BRDF through three waters (tau 0.45, 0.3, 0.15) out of the plane of
    incidence, fast rule: each channel's values within 0.5 % of its own program's (measured:
    at most 0.015 %), and the channels' values differ from each other by far more; waters
    that differ only in scales do not take this path."""
    brdf = ref_preset("BRDF2")
    waters = _waters((0.45, 0.3, 0.15), (0.95, 0.97, 0.99), **PLATE)
    got, f = _anticipated_values(brdf, waters, TI, TR, RULES["fast"], 180.0, PR)
    errors = []
    for c, water in enumerate(waters):
        alone = Forward(brdf, water, TI, TR, 180.0, PR, RULES["fast"])
        errors.append(np.abs(got[c] / alone(brdf.to_vector(), water.to_vector()) - 1))
    print("largest relative difference from each channel's own program:", np.max(errors))
    assert np.max(errors) < 5e-3
    assert np.all(np.abs(got[0] / got[2] - 1) > 3 * np.maximum(errors[0], errors[2]))
    same = [waters[0].to_vector(), waters[0].replace(s=2.0).to_vector()]
    assert not channel_programs.anticipate(f, [brdf.to_vector()] * 2, same)


def test_channels_jacobian_is_the_derivative_of_their_quadrature():
    """The channels' Jacobian programs (forward mode through the shared nodes; in the plane
    of incidence, the programs a fit of tests/test_channels_medium.py runs) against
    central differences of the channels' terms: each channel's derivatives in the shared
    BRDF's n and eta (differences of the channels' values program: the law does not depend
    on the BRDF), and in its own tau, omega and the shared g and eta_u (differences of the
    quadrature with the sampling law held, as the program holds it), to 1e-5 of the terms
    (a derivative that missed the law's weights or another channel's tangent is 1e-2 off)."""
    brdf = ref_preset("BRDF2")
    # eta_u off 1, where the boundary's Fresnel factors vanish and have a kink
    waters = [w.replace(eta_u=1.33) for w in _waters((0.45, 0.3, 0.15), (0.95, 0.97, 0.99),
                                                     **PLATE)]
    rule = RULES["fast"]
    m = IN_TR.size
    ti = np.full(m, 60.0)
    f = Forward(brdf, waters[0], ti, IN_TR, 180.0, IN_PR, rule)
    assert f.half
    vb = np.asarray(brdf.to_vector())
    vms = np.stack([w.to_vector() for w in waters])
    values = channel_programs._programs(f, 3, None)[1]
    wi = jnp.asarray(np.asarray(direction(ti, np.full(m, 180.0))))
    wr = jnp.asarray(np.asarray(direction(IN_TR, IN_PR)))
    held = _fixed_law_terms(brdf, waters[0], vms, wi, wr, rule)
    for wrt, free in (("brdf", ((2, 3), ())), ("medium", ((), (0, 1, 2, 3)))):
        terms, jac = (np.asarray(a)[:m] for a in f._run(channel_programs._programs(
            f, 3, free)[1], vb, vms))
        scale = np.max(np.abs(terms))
        assert math.isfinite(scale) and scale > 0
        for k, i in enumerate(free[0] or free[1]):
            if wrt == "brdf":
                h = 1e-6 * abs(vb[i])
                up, down = vb.copy(), vb.copy()
                up[i] += h
                down[i] -= h
                diff = (np.asarray(f._run(values, up, vms)) -
                        np.asarray(f._run(values, down, vms)))[:m] / (2 * h)
            else:
                h = 1e-6
                up, down = vms.copy(), vms.copy()
                up[:, i] += h
                down[:, i] -= h
                diff = (np.asarray(held(vb, up)) - np.asarray(held(vb, down))) / (2 * h)
            assert np.max(np.abs(jac[..., k] - diff)) < 1e-5 * scale, (wrt, i)


def _fixed_law_terms(brdf, water, vms, wi, wr, rule):
    """apparent_terms_channels with the sampling law of ``vms`` held (a jitted function of
    the parameters)."""
    bt, mt = integrator.template(brdf), integrator.template(water)
    law = integrator.channel_law(mt, vms)
    return jax.jit(lambda b, m: integrator.apparent_terms_channels(
        bt, mt, rule, b, m, wi, wr, True, law))
