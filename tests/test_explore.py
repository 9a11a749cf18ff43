"""``veil explore`` without a browser (docs/explore.md): controls from the declarations, the
page's state file, the page's numbers against the engine, a fit with its data, and the
command's answers to bad input. The browser test is tests/test_explore_browser.py."""

from __future__ import annotations

import json
import math
import socket
import webbrowser

import numpy as np
import pytest
from click.testing import CliRunner

import veil
from veil.cli import explore_cmd, main
from veil.data.measurements import save_measurements
from veil.errors import InputError
from veil.fitting import fit_target
from veil.models import REGISTRY, model_class
from veil.viz import explore as ex
from veil.viz import explore_fits as fits

SMALL = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")


# -- controls from the declarations -----------------------------------------------------

@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_one_slider_per_declared_parameter(name):
    cls = model_class(name)
    model = cls.template()
    for p in cls.PARAMS:
        value = getattr(model, p.name)
        spec = ex.slider_spec(cls, p.name, value)
        assert spec.log == p.log_scale
        assert spec.start < spec.end
        # every position of the slider is a valid value of the parameter
        for x in np.linspace(spec.start, spec.end, 7):
            assert p.contains(spec.to_value(x)), (p.name, x, spec)
        assert spec.to_value(spec.to_slider(value)) == pytest.approx(value, rel=1e-12)
        if p.log_scale:
            assert spec.label.startswith("log10 ")
        if math.isfinite(p.upper) and not p.log_scale:
            assert spec.end <= p.upper


def test_log_slider_of_a_zero_value():
    cls = type(veil.BTDF1)
    p = next(p for p in cls.PARAMS if p.log_scale and p.lower == 0 and not p.lower_open)
    spec = ex.slider_spec(cls, p.name, 0.0)
    assert spec.to_slider(0.0) == spec.start
    assert p.contains(spec.to_value(spec.start))


def test_log_slider_spans_decades_around_a_preset():
    cls = type(veil.BRDF1)
    scale = cls.scale_names()[-1]
    value = getattr(veil.BRDF1, scale)
    spec = ex.slider_spec(cls, scale, value)
    assert spec.log
    assert spec.start == pytest.approx(math.log10(value) - ex.LOG_SPAN)
    assert spec.end == pytest.approx(math.log10(value) + ex.LOG_SPAN)


def test_presets_are_read_from_the_registry():
    found = ex.presets_of(type(veil.BRDF1))
    assert "BRDF1" in found and "BTDF1" not in found
    assert ex.families("brdf") == veil.models.names("brdf")


# -- the state file ----------------------------------------------------------------------

def test_state_round_trip(tmp_path):
    state = ex.State(veil.BRDF2, veil.BTDF3, theta_i=30.0, psi=90.0, curve="goniometer")
    path = tmp_path / "state.json"
    state.save(path)
    assert ex.is_state_file(path)
    back = ex.State.load(path)
    assert back.brdf == veil.BRDF2 and back.medium == veil.BTDF3
    assert (back.theta_i, back.psi, back.curve) == (30.0, 90.0, "goniometer")
    clear = ex.State(veil.BRDF1, None)
    assert ex.State.from_dict(clear.to_dict()).medium is None


@pytest.mark.parametrize("change, message", [
    ({"format": "other"}, "not a veil explore state"),
    ({"theta_i": 95.0}, "theta_i"),
    ({"curve": "sideways"}, "curve"),
    ({"brdf": {"model": "no-such", "params": {}}}, "unknown BRDF model"),
    ({"brdf": None}, "a BRDF is required"),
])
def test_bad_state_files_say_what_is_wrong(change, message):
    data = {**ex.State.default().to_dict(), **change}
    with pytest.raises(InputError, match=message):
        ex.State.from_dict(data, "s.json")


def test_bad_parameter_in_a_state_names_it():
    data = ex.State.default().to_dict()
    cls = model_class(data["brdf"]["model"])
    p = next(p for p in cls.PARAMS if math.isfinite(p.upper))
    data["brdf"]["params"][p.name] = p.upper + 1.0
    with pytest.raises(InputError, match=p.name):
        ex.State.from_dict(data, "s.json")


# -- the page's numbers ------------------------------------------------------------------

