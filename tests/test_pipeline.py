"""The whole estimation (docs/model.md sec. 7): veil.run_pipeline, ``veil fit pipeline``, ``veil demo``.

Recovery: the paper's set-up (reference BRDF2, target BRDF1) in each of the three media, full
protocol, "default" accuracy, one black cloth for both sessions; every parameter within three
of its reported total standard errors (step 1 and 2 include the earlier steps' uncertainty).
File, CLI and determinism tests use one relative angle and the "fast" rule. Sessions come
from test_fitting.session (simulated once per process).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import veil
from test_fitting import assert_recovered, copy, session
from veil.cli import main
from veil.data.measurements import save_measurements
from veil.data.protocol import protocol
from veil.fitting import FitError, FitResult, fit_reference, prepare
from veil.pipeline import FILES, fit_figure, run_pipeline

SMALL = (90.0,)
PNG = b"\x89PNG\r\n\x1a\n"


def sessions(medium: str, psi=None, accuracy="default"):
    """Reference BRDF2 (clear, medium + black), target BRDF1 (medium, the same glow as the
    medium's glow depends on the medium only; clear): independent noise for every session."""
    kw = {} if psi is None else {"psi": psi}
    ref_clear, _ = session("BRDF2", None, **kw, accuracy=accuracy)
    ref_medium, black = session("BRDF2", medium, **kw, accuracy=accuracy)
    tgt_medium, _ = session("BRDF1", medium, **kw, seed=1, accuracy=accuracy)
    tgt_clear, _ = session("BRDF1", None, **kw, seed=3, accuracy=accuracy)
    return {"reference_clear": copy(ref_clear), "reference_medium": copy(ref_medium),
            "target_medium": copy(tgt_medium), "black": copy(black),
            "target_clear": copy(tgt_clear)}


@pytest.mark.parametrize("medium", ["BTDF1", "BTDF2", "BTDF3"])
def test_pipeline_recovers_every_step(medium, tmp_path):
    s = sessions(medium)
    with_direct = medium == "BTDF2"
    stages = []
    result = run_pipeline(s["reference_clear"], s["reference_medium"], s["target_medium"],
                          black=s["black"],
                          target_clear=s["target_clear"] if with_direct else None,
                          outdir=tmp_path, figures=with_direct,
                          progress=lambda stage, done, total: stages.append(stage))
    assert_recovered(result.reference, veil.BRDF2)
    assert_recovered(result.medium, veil.preset(medium), total=True)
    assert_recovered(result.target, veil.BRDF1, total=True)
    assert result.converged
    # the earlier steps' uncertainty is part of the later ones'
    for fit in (result.medium, result.target):
        assert all(fit.stderr_total[n] >= fit.stderr[n] for n in fit.free)
    assert result.target.stderr_total["n"] > 1.2 * result.target.stderr["n"]
    assert {st.split(":")[0] for st in stages} >= {"step 0, reference", "step 1, medium",
                                                   "step 2, target"}
    for key in ("reference", "medium", "target"):
        assert FitResult.from_json(tmp_path / FILES[key]) == getattr(result, key)
    if not with_direct:
        return
    # the target measured directly agrees with the estimate
    c = result.comparison
    assert set(c["params"]) == {"Pd", "Ps", "n", "eta"}
    for name, row in c["params"].items():
        assert abs(row["z"]) < 3, (name, row)
        se = result.target.stderr_total[name]
        assert row["stderr_combined"] == pytest.approx(
            np.hypot(se, result.direct.stderr[name]), rel=1e-12)
    configs = protocol()
    args = (configs["theta_i"], configs["theta_r"], configs["phi_i"], configs["phi_r"])
    est = veil.reflectance(result.target.as_model(), *args)
    ref = veil.reflectance(result.direct.as_model(), *args)
    assert c["n_configurations"] == len(configs) == 111
    assert c["rms_fr_relative"] == pytest.approx(np.sqrt(np.mean((est / ref - 1) ** 2)),
                                                 rel=1e-9)
    assert c["rms_fr_relative"] < 0.1
    # the curves in units of their standard error: simulated data from the true models, so
    # the estimate's band covers the direct fit nearly everywhere
    from veil.analysis.uncertainty import curve_stderr

    angles = tuple(configs[k].to_numpy() for k in ("theta_i", "phi_i", "theta_r", "phi_r"))
    se_est, se_dir = curve_stderr(result.target, angles)[1], curve_stderr(result.direct,
                                                                          angles)[1]
    z = np.abs(est - ref) / np.hypot(se_est, se_dir)
    assert c["fr_max_z"] == pytest.approx(z.max(), rel=1e-9)
    assert c["fr_within_2se"] == pytest.approx(np.mean(z <= 2), abs=1e-12)
    assert c["fr_within_2se"] > 0.9 and c["fr_max_z"] < 3
    assert "within two standard errors" in (tmp_path / "report.md").read_text()
    assert_recovered(result.direct, veil.BRDF1)
    for key in ("reference_fig", "medium_fig", "target_fig", "direct_fig"):
        data = (tmp_path / FILES[key]).read_bytes()
        assert data.startswith(PNG) and len(data) > 20_000
    report = (tmp_path / "report.md").read_text()
    for text in ("## Step 0", "## Step 1", "## Step 2", "| Td |", "![", "target.png",
                 "The target measured directly", "black-cloth session was subtracted"):
        assert text in report
    assert f"| g | {result.medium.params['g']:.6g} |" in report


def small_files(directory):
    s = sessions("BTDF1", psi=SMALL, accuracy="fast")
    paths = {}
    for role, table in s.items():
        paths[role] = directory / f"{role}.csv"
        save_measurements(table, paths[role])
    return paths


def test_outputs_are_deterministic_and_inputs_safe(tmp_path):
    paths = small_files(tmp_path)
    outs = []
    for k in range(2):
        out = tmp_path / f"out{k}"
        run_pipeline(paths["reference_clear"], paths["reference_medium"],
                     paths["target_medium"], black=paths["black"],
                     target_clear=paths["target_clear"], outdir=out, accuracy="fast",
                     fixed={"medium": {"eta": 1.3}})
        outs.append(out)
    names = sorted(os.listdir(outs[0]))
    assert names == sorted(FILES.values())
    for name in names:
        assert (outs[0] / name).read_bytes() == (outs[1] / name).read_bytes(), name
    assert json.loads((outs[0] / "medium.json").read_text())["params"]["eta"] == 1.3
    # an input where an output would go
    (tmp_path / "clash").mkdir()
    (tmp_path / "clash" / "target.json").write_bytes(paths["target_medium"].read_bytes())
    before = (tmp_path / "clash" / "target.json").read_bytes()
    with pytest.raises(FitError, match="would be overwritten"):
        run_pipeline(paths["reference_clear"], paths["reference_medium"],
                     tmp_path / "clash" / "target.json", black=paths["black"],
                     outdir=tmp_path / "clash", accuracy="fast")
    assert (tmp_path / "clash" / "target.json").read_bytes() == before
    with pytest.raises(FitError, match="expected a dict by step"):
        run_pipeline(paths["reference_clear"], paths["reference_medium"],
                     paths["target_medium"], outdir=tmp_path / "x", fixed={"eta": 1.3})
    assert not (tmp_path / "x").exists()


def test_figure_of_out_of_plane_data():
    """Rows off the plane of incidence have no psi curve: model against data instead."""
    rng = np.random.default_rng(4)
    ti = rng.uniform(5, 80, 60)
    pi_ = rng.uniform(0, 360, 60)
    # half of them within a few degrees of the mirror direction, where the peak is
    near = np.arange(60) < 30
    tr = np.where(near, np.clip(ti + rng.uniform(-2, 2, 60), 1, 85), rng.uniform(5, 80, 60))
    pr = np.where(near, pi_ + 180 + rng.uniform(-3, 3, 60), rng.uniform(0, 360, 60)) % 360
    value = veil.reflectance(veil.BRDF1, ti, tr, pi_, pr)
    table = pd.DataFrame({"theta_i": ti, "phi_i": pi_, "theta_r": tr, "phi_r": pr,
                          "value": value * (1 + 0.01 * rng.standard_normal(60)),
                          "sigma": 0.01 * value})
    result = fit_reference(table)
    assert_recovered(result, veil.BRDF1)
    png = fit_figure(prepare(table), result, None)
    assert png.startswith(PNG) and png == fit_figure(prepare(table), result, None)
    from io import BytesIO

    from PIL import Image

    assert Image.open(BytesIO(png)).size == (840, 552)     # 7 x 4.6 in: no residual panel


def test_relative_residuals_and_the_residual_panel():
    """The residual panel's numbers: (data - model) / model and sigma / model; NaN (not
    drawn) where the model is 0, too small to divide by, or not finite; the panel's range
    holds the bulk and the model-error band and clips an outlier to its edge."""
    import warnings

    from veil.viz.fit_figures import relative_residuals, residual_panel

    rel, err = relative_residuals([1.1, 2.0, 0.5], [1.0, 2.5, 0.0], [0.1, 0.5, 0.2])
    np.testing.assert_allclose(rel[:2], [0.1, -0.2], atol=1e-15)
    np.testing.assert_allclose(err[:2], [0.1, 0.2], atol=1e-15)
    assert np.isnan(rel[2]) and np.isnan(err[2])
    assert relative_residuals([1.0], [2.0])[1] is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rel, _ = relative_residuals([1.0, 1.0, 1.0, 1.0], [1.0, 1e-300, np.inf, 0.5])
    np.testing.assert_array_equal(np.isnan(rel), [False, True, True, False])
    assert rel[3] == 1.0
    bulk = np.r_[np.full(50, 0.01), 10.0]                   # 1 % and one 1000 % point
    half, shown, off = residual_panel(bulk)
    assert half == pytest.approx(1.1) and off.tolist() == [False] * 50 + [True]
    assert shown[-1] == pytest.approx(1.1) and shown[0] == pytest.approx(1.0)
    assert residual_panel(bulk, sigma_model=0.01)[0] == pytest.approx(4.4)   # 4 s, in %
    assert residual_panel(np.full(3, np.nan))[0] > 0
    scatter = np.linspace(-0.02, 0.02, 101)                  # no outlier: every point shown
    half, shown, off = residual_panel(scatter)
    assert half == pytest.approx(2.2) and not off.any()
    np.testing.assert_allclose(shown, 100 * scatter)


def test_in_plane_figure_has_the_panel_and_its_band():
    """In-plane data get the residual panel (a taller figure; out-of-plane data do not:
    test_figure_of_out_of_plane_data); a fit with a model-error term draws its band (the
    PNG differs from the same fit without it); a point far off the rest (its model half the
    datum, +100 %) goes to the panel's edge without warnings. Deterministic bytes."""
    import dataclasses
    import warnings
    from io import BytesIO

    from PIL import Image

    from veil.fitting.model_error import ModelError

    configs = protocol()
    value = veil.reflectance(veil.BRDF1, configs["theta_i"], configs["theta_r"],
                             configs["phi_i"], configs["phi_r"])
    noise = 1 + 0.01 * np.random.default_rng(3).standard_normal(len(configs))
    table = configs.assign(value=value * noise, sigma=0.01 * value)
    data = prepare(table)
    result = fit_reference(table)
    assert result.model_error is None or result.model_error.sigma == 0.0
    png = fit_figure(data, result, None, dpi=50)
    assert png == fit_figure(data, result, None, dpi=50)
    assert Image.open(BytesIO(png)).size == (350, 290)        # 7 x 5.8 in: with the panel
    term = ModelError(0.01, 40.0, 0.01, None, "own residuals", 1.3)
    banded = fit_figure(data, dataclasses.replace(result, model_error=term), None, dpi=50)
    assert banded != png
    far = np.array(result.residuals)
    far[0] += 0.5 * data.y[0] / data.sigma[0]             # the model at point 0: about y / 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        edged = fit_figure(data, dataclasses.replace(result, residuals=tuple(far)), None,
                           dpi=50)
    assert edged.startswith(PNG) and edged != png


