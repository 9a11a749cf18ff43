"""The data choose the model (issue 29): candidates generated from the registry, the ranking's
arithmetic (BIC with the model-discrepancy term, weights) by hand, ``fit pipeline --models
auto`` on the paper's simulated data, and the bad-input rules."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import veil
from support.cli import run as run_cli
from veil.fitting import FitResult, selection
from veil.fitting.model_error import ModelError
from veil.fitting.session_data import FitData
from veil.models import APPARATUS_OPTIONS, registry

#: The veil under test, for a subprocess (a worktree's src/ or the installed package).
SRC = str(Path(veil.__file__).parents[1])


def invoke(args):
    return run_cli(*args, catch_exceptions=False)


# --------------------------------------------------------------------------------------
# candidates
# --------------------------------------------------------------------------------------
def test_candidates_come_from_the_declarations():
    brdfs = [c.label for c in selection.candidates("brdf")]
    # every family, every value of its discrete options, the paper's first
    assert brdfs[0] == "torrance-sparrow"
    for dist in ("beckmann", "ggx"):
        assert f"rough-conductor[distribution={dist}]" in brdfs
        # nonlinear = True is declared but the model refuses it: no candidate, and the one
        # value left does not tell candidates apart (not in the label)
        assert f"rough-plastic[distribution={dist}]" in brdfs
    assert not any("nonlinear" in label for label in brdfs)
    media = selection.candidates("medium")
    assert media[0].label == "henyey-greenstein"
    # apparatus options are never ranked: the Fresnel variant, path length, plate width
    for c in selection.candidates("brdf") + media:
        assert not set(c.options) & APPARATUS_OPTIONS
    # with a plate width every order weighting is a model of its own; without one the view
    # side's landing factors are 1, and two pairs of them are one model each, fitted once
    placed = selection.candidates("medium", {"path_length": 15.0, "plate_width": 5.0})
    orders = {c.options["orders"] for c in placed if c.family == "forward-series"}
    assert orders == set(registry.REGISTRY["forward-series"].OPTIONS[3].choices)
    assert not any(c.same for c in placed)
    folded = {c.options["orders"]: c.same for c in media if c.family == "forward-series"}
    assert folded == {"poisson": ({"orders": "view-side"},),
                      "light-side": ({"orders": "cylinder"},)}
    # an option given pins its value; apparatus ones go to every candidate declaring them
    ggx = selection.candidates("brdf", {"distribution": "ggx"})
    assert [c.label for c in ggx if not c.family.endswith("-test")] == \
        ["torrance-sparrow", "nonparametric", "rough-conductor", "rough-plastic"]  # (and a
    # test plugin: no option of its own, the non-parametric one none either)
    assert {c.model_options({"distribution": "ggx"}).get("distribution", "ggx")
            for c in ggx} == {"ggx"}
    fs = next(c for c in media if c.family == "forward-series")
    given = {"path_length": 15.0, "variant": "exit", "distribution": "ggx"}
    assert fs.model_options(given) == {"path_length": 15.0, "variant": "exit",
                                       "orders": "poisson"}
    assert media[0].model_options(given) == {"variant": "exit"}
    assert "MODEL_SETS" not in dir(veil.models)


@pytest.mark.parametrize("apparatus", [{}, {"path_length": 15.0}])
def test_options_folded_into_one_candidate_make_the_same_medium(apparatus):
    """Every medium method the engine calls gives the same numbers for the option values
    Model.same_model folds together (else auto would rank a model it never fitted)."""
    rng = np.random.default_rng(3)
    v = np.array([0.7, 0.95, 0.9, 1.33, 1.0])
    cos = rng.uniform(0.1, 1.0, 9)
    omm = rng.uniform(0.0, 0.3, 9)
    r = rng.normal(size=(9, 3))
    r[:, 2] = np.abs(r[:, 2]) + 0.5
    r = r / np.linalg.norm(r, axis=1, keepdims=True)
    rp = np.roll(r, 1, axis=0)
    folded = 0
    for name in registry.names("medium"):
        cls = registry.REGISTRY[name]
        seen: dict = {}
        for c in selection.candidates("medium", dict(apparatus), families=[name]):
            for opts in (c.options, *c.same):
                full = {**cls.default_options(), **c.model_options(apparatus), **opts}
                seen.setdefault(tuple(sorted(cls.same_model(full).items())), []).append(full)
        for group in seen.values():
            first, *others = [cls.template(**o) for o in group]
            folded += len(others)
            for other in others:
                for out_a, out_b in (
                    (first.lobe_weight(v), other.lobe_weight(v)),
                    (first.delta_weight(v), other.delta_weight(v)),
                    (first.phase(v, omm), other.phase(v, omm)),
                    (first.factor_first(v, cos), other.factor_first(v, cos)),
                    (first.view_weight(v, rp, r[0]), other.view_weight(v, rp, r[0])),
                ):
                    np.testing.assert_allclose(out_a, out_b, rtol=1e-13, atol=0)
                assert first.has_view_weight() == other.has_view_weight()
    assert folded == 2  # forward-series: view-side is poisson, cylinder is light-side


def test_a_registered_plugin_family_becomes_a_candidate():
    import veil_test_models  # noqa: F401 - registers lambertian-test and fisher-test
    assert "lambertian-test" in [c.label for c in selection.candidates("brdf")]
    assert "fisher-test" in [c.label for c in selection.candidates("medium")]


def test_models_names_are_checked():
    assert selection.parse_models("AUTO") == "auto"
    assert selection.parse_models("Rough-Plastic+forward-series") == \
        ("rough-plastic", "forward-series")
    with pytest.raises(veil.errors.InputError, match="known: torrance-sparrow"):
        selection.parse_models("nosuch+henyey-greenstein")
    with pytest.raises(veil.errors.InputError, match="expected auto, paper or FAMILY"):
        selection.parse_models("best")


# --------------------------------------------------------------------------------------
# the ranking's arithmetic
# --------------------------------------------------------------------------------------
def _result(residuals, n_free, term=None, converged=True):
    params = {f"p{i}": 1.0 for i in range(n_free)}
    r = np.asarray(residuals, dtype=float)
    return FitResult(model="torrance-sparrow", params=params, stderr={}, correlation={},
                     residuals=tuple(r), chi2_reduced=float(r @ r) / (r.size - n_free),
                     rms_relative=0.01, n_points=r.size, converged=converged, message="",
                     model_error=term)


def _data(n, rng):
    angles = tuple(rng.uniform(0, 80, n) for _ in range(4))
    y = rng.uniform(1.0, 3.0, n)
    return FitData(angles, y, 0.02 * y, None)


def test_bic_and_weights_against_hand_computation():
    rng = np.random.default_rng(3)
    n = 40
    data = _data(n, rng)
    r_a, r_b, r_c = rng.normal(size=n), 1.1 * rng.normal(size=n), rng.normal(size=n)
    fitted = {"a": (_result(r_a, 3), 1.0), "b": (_result(r_b, 2), 1.0),
              "c": (_result(r_c, 5), 1.0)}
    ranking = selection.rank("reference", fitted, data)
    bic = {"a": r_a @ r_a + 3 * math.log(n), "b": r_b @ r_b + 2 * math.log(n),
           "c": r_c @ r_c + 5 * math.log(n)}
    aic = {"a": r_a @ r_a + 6, "b": r_b @ r_b + 4, "c": r_c @ r_c + 10}
    best = min(bic.values())
    w = {k: math.exp(-0.5 * (v - best)) for k, v in bic.items()}
    total = sum(w.values())
    assert [row["label"] for row in ranking.rows] == sorted(bic, key=bic.get)
    for row in ranking.rows:
        lab = row["label"]
        assert row["bic"] == pytest.approx(bic[lab], rel=1e-12)
        assert row["aic"] == pytest.approx(aic[lab], rel=1e-12)
        assert row["delta_bic"] == pytest.approx(bic[lab] - best, abs=1e-9)
        assert row["weight"] == pytest.approx(w[lab] / total, rel=1e-12)
    assert ranking.chosen == min(bic, key=bic.get)


def test_the_written_ranking_is_the_same_whatever_the_fits_took():
    """Two runs differ in their candidates' wall times only: the record (ranking.json, the
    results, report.md's markdown) is the same; the terminal's table shows the seconds."""
    rng = np.random.default_rng(3)
    data = _data(30, rng)
    r_a, r_b = rng.normal(size=30), 1.2 * rng.normal(size=30)
    runs = [selection.rank("reference", {"a": (_result(r_a, 3), t), "b": (_result(r_b, 2), 2 * t)},
                           data) for t in (1.25, 7.5)]
    assert json.dumps(runs[0].to_dict()) == json.dumps(runs[1].to_dict())
    assert "seconds" not in json.dumps(runs[0].to_dict())
    assert selection.table_lines(runs[0], markdown=True) == selection.table_lines(
        runs[1], markdown=True)
    text = selection.table_lines(runs[1])
    assert text[0].split()[-1] == "s"
    rows = {line.split()[0].rstrip("*"): line.split()[-1] for line in text[1:3]}
    assert rows == {"a": "7.5", "b": "15.0"}


def test_the_discrepancy_term_enters_the_likelihood():
    """An independent term s: -2 ln L = sum ln(1 + s^2 a^2) + r^2 / (1 + s^2 a^2),
    a = f / sigma, and s counts as a parameter when fitted from the fit's own residuals."""
    rng = np.random.default_rng(4)
    n = 30
    data = _data(n, rng)
    r = 3.0 * rng.normal(size=n)
    term = ModelError(sigma=0.05, length=0.0, own=0.05, given=None, source="own residuals",
                      chi2_threshold=1.5)
    ranking = selection.rank("target", {"x": (_result(r, 2, term), 0.0)}, data)
    a = (data.y - r * data.sigma) / data.sigma
    v = 1.0 + 0.05 ** 2 * a * a
    dev = float(np.sum(np.log(v) + r * r / v))
    row = ranking.rows[0]
    assert row["deviance"] == pytest.approx(dev, rel=1e-12)
    assert row["k"] == 3 and row["bic"] == pytest.approx(dev + 3 * math.log(n), rel=1e-12)
    assert row["chi2"] == pytest.approx(float(r @ r))


