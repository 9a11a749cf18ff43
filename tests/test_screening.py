"""Screening the candidates of a step through the medium (veil.fitting.screening): the BIC
interval a quick fit leaves for the fast quadrature's error, who goes on to the full fit,
and, end to end, that a screened ranking chooses exactly what the pinned pair fits."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import veil
from veil.fitting import FitResult, screening, selection
from veil.fitting.session_data import FitData

N = 40
ANGLES = tuple(np.full(N, v) for v in (10.0, 0.0, 10.0, 180.0))


def _data(y, sigma) -> FitData:
    return FitData(ANGLES, np.asarray(y, float), None if sigma is None else np.asarray(sigma),
                   table=None)  # type: ignore[arg-type]


def _fit(residuals, converged=True) -> FitResult:
    """A fit of two free parameters (Pd, n) with these weighted residuals."""
    return FitResult(model="torrance-sparrow", params={"Pd": 1.0, "n": 1.0, "Ps": 1.0,
                                                       "eta": 1.5},
                     stderr={"Pd": 0.1, "n": 0.1}, correlation={},
                     residuals=tuple(float(r) for r in residuals), chi2_reduced=1.0,
                     rms_relative=0.01, n_points=len(residuals), converged=converged,
                     message="" if converged else "did not converge: test", weighted=True,
                     fixed={"Ps": 1.0, "eta": 1.5})


def test_bic_interval_moves_every_value_by_the_fast_rules_error():
    """Without a model-error term the deviance is the chi-square: the interval's ends are
    sum(max(|r| - a, 0)^2) and sum((|r| + a)^2), a = FAST_ERROR f / sigma, widened by the
    BIC of the term's two parameters."""
    rng = np.random.default_rng(0)
    y = rng.uniform(50, 150, N)
    sigma = np.full(N, 1.0)
    r = rng.normal(0, 2.0, N)
    fit = _fit(r)
    data = _data(y, sigma)
    f = y - r * sigma  # all well above 1e-3 of the largest
    a = screening.FAST_ERROR * np.abs(f) / sigma
    chi2 = float(r @ r)
    bic = chi2 + 2 * math.log(N)
    lower, upper = screening.bic_interval(fit, data, bic)
    term = 2 * math.log(N)  # the discrepancy term's two parameters, switched on or off
    assert lower == pytest.approx(bic - chi2 + np.sum(np.maximum(np.abs(r) - a, 0) ** 2) - term)
    assert upper == pytest.approx(bic - chi2 + np.sum((np.abs(r) + a) ** 2) + term)
    assert lower < bic < upper


@pytest.mark.parametrize("seed", range(6))
def test_the_measured_interval_brackets_the_refit_at_the_finer_rule(seed):
    """A linear model y ~ J x, the finer rule's values J x + e: from the fast optimum's
    residuals r (orthogonal to J) and the rule error e, the interval holds the finer rule's
    optimum min |y - J x - e|^2 exactly where the refit is a projection, its upper end is
    the finer rule's deviance at the fast optimum, and it is no wider than |e|^2."""
    rng = np.random.default_rng(seed)
    n, p = 60, 3
    jac = rng.normal(size=(n, p))
    y = jac @ rng.normal(size=p) + rng.normal(size=n)
    e = rng.normal(scale=0.3, size=n) + 0.2 * jac @ rng.normal(size=p)  # partly in the span
    x_fast = np.linalg.lstsq(jac, y, rcond=None)[0]
    r = y - jac @ x_fast
    x_fine = np.linalg.lstsq(jac, y - e, rcond=None)[0]
    fine = float(np.sum((y - e - jac @ x_fine) ** 2))

    def moved(res):
        return float(res @ res)

    lower, upper = screening.measured_interval(r, e, moved, weighted=True)
    assert upper == pytest.approx(moved(r - e))
    assert lower - 1e-9 <= fine <= upper + 1e-9
    assert fine < upper - 1e-3  # the part of e in J's span is refitted away
    assert lower == pytest.approx(min(moved(r), upper) - float(e @ e))
    assert screening.measured_interval(r, e, moved, True, slack=2.0)[0] == \
        pytest.approx(lower - 2.0)
    # unweighted: the deviance N ln(RSS / N), its ends from the same sums of squares
    lo, up = screening.measured_interval(r, e, moved, weighted=False)
    assert lo <= n * math.log(fine / n) <= up


