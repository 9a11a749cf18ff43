"""Colour channels in the joint fit, in --models auto and in truth= (issue 30, items 2 and 3;
docs/channels.md): the joint fit of RGB sessions is one problem, the parameters declared
per channel one per channel and the shared ones tied; auto fits every candidate over every
channel and ranks it by a BIC counting every channel's points; truth= compares channel by
channel; a one-channel table gives exactly the result of the table without the column.

Small sessions (55 configurations a channel) at the "fast" quadrature, the paper's models."""

from __future__ import annotations

import json
import math
import re

import pandas as pd
import pytest

import veil
from support.cli import run
from veil.analysis.comparison import check_truth, true_values
from veil.analysis.diagnostics import problem_for
from veil.data.measurements import save_measurements
from veil.data.simulate import simulate_channels
from veil.errors import FitError
from veil.fitting import (
    JointResult,
    Session,
    build,
    fit_joint,
    fit_medium,
    fit_reference,
    fit_target,
    load_result,
    selection,
)

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, accuracy="fast")
FAST = "fast"
#: Per channel: the reference BRDF2's and the target BRDF1's diffuse albedo, the factor on
#: the medium BTDF2's T_d and T_t (water that dims red). n, eta and g are shared.
REF_PD = {"r": 800.0, "g": 1000.0, "b": 1200.0}
TGT_PD = {"r": 100.0, "g": 200.0, "b": 400.0}
DIM = {"r": 0.6, "g": 1.0, "b": 1.5}


def _ref(c: str):
    return veil.BRDF2.replace(Pd=REF_PD[c])


def _tgt(c: str):
    return veil.BRDF1.replace(Pd=TGT_PD[c])


def _medium(c: str):
    return veil.BTDF2.replace(Td=veil.BTDF2.Td * DIM[c], Tt=veil.BTDF2.Tt * DIM[c])


@pytest.fixture(scope="module")
def tables() -> dict:
    """The RGB sessions of the two-step method: the reference in clear water and in the
    medium, the target in the medium, the medium's glow in the black cloth."""
    clear = simulate_channels({c: (_ref(c), None) for c in DIM}, noise=0.01, seed=1, **SMALL)
    ref_m, black = simulate_channels({c: (_ref(c), _medium(c)) for c in DIM}, noise=0.01,
                                     seed=2, black=True, **SMALL)
    tgt_m = simulate_channels({c: (_tgt(c), _medium(c)) for c in DIM}, noise=0.01, seed=3,
                              **SMALL)
    return {"clear": clear, "ref_m": ref_m, "tgt_m": tgt_m, "black": black}