def test_failed_and_unconverged_candidates_are_listed_not_ranked():
    rng = np.random.default_rng(5)
    data = _data(20, rng)
    r = rng.normal(size=20)

    def fit(c):
        if c.label == "boom":
            raise RuntimeError("no luck")
        return _result(r, 2, converged=c.label != "stuck")

    cands = [selection.Candidate("torrance-sparrow"), ]
    fitted = selection.fit_candidates(
        fit, [type("C", (), {"label": lab})() for lab in ("ok", "boom", "stuck")])
    ranking = selection.rank("reference", fitted, data, cands)
    assert ranking.chosen == "ok" and ranking.rows[0]["weight"] == 1.0
    rows = {row["label"]: row for row in ranking.rows}
    assert "RuntimeError: no luck" in rows["boom"]["error"] and rows["boom"]["bic"] is None
    assert rows["stuck"]["error"].startswith("did not converge") and rows["stuck"]["weight"] == 0
    text = "\n".join(selection.table_lines(ranking))
    assert "boom" in text and "failed" in text
    none = selection.rank("reference", {"boom": fitted["boom"]}, data)
    assert none.chosen is None
    assert "every candidate failed" in "\n".join(selection.table_lines(none))


def test_a_close_call_is_said_and_widens_by_the_spread():
    rng = np.random.default_rng(6)
    data = _data(25, rng)
    r = rng.normal(size=25)
    fitted = {"a": (_result(r, 2), 0.0), "b": (_result(1.001 * r, 2), 0.0),
              "c": (_result(3 * r, 2), 0.0)}
    ranking = selection.rank("target", fitted, data)
    assert ranking.close == ["a", "b"] and ranking.close_call
    curves = {"a": np.array([1.0, 2.0]), "b": np.array([1.2, 2.0]), "c": np.array([9.0, 9.0])}
    spread = selection.curve_spread(ranking, curves)
    wa, wb = ranking.row("a")["weight"], ranking.row("b")["weight"]
    wa, wb = wa / (wa + wb), wb / (wa + wb)
    mean = wa * 1.0 + wb * 1.2
    sd = math.sqrt(wa * (1.0 - mean) ** 2 + wb * (1.2 - mean) ** 2)
    assert spread["spread"] == pytest.approx([sd, 0.0], abs=1e-12)
    assert spread["max_relative"] == pytest.approx(sd / 1.0)
    text = "\n".join(selection.close_call_lines(ranking.with_spread(spread)))
    assert "close call: b within delta-BIC 2 of a" in text and "widened" in text


