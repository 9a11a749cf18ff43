"""Uncertainty through the pipeline (veil.analysis.uncertainty, docs/model.md sec. 7).

The two-step fits run on small sessions (55 configurations, one engine chunk) at the "fast"
quadrature; the point is the propagation arithmetic, checked against its definition, the
fits' own first-order totals and a sampling of step 1's distribution. The noise is 0.3 %, so
that the medium's spread moves the target by a few per cent, where a first-order
propagation should hold (at 1 % noise Ps moves by up to 90 % and the linearization visibly
underestimates the tail: docs/ambiguity.md).
"""

import dataclasses

import numpy as np
import pytest

import veil
from support.chain import small_chain
from veil.analysis.uncertainty import PARTS, budget_table, propagate, sample_propagation
from veil.errors import InputTypeError
from veil.fitting import FitError, fit_target


@pytest.fixture(scope="module")
def steps():
    chain = small_chain()
    r2 = fit_target(chain["target"], chain["r1"], accuracy="fast")
    assert chain["r0"].converged and chain["r1"].converged and r2.converged
    return dict(chain, r2=r2)


def test_budget_adds_up_and_matches_the_fits_own_total(steps):
    r2 = steps["r2"]
    p = propagate(r2, steps["r1"], steps["target"])
    budget = p.stats["budget"]
    assert set(budget) == set(r2.free)
    for name, entry in budget.items():
        assert set(entry) == set(PARTS) | {"total"}
        assert all(entry[k] >= 0 for k in PARTS)
        assert entry["total"] == pytest.approx(sum(entry[k] for k in PARTS), rel=1e-12)
        assert p.stderr_total[name] == pytest.approx(np.sqrt(entry["total"]), rel=1e-12)
        assert entry["step2"] == pytest.approx(r2.stderr[name] ** 2, rel=1e-12)
        assert p.stderr_total[name] > r2.stderr[name]
        # veil.fitting.steps chains the same first-order propagation inside fit_target
        assert p.stderr_total[name] == pytest.approx(r2.stderr_total[name], rel=1e-4)
    # through a strongly scattering medium step 1 is a large part of n's budget
    rows = {row["parameter"]: row for row in budget_table(p)}
    assert rows["n"]["step1_%"] > 20
    assert sum(rows["n"][f"{k}_%"] for k in PARTS) == pytest.approx(100.0)
    assert p.stderr == r2.stderr and p.params == r2.params
    assert "propagated by linearization" in p.message


def test_explicit_step0_equals_the_chained_one(steps):
    implicit = propagate(steps["r2"], steps["r1"], steps["target"])
    explicit = propagate(steps["r2"], steps["r1"], steps["target"],
                         reference_result=steps["r0"], reference_table=steps["ref_medium"])
    for name, entry in explicit.stats["budget"].items():
        assert entry["step0"] > 0
        assert entry["step0"] == pytest.approx(implicit.stats["budget"][name]["step0"], rel=1e-4)
    # without step 0's information there is no step-0 entry
    bare = dataclasses.replace(steps["r1"], stderr_total=None, correlation_total=None)
    target = dataclasses.replace(steps["r2"], given=None)
    alone = propagate(target, bare, steps["target"])
    assert all("step0" not in e for e in alone.stats["budget"].values())


def test_linearization_agrees_with_sampling(steps):
    s = sample_propagation(steps["r2"], steps["r1"], steps["target"], n_draws=12, seed=3)
    assert s["converged"].all() and s["redrawn"] == 0   # a medium far inside its bounds
    assert s["shifts"].shape == s["linear"].shape == (12, 4)
    names = s["names"]
    for k, name in enumerate(names):
        shift, lin = s["shifts"][:, k], s["linear"][:, k]
        # draw by draw, the refit moves as the linearization predicts
        assert np.corrcoef(shift, lin)[0, 1] > 0.98, name
        assert np.sum(shift ** 2) / np.sum(lin ** 2) == pytest.approx(1.0, abs=0.1), name
        assert np.std(shift) > 0
    # the sampled covariance equals the linear one over the same draws ...
    lin_cov = np.cov(s["linear"], rowvar=False)
    sd = np.sqrt(np.diag(lin_cov))
    assert np.allclose(s["covariance"] / np.outer(sd, sd), lin_cov / np.outer(sd, sd),
                       atol=0.1)
    # ... and the population one is propagate()'s step-1 part
    p = propagate(steps["r2"], steps["r1"], steps["target"])
    for k, name in enumerate(names):
        assert s["linear_covariance"][k, k] == pytest.approx(
            p.stats["budget"][name]["step1"], rel=1e-3)


