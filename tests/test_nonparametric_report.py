"""The report of a non-parametric fit (docs/nonparametric.md): the coefficients the
non-negative solve holds at 0 read "at its bound", apart from those the user fixed, in the
report, the pipeline's table and the result file (an older file without the key too); the
evaluations line counts every engine call from the columns made at each rule."""

from __future__ import annotations

import dataclasses
import json

import pytest

from veil.data.simulate import simulate
from veil.fitting import fit_direct
from veil.fitting.problem import Problem
from veil.fitting.result import FitResult
from veil.models import REGISTRY

GGX_PLASTIC = dict(rho=0.4, alpha=0.15, eta=1.12, ks=1.0, distribution="ggx")
#: Held by the user: d2 at 0 (as the solve holds others) and a lobe coefficient above 0.
FIXED = {"d2": 0.0, "w05_1": 1e-6}


@pytest.fixture(scope="module")
def counted():
    """(a clear-water fit with FIXED, the engine calls it made)."""
    table = simulate(REGISTRY["rough-plastic"](**GGX_PLASTIC), None, noise=0.01, seed=7)
    calls = []
    plain = Problem.model_values

    def count(self, x, accuracy="fast"):
        calls.append(accuracy)
        return plain(self, x, accuracy)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Problem, "model_values", count)
        fit = fit_direct(table, brdf_model="nonparametric", fixed=FIXED)
    return fit, len(calls)


def _line(report: str, label: str) -> str:
    return next(line.strip() for line in report.splitlines() if line.strip().startswith(label))


def test_coefficients_at_0_read_at_their_bound_apart_from_the_fixed_ones(counted):
    fit = counted[0]
    zero = [n for n, v in fit.params.items() if v == 0.0 and n not in FIXED]
    assert zero and set(fit.at_bound) == set(zero) and not set(FIXED) & set(fit.at_bound)
    report = fit.report()
    assert _line(report, "free parameters").endswith("(fixed: d2, w05_1)")
    assert _line(report, "at their bound") == (
        f"at their bound     = {len(zero)} coefficients at 0, held there by the "
        f"non-negative solve"
    )
    assert all(f"    {n}: 0 (at its bound)" in report.splitlines() for n in zero)
    assert "    d2   : 0 (fixed)" in report.splitlines()
    assert report.count("(fixed)") == len(FIXED)


def test_the_result_file_keeps_them_apart_and_an_older_one_still_reads(counted, tmp_path):
    """``fixed`` still holds both (the format read before); ``stats["at_bound"]`` names
    the solve's. A file without that key: the coefficients fixed at 0 are the solve's when
    their number is the columns' at 0, else (the user fixed one at 0 too) all read fixed."""
    fit = counted[0]
    path = tmp_path / "np.json"
    fit.to_json(path)
    data = json.loads(path.read_text())
    assert data["stats"]["at_bound"] == list(fit.at_bound)
    assert set(data["fixed"]) == set(fit.at_bound) | set(FIXED)
    assert FitResult.from_json(path).report() == fit.report()
    del data["stats"]["at_bound"]
    path.write_text(json.dumps(data))
    older = FitResult.from_json(path)
    assert older.at_bound == () and older.report().count("(fixed)") == len(older.fixed)
    none_fixed = dataclasses.replace(older, fixed={n: 0.0 for n in fit.at_bound})
    assert none_fixed.at_bound == fit.at_bound


def test_the_evaluations_line_counts_every_engine_call(counted):
    """One call per column at each rule and one per fixed coefficient above 0 at each: the
    count of the calls made (one rule in clear water), and of a fit at two rules."""
    fit, calls = counted
    assert fit.stats["columns_at_rule"] == {"fast": 53}
    assert _line(fit.report(), "evaluations") == (
        f"evaluations        = {calls} engine calls for the columns: 53 at the 'fast' rule, 1 for "
        f"the fixed coefficients' part"
    )
    assert calls == 54
    two = dataclasses.replace(
        fit,
        fixed={n: 0.0 for n in fit.at_bound},
        stats={**fit.stats, "columns": 55, "columns_at_rule": {"fast": 55, "default": 19}},
    )
    assert _line(two.report(), "evaluations") == (
        "evaluations        = 74 engine calls for the columns: 55 at the 'fast' rule, 19 again at "
        "'default'"
    )


def test_the_pipelines_parameter_table_says_the_same(counted):
    from veil.viz.pipeline_report import _param_table

    fit = counted[0]
    rows = {row.split(" | ")[0].lstrip("| "): row for row in _param_table(fit, None)[2:]}
    assert all(rows[n].endswith("| at its bound | at its bound |") for n in fit.at_bound)
    assert all(rows[n].endswith("| fixed | fixed |") for n in FIXED)
