"""The step-1 medium's uncertainty in reflectance maps (``propagation="off" | "linear"`` of
``veil.fit_maps``, ``--propagation`` of ``veil fit maps``; docs/maps-medium-error.md). A
grey 12 x 12 map of four materials through the paper's medium (BTDF2), photos rendered at
the maps' own quadrature ("fast") with 1 % noise, the medium a step-1 result whose total
covariance has strong correlations: the medium's part of every converged pixel's standard
errors is checked against refits of the map through media moved by central differences
(brute force) and against the first order S = -J_w^+ J_w,theta recomputed from the tables;
it composes with the noise's in quadrature, leaves the estimates bit for bit, is part of
the store's fingerprint, its summary, its export and the command's report; over channels
a red medium parameter moves the red scales and not the others; bad requests are refused
before anything is written."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
import tifffile

import veil
from support.cli import run
from support.maps import angles_of, configurations, write_photos
from test_maps_channels import _medium, medium_result

# the grey stack of the model's error's tests: BRDF1 through BTDF2, Pd, Ps, n free, eta
# fixed, 24 configurations, 1 % noise, 12 x 12 pixels in four tiles of at most 8 x 8
from test_maps_model_error import (
    BRDF,
    CLS,
    CONFIGS,
    FIX,
    FREE,
    GRID,
    INDEX,
    MEDIUM,
    NAMES,
    NOISE,
    PD,
    SHAPE,
    TILE,
    H,
    W,
    _channel_materials,
    _material_maps,
    _photos,
    _render,
    _snapshot,
)
from veil.errors import InputError
from veil.fitting import FitResult
from veil.maps.run import open_maps
from veil.maps.solve import CONVERGED
from veil.maps.store import summarize_maps
from veil.maps.tables import build_tables

BASE_KEYS = {"params", "stderr", "chi2_reduced", "n_points", "status", "info"}

#: the medium's parameters (Td, Tt, g, eta) and the step-1 result's total standard errors,
#: relative: Td 2 %, Tt 1 %, g 0.1 % (g = 0.93 near its bound 1: 1 % of it moves Ps by more
#: than its value), eta 0 (left out). Td and Tt strongly anti-correlated (step 1 trades the
#: diffuse for the specular transmission), which lowers Pd's medium part (measured: the
#: refits' part without the correlations 1.21 times the propagated one for Pd, 0.964 for
#: Ps).
MNAMES = type(MEDIUM).param_names()
VALUES = dict(zip(MNAMES, map(float, MEDIUM.to_vector())))
RELATIVE = {"Td": 0.02, "Tt": 0.01, "g": 0.001, "eta": 0.0}
TOTAL = {k: RELATIVE[k] * v for k, v in VALUES.items()}
CORRELATION = {"Td": {"Tt": -0.8}, "Tt": {"Td": -0.8, "g": 0.3}, "g": {"Tt": 0.3}}
PROPAGATED = ("Td", "Tt", "g")
#: the fit's own standard errors (``stderr``) are those of the total over 1.5 and
#: uncorrelated: a propagation of the covariance without ``total`` is 1/1.5 of the right one
OWN = 1.5
#: the relative step of the brute-force central differences (not the implementation's
#: one-sided steps, a tenth of each standard error; measured: 1e-4 to 1e-3 give the same
#: ratios, 3e-3 is too coarse for g, whose response is curved)
STEP = 3e-4


def medium_fit() -> FitResult:
    """The grey step-1 result: values of BTDF2, total covariance of TOTAL and CORRELATION."""
    return FitResult(model=type(MEDIUM).NAME, params=dict(VALUES),
                     stderr={k: v / OWN for k, v in TOTAL.items()}, correlation={},
                     stderr_total=dict(TOTAL), correlation_total=CORRELATION,
                     residuals=tuple([0.0] * 10), chi2_reduced=1.0, rms_relative=0.0,
                     n_points=10, converged=True, message="synthetic", step="medium",
                     options=MEDIUM.options())


def _covariance() -> np.ndarray:
    """(3, 3) the total covariance of Td, Tt, g, as the result gives it (checked)."""
    names, cov = medium_fit().covariance(total=True)
    assert tuple(names) == tuple(MNAMES)
    se = np.array([TOTAL[n] for n in PROPAGATED])
    corr = np.array([[1.0, -0.8, 0.0], [-0.8, 1.0, 0.3], [0.0, 0.3, 1.0]])
    np.testing.assert_allclose(cov[:3, :3], corr * np.outer(se, se), rtol=1e-12)
    assert np.all(cov[3] == 0) and np.all(cov[:, 3] == 0)
    assert np.all(np.linalg.eigvalsh(corr) > 0)
    return cov[:3, :3]


def _fit(photos, manifest, medium, out, **kw):
    return veil.fit_maps(photos, manifest, medium, out, fixed=FIX, grid=[GRID], tile=TILE,
                         accuracy="fast", **({"noise": (NOISE, 0.0)} | kw))


def _cli_args(manifest, medium, out, *extra):
    return ["fit", "maps", manifest.parent, "--manifest", manifest, "--medium", medium,
            "--fix", f"{NAMES[INDEX]}={FIX[NAMES[INDEX]]}", "--grid", GRID, "--tile", TILE,
            "--accuracy", "fast", "--noise", NOISE, "-o", out, *extra]


def _ratio_stats(want: np.ndarray, got: np.ndarray, ok) -> tuple:
    """Per row of (3, H, W): the median of want / got over ``ok`` and the share within 3 %
    and within 10 %."""
    r = want[:, ok] / got[:, ok]
    return (np.median(r, axis=1), np.mean(np.abs(r - 1) < 0.03, axis=1),
            np.mean(np.abs(r - 1) < 0.1, axis=1))


# --------------------------------------------------------------------------------------
# the grey map
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def grey(tmp_path_factory):
    root = tmp_path_factory.mktemp("medium_error")
    configs = configurations(CONFIGS)
    angles = angles_of(configs)
    truth = _material_maps(H, W)
    clean = _render(MEDIUM, angles, truth.reshape(len(NAMES), -1).T)
    manifest = write_photos(root / "photos", configs, clean, (H, W), NOISE, seed=11)
    medium_fit().to_json(root / "medium.json")
    return {"root": root, "angles": angles, "manifest": manifest, "medium": root / "medium.json"}


def _grey_map(grey, name: str, medium=None, **kw):
    manifest = grey["manifest"]
    out = grey["root"] / f"{name}.zarr"
    run_ = _fit(manifest.parent, manifest, medium_fit() if medium is None else medium, out, **kw)
    return out, open_maps(out), run_


@pytest.fixture(scope="module")
def grey_off(grey):
    return _grey_map(grey, "off", propagation="off")


@pytest.fixture(scope="module")
def grey_linear(grey):
    return _grey_map(grey, "linear", propagation="linear")


@pytest.fixture(scope="module")
def refits(grey):
    """(3 medium parameters, 4 map parameters, H, W): d(estimate) / d(theta) of every pixel
    by central differences of maps refitted through the literal media theta +- d."""
    out = []
    for name in PROPAGATED:
        d = STEP * VALUES[name]
        moved = [_grey_map(grey, f"{name}{s:+d}", MEDIUM.replace(**{name: VALUES[name] + s * d}))
                 [1]["params"] for s in (1, -1)]
        out.append((moved[0] - moved[1]) / (2 * d))
    return np.stack(out)


def test_the_medium_part_is_that_of_refits_through_moved_media(grey_linear, refits):
    """sqrt(S C S^T) with S from refits of the whole map through Td, Tt, g moved by +-0.03 %
    and C the result's total covariance: within 3 % of stderr_medium in the median of each
    free parameter and within 10 % on most pixels (measured: medians 0.9995, 0.9997, 0.9991;
    within 10 % 100 %, 95 %, 94 %: the refit's exact derivative and the first order differ
    by the residuals' curvature where n is poorly determined; on noise-free photos they
    agree within 1 % everywhere). Wrong propagations fail it: the correlations ignored
    (Pd 1.21 times), the fit's own covariance instead of the total (1.5 times), the
    variance instead of the standard error or a factor 2."""
    _, maps, _ = grey_linear
    ok = maps["status"] == CONVERGED
    assert ok.mean() >= 0.9, np.unique(maps["status"], return_counts=True)
    cov = _covariance()
    s = refits[:, list(FREE)]                                        # (3, 3, H, W)
    want = np.sqrt(np.einsum("kphw,kl,lphw->phw", s, cov, s))
    got = maps["stderr_medium"][list(FREE)]
    median, _, within10 = _ratio_stats(want, got, ok)
    assert np.all(np.abs(median - 1) < 0.03), median
    assert np.all(within10 >= 0.75), within10
    # the check sees the correlations: without them Pd's part is >10 % off
    plain = np.sqrt(np.einsum("kphw,kl,lphw->phw", s, np.diag(np.diag(cov)), s))
    assert abs(_ratio_stats(plain, got, ok)[0][0] - 1) > 0.1

    record = maps["info"]["propagation"]
    assert record["method"] == "linear"
    assert record["parameters"] == list(PROPAGATED)       # eta (stderr 0) left out
    np.testing.assert_allclose(record["values"], [VALUES[n] for n in PROPAGATED], rtol=1e-12)
    np.testing.assert_allclose(record["stderr"], [TOTAL[n] for n in PROPAGATED], rtol=1e-12)
    assert len(record["steps"]) == 3
    assert all(0 < st < e for st, e in zip(record["steps"], record["stderr"])), record


def test_the_medium_part_is_the_first_order_of_the_tables(grey, grey_linear):
    """The first order of veil.fitting.propagation, recomputed pixel by pixel from the
    photos and tables: S = -J_w^+ J_w,theta (J_w the weighted Jacobian in Pd, Ps, n at the
    pixel's estimate, J_w,theta the model's central difference over tables built through
    Td, Tt, g moved by +-0.03 %, weights 1 / (0.01 y)), sqrt(diag(S C S^T)): within 1 % of
    stderr_medium at every converged pixel (measured: within 0.25 %)."""
    _, maps, _ = grey_linear
    ok = maps["status"] == CONVERGED
    grid = {NAMES[SHAPE]: (0.25, 2.5, 16)}

    def tables(medium):
        return build_tables(CLS, medium, grey["angles"], fixed=FIX, grid=grid, accuracy="fast")

    base = tables(MEDIUM)
    moved = {name: [tables(MEDIUM.replace(**{name: VALUES[name] + s * STEP * VALUES[name]}))
                    for s in (1, -1)] for name in PROPAGATED}
    photos = _photos(grey["manifest"])
    cov = _covariance()
    want = np.zeros((3, H, W))

    def model(tab, x):
        b = tab.basis({NAMES[SHAPE]: x[2]})
        return x[0] * b[:, 0] + x[1] * b[:, 1] + b[:, 2]

    for py, px in np.argwhere(ok):
        x = maps["params"][list(FREE), py, px]
        h = 1e-5 * x[2] * np.array([0, 0, 1])
        b = base.basis({NAMES[SHAPE]: x[2]})
        jac = np.stack([b[:, 0], b[:, 1], (model(base, x + h) - model(base, x - h)) / (2 * h[2])],
                       1)
        given = np.stack([(model(p, x) - model(m, x)) / (2 * STEP * VALUES[k])
                          for k, (p, m) in moved.items()], 1)
        w = 1 / (NOISE * photos[:, py, px])
        sens = -np.linalg.lstsq(jac * w[:, None], given * w[:, None], rcond=None)[0]
        want[:, py, px] = np.sqrt(np.diag(sens @ cov @ sens.T))
    got = maps["stderr_medium"][list(FREE)]
    np.testing.assert_allclose(want[:, ok], got[:, ok], rtol=1e-2)


def test_the_parts_add_in_quadrature_and_the_estimates_do_not_move(grey_off, grey_linear):
    """stderr^2 = stderr_off^2 + stderr_medium^2 on converged pixels (1e-9 relative);
    params, chi2_reduced, n_points and status bit for bit those of "off"; the fixed eta has
    no part; "off" has neither the array nor the record, and another fingerprint."""
    _, off, _ = grey_off
    _, lin, _ = grey_linear
    ok = lin["status"] == CONVERGED
    for name in ("params", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(lin[name], off[name]), name
    assert set(off) == BASE_KEYS and "propagation" not in off["info"]
    assert set(lin) == BASE_KEYS | {"stderr_medium"}
    assert lin["stderr_medium"].shape == lin["stderr"].shape == (len(NAMES), H, W)
    assert np.all(np.isfinite(lin["stderr_medium"]))
    free = list(FREE)
    np.testing.assert_allclose(lin["stderr"][free][:, ok] ** 2,
                               off["stderr"][free][:, ok] ** 2
                               + lin["stderr_medium"][free][:, ok] ** 2, rtol=1e-9, atol=0)
    assert np.all(lin["stderr_medium"][free][:, ok] > 0)
    assert np.all(lin["stderr_medium"][INDEX] == 0) and np.all(lin["stderr"][INDEX] == 0)
    assert np.all(lin["stderr_medium"][:, ~ok] == 0)
    assert np.array_equal(lin["stderr"][:, ~ok], off["stderr"][:, ~ok])
    # the medium's part is no small correction here: 1 % of Tt against 1 % noise per photo
    assert np.median(lin["stderr_medium"][PD][ok] / lin["stderr"][PD][ok]) > 0.5
    assert lin["info"]["fingerprint"] != off["info"]["fingerprint"]


def test_with_the_models_error_and_unweighted_the_parts_still_add(grey, grey_linear):
    """With the model's error (correlated) the medium's part is the same, bit for bit (it
    does not depend on the term: the estimator's weights are the noise's), and the terms
    add in quadrature to it; an unweighted map (no --noise) gets its part too, its
    estimates and residual-scaled errors those of its map without, the parts adding."""
    _, linear, _ = grey_linear
    _, term, _ = _grey_map(grey, "term", propagation="linear", model_error="correlated")
    _, term_off, _ = _grey_map(grey, "term-off", propagation="off", model_error="correlated")
    ok = term["status"] == CONVERGED
    assert np.array_equal(term["stderr_medium"], linear["stderr_medium"])
    assert np.array_equal(term["params"], term_off["params"])
    np.testing.assert_allclose(term["stderr"][:, ok] ** 2, term_off["stderr"][:, ok] ** 2
                               + term["stderr_medium"][:, ok] ** 2, rtol=1e-9)
    assert {"model_error", "stderr_noise", "stderr_medium"} <= set(term)
    _, plain, _ = _grey_map(grey, "plain", propagation="linear", noise=None)
    _, plain_off, _ = _grey_map(grey, "plain-off", propagation="off", noise=None)
    ok = plain["status"] == CONVERGED
    assert ok.mean() > 0.9 and np.array_equal(plain["params"], plain_off["params"])
    np.testing.assert_allclose(plain["stderr"][:, ok] ** 2, plain_off["stderr"][:, ok] ** 2
                               + plain["stderr_medium"][:, ok] ** 2, rtol=1e-9)
    free = [k for k, n in enumerate(NAMES) if n in plain["info"]["free"]]
    part = plain["stderr_medium"][free][:, ok]
    # unweighted, S weighs every photo alike: near the weighted map's part, not equal
    ratio = np.median(part / linear["stderr_medium"][free][:, ok], axis=1)
    assert np.all(part > 0) and np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def test_the_summary_the_export_and_the_command(grey, grey_off, grey_linear, tmp_path):
    """summary.json and summarize_maps: the parameters and, per free map parameter, the
    median over converged pixels of stderr_medium and of its share of stderr (none for the
    fixed eta; no entry without propagation); `veil maps export` writes NAME_stderr_medium
    of each free parameter (0 where a pixel did not converge), only with propagation; the
    command's line names the medium's parameters and the shares."""
    path, maps, run_ = grey_linear
    ok = maps["status"] == CONVERGED
    summary = json.loads((path / "summary.json").read_text())
    entry = summary["propagation"]
    assert summarize_maps(path)["propagation"] == entry == run_.summary["propagation"]
    assert entry["parameters"] == list(PROPAGATED)
    assert set(entry["maps"]) == {NAMES[k] for k in FREE}
    for k in FREE:
        part, total = maps["stderr_medium"][k][ok], maps["stderr"][k][ok]
        m = entry["maps"][NAMES[k]]
        assert m["median_stderr_medium"] == pytest.approx(float(np.median(part)), rel=1e-12)
        assert m["median_share"] == pytest.approx(float(np.median(part / total)), rel=1e-12)
        assert 0 < m["median_share"] < 1
    assert "propagation" not in json.loads((grey_off[0] / "summary.json").read_text())

    exported = run("maps", "export", path, "-o", tmp_path / "exp", "--format", "tiff")
    assert exported.exit_code == 0, exported.output
    plain = run("maps", "export", grey_off[0], "-o", tmp_path / "plain", "--format", "tiff")
    assert plain.exit_code == 0, plain.output
    written = {p.name for p in (tmp_path / "exp").iterdir()}
    others = {p.name for p in (tmp_path / "plain").iterdir()}
    assert written - others == {f"{NAMES[k]}_stderr_medium.tif" for k in FREE}
    for k in FREE:
        image = tifffile.imread(tmp_path / "exp" / f"{NAMES[k]}_stderr_medium.tif")
        want = np.where(ok, maps["stderr_medium"][k], 0.0).astype(np.float32)
        assert np.array_equal(image, want), NAMES[k]
    # without a format (TIFF and EXR): both files of each
    pytest.importorskip("OpenEXR")
    both = run("maps", "export", path, "-o", tmp_path / "both")
    assert both.exit_code == 0, both.output
    for k in FREE:
        for suffix in ("tif", "exr"):
            assert (tmp_path / "both" / f"{NAMES[k]}_stderr_medium.{suffix}").is_file()

    # the command: a corner of the photos, the medium's line
    manifest = grey["manifest"]
    out = tmp_path / "cli.zarr"
    result = run(*_cli_args(manifest, grey["medium"], out, "--propagation", "linear",
                            "--roi", "0,0,8,8"))
    assert result.exit_code in (0, 1), result.output
    [line] = [t for t in result.output.splitlines()
              if "the medium's uncertainty" in t and "part of the standard error" in t]
    for name in PROPAGATED:
        assert name in line, line
    shares = summarize_maps(out)["propagation"]["maps"]
    for k in FREE:
        assert NAMES[k] in line and f"{100 * shares[NAMES[k]]['median_share']:.0f}" in line, line
    quiet = run(*_cli_args(manifest, grey["medium"], tmp_path / "quiet.zarr", "--roi", "0,0,8,8"))
    assert quiet.exit_code in (0, 1) and "the medium's uncertainty" not in quiet.output


def test_the_same_inputs_give_the_same_bits(grey, grey_linear, tmp_path):
    """A second run (one worker this time) into a new store: every array bit for bit."""
    _, first, _ = grey_linear
    manifest = grey["manifest"]
    out = tmp_path / "again.zarr"
    _fit(manifest.parent, manifest, medium_fit(), out, propagation="linear", workers=1)
    again = open_maps(out)
    assert set(again) == set(first)
    for name in set(first) - {"info"}:
        assert np.array_equal(again[name], first[name]), name
    assert again["info"]["propagation"] == first["info"]["propagation"]
    assert again["info"]["fingerprint"] == first["info"]["fingerprint"]


# --------------------------------------------------------------------------------------
# the setting is one of the store's inputs
# --------------------------------------------------------------------------------------
def test_a_store_of_the_other_setting_is_refused_and_left_untouched(grey, grey_off,
                                                                    grey_linear, tmp_path):
    """An "off" store rerun with "linear", and a "linear" one rerun with "off" or with
    another covariance of the medium: an InputError naming other settings (the command:
    exit 2), nothing touched; the same setting again has nothing to compute."""
    manifest = grey["manifest"]
    for (src, _, _), method, other in ((grey_off, "off", "linear"),
                                       (grey_linear, "linear", "off")):
        store = tmp_path / f"{method}.zarr"
        shutil.copytree(src, store)
        failed = json.loads((store / "summary.json").read_text())["failed"]
        before = _snapshot(store)
        with pytest.raises(InputError, match="other settings"):
            _fit(manifest.parent, manifest, medium_fit(), store, propagation=other)
        assert _snapshot(store) == before, (method, other)
        refused = run(*_cli_args(manifest, grey["medium"], store, "--propagation", other))
        assert refused.exit_code == 2, (method, other, refused.output)
        assert "Traceback" not in refused.output
        assert _snapshot(store) == before, (method, other)
        same = run(*_cli_args(manifest, grey["medium"], store, "--propagation", method))
        assert same.exit_code == (1 if failed else 0), same.output
        assert "nothing to compute" in same.output, same.output
        again = _fit(manifest.parent, manifest, medium_fit(), store, propagation=method)
        assert again.tiles_computed == 0 and again.tiles_reused == 4
        assert _snapshot(store) == before, (method, other)
    # the medium's covariance too (docs/maps-medium-error.md): the same values, Tt's error
    # twice as large, is another store's
    wider = dataclasses.replace(medium_fit(), stderr_total=dict(TOTAL, Tt=2 * TOTAL["Tt"]))
    before = _snapshot(tmp_path / "linear.zarr")
    with pytest.raises(InputError, match="other settings"):
        _fit(manifest.parent, manifest, wider, tmp_path / "linear.zarr", propagation="linear")
    assert _snapshot(tmp_path / "linear.zarr") == before


# --------------------------------------------------------------------------------------
# bad requests
# --------------------------------------------------------------------------------------
def test_a_medium_without_a_covariance_or_an_unknown_method_is_refused(grey, tmp_path):
    """"linear" through a literal medium (a model, the command's BTDF2) or a result without
    standard errors: an InputError naming --propagation (the command: exit 2, its message),
    before anything is written; an unknown method ("sigma-points", "bogus") too; no store."""
    manifest = grey["manifest"]
    out = tmp_path / "bad.zarr"
    no_errors = dataclasses.replace(medium_fit(), stderr={k: None for k in VALUES},
                                    stderr_total=None, correlation_total=None)
    assert no_errors.covariance(total=True) is None
    for medium in (MEDIUM, no_errors):
        with pytest.raises(InputError, match="--propagation"):
            _fit(manifest.parent, manifest, medium, out, propagation="linear")
        assert not out.exists()
    for method in ("sigma-points", "bogus"):
        with pytest.raises(InputError):
            _fit(manifest.parent, manifest, medium_fit(), out, propagation=method)
        assert not out.exists()
    literal = run(*_cli_args(manifest, "BTDF2", out, "--propagation", "linear"))
    assert literal.exit_code == 2, literal.output
    assert "--propagation" in literal.output and "Traceback" not in literal.output
    assert "tables:" not in literal.output, literal.output
    no_errors.to_json(tmp_path / "no-errors.json")
    bad = run(*_cli_args(manifest, tmp_path / "no-errors.json", out, "--propagation", "linear"))
    assert bad.exit_code == 2 and "--propagation" in bad.output, bad.output
    bogus = run(*_cli_args(manifest, grey["medium"], out, "--propagation", "bogus"))
    assert bogus.exit_code == 2, bogus.output
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["no-errors.json"]
    # an undetermined parameter (NaN standard error, as a fit may leave one): refused by
    # name, in Python as on the command line (a JSON file holds it as null)
    total = dict(medium_fit().stderr_total or medium_fit().stderr, g=float("nan"))
    nan = dataclasses.replace(medium_fit(), stderr_total=total)
    with pytest.raises(InputError, match="g has no finite standard error"):
        _fit(manifest.parent, manifest, nan, out, propagation="linear")
    assert not out.exists()
    # the command's choices are the module's methods
    from veil.cli.maps_cmd import fit_maps_command
    from veil.maps.medium_error import METHODS
    option = next(o for o in fit_maps_command.params if o.name == "propagation")
    assert tuple(option.type.choices) == METHODS
    # "off" (the default) through a literal medium: the map of before
    plain = _fit(manifest.parent, manifest, MEDIUM, out, roi="0,0,4,4")
    assert set(open_maps(out)) == BASE_KEYS and plain.tiles_computed == 1


def test_blur_rounds_refuse_a_bad_propagation_before_the_first_round(tmp_path):
    """--blur-rounds through a literal forward-series medium (near field) with
    --propagation linear: exit 2 naming --propagation before any table is built, nothing
    written; fit_maps_rounds the same (an InputError, no store, no round's folder)."""
    from veil.maps.blur_rounds import fit_maps_rounds

    configs = configurations(8)
    values = 0.05 * (1 + 0.1 * np.random.default_rng(0).random((64, len(configs))))
    manifest = write_photos(tmp_path / "photos", configs, values, (8, 8), noise=0.0)
    out = tmp_path / "rounds.zarr"
    near = ["--near-field", "--camera-distance", 100.0, "--pixel-pitch", 0.25]
    medium = ["--medium-model", "forward-series", "--medium", "0.9,0.95,0.9,1,1",
              "--path-length", 15, "--plate-width", 2.0]
    result = run("fit", "maps", tmp_path / "photos", "--manifest", manifest, *medium, "--fix",
                 f"{NAMES[INDEX]}={FIX[NAMES[INDEX]]}", "--grid", f"{NAMES[SHAPE]}=0.25:2.5:4",
                 "--accuracy", "fast", "--tile", 8, "-o", out, *near, "--blur-rounds", 2,
                 "--propagation", "linear")
    assert result.exit_code == 2, result.output
    assert "--propagation" in result.output and "tables" not in result.output, result.output
    assert "Traceback" not in result.output
    forward = veil.ForwardSeries(tau=0.9, omega=0.95, g=0.9, path_length=15.0, plate_width=2.0)
    with pytest.raises(InputError, match="--propagation"):
        fit_maps_rounds(tmp_path / "photos", manifest, forward, out, 2, fixed=FIX,
                        grid=[f"{NAMES[SHAPE]}=0.25:2.5:4"], accuracy="fast", tile=8,
                        geometry=(100.0, 0.25), near_field=True, propagation="linear")
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith("-lock")) == [
        "photos"]


def test_blur_rounds_propagate_in_the_last_round_only(tmp_path, monkeypatch):
    """fit_maps_rounds (one round after the first map, near field, a forward-series step-1
    result with tau uncertain by 1 %) with "linear": the first map is fitted without the
    propagation, the last with it; its record lists tau."""
    import veil.maps.run as mr
    from support.maps import render_near
    from veil.maps.blur_rounds import fit_maps_rounds
    from veil.maps.near import NearGeometry

    forward = veil.ForwardSeries(tau=0.9, omega=0.95, g=0.9, path_length=15.0, plate_width=2.0)
    values = dict(zip(type(forward).param_names(), map(float, forward.to_vector())))
    result = FitResult(model=type(forward).NAME, params=values,
                       stderr={k: 0.01 * v if k == "tau" else 0.0 for k, v in values.items()},
                       correlation={}, residuals=(0.0,) * 10, chi2_reduced=1.0,
                       rms_relative=0.0, n_points=10, converged=True, message="synthetic",
                       step="medium", options=forward.options())
    configs = configurations(8)
    truth = np.repeat(BRDF.to_vector()[:, None, None], 8, 1).repeat(8, 2)
    photos = render_near(BRDF, forward, configs, truth, NearGeometry(100.0, 0.25, (8, 8)))
    manifest = write_photos(tmp_path / "photos", configs, photos, (8, 8), NOISE, seed=1)
    seen = []
    real = mr.fit_maps

    def spy(*args, **kw):
        done = real(*args, **kw)
        seen.append("propagation" in open_maps(done.store)["info"])
        return done

    monkeypatch.setattr(mr, "fit_maps", spy)
    out = tmp_path / "rounds.zarr"
    fit_maps_rounds(tmp_path / "photos", manifest, result, out, 1, fixed=FIX,
                    grid=[f"{NAMES[SHAPE]}=0.25:2.5:4"], accuracy="fast", tile=8,
                    geometry=(100.0, 0.25), near_field=True, noise=(NOISE, 0.0),
                    propagation="linear")
    assert seen == [False, True]
    maps = open_maps(out)
    assert maps["info"]["propagation"]["parameters"] == ["tau"]
    ok = maps["status"] == CONVERGED
    assert ok.mean() >= 0.9
    assert np.all(maps["stderr_medium"][list(FREE)][:, ok] > 0)


# --------------------------------------------------------------------------------------
# over channels, and one channel of a medium fitted over several
# --------------------------------------------------------------------------------------
HC = WC = 8


@pytest.fixture(scope="module")
def rgb(tmp_path_factory):
    """RGB photos (8 x 8, 24 configurations, 1 % noise), each channel through its medium
    of tests/test_maps_channels.py (:func:`medium_result`), four materials by column."""
    root = tmp_path_factory.mktemp("medium_error_rgb")
    configs = configurations(CONFIGS)
    angles = angles_of(configs)
    values = [_render(_medium(c), angles, _channel_materials(c, HC, WC).reshape(len(NAMES), -1).T)
              for c in "rgb"]
    manifest = write_photos(root / "photos", configs, np.stack(values, axis=-1), (HC, WC),
                            NOISE, seed=3)
    return root, manifest


def _with_errors(errors: dict) -> FitResult:
    """medium_result() with standard errors (relative) of ``errors``, the others 0."""
    res = medium_result()
    return dataclasses.replace(res, stderr={k: errors.get(k, 0.0) * v
                                            for k, v in res.params.items()})


def test_over_channels_a_red_parameter_moves_the_red_scales(rgb):
    """Over r, g, b with only Tt[r] uncertain (2 %): the record lists Tt[r] alone; the
    red scales carry a large medium part, green's and blue's (moved only through the shared
    n, which Tt[r] hardly moves) almost none (measured median shares: Pd[r] 0.995, Pd[g]
    and Pd[b] 0.005; Ps[r] 0.62, Ps[g], Ps[b] and n 0.03); the parts add in quadrature
    per channel, the estimates are those of "off" bit for bit; the summary names every
    per-channel map."""
    root, manifest = rgb
    medium = _with_errors({"Tt[r]": 0.02})
    maps = {}
    for method in ("off", "linear"):
        out = root / f"{method}.zarr"
        _fit(manifest.parent, manifest, medium, out, channel="rgb", propagation=method)
        maps[method] = open_maps(out)
    off, lin = maps["off"], maps["linear"]
    ok = lin["status"] == CONVERGED
    assert ok.mean() >= 0.85
    assert not {"stderr_medium", "channel_stderr_medium"} & set(off)
    for name in ("params", "channel_params", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(lin[name], off[name]), name
    assert lin["info"]["propagation"]["parameters"] == ["Tt[r]"]
    assert lin["channel_stderr_medium"].shape == lin["channel_stderr"].shape == (2, 3, HC, WC)
    assert lin["stderr_medium"].shape == lin["stderr"].shape
    np.testing.assert_allclose(lin["channel_stderr"][..., ok] ** 2,
                               off["channel_stderr"][..., ok] ** 2
                               + lin["channel_stderr_medium"][..., ok] ** 2, rtol=1e-9)
    np.testing.assert_allclose(lin["stderr"][:, ok] ** 2,
                               off["stderr"][:, ok] ** 2 + lin["stderr_medium"][:, ok] ** 2,
                               rtol=1e-9)
    share = lin["channel_stderr_medium"][0][:, ok] / lin["channel_stderr"][0][:, ok]  # Pd
    medians = np.median(share, axis=1)
    assert medians[0] > 0.5, medians
    assert medians[1] < 0.05 and medians[2] < 0.05, medians
    assert np.quantile(share[0], 0.1) > 5 * max(np.quantile(share[1], 0.9),
                                                np.quantile(share[2], 0.9)), medians
    entry = summarize_maps(root / "linear.zarr")["propagation"]
    assert entry["parameters"] == ["Tt[r]"]
    assert set(entry["maps"]) == {f"{p}[{c}]" for p in ("Pd", "Ps") for c in "rgb"} | {"n"}
    for k, c in enumerate("rgb"):
        assert entry["maps"][f"Pd[{c}]"]["median_share"] == pytest.approx(medians[k], rel=1e-9)


def test_one_channel_leaves_out_the_other_channels_parameters(rgb):
    """--channel b through a medium fitted over r, g, b with Tt[r] and Tt[b] uncertain: only
    Tt[b] moves channel b's medium, so the record lists it alone and the map is that of the
    result with Tt[b]'s error alone, bit for bit."""
    root, manifest = rgb
    out = {}
    for name, errors in (("rb", {"Tt[r]": 0.02, "Tt[b]": 0.01}), ("b", {"Tt[b]": 0.01})):
        out[name] = root / f"blue-{name}.zarr"
        _fit(manifest.parent, manifest, _with_errors(errors), out[name], channel="b",
             propagation="linear")
    both, alone = open_maps(out["rb"]), open_maps(out["b"])
    assert both["info"]["propagation"]["parameters"] == ["Tt[b]"]
    assert alone["info"]["propagation"]["parameters"] == ["Tt[b]"]
    for name in ("params", "stderr", "stderr_medium", "status"):
        assert np.array_equal(both[name], alone[name]), name
    ok = both["status"] == CONVERGED
    assert np.all(both["stderr_medium"][list(FREE)][:, ok] > 0)


def test_the_figure_draws_the_medium_s_share_of_each_standard_error(grey_linear, tmp_path):
    """`veil maps show` of a store with the propagation: one panel per free parameter, its
    image the medium's part over the standard error at converged pixels (NaN elsewhere)."""
    from veil.maps.show import _panels, maps_figure

    store, maps, _ = grey_linear
    ok = maps["status"] == CONVERGED
    panels = {title: image for title, image, _, _ in _panels(maps)}
    for k in FREE:
        image = panels[f"medium's share of stderr of {NAMES[k]}"]
        np.testing.assert_allclose(image[ok], maps["stderr_medium"][k][ok] / maps["stderr"][k][ok],
                                   rtol=1e-12)
        assert np.all(np.isnan(image[~ok])) and np.all((image[ok] > 0) & (image[ok] <= 1))
    assert maps_figure(store, tmp_path / "maps.png").stat().st_size > 10_000


def test_a_wide_uncertainty_warns_only_for_the_map_s_own_parameters():
    """A medium parameter uncertain by more than a quarter of its value (the single fits'
    limit for sigma points): a MapsWarning naming it when the map propagates it (channel
    b), none for a map of another channel (r), which does not."""
    import warnings

    from veil.maps.geometry_notes import MapsWarning
    from veil.maps.medium_error import plan_spread

    base = medium_result()
    errors = {"Td[b]": 0.5, "Td[r]": 0.01}
    result = dataclasses.replace(
        base, stderr={k: errors.get(k, 0.0) * v for k, v in base.params.items()})
    for channel, expect in (("r", None), ("b", "Td[b] by 0.5")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            spread = plan_spread("linear", result, channel)
        assert spread.names == (f"Td[{channel}]",)
        said = [str(w.message) for w in caught if issubclass(w.category, MapsWarning)]
        assert said == [] if expect is None else (len(said) == 1 and expect in said[0]), said
