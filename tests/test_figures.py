"""The reproduced experiment (veil.viz.figures, veil.viz.documents, `veil reproduce`, `veil plot`): the
numbers behind figs. 9-12 and the report, read back from the written files."""

from __future__ import annotations

import base64
import csv
import math
import re

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

import veil
from veil.cli import main
from veil.models.fresnel import transmittance
from veil.viz.figures import curve_metrics, fig9, figure_bytes, lobe_data, transmission_data


def fwhm_from_samples(theta, f):
    """Independent half-maximum width: linear crossings either side of the maximum."""
    k = int(np.argmax(f))
    half = f[k] / 2
    j = k
    while f[j] >= half:
        j -= 1
    left = theta[j] + (half - f[j]) / (f[j + 1] - f[j]) * (theta[j + 1] - theta[j])
    j = k
    while f[j] >= half:
        j += 1
    right = theta[j - 1] + (half - f[j - 1]) / (f[j] - f[j - 1]) * (theta[j] - theta[j - 1])
    return right - left


# -- pure functions ----------------------------------------------------------------------
def test_curve_metrics_on_a_gaussian_and_a_flat_curve():
    x = np.linspace(0, 90, 721)
    y = 3 + 100 * np.exp(-0.5 * ((x - 40) / 4.0) ** 2)
    m = curve_metrics(x, y)
    assert m.peak == pytest.approx(103) and m.peak_angle == pytest.approx(40)
    # half maximum 51.5 -> 48.5 above the base: width 2 sigma sqrt(2 ln(100/48.5))
    assert m.fwhm == pytest.approx(2 * 4 * math.sqrt(2 * math.log(100 / 48.5)), rel=2e-3)
    assert m.off_peak == pytest.approx(3.0, abs=1e-6)
    flat = curve_metrics(x, 10 - 0.01 * x)
    assert math.isnan(flat.fwhm)


def test_reflection_lobe_peaks_at_the_mirror_angle():
    for name, width in (("BRDF1", 4.2), ("BRDF2", 6.8)):
        t, f, s, g = lobe_data(name, 45.0)
        assert t[np.argmax(f)] == pytest.approx(45.0, abs=0.4)
        assert s[np.argmax(g)] == pytest.approx(0.0, abs=0.1)
        assert fwhm_from_samples(t, f) == pytest.approx(width, abs=0.1)
        assert f[np.argmin(np.abs(t))] == pytest.approx(veil.preset(name).Pd * math.cos(math.pi / 4))


def test_transmission_lobe_peak_and_widths():
    widths = []
    for name in ("BTDF1", "BTDF2", "BTDF3"):
        m = veil.preset(name)
        beta, f, s, g = transmission_data(m, 45.0)
        assert beta[np.argmax(f)] == pytest.approx(45.0, abs=0.06)
        p0 = (1 + m.g) / (4 * math.pi * (1 - m.g) ** 2)
        ft = float(transmittance(math.cos(math.pi / 4), m.eta))
        assert f.max() == pytest.approx(m.Td + m.Tt * p0 * ft ** 2, rel=1e-6)
        widths.append(fwhm_from_samples(beta, f))
    assert widths[0] < widths[1] < widths[2]
    assert widths[0] == pytest.approx(2 * 0.89, abs=0.1)  # HG half width (1-g) sqrt(0.587/g)


def test_figures_are_byte_for_byte_deterministic():
    import matplotlib.pyplot as plt

    a, b = fig9(), fig9()
    try:
        for fmt in ("png", "pdf"):
            assert figure_bytes(a, fmt) == figure_bytes(b, fmt)
    finally:
        plt.close(a)
        plt.close(b)


# -- veil reproduce ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def repro(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro") / "out"
    res = CliRunner().invoke(main, ["reproduce", "-o", str(out), "--size", "48", "--accuracy",
                                    "fast", "--check", "16", "--quiet"])
    assert res.exit_code == 0, res.output
    return out, res.output