def test_with_a_discrepancy_term_the_lower_end_allows_for_its_log_determinant():
    """A term's covariance grows with the model values, so a finer rule's larger values
    move the log-determinant too: the lower end allows for that change, and for the descent
    an iterative quick fit's tolerance leaves (TOL_SCREEN standard errors per parameter,
    scaled by the misfit), beyond the rule error's |delta|^2."""
    from veil.fitting.model_error import ModelError
    from veil.fitting.solver import TOL_SCREEN

    rng = np.random.default_rng(4)
    y = rng.uniform(50, 150, N)
    sigma = np.full(N, 1.0)
    data = _data(y, sigma)
    r = rng.normal(0, 1.0, N)
    term = ModelError(sigma=0.05, length=0.0, own=0.05, given=None, source="own residuals",
                      chi2_threshold=2.0)
    e = 0.01 * (y - r)  # the finer rule 1 % higher everywhere
    fit = dataclasses.replace(_fit(r), model_error=term,
                              stats={"rule_error": {"accuracy": "default",
                                                    "values": e.tolist()}})
    dev, _ = selection.deviance(fit, data)
    upper = screening.bic_interval(fit, data, dev)[1]
    n_term = 2 * math.log(N)
    at_rule = selection.deviance(dataclasses.replace(fit, residuals=tuple(r - e)), data)[0]
    assert upper - n_term == pytest.approx(at_rule)
    zero = dataclasses.replace(fit, residuals=(0.0,) * N)
    f = y - r
    logdet = (selection.deviance(zero, dataclasses.replace(data, y=f + e))[0]
              - selection.deviance(zero, dataclasses.replace(data, y=f))[0])
    assert logdet > 0.5  # larger values, a larger covariance
    slack = TOL_SCREEN**2 * len(fit.stderr) * max(fit.chi2_reduced, 1.0)
    # a linear family's quick fit (no iterations in its stats) is its exact solution: no slack
    linear_lower = screening.bic_interval(fit, data, dev)[0]
    assert linear_lower + n_term == pytest.approx(min(dev, at_rule) - float(e @ e) - logdet)
    iterated = dataclasses.replace(fit, stats=dict(fit.stats, nfev=12))
    lower, upper = screening.bic_interval(iterated, data, dev)
    width = float(e @ e) + slack + logdet
    assert lower + n_term == pytest.approx(min(dev, at_rule) - width)