# --------------------------------------------------------------------------------------
# the command line
# --------------------------------------------------------------------------------------
SIM = dict(psi=(30, 60, 90), fine_step=5, coarse_step=15, accuracy="fast")


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """The paper's simulated acquisition (veil demo's set-up, a coarser grid)."""
    d = tmp_path_factory.mktemp("sessions")
    paths = {}
    tables = {"reference-clear": veil.simulate(veil.BRDF2, None, noise=0.01, seed=0, **SIM)}
    tables["reference-medium"], tables["black"] = veil.simulate(
        veil.BRDF2, veil.BTDF2, noise=0.01, seed=1, black=True, **SIM)
    tables["target-medium"] = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=2, **SIM)
    for role, table in tables.items():
        paths[role] = d / f"{role}.csv"
        table.to_csv(paths[role], index=False)
    return paths


def _args(sessions, out):
    args = ["fit", "pipeline"]
    for role, path in sessions.items():
        args += [f"--{role}", path]
    return args + ["--accuracy", "fast", "--no-figures", "-o", out]


def test_unknown_family_in_models_exits_2_listing_the_registered(sessions, tmp_path):
    out = invoke(_args(sessions, tmp_path / "o") + ["--models", "nosuch+henyey-greenstein"])
    assert out.exit_code == 2
    assert "unknown BRDF model 'nosuch'" in out.output and "rough-plastic" in out.output
    out = invoke(_args(sessions, tmp_path / "o") + ["--models", "torrance-sparrow+nosuch"])
    assert out.exit_code == 2 and "forward-series" in out.output
    out = invoke(_args(sessions, tmp_path / "o") + ["--models", "auto", "--brdf-model",
                                                      "rough-plastic"])
    assert out.exit_code == 2 and "give one of the two" in out.output
    out = invoke(_args(sessions, tmp_path / "o") + ["--models", "auto", "--fix",
                                                      "medium.nosuch=1"])
    assert out.exit_code == 2 and "no candidate model has such a parameter" in out.output
    assert not (tmp_path / "o").exists()


