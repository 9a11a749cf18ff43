"""The registry is real: two families that exist only in the tests (tests/plugins) go through
veil eval, the three fits, the joint fit and veil diagnose, chosen by name, with no line of
veil changed for them; a subprocess finds them through VEIL_PLUGINS."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import veil_test_models
from click.testing import CliRunner

import veil
from veil.cli import main

PLUGINS = os.path.join(os.path.dirname(__file__), "plugins")
from veil.fitting import FitResult, load_result

FAST = ["--accuracy", "fast"]
KW = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")
LAMBERT = veil_test_models.LambertianTest(rho=0.6)
FISHER = veil_test_models.FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
FISHER_2 = veil_test_models.FisherTest(Td=4e-3, Tt=0.35, kappa=60.0)


def invoke(args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("plugins")
    ref_clear = veil.simulate(veil.BRDF2, None, seed=1, **KW)
    ref_medium, black = veil.simulate(veil.BRDF2, FISHER, seed=2, black=True, **KW)
    target = veil.simulate(LAMBERT, FISHER, seed=3, **KW)
    target_2 = veil.simulate(LAMBERT, FISHER_2, seed=4, **KW)
    target_clear = veil.simulate(LAMBERT, None, seed=5, **KW)
    out = {}
    for name, table in (("ref_clear", ref_clear), ("ref_medium", ref_medium),
                        ("black", black), ("target", target), ("target_2", target_2),
                        ("target_clear", target_clear)):
        out[name] = d / f"{name}.csv"
        veil.save_measurements(table, out[name])
    out["dir"] = d
    return out


def test_eval_with_test_models_matches_the_api():
    r = invoke(["eval", "--brdf-model", "lambertian-test", "--medium-model", "fisher-test",
                "--brdf", "0.6", "--medium", "2e-3,0.2,150", "--theta-i", "30",
                "--theta-r", "40", "--json"])
    assert r.exit_code == 0, r.output
    got = json.loads(r.stdout)
    assert got["brdf"]["model"] == "lambertian-test" and got["medium"]["model"] == "fisher-test"
    want = veil.apparent(LAMBERT, FISHER, 30.0, 40.0)
    assert got["apparent"][0] == pytest.approx(float(want), rel=1e-12)


def test_three_steps_joint_and_diagnose_with_test_models(files):
    d = files["dir"]
    # step 0: the paper's reference in clear water
    r = invoke(["fit", "reference", files["ref_clear"], "-o", d / "ref.json"])
    assert r.exit_code == 0, r.output
    # step 1: the test medium through it
    r = invoke(["fit", "medium", files["ref_medium"], "--reference", d / "ref.json", "--black",
                files["black"], "--medium-model", "fisher-test", "-o", d / "med.json"] + FAST)
    assert r.exit_code == 0, r.output
    med = FitResult.from_json(d / "med.json")
    assert med.model == "fisher-test" and med.kind == "medium" and med.converged
    assert list(med.params) == ["Td", "Tt", "kappa"]
    for name, true in FISHER.as_dict().items():
        assert abs(med.params[name] - true) < 4 * med.stderr_total[name], (name, med.params)
    # step 2: the test BRDF through the fitted test medium
    r = invoke(["fit", "target", files["target"], "--medium", d / "med.json",
                "--brdf-model", "lambertian-test", "-o", d / "tgt.json"] + FAST)
    assert r.exit_code == 0, r.output
    tgt = FitResult.from_json(d / "tgt.json")
    assert tgt.model == "lambertian-test" and tgt.given["model"] == "fisher-test"
    assert abs(tgt.params["rho"] - LAMBERT.rho) < 4 * tgt.stderr_total["rho"]
    # diagnose the target fit, the medium's uncertainty included
    r = invoke(["diagnose", d / "tgt.json", "--data", files["target"], "--medium",
                d / "med.json", "-o", d / "diag"])
    assert r.exit_code == 0, r.output
    diag = json.loads((d / "diag" / "diagnostics.json").read_text())
    assert "rho" in diag["parameters"] and "kappa" in diag["parameters"]
    # the joint fit: the test BRDF under two test media, the scale pinned by a clear session
    r = invoke(["fit", "joint", "--brdf-model", "lambertian-test", "--medium-model",
                "fisher-test", "--session", f"one={files['target']}", "--session",
                f"two={files['target_2']}", "--session", f"none={files['target_clear']}",
                "--fix", "kappa[one]=150", "--fix", "kappa[two]=60", "-o",
                d / "joint.json"] + FAST)
    assert r.exit_code == 0, r.output
    joint = load_result(d / "joint.json")
    assert joint.converged and joint.determined
    assert joint.layout["models"] == {"brdf": "lambertian-test", "medium": "fisher-test"}
    assert joint.brdf("target") == veil_test_models.LambertianTest(rho=joint.params["rho"])
    assert set(joint.params) == {"rho", "Td[one]", "Tt[one]", "kappa[one]", "Td[two]",
                                 "Tt[two]", "kappa[two]"}
    assert joint.params["rho"] == pytest.approx(LAMBERT.rho, rel=0.05)
    r = invoke(["diagnose", d / "joint.json", "--data", f"one={files['target']}", "--data",
                f"two={files['target_2']}", "--data", f"none={files['target_clear']}"])
    assert r.exit_code == 0, r.output
    # a session's table other than the fit's: exit 2 naming the session and both counts,
    # before any work (it ran for minutes without a word)
    short = d / "short.csv"
    veil.save_measurements(veil.load_measurements(files["target_2"]).iloc[:40], short)
    n = len(veil.load_measurements(files["target_2"]))
    r = invoke(["diagnose", d / "joint.json", "--data", f"one={files['target']}", "--data",
                f"two={short}", "--data", f"none={files['target_clear']}"])
    assert r.exit_code == 2, r.output
    assert f"session 'target in two ({short})' has 40 points but the fit used {n}" in r.output


def test_wrong_kinds_and_unknown_names(files):
    d = files["dir"]
    r = invoke(["eval", "--brdf-model", "fisher-test", "--brdf", "1", "--medium", "none",
                "--theta-i", "1", "--theta-r", "1"])
    assert r.exit_code == 2 and "not a registered brdf model" in r.output
    r = invoke(["fit", "reference", files["ref_clear"], "--brdf-model", "phong", "-o",
                d / "x.json"])
    assert r.exit_code == 2 and "lambertian-test" in r.output  # the known ones are listed


def test_a_subprocess_finds_the_plugins_through_the_environment(tmp_path):
    env = dict(os.environ, VEIL_PLUGINS="veil_test_models",
               PYTHONPATH=os.pathsep.join([PLUGINS, os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-m", "veil.cli", "models", "--json"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    names = {e["name"]: e for e in json.loads(out.stdout)}
    assert {"lambertian-test", "fisher-test", "torrance-sparrow",
            "henyey-greenstein"} <= set(names)
    assert [p["name"] for p in names["fisher-test"]["parameters"]] == ["Td", "Tt", "kappa"]
    bad = subprocess.run([sys.executable, "-m", "veil.cli", "models"],
                         env=dict(env, VEIL_PLUGINS="no_such_module"), capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and "VEIL_PLUGINS names module 'no_such_module'" in bad.stderr


def test_a_declared_model_error_reaches_every_fit_through_the_model(files, monkeypatch):
    """A family's MODEL_ERROR_FLOOR (here given to the test medium) is the least term of step
    1, step 2 and a joint fit in media (their residuals show none: simulated data), with its
    length only when correlated; a joint fit with a clear-water session gets none of it."""
    from veil.fitting import fit_joint, fit_medium, fit_reference, fit_target

    monkeypatch.setattr(veil_test_models.FisherTest, "MODEL_ERROR_FLOOR", (0.005, 40.0))
    ref = fit_reference(files["ref_clear"])
    med = fit_medium(files["ref_medium"], ref, black=files["black"],
                     medium_model="fisher-test", accuracy="fast")
    term = med.model_error
    assert (term.sigma, term.length, term.source) == (0.005, 40.0, "model's floor")
    assert term.influence is not None            # step 2 needs it for the shared cross term
    tgt = fit_target(files["target"], med, brdf_model="lambertian-test", accuracy="fast")
    assert tgt.model_error.sigma == 0.005 and tgt.model_error.length == 40.0
    alone = fit_medium(files["ref_medium"], ref, black=files["black"],
                       medium_model="fisher-test", accuracy="fast", model_error="independent")
    assert (alone.model_error.sigma, alone.model_error.length) == (0.005, 0.0)
    kw = dict(brdf_model="lambertian-test", medium_model="fisher-test", accuracy="fast",
              fixed={"kappa[one]": 150.0, "kappa[two]": 60.0})
    media = [(files["target"], "one", "target"), (files["target_2"], "two", "target")]
    # without a clear session one scale is fixed (the media's and the object's trade off)
    joint = fit_joint(media, **dict(kw, fixed=dict(kw["fixed"], **{"Td[one]": 2e-3})))
    assert joint.model_error.source == "model's floor" and joint.model_error.sigma == 0.005
    mixed = fit_joint(media + [(files["target_clear"], "none", "target")], **kw)
    assert mixed.model_error.source != "model's floor"