def test_a_quick_fit_through_a_medium_measures_its_rule_error(sessions):
    """A quick fit asked for the "default" rule iterates at "fast" and evaluates its optimum
    once at "default": stats["rule_error"] is that difference of the model values (checked
    against veil.apparent at both rules), and the measured BIC interval holds the full
    fit's chi-square, narrower than FAST_ERROR's."""
    from veil.fitting.session_data import prepare

    table, black = sessions["reference_medium"], sessions["black"]
    kw = dict(black=black, accuracy="default", propagation="off", model_error="off")
    quick = veil.fit_medium(table, veil.BRDF2, screen=True, **kw)
    assert quick.accuracy == "fast" and quick.converged
    measured = quick.stats["rule_error"]
    assert measured["accuracy"] == "default"
    data = prepare(table, black)
    medium = veil.BTDF2.replace(**quick.params)
    angles = [data.table[c].to_numpy() for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    rule = {acc: veil.apparent(veil.BRDF2, medium, *angles, accuracy=acc)
            for acc in ("fast", "default")}
    assert np.allclose(measured["values"], rule["default"] - rule["fast"], rtol=1e-9,
                       atol=1e-12 * np.abs(rule["fast"]).max())
    assert np.abs(measured["values"]).max() > 0  # the rules differ somewhere
    full = veil.fit_medium(table, veil.BRDF2, start=quick, **kw)
    chi2 = float(np.sum(np.square(full.residuals)))
    bic_quick = float(np.sum(np.square(quick.residuals)))  # the interval is relative to it
    lower, upper = screening.bic_interval(quick, data, bic_quick)
    term = 2 * math.log(len(quick.residuals))
    assert lower + term <= chi2 <= upper - term
    # the BIC it would start its full fit from: the "default" values at the quick optimum
    delta = np.asarray(measured["values"]) / data.sigma
    at_rule = float(np.sum(np.square(np.asarray(quick.residuals) - delta)))
    assert screening.rule_bic(quick, data, bic_quick) == pytest.approx(at_rule, rel=1e-12)
    assert upper - term == pytest.approx(at_rule, rel=1e-12)
    stale = dataclasses.replace(quick, stats={})  # without the measurement: FAST_ERROR
    wide = screening.bic_interval(stale, data, bic_quick)
    assert wide[0] < lower and upper < wide[1]
    assert screening.rule_bic(stale, data, bic_quick) is None


def test_a_quick_fit_reads_the_finer_rules_program_only_if_it_converges(sessions,
                                                                       monkeypatch):
    """The finer rule's values (a program of their own) serve only a converged quick fit's
    rule error: a quick fit that stops without converging neither prepares nor evaluates
    them (on the paper's data the forward series' two weightings read two programs of
    several MB for nothing); a converged one evaluates them once, at its optimum."""
    from veil.engine import evaluator
    from veil.fitting.problem import RULES

    seen = []
    init, prepare, values = (evaluator.ApparentModel.__init__, evaluator.ApparentModel.prepare,
                             evaluator.ApparentModel.values)

    def spy_init(self, brdf, medium, angles, rule):
        self.spied_rule = rule
        init(self, brdf, medium, angles, rule)

    def spy_prepare(self, values=True, jacobians=(), channels=1):
        seen.append(("prepare", self.spied_rule, values))
        return prepare(self, values, jacobians, channels)

    def spy_values(self, vb, vm):
        seen.append(("values", self.spied_rule, True))
        return values(self, vb, vm)

    monkeypatch.setattr(evaluator.ApparentModel, "__init__", spy_init)
    monkeypatch.setattr(evaluator.ApparentModel, "prepare", spy_prepare)
    monkeypatch.setattr(evaluator.ApparentModel, "values", spy_values)
    kw = dict(black=sessions["black"], accuracy="default", propagation="off", model_error="off")
    table = sessions["reference_medium"]
    stopped = veil.fit_medium(table, veil.BRDF2, screen=True, max_nfev=1, **kw)
    assert not stopped.converged and "rule_error" not in stopped.stats
    assert all(rule == RULES["fast"] for _, rule, _ in seen)
    assert any(what == "values" for what, _, _ in seen)  # the spies saw the fast rule's
    seen.clear()
    quick = veil.fit_medium(table, veil.BRDF2, screen=True, **kw)
    assert quick.converged and quick.stats["rule_error"]["accuracy"] == "default"
    assert [s for s in seen if s[1] == RULES["default"]] == [("values", RULES["default"], True)]
    seen.clear()
    full = veil.fit_medium(table, veil.BRDF2, start=quick, **kw)  # a full fit reads ahead
    assert full.converged and ("prepare", RULES["default"], True) in seen


def test_two_runs_that_agree_end_the_search_even_at_a_bound():
    """solver.agreeing: two converged runs within AGREEMENT of each other's deviance, with a
    plausible chi-square, are one minimum (convincing alone asks for another start when a
    run ends at a bound); runs apart, unconverged or misfitting are not."""
    from types import SimpleNamespace as NS

    from veil.fitting import solver

    problem = NS(n_points=104, n_free=4, weighted=True)
    run = lambda cost, status=1: NS(cost=cost, status=status)  # noqa: E731
    assert solver.agreeing(problem, [run(50.0), run(50.0 + solver.AGREEMENT / 2 - 1e-9)])
    assert not solver.agreeing(problem, [run(50.0), run(50.0 + solver.AGREEMENT)])
    assert not solver.agreeing(problem, [run(50.0), run(50.1, status=0)])
    assert not solver.agreeing(problem, [run(50.0)])
    assert not solver.agreeing(problem, [run(150.0), run(150.01)])  # chi-square 3
    assert not solver.agreeing(NS(n_points=104, n_free=4, weighted=False),
                               [run(50.0), run(50.0)])


def test_starts_stop_once_two_runs_agree_at_a_bound(monkeypatch):
    """The starts' loop (solver._starts_run): runs that end at a bound do not convince, so
    the next start runs, until two of them agree; runs at a bound that disagree use every
    start."""
    from types import SimpleNamespace as NS

    from veil.fitting import solver

    problem = NS(n_points=104, n_free=4, weighted=True)
    costs = {}

    def fake_solve(problem, start, **kw):
        return NS(cost=costs[start], status=1, at_bound=True)

    monkeypatch.setattr(solver, "solve", fake_solve)
    costs.update({"a": 50.0, "b": 50.1, "c": 40.0})
    runs, skipped = solver._starts_run(problem, ["a", "b", "c"], None, False, 1e-2, None, None)
    assert [r.cost for r in runs] == [50.0, 50.1] and skipped == 1
    costs.update({"b": 55.0})
    runs, skipped = solver._starts_run(problem, ["a", "b", "c"], None, False, 1e-2, None, None)
    assert [r.cost for r in runs] == [50.0, 55.0, 40.0] and skipped == 0


def _ranked(fits: dict, data) -> tuple[selection.Ranking, dict]:
    """The quick fits' ranking and results (a value that is an exception: a fit that
    raised)."""
    cands = [selection.Candidate(f"family-{k}") for k in fits]
    fitted = {c.label: (fit, 0.1) for c, fit in zip(cands, fits.values())}
    ranking = selection.rank("medium", fitted, data, cands)
    return ranking, {lab: q[0] for lab, q in fitted.items()}


def test_only_a_candidate_that_cannot_be_chosen_is_screened_out(monkeypatch):
    """A fit 30 sigma off every point is out, and so is one that stopped 40 sigma off; one
    whose chi-square is 15 above the best is within the fast rule's reach (its interval
    overlaps the best's) and goes on; a quick fit that raised is neither (it is reported as
    failed)."""
    y, sigma = np.full(N, 100.0), np.full(N, 1.0)
    data = _data(y, sigma)
    base = np.resize([1.0, -1.0], N)
    fits = {
        "good": _fit(base),
        "near": _fit(base * math.sqrt(1 + 15 / N)),
        "far": _fit(base * 30.0),
        "stopped-far": _fit(base * 40.0, converged=False),
        "raised": RuntimeError("no start"),
    }
    ranking, results = _ranked(fits, data)
    assert ranking.row("family-raised")["error"].startswith("RuntimeError")
    keep, out = screening.survivors(ranking, results, data)
    assert keep == ["family-good", "family-near"]
    assert set(out) == {"family-far", "family-stopped-far"}
    best_upper = screening.bic_interval(fits["good"], data, ranking.row("family-good")["bic"])[1]
    assert all(lo > best_upper + screening.SCREEN_MARGIN for lo, _ in out.values())
    # with the margin widened past the far one's interval, it would go on too
    monkeypatch.setattr(screening, "SCREEN_MARGIN", out["family-far"][0] - best_upper + 1.0)
    assert "family-far" in screening.survivors(ranking, results, data)[0]


def test_a_screened_candidate_is_fitted_when_the_best_full_fit_fails():
    """The quick fits only estimate the best: when the best one's full fit raises, the
    candidates screened out against it are measured again against the full fits that rank
    (none here) and fitted in full; the one left is chosen."""
    y, sigma = np.full(N, 100.0), np.full(N, 1.0)
    data = _data(y, sigma)
    base = np.resize([1.0, -1.0], N)
    quick = {"good": _fit(base), "far": _fit(base * 30.0)}
    cands = [selection.Candidate(k) for k in quick]
    calls = []

    def full(c, start=None):
        assert start is quick[c.label]  # each full fit continues from its own quick fit
        calls.append(c.label)
        if c.label == "good":
            raise RuntimeError("the polish failed")
        return _fit(base * 29.0)

    fitted, screened = screening.screen_fits("medium", cands, data, full,
                                             lambda c, start=None: quick[c.label])
    assert calls == ["good", "far"] and screened == []
    ranking = selection.rank("medium", fitted, data, cands, screened)
    assert ranking.chosen == "far"
    assert ranking.row("good")["error"] == "RuntimeError: the polish failed"
    # with the best full fit as the quick fit said, "far" stays out, its dBIC above the margin
    calls.clear()
    fitted, screened = screening.screen_fits("medium", cands, data,
                                             lambda c, start=None: _fit(base),
                                             lambda c, start=None: quick[c.label])
    ranking = selection.rank("medium", fitted, data, cands, screened)
    assert [r["label"] for r in screened] == ["far"]
    assert ranking.chosen == "good"
    assert ranking.row("far")["delta_bic"] > screening.SCREEN_MARGIN


def test_a_familys_other_options_start_from_its_first_candidates_quick_fit():
    """The first candidate of each family starts from its grid (start None), the family's
    other candidates from that one's quick fit, converged or not; after a first candidate
    that raised, from their own grid. The results come back in the candidates' order."""
    cands = [selection.Candidate("fs", {"orders": "poisson"}),
             selection.Candidate("hg"),
             selection.Candidate("fs", {"orders": "cylinder"}),
             selection.Candidate("rp", {"distribution": "beckmann"}),
             selection.Candidate("rp", {"distribution": "ggx"}),
             selection.Candidate("rc", {"distribution": "beckmann"}),
             selection.Candidate("rc", {"distribution": "ggx"})]
    made = {c.label: _fit(np.full(N, float(k + 1)), converged=not c.label.startswith("rc"))
            for k, c in enumerate(cands)}
    starts = {}

    def quick(c, start=None):
        starts[c.label] = start
        if c.label == "rp[distribution=beckmann]":
            raise RuntimeError("no finite start")
        return made[c.label]

    out = screening.quick_fits("medium", cands, quick)
    assert list(out) == [c.label for c in cands]
    assert starts["fs[orders=poisson]"] is None and starts["hg"] is None
    assert starts["rp[distribution=beckmann]"] is None
    assert starts["fs[orders=cylinder]"] is made["fs[orders=poisson]"]
    assert starts["rp[distribution=ggx]"] is None  # its first candidate raised
    # where its first candidate stopped, though that did not converge
    assert starts["rc[distribution=ggx]"] is made["rc[distribution=beckmann]"]
    assert isinstance(out["rp[distribution=beckmann]"][0], RuntimeError)
    assert out["fs[orders=cylinder]"][0] is made["fs[orders=cylinder]"]


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """The paper's simulated sessions (test_model_selection.py's, the same coarse grid)."""
    from test_model_selection import SIM

    d = tmp_path_factory.mktemp("screen")
    tables = {"reference_clear": veil.simulate(veil.BRDF2, None, noise=0.01, seed=0, **SIM)}
    tables["reference_medium"], tables["black"] = veil.simulate(
        veil.BRDF2, veil.BTDF2, noise=0.01, seed=1, black=True, **SIM)
    tables["target_medium"] = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=2, **SIM)
    paths = {}
    for role, table in tables.items():
        paths[role] = d / f"{role}.csv"
        table.to_csv(paths[role], index=False)
    return paths