def test_curve_axes():
    x, name = ex.curve_axis("incidence", 45.0, 60.0)
    assert x.min() == -ex.MAX_ANGLE and x.max() == ex.MAX_ANGLE and "theta_r" in name
    assert np.all(np.diff(x) > 0)
    assert np.any(np.isclose(x, 45.0)) and np.min(np.diff(x)) == pytest.approx(0.1)
    x, name = ex.curve_axis("goniometer", 45.0, 60.0)
    ti, _, tr, _ = ex.curve_angles("goniometer", 45.0, 60.0, x)
    assert np.all(ti < 90) and np.all(tr < 90) and "rho" in name
    # goniometer: theta_i + theta_r (signed) = psi everywhere
    ti, pi_, tr, pr = ex.curve_angles("goniometer", 45.0, 60.0, x)
    signed = np.where(pi_ == 180.0, ti, -ti) + np.where(pr == 0.0, tr, -tr)
    np.testing.assert_allclose(signed, 60.0)
    # every curve fits the engine's one compiled size
    sizes = [ex.curve_axis(c, t, p)[0].size for c in ex.CURVES
             for t in np.arange(0.0, 88.5, 0.5) for p in (0.0, 0.5, 60.0, 175.0)]
    assert max(sizes) <= ex.CURVE_SIZE


def test_clear_curve_and_polar_lobe_are_the_brdf():
    curves = ex.Curves(veil.BRDF1, None, "incidence", 30.0, 60.0)
    ti, pi_, tr, pr = curves.angles
    values = curves.clear(veil.BRDF1)
    np.testing.assert_allclose(values, veil.reflectance(veil.BRDF1, ti, tr, pi_, pr))
    assert curves.through(veil.BRDF1, None) is None
    x, y = ex.polar_lobe(curves.x, values, "incidence", 30.0, 60.0)
    np.testing.assert_allclose(np.hypot(x, y), values)
    k = int(np.argmax(values))
    assert curves.x[k] == pytest.approx(30.0, abs=0.11)  # mirror direction
    assert x[k] > 0  # on the camera's side


def test_transmission_lobe_peaks_forward():
    angle, value, x, y = ex.transmission_lobe(veil.BTDF2, 40.0)
    # f_t(I, w) peaks where w = I: the light's own direction, on the light's side
    assert angle[int(np.argmax(value))] == pytest.approx(-40.0, abs=0.3)
    assert np.all(value > 0)
    r = ex.log_radius(value)
    assert r.max() == 1.0 and r.min() >= 0.0


def test_page_follows_a_slider_as_the_engine_says(tmp_path):
    """The page object without a server: moving a slider redraws the curves with the
    engine's values, and the share button writes the state."""
    from veil.viz.explore_page import ExplorePage

    state = ex.State(veil.BRDF1, veil.BTDF2, theta_i=40.0)
    page = ExplorePage(state, share_dir=tmp_path, background=False)
    cls = type(state.brdf)
    name = next(p.name for p in cls.PARAMS if p.name not in cls.scale_names())
    slider, spec = page.brdf.sliders[name]
    slider.value = spec.to_slider(getattr(state.brdf, name) * 1.5)
    new = page.state.brdf
    assert getattr(new, name) == pytest.approx(getattr(state.brdf, name) * 1.5, rel=1e-9)
    data = page.views.src["medium"].data
    x = np.asarray(data["x"])
    expected = veil.apparent(new, state.medium, 40.0, np.abs(x), 180.0,
                             np.where(x >= 0, 0.0, 180.0), accuracy=ex.LIVE_ACCURACY)
    np.testing.assert_allclose(data["y"], expected, rtol=1e-9)
    assert page.brdf.preset.value == "(custom)"  # moved off the preset
    written = page.on_share()
    assert ex.State.load(written).brdf == new
    # a preset puts every slider back, and the sphere follows it
    page.brdf.preset.value = "BRDF1"
    assert page.state.brdf == veil.BRDF1
    assert slider.value == pytest.approx(spec.to_slider(getattr(veil.BRDF1, name)))
    image = page.views.src["sphere"].data["image"][0]
    np.testing.assert_array_equal(image, ex.sphere(veil.BRDF1, state.medium, 40.0)[0])
    # psi does not move the curve at fixed incidence; the goniometer curve follows it
    before = np.asarray(page.views.src["medium"].data["y"])
    page.psi.value = 90.0
    np.testing.assert_array_equal(page.views.src["medium"].data["y"], before)
    page.curve.value = "goniometer"
    x = np.asarray(page.views.src["medium"].data["x"])
    assert x.max() == pytest.approx(ex.MAX_ANGLE - 45.0)
    ti, pi_, tr, pr = ex.curve_angles("goniometer", 40.0, 90.0, x)
    np.testing.assert_allclose(page.views.src["medium"].data["y"],
                               veil.apparent(veil.BRDF1, state.medium, ti, tr, pi_, pr,
                                             accuracy=ex.LIVE_ACCURACY), rtol=1e-9)


# -- a fit with its data -----------------------------------------------------------------

