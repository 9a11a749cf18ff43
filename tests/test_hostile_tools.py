"""Hostile inputs of the tools beyond the fits: ``veil export`` (--verify, --scale,
--ext-ior), ``veil render --exposure``, ``veil explore --static`` of a fit that did not
converge, and an output path under a regular file. Each is status 2 with a message naming
the option or file (or, for the unconverged fit, a warning), never status 3, never a
non-finite number in an output or a printed line, and nothing written on status 2."""

from __future__ import annotations

import pytest

from support.cli import run_checked
from veil.fitting.result import FitResult
from veil.models import model_class

PLASTIC = model_class("rough-plastic")


def _result(model, path, converged=True):
    FitResult(model=model.NAME, params=model.as_dict(),
              stderr={k: None for k in model.as_dict()}, correlation={}, residuals=(0.0,),
              chi2_reduced=1.0, rms_relative=0.01, n_points=10, converged=converged,
              message="", options=model.options()).to_json(path)
    return path


@pytest.fixture
def plastic(tmp_path):
    return _result(PLASTIC(rho=0.5, alpha=0.1, eta=1.5, ks=2.0), tmp_path / "p.json")


def _refused(args, *names):
    r = run_checked([str(a) for a in args])
    assert r.exit_code == 2, r.output
    assert "internal error" not in r.output
    for name in names:
        assert name in r.output, (name, r.output)
    return r


# -- export: values a renderer's 32-bit floats cannot hold --------------------------------
@pytest.mark.parametrize("to, option, value", [
    ("mitsuba", "--scale", "1e-300"),  # was written (4.98e+299: inf in Mitsuba; --verify exit 3)
    ("mitsuba", "--ext-ior", "1e300"),  # int_ior 1.5e300 was written
    ("pbrt", "--scale", "1e-300"),  # pbrt's relative eta ignores --ext-ior
])
def test_export_values_beyond_a_renderers_float_are_refused(plastic, tmp_path, to, option,
                                                            value):
    if to == "pbrt":  # pbrt-v4 takes GGX only
        plastic = _result(PLASTIC(rho=0.5, alpha=0.1, eta=1.5, ks=2.0, distribution="ggx"),
                          tmp_path / "g.json")
    out = tmp_path / "x.out"
    _refused(["export", plastic, "--to", to, option, value, "-o", out], option, "32-bit")
    assert not out.exists()


# -- export --verify: a bad --psi or --spp before anything is written -------------------
@pytest.mark.parametrize("psi", ["nan", "0", "180", "175"])
def test_export_verify_checks_psi_before_writing(plastic, tmp_path, psi):
    # (checked before Mitsuba is loaded: no Mitsuba needed)
    out = tmp_path / "p.xml"
    _refused(["export", plastic, "--to", "mitsuba", "-o", out, "--verify", "--psi", psi],
             "psi")
    assert not out.exists()


def test_export_verify_spp_beyond_mitsubas_range_is_refused(plastic, tmp_path):
    out = tmp_path / "p.xml"
    _refused(["export", plastic, "--to", "mitsuba", "-o", out, "--verify", "--spp",
              "100000000000"], "--spp")
    assert not out.exists()


# -- render: an exposure that overflows the image ---------------------------------------
@pytest.mark.parametrize("tone", ["clip", "reinhard"])
def test_render_exposure_that_overflows_is_refused(tmp_path, tone):
    out = tmp_path / "r.png"
    r = _refused(["render", "--brdf", "BRDF1", "--medium", "BTDF2", "--size", "16",
                  "--exposure", "1e308", "--tone", tone, "-o", out], "--exposure")
    assert "inf" not in r.output.replace("info", "")
    assert not out.exists()