def test_an_empty_models_value_exits_2_not_auto(sessions, tmp_path):
    """--models "" is a mistake (an unset variable in a script), not --models auto."""
    out = invoke(_args(sessions, tmp_path / "o") + ["--models", ""])
    assert out.exit_code == 2
    assert "expected auto, paper or FAMILY+MEDIUM" in out.output
    assert not (tmp_path / "o").exists()


def test_an_option_value_no_family_makes_is_named_as_such():
    """rough-plastic declares nonlinear but makes no model with True: not "no candidate
    declares" it, which would send the user looking for a typo."""
    from veil.errors import FitError
    from veil.fitting.auto import plan_candidates

    with pytest.raises(FitError, match=r"nonlinear = True \(rough-plastic\).*no model"):
        plan_candidates({}, {}, {"nonlinear": True}, {}, None)
    with pytest.raises(FitError, match="no BRDF candidate declares them"):
        plan_candidates({}, {}, {"nosuch": 1}, {}, None)
    # both kinds at once: each named (the typo is not left for the next run)
    with pytest.raises(FitError, match=r"nosuch: no BRDF candidate.*nonlinear = True"):
        plan_candidates({}, {}, {"nonlinear": True, "nosuch": 1}, {}, None)


def _subprocess(args):
    """``veil`` in a subprocess, the registry without the test plugins (a family registered
    in this process would be a candidate too)."""
    env = dict(os.environ, PYTHONPATH=SRC, VEIL_PLUGINS="")
    cmd = [sys.executable, "-m", "veil.cli"] + [str(a) for a in args]
    return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)