def read_curves(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    head = rows[0]
    data = np.array([[float(x) for x in r] for r in rows[1:]])
    return {h: data[:, k] for k, h in enumerate(head)}


def test_reproduce_writes_figures_as_png_and_pdf(repro):
    out, _ = repro
    for stem in ("fig09_reflection_lobes", "fig10_transmission_lobes", "fig11_observed_values",
                 "fig12_spheres"):
        with Image.open(out / f"{stem}.png") as im:
            w, h = im.size
        assert w >= 1000 and h >= 500
        assert (out / f"{stem}.pdf").read_bytes()[:5] == b"%PDF-"
    for b in ("BRDF1", "BRDF2"):
        for m in ("clear", "BTDF1", "BTDF2", "BTDF3"):
            with Image.open(out / "spheres" / f"{b}_{m}.png") as im:
                assert im.size == (48, 48)
            assert np.load(out / "spheres" / f"{b}_{m}.npy").shape == (48, 48)
    assert not list(out.glob(".*.tmp")), "temporary files left behind"


def test_reproduce_curves_match_the_engine_and_show_the_papers_trends(repro):
    out, _ = repro
    c = read_curves(out / "fig11_curves.csv")
    t = c["theta_r_deg"]
    assert t[0] == 0 and t[-1] == 89 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(c["BRDF1/clear"], veil.reflectance("BRDF1", 45.0, t), rtol=1e-8)
    pick = np.searchsorted(t, [0.0, 45.0, 70.0])
    direct = veil.apparent("BRDF2", "BTDF2", 45.0, t[pick], accuracy="fast")
    np.testing.assert_allclose(c["BRDF2/BTDF2"][pick], direct, rtol=1e-7)
    for b in ("BRDF1", "BRDF2"):
        widths = [fwhm_from_samples(t, c[f"{b}/{m}"]) for m in ("clear", "BTDF1", "BTDF2", "BTDF3")]
        assert widths == sorted(widths) and widths[3] > 5 * widths[0], widths
        # peak relative to the diffuse level (f at 0 deg) falls as g falls
        contrast = [c[f"{b}/{m}"].max() / c[f"{b}/{m}"][0] for m in ("clear", "BTDF1", "BTDF2", "BTDF3")]
        assert contrast == sorted(contrast, reverse=True), contrast
        for m in ("clear", "BTDF1", "BTDF2", "BTDF3"):
            assert 44.5 <= t[np.argmax(c[f"{b}/{m}"])] <= 46.5


def test_report_states_the_measured_numbers(repro):
    out, _ = repro
    md = (out / "report.md").read_text()
    c = read_curves(out / "fig11_curves.csv")
    t = c["theta_r_deg"]
    rows = re.findall(r"^\| (BRDF\d) \| (clear|BTDF\d) \| ([^|]+) \| ([^|]+)° \| ([^|]+)° \|", md, re.M)
    assert len(rows) == 8
    for b, m, peak, at, width in rows:
        f = c[f"{b}/{m}"]
        assert float(peak) == pytest.approx(f.max(), rel=5e-3)
        assert float(at) == t[np.argmax(f)]
        assert float(width) == pytest.approx(fwhm_from_samples(t, f), abs=0.06)
    for needle in ("## Observations", "peak / T_t² decreases", "full width at half maximum increases",
                   "T_d = 0", "grows wider and weaker as g falls", "BTDF1 | 0.001 | 0.01 | 0.98"):
        assert needle in md, needle
    assert "![fig. 12](fig12_spheres.png)" in md


def test_report_html_is_self_contained(repro):
    out, _ = repro
    page = (out / "report.html").read_text()
    sources = re.findall(r'src="([^"]*)"', page)
    assert len(sources) == 4 and all(s.startswith("data:image/png;base64,") for s in sources)
    embedded = {base64.b64decode(s.split(",", 1)[1]) for s in sources}
    assert (out / "fig11_observed_values.png").read_bytes() in embedded
    text = re.sub(r'data:image/png;base64,[A-Za-z0-9+/=]*', "", page)  # base64 may spell "http"
    assert "<table>" in page and "http" not in text.replace("http-equiv", "")


def test_reproduced_spheres_highlight_wider_as_g_falls(repro):
    out, _ = repro
    imgs = [np.load(out / "spheres" / f"BRDF2_{m}.npy") for m in ("clear", "BTDF1", "BTDF2", "BTDF3")]
    areas = [int(np.count_nonzero(i >= 0.5 * i.max())) for i in imgs]
    assert areas == sorted(areas) and areas[3] > areas[0], areas


def test_reproduce_errors_exit_2(tmp_path):
    runner = CliRunner()
    (tmp_path / "file").write_text("x")
    for args, message in [(["-o", str(tmp_path / "file")], "not a directory"),
                          (["-o", str(tmp_path / "no" / "out")], "does not exist"),
                          (["-o", str(tmp_path / "o"), "--size", "4"], "--size")]:
        res = runner.invoke(main, ["reproduce", *args, "--quiet"])
        assert res.exit_code == 2, res.output
        assert message in res.output and "Traceback" not in res.output
    assert (tmp_path / "file").read_text() == "x"


# -- veil plot -----------------------------------------------------------------------------
def test_plot_commands_write_figures(tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["plot", "lobe", "--brdf", "BRDF1", "--brdf", "300,1e5,0.3,1.4",
                               "--theta-i", "30", "-o", str(tmp_path / "lobe.pdf")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "lobe.pdf").read_bytes()[:5] == b"%PDF-"
    res = runner.invoke(main, ["plot", "transmission", "--medium", "BTDF2", "--variant", "exit",
                               "-o", str(tmp_path / "t.png")])
    assert res.exit_code == 0, res.output
    with Image.open(tmp_path / "t.png") as im:
        assert im.size[0] > 1000
    res = runner.invoke(main, ["plot", "curve", "--brdf", "BRDF1", "--medium", "none", "--medium",
                               "BTDF1", "--scale", "peak", "--accuracy", "fast", "-o",
                               str(tmp_path / "c.svg")])
    assert res.exit_code == 0, res.output
    assert "<svg" in (tmp_path / "c.svg").read_text()
    peaks = [float(x) for x in re.findall(r"peak ([0-9.e+-]+) at", res.output)]
    assert peaks[0] == pytest.approx(float(veil.reflectance("BRDF1", 45.0, 45.0)), rel=1e-3)
    assert peaks[1] == pytest.approx(0.842, rel=5e-3)


@pytest.mark.parametrize("args, message", [
    (["lobe", "--brdf", "BRDF1", "-o", "{d}/x.jpg"], ".png"),
    (["lobe", "--brdf", "BRDF1", "--theta-i", "95", "-o", "{d}/x.png"], "--theta-i"),
    (["lobe", "--brdf", "BRDF7", "-o", "{d}/x.png"], "neither a preset"),
    (["transmission", "--medium", "none", "-o", "{d}/x.png"], "no transmission lobe"),
    (["curve", "--brdf", "BRDF1", "--medium", "1,2,3", "-o", "{d}/x.png"], "4 numbers"),
    (["curve", "--brdf", "BRDF1", "-o", "{d}/nodir/x.png"], "does not exist"),
])
def test_plot_errors_exit_2(tmp_path, args, message):
    args = [a.replace("{d}", str(tmp_path)) for a in args]
    res = CliRunner().invoke(main, ["plot", *args])
    assert res.exit_code == 2, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not list(tmp_path.glob("x.*"))
