"""Least-squares estimation (docs/model.md sec. 7): steps 0-2, results, errors and ``veil fit``.

Recovery runs on the paper's full protocol (111 configurations) at the "default" accuracy for
every preset pair; the other tests use one relative angle (psi = 90 deg, 31 configurations)
and the "fast" rule where accuracy is not the point. Sessions are simulated once per
process (``session``); the engine compiles once per accuracy for 64-configuration chunks,
shared with veil.data.simulate.
"""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest

import veil
from support.cli import run_checked
from veil.data.black_cloth import subtract_black
from veil.data.measurements import MeasurementError, save_measurements
from veil.data.protocol import PSI
from veil.fitting import FitError, FitResult, fit_medium, fit_reference, fit_target

PAIRS = [(b, m) for b in ("BRDF1", "BRDF2") for m in ("BTDF1", "BTDF2", "BTDF3")]
SMALL = (90.0,)
FAST = {"accuracy": "fast"}
JSON_KEYS = {"model", "params", "stderr", "correlation", "chi2_reduced", "rms_relative",
             "n_points", "converged", "message", "variant"}


# -- simulated sessions, once per process ---------------------------------------------------

@functools.cache
def session(brdf: str, medium: str | None, psi=PSI, seed: int = 0,
            glow: float | None = None, accuracy: str = "default"):
    """(table, black) of ``brdf`` seen through ``medium`` (None: clear water), 1 % noise."""
    from veil.data.simulate import GLOW_LEVEL

    b = veil.preset(brdf)
    if medium is None:
        return veil.simulate(b, None, psi=psi, seed=seed, accuracy=accuracy), None
    return veil.simulate(b, veil.preset(medium), psi=psi, seed=seed, black=True,
                         glow=GLOW_LEVEL if glow is None else glow, accuracy=accuracy)


def copy(table):
    return None if table is None else table.copy()


def assert_recovered(result: FitResult, truth, k: float = 3.0, total: bool = False):
    """Every free parameter within k standard errors of the truth; fixed ones exact.

    Parameters fitted as logarithms (Param.log_scale) are compared as logarithms: the
    interval is value * exp(+-k stderr / value) (docs/fitting.md, uncertainties)."""
    assert result.converged, result.message
    se = result.stderr_total if total else result.stderr
    params = {p.name: p for p in type(truth).PARAMS}
    for name, value in result.params.items():
        true = getattr(truth, name)
        if name in result.fixed:
            assert value == result.fixed[name]
            continue
        s = se[name]
        assert s is not None and 0 < s < abs(true), (name, s)
        z = math.log(value / true) / (s / value) if params[name].log_scale \
            else (value - true) / s
        assert abs(z) <= k, f"{name} = {value:.6g} +- {s:.3g}, true {true:.6g} ({z:+.2f} sigma)"
    assert 0.6 < result.chi2_reduced < 1.5, result.chi2_reduced
    assert 0.006 < result.rms_relative < 0.015, result.rms_relative


# -- recovery at 1 % noise, the paper's protocol -------------------------------------------

@pytest.mark.parametrize("brdf", ["BRDF1", "BRDF2"])
def test_step0_recovers_reference(brdf):
    table, _ = session(brdf, None)
    result = fit_reference(copy(table))
    assert_recovered(result, veil.preset(brdf))
    assert result.step == "reference" and result.model == "torrance-sparrow"
    assert result.variant is None and result.weighted and result.n_points == 111


@pytest.mark.parametrize("brdf,medium", PAIRS)
def test_step1_recovers_medium(brdf, medium):
    table, black = session(brdf, medium)
    result = fit_medium(copy(table), veil.preset(brdf), black=copy(black))
    assert_recovered(result, veil.preset(medium))
    assert result.accuracy == "default" and result.variant == "paper"
    assert result.given == {"model": "torrance-sparrow", "params": veil.preset(brdf).as_dict()}
    assert result.stderr_total is None  # the given model is exact


@pytest.mark.parametrize("brdf,medium", PAIRS)
def test_step2_recovers_target(brdf, medium):
    table, black = session(brdf, medium)
    result = fit_target(copy(table), veil.preset(medium), black=copy(black))
    assert_recovered(result, veil.preset(brdf))
    assert result.variant == "paper" and result.step == "target"