@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit")
    table = veil.simulate(veil.BRDF1, veil.BTDF1, noise=0.01, seed=31, **SMALL)
    other = veil.simulate(veil.BRDF2, veil.BTDF1, noise=0.01, seed=32, **SMALL)
    result = fit_target(table, veil.BTDF1, accuracy="fast")
    paths = {"result": folder / "target.json", "table": folder / "target.csv",
             "other": folder / "other.csv", "short": folder / "short.csv"}
    result.to_json(paths["result"])
    save_measurements(table, paths["table"])
    save_measurements(other, paths["other"])
    save_measurements(table.iloc[:-3], paths["short"])
    return result, paths


def test_fit_view_draws_data_band_and_residuals(fitted):
    result, paths = fitted
    view = fits.FitView(result, str(paths["table"]), source="target.json")
    assert view.brdf == result.as_model() and view.medium == veil.BTDF1
    np.testing.assert_allclose(view.residuals, result.residuals, rtol=1e-6, atol=1e-9)
    lo, hi = view.band
    assert np.all(lo <= hi) and np.any(hi > lo)
    # the band holds the fitted model for most points
    inside = (view.fitted >= lo * (1 - 1e-9)) & (view.fitted <= hi * (1 + 1e-9))
    assert inside.mean() > 0.9
    assert view.xlabel.startswith("rho") and set(view.group.tolist()) == {30.0, 60.0, 90.0}
    rows = {r["parameter"]: r for r in view.param_rows()}
    assert set(rows) == set(result.params)
    assert all(r["stderr"] > 0 for r in rows.values())


def test_table_of_another_session_is_refused(fitted):
    result, paths = fitted
    with pytest.raises(InputError, match="does not belong"):
        fits.FitView(result, str(paths["other"]), source="target.json", draws=0)
    with pytest.raises(InputError, match="does not belong.*points"):
        fits.FitView(result, str(paths["short"]), source="target.json", draws=0)


def test_cli_with_result_and_foreign_data_exits_2(fitted):
    _, paths = fitted
    run = CliRunner().invoke(main, ["explore", str(paths["result"]), "--data",
                                    str(paths["other"]), "--no-browser"])
    assert run.exit_code == 2, run.output
    assert "belongs to none of the results" in run.output


def test_models_of_a_result(fitted):
    result, paths = fitted
    state, views = explore_cmd.load_inputs([paths["result"]], None, None)
    assert state.brdf == result.as_model() and state.medium == veil.BTDF1
    assert views == []


# -- bad input ---------------------------------------------------------------------------

def _invoke(args):
    return CliRunner().invoke(main, ["explore", *args])


def test_wrong_kind_of_file_exits_2(tmp_path, fitted):
    _, paths = fitted
    junk = tmp_path / "junk.json"
    junk.write_text(json.dumps({"hello": 1}))
    run = _invoke([str(junk), "--no-browser"])
    assert run.exit_code == 2 and "Error" in run.output
    run = _invoke([str(paths["table"]), "--no-browser"])  # a table given as the result
    assert run.exit_code == 2 and "JSON" in run.output
    joint = tmp_path / "joint.json"
    joint.write_text(json.dumps({"format": "veil.fit/2", "model": "joint"}))
    run = _invoke([str(joint), "--no-browser"])
    assert run.exit_code == 2


@pytest.mark.parametrize("args, message", [
    (["--static"], "give -o"),
    (["-o", "x.html"], "-o is for --static"),
    (["--param", "n"], "--param is for --static"),
])
def test_option_mistakes_exit_2(args, message, tmp_path):
    run = _invoke(args)
    assert run.exit_code == 2 and message in run.output


def test_data_without_result_exits_2(fitted):
    _, paths = fitted
    run = _invoke(["--data", str(paths["table"]), "--no-browser"])
    assert run.exit_code == 2 and "give the fit result" in run.output


def test_static_unknown_parameter_exits_2(tmp_path):
    run = _invoke(["--static", "--param", "nonexistent", "-o", str(tmp_path / "p.html")])
    assert run.exit_code == 2 and "not a parameter" in run.output


def test_port_in_use_picks_another_and_says_so():
    said = []
    with socket.socket() as busy:
        busy.bind((explore_cmd.ADDRESS, 0))
        busy.listen()
        taken = busy.getsockname()[1]
        assert not explore_cmd.port_free(taken)
        port = explore_cmd.choose_port(taken, said.append)
    assert port != taken and port > 0
    assert said and f"port {taken} is in use" in said[0] and str(port) in said[0]
    assert explore_cmd.choose_port(0) > 0


def test_no_browser_prints_the_address(monkeypatch):
    def missing(*a, **k):
        raise webbrowser.Error("could not locate runnable browser")

    monkeypatch.setattr(webbrowser, "get", missing)
    said = []
    assert not explore_cmd.open_browser("http://127.0.0.1:1234/", said.append)
    assert "http://127.0.0.1:1234/" in said[0] and "no web browser" in said[0]
