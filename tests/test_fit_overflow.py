"""Scales that overflow float64 in a step fit: a given medium whose scale coefficients do
(exit 2 naming them, docs/errors.md), a fixed scale that makes every start's cost overflow
(named), a model-error sigma beyond the range of a relative error (exit 2 naming the file
and key), and the starting values' solves, which stay finite for finite inputs of any
magnitude."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import veil
from support.cli import run
from veil.errors import FitError
from veil.fitting import fit_medium, fit_target
from veil.fitting.model_error import MAX_SIGMA, ModelError, estimate, sandwich
from veil.fitting.result import FitResult, load_result
from veil.fitting.result_fields import model_entry
from veil.fitting.start_values import brdf_scales, medium_scales, weighted_nnls
from veil.models import preset

SMALL = dict(psi=(30, 90), fine_step=4, coarse_step=15, glow=0.0, accuracy="fast")
BTDF2 = preset("BTDF2")


# --------------------------------------------------------------------------------------
# inputs, made once
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A target's table through BTDF2 and a medium result file (step 1's format) of BTDF2
    with a model-error term."""
    root = tmp_path_factory.mktemp("overflow")
    target = veil.simulate(veil.BRDF1, BTDF2, noise=0.003, seed=3, **SMALL)
    target.to_csv(root / "tgt.csv", index=False)
    names = BTDF2.param_names()
    params = dict(zip(names, BTDF2.to_vector().tolist()))
    medium = FitResult(
        model=BTDF2.NAME,
        params=params,
        stderr={n: 0.01 * v for n, v in params.items()},
        correlation={a: {b: float(a == b) for b in names} for a in names},
        residuals=tuple([0.0] * 20),
        chi2_reduced=1.0,
        rms_relative=0.003,
        n_points=20,
        converged=True,
        message="ok",
        variant=BTDF2.options().get("variant"),
        step="medium",
        accuracy="fast",
        given=model_entry(veil.BRDF2),
        options=BTDF2.options(),
        model_error=ModelError(0.01, 0.0, 0.01, None, "own residuals", 1.9),
    )
    medium.to_json(root / "med.json")
    load_result(root / "med.json")  # the file reads back as it is
    return root


def _edited(root, name: str, edit) -> str:
    data = json.loads((root / "med.json").read_text())
    edit(data)
    path = root / name
    path.write_text(json.dumps(data))
    return str(path)


def _fit(root, *args):
    out = root / f"out{len(list(root.glob('out*')))}.json"
    r = run("fit", "target", root / "tgt.csv", "--accuracy", "fast", *args, "-o", out)
    return r, out


# --------------------------------------------------------------------------------------
# 7: a given medium whose scale coefficients overflow
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("tt", ["1e300", "1e160"])
def test_given_medium_overflowing_is_exit_2_naming_its_scales(files, tt):
    r, out = _fit(files, "--medium", f"0.001,{tt},0.93,1.3")
    assert r.exit_code == 2, r.output
    assert "overflows float64" in r.output
    assert f"Tt = {float(tt):.4g}" in r.output and "Td = 0.001" in r.output
    assert "smaller values" in r.output and not out.exists()


def test_given_medium_file_overflowing_is_exit_2_naming_its_scales(files):
    path = _edited(files, "tt.json", lambda d: d["params"].update(Tt=1e300))
    r, out = _fit(files, "--medium", path)
    assert r.exit_code == 2, r.output
    assert "overflows float64" in r.output and "Tt = 1e+300" in r.output
    assert not out.exists()


def test_given_medium_large_but_representable_gives_finite_output(files):
    """Tt = 1e100: the model is representable (the target's scales near 1e-200); the
    starting values' solve no longer loses the scales to an overflowing norm."""
    r, out = _fit(files, "--medium", "0.001,1e100,0.93,1.3")
    assert r.exit_code in (0, 1), r.output
    data = json.loads(out.read_text())  # valid JSON: no inf, no NaN
    assert all(0 < v < 1e-150 for k, v in data["params"].items() if k in ("Pd", "Ps"))


# --------------------------------------------------------------------------------------
# 15: a fixed scale that makes every start overflow
# --------------------------------------------------------------------------------------
def test_fixed_scale_overflowing_is_named(files):
    r, out = _fit(files, "--medium", "BTDF2", "--fix", "Ps=1e308")
    assert r.exit_code == 2, r.output
    assert "Ps fixed at 1e+308" in r.output and "--fix Ps=" in r.output
    assert "overflow float64" in r.output and not out.exists()