def test_result_is_at_the_requested_accuracy():
    """The polished parameters reproduce the reported residuals with the default rule."""
    table, black = session("BRDF1", "BTDF2")
    result = fit_medium(copy(table), veil.BRDF1, black=copy(black))
    data = subtract_black(table, black)
    angles = tuple(data[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    for acc, tol in (("default", 1e-12), ("fast", None)):
        model = veil.fitting.steps.model_values(result, veil.BRDF1, angles, acc)
        res = (data["value"].to_numpy() - model) / data["sigma"].to_numpy()
        if tol is not None:
            np.testing.assert_allclose(res, result.residuals, rtol=0, atol=tol)
        else:  # the fast rule differs by ~0.3 % of the value, ~0.3 sigma
            assert np.max(np.abs(res - np.array(result.residuals))) > 0.01


def test_steps_differentiate_only_the_models_they_need(monkeypatch):
    """Step 1 iterates with the medium's derivatives alone and step 2 with the object's;
    the given model's derivatives are taken once, for the propagated covariance. The
    partial Jacobians equal the full one's columns, the rest is NaN until asked for."""
    from veil.engine.evaluator import ApparentModel
    from veil.fitting import session_problem

    calls = []
    original = ApparentModel.value_and_jacobian

    def spy(self, vb, vm, wrt=("brdf", "medium")):
        calls.append(tuple(wrt))
        return original(self, vb, vm, wrt)

    monkeypatch.setattr(ApparentModel, "value_and_jacobian", spy)
    table, black = session("BRDF1", "BTDF1", psi=SMALL)
    ref = fit_reference(session("BRDF1", None)[0])
    med = fit_medium(copy(table), ref, black=copy(black), **FAST)
    assert calls.count(("medium",)) >= 3 and calls.count(("brdf",)) == 1, calls
    assert ("brdf", "medium") not in calls
    calls.clear()
    fit_target(copy(table), med, black=copy(black), **FAST)
    assert calls.count(("brdf",)) >= 3 and calls.count(("medium",)) == 1, calls
    assert ("brdf", "medium") not in calls

    monkeypatch.setattr(ApparentModel, "value_and_jacobian", original)
    problem = session_problem(subtract_black(table, black), veil.BRDF1, veil.BTDF1,
                              free=["g", "eta_u"])
    x = problem.values * (1 + 1e-3)
    full = session_problem(subtract_black(table, black), veil.BRDF1, veil.BTDF1,
                           free=["g", "eta_u"]).value_and_jacobian(x)[1]
    medium_cols = [problem.index(k) for k in ("Td", "Tt", "g", "eta_u")]
    brdf_cols = [problem.index(k) for k in ("Pd", "Ps", "n", "eta")]
    _, part = problem.value_and_jacobian(x, columns=problem.free)
    assert np.all(np.isnan(part[:, brdf_cols]))
    np.testing.assert_allclose(part[:, medium_cols], full[:, medium_cols], rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(full)))
    engine = problem.blocks[0].model("fast")._engine
    before = engine.jacobian_calls
    _, both = problem.value_and_jacobian(x, columns=brdf_cols)  # adds the BRDF's alone
    assert engine.jacobian_calls == before + 1
    np.testing.assert_allclose(both, full, rtol=1e-9, atol=1e-12 * np.max(np.abs(full)))
    problem.value_and_jacobian(x, columns=medium_cols + brdf_cols)  # both known: no call
    assert engine.jacobian_calls == before + 1


# -- the result object ----------------------------------------------------------------------

def test_json_round_trip_and_keys(tmp_path):
    table, black = session("BRDF2", "BTDF2")
    ref = fit_reference(copy(session("BRDF2", None)[0]))
    result = fit_medium(copy(table), ref, black=copy(black))
    path = tmp_path / "medium.json"
    result.to_json(path)
    data = json.loads(path.read_text())
    assert JSON_KEYS <= set(data)
    assert list(data["params"]) == ["Td", "Tt", "g", "eta"]
    assert data["model"] == "henyey-greenstein" and data["variant"] == "paper"
    again = FitResult.from_json(path)
    assert again == result
    assert again.as_model() == veil.HenyeyGreenstein(**result.params, variant="paper")
    # the reference's uncertainty propagates: the total is never below the conditional
    assert result.stderr_total is not None
    for name in result.free:
        assert result.stderr_total[name] >= result.stderr[name] > 0
    ref.to_json(tmp_path / "ref.json")
    assert FitResult.from_json(tmp_path / "ref.json") == ref


def test_report_text():
    result = fit_reference(copy(session("BRDF1", None)[0]), fixed={"eta": 1.55})
    text = str(result)
    assert text == result.report()
    assert "[[Variables]]" in text and "[[Correlations]]" in text
    assert "eta: 1.55 (fixed)" in text
    assert f"Pd : {result.params['Pd']:.6g} +/- {result.stderr['Pd']:.3g}" in text
    assert "converged          = yes" in text and "weighted by sigma" in text


def test_fit_is_deterministic(tmp_path):
    table, black = session("BRDF1", "BTDF1", SMALL, accuracy="fast")
    runs = [fit_medium(copy(table), veil.BRDF1, black=copy(black), fixed={"eta": 1.3}, **FAST)
            for _ in range(2)]
    for k, r in enumerate(runs):
        r.to_json(tmp_path / f"{k}.json")
    assert (tmp_path / "0.json").read_bytes() == (tmp_path / "1.json").read_bytes()


# -- fixed parameters -----------------------------------------------------------------------

def test_fixed_parameters_stay_fixed_exactly():
    table, _ = session("BRDF2", None)
    result = fit_reference(copy(table), fixed={"eta": 1.4, "Pd": 1000.0})
    assert result.params["eta"] == 1.4 and result.params["Pd"] == 1000.0
    assert result.fixed == {"Pd": 1000.0, "eta": 1.4}
    assert result.stderr["eta"] is None and result.stderr["Pd"] is None
    assert set(result.correlation) == {"Ps", "n"}
    assert result.free == ("Ps", "n")
    # a wrong eta is absorbed by Ps (strongly correlated): the fit moves it away from truth
    assert abs(result.params["Ps"] - 5e5) > 3 * result.stderr["Ps"]


def test_fixed_medium_parameter_through_the_medium():
    table, black = session("BRDF1", "BTDF2", SMALL, accuracy="fast")
    result = fit_medium(copy(table), veil.BRDF1, black=copy(black), fixed={"g": 0.93},
                        **FAST)
    assert result.params["g"] == 0.93 and result.converged
    assert result.stderr["g"] is None and "g" not in result.correlation
    assert abs(result.params["Tt"] - 0.13) < 3 * result.stderr["Tt"]


# -- black cloth, weights -------------------------------------------------------------------

def test_black_cloth_is_subtracted_first():
    table, black = session("BRDF2", "BTDF3", SMALL, accuracy="fast")
    given = fit_medium(copy(table), veil.BRDF2, black=copy(black), **FAST)
    manual = fit_medium(subtract_black(table, black), veil.BRDF2, **FAST)
    # the same fit, which says whether it subtracted a black cloth itself (for diagnose)
    assert given.stats.pop("black_subtracted") and not manual.stats.pop("black_subtracted")
    assert given.to_dict() == manual.to_dict()
    # the glow left in is taken for isotropic scattering: T_d comes out several times too high
    raw = fit_medium(copy(table), veil.BRDF2, **FAST)
    assert abs(given.params["Td"] - 1e-3) < 3 * given.stderr["Td"]
    assert raw.params["Td"] > 1e-3 + 10 * raw.stderr["Td"]


def test_black_cloth_must_cover_every_configuration():
    table, black = session("BRDF2", "BTDF3", SMALL, accuracy="fast")
    with pytest.raises(MeasurementError, match="no black-cloth measurement"):
        fit_medium(copy(table), veil.BRDF2, black=black.iloc[:-3].copy(), **FAST)


def test_unweighted_fit_scales_errors_by_chi_square():
    table, _ = session("BRDF1", None)
    plain = copy(table).drop(columns="sigma")
    a = fit_reference(plain)
    scaled = plain.copy()
    scaled["value"] *= 10.0
    b = fit_reference(scaled)
    assert not a.weighted and "UNWEIGHTED" in a.report()
    res = np.array(a.residuals)
    assert a.chi2_reduced == pytest.approx(res @ res / (111 - 4), rel=1e-12)
    # errors follow the data's scale: P_d x10 with its error; n's error unchanged
    assert b.params["Pd"] == pytest.approx(10 * a.params["Pd"], rel=1e-6)
    assert b.stderr["Pd"] == pytest.approx(10 * a.stderr["Pd"], rel=1e-4)
    assert b.stderr["n"] == pytest.approx(a.stderr["n"], rel=1e-4)


def test_starts_do_not_need_a_guess():
    """Objects far from the presets are found from the code's own starting grid."""
    for truth in (veil.TorranceSparrow(50.0, 2e3, 0.12, 1.2),
                  veil.TorranceSparrow(3e3, 8e6, 2.5, 2.4)):
        table = veil.simulate(truth, None, seed=5)
        assert_recovered(fit_reference(table), truth)


# -- non-convergence ------------------------------------------------------------------------

def test_non_convergence_is_reported():
    result = fit_reference(copy(session("BRDF1", None)[0]), max_nfev=1)
    assert not result.converged
    assert result.message.startswith("did not converge")
    assert "maximum number of function evaluations" in result.message
    assert "converged          = NO" in result.report()
    table, black = session("BRDF1", "BTDF1", SMALL, accuracy="fast")
    med = fit_medium(copy(table), veil.BRDF1, black=copy(black), max_nfev=1)
    assert not med.converged and "stopped early" in med.message
    assert med.accuracy == "default"


# -- bad input ------------------------------------------------------------------------------

def small_clear():
    return copy(session("BRDF1", None)[0])


def test_empty_and_too_small_tables():
    table = small_clear()
    with pytest.raises(MeasurementError, match="has no rows"):
        fit_reference(table.iloc[:0].copy())
    with pytest.raises(FitError, match=r"4 point\(s\) but the fit has 4 free parameter"):
        fit_reference(table.iloc[:4].copy())
    assert fit_reference(table.iloc[:40:8].copy(), fixed={"eta": 1.55, "n": 0.8}).n_points == 5


def test_zero_sigma_is_an_error():
    table = small_clear()
    table.loc[7, "sigma"] = 0.0
    with pytest.raises(MeasurementError, match=r"row 7 \(index label\).*column 'sigma'"):
        fit_reference(table)


def test_bad_rows_are_named(tmp_path):
    table = small_clear()
    save_measurements(table, tmp_path / "clear.csv")
    text = (tmp_path / "clear.csv").read_text().splitlines()
    fields = text[5].split(",")
    fields[-2] = "abc"
    text[5] = ",".join(fields)
    (tmp_path / "bad.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(MeasurementError, match=r"line 6 of .*bad.csv, column 'value'"):
        fit_reference(tmp_path / "bad.csv")


def test_wrong_models_and_options():
    table, black = session("BRDF1", "BTDF1", SMALL, accuracy="fast")
    medium_result = fit_medium(copy(table), veil.BRDF1, black=copy(black), **FAST)
    with pytest.raises(FitError, match="reference must be a BRDF fit.*henyey-greenstein"):
        fit_medium(copy(table), medium_result)
    with pytest.raises(FitError, match="reference must be a BRDF"):
        fit_medium(copy(table), veil.BTDF1)
    ref_result = fit_reference(small_clear())
    with pytest.raises(FitError, match="medium must be a medium fit.*torrance-sparrow"):
        fit_target(copy(table), ref_result)
    with pytest.raises(FitError, match="cannot fix 'G'.*Td, Tt, g, eta"):
        fit_medium(copy(table), veil.BRDF1, fixed={"G": 0.9})
    with pytest.raises(FitError, match=r"g = 1.5 is outside \(-1, 1\)"):
        fit_medium(copy(table), veil.BRDF1, fixed={"g": 1.5})
    with pytest.raises(FitError, match="every parameter .* is fixed"):
        fit_reference(small_clear(), fixed=veil.BRDF1.as_dict())
    with pytest.raises(FitError, match="accuracy = 'best'"):
        fit_medium(copy(table), veil.BRDF1, accuracy="best")
    with pytest.raises(FitError, match="variant = 'both'"):
        fit_medium(copy(table), veil.BRDF1, variant="both")
    with pytest.raises(FitError, match="variant = 'paper' but the medium was fitted with"):
        fit_target(copy(table), veil.BTDF1.replace(variant="exit"), variant="paper")
    with pytest.raises(FitError, match="max_nfev = 0"):
        fit_reference(small_clear(), max_nfev=0)
    with pytest.raises(TypeError, match="measurement table"):
        fit_reference([1, 2, 3])


def test_bad_result_files(tmp_path):
    good = fit_reference(small_clear())
    good.to_json(tmp_path / "good.json")
    data = json.loads((tmp_path / "good.json").read_text())
    cases = {
        "not json": ("{", r"not valid JSON at line 1, column 2"),
        "missing": (json.dumps({k: v for k, v in data.items() if k != "stderr"}),
                    "missing key\\(s\\) stderr"),
        "names": (json.dumps({**data, "params": {"Td": 1, "Tt": 1, "g": 0.5, "eta": 1.3}}),
                  "must map exactly Pd, Ps, n, eta"),
        "model": (json.dumps({**data, "model": "phong"}), "'phong' is not a known model"),
        "value": (json.dumps({**data, "params": {**data["params"], "n": -1}}),
                  r"n = -1 is outside"),
        "variant": (json.dumps({**data, "variant": "sideways"}), "key 'variant'"),
    }
    for name, (text, message) in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(text)
        with pytest.raises(FitError, match=message):
            FitResult.from_json(path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        FitResult.from_json(tmp_path / "nope.json")


# -- the command line -----------------------------------------------------------------------

invoke = run_checked


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fit-cli")
    save_measurements(session("BRDF1", None)[0], d / "clear.csv")
    table, black = session("BRDF1", "BTDF1", SMALL, accuracy="fast")
    save_measurements(table, d / "medium.csv")
    save_measurements(black, d / "black.csv")
    return d


def test_cli_fit_steps(files):
    d = files
    r = invoke(["fit", "reference", d / "clear.csv", "-o", d / "ref.json", "--fix", "eta=1.55"])
    assert r.exit_code == 0, r.output
    ref = FitResult.from_json(d / "ref.json")
    assert ref.params["eta"] == 1.55 and "[[Variables]]" in r.stdout
    r = invoke(["fit", "medium", d / "medium.csv", "--reference", d / "ref.json", "--black",
                d / "black.csv", "-o", d / "med.json", "--accuracy", "fast"])
    assert r.exit_code == 0, r.output
    med = FitResult.from_json(d / "med.json")
    assert med.model == "henyey-greenstein" and med.given["params"] == ref.params
    assert med == fit_medium(d / "medium.csv", ref, black=d / "black.csv", **FAST)
    r = invoke(["fit", "target", d / "medium.csv", "--medium", d / "med.json", "--black",
                d / "black.csv", "-o", d / "tgt.json", "--accuracy", "fast", "--fix", "n=0.8"])
    assert r.exit_code == 0, r.output
    tgt = FitResult.from_json(d / "tgt.json")
    assert tgt.params["n"] == 0.8 and tgt.step == "target"


def test_cli_exit_codes(files):
    d = files
    r = invoke(["fit", "reference", d / "clear.csv", "-o", d / "nc.json", "--max-nfev", "1"])
    assert r.exit_code == 1 and "did not converge" in r.output
    assert json.loads((d / "nc.json").read_text())["converged"] is False
    cases = [
        (["fit", "reference", d / "clear.csv", "-o", d / "clear.csv"], "never overwrites"),
        (["fit", "reference", d / "nope.csv", "-o", d / "x.json"], "does not exist"),
        (["fit", "reference", d / "clear.csv", "-o", d / "x.json", "--fix", "eta"],
         "expected NAME=VALUE"),
        (["fit", "reference", d / "clear.csv", "-o", d / "x.json", "--fix", "g=0.9"],
         "has no parameter 'g'"),
        (["fit", "reference", d / "clear.csv", "-o", d / "x.json", "--fix", "n=-2"],
         "outside"),
        (["fit", "medium", d / "medium.csv", "--reference", d / "nope.json", "-o",
          d / "x.json"], "does not exist"),
        (["fit", "medium", d / "medium.csv", "--reference", "BTDF1", "-o", d / "x.json"],
         "not a BRDF preset"),
        (["fit", "reference", d / "clear.csv", "-o", d / "x.json", "--black", d / "black.csv"],
         "no black-cloth measurement"),
    ]
    for args, message in cases:
        r = invoke(args)
        assert r.exit_code == 2, (args, r.output)
        assert message in r.output, (message, r.output)
        assert not (d / "x.json").exists()
    # a medium result given as the reference
    invoke(["fit", "medium", d / "medium.csv", "--reference", "BRDF1", "--black",
            d / "black.csv", "-o", d / "m.json", "--accuracy", "fast"])
    r = invoke(["fit", "medium", d / "medium.csv", "--reference", d / "m.json", "-o",
                d / "x.json", "--accuracy", "fast"])
    assert r.exit_code == 2 and "reference must be a BRDF fit" in r.output


@pytest.mark.parametrize("starts, said", [(1, "from 1 start"), (3, "over 3 starts")])
def test_the_report_counts_the_starts_in_words(starts, said):
    """The evaluations line names the starts in plain English (not "1 start(s)")."""
    names = veil.BRDF1.param_names()
    params = dict(zip(names, veil.BRDF1.to_vector().tolist()))
    result = FitResult(model=veil.BRDF1.NAME, params=params, stderr={n: 0.01 for n in names},
                       correlation={a: {b: float(a == b) for b in names} for a in names},
                       residuals=(0.0,) * 8, chi2_reduced=1.0, rms_relative=0.01, n_points=8,
                       converged=True, message="ok", variant=None,
                       stats={"nfev": 12, "njev": 5, "starts": starts})
    line = next(x for x in result.report().splitlines() if "evaluations" in x)
    assert line.strip() == f"evaluations        = 12 function, 5 Jacobian {said}", line
