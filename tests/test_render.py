"""Rendered spheres (veil.viz.render, `veil render`): geometry, symmetry, the medium's effect on
the highlight, the interpolation error, tone mapping and command-line errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

import veil
from veil.cli import main
from veil.viz.render import (
    VIEW,
    auto_exposure,
    clipping,
    render,
    render_sphere,
    srgb_encode,
    tone_map,
)


# -- independent geometry (not the module's) ---------------------------------------------
def light_vec(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def pixel_normal(size, row, col):
    x = ((col + 0.5) / size * 2 - 1) * VIEW
    y = (1 - (row + 0.5) / size * 2) * VIEW
    return np.array([x, y, math.sqrt(max(0.0, 1 - x * x - y * y))]), x * x + y * y


def mirror_pixel(size, theta, phi):
    """Where N = H = (L + V)/|L + V| lies in the image (fractional row, col)."""
    h = light_vec(theta, phi) + np.array([0.0, 0.0, 1.0])
    h /= np.linalg.norm(h)
    return (1 - h[1] / VIEW) / 2 * size - 0.5, (h[0] / VIEW + 1) / 2 * size - 0.5


def local_config(n, light):
    """theta_i, theta_r, phi_r - phi_i (deg) in the tangent frame of n, camera at +z."""
    v = np.array([0.0, 0.0, 1.0])
    lt, vt = light - (n @ light) * n, v - (n @ v) * n
    cos_d = lt @ vt / (np.linalg.norm(lt) * np.linalg.norm(vt))
    return (math.degrees(math.acos(n @ light)), math.degrees(math.acos(n @ v)),
            math.degrees(math.acos(max(-1.0, min(1.0, cos_d)))))


def brightest(img):
    return np.unravel_index(int(np.argmax(img)), img.shape)


# -- geometry and the pixel value ------------------------------------------------------
@pytest.mark.parametrize("theta, phi", [(45.0, 0.0), (35.0, 120.0), (60.0, -90.0)])
def test_highlight_of_true_brdf_where_the_mirror_direction_puts_it(theta, phi):
    size = 96
    img = render_sphere("BRDF1", None, theta, phi, size)
    row, col = brightest(img)
    r0, c0 = mirror_pixel(size, theta, phi)
    assert math.hypot(row - r0, col - c0) <= 1.0, (row, col, r0, c0)


def test_clear_medium_pixel_is_f_r_times_cos_theta_i():
    size, theta, phi = 40, 50.0, 30.0
    img = render_sphere("BRDF2", None, theta, phi, size)
    light = light_vec(theta, phi)
    checked = 0
    for row, col in [(20, 20), (10, 25), (30, 12), (22, 31), (5, 20), (20, 35)]:
        n, r2 = pixel_normal(size, row, col)
        if r2 >= 1 or n @ light <= 0:
            continue
        ti, tr, dp = local_config(n, light)
        want = float(veil.reflectance("BRDF2", ti, tr, 0.0, dp)) * math.cos(math.radians(ti))
        assert img[row, col] == pytest.approx(want, rel=1e-9)
        checked += 1
    assert checked >= 4


def test_background_and_unlit_side_are_exactly_zero():
    size = 64
    img = render_sphere("BRDF1", "BTDF2", 60.0, 0.0, size, accuracy="fast")
    c = ((np.arange(size) + 0.5) / size * 2 - 1) * VIEW
    x, y = np.meshgrid(c, -c)
    half = VIEW / size * math.sqrt(2)  # half a pixel diagonal, in sphere radii
    outside = np.sqrt(x * x + y * y) > 1 + half
    assert outside.any() and np.all(img[outside] == 0.0)
    z = np.sqrt(np.clip(1 - x * x - y * y, 0, None))
    cos_i = x * math.sin(math.radians(60)) + z * math.cos(math.radians(60))
    unlit = (np.sqrt(x * x + y * y) < 1) & (cos_i < 0)
    lit = (np.sqrt(x * x + y * y) < 1) & (cos_i > 0)
    assert unlit.sum() > 100 and np.all(img[unlit] == 0.0)
    assert np.all(img[lit] > 0.0)


def test_mirror_symmetry_about_the_plane_of_the_light():
    # light from the top (phi = 90): plane of light and view is x = 0, columns mirror
    clear = render_sphere("BRDF2", None, 40.0, 90.0, 48)
    np.testing.assert_allclose(clear, clear[:, ::-1], rtol=1e-12, atol=0)
    # light from the right (phi = 0): plane y = 0, rows mirror
    murky = render_sphere("BRDF1", "BTDF2", 40.0, 0.0, 48, accuracy="fast")
    np.testing.assert_allclose(murky, murky[::-1, :], rtol=1e-9, atol=0)
    # and it is not trivially symmetric the other way
    assert np.max(np.abs(murky - murky[:, ::-1])) > 0.1 * murky.max()


def test_highlight_grows_wider_and_weaker_as_g_falls():
    size = 64
    imgs = [render("BRDF1", m, 45.0, 0.0, size, accuracy="fast", check=0, density=0.5).image
            for m in ("BTDF1", "BTDF2", "BTDF3")]
    areas = [int(np.count_nonzero(im >= 0.5 * im.max())) for im in imgs]
    contrast = [im.max() / np.median(im[im > 0]) for im in imgs]
    assert areas[0] < areas[1] < areas[2], areas
    assert contrast[0] > contrast[1] > contrast[2], contrast
    assert areas[2] > 4 * areas[0]
    r0, c0 = mirror_pixel(size, 45.0, 0.0)
    row, col = brightest(imgs[0])
    assert math.hypot(row - r0, col - c0) <= 1.5


def test_interpolation_error_is_measured_and_small():
    r = render("BRDF1", "BTDF3", 45.0, 0.0, 64, accuracy="fast", check=48)
    assert r.table_nodes > 500 and r.checked >= 40
    assert r.max_rel_error < 2e-3  # measured ~2e-4
    assert r.max_peak_error < 1e-3
    assert r.max_rel_error_all >= r.max_rel_error
    # independently: the image against direct engine evaluations at a few pixels
    light = light_vec(45.0, 0.0)
    pix = [(32, 45), (20, 40), (40, 30), (32, 32), (25, 50)]
    cfg = []
    for row, col in pix:
        n, _ = pixel_normal(64, row, col)
        cfg.append(local_config(n, light))
    ti, tr, dp = (np.array(a) for a in zip(*cfg))
    direct = veil.apparent("BRDF1", "BTDF3", ti, tr, 0.0, dp, accuracy="fast")
    got = np.array([r.image[p] for p in pix]) / np.cos(np.radians(ti))
    np.testing.assert_allclose(got, direct, rtol=2e-3)


def test_interpolation_error_bound_holds_for_a_light_near_grazing():
    # at 80 deg from the view the lit, visible region reaches grazing angles; the table is
    # refined there and the error at pixels with both angles <= 80 deg stays small
    r = render("BRDF2", "BTDF2", 80.0, 30.0, 48, accuracy="fast", check=64)
    assert r.table_nodes > 3000
    assert r.max_rel_error < 5e-3
    assert r.max_peak_error < 2e-3


def test_bad_arguments_raise_clear_errors():
    with pytest.raises(ValueError, match="light_theta"):
        render_sphere("BRDF1", None, 130.0)
    with pytest.raises(ValueError, match="size"):
        render_sphere("BRDF1", None, 45.0, size=3)
    with pytest.raises(ValueError, match="accuracy"):
        render_sphere("BRDF1", "BTDF1", 45.0, size=16, accuracy="sloppy")
    with pytest.raises(TypeError, match="BRDF"):
        render_sphere("BTDF1", None, 45.0, size=16)


# -- tone mapping ----------------------------------------------------------------------
def test_auto_exposure_maps_median_to_mid_grey_and_clipping_is_counted():
    lin = np.zeros((10, 10))
    lin[:5, :] = np.linspace(1.0, 3.0, 50).reshape(5, 10)
    lin[0, 0] = 100.0  # a highlight
    e = auto_exposure(lin)
    assert e == pytest.approx(0.18 / np.median(lin[lin > 0]))
    u8 = tone_map(lin, e)
    assert u8.dtype == np.uint8 and u8[9, 9] == 0 and u8[0, 0] == 255
    med = np.median(lin[lin > 0])
    k = np.argmin(np.abs(lin - med))
    assert abs(int(u8.flat[k]) - round(255 * float(srgb_encode(0.18)))) <= 2
    n, frac, peak = clipping(lin, e)
    assert n == 1 and frac == pytest.approx(1 / 50) and peak == pytest.approx(100 * e)
    assert clipping(lin, e, "reinhard")[0] == 0 and tone_map(lin, e, "reinhard").max() < 255
    with pytest.raises(ValueError, match="exposure"):
        tone_map(lin, -1.0)


# -- command line ----------------------------------------------------------------------
def read_png(path):
    with Image.open(path) as im:
        return np.asarray(im), dict(im.text)


def test_cli_render_writes_image_linear_values_and_reports_exposure(tmp_path):
    out, lin = tmp_path / "s.png", tmp_path / "s.npy"
    res = CliRunner().invoke(main, ["render", "--brdf", "BRDF1", "--light-theta", "30",
                                    "--light-phi", "90", "--size", "64", "-o", str(out),
                                    "--linear", str(lin), "--quiet"])
    assert res.exit_code == 0, res.output
    img, text = read_png(out)
    values = np.load(lin)
    assert img.shape == (64, 64) and values.shape == (64, 64) and values.dtype == np.float32
    e = float(text["veil:exposure"])
    assert f"exposure {text['veil:exposure']}" in res.output
    assert e == pytest.approx(0.18 / np.median(values[values > 0]), rel=1e-5)
    assert "highlights clip" in res.output  # the true BRDF1 highlight is 100x the body
    np.testing.assert_array_equal(img, tone_map(values.astype(float), e))
    row, col = brightest(values)
    r0, c0 = mirror_pixel(64, 30.0, 90.0)
    assert math.hypot(row - r0, col - c0) <= 1.0
    assert img[row, col] == 255 and img[0, 0] == 0


def test_cli_render_given_exposure_and_reinhard(tmp_path):
    out = tmp_path / "s.png"
    res = CliRunner().invoke(main, ["render", "--brdf", "BRDF2", "--size", "32", "--exposure",
                                    "1e-4", "--tone", "reinhard", "-o", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    assert "exposure 0.0001 (given)" in res.output
    img, text = read_png(out)
    assert text["veil:tone"] == "reinhard" and img.max() < 255


@pytest.mark.parametrize("args, message", [
    (["--brdf", "BRDF9"], "neither a preset"),
    (["--brdf", "BRDF1", "--medium", "BTDF1", "--size", "2"], "size"),
    (["--brdf", "BRDF1", "--light-theta", "200"], "--light-theta 200"),
    (["--brdf", "BRDF1", "--exposure", "-1"], "--exposure"),
    (["--brdf", "BRDF1", "--medium", "0.001,0.1,1.5,1.3"], "outside"),
    (["--brdf", "BTDF1"], "not a BRDF"),
])
def test_cli_render_errors_exit_2(tmp_path, args, message):
    res = CliRunner().invoke(main, ["render", *args, "-o", str(tmp_path / "s.png"), "--quiet"])
    assert res.exit_code == 2, res.output
    assert message in res.output and "Traceback" not in res.output
    assert not (tmp_path / "s.png").exists()


def test_cli_render_output_path_errors_exit_2(tmp_path):
    runner = CliRunner()
    for out, extra, message in [
        (tmp_path / "missing" / "s.png", [], "does not exist"),
        (tmp_path / "s.jpg", [], ".png"),
        (tmp_path, [], ".png"),
        (tmp_path / "s.png", ["--linear", str(tmp_path / "s.txt")], ".npy"),
    ]:
        res = runner.invoke(main, ["render", "--brdf", "BRDF1", "--size", "16", "-o", str(out),
                                   "--quiet", *extra])
        assert res.exit_code == 2, (out, res.output)
        assert message in res.output and "Traceback" not in res.output