def test_only_the_fixed_scale_to_blame_is_named(files):
    table = str(files / "tgt.csv")
    with pytest.raises(FitError, match="Ps fixed at 1e\\+308") as info:
        fit_target(table, BTDF2, accuracy="fast", fixed={"Ps": 1e308, "Pd": 0.5})
    assert "Pd" not in str(info.value)
    with pytest.raises(FitError, match="Pd fixed at 1e\\+308 and Ps fixed at 1e\\+308"):
        fit_target(table, BTDF2, accuracy="fast", fixed={"Ps": 1e308, "Pd": 1e308})


def test_fixed_medium_scale_and_given_brdf_overflowing_are_named(files):
    table = veil.simulate(veil.BRDF2, BTDF2, noise=0.003, seed=4, **SMALL)
    with pytest.raises(FitError, match="Tt fixed at 1e\\+300"):
        fit_medium(table, veil.BRDF2, accuracy="fast", fixed={"Tt": 1e300})
    huge = veil.BRDF2.replace(Ps=1e307)
    with pytest.raises(FitError, match="given torrance-sparrow brdf's Pd = .*, Ps = 1e\\+307"):
        fit_medium(table, huge, accuracy="fast")


# --------------------------------------------------------------------------------------
# 8: a model error beyond the range of a relative error
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("key", ["sigma", "own"])
def test_huge_model_error_in_medium_file_is_exit_2(files, key):
    path = _edited(files, f"me_{key}.json", lambda d: d["model_error"].update({key: 1e300}))
    r, out = _fit(files, "--medium", path)
    assert r.exit_code == 2, r.output
    assert path in r.output and f"model_error.{key} = 1e+300" in r.output
    assert f"[0, {MAX_SIGMA:g}]" in r.output and not out.exists()


def test_largest_model_error_gives_finite_output(files):
    path = _edited(files, "me_max.json", lambda d: d["model_error"].update(sigma=MAX_SIGMA))
    r, out = _fit(files, "--medium", path)
    assert r.exit_code in (0, 1), r.output
    data = json.loads(out.read_text())
    assert data["model_error"]["sigma"] == MAX_SIGMA
    assert all(math.isfinite(v) for v in data["stderr"].values())


def test_sandwich_and_estimate_stay_in_range():
    cov, jw, a = np.eye(2), np.ones((5, 2)), np.ones(5)
    with pytest.raises(FitError, match="sigma = 1e\\+300"):
        sandwich(cov, jw, a, 1e300)
    assert np.all(np.isfinite(sandwich(cov, jw, a, MAX_SIGMA)))
    s, _ = estimate(np.full(10, 100.0), np.full(10, 1e-12), 8, None, (0.0,))
    assert s == MAX_SIGMA


# --------------------------------------------------------------------------------------
# the starting values' solves
# --------------------------------------------------------------------------------------
def test_weighted_nnls_equilibrates_huge_columns():
    rng = np.random.default_rng(1)
    cols = rng.uniform(0.5, 1.0, (40, 2)) * np.array([1e200, 3e199])
    coef = np.array([2e-200, 5e-199])
    got = weighted_nnls(cols, cols @ coef, np.full(40, 1e3))
    assert np.allclose(got, coef, rtol=1e-8, atol=0.0)


def test_scale_solves_give_inf_cost_not_a_crash():
    cls = type(veil.BRDF1)
    y, w = np.ones(6), np.ones(6)
    basis = np.full((6, 2), 1.0)
    x = veil.BRDF1.replace(Ps=1e308).to_vector()
    _, cost = brdf_scales(basis * 10, x, cls, {"Ps"}, y, w)
    assert cost == math.inf
    _, cost = brdf_scales(np.full((6, 2), np.inf), veil.BRDF1.to_vector(), cls, set(), y, w)
    assert cost == math.inf
    mcls = type(BTDF2)
    xm = BTDF2.replace(Tt=1e300).to_vector()
    _, cost = medium_scales(np.ones((6, 3)), xm, mcls, {"Tt"}, y, w)
    assert cost == math.inf
    _, cost = medium_scales(np.ones((6, 3)), BTDF2.to_vector(), mcls, set(), y, w)
    assert math.isfinite(cost)



# --------------------------------------------------------------------------------------
# a misfit in clear water: the advice does not send the user to a black cloth
# --------------------------------------------------------------------------------------
def test_a_clear_water_misfit_points_to_the_fixed_parameters_not_the_black_cloth(tmp_path):
    table = veil.simulate(veil.BRDF2, None, noise=0.003, seed=5, **SMALL)  # n = 0.5
    table.to_csv(tmp_path / "ref.csv", index=False)
    assert "sigma" in table.columns
    r = run("fit", "reference", tmp_path / "ref.csv", "--fix", "n=50", "-o",
            tmp_path / "ref.json")
    assert "reduced chi-square" in r.output, r.output
    assert "held fixed" in r.output and "measure the medium" not in r.output
