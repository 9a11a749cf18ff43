"""Colour out of veil (issue 30, item 5; docs/interop.md "Colour", docs/channels.md): a
result fitted over the channels r, g, b exported as one RGB material and medium (Mitsuba 3
``rgb``, pbrt-v4 RGB spectra) whose per-channel values are the channels' own, checked
channel by channel by rendering; the MERL reader's three channels; colour renders.

Expected values come from the definitions in docs/interop.md (rho / ks, tau / path length,
the MERL scales), computed here from the models' parameters."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from support.cli import run

import veil
from veil.fitting.channel_fit import channel_layout
from veil.fitting.result import FitResult
from veil.models import model_class
from veil.models.renderers import Plugin, Unsupported, Value

PLASTIC = model_class("rough-plastic")
CONDUCTOR = model_class("rough-conductor")
SERIES = model_class("forward-series")
RGB = ("r", "g", "b")


def channel_result(models: dict, path, channels_key=True):
    """A result file of a fit over the channels of ``models`` ({channel: model}, one
    family), its parameters named as a multi-channel fit names them (``rho[r]``, ``alpha``)."""
    first = next(iter(models.values()))
    cls = type(first)
    slots, layout = channel_layout(cls, list(models), cls.KIND)
    params: dict = {}
    for s in slots:
        owners = list(models) if s.owner == "*" else [s.owner]
        values = {models[c].as_dict()[s.spec.name] for c in owners}
        assert len(values) == 1, f"{s.name} is shared but differs"
        params[s.name] = values.pop()
    FitResult(model=cls.NAME, params=params, stderr={k: None for k in params},
              correlation={}, residuals=(0.0,), chi2_reduced=1.0, rms_relative=0.01,
              n_points=10, converged=True, message="", options=first.options(),
              channels=layout if channels_key else None).to_json(path)
    return path


def _plates():
    return {c: PLASTIC(rho=r, alpha=0.1, eta=1.5, ks=k)
            for c, r, k in zip(RGB, (0.5, 0.8, 1.2), (2.0, 2.0, 1.6))}


def _waters():
    return {c: SERIES(tau=t, omega=w, g=0.9, path_length=15.0, plate_width=5.0)
            for c, t, w in zip(RGB, (0.45, 0.3, 0.15), (0.95, 0.97, 0.99))}


def _xml_rgb(text: str, name: str) -> list[float]:
    found = re.search(rf'<rgb name="{name}" value="([^"]+)"/>', text) or re.search(
        rf'<texture type="srgb" name="{name}"><rgb name="color" value="([^"]+)"/>', text)
    assert found, name
    return [float(x) for x in found.group(1).split(",")]


# -- the scene text -------------------------------------------------------------------------

def test_rgb_export_values_are_each_channels_own(tmp_path):
    plates, waters = _plates(), _waters()
    plate = channel_result(plates, tmp_path / "plate.json")
    water = channel_result(waters, tmp_path / "water.json")
    out = run("export", plate, water, "--to", "mitsuba", "-o", tmp_path / "s.xml")
    assert out.exit_code == 0, out.output
    text = (tmp_path / "s.xml").read_text()
    # each channel divided by its own specular scale: the interface is physical in each
    assert _xml_rgb(text, "diffuse_reflectance") == [plates[c].rho / plates[c].ks for c in RGB]
    assert '<float name="specular_reflectance" value="1.0"/>' in text
    assert '<float name="alpha" value="0.1"/>' in text    # shared: one number
    assert _xml_rgb(text, "sigma_t") == pytest.approx([waters[c].tau / 15.0 for c in RGB],
                                                      rel=1e-15)
    assert _xml_rgb(text, "albedo") == [0.95, 0.97, 0.99]
    assert "r 2.0, g 2.0, b 1.6" in text and "1.6" in out.output
    # the dict form loads the same values
    out = run("export", plate, water, "--to", "mitsuba", "--format", "dict", "-o",
              tmp_path / "s.py")
    space: dict = {}
    exec((tmp_path / "s.py").read_text(), space)
    bsdf = space["scene"]["veil_material"]
    diffuse = [plates[c].rho / plates[c].ks for c in RGB]
    assert bsdf["diffuse_reflectance"] == {"type": "rgb", "value": diffuse}
    assert space["scene"]["veil_medium"]["albedo"]["value"] == [0.95, 0.97, 0.99]
    # pbrt-v4: RGB spectra; sigma_a + sigma_s = sigma_t and sigma_s / sigma_t = omega per channel
    ggx = {c: m.replace(distribution="ggx") for c, m in plates.items()}
    out = run("export", channel_result(ggx, tmp_path / "ggx.json"), water, "--to", "pbrt",
              "-o", tmp_path / "s.pbrt")
    assert out.exit_code == 0, out.output
    pbrt = (tmp_path / "s.pbrt").read_text()

    def rgb(name):
        return [float(x) for x in pbrt.split(f'"rgb {name}" [ ')[1].split(" ]")[0].split()]

    assert rgb("reflectance") == diffuse
    sa, ss = np.array(rgb("sigma_a")), np.array(rgb("sigma_s"))
    np.testing.assert_allclose(sa + ss, [0.03, 0.02, 0.01], rtol=1e-14)
    np.testing.assert_allclose(ss / (sa + ss), [0.95, 0.97, 0.99], rtol=1e-14)


def test_rgb_export_above_one_and_conductor_spectra(tmp_path):
    """A diffuse value above 1 is an unbounded sRGB texture in Mitsuba (its plain rgb is a
    reflectance, refused above 1); a conductor's n, k become RGB spectra in pbrt."""
    from veil.interop.colour import export_colour

    plates = {c: PLASTIC(rho=r, alpha=0.2, eta=1.4, ks=1.0) for c, r in zip(RGB, (0.3, 0.9, 1.3))}
    text = export_colour({c: [m] for c, m in plates.items()}).text
    assert ('<texture type="srgb" name="diffuse_reflectance"><rgb name="color" '
            'value="0.3, 0.9, 1.3"/><boolean name="unbounded" value="true"/></texture>') in text
    assert "channel b: rho / scale = 1.3 > 1 is not a physical albedo" in text
    metals = {c: CONDUCTOR(alpha=0.2, n=n, k=k, ks=1.0, distribution="ggx")
              for c, n, k in zip(RGB, (0.2, 0.9, 1.1), (3.0, 2.5, 2.0))}
    pbrt = export_colour({c: [m] for c, m in metals.items()}, "pbrt").text
    assert '"rgb eta" [ 0.2 0.9 1.1 ]' in pbrt and '"rgb k" [ 3.0 2.5 2.0 ]' in pbrt