@pytest.fixture(scope="module")
def files(tables, tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("rgb")
    paths = {}
    for key, table in tables.items():
        paths[key] = folder / f"{key}.csv"
        save_measurements(table, paths[key])
    return paths


@pytest.fixture(scope="module")
def joint(files, tmp_path_factory) -> JointResult:
    """`veil fit joint` on the RGB files: the reference in clear water and in the medium,
    the target in the medium, the black cloth subtracted channel by channel."""
    out = tmp_path_factory.mktemp("joint") / "joint.json"
    result = run("fit", "joint", "--reference-session", f"none={files['clear']}",
                 "--reference-session", f"m={files['ref_m']}", "--session",
                 f"m={files['tgt_m']}", "--black", f"m={files['black']}", "--accuracy", FAST,
                 "-o", out)
    assert result.exit_code == 0, result.output
    assert "in 3 channels" in result.output and "Td[m][b]" in result.output
    return load_result(out)


@pytest.fixture(scope="module")
def steps(tables):
    """The two-step method over the same channels."""
    ref = fit_reference(tables["clear"])
    med = fit_medium(tables["ref_m"], ref, black=tables["black"], accuracy=FAST)
    return ref, med, fit_target(tables["tgt_m"], med, black=tables["black"], accuracy=FAST)


def _sessions(tables, black=True) -> list[Session]:
    return [Session(tables["clear"], "none", "reference"),
            Session(tables["ref_m"], "m", "reference", black=tables["black"] if black else None),
            Session(tables["tgt_m"], "m", "target", black=tables["black"] if black else None)]


# --------------------------------------------------------------------------------------
# the joint fit over channels
# --------------------------------------------------------------------------------------
def test_the_joint_fit_recovers_each_channel_and_the_shared_parameters(joint):
    assert isinstance(joint, JointResult) and joint.converged
    assert joint.channel_names == ("r", "g", "b") and joint.n_points == 3 * 3 * 55
    truth = {"n": veil.BRDF1.n, "eta": veil.BRDF1.eta, "ref.n": veil.BRDF2.n,
             "g[m]": veil.BTDF2.g, "eta_u": veil.BTDF2.eta}
    for c in DIM:
        truth |= {f"Pd[{c}]": TGT_PD[c], f"Ps[{c}]": veil.BRDF1.Ps, f"ref.Pd[{c}]": REF_PD[c],
                  f"Td[m][{c}]": _medium(c).Td, f"Tt[m][{c}]": _medium(c).Tt}
    for name, value in truth.items():
        se = joint.stderr[name]
        assert se is not None and abs(joint.params[name] - value) < 3 * se, (name, se)


def test_the_joint_fit_agrees_with_the_steps_over_the_same_channels(joint, steps):
    _, med, tgt = steps
    for name, value in tgt.params.items():
        combined = math.hypot(tgt.stderr_total[name], joint.stderr[name])
        assert abs(joint.params[name] - value) < 2 * combined, name
    for c in DIM:
        for p in ("Td", "Tt"):
            a, b = joint.params[f"{p}[m][{c}]"], med.params[f"{p}[{c}]"]
            assert abs(a - b) < 2 * math.hypot(joint.stderr[f"{p}[m][{c}]"],
                                               med.stderr_total[f"{p}[{c}]"]), (p, c)


def test_three_channels_have_the_tied_parameters_once(tables):
    """24 free parameters: per channel P_d, P_s of both objects and T_d, T_t of the medium
    (18), n, eta of both objects, g and eta_u once (6). Three fits of one channel have 36."""
    problem, layout = build(_sessions(tables))
    assert problem.n_free == 24
    one, _ = build(_sessions(tables), channel="g")
    assert one.n_free == 12 and 3 * one.n_free > problem.n_free
    names = set(problem.free_names)
    assert {"Pd[r]", "ref.Ps[b]", "Td[m][g]", "n", "ref.eta", "g[m]", "eta_u"} <= names
    assert not {"n[r]", "g[m][r]", "Pd", "Td[m]"} & names
    assert layout["channels"]["b"]["media"]["m"] == {"Td": "Td[m][b]", "Tt": "Tt[m][b]",
                                                     "g": "g[m]", "eta_u": "eta_u"}
    # the blocks: session after session, channel after channel, each its channel's slots
    r_block = problem.blocks[3 * 2]  # the target in the medium, channel r
    assert [problem.names[k] for k in r_block.ib] == ["Pd[r]", "Ps[r]", "n", "eta"]


def test_the_joint_result_round_trips_and_gives_each_channels_models(joint, tmp_path):
    joint.to_json(tmp_path / "j.json")
    back = load_result(tmp_path / "j.json")
    assert back.to_dict() == joint.to_dict()
    assert back.brdf("target", "r").Pd == joint.params["Pd[r]"]
    assert back.brdf("reference", "b").Pd == joint.params["ref.Pd[b]"]
    assert back.medium("m", "g").Td == joint.params["Td[m][g]"]
    every = back.as_model()
    assert isinstance(every, veil.ChannelModel) and every["b"] == back.brdf("target", "b")
    with pytest.raises(FitError, match="fits channels r, g, b at once"):
        back.medium("m")
    with pytest.raises(FitError, match="no channel 'x'"):
        back.one_model("x")
    with pytest.raises(FitError, match="the diagnostics take a joint fit of one channel"):
        problem_for(back, [])
    data = json.loads((tmp_path / "j.json").read_text())
    assert data["channels"]["g"] == {"Pd": "Pd[g]", "Ps": "Ps[g]", "n": "n", "eta": "eta"}
    assert [s["channel"] for s in data["layout"]["sessions"]][:3] == ["r", "g", "b"]


def test_a_reference_fitted_over_the_channels_is_held_with_its_covariance(tables, steps):
    """The step-0 fit over r, g, b as the joint fit's reference: each channel's model held,
    its covariance propagated per channel into stderr_total, the given entry per channel."""
    result = fit_joint(_sessions(tables)[1:], reference=steps[0], accuracy=FAST)
    assert result.converged and result.n_free == 16  # the target's 8, the medium's 8
    assert result.given["channels"] == steps[0].channels
    assert result.given_model("b") == steps[0].as_model(channel="b")
    for name in ("Pd[r]", "n", "Td[m][b]"):
        assert result.stderr_total[name] > result.stderr[name], name
    assert abs(result.params["Pd[g]"] - TGT_PD["g"]) < 3 * result.stderr_total["Pd[g]"]


def test_a_one_channel_table_gives_the_joint_fit_of_the_table_without_the_column(tables):
    def green(table, column=True):
        one = table[table["channel"] == "g"].reset_index(drop=True)
        return one if column else one.drop(columns="channel")

    fits = []
    for column in (True, False):
        sessions = [Session(green(tables["ref_m"], column), "m", "reference"),
                    Session(green(tables["tgt_m"], column), "m", "target")]
        fits.append(fit_joint(sessions, reference=_ref("g"), accuracy=FAST))
    assert fits[0].channels is None and fits[0].to_dict() == fits[1].to_dict()


def test_fixing_a_parameter_by_its_one_channel_name_holds_every_channel(tables):
    targets = [Session(tables["tgt_m"], "m", "target", black=tables["black"])]
    problem, _ = build(targets, fixed={"Td[m]": 1e-3})
    held = {n: problem.values[k] for k, n in enumerate(problem.names) if not problem.free[k]}
    assert held == {"Td[m][r]": 1e-3, "Td[m][g]": 1e-3, "Td[m][b]": 1e-3}
    with pytest.raises(FitError, match="not determined in channel g"):
        build(targets, fixed={"Td[m][r]": 1e-3})


def test_joint_bad_input_over_channels(tables, files, steps, tmp_path):
    two = tables["tgt_m"][tables["tgt_m"]["channel"] != "b"]
    with pytest.raises(FitError, match=r"has channels r, g but session .* has channels r, g, b"):
        build([Session(tables["ref_m"], "m", "reference"), Session(two, "m", "target")],
              reference=_ref("g"))
    one_channel = fit_reference(tables["clear"], channel="g")
    with pytest.raises(FitError, match="a fit of one channel"):
        build(_sessions(tables)[1:], reference=one_channel)
    # a fit over the channels as the reference: each channel's model held
    problem, layout = build(_sessions(tables)[1:], reference=steps[0])
    assert problem.values[problem.index("ref.Pd[b]")] == steps[0].params["Pd[b]"]
    assert not problem.free[problem.index("ref.Pd[b]")] and layout["reference_given"]
    grey = tmp_path / "grey.csv"
    save_measurements(veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=9, **SMALL), grey)
    out = run("fit", "joint", "--session", f"m={files['tgt_m']}", "--session", f"low={grey}",
              "--fix", "Td[m]=1e-3", "-o", tmp_path / "x.json")
    assert out.exit_code == 2 and "no channel column" in out.output and "grey.csv" in out.output
    assert not (tmp_path / "x.json").exists()