def test_every_candidate_failing_exits_1_with_the_table(sessions, tmp_path):
    """One evaluation per iterative fit, and the non-parametric family (a linear solve, which
    --max-nfev does not bound) held at a coefficient outside its bounds: no candidate of
    step 0 succeeds; each says why in the table, and nothing is written."""
    # one value of the distribution: fewer programs to compile
    run = _subprocess(_args(sessions, tmp_path / "o") + ["--models", "auto", "--max-nfev", "1",
                                                         "--distribution", "beckmann",
                                                         "--fix", "reference.d0=-1"])
    assert run.returncode == 1, run.stderr[-3000:]
    assert "Candidates of step 'reference'" in run.stdout
    assert "every candidate failed" in run.stdout and "torrance-sparrow" in run.stdout
    assert "did not converge" in run.stdout
    assert "nonparametric: FitError: fixed NonParametric.d0 = -1 is outside" in run.stdout
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_auto_picks_the_papers_models_on_the_papers_data(sessions, tmp_path):
    """A subprocess (no test plugin registered): every candidate of every step fitted, the
    paper's Torrance-Sparrow and Henyey-Greenstein chosen (they made the data), the
    rankings in the terminal, report.md and the results; every candidate's result (--compare)
    loads and evaluates."""
    out_dir = tmp_path / "auto"
    # the discrete options pinned to one value each: every family, fewer engine programs;
    # no propagation (it moves no ranking; tests/test_propagation.py checks that, and that
    # auto propagates into the chosen candidate): no derivatives in the given models
    pins = ["--distribution", "beckmann", "--orders", "poisson", "--propagation", "off"]
    run = _subprocess(_args(sessions, out_dir) + ["--compare", "--max-nfev", "40"] + pins)
    assert run.returncode in (0, 1), run.stderr[-3000:]
    ranking = json.loads((out_dir / "ranking.json").read_text())
    assert ranking["reference"]["chosen"] == "torrance-sparrow"
    assert ranking["medium"]["chosen"] == "henyey-greenstein"
    assert ranking["target"]["chosen"] == "torrance-sparrow"
    pinned = {"distribution": "beckmann", "orders": "poisson"}
    count = {kind: len([c for c in selection.candidates(kind, pinned)
                        if not c.family.endswith("-test")]) for kind in ("brdf", "medium")}
    assert count == {"brdf": 4, "medium": 2}  # the non-parametric family among the BRDFs
    for step in ("reference", "medium", "target"):
        rows = ranking[step]["candidates"]
        assert len(rows) == count["brdf" if step != "medium" else "medium"]
        assert sum(r["weight"] for r in rows) == pytest.approx(1.0)
        assert f"Candidates of step '{step}'" in run.stdout
    result = json.loads((out_dir / "target.json").read_text())
    assert result["stats"]["selection"]["chosen"] == "torrance-sparrow"
    assert "The data choose the model" in (out_dir / "report.md").read_text()
    files = sorted((out_dir / "candidates").rglob("*.json"))
    assert len(files) == 2 * count["brdf"] + count["medium"]
    for path in files:
        model = FitResult.from_json(path).as_model()
        assert model.NAME == json.loads(path.read_text())["model"]
        if model.KIND == "brdf":  # (a medium's evaluation compiles a program per family)
            assert np.all(np.isfinite(veil.reflectance(model, [20.0, 40.0], [20.0, 40.0])))


def test_a_close_call_widens_the_estimates_curve_uncertainty():
    """veil.pipeline.compare: the spread of a close call at step 2 (stats.selection.spread,
    one value per protocol configuration) is added to the estimate's curve uncertainty."""
    import dataclasses

    from veil.data.protocol import protocol
    from veil.pipeline import compare

    params = dict(zip(("Pd", "Ps", "n", "eta"), veil.BRDF1.to_vector()))
    se = {k: 1e-3 * abs(v) for k, v in params.items()}
    direct = FitResult(model="torrance-sparrow", params=params, stderr=se, correlation={},
                       residuals=(0.0,) * 10, chi2_reduced=1.0, rms_relative=0.0,
                       n_points=10, converged=True, message="")
    shifted = dataclasses.replace(direct, params=dict(params, Pd=1.05 * params["Pd"]))
    n = len(protocol())
    plain = compare(shifted, direct)
    spread = {"spread": [0.5 * params["Pd"]] * n, "rms_relative": 0.2, "max_relative": 0.3}
    wide = compare(dataclasses.replace(shifted, stats={"selection": {"spread": spread}}),
                   direct)
    assert plain["model_spread_rms_relative"] is None
    assert wide["model_spread_rms_relative"] == 0.2
    assert wide["fr_max_z"] < plain["fr_max_z"]
    assert wide["rms_fr_relative"] == plain["rms_fr_relative"]