@pytest.mark.slow
def test_torrance_sparrow_colour_becomes_one_closest_rough_plastic(tmp_path):
    """The paper's BRDF1 with P_d per channel: the closest rough plastic is fitted to the
    three channels at once, so its roughness and index are one number in the file (measured:
    alpha 0.0216, eta 1.385; 10.2-10.3 % RMS in f_r per channel, as BRDF1 alone)."""
    ts = {c: veil.BRDF1.replace(Pd=p) for c, p in zip(RGB, (400.0, 1000.0, 2500.0))}
    out = run("export", channel_result(ts, tmp_path / "ts.json"), "--to", "mitsuba", "-o",
              tmp_path / "ts.xml")
    assert out.exit_code == 0, out.output
    rms = [float(out.output.split(f"channel {c}: rough-plastic fitted")[1]
                 .split("in f_r ")[1].split(" %")[0]) for c in RGB]
    assert all(5 < r < 15 for r in rms), rms
    text = (tmp_path / "ts.xml").read_text()
    closest = re.findall(r"closest rough-plastic: RoughPlastic\(rho=([^,]+), alpha=([^,]+), "
                         r"eta=([^,]+), ks=([^,]+),", text)
    assert len(closest) == 3 and len({(a, e) for _, a, e, _ in closest}) == 1
    rho = [float(r) / float(k) for r, _, _, k in closest]
    assert _xml_rgb(text, "diffuse_reflectance") == pytest.approx(rho, rel=1e-5)
    assert rho[0] < rho[1] < rho[2]


def test_a_value_the_renderer_takes_once_must_be_shared():
    from veil.interop.colour import merge_plugins

    per = {c: Plugin("bsdf", "roughplastic", (Value("alpha", "float", a),
                                              Value("diffuse_reflectance", "float", 0.5, True)))
           for c, a in zip(RGB, (0.1, 0.1, 0.2))}
    with pytest.raises(Unsupported, match="takes one alpha for every colour.*b 0.2"):
        merge_plugins(per, "mitsuba")