def test_screened_auto_chooses_exactly_what_the_pinned_pair_fits(sessions, tmp_path,
                                                                monkeypatch):
    """Steps 1 and 2 through the medium, screened: the forward series (which cannot describe
    the paper's medium) is screened out, and the chosen fits are the pinned pair's to the
    fit's tolerance (a survivor's full fit continues from its quick fit, the pinned one
    starts from the grid: at the "fast" rule both stop within 1e-4 standard errors of the
    optimum)."""
    from veil.models import registry

    for name in [n for n in registry.REGISTRY if n.endswith("-test")]:
        # a test plugin another test registered in this process is no candidate here
        monkeypatch.delitem(registry.REGISTRY, name)
    kw = dict(black=sessions["black"], accuracy="fast", figures=False, propagation="off",
              max_nfev=40)
    files = [sessions[k] for k in ("reference_clear", "reference_medium", "target_medium")]
    # one value of each ranked option: every family, fewer programs
    auto = veil.run_pipeline(*files, outdir=tmp_path / "auto", models="auto",
                             brdf_options={"distribution": "beckmann"},
                             medium_options={"orders": "poisson"}, **kw)
    pinned = veil.run_pipeline(*files, outdir=tmp_path / "pinned", models="paper", **kw)
    medium = {r["label"]: r for r in auto.rankings["medium"].rows}
    assert auto.rankings["medium"].chosen == "henyey-greenstein"
    assert medium["forward-series"].get("screened") is True
    assert medium["forward-series"]["weight"] == 0.0
    assert medium["forward-series"]["delta_bic"] > screening.SCREEN_MARGIN
    lines = "\n".join(selection.table_lines(auto.rankings["medium"]))
    assert "screened out: its quick fit" in lines
    assert auto.rankings["target"].chosen == "torrance-sparrow"
    # step 0 in clear water is screened too: every family but the paper's stops at its
    # quick fit, which has no quadrature to allow for
    reference = {r["label"]: r for r in auto.rankings["reference"].rows}
    assert auto.rankings["reference"].chosen == "torrance-sparrow"
    out = [lab for lab, r in reference.items() if r.get("screened")]
    assert out == ["rough-plastic"] and reference["rough-plastic"]["delta_bic"] > 100
    note = reference["rough-plastic"]["note"]
    assert "(one start)" in note and "the fit's tolerance" in note and "quadrature" not in note
    a, p = auto.reference, pinned.reference
    for name, se in p.stderr.items():
        assert abs(a.params[name] - p.params[name]) <= 1e-3 * se, ("reference", name)
    assert a.chi2_reduced == pytest.approx(p.chi2_reduced, rel=1e-6)
    for step in ("medium", "target"):
        a, p = getattr(auto, step), getattr(pinned, step)
        assert a.params.keys() == p.params.keys() and a.stderr.keys() == p.stderr.keys()
        for name, se in p.stderr.items():
            assert abs(a.params[name] - p.params[name]) <= 1e-3 * se, (step, name)
        assert a.chi2_reduced == pytest.approx(p.chi2_reduced, rel=1e-4)
        assert a.stats["grid_points"] == 0 < p.stats["grid_points"]  # it needed no grid
    assert "screened out" in (tmp_path / "auto" / "report.md").read_text()


