"""The profile likelihoods of `veil diagnose --profile` (veil.analysis.profiles; docs/ambiguity.md
"Identifiability diagnostics"): their progress, one line per parameter off a terminal, and a
linear family's profile (docs/nonparametric.md) refitted on its columns, the same as the solver's;
and the progress of the non-parametric fit's passes at the finer rule.

Small sessions (55 configurations) at the "fast" rule.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import veil
from veil.analysis.diagnostics import diagnose, problem_for
from veil.analysis.profiles import LinearRefit, SolverRefit, profile_likelihood
from veil.cli import main
from veil.fitting import FitResult, fit_direct, fit_target
from veil.fitting.linear_fit import nonnegative_solve

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")


@pytest.fixture(scope="module")
def through_btdf2() -> tuple[pd.DataFrame, FitResult]:
    """The paper's target through BTDF2 and its non-parametric fit at the "fast" rule."""
    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=3, **SMALL)
    return table, fit_target(table, veil.BTDF2, brdf_model="nonparametric", accuracy="fast")


def test_cli_profile_says_each_parameter_off_a_terminal(tmp_path) -> None:
    """Off a terminal (CliRunner's output is no tty) `veil diagnose --profile` writes one line
    per parameter profiled, naming it, with the count of refits done."""
    table = veil.simulate(veil.BRDF1, veil.BTDF1, noise=0.01, seed=21, **SMALL)
    fit = fit_target(table, veil.BTDF1, accuracy="fast")
    res, data = tmp_path / "t.json", tmp_path / "t.csv"
    fit.to_json(res)
    veil.save_measurements(table, data)
    args = ["diagnose", str(res), "--data", str(data), "--profile", "--points", "3"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    lines = re.findall(r"^veil diagnose: profile (\d)/4: (\S+) \((\d+)/8\)$", r.output, re.M)
    assert lines == [(str(k + 1), n, str(2 * k)) for k, n in enumerate(["Pd", "Ps", "n", "eta"])]
    assert "veil diagnose: the covariance" in r.output


def test_a_linear_familys_profile_needs_no_solver(through_btdf2, monkeypatch) -> None:
    """Through the medium: the profile of a non-parametric fit refits on its columns, made
    once (one engine call per free coefficient), never by the solver; the columns' cost is the
    engine's at the estimate and at a refit, and the progress names each parameter."""
    import veil.analysis.profiles as profiles

    table, fit = through_btdf2
    problem, _ = problem_for(fit, table)
    assert LinearRefit.of(problem)
    x = problem.values.copy()
    lin, engine = LinearRefit(problem, "fast"), SolverRefit(problem, "fast")
    assert lin.cost(x) == pytest.approx(engine.cost(x), rel=1e-9)
    name = problem.free_names[0]
    moved, cost, ok = lin.refit(name, 1.1 * x[problem.index(name)], x)
    assert ok and cost == pytest.approx(engine.cost(moved), rel=1e-9)

    def refused(*args, **kwargs):
        raise AssertionError("a linear family's profile called the solver")

    monkeypatch.setattr(profiles, "solve", refused)
    said: list = []
    which = problem.free_names[:3]
    d = diagnose(fit, table, profile=which, points=5, progress=lambda *a: said.append(a))
    assert list(d.profiles) == which and all(p.converged for p in d.profiles.values())
    for k, n in enumerate(which):
        assert (f"profile {k + 1}/3: {n}", 4 * k, 12) in said
    assert said[-1] == ("profile 3/3: " + which[-1], 12, 12)


def test_a_linear_familys_profile_equals_the_solvers() -> None:
    """The refits on the columns (an exact non-negative least-squares solve) against the
    solver's (Levenberg-Marquardt in the bounded coefficients, the way before), every active
    coefficient's profile from the unpenalized minimum: Delta chi^2 within 1e-6 (measured:
    2e-8 at most). In clear water, where the solver's refits take a tenth of a second; through
    a medium one of its refits takes minutes (the family's Jacobian in 55 coefficients), and
    the columns are checked against the engine's values instead (the test above)."""
    table = veil.simulate(veil.BRDF1, None, noise=0.01, seed=5, **SMALL)
    fit = fit_direct(table, brdf_model="nonparametric")
    problem, _ = problem_for(fit, table)
    lin, engine = LinearRefit(problem, "fast"), SolverRefit(problem, "fast")
    x = problem.values.copy()
    x[lin.index] = nonnegative_solve(lin.xw, lin.yw)  # (the penalized estimate's chi^2 is higher)
    active = [n for n in problem.free_names if x[problem.index(n)] > 0]
    assert len(active) >= 5
    rises = []
    for n in active:
        se = fit.stderr[n]
        fast = profile_likelihood(problem, x, n, se, points=5, refits=lin)
        slow = profile_likelihood(problem, x, n, se, points=5, refits=engine)
        assert slow.converged and fast.converged and fast.values == slow.values
        assert np.allclose(fast.delta_chi2, slow.delta_chi2, rtol=1e-6, atol=1e-6), n
        rises.append(max(fast.delta_chi2))
    assert max(rises) > 0.05  # (profiles that rise: not only the clipped zeros)


def test_the_finer_rule_passes_report_progress() -> None:
    """A non-parametric fit at the "default" rule reports each column it makes at that rule,
    pass by pass, as it does the "fast" rule's."""
    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=3, **SMALL).iloc[::2]
    said: list = []
    fit = fit_target(
        table, veil.BTDF2, brdf_model="nonparametric", progress=lambda *a: said.append(a)
    )
    made = fit.stats["columns_at_rule"]
    fine = [(s, d, t) for s, d, t in said if "'default' rule" in s]
    assert fine and fine[0][0].endswith("pass 1") and fine[0][1] == 1
    ends = [d for s, d, t in fine if d == t]
    assert sum(ends) == made["default"] > 0
    assert ("columns", made["fast"], made["fast"]) in said
