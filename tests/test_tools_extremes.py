"""Extreme inputs of the command-line tools (veil eval, render, simulate) and of measurement
tables: a set-up length out of the range the plate's weighting computes in, linear render
values beyond the --linear file's float32, simulated values beyond float64, an empty
channel cell. Each gets exit status 2 and a message naming what to change; nothing is
written, and no raw RuntimeWarning reaches the user."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from veil.cli import main
from veil.errors import InputError, MeasurementError


def _run(args):
    """``veil ARGS`` with every warning recorded: (result, the RuntimeWarnings raised, but
    the program store's notes that it rebuilds a program made by other code)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = CliRunner().invoke(main, args)
    return result, [w for w in caught if issubclass(w.category, RuntimeWarning)
                    and "stored engine program" not in str(w.message)]


# -- set-up lengths (--path-length, --plate-width): the model's range, its message ---------
FORWARD = ["--medium-model", "forward-series", "--medium", "0.5,0.9,0.8,1,1"]
EVAL = ["eval", "--brdf", "BRDF1", *FORWARD, "--theta-i", "45", "--theta-r", "50",
        "--accuracy", "fast"]


@pytest.mark.parametrize("lengths, flag", [
    (["--path-length", "1e-300", "--plate-width", "1e308"], "path_length = 1e-300"),
    (["--path-length", "1", "--plate-width", "1e308"], "plate_width = 1e+308"),
    # alone, R_c = 1e308 dropped the scattered light (J_v flushed to 0) and exited 0
    (["--path-length", "1e308"], "path_length = 1e+308"),
    (["--path-length", "1e-120"], "path_length = 1e-120"),
])
def test_eval_set_up_length_out_of_range_exit_2(lengths, flag):
    result, _ = _run([*EVAL, *lengths])
    assert result.exit_code == 2, result.output
    assert flag in result.output
    assert "from 1e-100 to 1e+100" in result.output
    assert "Traceback" not in result.output and "internal error" not in result.output


@pytest.mark.parametrize("command", [
    ["warmup", "--quiet", "--models", "forward-series"],
    ["simulate", "--brdf", "BRDF1", *FORWARD, "--psi", "60", "-o", "never.csv"],
    ["render", "--brdf", "BRDF1", *FORWARD, "--size", "16", "-o", "never.png", "--quiet"],
])
def test_every_command_refuses_an_out_of_range_plate(command, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result, _ = _run([*command, "--path-length", "1e-300", "--plate-width", "1e308"])
    assert result.exit_code == 2, result.output
    assert "path_length = 1e-300" in result.output and "from 1e-100 to 1e+100" in result.output
    assert list(tmp_path.iterdir()) == []


def test_set_up_lengths_at_the_ends_of_the_range_are_accepted():
    # the lengths pass the option layer: the command then stops at the bad angle
    result, _ = _run([*EVAL[:-6], "--theta-i", "95", "--theta-r", "50",
                      "--path-length", "1e-100", "--plate-width", "1e100"])
    assert result.exit_code == 2, result.output
    assert "--theta-i" in result.output and "length" not in result.output


def test_the_plate_weighting_depends_on_the_ratio_alone_within_the_range():
    """The range of --path-length/--plate-width: at its ends J_v (every order weighting) is
    finite and equals the one at the same ratio in unit lengths."""
    from veil.models.forward_series import LENGTH_RANGE
    from veil.models.forward_series import ForwardSeries

    lo, hi = LENGTH_RANGE
    rng = np.random.default_rng(3)
    rp = rng.normal(size=(200, 3))
    rp[:, 2] = np.abs(rp[:, 2])
    rp = np.concatenate([rp / np.linalg.norm(rp, axis=1, keepdims=True), [[0.0, 1.0, 1e-14]]])
    r = np.array([0.6, 0.0, 0.8])
    v = np.array([3.0, 0.9, 0.9, 1.0, 1.0])
    for orders in ("poisson", "view-side"):
        def weight(pl, pw, orders=orders):
            m = ForwardSeries(3.0, 0.9, 0.9, path_length=pl, plate_width=pw, orders=orders)
            return np.asarray(m.view_weight(v, rp, r))

        for pl, pw, ratio in [(lo, lo, 1.0), (hi, hi, 1.0), (lo, hi, 1e13), (lo, 0.0, 0.0)]:
            w = weight(pl, pw)
            assert np.all(np.isfinite(w)), (orders, pl, pw)
            # (lo, hi): a plate 1e200 path lengths wide is infinite, as one 1e13 wide
            np.testing.assert_allclose(w, weight(1.0, ratio), rtol=1e-8, atol=1e-12)
        # a plate 1e-200 path lengths wide: no scattered light leaves it to speak of
        w = weight(hi, lo)
        assert np.all(np.isfinite(w)) and np.all(np.abs(w) < 1e-150)


@pytest.mark.parametrize("lengths", [dict(path_length=1e-300, plate_width=1e308),
                                     dict(path_length=1e308), dict(path_length=1.0,
                                                                   plate_width=1e-101)])
def test_the_model_refuses_set_up_lengths_outside_its_range(lengths):
    """veil.ForwardSeries itself (the API, a result file): a ParameterError naming the
    length, not a non-finite engine term or the scattered light silently dropped."""
    from veil.errors import ParameterError
    from veil.models.forward_series import ForwardSeries

    name = "plate_width" if lengths.get("plate_width", 1.0) < 1e-100 else "path_length"
    with pytest.raises(ParameterError, match=f"ForwardSeries.{name} = .*from 1e-100 to 1e"):
        ForwardSeries(0.5, 0.9, 0.8, **lengths)


# -- veil render --linear -------------------------------------------------------------------
RENDER = ["render", "--medium", "none", "--light-theta", "45", "--size", "16", "--quiet"]


@pytest.mark.parametrize("brdf, shown, advice", [
    ("1e40,1e40,0.8,1.5", "Pd = 1e+40, Ps = 1e+40", "smaller"),
    ("1.7e308,1.7e308,0.8,1.5", "Pd = 1.7e+308, Ps = 1.7e+308", "smaller"),
    ("1e-300,1e-300,0.8,1.5", "Pd = 1e-300, Ps = 1e-300", "larger"),
])
def test_render_linear_values_beyond_float32_exit_2(tmp_path, brdf, shown, advice):
    png, npy = tmp_path / "r.png", tmp_path / "r.npy"
    result, warned = _run([*RENDER, "--brdf", brdf, "-o", str(png), "--linear", str(npy)])
    assert result.exit_code == 2, result.output
    assert f"--linear {npy}" in result.output and "float32" in result.output
    assert shown in result.output and f"--brdf {brdf}" in result.output
    assert f"give {advice} coefficients" in result.output
    assert not png.exists() and not npy.exists()  # both files or neither
    assert not warned


def test_render_linear_values_within_float32_are_written(tmp_path):
    png, npy = tmp_path / "r.png", tmp_path / "r.npy"
    result, _ = _run([*RENDER, "--brdf", "1e30,1e30,0.8,1.5", "-o", str(png),
                      "--linear", str(npy)])
    assert result.exit_code == 0, result.output
    image = np.load(npy)
    assert image.dtype == np.float32 and np.all(np.isfinite(image))
    assert np.nanmax(image) > 1e29


def test_render_without_linear_keeps_working_for_large_coefficients(tmp_path):
    result, _ = _run([*RENDER, "--brdf", "1e40,1e40,0.8,1.5", "-o", str(tmp_path / "r.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "r.png").exists()


# -- veil simulate: values beyond float64 ----------------------------------------------------
@pytest.mark.parametrize("args, flag", [
    (["--brdf", "BRDF1", "--medium", "BTDF2", "--accuracy", "fast", "--glow", "1e308",
      "--black", "b.csv"], "--glow 1e+308"),
    (["--brdf", "BRDF1", "--medium", "none", "--noise", "1e306"], "--noise 1e+306"),
    (["--brdf", "1.7e308,1.7e308,0.8,1.5", "--medium", "none", "--noise", "0.9"],
     "--brdf 1.7e308,1.7e308,0.8,1.5"),
    (["--brdf", "BRDF1", "--medium", "none", "--channels", "r,g", "--per-channel",
      "Pd=1,1.7e308", "--noise", "0.9"], "--per-channel Pd=1,1.7e308"),
])
def test_simulate_overflow_names_the_option(tmp_path, monkeypatch, args, flag):
    monkeypatch.chdir(tmp_path)
    result, warned = _run(["simulate", "--psi", "60", "-o", "a.csv", *args])
    assert result.exit_code == 2, result.output
    assert flag in result.output and "overflow" in result.output
    assert "index label" not in result.output and "RuntimeWarning" not in result.output
    assert not warned, [str(w.message) for w in warned]
    assert list(tmp_path.iterdir()) == []


def test_simulate_overflow_blames_the_channel_that_overflows(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result, _ = _run(["simulate", "--psi", "60", "-o", "a.csv", "--brdf", "BRDF1",
                      "--medium", "none", "--channels", "r,g", "--per-channel",
                      "Pd=1,1.7e308", "--noise", "0.9"])
    assert "channel g: Pd = 1.7e+308" in result.output
    assert "channel r" not in result.output


@pytest.mark.parametrize("kwargs, medium, argument", [
    ({"noise": 1e306}, None, "noise"),
    ({"glow": 1e308}, "BTDF2", "glow"),
])
def test_simulate_api_overflow_names_the_argument(kwargs, medium, argument):
    from veil.data.simulate import SimulatedOverflowError, simulate

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(InputError) as info:
            simulate("BRDF1", medium, psi=(60,), accuracy="fast", **kwargs)
    assert isinstance(info.value, SimulatedOverflowError)
    assert info.value.argument == argument
    assert str(info.value).startswith(f"{argument} = ") and "overflow" in str(info.value)
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]


def test_simulate_api_brdf_overflow_names_the_coefficients():
    import veil
    from veil.data.simulate import simulate

    big = veil.TorranceSparrow(Pd=1.7e308, Ps=1.7e308, n=0.8, eta=1.5)
    with pytest.raises(InputError, match=r"^brdf = .*Pd = 1\.7e\+308, Ps = 1\.7e\+308"):
        simulate(big, None, psi=(60,), noise=0.9)
    # a noise above 1 is not blamed when the noise-free values are already at the top
    with pytest.raises(InputError, match=r"^brdf = .*give the object smaller coefficients"):
        simulate(big, None, psi=(60,), noise=2.0)
    with pytest.raises(InputError, match=r"^noise = 1e\+306: "):
        simulate(veil.BRDF1, None, psi=(60,), noise=1e306)


def test_simulate_large_but_finite_values_are_written(tmp_path):
    out = tmp_path / "a.csv"
    result, warned = _run(["simulate", "--psi", "60", "-o", str(out), "--brdf",
                           "1e300,1e300,0.8,1.5", "--medium", "none", "--noise", "0.01"])
    assert result.exit_code == 0, result.output
    from veil.data.measurements import load_measurements

    table = load_measurements(out)
    assert np.all(np.isfinite(table["value"])) and table["value"].max() > 1e299
    assert not warned


# -- an empty channel cell -------------------------------------------------------------------
TABLE = "psi,rho,channel,value\n60,0,r,1\n60,5,r,2\n60,0,g,3\n60,5,g,4\n"


@pytest.mark.parametrize("cell", ["", "  "])
def test_empty_channel_cell_is_called_empty(tmp_path, cell):
    from veil.data.measurements import load_measurements

    path = tmp_path / "t.csv"
    path.write_text(TABLE.replace("60,5,r,2", f"60,5,{cell},2"))
    with pytest.raises(MeasurementError) as info:
        load_measurements(path)
    message = str(info.value)
    assert f"line 3 of {path}, column 'channel': empty" in message
    assert "nan" not in message.lower()
    result, _ = _run(["fit", "reference", str(path), "-o", str(tmp_path / "x.json")])
    assert result.exit_code == 2, result.output
    assert "line 3 of" in result.output and "'channel': empty" in result.output


def test_empty_channel_cell_of_a_dataframe_is_called_empty():
    import pandas as pd

    from veil.data.measurements import validate

    table = pd.DataFrame({"psi": [60.0] * 4, "rho": [0.0, 5.0, 0.0, 5.0],
                          "channel": ["r", None, "g", pd.NA], "value": [1.0] * 4})
    with pytest.raises(MeasurementError) as info:
        validate(table)
    assert "row 1 (index label) of the table, column 'channel': empty" in str(info.value)
    assert "row 3 (index label) of the table, column 'channel': empty" in str(info.value)


def test_a_blank_pass_through_cell_keeps_the_rows_aligned(tmp_path):
    """A cell of blanks in the only pass-through column was read as a blank line and
    skipped, shifting the column's later rows up by one."""
    from veil.data.measurements import load_measurements

    path = tmp_path / "t.csv"
    path.write_text("psi,rho,value,note\n60,0,1,a\n60,5,2,  \n60,10,3,c\n")
    table = load_measurements(path)
    assert table["note"].tolist()[0] == "a" and table["note"].tolist()[2] == "c"
    assert table["value"].tolist() == [1.0, 2.0, 3.0]


# -- a result that did not converge: exported and rendered with a word, not silently ------
def test_export_and_render_of_an_unconverged_fit_say_so(tmp_path):
    import json

    import veil

    table = tmp_path / "ref.csv"
    veil.save_measurements(veil.simulate(veil.BRDF1, None, fine_step=5, coarse_step=15,
                                         seed=4), table)
    fitted = CliRunner().invoke(main, ["fit", "reference", str(table), "-o",
                                       str(tmp_path / "ref.json")])
    assert fitted.exit_code == 0, fitted.output
    data = json.loads((tmp_path / "ref.json").read_text())
    data["converged"] = False
    (tmp_path / "bad.json").write_text(json.dumps(data))
    for name in ("ref", "bad"):
        out = tmp_path / f"{name}.pbrt"
        done = CliRunner().invoke(main, ["export", str(tmp_path / f"{name}.json"), "--to",
                                         "pbrt", "-o", str(out)])
        assert done.exit_code == 0, done.output
        said = "did not converge" in done.output
        written = "not converged" in out.read_text()
        assert said == written == (name == "bad"), (name, done.output)
        assert f"wrote pbrt to {out}" in done.output  # (was "wrote pbrt pbrt to")
    # a scale whose reciprocal overflows is the option's fault, not the model's
    tiny = CliRunner().invoke(main, ["export", str(tmp_path / "ref.json"), "--to", "mitsuba",
                                     "--scale", "1e-320", "-o", str(tmp_path / "t.xml")])
    assert tiny.exit_code == 2 and "--scale" in tiny.output, tiny.output
    assert "counterpart" not in tiny.output and not (tmp_path / "t.xml").exists()
    shown = CliRunner().invoke(main, ["render", "--brdf", str(tmp_path / "bad.json"),
                                      "--size", "16", "-o", str(tmp_path / "bad.png")])
    assert shown.exit_code == 0 and "did not converge" in shown.output, shown.output
