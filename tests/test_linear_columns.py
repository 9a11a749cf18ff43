"""A linear family's derivative in its coefficients is its values at unit vectors
(veil.engine.forward.LinearForward): no program of derivatives is compiled or run for it,
and the columns are those of the linear fit's design (veil.fitting.linear_fit.design)."""

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
    assert np.array_equal(value, fwd(vb, vm))
    for k, i in enumerate(free):
        unit = np.zeros_like(vb)
        unit[i] = 1.0
        # linear: the column is the family's values at the unit vector, to rounding
        assert np.allclose(jac[:, k], fwd(unit, vm), rtol=1e-12, atol=0.0)
        assert np.all(jac[:, k] >= 0.0) and np.max(jac[:, k]) > 0.0
    # a coefficient of an inactive width's group (w12_3 is 0 here) still has its column
    assert np.max(jac[:, 2]) > 0.0