def test_bad_input(steps):
    r0, r1, r2, target = steps["r0"], steps["r1"], steps["r2"], steps["target"]
    with pytest.raises(FitError, match="step-2 fit"):
        propagate(r1, r1, target)
    with pytest.raises(FitError, match="step-1 fit"):
        propagate(r2, r0, target)
    other = dataclasses.replace(r1, params={**r1.params, "Tt": r1.params["Tt"] * 1.1})
    with pytest.raises(FitError, match="different medium"):
        propagate(r2, other, target)
    with pytest.raises(FitError, match="give both reference_result"):
        propagate(r2, r1, target, reference_result=r0)
    with pytest.raises(FitError, match="the target fit used 55"):
        propagate(r2, r1, target.iloc[:40])
    undetermined = dataclasses.replace(r1, stderr={k: None for k in r1.stderr},
                                       stderr_total=None)
    with pytest.raises(FitError, match="no standard error"):
        propagate(dataclasses.replace(r2, given=None), undetermined, target)
    with pytest.raises(FitError, match="n_draws"):
        sample_propagation(r2, r1, target, n_draws=1)
    with pytest.raises(FitError, match="no uncertainty budget"):
        budget_table(r2)


def test_curve_stderr_is_the_total_covariance_through_central_differences(steps):
    """se of f_r per configuration = sqrt(J C J^T), with J by central differences of
    veil.reflectance (an independent path) over the free parameters only, C the total
    covariance; a sampled check: the spread of f_r over parameters drawn from C agrees."""
    from veil.analysis.uncertainty import curve_stderr

    r2 = steps["r2"]
    ti = np.array([10.0, 30.0, 45.0, 60.0, 20.0])
    tr = np.array([10.0, 32.0, 44.0, 20.0, 70.0])
    angles = (ti, np.full(5, 180.0), tr, np.zeros(5))
    values, se = curve_stderr(r2, angles)
    names, cov = r2.covariance(total=True)
    assert set(names) == set(r2.free) and len(names) >= 3

    def f_r(params):
        model = type(r2.as_model()).from_params(params, r2.options)
        return veil.reflectance(model, ti, tr)

    assert np.allclose(values, f_r(r2.params), rtol=1e-12)
    jac = []
    for n in names:
        h = 1e-5 * max(abs(r2.params[n]), 1.0)
        up, down = dict(r2.params), dict(r2.params)
        up[n] += h
        down[n] -= h
        jac.append((f_r(up) - f_r(down)) / (2 * h))
    jac = np.array(jac).T
    expected = np.sqrt(np.einsum("ij,jk,ik->i", jac, cov, jac))
    assert np.allclose(se, expected, rtol=1e-4)
    # the own covariance (without step 1) gives a smaller band here: the total is used
    own = dataclasses.replace(r2, stderr_total=None, correlation_total=None)
    assert np.all(curve_stderr(own, angles)[1] < se)

    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal([r2.params[n] for n in names], cov, size=400)
    curves = np.array([f_r({**r2.params, **dict(zip(names, d))}) for d in draws])
    assert np.allclose(curves.std(axis=0), se, rtol=0.2)


def test_curve_stderr_refuses_a_medium(steps):
    from veil.analysis.uncertainty import curve_stderr

    with pytest.raises(InputTypeError, match="BRDF result"):
        curve_stderr(steps["r1"], (np.array([10.0]), np.array([180.0]), np.array([10.0]),
                                   np.array([0.0])))


def test_draws_outside_the_bounds_are_redrawn_and_counted():
    """A forward-series medium with tau's standard error above its value (the thin medium
    of docs/validity.md): every draw inside the bounds, the redrawn ones counted."""
    from veil.analysis.uncertainty import _draw
    from veil.models import model_class

    cls = model_class("forward-series")
    names = ["tau", "omega", "g"]
    mean = np.array([0.108, 0.99, 0.98])
    cov = np.diag([0.18, 0.004, 0.01]) ** 2
    draws, redrawn = _draw(np.random.default_rng(0), mean, cov, names, 200, cls)
    assert draws.shape == (200, 3)
    assert np.all(draws[:, 0] >= 0) and np.all(draws[:, 1] <= 1) and np.all(draws[:, 2] < 1)
    # P(tau < 0) = 0.27, P(omega > 1) = 0.006, P(g >= 1) = 0.023: a draw is rejected with
    # probability 0.29, about 0.41 redrawn per kept (82 expected, sd about 11)
    assert 50 < redrawn < 120
    again, n = _draw(np.random.default_rng(0), mean, cov, names, 200, cls)
    assert n == redrawn and np.array_equal(again, draws)
