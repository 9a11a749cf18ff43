"""The profile likelihoods of `veil diagnose --profile` (veil.analysis.profiles; docs/ambiguity.md
"Identifiability diagnostics"): their progress, one line per parameter off a terminal, and a
linear family's profile (docs/nonparametric.md) refitted on its columns, the same as the solver's,
of the penalized objective its fit minimized; and the progress of the non-parametric fit's passes
at the finer rule.

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


def test_cli_profile_says_each_parameter_off_a_terminal(tmp_path, monkeypatch) -> None:
    """Off a terminal (CliRunner's output is no tty) `veil diagnose --profile` writes one line
    per parameter profiled, naming it, with the count of refits done (no repeated line of a
    long stage: a loaded machine would add one)."""
    monkeypatch.setattr("veil.cli._common.STAGE_LINE_SECONDS", float("inf"))
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


@pytest.fixture(scope="module")
def penalized_profiles(through_btdf2) -> tuple:
    """The non-parametric fit's profiles (`diagnose`, at its smoothness) of the coefficients
    well away from 0 (estimate > 5 reported standard errors), and the refits' columns."""
    table, fit = through_btdf2
    far = [n for n in fit.free if fit.params[n] > 5.0 * fit.stderr[n]]
    d = diagnose(fit, table, profile=far, points=9)
    problem, _ = problem_for(fit, table)
    bound = [fit.model_class.param(n).key for n in fit.at_bound]
    assert bound  # (coefficients the solve held at 0: free in the refits, as in the fit)
    lin = LinearRefit(problem, "fast", smoothness=fit.stats["smoothness"], bound=bound)
    return fit, d, problem, lin


def test_a_linear_familys_profile_is_the_penalized_objectives(penalized_profiles) -> None:
    """The profile of the objective the fit minimized, |W (X c - y)|^2 + lambda |D c|^2 at
    the fit's lambda (weighted data: Delta chi^2 in noise units). With the others' active
    set unchanged it is exactly quadratic, curvature 1 / [(X'WX + lambda D'D)^-1]_jj, and
    the 1-sigma half-width (sqrt(Delta chi^2) interpolated, exact for a quadratic) is
    sqrt([...]^-1_jj) to rounding: 1e-6, on the sides where no other coefficient enters
    or leaves the active set out to the crossing. The fit
    reports the sandwich covariance inv X'WX inv times max(reduced chi-square, 1), smaller
    than inv by lambda inv D'D inv: the half-width is never below the reported standard
    error over that scale (measured: 1.03 to 8.2 times it, near 1 for the diffuse
    coefficients d0, d1, most for the lobes the smoothness ties to their neighbours). The
    old profiles (unpenalized refits from the penalized estimate, the grid capped at 0.5)
    were flat."""
    fit, d, problem, lin = penalized_profiles
    assert len(d.profiles) >= 6
    x = problem.values
    act = x[lin.index] > 0  # the active set, whose curvature the quadratic has
    xa, da = lin.xw[:, act], lin.d[:, act]
    inv = np.diag(np.linalg.inv(xa.T @ xa + fit.stats["smoothness"] * da.T @ da))
    active_names = [n for n, a in zip(lin.names, act) if a]
    s = max(fit.chi2_reduced, 1.0)
    tight = 0
    for n, p in d.profiles.items():
        j = active_names.index(n)
        want, est = float(np.sqrt(inv[j])), p.estimate
        assert not p.flat and None not in p.interval, n
        for side, half in ((-1, est - p.interval[0]), (1, p.interval[1] - est)):
            if not _changes(lin, n, x, p, side):
                assert half == pytest.approx(want, rel=1e-6), (n, side)
                assert half >= fit.stderr[n] / np.sqrt(s) * (1 - 1e-6), (n, side)
                tight += 1
    # (4 of the 20 sides keep the others' active set out to the crossing: a neighbour held
    # at 0 by the fit usually takes over; the exact check above is not vacuous)
    assert tight >= 3


def _changes(lin: LinearRefit, name: str, x: np.ndarray, p, side: int) -> bool:
    """Whether the other coefficients' active set changes (one reaches its bound 0, or one
    held there by the fit leaves it) in a refit of ``p``'s grid on one ``side`` (-1, 1), out
    to the first point past Delta chi^2 = 1 (those the crossing interpolates between)."""
    mid = len(p.values) // 2
    others = np.array([n != name for n in lin.names])
    before = x[lin.index][others] > 0
    for j in range(mid + side, mid + side * (mid + 1), side):
        moved, _, _ = lin.refit(name, p.values[j], x)
        if np.any((moved[lin.index][others] > 0) != before):
            return True
        if p.delta_chi2[j] >= 1.0:
            return False
    return False


def test_the_coefficients_held_at_0_are_free_in_the_refits(penalized_profiles) -> None:
    """The fit's objective lets every coefficient be >= 0, those it left at 0 too: a refit
    that holds one coefficient may raise a neighbour from 0, so every profile lies at or
    below the one with those held at 0 (measured from the same minimum), and below it by
    more than 1 somewhere (the freed neighbours matter; holding them gave narrow intervals
    and missed flat sides)."""
    fit, d, problem, lin = penalized_profiles
    narrow = LinearRefit(problem, "fast", smoothness=fit.stats["smoothness"])
    x = problem.values
    base = narrow.base(x)
    gaps = []
    for n, p in d.profiles.items():
        held = [2 * (narrow.refit(n, v, x)[1] - base) for v in p.values]
        assert np.all(np.asarray(p.delta_chi2) <= np.asarray(held) + 1e-9), n
        gaps.append(max(np.asarray(held) - np.asarray(p.delta_chi2)))
    assert max(gaps) > 1.0


def test_a_linear_familys_profile_rises_from_its_estimate(penalized_profiles) -> None:
    """Delta chi^2 is measured from the penalized objective's own minimum on the profile's
    columns: >= 0 at every grid point, 0 at the estimate (to rounding: the fit's rule), and
    the grid 3 standard errors of that objective each side, clipped at the bound 0."""
    fit, d, problem, lin = penalized_profiles
    assert not any(n for n, why in d.poorly_determined if "flat" in why)
    for n, p in d.profiles.items():
        assert min(p.delta_chi2) >= 0.0 and p.note is None
        assert p.delta_chi2[len(p.values) // 2] == pytest.approx(0.0, abs=1e-9)
        assert p.values[len(p.values) // 2] == p.estimate and min(p.values) >= 0.0
        assert max(p.delta_chi2) > 4.0, n  # (3 standard errors: 9 where quadratic)


def test_a_linear_family_is_diagnosed_with_its_medium_held(monkeypatch) -> None:
    """With the medium's parameters free under its fit's covariance (``medium=``) the
    problem is neither linear in the coefficients nor the fit's penalized one, and its
    estimate would be re-solved by the solver in 55 coefficients (minutes a step): refused
    at once, naming what to do."""
    from veil.errors import FitError
    from veil.fitting import fit_medium, fit_reference

    ref_clear = veil.simulate(veil.BRDF2, None, noise=0.01, seed=23, **SMALL)
    ref_medium = veil.simulate(veil.BRDF2, veil.BTDF2, noise=0.01, seed=24, **SMALL)
    medium = fit_medium(ref_medium, fit_reference(ref_clear), accuracy="fast")
    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=3, **SMALL)
    fit = fit_target(table, medium, brdf_model="nonparametric", accuracy="fast")
    import veil.analysis.diagnostics as diagnostics

    def refused(*args, **kwargs):
        raise AssertionError("the estimate was re-solved before the refusal")

    monkeypatch.setattr(diagnostics, "solve", refused)
    with pytest.raises(FitError, match="diagnose it without --medium / --reference"):
        diagnose(fit, table, medium=medium)