def test_rgb_export_bad_input(tmp_path):
    plate = channel_result(_plates(), tmp_path / "plate.json")
    # wavelength channels are not the renderer's RGB
    waves = channel_result({"450": _plates()["b"], "550": _plates()["g"]}, tmp_path / "w.json")
    out = run("export", waves, "--to", "mitsuba", "-o", tmp_path / "x.xml")
    assert out.exit_code == 2
    assert "w.json: channels 450, 550" in out.output and "--channel NAME" in out.output
    # two results of different channels: both named
    out = run("export", plate, channel_result({c: _waters()[c] for c in "rg"},
                                              tmp_path / "rg.json"),
              "--to", "mitsuba", "-o", tmp_path / "x.xml")
    assert out.exit_code == 2 and "plate.json is a fit of channels r, g, b" in out.output
    assert "rg.json" in out.output
    out = run("export", plate, "--channel", "450", "--to", "mitsuba", "-o", tmp_path / "x.xml")
    assert out.exit_code == 2 and "has no channel '450'" in out.output
    # the input is never the output
    before = plate.read_bytes()
    out = run("export", plate, "--to", "mitsuba", "-o", plate)
    assert out.exit_code == 2 and plate.read_bytes() == before
    assert not (tmp_path / "x.xml").exists()


def test_one_channel_of_a_colour_result_and_a_grey_medium(tmp_path):
    plates = _plates()
    plate = channel_result(plates, tmp_path / "plate.json")
    out = run("export", plate, "--channel", "g", "--to", "mitsuba", "-o", tmp_path / "g.xml")
    assert out.exit_code == 0, out.output
    one = veil.interop.export.export([plates["g"]], "mitsuba").text
    assert (tmp_path / "g.xml").read_text().split("<scene")[1] == one.split("<scene")[1]
    # a medium of one channel beside a plate of three: every channel's medium
    grey = tmp_path / "grey.json"
    FitResult(model=SERIES.NAME, params=_waters()["g"].as_dict(),
              stderr={k: None for k in _waters()["g"].as_dict()}, correlation={},
              residuals=(0.0,), chi2_reduced=1.0, rms_relative=0.01, n_points=10,
              converged=True, message="", options=_waters()["g"].options()).to_json(grey)
    out = run("export", plate, grey, "--to", "mitsuba", "-o", tmp_path / "s.xml")
    assert out.exit_code == 0, out.output
    assert "grey.json is a fit of one channel: its model is every channel's" in out.output
    text = (tmp_path / "s.xml").read_text()
    assert f'<float name="sigma_t" value="{0.3 / 15.0!r}"/>' in text


def test_rgb_csv_curves(tmp_path):
    plates = _plates()
    out = run("export", channel_result(plates, tmp_path / "plate.json"), "--to", "csv",
              "-o", tmp_path / "c.csv", "--psi", "60")
    assert out.exit_code == 0, out.output
    table = pd.read_csv(tmp_path / "c.csv")
    assert list(table["channel"].unique()) == list(RGB)
    cols = ["theta_i", "theta_r", "phi_i", "phi_r"]
    for c in RGB:
        part = table[table["channel"] == c]
        np.testing.assert_allclose(part["value"],
                                   veil.reflectance(plates[c], *part[cols].to_numpy().T),
                                   rtol=1e-14)


# -- rendered by Mitsuba, channel by channel ----------------------------------------------------

@pytest.fixture(scope="module")
def mi():
    return pytest.importorskip("mitsuba")


