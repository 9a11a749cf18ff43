"""``veil plot lobe|transmission|curve`` at the edges of the models' bounds: zero
coefficients (a lobe that is 0 somewhere or everywhere), huge but finite coefficients, and
curves without a half-maximum crossing. Valid input draws the figure (exit 0, a non-empty
PNG), prints no NaN and lets no raw library warning through; coefficients whose lobe
overflows float64 are the user's to change (exit 2)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from support.cli import run

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def plot(*args):
    """``veil plot ARGS`` in-process, recording every warning that escapes the command (but
    the program store's note that it rebuilds a program made by other code)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run("plot", *args)
    return result, [w for w in caught if not issubclass(w.category, DeprecationWarning)
                    and "stored engine program" not in str(w.message)]


def assert_drawn(result, escaped, out) -> None:
    """Exit 0, a real PNG at ``out``, no NaN/inf in what was printed, no raw warning."""
    assert result.exit_code == 0, result.output
    assert "internal error" not in result.output
    data = out.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 5000
    words = result.output.lower().replace(",", " ").split()
    assert "nan" not in words and "inf" not in words, result.output
    assert not escaped, [str(w.message) for w in escaped]
    assert "UserWarning" not in result.output and "RuntimeWarning" not in result.output


# -- defects 1, 4: Pd = 0 and huge coefficients -----------------------------------------
@pytest.mark.parametrize(
    "brdf",
    [
        "0,5e5,0.8,1.5",  # Pd = 0: f_r falls to 0 far from the mirror direction
        "0,5e5,50,1.5",  # Pd = 0 and the narrowest lobe: 0 almost everywhere
        "1e40,1e40,0.8,1.5",  # 10 ** 39 as a Python int broke matplotlib's limits
        "1e100,1e100,0.8,1.5",
        "1e200,1e200,0.8,1.5",
    ],
)
def test_lobe_zero_diffuse_and_huge_coefficients(tmp_path, brdf):
    out = tmp_path / "l.png"
    result, escaped = plot("lobe", "--brdf", brdf, "-o", out)
    assert_drawn(result, escaped, out)
    assert "Warning" not in result.output  # these lobes are drawn: nothing to warn about


# -- defect 2: an all-zero BRDF is drawn (empty log axes, a note) with a warning ----------
def test_lobe_all_zero_brdf_is_drawn_with_a_note(tmp_path):
    out = tmp_path / "l.png"
    result, escaped = plot("lobe", "--brdf", "0,0,0.8,1.5", "-o", out)
    assert_drawn(result, escaped, out)
    assert "Warning: f_r of Pd=0 Ps=0" in result.output
    assert "0 in every direction" in result.output


def test_lobe_all_zero_next_to_a_real_one(tmp_path):
    out = tmp_path / "l.png"
    result, escaped = plot("lobe", "--brdf", "0,0,0.8,1.5", "--brdf", "BRDF1", "-o", out)
    assert_drawn(result, escaped, out)
    assert "0 in every direction" in result.output


# -- defect 3: an all-zero medium ---------------------------------------------------------
def test_transmission_all_zero_medium_is_drawn_with_a_note(tmp_path):
    out = tmp_path / "t.png"
    result, escaped = plot("transmission", "--medium", "0,0,0.93,1.3", "-o", out)
    assert_drawn(result, escaped, out)
    assert "Warning: f_t of Td=0 Tt=0" in result.output


def test_transmission_huge_but_finite_medium(tmp_path):
    out = tmp_path / "t.png"
    result, escaped = plot("transmission", "--medium", "1e200,1e200,0.93,1.3", "-o", out)
    assert_drawn(result, escaped, out)


def test_transmission_overflow_is_the_users_to_fix(tmp_path):
    """f_t beyond float64 (1e308 * a lobe above 1): exit 2 naming the coefficients."""
    out = tmp_path / "t.png"
    result, _ = plot("transmission", "--medium", "1e308,1e308,0.93,1.3", "-o", out)
    assert result.exit_code == 2, result.output
    assert "overflows float64" in result.output and "Tt = 1e+308" in result.output
    assert not out.exists()


# -- defect 11: curves without a half-maximum crossing, all-zero curves ------------------
@pytest.mark.parametrize(
    "args, side",
    [
        (["--brdf", "200,0,0.8,1.5", "--medium", "none"], "on either side of the peak"),
        (["--brdf", "200,200,0.8,1.5", "--medium", "BTDF2"], "below the peak angle"),
        (["--brdf", "1e20,1e20,0.8,1.5", "--medium", "BTDF2"], "below the peak angle"),
    ],
)
def test_curve_without_half_maximum_crossing_says_so(tmp_path, args, side):
    out = tmp_path / "p.png"
    result, escaped = plot("curve", *args, "--theta-i", "45", "-o", out)
    assert_drawn(result, escaped, out)
    assert f"FWHM not defined (no half-maximum crossing {side} in the range)" in result.output


@pytest.mark.parametrize("scale", ["log", "linear", "peak", "tt2"])
def test_curve_all_zero_brdf(tmp_path, scale):
    out = tmp_path / "p.png"
    result, escaped = plot("curve", "--brdf", "0,0,0.8,1.5", "--scale", scale, "-o", out)
    assert_drawn(result, escaped, out)
    assert "f = 0 at every angle (no peak or width to measure)" in result.output
    assert "FWHM" not in result.output and "log-scaled" not in result.output


def test_curve_tt2_of_a_medium_without_lobe_weight(tmp_path):
    """f / T_t^2 with T_t = 0 is not drawn (no 0/0 warning); the clear curve is."""
    out = tmp_path / "p.png"
    result, escaped = plot(
        "curve", "--brdf", "BRDF1", "--medium", "0,0,0.93,1.3", "--medium", "none",
        "--scale", "tt2", "--accuracy", "fast", "-o", out,
    )
    assert_drawn(result, escaped, out)
    assert "FWHM 4.18 deg" in result.output


def test_curve_tt2_beyond_what_the_figures_draw_is_not_drawn():
    """f / T_t^2 above PLOT_MAX or beyond float64 (T_t of 1e-160: T_t^2 subnormal), or T_t^2
    that underflows to 0: the curve is not drawn on the tt2 scale and says why; the log
    scale draws it."""
    import warnings

    import veil
    from veil.viz.figures import PLOT_MAX, Curve, _curve_y, curve_metrics

    theta = np.linspace(0.0, 89.0, 90)
    values = np.exp(-(((theta - 45.0) / 5.0) ** 2)) + 0.1
    for tt, why in [(1e-160, "above"), (1e-126, "above"), (1e-170, "T_t² = 0")]:
        medium = veil.HenyeyGreenstein(0.5, tt, 0.93, 1.3)
        curve = Curve(veil.BRDF1, medium, 45.0, theta, values, curve_metrics(theta, values))
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no overflow or underflow warning escapes
            y, note = _curve_y(curve, "tt2")
            assert y is None and why in note and "not drawn" in note, (tt, note)
            y, note = _curve_y(curve, "log")
            assert note == "" and np.array_equal(y, values)
    fine = veil.HenyeyGreenstein(0.5, 1e-100, 0.93, 1.3)  # f / T_t^2 = 1e199 at most
    curve = Curve(veil.BRDF1, fine, 45.0, theta, values, curve_metrics(theta, values))
    y, note = _curve_y(curve, "tt2")
    assert note == "" and np.max(y) <= PLOT_MAX


def test_values_above_what_the_figures_draw_are_refused(tmp_path):
    """A lobe, transmission or curve above PLOT_MAX (matplotlib's log axes overflow near
    float64's top): exit 2 naming the model, nothing written."""
    out = tmp_path / "p.png"
    for args in (["lobe", "--brdf", "0,6e307,5,1.5", "--theta-i", "80"],
                 ["lobe", "--brdf", "0,1e300,5,1.5"],
                 ["transmission", "--medium", "1e308,0,0.9,1.33"],
                 ["curve", "--brdf", "1.7e308,1.7e308,0.8,1.5", "--scale", "linear"]):
        result, _ = plot(*args, "-o", out)
        assert result.exit_code == 2, (args, result.output)
        assert "the largest value the figures draw" in result.output
        assert ("Ps=" in result.output or "Td=" in result.output), result.output
        assert not out.exists()


def test_curve_regular_output_unchanged(tmp_path):
    out = tmp_path / "p.png"
    result, escaped = plot("curve", "--brdf", "BRDF1", "-o", out)
    assert_drawn(result, escaped, out)
    assert "peak 4.065e+04 at 45.00 deg, FWHM 4.18 deg, f(0 deg) 141.4" in result.output


# -- the helpers --------------------------------------------------------------------------
def test_fwhm_text_never_nan():
    from veil.viz.figures import CurveMetrics, curve_metrics

    theta = np.linspace(0.0, 89.0, 90)
    peaked = curve_metrics(theta, np.exp(-(((theta - 45.0) / 5.0) ** 2)))
    assert peaked.fwhm_text().startswith("FWHM ") and "nan" not in peaked.fwhm_text()
    assert "not defined (f = 0" in curve_metrics(theta, np.zeros(90)).fwhm_text()
    flat = CurveMetrics(1.0, 0.0, math.nan, math.nan, 1.0, 0.0)
    assert flat.fwhm_text() == (
        "FWHM not defined (no half-maximum crossing on either side of the peak in the range)"
    )
    assert "above the peak angle" in CurveMetrics(1.0, 80.0, 70.0, math.nan, 0.5, 0.0).fwhm_text()


def test_decades_and_close_up_limits_are_finite_floats():
    from veil.viz.lobe_figures import _close_up_limits, _decades

    assert _decades(np.zeros(5)) == (-1, 1)
    assert _decades([0.0, 150.0, 4.0e4]) == (1, 5)
    for v in (np.zeros(4), np.array([0.0, 1e-300, 3.5e4]), np.array([7e199, 7.8e199])):
        lo, hi = _decades(v)
        bottom, top = _close_up_limits([v], lo, hi)
        assert isinstance(bottom, float) and math.isfinite(bottom) and bottom > 0
        assert top is None or (isinstance(top, float) and math.isfinite(top) and top > bottom)
    assert _close_up_limits([np.array([141.4, 4e4])], 1, 5) == (100.0, None)  # as before