# --------------------------------------------------------------------------------------
# the single fits: --brdf-model auto / --medium-model auto
# --------------------------------------------------------------------------------------
def test_fit_reference_auto_ranks_every_family(sessions, tmp_path):
    """`veil fit reference --brdf-model auto`: every BRDF candidate fitted to the clear
    reference, the paper's Torrance-Sparrow chosen (it made the data), the ranking in the
    terminal and in the result; a --fix applies to the families that declare it."""
    out = tmp_path / "ref.json"
    run = _subprocess(["fit", "reference", sessions["reference-clear"], "--brdf-model", "auto",
                       "--fix", "ks=1", "-o", out])
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Candidates of step 'reference'" in run.stdout
    result = json.loads(out.read_text())
    chosen = result["stats"]["selection"]
    assert result["model"] == chosen["chosen"] == "torrance-sparrow"
    labels = [row["label"] for row in chosen["candidates"]]
    families = {row["family"] for row in chosen["candidates"]}
    assert families == {"torrance-sparrow", "rough-plastic", "rough-conductor", "nonparametric"}
    assert len(labels) == len(selection.candidates("brdf")) - len(
        [c for c in selection.candidates("brdf") if c.family.endswith("-test")])
    weights = [row["weight"] for row in chosen["candidates"]]
    assert sum(weights) == pytest.approx(1.0) and weights[0] == max(weights)
    # screened as the pipeline's step 0: a candidate far behind keeps its quick fit
    # (one whose quick fit stopped short, or could not be measured, gets the full fit)
    screened = [row for row in chosen["candidates"] if row.get("screened")]
    assert screened and all(row["delta_bic"] > 10 and "(one start)" in row["note"]
                            for row in screened)
    assert "screened out: its quick fit (one start)" in run.stdout
    assert FitResult.from_json(out).as_model().NAME == "torrance-sparrow"
    # the explorer's fit view lists the candidates beside the fit's parameters, best first
    from veil.viz.explore_fits import FitView
    from veil.viz.explore_plots import FitPlots

    view = FitView(FitResult.from_json(out), str(sessions["reference-clear"]), draws=0)
    table = FitPlots(view, 0).table()
    assert f"Chosen from {len(labels)} candidates" in table
    listed = [line.split("|")[1].strip() for line in table.splitlines()
              if line.startswith("| ") and "|---" not in line][len(result["params"]) + 2:]
    assert [name.rstrip("*").removesuffix(" (screened out)") for name in listed] == labels
    assert listed[0] == "torrance-sparrow*"


def test_fit_view_ranking_says_failures_and_a_close_call():
    """The explorer's candidate table: failed, unconverged and screened-out candidates named
    so, a close call said; a fit without a ranking gets no table."""
    from veil.viz.explore_fits import ranking_lines

    rows = [dict(label="a", rms_relative=0.01, delta_bic=0.0, weight=0.6, converged=True, chi2=1.0),
            dict(label="b", rms_relative=0.012, delta_bic=1.2, weight=0.4, converged=True, chi2=1.1),
            dict(label="c", rms_relative=0.3, delta_bic=None, weight=0.0, converged=False, chi2=9.0),
            dict(label="d", rms_relative=None, delta_bic=None, weight=0.0, converged=False,
                 chi2=None),
            dict(label="e", rms_relative=0.29, delta_bic=5040.0, weight=0.0, converged=True,
                 chi2=1e5, screened=True)]
    ranking = dict(candidates=rows, chosen="a", close_call=True, close=["a", "b"],
                   close_delta_bic=2.0)
    result = FitResult(model="torrance-sparrow", params={}, stderr={}, correlation={},
                       residuals=(), chi2_reduced=1.0, rms_relative=0.01, n_points=3,
                       converged=True, message="", stats={"selection": ranking})
    lines = ranking_lines(result)
    assert "| a* | 1 | 0.0 | 0.600 |" in lines
    assert "| c (not converged) | 30 | - | 0.000 |" in lines
    assert "| d (failed) | - | - | 0.000 |" in lines
    assert "| e (screened out) | 29 | 5040.0 | 0.000 |" in lines
    assert "Close call: a, b within dBIC 2." in lines
    assert ranking_lines(dataclasses.replace(result, stats={})) == []


def test_single_fit_auto_bad_input(sessions, tmp_path):
    """A --fix no candidate declares: exit 2 before any fit; `auto` is not a family of the
    commands that do not rank (fit pipeline has --models auto), exit 2."""
    out = tmp_path / "ref.json"
    run = invoke(["fit", "reference", sessions["reference-clear"], "--brdf-model", "auto",
                  "--fix", "nosuch=1", "-o", str(out)])
    assert run.exit_code == 2 and "no candidate family has such a parameter" in run.output
    assert not out.exists()
    run = invoke(_args(sessions, tmp_path / "o") + ["--brdf-model", "auto"])
    assert run.exit_code == 2 and "'auto' is not a registered brdf model" in run.output