def test_verify_each_channel_and_catch_a_wrong_one(mi):
    """Each channel of one render against veil's curve of that channel: the plastic within
    Mitsuba's known F_int difference (1.5-1.7 % RMS measured), the conductor to float32
    (7e-7); a conductor whose green index is written wrong fails in green alone."""
    from veil.data.protocol import protocol
    from veil.interop.colour import export_colour
    from veil.interop.verify import verify_channels

    cfg = protocol((30, 90), fine_step=5.0, coarse_step=20.0)[
        ["theta_i", "theta_r", "phi_i", "phi_r"]].to_numpy()
    plates = _plates()
    done = export_colour({c: [m] for c, m in plates.items()})
    checks = verify_channels(done.text, done.scales,
                             {c: veil.reflectance(m, *cfg.T) for c, m in plates.items()}, cfg)
    for c in RGB:
        assert 0.005 < checks[c].rms_relative < 0.02 and checks[c].max_relative < 0.022
    metals = {c: CONDUCTOR(alpha=0.1, n=n, k=k, ks=s)
              for c, n, k, s in zip(RGB, (0.2, 0.9, 1.1), (3.0, 2.5, 2.0), (3.0, 2.0, 1.0))}
    done = export_colour({c: [m] for c, m in metals.items()})
    predicted = {c: veil.reflectance(m, *cfg.T) for c, m in metals.items()}
    checks = verify_channels(done.text, done.scales, predicted, cfg)
    assert all(checks[c].rms_relative < 1e-5 for c in RGB)
    # the renders differ per channel as veil's curves do (not one channel copied)
    peak = int(np.argmax(predicted["r"]))
    seen = np.array([checks[c].rendered[peak] / done.scales[c] for c in RGB])
    assert np.ptp(seen) > 0.05 * seen.max()
    assert _xml_rgb(done.text, "eta") == [0.2, 0.9, 1.1]
    wrong = done.text.replace('value="0.2, 0.9, 1.1"', 'value="0.2, 0.6, 1.1"')
    assert wrong.count("0.2, 0.6, 1.1") == 1
    checks = verify_channels(wrong, done.scales, predicted, cfg)
    assert checks["g"].rms_relative > 0.05
    assert checks["r"].rms_relative < 1e-5 and checks["b"].rms_relative < 1e-5


def test_cli_verify_prints_each_channel(mi, tmp_path):
    out = run("export", channel_result(_plates(), tmp_path / "plate.json"), "--to", "mitsuba",
              "-o", tmp_path / "p.xml", "--verify", "--psi", "60")
    assert out.exit_code == 0, out.output
    rms = {c: float(out.output.split(f"channel {c}: Mitsuba")[1].split("from veil ")[1]
                    .split(" %")[0]) for c in RGB}
    assert all(0.3 < v < 2.2 for v in rms.values()), rms


# -- MERL: the three channels ------------------------------------------------------------------

#: Raw values of a Lambertian MERL file, one per channel.
LAMBERT = {"r": 300.0, "g": 500.0, "b": 200.0}


def _lambert(tmp_path):
    from veil.data import merl

    path = tmp_path / "lambert.binary"
    merl.write_merl(path, np.stack([np.full((90, 90, 180), LAMBERT[c]) for c in RGB]))
    return path


def test_merl_channels_table_is_the_three_channels(tmp_path):
    from veil.data import merl

    data = np.stack([np.full((90, 90, 180), 1000.0 + 100 * k) for k in range(3)])
    data[:, 47, 25, 179] += [1.0, 2.0, 3.0]   # theta_i 0, theta_r 51 deg in the plane
    merl.write_merl(tmp_path / "m.binary", data)
    brdf = merl.read_merl(tmp_path / "m.binary")
    table = merl.channels_table(brdf, sampling="inplane")
    assert list(table.columns[-3:]) == ["channel", "value", "sigma"]
    assert list(dict.fromkeys(table["channel"])) == list(RGB) and len(table) == 3 * 18 * 35
    for k, c in enumerate(RGB):
        part = table[table["channel"] == c]
        one = merl.measurement_table(brdf, c, "inplane")
        np.testing.assert_array_equal(part["value"].to_numpy(), one["value"].to_numpy())
        # the hand-computed cell of that channel (tests/test_interop.py's index formulas)
        assert float(merl.reflectance(brdf, c, 0.0, 51.0)) == pytest.approx(
            (1000 + 100 * k + 1 + k) * merl.SCALES[c], rel=1e-15)
    with pytest.raises(veil.errors.InputError, match="a MERL file has the channels r, g, b"):
        merl.channels_table(brdf, ["r", "450"])


def test_a_merl_channel_out_of_range_names_the_file_and_channel(tmp_path):
    """A MERL file whose blue channel is 1e-150 of the others: the message named neither
    the file ("row 10 (index label) of the reference (clear medium) table") nor the
    channel, and told to rescale the whole table."""
    from veil.data import merl

    data = np.stack([np.full((90, 90, 180), LAMBERT[c]) for c in RGB])
    data[2] *= 1e-150
    merl.write_merl(tmp_path / "dim.binary", data)
    out = run("fit", "reference", "--merl", tmp_path / "dim.binary", "-o", tmp_path / "x.json")
    assert out.exit_code == 2, out.output
    text = " ".join(out.output.split())
    assert "the table sampled from" in text and "dim.binary, column 'value' of channel 'b'" in text
    assert "rescale the rows of channel 'b'" in text and not (tmp_path / "x.json").exists()


