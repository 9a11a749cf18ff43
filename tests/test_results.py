"""Result files across versions, the unweighted standard errors, and the joint fit's
starting models (issues 10 and 11)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import veil
from veil.fitting import FitError, FitResult, JointResult, fit_joint, fit_medium, load_result
from veil.fitting.steps import model_values

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")


@pytest.fixture(scope="module")
def medium_result():
    table, black = veil.simulate(veil.BRDF2, veil.BTDF2, seed=3, black=True, **SMALL)
    return fit_medium(table, veil.BRDF2, black=black, accuracy="fast")


def test_format_1_files_are_read_and_unknown_formats_refused(medium_result, tmp_path):
    data = medium_result.to_dict()
    assert data["format"] == "veil.fit/2"
    old = {k: v for k, v in data.items() if k not in ("options", "determined", "aic", "bic")}
    old["format"] = "veil.fit/1"
    (tmp_path / "old.json").write_text(json.dumps(old))
    back = FitResult.from_json(tmp_path / "old.json")
    assert back.params == medium_result.params and back.as_model() == medium_result.as_model()
    assert back.options == {"variant": "paper"}
    for fmt in ("veil.fit/99", "veil.joint/3", 7):
        (tmp_path / "new.json").write_text(json.dumps({**data, "format": fmt}))
        with pytest.raises(FitError, match="newer"):
            FitResult.from_json(tmp_path / "new.json")
    for key, value, message in (("model", ["x"], "expected a model name"),
                                ("residuals", 3, "list of numbers"),
                                ("stats", [1], "must be an object")):
        (tmp_path / "bad.json").write_text(json.dumps({**data, key: value}))
        with pytest.raises(FitError, match=message):
            FitResult.from_json(tmp_path / "bad.json")


@pytest.fixture(scope="module")
def joint_sessions():
    out = []
    for k, medium in enumerate((veil.BTDF1, veil.BTDF3)):
        table = veil.simulate(veil.BRDF1, medium, seed=10 + k, **SMALL)
        out.append((table, f"m{k}", "target"))
    return out


def test_joint_start_models_and_old_joint_files(joint_sessions, tmp_path):
    fixed = {"Td[m0]": 1e-3}
    start = {"target": veil.BRDF1, "m0": veil.BTDF1, "m1": veil.BTDF3}
    result = fit_joint(joint_sessions, fixed=fixed, start=start, accuracy="fast")
    assert result.converged
    assert result.params["n"] == pytest.approx(veil.BRDF1.n, rel=0.05)
    # the medium's own eta arrives under its alias eta_u (shared by default)
    assert result.params["eta_u"] == pytest.approx(1.3, abs=0.1)
    with pytest.raises(FitError, match="start\\['target'\\] is a henyey-greenstein model"):
        fit_joint(joint_sessions, fixed=fixed, start={"target": veil.BTDF1}, accuracy="fast")
    data = result.to_dict()
    layout = {k: v for k, v in data["layout"].items() if k not in ("models", "options")}
    (tmp_path / "j1.json").write_text(json.dumps({**data, "format": "veil.joint/1",
                                                  "layout": layout}))
    back = load_result(tmp_path / "j1.json")
    assert isinstance(back, JointResult)
    assert back.medium("m1") == result.medium("m1") and back.brdf() == result.brdf()


def test_unweighted_stderr_uses_the_reported_residuals():
    """Without sigmas the covariance is scaled by the reduced chi-square of the reported
    (polished) model, not of the iterations' coarser rule: with small noise the two differ
    by far more than the noise, so a wrong scale shows."""
    table = veil.simulate(veil.BRDF2, veil.BTDF2, seed=5, noise=1e-4, **SMALL)
    table = table.drop(columns=["sigma"])
    result = fit_medium(table, veil.BRDF2, accuracy="default", fixed={"eta": 1.3})
    assert not result.weighted
    free = list(result.free)
    model = result.as_model()
    angles = tuple(table[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    columns = []
    for name in free:  # d f / d log(parameter): every free one is a log-scale parameter or g
        h = 1e-5 * abs(result.params[name])
        up = model.replace(**{name: result.params[name] + h})
        down = model.replace(**{name: result.params[name] - h})
        columns.append((model_values(up, veil.BRDF2, angles) -
                        model_values(down, veil.BRDF2, angles)) / (2 * h))
    jac = np.stack(columns, axis=1)
    cov = np.linalg.inv(jac.T @ jac) * result.chi2_reduced
    want = np.sqrt(np.diag(cov))
    got = np.array([result.stderr[n] for n in free])
    assert np.allclose(got, want, rtol=0.02), (got, want)