# --------------------------------------------------------------------------------------
# --models auto over channels
# --------------------------------------------------------------------------------------
#: The candidates of the auto test: the paper's families against the test plugins' (a
#: Lambertian surface, a medium with a von Mises-Fisher lobe), all cheap to compile.
FAMILIES = {"brdf": ["torrance-sparrow", "lambertian-test"],
            "medium": ["henyey-greenstein", "fisher-test"]}


@pytest.fixture
def few_candidates(monkeypatch):
    import veil_test_models  # noqa: F401  (registers the plugin families)

    every = selection.candidates
    monkeypatch.setattr(selection, "candidates",
                        lambda kind, given=None, families=None: every(kind, given,
                                                                      FAMILIES[kind]))


def test_auto_over_channels_picks_the_generating_families(tables, few_candidates, tmp_path):
    """Every candidate fitted over r, g, b at once and ranked by a BIC that counts every
    channel's points and the fit's free parameters (the shared ones once); the paper's
    families, which made the data, chosen at each step; the ranking's shape as for one
    channel; truth= per channel beside the estimates in report.md."""
    truth = {"reference": {c: _ref(c) for c in DIM},
             "medium": veil.ChannelModel({c: _medium(c) for c in DIM}), "target": "BRDF1"}
    res = veil.run_pipeline(tables["clear"], tables["ref_m"], tables["tgt_m"],
                            black=tables["black"], outdir=tmp_path / "auto", models="auto",
                            accuracy=FAST, figures=False, truth=truth)
    chosen = {step: r.chosen for step, r in res.rankings.items()}
    assert chosen == {"reference": "torrance-sparrow", "medium": "henyey-greenstein",
                      "target": "torrance-sparrow"}
    for step, result in (("reference", res.reference), ("medium", res.medium),
                         ("target", res.target)):
        assert result.channel_names == ("r", "g", "b")
        best, other = res.rankings[step].rows
        assert best["n_points"] == result.n_points == 3 * 55
        assert best["k"] >= result.n_free == 8  # (+ the discrepancy term's, if any)
        assert best["bic"] == pytest.approx(best["deviance"] + best["k"] * math.log(165))
        assert other["delta_bic"] > 100
    ranking = json.loads((tmp_path / "auto" / "ranking.json").read_text())
    one = selection.Ranking("x", [], None, []).to_dict()
    assert set(ranking["target"]) == set(one)
    report = (tmp_path / "auto" / "report.md").read_text()
    row = re.search(r"\| Pd\[r\] \| [^|]+ \| [^|]+ \| [^|]+ \| ([^|]+) \| ([^|]+) \|", report)
    assert float(row.group(1)) == REF_PD["r"] and abs(float(row.group(2))) < 3
    assert re.search(r"\| Tt\[b\] \| [^|]+ \| [^|]+ \| [^|]+ \| 0\.195 \|", report)