def test_fit_reference_from_merl_fits_the_three_channels(tmp_path):
    out = run("fit", "reference", "--merl", _lambert(tmp_path), "--sampling", "inplane",
              "-o", tmp_path / "rgb.json")
    assert out.exit_code == 0, out.output
    result = veil.fitting.result.load_result(tmp_path / "rgb.json")
    assert result.channel_names == RGB and result.n_points == 3 * 18 * 35
    from veil.data.merl import SCALES

    for c in RGB:   # the paper's Pd: f_r = Pd cos theta_i, the specular part vanishing
        assert result.params[f"Pd[{c}]"] == pytest.approx(LAMBERT[c] * SCALES[c], rel=1e-6)
    # one channel as before
    out = run("fit", "reference", "--merl", _lambert(tmp_path), "--channel", "b",
              "--sampling", "inplane", "-o", tmp_path / "b.json")
    b = veil.fitting.result.load_result(tmp_path / "b.json")
    assert b.channels is None and b.params["Pd"] == pytest.approx(200 * SCALES["b"], rel=1e-6)


def test_simulate_from_merl_channels(tmp_path):
    out = run("simulate", "--merl", _lambert(tmp_path), "--channels", "r,g,b", "--medium",
              "none", "--noise", "0", "--psi", "60", "-o", tmp_path / "s.csv")
    assert out.exit_code == 0, out.output
    assert "channels r, g, b fitted at once" in out.output
    table = pd.read_csv(tmp_path / "s.csv")
    from veil.data.merl import SCALES

    v = {c: table.loc[table["channel"] == c, "value"].to_numpy() for c in RGB}
    for c in RGB:
        np.testing.assert_allclose(v[c] / v["g"], LAMBERT[c] * SCALES[c]
                                   / (LAMBERT["g"] * SCALES["g"]), rtol=1e-5)
    out = run("simulate", "--merl", _lambert(tmp_path), "--channels", "r,550", "--medium",
              "none", "-o", tmp_path / "x.csv")
    assert out.exit_code == 2 and "lambert.binary: channels r, 550" in out.output


# -- veil render in colour ---------------------------------------------------------------------

def test_colour_render_is_each_channels_sphere(tmp_path):
    """Each channel of the RGB image is the sphere under that channel's model (the same
    numbers as a grey render of it); the channels differ as the models do."""
    from PIL import Image

    from veil.viz.render import render

    plates = _plates()
    plate = channel_result(plates, tmp_path / "plate.json")
    out = run("render", "--brdf", plate, "--size", "32", "--quiet", "-o", tmp_path / "c.png",
              "--linear", tmp_path / "c.npy")
    assert out.exit_code == 0, out.output
    assert "channel b: RoughPlastic(rho=1.2" in out.output and "median lit luminance" in out.output
    image = np.load(tmp_path / "c.npy")
    assert image.shape == (32, 32, 3)
    for k, c in enumerate(RGB):
        np.testing.assert_array_equal(image[..., k],
                                      render(plates[c], None, size=32).image.astype(np.float32))
    png = Image.open(tmp_path / "c.png")
    assert png.mode == "RGB" and png.size == (32, 32)
    rgb = np.asarray(png).reshape(-1, 3)
    assert np.ptp(rgb.mean(axis=0)) > 10      # coloured, not grey
    # one channel of the result: the grey render of that channel's model
    out = run("render", "--brdf", plate, "--channel", "b", "--size", "32", "--quiet", "-o",
              tmp_path / "b.png", "--linear", tmp_path / "b.npy")
    assert out.exit_code == 0, out.output
    np.testing.assert_array_equal(np.load(tmp_path / "b.npy"), image[..., 2])
    assert Image.open(tmp_path / "b.png").mode == "L"


