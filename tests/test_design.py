"""Acquisition design (veil.analysis.design, veil design; docs/model.md sec. 1, 7).

Coarse candidate grids (fine step 2 deg, coarse step 10 deg) at the "fast" quadrature.
"""

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import veil
from veil.analysis.design import (
    PLAN_COLUMNS,
    Information,
    candidates,
    conditions,
    design,
    greedy,
    rank,
    simulate_plan,
)
from veil.cli import main
from veil.data.measurements import validate

COARSE = dict(fine_step=2.0, coarse_step=10.0)


@pytest.fixture(scope="module")
def info_known():
    conds = conditions(["BTDF1"])
    table = candidates(conds, psi=(60,), **COARSE)
    return Information(veil.BRDF1, conds, table, mode="known")


def test_peak_ranks_above_a_redundant_configuration(info_known):
    info = info_known
    rho = info.table["rho"].to_numpy()
    # already measured: the diffuse wing rho <= -20 deg
    base = np.flatnonzero(rho <= -20)
    ranking = rank(info, base)
    order = {int(r.index): pos for pos, r in enumerate(ranking.itertuples())}
    peak = int(np.flatnonzero(rho == 0)[0])
    wing = int(np.flatnonzero(rho == -10)[0])  # next to the measured wing, off the peak
    assert order[peak] < order[wing]
    gains = dict(zip(ranking["index"], ranking["gain"]))
    assert gains[peak] > 2 * gains[wing]
    # with everything else measured, a further wing point is redundant, the peak is not
    others = [k for k in range(len(rho)) if rho[k] not in (0.0, -30.0)]
    last = rank(info, others)
    assert list(last["rho"]) == [0.0, -30.0]
    assert last["gain"][0] > 2 * last["gain"][1]
    assert set(ranking["index"]).isdisjoint(base) and len(ranking) == len(rho) - len(base)
    # the best candidates are all within the specular window
    assert np.all(np.abs(ranking["rho"].to_numpy()[:3]) <= 6)
    # a greedy plan on top of the wing starts at the top of the ranking
    chosen, g = greedy(info, 3, base=base)
    assert chosen[0] == ranking["index"][0] and g[0] == pytest.approx(ranking["gain"][0])
    assert np.all(np.diff(g) <= 1e-9) or len(set(chosen)) == 3


def test_plan_is_deterministic_distinct_and_reduces_uncertainty():
    kw = dict(psi=(30, 60, 90), mode="joint", **COARSE)
    a = design(veil.BRDF1, ["BTDF1", "BTDF3"], 12, **kw)
    b = design(veil.BRDF1, ["BTDF1", "BTDF3"], 12, **kw)
    pd.testing.assert_frame_equal(a["plan"], b["plan"])
    plan = a["plan"]
    assert list(plan.columns) == list(PLAN_COLUMNS) and len(plan) == 12
    assert not plan.duplicated(["condition", "psi", "rho"]).any()
    info = a["information"]
    # jointly estimated media: the thin medium is worth more than the thick one alone
    cond = a["conditions"].set_index("condition")
    assert cond.loc["BTDF1", "alone_se_n"] < cond.loc["BTDF3", "alone_se_n"]
    assert cond["in_plan"].sum() == 12
    assert a["stderr"]["n"] <= cond["alone_se_n"].min() + 1e-12
    # the plan's criterion beats a plan of the first 12 candidates
    assert a["criterion"] > info.criterion(info.matrix(range(12)))


def test_common_concentration_factor_carries_no_information_under_relative_noise():
    # f is proportional to c^2 when Td and Tt both scale by c (docs/model.md sec. 5)
    r = design(veil.BRDF1, ["BTDF2"], 8, factors=(0.5, 1.0, 2.0), psi=(60,), **COARSE)
    se = r["conditions"]["alone_se_n"].to_numpy()
    assert np.allclose(se, se[0], rtol=1e-6)
    # with an absolute noise floor the concentrated medium wins
    r = design(veil.BRDF1, ["BTDF2"], 8, factors=(0.5, 1.0, 2.0), psi=(60,), floor=50.0,
               **COARSE)
    se = r["conditions"]["alone_se_n"].to_numpy()
    assert se[0] > se[1] > se[2]


def test_plan_can_be_simulated(info_known):
    chosen, gains = greedy(info_known, 6)
    from veil.analysis.design import plan_table

    plan = plan_table(info_known, chosen, gains)
    tables = simulate_plan(plan, veil.BRDF1, noise=0.0, accuracy="fast")
    assert list(tables) == ["BTDF1"]
    t = validate(tables["BTDF1"])
    assert len(t) == 6
    # veil.engine.apparent on 64 configurations (padded): the engine's compiled chunk size
    idx = np.minimum(np.arange(64), 5)
    cols = [t[c].to_numpy()[idx] for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    expected = veil.apparent(veil.BRDF1, veil.BTDF1, *cols, accuracy="fast")[:6]
    assert np.allclose(t["value"], expected, rtol=1e-9)


def test_bad_input(info_known):
    with pytest.raises(ValueError, match="size"):
        greedy(info_known, 0)
    with pytest.raises(ValueError, match="only"):
        greedy(info_known, len(info_known.rows) + 1)
    conds = conditions(["BTDF1"])
    table = candidates(conds, psi=(60,), **COARSE)
    with pytest.raises(ValueError, match="parameters of interest"):
        Information(veil.BRDF1, conds, table, interest=("Td",))
    with pytest.raises(ValueError, match="both 0"):
        Information(veil.BRDF1, conds, table, noise=0.0)
    with pytest.raises(ValueError, match="repeated"):
        conditions(["BTDF1"], factors=(1, 1))
    runner = CliRunner()
    for args, message in [
        (["design", "--brdf", "BRDF1", "--medium", "none"], "scattering media"),
        (["design", "--brdf", "BRDF1", "--medium", "BTDF1", "--psi", "30,x"], "not a number"),
        (["design", "--brdf", "BRDF1", "--medium", "BTDF9"], "BTDF9"),
        (["design", "--brdf", "BRDF1", "--medium", "BTDF1", "--medium", "btdf1"], "twice"),
        (["design", "--brdf", "BRDF1", "--medium", "BTDF1", "--interest", "g"], "interest"),
        # the value as a user wrote it, not numpy's repr (was "np.float64(0.0)")
        (["design", "--brdf", "BRDF1", "--medium", "BTDF1", "--psi", "0"], "--psi 0: expected"),
        (["design", "--brdf", "BRDF1", "--medium", "BTDF1", "--psi", "nan"], "--psi nan:"),
    ]:
        r = runner.invoke(main, args)
        assert r.exit_code == 2, (args, r.output)
        assert message in r.output and "Traceback" not in r.output
        assert "np.float64" not in r.output


def test_cli_design_writes_plan(tmp_path):
    out = tmp_path / "plan.csv"
    r = CliRunner().invoke(main, ["design", "--brdf", "BRDF1", "--medium", "BTDF1",
                                  "--medium", "BTDF3", "--size", "5", "--psi", "60",
                                  "--fine-step", "2", "--coarse-step", "10", "-o", str(out)])
    assert r.exit_code == 0, r.output
    plan = pd.read_csv(out)
    assert list(plan.columns) == list(PLAN_COLUMNS) and len(plan) == 5
    assert set(plan["condition"]) <= {"BTDF1", "BTDF3"}
    assert "Plan of 5 measurements" in r.output
