"""Simulated sessions (docs/model.md sec. 7) and ``veil simulate``.

The engine compiles once per model structure, accuracy and array shape; ``simulate`` always
calls it with CHUNK configurations, so everything here at accuracy "fast" shares one
compilation (the truth for the medium test is padded to CHUNK on purpose).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

import veil
from veil.cli import main
from veil.data.black_cloth import subtract_black
from veil.data.measurements import canonical_angles, load_measurements
from veil.data.simulate import CHUNK, glow_scale, simulate

FAST = {"accuracy": "fast"}


def angles(table):
    return tuple(table[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))


def hg_glow_shape(medium, psi):
    """s = T_d + T_t p(g, gamma) with cos(gamma) = -cos(psi), by hand (docs/model.md sec. 3)."""
    g, cos_gamma = medium.g, -math.cos(math.radians(psi))
    p = (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * cos_gamma) ** 1.5)
    return medium.Td + medium.Tt * p


# -- clear medium ---------------------------------------------------------------------------

def test_clear_medium_equals_reflectance():
    table, black = simulate(veil.BRDF2, None, noise=0.0, black=True)
    ti, pi_, tr, pr = angles(table)
    np.testing.assert_array_equal(table["value"].to_numpy(),
                                  veil.reflectance(veil.BRDF2, ti, tr, pi_, pr))
    assert table.columns.tolist() == ["psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r",
                                      "value", "sigma"]
    assert len(table) == 111 and (table["sigma"] == 0).all()
    assert (black["value"] == 0).all() and (black["sigma"] == 0).all()


def test_noise_statistics():
    psi = tuple(range(20, 161, 10))
    table = simulate(veil.BRDF1, None, psi=psi, noise=0.05, seed=3)
    truth = veil.reflectance(veil.BRDF1, table["theta_i"], table["theta_r"], table["phi_i"],
                             table["phi_r"])
    r = (table["value"].to_numpy() - truth) / truth
    n = len(r)
    assert n > 300
    assert abs(r.mean()) < 4 * 0.05 / math.sqrt(n)
    assert abs(r.std(ddof=1) / 0.05 - 1) < 4 / math.sqrt(2 * n)
    np.testing.assert_allclose(table["sigma"], 0.05 * truth, rtol=1e-15)


def test_seed_determinism():
    a = simulate(veil.BRDF1, None, psi=(30,), seed=7)
    b = simulate(veil.BRDF1, None, psi=(30,), seed=7)
    c = simulate(veil.BRDF1, None, psi=(30,), seed=8)
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert (a["value"] != c["value"]).all()
    assert (a["sigma"] == c["sigma"]).all()


# -- through a medium -----------------------------------------------------------------------

def test_medium_values_equal_apparent_and_are_deterministic():
    table = simulate(veil.BRDF1, veil.BTDF2, psi=(90,), noise=0.0, glow=0.0, **FAST)
    ti, pi_, tr, pr = angles(table)
    n = len(ti)
    assert n == 31 < CHUNK
    pad = np.minimum(np.arange(CHUNK), n - 1)
    truth = veil.apparent(veil.BRDF1, veil.BTDF2, ti[pad], tr[pad], pi_[pad], pr[pad], **FAST)[:n]
    np.testing.assert_allclose(table["value"], truth, rtol=1e-12, atol=0)
    noisy = simulate(veil.BRDF1, veil.BTDF2, psi=(90,), seed=5, **FAST)
    again = simulate(veil.BRDF1, veil.BTDF2, psi=(90,), seed=5, **FAST)
    pd.testing.assert_frame_equal(noisy, again, check_exact=True)


def test_glow_model():
    # psi = 60 holds the reference configuration (rho = -30: theta_i = 0, theta_r = 60)
    table, black = simulate(veil.BRDF1, veil.BTDF2, psi=(30, 60, 90), noise=0.0, glow=0.05,
                            black=True, **FAST)
    level = {}
    for psi in (30.0, 60.0, 90.0):
        g = black.loc[black["psi"] == psi, "value"].to_numpy()
        np.testing.assert_allclose(g, g[0], rtol=1e-12)  # constant within a psi: I.R = cos psi
        level[psi] = g[0]
    # the scale is the standard object's (BRDF2's) signal through the medium there
    standard = simulate(veil.BRDF2, veil.BTDF2, psi=(60,), noise=0.0, glow=0.0, **FAST)
    at_ref = standard.loc[standard["rho"] == -30, "value"].iloc[0]
    assert level[60.0] == pytest.approx(0.05 * at_ref, rel=1e-10)
    assert glow_scale(veil.BTDF2, FAST["accuracy"]) == pytest.approx(at_ref, rel=1e-12)
    m = veil.BTDF2
    for psi in (30.0, 90.0):
        assert level[psi] / level[60.0] == pytest.approx(
            hg_glow_shape(m, psi) / hg_glow_shape(m, 60.0), rel=1e-10)
    # a few percent of the standard object's signal off the peak
    off_peak = np.median(standard.loc[standard["rho"].abs() >= 15, "value"].to_numpy())
    assert 0.01 < level[60.0] / off_peak < 0.1


def test_glow_depends_on_the_medium_only():
    """One black cloth serves every object in a medium, as in the lab."""
    kw = dict(psi=(30, 90), noise=0.0, black=True, **FAST)
    _, black1 = simulate(veil.BRDF1, veil.BTDF3, **kw)
    _, black2 = simulate(veil.BRDF2, veil.BTDF3, **kw)
    _, other = simulate(veil.BRDF1, veil.BTDF1, **kw)
    pd.testing.assert_frame_equal(black1, black2, check_exact=True)
    assert not np.allclose(black1["value"], other["value"], rtol=1e-3)


def test_black_subtraction_recovers_apparent():
    kw = dict(psi=(30, 90), **FAST)
    truth = simulate(veil.BRDF1, veil.BTDF2, noise=0.0, glow=0.0, **kw)
    table, black = simulate(veil.BRDF1, veil.BTDF2, noise=0.01, black=True, seed=11, **kw)
    alone = simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=11, **kw)
    pd.testing.assert_frame_equal(table, alone, check_exact=True)  # independent of black=
    assert (black["value"] > 0).all()
    out = subtract_black(table, black)
    z = (out["value"].to_numpy() - truth["value"].to_numpy()) / out["sigma"].to_numpy()
    assert np.all(np.abs(z) < 5)
    assert 0.5 < np.mean(z ** 2) < 1.6
    # without the subtraction the glow is a visible bias in the off-peak configurations
    off = (table["rho"].abs() >= 15).to_numpy()
    bias = (table["value"].to_numpy() - truth["value"].to_numpy()) / table["sigma"].to_numpy()
    assert np.mean(bias[off]) > 2


def test_progress_reports():
    calls = []
    simulate(veil.BRDF1, veil.BTDF1, psi=(30, 60), noise=0.0,
             progress=lambda done, total: calls.append((done, total)), **FAST)
    assert calls[-1] == (80, 80)
    assert [d for d, _ in calls] == sorted(d for d, _ in calls) and len(calls) == 2


@pytest.mark.parametrize("kwargs, message", [
    ({"noise": -0.1}, "noise = -0.1"),
    ({"glow": float("nan")}, "glow = nan"),
    ({"seed": -1}, "seed = -1"),
    ({"seed": 1.5}, "seed = 1.5"),
    ({"accuracy": "best"}, "accuracy = 'best'"),
    ({"psi": (200,)}, "psi = 200"),
])
def test_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        simulate(veil.BRDF1, None, **kwargs)
    with pytest.raises(TypeError, match="BRDF"):
        simulate(veil.BTDF1, None)


# -- command line ---------------------------------------------------------------------------

def run(*args):
    return CliRunner().invoke(main, ["simulate", *args])


def test_cli_files_are_deterministic_and_loadable(tmp_path):
    a, b, c = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "c.csv"
    base = ["--brdf", "BRDF1", "--medium", "none", "--psi", "30,60"]
    for path, seed in ((a, "0"), (b, "0"), (c, "1")):
        result = run(*base, "--seed", seed, "-o", str(path))
        assert result.exit_code == 0, result.output
    assert a.read_bytes() == b.read_bytes() != c.read_bytes()
    table = load_measurements(a)
    assert table.columns.tolist() == ["psi", "rho", "theta_i", "theta_r", "value", "sigma"]
    assert len(table) == 43 + 37
    api = simulate(veil.BRDF1, None, psi=(30, 60))
    np.testing.assert_array_equal(table["value"], api["value"])  # bit for bit through the file
    for form, cols in (("full", ["theta_i", "phi_i", "theta_r", "phi_r"]),
                       ("inplane", ["theta_i", "theta_r"])):
        path = tmp_path / f"{form}.csv"
        assert run(*base, "--form", form, "-o", str(path)).exit_code == 0
        other = load_measurements(path)
        assert other.columns.tolist() == cols + ["value", "sigma"]
        pd.testing.assert_frame_equal(canonical_angles(other).iloc[:, :4],
                                      canonical_angles(table).iloc[:, :4], check_exact=True)


def test_cli_with_medium_and_black(tmp_path):
    out, black = tmp_path / "m.csv", tmp_path / "black.csv"
    result = run("--brdf", "BRDF1", "--medium", "BTDF2", "--psi", "90", "--accuracy", "fast",
                 "--noise", "0", "--variant", "paper", "-o", str(out), "--black", str(black))
    assert result.exit_code == 0, result.output
    session, cloth = load_measurements(out), load_measurements(black)
    api, api_black = simulate(veil.BRDF1, veil.BTDF2, psi=(90,),
                              noise=0.0, black=True, **FAST)
    np.testing.assert_array_equal(session["value"], api["value"])
    np.testing.assert_array_equal(cloth["value"], api_black["value"])
    assert (subtract_black(session, cloth)["value"] > 0).all()


@pytest.mark.parametrize("args, message", [
    (["--brdf", "BRDF9"], "BRDF 'BRDF9'"),
    (["--brdf", "1,2,3"], "must have 4 numbers"),
    (["--medium", "BRDF1"], "not a BTDF preset"),
    (["--psi", "30,abc"], "'abc' is not a number"),
    (["--psi", "200"], "--psi 200 deg"),
    (["--psi", "30,30"], "repeated"),
    (["--noise", "-1"], "--noise"),
    (["--glow", "-0.5"], "--glow"),
    (["--seed", "-3"], "--seed"),
    (["--fine-step", "0"], "--fine-step 0"),
    (["--fine-step", "1e-9", "--window", "1e300"], "configurations"),
    (["--limit", "95"], "--limit 95"),
    (["--form", "polar"], "--form"),
])
def test_cli_bad_input_exit_2(tmp_path, args, message):
    out = tmp_path / "out.csv"
    out.write_text("keep")
    opts = {"--brdf": "BRDF1", "--medium": "none"}
    base = []
    for key, val in opts.items():
        if key not in args:
            base += [key, val]
    result = run(*base, *args, "-o", str(out))
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert out.read_text() == "keep"


def test_cli_huge_window_is_clamped_to_the_limit(tmp_path):
    # --window past what --limit allows used to take a rotation per fine step (1e9: > 60 s)
    huge, at_limit = tmp_path / "huge.csv", tmp_path / "at_limit.csv"
    for path, window in ((huge, "1e300"), (at_limit, "90")):
        result = run("--brdf", "BRDF1", "--medium", "none", "--psi", "30", "--window", window,
                     "-o", str(path))
        assert result.exit_code == 0, result.output
    assert huge.read_bytes() == at_limit.read_bytes()
    assert len(load_measurements(huge)) == 139


def test_cli_refuses_same_output_twice_and_missing_directory(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("keep")
    result = run("--brdf", "BRDF1", "--medium", "none", "-o", str(out), "--black",
                 str(tmp_path / "." / "out.csv"))
    assert result.exit_code == 2 and "same file" in result.output
    assert out.read_text() == "keep"
    result = run("--brdf", "BRDF1", "--medium", "none", "-o", str(tmp_path / "no" / "x.csv"))
    assert result.exit_code == 2 and "does not exist" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_cli_help_names_units():
    result = run("--help")
    assert result.exit_code == 0
    for word in ("--psi", "degrees", "--noise", "Relative standard deviation", "--black",
                 "--form", "--variant", "--seed", "--glow"):
        assert word in result.output
