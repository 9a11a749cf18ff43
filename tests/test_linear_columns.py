"""A linear family's derivative in its coefficients is its values at unit vectors
(veil.engine.forward.LinearForward): no program of derivatives is compiled or run for it,
and each column is the change of the family's values when its coefficient grows by one."""

from __future__ import annotations

import numpy as np

from veil.engine.evaluator import CHUNK
from veil.engine.forward import Forward, LinearForward
from veil.engine.quadrature import RULES
from veil.models import PRESETS
from veil.models.henyey_greenstein import HenyeyGreenstein
from veil.models.nonparametric import NonParametric


def _forward():
    # the fits' chunk at the fast rule, through the first preset of the paper's medium: the
    # values program tests/test_model_contract.py compiles for this family
    ti, tr = np.linspace(5.0, 75.0, CHUNK), np.linspace(70.0, 10.0, CHUNK)
    brdf = NonParametric.template().replace(d0=0.4, w02_1=0.35, w09_2=0.2)
    medium = next(m for m in PRESETS.values() if isinstance(m, HenyeyGreenstein))
    return Forward(brdf, medium, ti, tr, rule=RULES["fast"])


def test_the_coefficients_columns_need_no_program_of_derivatives(monkeypatch):
    fwd = _forward()
    assert isinstance(fwd, LinearForward)
    vb, vm = fwd.brdf.to_vector(), fwd.medium.to_vector()
    free = (NonParametric.index("d1"), NonParametric.index("w02_1"),
            NonParametric.index("w12_3"))

    def refuse(*args, **kwargs):
        raise AssertionError("a program of derivatives was asked for")

    monkeypatch.setattr(Forward, "_jacobian_fn", refuse)
    assert fwd.prepare(values=False, jacobians=[((0, 1), ())])  # the values program alone
    value, jac = fwd.value_and_jacobian(vb, vm, free, ())
    assert np.allclose(value, fwd(vb, vm), rtol=1e-12, atol=0.0)
    for k, i in enumerate(free):
        # linear: the column is the change of the family's values when the coefficient grows
        # by 1 from the plate's (other group vectors than the column's own unit vector)
        step = vb.copy()
        step[i] += 1.0
        assert np.allclose(jac[:, k], fwd(step, vm) - fwd(vb, vm), rtol=1e-9,
                           atol=1e-12 * np.max(np.abs(jac[:, k])))
        assert np.all(jac[:, k] >= 0.0) and np.max(jac[:, k]) > 0.0
    assert not np.allclose(jac[:, 0], jac[:, 1], rtol=1e-3)  # distinct basis functions


def test_with_the_medium_free_too_the_coefficients_columns_are_the_same():
    """With the medium's derivatives asked for as well, the value (then from the groups'
    Jacobian programs) and the coefficients' columns are those without."""
    fwd = _forward()
    vb, vm = fwd.brdf.to_vector(), fwd.medium.to_vector()
    free = (NonParametric.index("d0"), NonParametric.index("w09_2"))
    alone_value, alone = fwd.value_and_jacobian(vb, vm, free, ())
    value, jac = fwd.value_and_jacobian(vb, vm, free, (0, 1))
    assert np.allclose(value, alone_value, rtol=1e-12, atol=0.0)
    assert np.array_equal(jac[:, :2], alone)
    # the medium's scales (Td, Tt): the values are quadratic in them (rows Td^2, Td Tt,
    # Tt^2) and the sampling does not move with them, so a forward difference of 1e-3 of
    # the scale is its derivative to about 1e-3
    for k in (0, 1):
        up = vm.copy()
        up[k] *= 1.0 + 1e-3
        moved = (fwd(vb, up) - fwd(vb, vm)) / (vm[k] * 1e-3)
        assert np.allclose(jac[:, 2 + k], moved, rtol=1e-2, atol=1e-9 * np.max(np.abs(moved)))
