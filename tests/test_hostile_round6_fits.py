"""Hostile use of the fits and of model selection, sixth round: a ``--fix`` under ``--models
auto`` that no candidate family can hold (the pipeline listed those candidates as failed
and exited 0 with a model that ignored the fix), an option no candidate takes given to a
single step's auto (the family dropped without a word), a fit result handed to ``veil.apparent``,
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


# -- 1. --fix under --models auto that no candidate family can hold ----------------------
def test_auto_pipeline_refuses_a_fixed_value_no_candidate_could_hold(sessions, tmp_path):
    """tau is the forward series' alone: -0.5 made every such candidate fail, and the
    paper's medium was chosen, exit 0, the fix unused (only a row of the table said why)."""
    r = _pipeline(sessions, tmp_path / "out", "--models", "auto", "--fix", "medium.tau=-0.5")
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert "--fix medium.tau=-0.5: no candidate could hold it (fixed forward-series tau = " \
        "-0.5 is outside [0, 3]" in text
    assert "the one chosen (henyey-greenstein) has no tau: the value would go unused" in text
    assert "internal error" not in text
    assert not (tmp_path / "out").exists()


def test_auto_pipeline_in_python_names_the_keyword(sessions, tmp_path):
    with pytest.raises(FitError, match=r"fixed=\{'medium': \{'tau': -0.5\}\}.*no candidate "
                                       r"could hold it"):
        veil.run_pipeline(str(sessions["reference-clear"]), str(sessions["reference-medium"]),
                          str(sessions["target-medium"]), black=str(sessions["black"]),
                          outdir=tmp_path / "out", models="auto", accuracy="fast",
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


def test_a_fix_of_a_candidate_left_out_of_the_ranking_is_not_looked_up():
    """Over several channels the linear family is left out of the ranking, its fixes kept
    in the plan: looking its row up raised StopIteration (an internal error). Its fix is
    passed over; the ranked candidates' own failures still refuse the value."""
    from types import SimpleNamespace

    from veil.fitting.auto import refuse_unheld

    rows = [{"label": "henyey-greenstein", "error": None},
            {"label": "forward-series", "error": "FitError: fixed forward-series.tau = -0.5 "
                                                 "is outside [0, 3]"}]
    ranking = SimpleNamespace(rows=rows, chosen="henyey-greenstein",
                              row=lambda lab: next(r for r in rows if r["label"] == lab))
    refuse_unheld("target", ranking, {"nonparametric": {"d0": 0.5}})
    with pytest.raises(FitError, match="no candidate could hold it"):
        refuse_unheld("medium", ranking, {"forward-series": {"tau": -0.5},
                                          "nonparametric": {"tau": -0.5}})


def test_a_malformed_fix_under_auto_gets_no_hint_about_values(sessions, tmp_path):
    """A --fix that does not parse was given the out-of-bounds hint ("give a value they all
    take"), which does not apply to it."""
    for item, said in (("n=abc", "'abc' is not a number"), ("n", "expected NAME=VALUE")):
        r = run_checked(["fit", "reference", sessions["reference-clear"], "--brdf-model",
                         "auto", "--fix", item, "-o", tmp_path / "r.json"])
        assert r.exit_code == 2, r.output
        assert f"--fix '{item}': {said}" in _said(r), r.output
        assert "give a value they all take" not in _said(r), r.output


# -- 2. a fit result where the forward model takes a model ---------------------------------
@pytest.fixture(scope="module")
def fitted():
    """A fit of the paper's surface in clear water and a medium's fit result (HG, BTDF2)."""
    table = veil.simulate("BRDF1", None, **SCREEN)
    brdf = veil.fit_reference(table)
    medium = veil.FitResult(model="henyey-greenstein", params=veil.BTDF2.as_dict(),
                            stderr={k: None for k in veil.BTDF2.as_dict()}, correlation={},
                            residuals=tuple(range(2000)), chi2_reduced=1.0, rms_relative=0.01,
                            n_points=2000, converged=True, message="", step="medium")
    return brdf, medium


@pytest.mark.parametrize("call, family", [
    (lambda b, m: veil.reflectance(b, 45, [40, 45]), "torrance-sparrow"),
    (lambda b, m: veil.apparent(b, "BTDF2", 45, 45, accuracy="fast"), "torrance-sparrow"),
    (lambda b, m: veil.apparent("BRDF1", m, 45, 45, accuracy="fast"), "henyey-greenstein"),
    (lambda b, m: veil.simulate(b, "BTDF2", accuracy="fast"), "torrance-sparrow"),
    (lambda b, m: veil.simulate("BRDF1", m, accuracy="fast"), "henyey-greenstein"),
])
def test_a_fit_result_given_as_a_model_says_as_model(fitted, call, family):
    """The message held the result's repr: every parameter, correlation and residual (a
    thousand lines for a session's fit)."""
    with pytest.raises(InputError) as caught:
        call(*fitted)
    text = str(caught.value)
    assert f"got FitResult({family} fit, step " in text
    assert text.endswith("converged; its model: .as_model())")
    assert len(text) < 300 and "residuals" not in text and "\n" not in text


def test_the_repr_of_a_result_of_many_parameters_is_one_short_line(fitted):
    brdf, _ = fitted
    table = veil.simulate("BRDF1", None, **SCREEN)
    lobes = veil.fit_reference(table, brdf_model="nonparametric")
    for result in (brdf, lobes):
        text = repr(result)
        assert "\n" not in text and len(text) < 250 and "residuals" not in text
    assert "... (55 parameters)" in repr(lobes)


def test_a_joint_result_file_reads_as_one_by_fit_result_from_json(tmp_path):
    """FitResult.from_json of a joint fit's file said "key 'model' = 'joint' is not a known
    model", though veil wrote it; load_result read it."""
    from veil.fitting import JointResult, load_result

    sessions = [(veil.simulate(brdf, medium, **SCREEN), label, obj)
                for label, medium in (("none", None), ("m", "BTDF2"))
                for obj, brdf in (("reference", "BRDF2"), ("target", "BRDF1"))]
    joint = veil.fit_joint(sessions, accuracy="fast")
    joint.to_json(tmp_path / "joint.json")
    read = veil.FitResult.from_json(tmp_path / "joint.json")
    assert isinstance(read, JointResult)
    assert read.params == load_result(tmp_path / "joint.json").params == joint.params
    assert repr(read).endswith("its model: .as_model(), .brdf(object), .medium(label))")


# -- 3. a grey reference in clear water, the sessions in the medium in colour ---------------
def test_a_grey_clear_reference_with_colour_sessions_says_the_channels_differ(sessions,
                                                                              tmp_path):
    """The message was the single-step fits' ("the reference (in the medium) fit does not
    fit several channels at once; select one with --channel NAME in veil fit reference,
    medium or target"), though the pipeline fits several channels and has --channel."""
    colour = {c: ("BRDF2", "BTDF2") for c in "rgb"}
    table, black = veil.simulate(colour, None, black=True, **SCREEN)
    table.to_csv(tmp_path / "rgb.csv", index=False)
    black.to_csv(tmp_path / "rgb_black.csv", index=False)
    args = ["fit", "pipeline", "--no-figures", "--accuracy", "fast", "-o", tmp_path / "out",
            "--reference-clear", sessions["reference-clear"],
            "--reference-medium", tmp_path / "rgb.csv", "--target-medium", tmp_path / "rgb.csv",
            "--black", tmp_path / "rgb_black.csv"]
    r = run_checked(args)
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert f"the reference (in the medium) table {tmp_path / 'rgb.csv'} has channels r, g, b " \
        "but the reference (clear medium) table has one channel: every session needs the " \
        "same channels (or fit one: channel='NAME', --channel NAME)" in text
    assert "veil fit reference, medium or target" not in text
    assert not (tmp_path / "out").exists()


# -- 4. a non-parametric result of no signal exported -------------------------------------
@pytest.mark.parametrize("to", ["mitsuba", "pbrt"])
def test_exporting_a_result_whose_f_r_is_zero_says_so_not_rescale(tmp_path, to):
    """All-zero data give the non-parametric fit every coefficient 0 (written, not
    converged); its export said f_r "reaches 0, beyond the magnitudes (1e-100 to 1e+100)"
    and asked to rescale the data: no factor makes zero data fit."""
    table = veil.simulate("BRDF1", None, **SCREEN)
    table["value"] = 0.0
    table["sigma"] = 1.0
    lobes = veil.fit_reference(table, brdf_model="nonparametric")
    assert not lobes.converged and not any(lobes.params.values())
    lobes.to_json(tmp_path / "zero.json")
    r = run_checked(["export", tmp_path / "zero.json", "--to", to, "-o", tmp_path / "m.out"])
    assert r.exit_code == 2, r.output
    text = _said(r)
    assert f"{tmp_path / 'zero.json'}: nonparametric: f_r is 0 at every configuration " \
        "(every coefficient 0), so there is no reflectance to export" in text
    assert "rescale" not in text and "internal error" not in text
    assert not (tmp_path / "m.out").exists()


# -- 5. a parameter both fixed and freed ---------------------------------------------------
@pytest.mark.parametrize("args, said", [
    (["fit", "target", "{ref}", "--medium", "BTDF2", "--fix", "n=0.5", "--free", "n"],
     "--fix n=0.5 and --free n: a parameter is held at a value (--fix) or fitted"),
    (["fit", "target", "{ref}", "--medium", "BTDF2", "--brdf-model", "auto", "--fix",
      "eta=1.5", "--free", "eta"],
     "--fix eta=1.5 and --free eta: a parameter is held"),
    (["fit", "pipeline", "--reference-clear", "{ref}", "--reference-medium", "{ref}",
      "--target-medium", "{ref}", "--fix", "target.n=0.5", "--free", "target.n"],
     "--fix target.n=0.5 and --free target.n: a parameter is held"),
    (["fit", "pipeline", "--reference-clear", "{ref}", "--reference-medium", "{ref}",
      "--target-medium", "{ref}", "--models", "auto", "--fix", "medium.g=0.5", "--free",
      "medium.g"],
     "--fix medium.g=0.5 and --free medium.g: a parameter is held"),
])
def test_a_parameter_both_fixed_and_freed_names_both_options(sessions, tmp_path, args, said):
    """The message was "n both fixed and freed", naming neither option nor step."""
    ref = str(sessions["reference-clear"])
    r = run_checked([a.format(ref=ref) for a in args] + ["-o", tmp_path / "out"])
    assert r.exit_code == 2, r.output
    assert said in _said(r) and "give one of the two" in _said(r)
    assert not (tmp_path / "out").exists()


def test_a_parameter_both_fixed_and_freed_in_python_says_why(sessions):
    with pytest.raises(FitError, match="n both fixed and freed: a parameter is held at its "
                                       "fixed value or fitted"):
        veil.fit_reference(str(sessions["reference-clear"]), fixed={"n": 0.5}, free=["n"])


# -- 6. an option no candidate takes, given to a single step's auto ------------------------
def test_auto_step_fit_refuses_an_option_no_candidate_takes(sessions, tmp_path):
    """rough-plastic declares --nonlinear True but makes no model with it: under auto the
    family was dropped from the candidates without a word and the fit exited 0 with the
    option unused (the pipeline's auto refused it)."""
    r = run_checked(["fit", "reference", sessions["reference-clear"], "--brdf-model", "auto",
                     "--nonlinear", "True", "-o", tmp_path / "r.json"])
    assert r.exit_code == 2, r.output
    assert "option(s) nonlinear = True (rough-plastic): the families that declare them make " \
        "no model with that value, so no candidate takes it" in _said(r)
    assert not (tmp_path / "r.json").exists()
