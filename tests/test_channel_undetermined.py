"""A fit over colour channels where one channel carries no signal (all zero): "not
determined" for that channel's own parameters only (veil.fitting.undetermined); the
parameters the other channels determine keep their standard errors and correlations, the
same as a fit of the table without that channel; a one-channel all-zero table is "not
determined" in every parameter, as before."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest

from support.cli import run
from veil.data.measurements import save_measurements
from veil.data.simulate import simulate_channels
from veil.fitting import FitResult, fit_reference
from veil.models import PRESETS

ALBEDO = {"r": 400.0, "g": 1000.0, "b": 2500.0}
SEED = 7
#: evaluations per least-squares run: the fits here take about 10
MAX_NFEV = 80
#: the reduced problem's standard errors against those of the fit without channel b
MATCH = 0.03


def _table() -> pd.DataFrame:
    channels = {c: (PRESETS["BRDF1"].replace(Pd=pd_), None) for c, pd_ in ALBEDO.items()}
    return simulate_channels(channels, noise=0.01, seed=SEED)


@pytest.fixture(scope="module")
def tables() -> dict[str, pd.DataFrame]:
    """The table with channel b all zero, and the same table without channel b."""
    table = _table()
    table.loc[table["channel"] == "b", "value"] = 0.0
    rg = table[table["channel"] != "b"].reset_index(drop=True)
    return {"zero": table, "rg": rg}


def _fit(table: pd.DataFrame) -> FitResult:
    return fit_reference(table, max_nfev=MAX_NFEV, model_error="off")


@pytest.fixture(scope="module")
def fits(tables) -> dict[str, FitResult]:
    return {k: _fit(t) for k, t in tables.items()}


def _silent_clause(message: str) -> list[str]:
    """The parameters the message says a session carries no signal to fit."""
    found = re.search(r"carries no signal to fit ([^;]*)", message)
    assert found, message
    return [n.strip() for n in found.group(1).split(",")]


def test_a_silent_channel_names_only_its_own_parameters(fits):
    res = fits["zero"]
    assert not res.converged and not res.determined
    assert res.message.startswith("not determined: session 'channel b' has no positive value")
    assert _silent_clause(res.message) == ["Pd[b]", "Ps[b]"]
    for shared in ("n", "eta", "Pd[r]", "Ps[g]"):
        assert shared not in _silent_clause(res.message)


def test_the_determined_parameters_keep_the_uncertainty_of_a_fit_without_the_channel(fits):
    zero, rg = fits["zero"], fits["rg"]
    assert rg.converged and rg.determined
    assert zero.stderr["Pd[b]"] is None and zero.stderr["Ps[b]"] is None
    for name in ("Pd[r]", "Pd[g]", "Ps[r]", "Ps[g]", "n", "eta"):
        se = zero.stderr[name]
        assert isinstance(se, float) and se > 0, name
        assert se == pytest.approx(rg.stderr[name], rel=MATCH), name
        assert zero.params[name] == pytest.approx(rg.params[name], rel=1e-3), name
    # correlations among the determined ones, as the fit without b; none of b's
    assert zero.correlation["Ps[r]"]["eta"] == pytest.approx(
        rg.correlation["Ps[r]"]["eta"], abs=0.01
    )
    assert "Pd[b]" not in zero.correlation and "Pd[b]" not in zero.correlation["Pd[r]"]
    # a partial covariance is no covariance of every free parameter (nothing propagates it)
    assert zero.covariance() is None


def test_unweighted_data_scale_by_the_channels_that_carry_a_signal(tables):
    zero, rg = (_fit(tables[k].drop(columns="sigma")) for k in ("zero", "rg"))
    assert not zero.weighted and not zero.determined
    assert _silent_clause(zero.message) == ["Pd[b]", "Ps[b]"]
    for name in ("Pd[r]", "n", "eta"):
        assert zero.stderr[name] == pytest.approx(rg.stderr[name], rel=MATCH), name


def test_a_one_channel_table_of_zeros_is_not_determined_in_every_parameter(tables):
    one = tables["zero"]
    one = one[one["channel"] == "b"].drop(columns="channel").reset_index(drop=True)
    res = _fit(one)
    assert not res.converged and not res.determined
    assert (
        "has no positive value (all zero): it carries no signal to fit Pd, Ps, n, eta"
        in res.message
    )
    assert all(v is None for v in res.stderr.values())


def test_the_command_line_exits_1_and_writes_the_partly_determined_result(tables, tmp_path):
    path = tmp_path / "rgbz.csv"
    save_measurements(tables["zero"], path)
    out = run("fit", "reference", path, "--max-nfev", MAX_NFEV, "-o", tmp_path / "out.json")
    assert out.exit_code == 1, out.output
    assert "it carries no signal to fit Pd[b], Ps[b];" in out.output
    assert re.search(r"Pd\[b\]: \S+ \+/- \(not determined\)", out.output)
    assert re.search(r"Pd\[r\]: \S+ \+/- [0-9]", out.output)
    data = json.loads((tmp_path / "out.json").read_text())
    assert data["converged"] is False and data["determined"] is False
    assert data["stderr"]["Pd[b]"] is None and data["stderr"]["Pd[r]"] > 0
    assert FitResult.from_json(tmp_path / "out.json").stderr["n"] is not None