# -- explore --static: a fit that did not converge says so -------------------------------
def test_explore_static_of_an_unconverged_fit_says_so(tmp_path):
    pytest.importorskip("panel")
    bad = _result(PLASTIC(rho=0.5, alpha=0.1, eta=1.5, ks=2.0), tmp_path / "bad.json",
                  converged=False)
    out = tmp_path / "page.html"
    r = run_checked(["explore", str(bad), "--static", "--points", "2", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "did not converge" in r.output and str(bad) in r.output, r.output


# -- an output "folder" that is a regular file -------------------------------------------
def test_output_under_a_regular_file_says_it_is_a_file(plastic, tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    r = _refused(["export", plastic, "--to", "csv", "-o", blocker / "x.csv"], "file.txt")
    assert "is a file, not a directory" in r.output, r.output
    r = _refused(["diagnose", plastic, "--data", plastic, "-o", blocker / "d"], "file.txt")
    assert "is a file, not a directory" in r.output, r.output
    assert blocker.read_text() == "x"


# -- diagnose: a result that did not converge says so ------------------------------------
def test_diagnose_of_an_unconverged_fit_says_so(tmp_path):
    import json

    import veil
    from veil.data.measurements import save_measurements
    from veil.fitting import fit_target

    table = veil.simulate(veil.BRDF1, veil.BTDF2, seed=6, psi=(30, 90), fine_step=2,
                          coarse_step=10, glow=0.0, accuracy="fast")
    save_measurements(table, tmp_path / "t.csv")
    fit_target(table, veil.BTDF2, accuracy="fast").to_json(tmp_path / "t.json")
    data = json.loads((tmp_path / "t.json").read_text())
    data["converged"] = False
    (tmp_path / "bad.json").write_text(json.dumps(data))
    r = run_checked(["diagnose", str(tmp_path / "bad.json"), "--data", str(tmp_path / "t.csv"),
                     "-o", str(tmp_path / "d")])
    assert r.exit_code == 0, r.output
    assert "did not converge" in " ".join(r.output.split()), r.output
    notes = json.loads((tmp_path / "d" / "diagnostics.json").read_text())["notes"]
    assert any("did not converge" in n for n in notes), notes


def test_diagnose_says_when_its_refit_with_the_medium_free_did_not_converge(monkeypatch):
    import dataclasses

    import veil
    from veil.analysis import diagnostics
    from veil.fitting import fit_medium, fit_reference, fit_target

    small = dict(psi=(30, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")
    ref = fit_reference(veil.simulate(veil.BRDF2, None, seed=4, **small))
    medium = fit_medium(veil.simulate(veil.BRDF2, veil.BTDF2, seed=5, **small), ref,
                        accuracy="fast")
    table = veil.simulate(veil.BRDF1, veil.BTDF2, seed=6, **small)
    target = fit_target(table, medium, accuracy="fast")
    real = diagnostics.solve

    def stopped(*args, **kw):  # the refit's evaluations run out
        return dataclasses.replace(real(*args, **kw), status=0, message="limit reached")

    monkeypatch.setattr(diagnostics, "solve", stopped)
    diag = diagnostics.diagnose(target, table, medium=medium)
    assert any("did not converge (limit reached)" in n for n in diag.notes), diag.notes


# -- diagnose: a result of several channels, named by the option that gave it -----------
def test_diagnose_names_the_option_that_gave_a_result_of_several_channels(tmp_path):
    import veil
    from veil.data.measurements import save_measurements
    from veil.fitting import fit_target

    table = veil.simulate(veil.BRDF1, veil.BTDF2, seed=6, psi=(30, 90), fine_step=5,
                          coarse_step=15, glow=0.0, accuracy="fast")
    save_measurements(table, tmp_path / "t.csv")
    fit_target(table, veil.BTDF2, accuracy="fast").to_json(tmp_path / "t.json")
    shared = {"g": 0.93, "eta_u": 1.3}
    params = {**{f"{p}[{c}]": v for p, v in (("Td", 1e-3), ("Tt", 0.13)) for c in "rgb"},
              **shared}
    med = FitResult(model="henyey-greenstein", params=params, stderr={k: None for k in params},
                    correlation={}, residuals=(0.0,), chi2_reduced=1.0, rms_relative=0.01,
                    n_points=10, converged=True, message="", channels={
                        c: {"Td": f"Td[{c}]", "Tt": f"Tt[{c}]", "g": "g", "eta": "eta_u"}
                        for c in "rgb"})
    med.to_json(tmp_path / "rgb.json")
    _refused(["diagnose", tmp_path / "t.json", "--data", tmp_path / "t.csv", "--medium",
              tmp_path / "rgb.json", "-o", tmp_path / "d"], "--medium", "rgb.json",
             "fits channels r, g, b")
    assert not (tmp_path / "d").exists()


# -- design: noise levels beyond what float64 computes -----------------------------------
@pytest.mark.parametrize("option, value, said", [
    ("--noise-floor", "1e308", None),  # was status 3 (OverflowError squaring the floor)
    ("--noise", "1e308", "beyond the range of float64"),  # was 'not identified', inf inside
    ("--noise", "1e-20", "relative noise"),  # was status 3 (LinAlgError: singular matrix)
    ("--noise", "1e-300", "relative noise"),  # was 'the model is 0 at some configuration'
])
def test_design_noise_beyond_float64_is_refused_or_computed(tmp_path, option, value, said):
    out = tmp_path / "plan.csv"
    r = run_checked(["design", "--brdf", "BRDF1", "--medium", "BTDF3", "--accuracy", "fast",
                     "--fine-step", "5", "--coarse-step", "15", "--size", "5", option, value,
                     "-o", str(out)])
    assert "internal error" not in r.output and "nan" not in r.output, r.output
    if said is None:  # a floor that large: every configuration equally useless, said so
        assert r.exit_code == 0 and "not identified" in " ".join(r.output.split()), r.output
        return
    assert r.exit_code == 2 and said in " ".join(r.output.split()), r.output
    assert option.lstrip("-").replace("-", " ") in r.output and not out.exists()


# -- an empty output path is refused before any work -------------------------------------
def test_eval_to_an_empty_output_path_is_refused_up_front(tmp_path):
    configs = tmp_path / "c.csv"
    configs.write_text("theta_i,theta_r\n45,50\n")
    r = _refused(["eval", "--brdf", "BRDF1", "--medium", "BTDF2", "--configs", configs,
                  "--accuracy", "fast", "-o", ""], "empty")
    assert "cannot write :" not in r.output  # was: evaluated, then "cannot write : ENOENT"