def test_fit_reference_auto_over_channels(files, few_candidates, tmp_path):
    out = run("fit", "reference", files["clear"], "--brdf-model", "auto", "-o",
              tmp_path / "r.json")
    assert out.exit_code == 0, out.output
    rows = json.loads((tmp_path / "r.json").read_text())["stats"]["selection"]["candidates"]
    assert rows[0]["label"] == "torrance-sparrow" and rows[0]["n_points"] == 165


# --------------------------------------------------------------------------------------
# truth= over channels
# --------------------------------------------------------------------------------------
def test_truth_channel_by_channel(steps):
    ref = steps[0]
    per = check_truth({"reference": {c: _ref(c) for c in DIM}}, ["r", "g", "b"])
    values = true_values(ref, per["reference"])
    assert values["Pd[b]"] == REF_PD["b"] and values["n"] == veil.BRDF2.n
    # one model for every channel: each channel against it
    assert true_values(ref, check_truth({"reference": "BRDF2"}, ["r", "g", "b"])["reference"]
                       )["Pd[r]"] == veil.BRDF2.Pd
    # a tied parameter whose channels' truths differ has no one true value
    rough = {c: _ref(c).replace(n=0.5 + 0.1 * k) for k, c in enumerate(DIM)}
    assert true_values(ref, rough)["n"] is None
    # of one channel of the tables, that channel's truth
    assert check_truth({"reference": per["reference"]}, None, "g")["reference"] == _ref("g")
    with pytest.raises(FitError, match="gives channels r, g but the tables are fitted in "
                                       "channels r, g, b"):
        check_truth({"reference": {"r": _ref("r"), "g": _ref("g")}}, ["r", "g", "b"])
    with pytest.raises(FitError, match="expected a dict by step"):
        check_truth({"direct": "BRDF1"}, None)


# --------------------------------------------------------------------------------------
# review mends: inputs kept, channel order, one channel of a reference, truths
# --------------------------------------------------------------------------------------
def test_joint_never_writes_over_a_table_with_channels(files, tmp_path):
    victim = tmp_path / "victim.csv"
    victim.write_bytes(files["clear"].read_bytes())
    out = run("fit", "joint", "--reference-session", f"none={victim}", "--reference-session",
              f"m={files['ref_m']}", "--session", f"m={files['tgt_m']}", "--black",
              f"m={files['black']}", "--max-nfev", "1", "-o", victim)
    assert out.exit_code == 2 and "never overwrites an input" in out.output, out.output
    assert victim.read_bytes() == files["clear"].read_bytes()


