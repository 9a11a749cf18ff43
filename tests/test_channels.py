"""Colour channels (issue 30, first slice; docs/measurements.md and docs/fitting.md,
"Channels"): tables with a channel column read, checked and written; simulated per channel;
f_r of every channel fitted as one problem with the shared parameters tied; per-channel
results in the report and the JSON; a one-channel table exactly as before."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import veil
from support.cli import run
from veil.data.measurements import load_measurements, save_measurements, validate
from veil.data.simulate import simulate_channels
from veil.errors import FitError, MeasurementError
from veil.fitting import FitResult, fit_reference
from veil.models import REGISTRY, model_class

#: The true diffuse coefficient of each channel; n and eta are BRDF1's in every channel.
ALBEDO = {"r": 400.0, "g": 1000.0, "b": 2500.0}
SEED = 7


def _channels() -> dict:
    return {c: (veil.BRDF1.replace(Pd=pd_), None) for c, pd_ in ALBEDO.items()}


@pytest.fixture(scope="module")
def rgb_table() -> pd.DataFrame:
    return simulate_channels(_channels(), noise=0.01, seed=SEED)


@pytest.fixture(scope="module")
def rgb_fit(rgb_table) -> FitResult:
    return fit_reference(rgb_table)


# --------------------------------------------------------------------------------------
# the fit across channels
# --------------------------------------------------------------------------------------
def test_each_albedo_and_the_shared_roughness_come_back_within_their_uncertainty(rgb_fit):
    assert rgb_fit.converged and rgb_fit.channel_names == ("r", "g", "b")
    for c, truth in ALBEDO.items():
        name = f"Pd[{c}]"
        assert abs(rgb_fit.params[name] - truth) < 2 * rgb_fit.stderr[name], name
    n_true = veil.BRDF1.n
    assert abs(rgb_fit.params["n"] - n_true) < 2 * rgb_fit.stderr["n"]
    assert 0.7 < rgb_fit.chi2_reduced < 1.4


def test_the_tie_is_real_one_roughness_fewer_free_parameters(rgb_fit, rgb_table):
    assert [n for n in rgb_fit.params if n.startswith("n")] == ["n"]
    assert set(rgb_fit.params) == {"Pd[r]", "Pd[g]", "Pd[b]", "Ps[r]", "Ps[g]", "Ps[b]",
                                   "n", "eta"}
    for c in ALBEDO:  # the layout maps every channel's model onto the tied slots
        assert rgb_fit.channels[c] == {"Pd": f"Pd[{c}]", "Ps": f"Ps[{c}]", "n": "n",
                                       "eta": "eta"}
    separate = [fit_reference(rgb_table, channel=c) for c in ALBEDO]
    assert rgb_fit.n_free == 8 < sum(r.n_free for r in separate) == 12
    assert rgb_fit.n_points == sum(r.n_points for r in separate)
    # three separate fits find three roughnesses; the tied fit one, as precise as any
    assert len({r.params["n"] for r in separate}) == 3
    assert rgb_fit.stderr["n"] < min(r.stderr["n"] for r in separate)


def test_fixing_a_parameter_holds_it_in_every_channel_or_one(rgb_table):
    both = fit_reference(rgb_table, fixed={"eta": 1.55, "Ps[g]": 5e5})
    assert both.params["eta"] == 1.55 and both.params["Ps[g]"] == 5e5
    assert both.stderr["eta"] is None and both.n_free == 6
    with pytest.raises(FitError, match=r"cannot fix 'k'.*Pd\[r\]"):
        fit_reference(rgb_table, fixed={"k": 1.0})


def test_json_round_trip_and_the_model_of_one_channel(rgb_fit, tmp_path):
    path = tmp_path / "rgb.json"
    rgb_fit.to_json(path)
    data = json.loads(path.read_text())
    assert data["format"] == "veil.fit/2" and set(data["channels"]) == {"r", "g", "b"}
    back = FitResult.from_json(path)
    assert back == rgb_fit
    red = back.as_model(channel="r")
    assert type(red) is type(veil.BRDF1)
    assert red.Pd == rgb_fit.params["Pd[r]"] and red.n == rgb_fit.params["n"]
    values = veil.reflectance(red, 45, [40, 45, 50])
    assert np.all(np.isfinite(values)) and values[1] > values[0]
    every = back.as_model()  # every channel at once (tests/test_channel_model.py)
    assert isinstance(every, veil.ChannelModel) and every["r"] == red
    with pytest.raises(FitError, match="no channel 'x'"):
        back.as_model(channel="x")
    data["channels"]["g"] = {"Pd": "Pd[g]"}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(FitError, match=r"bad.json: key 'channels'"):
        FitResult.from_json(bad)


def test_report_names_the_channels_and_the_tie(rgb_fit):
    text = rgb_fit.report()
    assert "channels           = r, g, b (one fit; tied across them: n, eta)" in text
    for c in ALBEDO:
        assert f"Pd[{c}]:" in text


# --------------------------------------------------------------------------------------
# one channel: exactly as before
# --------------------------------------------------------------------------------------
def test_a_one_channel_table_gives_the_result_of_the_table_without_the_column(tmp_path):
    plain = veil.simulate(veil.BRDF2, None, noise=0.01, seed=SEED)
    coloured = plain.copy()
    coloured.insert(len(plain.columns) - 2, "channel", "g")
    save_measurements(plain, tmp_path / "plain.csv")
    save_measurements(coloured, tmp_path / "green.csv")
    a = fit_reference(tmp_path / "plain.csv")
    b = fit_reference(tmp_path / "green.csv")
    a.to_json(tmp_path / "a.json")
    b.to_json(tmp_path / "b.json")
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert b.channels is None
    c = fit_reference(coloured, channel="g")  # the channel chosen by name: the same fit
    assert c.params == a.params and c.residuals == a.residuals


# --------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------
def test_channel_tables_round_trip_and_keep_their_column(rgb_table, tmp_path):
    path = tmp_path / "rgb.csv"
    save_measurements(rgb_table, path)
    back = load_measurements(path)
    assert list(back.columns) == list(rgb_table.columns)
    assert list(back["channel"]) == list(rgb_table["channel"])
    assert np.array_equal(back["value"].to_numpy(), rgb_table["value"].to_numpy())
    nm = rgb_table.copy()
    nm["channel"] = nm["channel"].map({"r": 650, "g": 550, "b": 450})
    save_measurements(nm, tmp_path / "nm.csv")
    assert set(load_measurements(tmp_path / "nm.csv")["channel"]) == {450, 550, 650}


def _small(channels=("r", "g")) -> str:
    rows = [f"{ti},{tr},{c},{v}" for c in channels
            for ti, tr, v in ((10, 40, 1.0), (20, 50, 2.0), (30, 60, 3.0))]
    return "theta_i,theta_r,channel,value\n" + "\n".join(rows) + "\n"


@pytest.mark.parametrize("edit, expected", [
    (("5", "x"), r"line 5 of \S+bad.csv, column 'channel': 'x' \(expected a channel: r, g "
                 r"or b, or a wavelength in nm from 200 to 2500\)"),
    (("all", "3000"), r"line 2 of \S+bad.csv, column 'channel': '3000'.*wavelength in nm"),
    (("angle", ""), r"the channels of \S+bad.csv differ: channel 'g' measures configurations "
                    r"that channel 'r' does not \(line 7 of \S+bad.csv\); channel 'g' lacks "
                    r"configurations of channel 'r' \(line 4 of \S+bad.csv\)"),
    (("drop", ""), r"channel 'g' lacks configurations of channel 'r' \(line 4 of \S+bad.csv\)"),
])
def test_bad_channel_tables_exit_2_naming_file_channel_and_rows(tmp_path, edit, expected):
    lines = _small().splitlines()
    what, value = edit
    if what == "all":
        lines = [lines[0]] + [ln.replace(",r,", f",{value},").replace(",g,", ",550,")
                              for ln in lines[1:]]
    elif what == "angle":
        lines[6] = lines[6].replace("30,60", "30,61")
    elif what == "drop":
        del lines[6]
    else:
        k = int(what) - 1
        lines[k] = lines[k].replace(",g,", f",{value},")
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(MeasurementError, match=expected):
        load_measurements(path)
    out = run("fit", "reference", path, "-o", tmp_path / "out.json")
    assert out.exit_code == 2, out.output
    assert "Traceback" not in out.output and "bad.csv" in out.output
    assert not (tmp_path / "out.json").exists()


def test_a_repeated_configuration_within_one_channel_is_still_a_duplicate(tmp_path):
    table = pd.DataFrame({"theta_i": [10, 10, 10, 10], "theta_r": [40, 40, 40, 40],
                          "channel": ["r", "r", "g", "g"], "value": [1.0, 1.1, 2.0, 2.1]})
    with pytest.raises(MeasurementError, match="duplicate configurations"):
        validate(table)


def test_a_wavelength_with_an_underscore_is_not_read_as_a_number():
    """Python's float() reads '6_50' as 650; a table's cell '6_50' names no channel."""
    table = pd.DataFrame({"theta_i": [10, 10], "theta_r": [40, 40],
                          "channel": ["6_50", "550"], "value": [1.0, 2.0]})
    with pytest.raises(MeasurementError, match="column 'channel': '6_50'"):
        validate(table)


def test_a_duplicate_from_two_spellings_of_one_channel_names_them(tmp_path):
    """'R' and 'r' (any case) name one channel: the duplicate's message says which channel
    and how the column spells it, not only 'average repeated measurements'."""
    table = pd.DataFrame({"theta_i": [10, 10, 10, 10], "theta_r": [40, 40, 40, 40],
                          "channel": ["r", "R", "g", "g"], "value": [1.0, 1.1, 2.0, 2.1]})
    with pytest.raises(MeasurementError, match="channel 'r' .column 'channel' writes it "
                       "'R' and 'r': one channel"):
        validate(table)


def test_a_results_channel_is_named_as_a_tables_is(tmp_path, rgb_fit):
    """A table reads 'R' as channel r ("any case"), so --channel R of a fit over r, g, b is
    its channel r too (it was refused: "it has no channel 'R'"), in Python and in export."""
    assert rgb_fit.as_model(channel="R") == rgb_fit.as_model(channel="r")
    rgb_fit.to_json(tmp_path / "rgb.json")
    outs = {}
    for name in ("r", "R"):
        outs[name] = tmp_path / f"{name}.csv"
        out = run("export", tmp_path / "rgb.json", "--to", "csv", "--channel", name,
                  "-o", outs[name])
        assert out.exit_code == 0, out.output
    assert outs["r"].read_bytes() == outs["R"].read_bytes()
    out = run("export", tmp_path / "rgb.json", "--to", "csv", "--channel", "Q",
              "-o", tmp_path / "q.csv")
    assert out.exit_code == 2 and "has no channel 'Q'" in out.output, out.output


def test_steps_through_a_medium_refuse_a_reference_of_other_channels(tmp_path, rgb_fit):
    """A table of several channels through a medium needs the reference fitted over the same
    channels (tests/test_channels_medium.py fits them): one of other channels, or of one
    channel, exits 2 naming both."""
    path = tmp_path / "rgb.csv"
    save_measurements(simulate_channels(_channels(), noise=0.01, seed=1), path)
    two = simulate_channels({c: _channels()[c] for c in "rg"}, noise=0.01, seed=1)
    save_measurements(two, tmp_path / "rg.csv")
    rgb_fit.to_json(tmp_path / "ref.json")
    out = run("fit", "medium", tmp_path / "rg.csv", "--reference", tmp_path / "ref.json",
              "-o", tmp_path / "out.json")
    assert out.exit_code == 2, out.output
    assert "fit of channels r, g, b" in out.output and "has channels r, g" in out.output
    fit_reference(path, channel="g").to_json(tmp_path / "ref_g.json")
    out = run("fit", "medium", path, "--reference", tmp_path / "ref_g.json",
              "-o", tmp_path / "out.json")
    assert out.exit_code == 2 and "a fit of one channel" in out.output, out.output
    assert "--channel" in out.output and "Traceback" not in out.output
    out = run("fit", "reference", path, "--channel", "q", "-o", tmp_path / "out.json")
    assert out.exit_code == 2 and "has no channel 'q'" in out.output
    assert not (tmp_path / "out.json").exists()


def test_commands_of_one_channel_refuse_several_and_name_the_file(tmp_path, rgb_fit):
    """veil diagnose, given a result of several channels: exit 2 naming its channels, no
    traceback."""
    path = tmp_path / "rgb.csv"
    save_measurements(simulate_channels(_channels(), noise=0.01, seed=1), path)
    rgb_fit.to_json(tmp_path / "ref.json")
    out = run("diagnose", tmp_path / "ref.json", "--data", path, "-o", tmp_path / "diag")
    assert out.exit_code == 2, out.output
    assert "fits channels r, g, b at once" in out.output and "Traceback" not in out.output
    assert not (tmp_path / "diag").exists()


def test_a_black_cloth_missing_a_channel_is_an_error_naming_it(tmp_path):
    table = simulate_channels(_channels(), noise=0.01, seed=1)
    black = table[table["channel"] != "b"].copy()
    black["value"] = 0.0
    black.attrs["veil_name"] = "black.csv"
    with pytest.raises(MeasurementError, match="black-cloth table black.csv has no channel 'b'"):
        fit_reference(table, black=black)


# --------------------------------------------------------------------------------------
# the command line end to end
# --------------------------------------------------------------------------------------
def test_simulate_and_fit_three_channels_on_the_command_line(tmp_path):
    table = tmp_path / "rgb.csv"
    out = run("simulate", "--brdf", "BRDF1", "--medium", "none", "--channels", "r,g,b",
              "--per-channel", "Pd=400,1000,2500", "--seed", SEED, "-o", table)
    assert out.exit_code == 0, out.output
    assert load_measurements(table).equals(load_measurements(table))
    assert np.array_equal(load_measurements(table)["value"].to_numpy(),
                          simulate_channels(_channels(), noise=0.01, seed=SEED)["value"])
    out = run("fit", "reference", table, "-o", tmp_path / "rgb.json")
    assert out.exit_code == 0, out.output
    assert "Pd[b]" in out.output and "tied across them: n, eta" in out.output
    result = FitResult.from_json(tmp_path / "rgb.json")
    assert result.as_model(channel="b").Pd == pytest.approx(2500, rel=0.01)


@pytest.mark.parametrize("args, message", [
    (("--per-channel", "Pd=1,2,3"), "--per-channel needs --channels"),
    (("--channels", "r,g,b", "--per-channel", "Pd=1,2"), "one number per channel"),
    (("--channels", "r,g,b", "--per-channel", "zz=1,2,3"), "'zz' is not a parameter"),
    (("--channels", "r,r"), "expected distinct channels"),
    (("--channels", "r,5000"), "expected distinct channels"),
    # each bad entry named: a forgotten channel, two spellings of one, a mix of both kinds
    (("--channels", "r,,b"), "--channels 'r,,b': an empty entry"),
    (("--channels", "r,R"), "'R' names channel r a second time"),
    (("--channels", "650,650.0"), "'650.0' names channel 650 a second time"),
    (("--channels", "r,100"), "'100' is not r, g, b or a wavelength from 200 to 2500 nm"),
    (("--channels", "r,650"), "--channels 'r,650': colour channels mixed with wavelengths"),
    (("--channels", "r,g,b", "--per-channel", "Pd=1,nan,3"),
     "--per-channel, channel g: torrance-sparrow Pd = nan"),
])
def test_simulate_channel_options_are_checked(tmp_path, args, message):
    out = run("simulate", "--brdf", "BRDF1", "--medium", "none", *args,
              "-o", tmp_path / "x.csv")
    assert out.exit_code == 2 and message in out.output, out.output


# --------------------------------------------------------------------------------------
# declarations
# --------------------------------------------------------------------------------------
def test_the_declared_defaults_albedos_per_channel_shape_shared():
    ts, hg = model_class("torrance-sparrow"), model_class("henyey-greenstein")
    assert ts.channel_sharing() == {"Pd": "per-channel", "Ps": "per-channel", "n": "shared",
                                    "eta": "shared"}
    assert hg.channel_sharing() == {"Td": "per-channel", "Tt": "per-channel", "g": "shared",
                                    "eta": "shared"}
    fs = model_class("forward-series").channel_sharing()
    assert fs["tau"] == fs["omega"] == "per-channel" and fs["g"] == "shared"
    assert set(REGISTRY) >= {"rough-plastic", "rough-conductor"}