def test_a_quick_fit_in_clear_water_is_its_grids_best_start_without_a_rule_error(sessions):
    """fit_direct(screen=True): the starting grid's best start only (the full fit runs every
    start), to the screen's tolerance; f_r is evaluated directly, so its rule error is zero
    and its BIC interval only allows for the descent that tolerance leaves and the
    discrepancy term's two parameters. The full fit continued from it reaches the fit from
    the grid."""
    from veil.fitting.session_data import prepare
    from veil.fitting.solver import TOL_SCREEN
    from veil.fitting.step_fit import STARTS

    kw = dict(brdf_model="torrance-sparrow", step="reference", model_error="off")
    table = sessions["reference_clear"]
    from veil.fitting.steps import fit_direct

    quick = fit_direct(table, screen=True, **kw)
    full = fit_direct(table, **kw)
    assert quick.stats["starts"] == 1 and full.stats["starts"] == STARTS["reference"]
    assert quick.stats["nfev"] < full.stats["nfev"]
    assert quick.stats["rule_error"]["values"] == [0.0] * quick.n_points
    data = prepare(table)
    chi2 = float(np.sum(np.square(quick.residuals)))
    lower, upper = screening.bic_interval(quick, data, chi2)
    term = 2 * math.log(quick.n_points)
    slack = TOL_SCREEN**2 * len(quick.stderr) * max(quick.chi2_reduced, 1.0)
    assert upper == pytest.approx(chi2 + term, rel=1e-12)
    assert lower == pytest.approx(chi2 - slack - term, rel=1e-12)
    assert lower + term <= float(np.sum(np.square(full.residuals))) <= chi2
    resumed = fit_direct(table, start=quick, **kw)
    assert resumed.stats["start"] == "given"
    for name, se in full.stderr.items():
        assert abs(resumed.params[name] - full.params[name]) <= 1e-3 * se, name