def test_the_ranking_stacks_each_session_in_its_fits_channel_order(tables, steps):
    """A session whose rows run b, g, r is fitted channel after channel in that order; the
    data auto ranks it on are stacked the same way (else the discrepancy term's likelihood
    pairs one channel's residuals with another's values)."""
    from veil.fitting.session_data import stack
    from veil.pipeline import CHANNEL_DATA, _prepare_sessions

    ref_m = tables["ref_m"]
    reordered = pd.concat([ref_m[ref_m["channel"] == c] for c in "bgr"], ignore_index=True)
    inputs = {"reference_clear": tables["clear"], "reference_medium": reordered,
              "target_medium": tables["tgt_m"], "target_clear": None, "black": tables["black"]}
    data, channels = _prepare_sessions(inputs)
    assert channels == ["r", "g", "b"]
    stacked = stack(data[CHANNEL_DATA]["reference_medium"])
    med = fit_medium(reordered, steps[0], black=tables["black"], accuracy=FAST, max_nfev=2)
    assert med.channel_names == ("b", "g", "r")
    assert list(dict.fromkeys(stacked.table["channel"])) == list(med.channel_names)
    assert len(stacked.y) == len(med.residuals)
    with pytest.raises(FitError, match="every session needs the same channels"):
        _prepare_sessions({**inputs, "reference_medium": ref_m[ref_m["channel"] != "b"]})


def test_a_pipeline_session_of_other_channels_names_its_file(tables, tmp_path):
    """The refusal named the session's role only ("the target (clear medium) table"), not
    the file the user gave."""
    from veil.pipeline import _prepare_sessions

    ref_m = tables["ref_m"]
    path = tmp_path / "only_rg.csv"
    save_measurements(ref_m[ref_m["channel"] != "b"], path)
    inputs = {"reference_clear": tables["clear"], "reference_medium": path,
              "target_medium": tables["tgt_m"], "target_clear": None, "black": tables["black"]}
    with pytest.raises(FitError, match=r"table \S*only_rg\.csv has channels r, g but the "):
        _prepare_sessions(inputs)


def test_one_channel_of_a_reference_fitted_over_several(tables, steps):
    problem, _ = build(_sessions(tables)[1:], reference=steps[0].one_model("g"),
                       channel="g")
    held = problem.values[problem.index("ref.Pd")]
    assert held == steps[0].params["Pd[g]"]
    joint = fit_joint(_sessions(tables)[1:], reference=steps[0], channel="g", accuracy=FAST,
                      max_nfev=1)
    assert joint.params["ref.Pd"] == steps[0].params["Pd[g]"]


def test_tables_of_different_single_channels_are_refused(tables):
    clear_g = tables["clear"][tables["clear"]["channel"] == "g"]
    ref_r = tables["ref_m"][tables["ref_m"]["channel"] == "r"]
    tgt_r = tables["tgt_m"][tables["tgt_m"]["channel"] == "r"]
    with pytest.raises(FitError, match="is of channel r but session .* of channel g"):
        build([Session(clear_g, "none", "reference", name="clear"),
               Session(ref_r, "m", "reference", name="ref"),
               Session(tgt_r, "m", "target", name="tgt")])


def test_fix_by_a_channels_own_name_wins_in_any_order():
    from veil.fitting.joint_channels import expand_names
    from veil.fitting.problem import Slot

    params = [Slot(f"Td[m][{c}]", "medium", "m", 0, None, True) for c in "rgb"]  # type: ignore[arg-type]
    names = {c: {"Td[m]": f"Td[m][{c}]"} for c in "rgb"}
    one = expand_names({"Td[m]": 1e-3, "Td[m][r]": 2e-3}, params, names)
    other = expand_names({"Td[m][r]": 2e-3, "Td[m]": 1e-3}, params, names)
    assert one == other == {"Td[m][r]": 2e-3, "Td[m][g]": 1e-3, "Td[m][b]": 1e-3}


def test_a_truth_of_another_family_or_more_channels(steps):
    from veil.models import model_class
    from veil.viz.pipeline_report import _param_table

    plastic = model_class("rough-plastic")(0.5, 0.1, 1.5, 1.0)
    lines = _param_table(steps[0], {c: plastic for c in DIM})
    assert "true |" not in lines[0]
    assert any("The truth is a rough-plastic model and the fit a torrance-sparrow" in x
               for x in lines)
    with pytest.raises(FitError, match="gives channels r, g, b, nir"):
        check_truth({"reference": {**{c: _ref(c) for c in DIM}, "nir": _ref("r")}},
                    ["r", "g", "b"])
