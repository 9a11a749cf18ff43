"""Joint estimation over several media (veil.fitting.joint, docs/model.md sec. 7; docs/ambiguity.md).

Small sessions (55 configurations: one engine chunk) at the "fast" quadrature keep the
compilations and fits short; accuracy is not the point here.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import veil
import veil.data.protocol
from veil.cli import main
from veil.fitting import FitError, FitResult, JointResult, Session, build, fit_joint, load_result

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")
MEDIA = {"low": veil.BTDF1, "mid": veil.BTDF2, "high": veil.BTDF3}


@pytest.fixture(scope="module")
def tables():
    return {label: veil.simulate(veil.BRDF1, m, noise=0.01, seed=k, **SMALL)
            for k, (label, m) in enumerate(MEDIA.items())}


@pytest.fixture(scope="module")
def joint(tables):
    # the scale is fixed by Td of one medium (the data determine P x T^2 only)
    return fit_joint(tables, fixed={"Td[low]": veil.BTDF1.Td}, accuracy="fast")


def test_joint_fit_recovers_parameters_within_3_sigma(joint):
    assert isinstance(joint, JointResult) and joint.converged
    assert joint.n_points == 165 and joint.weighted
    assert 0.5 < joint.chi2_reduced < 1.6
    truth = {"Pd": 200.0, "Ps": 5e5, "n": 0.8, "eta": 1.55, "eta_u": 1.3}
    for label, m in MEDIA.items():
        truth.update({f"Tt[{label}]": m.Tt, f"g[{label}]": m.g})
        if label != "low":
            truth[f"Td[{label}]"] = m.Td
    for name, value in truth.items():
        se = joint.stderr[name]
        assert se is not None and se > 0, name
        assert abs(joint.params[name] - value) < 3 * se, (name, joint.params[name], value, se)
    # n is well determined jointly (a single BTDF3 session with its medium free gives ~16 %)
    assert joint.stderr["n"] / joint.params["n"] < 0.03
    assert joint.fixed == {"Td[low]": veil.BTDF1.Td} and joint.stderr["Td[low]"] is None


def test_sharing_declarations_are_honoured(joint):
    # default: eta_u shared (one parameter, identical in every medium), g per medium
    assert joint.layout["shared"] == ["eta_u"]
    media = {label: joint.medium(label) for label in MEDIA}
    assert len({m.eta for m in media.values()}) == 1
    assert media["low"].eta == joint.params["eta_u"]
    gs = [m.g for m in media.values()]
    assert len(set(gs)) == 3 and gs[0] > gs[1] > gs[2]
    assert "g" not in joint.params and "g[mid]" in joint.params
    # declared the other way round, the layout maps every medium to one g
    problem, layout = build(_sessions_from(joint_tables_small()), shared=("g",),
                            fixed={"Td[a]": 1e-3})
    assert layout["media"]["a"]["g"] == layout["media"]["b"]["g"] == "g"
    assert layout["media"]["a"]["eta_u"] == "eta_u[a]"
    ia, ib = (b.im for b in problem.blocks)
    assert ia[2] == ib[2] and ia[3] != ib[3] and ia[0] != ib[0]


def test_json_round_trip_and_loader(joint, tmp_path):
    path = tmp_path / "joint.json"
    joint.to_json(path)
    data = json.loads(path.read_text())
    assert data["model"] == "joint" and data["layout"]["media"]["low"]["Tt"] == "Tt[low]"
    back = load_result(path)
    assert isinstance(back, JointResult)
    assert back.params == joint.params and back.stderr == joint.stderr
    assert back.medium("high") == joint.medium("high")
    assert back.brdf("target") == joint.brdf("target")
    assert "Joint fit" in back.report() and "Tt[high]" in back.report()
    # FitResult.from_json reads it as the joint result it is, as load_result does
    assert FitResult.from_json(path).params == back.params
    assert isinstance(FitResult.from_json(path), JointResult)
    bad = dict(data, layout={"objects": {"target": {"Pd": "Pd", "Ps": "Ps", "n": "nn",
                                                    "eta": "eta"}}, "media": {}})
    path.write_text(json.dumps(bad))
    with pytest.raises(FitError, match="nn"):
        load_result(path)


# ------------------------------------------------------------------------------------------
# bad input (no fit needed)
# ------------------------------------------------------------------------------------------
def joint_tables_small():
    t = veil.data.protocol.protocol((30, 60), fine_step=5, coarse_step=20)
    t = t.assign(value=1.0 + 0.01 * np.arange(len(t)), sigma=0.01)
    return t


def _sessions_from(t):
    return [Session(t, "a", "target"), Session(t.copy(), "b", "target")]


def test_sessions_that_share_no_configuration_are_rejected():
    a = joint_tables_small()
    b = veil.data.protocol.protocol((120,), fine_step=5, coarse_step=20)
    b = b.assign(value=1.0, sigma=0.01)
    with pytest.raises(FitError, match="shares no configuration"):
        build([Session(a, "a"), Session(b, "b")], fixed={"Td[a]": 1e-3})


def test_contradictory_sharing_declarations_are_rejected():
    s = _sessions_from(joint_tables_small())
    with pytest.raises(FitError, match="contradictory.*g"):
        build(s, shared=("g", "eta_u"), per_medium=("g",), fixed={"Td[a]": 1e-3})
    with pytest.raises(FitError, match="always per medium"):
        build(s, shared=("Td",), fixed={"Td[a]": 1e-3})
    with pytest.raises(FitError, match="eta_u"):
        build(s, shared=("eta",), fixed={"Td[a]": 1e-3})
    with pytest.raises(FitError, match=r"free per medium here: fix g\[label\]"):
        build(s, fixed={"Td[a]": 1e-3, "g": 0.9})


def test_fixed_must_be_a_dict():
    """As in the step fits: a list of pairs or a string is a FitError, not silently used."""
    s = _sessions_from(joint_tables_small())
    for fixed in ([("Td[a]", 1e-3)], "Td[a]=1e-3"):
        with pytest.raises(FitError, match="expected a dict"):
            build(s, fixed=fixed)


def test_medium_session_without_target_session_is_rejected():
    t = joint_tables_small()
    with pytest.raises(FitError, match="no session of the target"):
        build([Session(t, "none", "reference"), Session(t, "a", "reference")])
    with pytest.raises(FitError, match="medium 'b' has a session of the reference "
                       r"\(object 'reference', medium 'b'\) but none of the target"):
        build([Session(t, "none", "reference"), Session(t, "a", "target"),
               Session(t, "b", "reference")])
    with pytest.raises(FitError, match="no sessions"):
        build([])


def test_unanchored_scale_and_other_mistakes_are_rejected():
    t = joint_tables_small()
    with pytest.raises(FitError, match="overall scale is not determined"):
        build(_sessions_from(t))
    # a clear-water session of the reference does not pin the target's scale...
    with pytest.raises(FitError, match="overall scale"):
        build(_sessions_from(t) + [Session(t, "none", "reference")])
    # ... but together with the reference in a medium it does
    build(_sessions_from(t) + [Session(t, "none", "reference"), Session(t, "a", "reference")])
    with pytest.raises(FitError, match="cannot fix 'Tq'"):
        build(_sessions_from(t), fixed={"Tq": 1.0})
    with pytest.raises(FitError, match="two sessions of the target in medium 'a'"):
        build([Session(t, "a"), Session(t, "a")], fixed={"Td[a]": 1e-3})
    nosigma = t.drop(columns="sigma")
    with pytest.raises(FitError, match="no sigma column"):
        build([Session(t, "a"), Session(nosigma, "b")], fixed={"Td[a]": 1e-3})
    with pytest.raises(FitError, match="label"):
        Session(t, "a b")
    with pytest.raises(FitError, match="reference sessions in a medium need"):
        build([Session(t, "a"), Session(t, "a", "reference")], fixed={"Td[a]": 1e-3})


def test_cli_joint_bad_input_exits_2(tmp_path):
    t = joint_tables_small()
    path = tmp_path / "a.csv"
    veil.save_measurements(t, path)
    runner = CliRunner()
    out = tmp_path / "j.json"
    cases = [
        (["fit", "joint", "--session", str(path), "-o", str(out)], "LABEL=PATH"),
        (["fit", "joint", "--session", f"a={path}", "--session", f"b={path}", "--shared", "g",
          "--per-medium", "g", "--fix", "Td[a]=1e-3", "-o", str(out)], "contradictory"),
        (["fit", "joint", "--session", f"a={tmp_path / 'missing.csv'}", "-o", str(out)],
         "does not exist"),
        (["fit", "joint", "--session", f"a={path}", "--session", f"b={path}", "-o", str(out)],
         "overall scale"),
        (["fit", "joint", "--session", f"a={path}", "--fix", "Td[a]=1e-3", "-o", str(path)],
         "never overwrites"),
        (["fit", "joint", "-o", str(out)], "no --session"),
        # there is no `veil fit direct`: f_r in clear water is `veil fit reference`'s
        (["fit", "joint", "--session", f"none={path}", "--reference-session", f"none={path}",
          "-o", str(out)], "directly with veil fit reference"),
    ]
    for args, message in cases:
        result = runner.invoke(main, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output, (args, result.output)
        assert "Traceback" not in result.output and "fit direct" not in result.output
    assert not out.exists()
    assert path.read_text().startswith("psi,rho")  # the input is untouched


def test_cli_joint_not_converged_says_so(tables, tmp_path):
    paths = {}
    for label, t in tables.items():
        paths[label] = tmp_path / f"{label}.csv"
        veil.save_measurements(t, paths[label])
    out = tmp_path / "j.json"
    args = ["fit", "joint", "--accuracy", "fast", "--max-nfev", "2", "--fix", "Td[low]=1e-3",
            "-o", str(out)]
    for label, p in paths.items():
        args += ["--session", f"{label}={p}"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    assert "did not converge" in result.output
    data = json.loads(out.read_text())
    assert data["converged"] is False and data["message"].startswith("did not converge")
    assert math.isfinite(data["params"]["n"])
    # no sigma points about a point that is not an optimum: the first order, said so
    how = data["stats"]["propagation"]
    assert how["method"] == "linear" and "optimum the fit has not reached" in how["fallback"], how


def test_cli_joint_medium_model_auto_ranks_the_media(tables, joint, tmp_path):
    """``veil fit joint --medium-model auto``: every medium's joint fit (one order weighting:
    fewer programs), screened and ranked; the paper's medium made the data and is chosen
    (the forward series, which cannot describe it, screened out by its quick fit), and its
    result is the pinned joint fit's, to the fit's tolerance (it continued from its quick
    fit, one start)."""
    paths = {}
    for label, t in tables.items():
        paths[label] = tmp_path / f"{label}.csv"
        veil.save_measurements(t, paths[label])
    out = tmp_path / "j.json"
    args = ["fit", "joint", "--accuracy", "fast", "--fix", "Td[low]=1e-3", "--medium-model",
            "auto", "--orders", "poisson"]
    for label, p in paths.items():
        args += ["--session", f"{label}={p}"]
    # a subprocess: a test plugin's family registered in this process would be a candidate
    env = dict(os.environ, PYTHONPATH=str(Path(veil.__file__).parents[1]), VEIL_PLUGINS="")
    result = subprocess.run([sys.executable, "-m", "veil.cli", *args, "-o", str(out)],
                            capture_output=True, text=True, env=env, timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "Candidates of step 'joint'" in result.stdout
    saved = json.loads(out.read_text())
    ranking = saved["stats"]["selection"]
    assert ranking["chosen"] == "torrance-sparrow + henyey-greenstein"
    rows = {row["label"]: row for row in ranking["candidates"]}
    assert set(rows) == {"torrance-sparrow + henyey-greenstein",
                         "torrance-sparrow + forward-series"}
    assert rows["torrance-sparrow + forward-series"]["screened"] is True
    # the chosen fit continued from its quick fit: the pinned joint fit's optimum to the
    # fit's tolerance (the runs stop within 1e-4 standard errors of it at the "fast" rule;
    # asserted to 1e-3), without a starting grid
    chosen = load_result(out)
    for name, value in joint.params.items():
        se = joint.stderr.get(name)
        assert abs(chosen.params[name] - value) <= (1e-3 * se if se else 1e-12), name
    assert chosen.chi2_reduced == pytest.approx(joint.chi2_reduced, rel=1e-4)
    assert saved["stats"]["starts"] == 1 and saved["stats"]["nfev"] < joint.stats["nfev"]
    # a fixed name no candidate declares is an input error, and nothing is written
    bad = CliRunner().invoke(main, args + ["--fix", "nosuch=1", "-o", str(tmp_path / "b")])
    # (in this process: the names are checked before any fit)
    assert bad.exit_code == 2 and "no candidate model has such a parameter" in bad.output
    assert not (tmp_path / "b").exists()
    # a medium parameter named by its slot in a joint fit (the paper's eta is eta_u) applies
    # to both media
    from veil.fitting.joint_selection import joint_candidates, per_candidate

    cands = [c for c in joint_candidates({"medium"}, None, None, {}, {"orders": "poisson"})
             if not c.medium.family.endswith("-test")]  # (a test plugin aside)
    shared = per_candidate(cands, ["eta_u"], "shared")
    assert all(v == ["eta_u"] for v in shared.values()) and len(shared) == 2
