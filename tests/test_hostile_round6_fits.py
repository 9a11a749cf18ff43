"""Hostile use of the fits and of model selection, sixth round: a ``--fix`` under ``--models
auto`` that no candidate family can hold (the pipeline dropped those candidates as failed
and exited 0 with a model that ignored the fix), a fit result handed to ``veil.apparent``,
``veil.reflectance`` or ``veil.simulate`` in place of its model (the message printed the
whole result), a grey clear-water reference with colour sessions in the medium (the message
sent the user to the single-step commands), a non-parametric result of no signal exported
(the message asked to rescale data that were zero), and a parameter both fixed and freed
(the message named neither option nor step). Each is status 2 (an InputError in Python)
whose words name the option, step or argument and say what to do; nothing is written."""

from __future__ import annotations

import pytest

import veil
from support.cli import run_checked
from veil.errors import FitError, InputError

SCREEN = {"accuracy": "fast", "seed": 0}


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """The paper's four sessions (reference BRDF2 and target BRDF1, clear and through
    BTDF2) and the black cloth, as files."""
    folder = tmp_path_factory.mktemp("sessions")
    ref_medium, black = veil.simulate("BRDF2", "BTDF2", black=True, **SCREEN)
    tables = {
        "reference-clear": veil.simulate("BRDF2", None, **SCREEN),
        "reference-medium": ref_medium,
        "target-medium": veil.simulate("BRDF1", "BTDF2", **SCREEN),
        "black": black,
        "target-clear": veil.simulate("BRDF1", None, **SCREEN),
    }
    paths = {}
    for role, table in tables.items():
        paths[role] = folder / f"{role}.csv"
        table.to_csv(paths[role], index=False)
    return paths


def _pipeline(sessions, out, *extra, clear_target=False):
    args = ["fit", "pipeline", "--no-figures", "--accuracy", "fast", "-o", out]
    for role in ("reference-clear", "reference-medium", "target-medium", "black"):
        args += [f"--{role}", sessions[role]]
    if clear_target:
        args += ["--target-clear", sessions["target-clear"]]
    return run_checked([*args, *extra])


def _said(result) -> str:
    return " ".join(result.output.split())


# -- 1. --fix under --models auto that a candidate family cannot hold ----------------------
@pytest.mark.parametrize("fix, said", [
    # tau is the forward series' alone: every candidate having it failed, the fix unused,
    # and the paper's medium was chosen with status 0
    ("medium.tau=-0.5", "--fix medium.tau=-0.5: forward-series tau = -0.5 is outside [0, 3]"),
    # n is Torrance-Sparrow's smoothness (up to 50 1/deg) and rough-conductor's index (to 10)
    ("reference.n=20", "--fix reference.n=20: rough-conductor n = 20 is outside (0, 10]"),
])
def test_auto_pipeline_refuses_a_fixed_value_a_candidate_cannot_hold(sessions, tmp_path, fix,
                                                                      said):
    r = _pipeline(sessions, tmp_path / "out", "--models", "auto", "--fix", fix)
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert said in text
    assert "holds in every candidate family that has the parameter" in text
    assert "--models FAMILY+MEDIUM" in text and "internal error" not in text
    assert not (tmp_path / "out").exists()


def test_auto_pipeline_in_python_names_the_keyword(sessions, tmp_path):
    with pytest.raises(FitError, match=r"fixed=\{'medium': \{'tau': -0.5\}\}.*outside \[0, 3\]"):
        veil.run_pipeline(str(sessions["reference-clear"]), str(sessions["reference-medium"]),
                          str(sessions["target-medium"]), black=str(sessions["black"]),
                          outdir=tmp_path / "out", models="auto",
                          fixed={"medium": {"tau": -0.5}}, figures=False)
    assert not (tmp_path / "out").exists()


def test_auto_pipeline_names_the_option_of_an_unknown_parameter(sessions, tmp_path):
    r = _pipeline(sessions, tmp_path / "out", "--models", "auto", "--free", "medium.nosuch")
    assert r.exit_code == 2
    assert "(--free medium.nosuch): no candidate model has such a parameter" in _said(r)


def test_auto_step_fit_says_the_fix_holds_in_every_family_having_it(sessions, tmp_path):
    r = run_checked(["fit", "reference", sessions["reference-clear"], "--brdf-model", "auto",
                     "--fix", "n=20", "-o", tmp_path / "r.json"])
    assert r.exit_code == 2
    text = _said(r)
    assert "rough-conductor n = 20 is outside (0, 10]" in text
    assert "every candidate family that has the parameter (torrance-sparrow, rough-conductor)" \
        in text and "--brdf-model FAMILY" in text
    assert not (tmp_path / "r.json").exists()