def test_a_fit_from_a_start_evaluates_the_grid_only_when_it_is_needed(sessions):
    """fit_medium(start=...): from a converged fit's estimate it stops there without the
    starting grid (and agrees with the fit from the grid); from a start whose run does not
    convince (here: out of evaluations) the grid is evaluated and its next start runs, in
    the place of its best one."""
    from veil.fitting.step_fit import STARTS

    kw = dict(black=sessions["black"], accuracy="fast", propagation="off", model_error="off")
    table = sessions["reference_medium"]
    from_grid = veil.fit_medium(table, veil.BRDF2, **kw)
    resumed = veil.fit_medium(table, veil.BRDF2, start=from_grid, **kw)
    assert from_grid.converged and resumed.converged
    assert from_grid.stats["grid_points"] > 0 and resumed.stats["grid_points"] == 0
    assert resumed.stats["starts"] == 1 and resumed.stats["nfev"] < from_grid.stats["nfev"]
    for name, se in from_grid.stderr.items():
        assert abs(resumed.params[name] - from_grid.params[name]) <= 1e-3 * se
    poor = veil.fit_medium(table, veil.BRDF2, start=dict(from_grid.params, g=0.0), max_nfev=2,
                           **kw)
    assert not poor.converged
    assert poor.stats["grid_points"] == from_grid.stats["grid_points"]
    # a start given as values ran none of the grid's: the start, then the grid's best
    assert poor.stats["starts"] == 1 + STARTS["medium"] and poor.stats["start"] == "given"


def test_a_start_that_is_not_this_fits_is_refused(sessions):
    """start= of another family, without a value of a free parameter, or outside its bounds:
    a FitError naming it (before anything is fitted)."""
    kw = dict(black=sessions["black"], accuracy="fast", propagation="off", model_error="off")
    table = sessions["reference_medium"]
    other = _fit(np.zeros(N))  # a torrance-sparrow result
    from veil.errors import FitError

    with pytest.raises(FitError, match="a torrance-sparrow result; this fit's model is"):
        veil.fit_medium(table, veil.BRDF2, start=other, **kw)
    with pytest.raises(FitError, match="has no value of"):
        veil.fit_medium(table, veil.BRDF2, start={"g": 0.9}, **kw)
    good = {"Td": 0.5, "Tt": 0.5, "g": 0.9, "eta": 1.33}
    with pytest.raises(FitError, match=r"g = 1\.5 is outside"):
        veil.fit_medium(table, veil.BRDF2, start=dict(good, g=1.5), **kw)