def invoke(args):
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result


def test_cli_pipeline(tmp_path):
    p = small_files(tmp_path)
    base = ["fit", "pipeline", "--reference-clear", p["reference_clear"], "--reference-medium",
            p["reference_medium"], "--target-medium", p["target_medium"], "--black",
            p["black"], "--accuracy", "fast"]
    # one psi: the reference's Ps and eta are exactly degenerate (Ps F(psi/2, eta)), a fit
    # that is "not determined" (exit 1): its eta is held as the target's
    r = invoke(base + ["-o", tmp_path / "out", "--target-clear", p["target_clear"],
                       "--fix", "medium.eta=1.3", "--fix", "target.eta=1.55",
                       "--fix", "reference.eta=1.55"])
    assert r.exit_code == 0, r.output
    assert "[[Estimated target f_r against the direct fit]]" in r.stdout
    med = FitResult.from_json(tmp_path / "out" / "medium.json")
    tgt = FitResult.from_json(tmp_path / "out" / "target.json")
    direct = FitResult.from_json(tmp_path / "out" / "target_direct.json")
    assert med.params["eta"] == 1.3 and tgt.params["eta"] == 1.55 == direct.params["eta"]
    r = invoke(base + ["-o", tmp_path / "nc", "--max-nfev", "1", "--no-figures"])
    assert r.exit_code == 1 and "did not converge" in r.output
    assert json.loads((tmp_path / "nc" / "medium.json").read_text())["converged"] is False
    assert (tmp_path / "nc" / "report.md").exists() and not list((tmp_path / "nc").glob("*.png"))
    for args, message in ((["--fix", "eta=1.3"], "expected STEP.NAME=VALUE"),
                          (["--fix", "medium.n=1"], "has no parameter 'n'"),
                          (["--variant", "both"], "Invalid value for '--variant'")):
        r = invoke(base + ["-o", tmp_path / "bad"] + args)
        assert r.exit_code == 2 and message in r.output, r.output
        assert not (tmp_path / "bad").exists()
    (tmp_path / "file").write_text("x")
    r = invoke(base + ["-o", tmp_path / "file"])
    assert r.exit_code == 2


def test_demo_acquisition(tmp_path):
    """veil demo's simulated acquisition and estimation (its functions, at "fast"; the
    command also runs the paper's figures, tested with veil reproduce)."""
    from rich.console import Console

    from veil.cli.demo_cmd import fit_sessions, simulate_sessions, summary_table

    paths = simulate_sessions(tmp_path, seed=0, noise=0.01, accuracy="fast")
    assert sorted(p.name for p in paths.values()) == sorted(
        f"{name}.csv" for name in ("reference_clear", "reference_medium", "black",
                                   "target_medium", "target_clear"))
    result = fit_sessions(paths, tmp_path, "fast")
    assert result.converged and (tmp_path / "report.md").exists()
    assert "| Pd | " in (tmp_path / "report.md").read_text()  # with the true values
    console = Console(width=100, record=True)
    console.print(summary_table(result))
    text = console.export_text()
    row = [line for line in text.splitlines() if "2 target BRDF1" in line and " n " in line]
    assert row and f"{result.target.params['n']:.6g}" in row[0] and "0.8" in row[0]
    (tmp_path / "plain").write_text("")
    r = invoke(["demo", "-o", tmp_path / "plain"])
    assert r.exit_code == 2 and "is a file" in r.output