def test_colour_render_bad_input(tmp_path):
    waves = channel_result({"450": _plates()["b"], "550": _plates()["g"]}, tmp_path / "w.json")
    out = run("render", "--brdf", waves, "--size", "16", "-o", tmp_path / "x.png")
    assert out.exit_code == 2 and "needs the channels r, g, b; got 450, 550" in out.output
    out = run("render", "--brdf", "BRDF1", "--channel", "r", "-o", tmp_path / "x.png")
    assert out.exit_code == 2 and "--channel r" in out.output
    water = channel_result(_waters(), tmp_path / "water.json")
    out = run("render", "--brdf", water, "-o", tmp_path / "x.png")
    assert out.exit_code == 2 and "a medium result; expected a BRDF result" in out.output
    assert not (tmp_path / "x.png").exists()


# -- veil explore in colour --------------------------------------------------------------------

def test_explore_draws_each_channel_in_its_colour(tmp_path):
    """A result fitted over r, g, b: one curve per channel (the channel's own f_r), the
    controls edit one channel, a shared parameter follows in every channel and a per-channel
    one does not, the sphere is the colour sphere, the shared state reopens."""
    pytest.importorskip("panel")
    from veil.cli.explore_cmd import load_inputs
    from veil.viz import explore as ex
    from veil.viz.explore_page import ExplorePage

    plates = _plates()
    state, _ = load_inputs([channel_result(plates, tmp_path / "plate.json")], None, None)
    assert list(state.channels) == list(RGB) and state.channel == "r"
    page = ExplorePage(state.with_model(None, "medium"), share_dir=tmp_path, background=False)

    def plotted(c):
        data = page.views.channels.src[c].data
        x = np.asarray(data["x"])
        ti, pi_, tr, pr = ex.curve_angles("incidence", state.theta_i, state.psi, x)
        return np.asarray(data["clear"]), ti, tr, pi_, pr

    for c in RGB:
        y, ti, tr, pi_, pr = plotted(c)
        np.testing.assert_allclose(y, veil.reflectance(plates[c], ti, tr, pi_, pr), rtol=1e-12)
    assert ex.channel_colour("r") != ex.channel_colour("b")
    # a shared parameter (the roughness) moves every channel; a per-channel one (rho) one
    cls = type(plates["r"])
    shared = next(n for n, s in cls.channel_sharing().items() if s == "shared")
    own = next(n for n, s in cls.channel_sharing().items() if s == "per-channel")
    for name, factor in ((shared, 1.5), (own, 2.0)):
        slider, spec = page.brdf.sliders[name]
        slider.value = spec.to_slider(getattr(plates["r"], name) * factor)
    now = {c: page.state.channels[c][0] for c in RGB}
    for c in RGB:
        assert getattr(now[c], shared) == pytest.approx(1.5 * getattr(plates[c], shared))
        assert getattr(now[c], own) == pytest.approx(
            getattr(plates[c], own) * (2.0 if c == "r" else 1.0))
        y, ti, tr, pi_, pr = plotted(c)
        np.testing.assert_allclose(y, veil.reflectance(now[c], ti, tr, pi_, pr), rtol=1e-12)
    # the controls switch to channel b: its own value on the per-channel slider
    page.channel.value = "b"
    slider, spec = page.brdf.sliders[own]
    assert page.state.brdf == now["b"]
    assert spec.to_value(slider.value) == pytest.approx(getattr(plates["b"], own), rel=1e-3)
    # the sphere in colour: each channel's sphere, distinct channels
    image = page.views.src["sphere"].data["image"][0]
    want, linear = ex.sphere_colour(state.with_model(None, "medium").channels, state.theta_i)
    np.testing.assert_array_equal(image, want)
    assert linear.shape[-1] == 3 and np.ptp(linear.reshape(-1, 3).mean(axis=0)) > 0.01
    written = page.on_share()
    again = ex.State.load(written)
    assert again.channels == page.state.channels and again.channel == "b"


def test_explore_colour_refusals(tmp_path):
    pytest.importorskip("panel")
    plate = channel_result(_plates(), tmp_path / "plate.json")
    table = tmp_path / "t.csv"
    table.write_text("theta_i,theta_r,value\n10,20,1\n")
    out = run("explore", plate, "--data", table, "--no-browser")
    assert out.exit_code == 2 and "the data panel shows a fit of one channel" in out.output
    out = run("explore", plate, "--static", "-o", tmp_path / "p.html")
    assert out.exit_code == 2 and "--static precomputes one channel's page" in out.output
