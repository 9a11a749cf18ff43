"""The model's own error in reflectance maps (docs/maps.md; docs/uncertainty.md "The model's
own error"): ``model_error="off" | "independent" | "correlated"`` of ``veil.fit_maps`` and
``--model-error`` of ``veil fit maps``. Synthetic photo stacks rendered at the maps' own
quadrature ("fast"), each pixel's values multiplied by (1 + d), d a draw of the Gaussian
process of veil.fitting.model_error (s = 4 %, ell = 40 deg, one draw per pixel), then 1 %
relative noise: the term is estimated near s, covers the true parameters near 95 % where the
noise alone covers them far less, is the sandwich of the pixel's own REML estimate, vanishes
on data with the noise alone, leaves "off" the map of before, bit for bit, and is part of
the store's inputs; over channels one term per channel."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import tifffile

import veil
from support.cli import run
from support.maps import angles_of, configurations, write_photos
from test_maps_channels import _medium, _vector, medium_result
from veil.engine.evaluator import ApparentModel
from veil.engine.quadrature import RULES
from veil.errors import InputError
from veil.fitting import model_error as me
from veil.maps.run import fit_maps, open_maps
from veil.maps.solve import CONVERGED, solve_pixels
from veil.maps.store import summarize_maps
from veil.maps.tables import build_tables

BRDF, MEDIUM = veil.BRDF1, veil.BTDF2
CLS = type(BRDF)
NAMES = CLS.param_names()                   # Pd, Ps, n, eta
PD, PS, SHAPE, INDEX = range(4)
FREE = (PD, PS, SHAPE)
FIX = {NAMES[INDEX]: float(BRDF.to_vector()[INDEX])}
GRID = f"{NAMES[SHAPE]}=0.25:2.5:16"
NOISE = 0.01
SIGMA, LENGTH = 0.04, 40.0                  # the injected relative model error and its ell
CONFIGS = 24
TILE = 8
H = W = 12                                  # the grey maps: four tiles (8x8, 8x4, 4x8, 4x4)
#: four materials (Pd factor, n), one per column modulo 4: every tile holds all four
MATERIALS = ((1.0, 0.6), (1.5, 0.9), (0.8, 1.3), (1.2, 0.45))
BASE_KEYS = {"params", "stderr", "chi2_reduced", "n_points", "status", "info"}


def _configs():
    return configurations(CONFIGS)


def _render(medium, angles, vectors: np.ndarray) -> np.ndarray:
    """Apparent values (P, M) at the maps' quadrature ("fast"): the data differ from the
    tables' model by the injected error and the noise only."""
    engine = ApparentModel(BRDF, medium, angles, RULES["fast"])
    uniq, inverse = np.unique(vectors, axis=0, return_inverse=True)
    values = np.array([engine.values(v, medium.to_vector()) for v in uniq])
    return values[inverse.ravel()]


def _draws(angles, count: int, rng) -> np.ndarray:
    """(count, M) relative errors d: the Gaussian process of veil.fitting.model_error
    (standard deviation SIGMA, correlation exp(-D / LENGTH)), one draw per row."""
    cov = SIGMA**2 * me.correlation(me.distances(angles), LENGTH)
    chol = np.linalg.cholesky(cov + 1e-12 * np.eye(len(cov)))
    return rng.standard_normal((count, len(cov))) @ chol.T


def _material_maps(h: int, w: int) -> np.ndarray:
    """(4, h, w) BRDF vectors: the materials by column."""
    pm = np.repeat(BRDF.to_vector()[:, None, None], h, 1).repeat(w, 2).astype(float)
    for x in range(w):
        pd, n = MATERIALS[x % len(MATERIALS)]
        pm[PD, :, x] *= pd
        pm[SHAPE, :, x] = n
    return pm


def _fit(photos, manifest, medium, out, **kw):
    return veil.fit_maps(photos, manifest, medium, out, fixed=FIX, grid=[GRID], tile=TILE,
                    accuracy="fast", **({"noise": (NOISE, 0.0)} | kw))


def _coverage(maps: dict, truth: np.ndarray, ok) -> list:
    """Per free parameter, the share of converged pixels whose truth is within 2 standard
    errors."""
    out = []
    for k in FREE:
        z = np.abs(maps["params"][k] - truth[k])[ok]
        out.append(float(np.mean(z < 2 * maps["stderr"][k][ok])))
    return out


def _channel_materials(c: str, h: int = 8, w: int = 8) -> np.ndarray:
    """(4, h, w) BRDF vectors of channel ``c`` of the RGB stacks (tests/test_maps_channels.py
    ``_vector``): the materials by column."""
    pm = np.stack([_vector(c, 1.0)] * (h * w), axis=1).reshape(len(NAMES), h, w)
    for x in range(w):
        pd, n = MATERIALS[x % len(MATERIALS)]
        pm[PD, :, x] *= pd
        pm[SHAPE, :, x] = n
    return pm


def _kind(info: dict) -> str:
    """The store's record of the kind: the kind itself, or a record whose "kind" it is."""
    record = info["model_error"]
    return record["kind"] if isinstance(record, dict) else record


def _tiles(h: int, w: int):
    for y0 in range(0, h, TILE):
        for x0 in range(0, w, TILE):
            yield slice(y0, y0 + TILE), slice(x0, x0 + TILE)


def _snapshot(store: Path) -> dict:
    """Every file inside a store: its bytes and modification time."""
    return {p.relative_to(store): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(store.rglob("*")) if p.is_file()}


# --------------------------------------------------------------------------------------
# grey stacks: one with the injected model error, one with the noise alone
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def grey(tmp_path_factory):
    root = tmp_path_factory.mktemp("model_error")
    configs = _configs()
    angles = angles_of(configs)
    truth = _material_maps(H, W)
    clean = _render(MEDIUM, angles, truth.reshape(len(NAMES), -1).T)          # (H*W, M)
    d = _draws(angles, H * W, np.random.default_rng(20261207))
    erred = write_photos(root / "erred", configs, clean * (1 + d), (H, W), NOISE, seed=1)
    plain = write_photos(root / "plain", configs, clean, (H, W), NOISE, seed=2)
    return {"root": root, "truth": truth, "angles": angles, "erred": erred, "plain": plain}


def _grey_map(grey, which: str, name: str, **kw):
    manifest = grey[which]
    out = grey["root"] / f"{which}-{name}.zarr"
    if not out.exists():
        _fit(manifest.parent, manifest, MEDIUM, out, **kw)
    return out, open_maps(out)


@pytest.fixture(scope="module")
def erred_off(grey):
    return _grey_map(grey, "erred", "off", model_error="off")


@pytest.fixture(scope="module")
def erred_default(grey):
    """The map without the keyword, and the fingerprint veil computed before the option
    (the acquisition's, the tables' and (noise, tile), as the run passes them, and since
    the noise is of the model's values that with its words, docs/maps-noise.md; "old" the
    legacy key without them, as a veil before that wrote it)."""
    import veil.maps.run as mr

    seen = []
    real = mr.store_attributes
    words = "relative noise of the model's values"

    def spy(acq, tables, cls, noise, tile, *rest, **kw):
        def key(legacy, of):
            text = acq.fingerprint(legacy=legacy) + tables.fingerprint() + repr((noise, tile))
            return hashlib.sha256((text + of).encode()).hexdigest()

        seen.append({False: key(False, words), True: key(True, words), "old": key(True, "")})
        return real(acq, tables, cls, noise, tile, *rest, **kw)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mr, "store_attributes", spy)
        out, maps = _grey_map(grey, "erred", "default")
    assert len(seen) == 1
    return out, maps, seen[0]


@pytest.fixture(scope="module")
def erred_correlated(grey):
    return _grey_map(grey, "erred", "correlated", model_error="correlated")


@pytest.fixture(scope="module")
def plain_correlated(grey):
    return _grey_map(grey, "plain", "correlated", model_error="correlated")


def test_a_smooth_model_error_is_estimated_and_its_errors_cover_the_truth(
        grey, erred_off, erred_correlated):
    """With the noise alone the standard errors cover the true parameters far less than
    95 % (the model error moves the estimates 2.5-5 noise standard errors); with the
    correlated term near 95 %, s near the injected 4 %, one ell per tile near the injected
    40 deg, the estimates and everything but the errors unchanged."""
    truth = grey["truth"]
    off_path, off = erred_off
    cor_path, cor = erred_correlated
    ok = cor["status"] == CONVERGED
    assert ok.mean() >= 0.85, np.unique(cor["status"], return_counts=True)

    # the estimates do not move; the noise-only errors are the map of "off"
    for name in ("params", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(cor[name], off[name]), name
    assert np.array_equal(cor["stderr_noise"], off["stderr"])
    assert set(off) == BASE_KEYS
    assert {"stderr_noise", "model_error", "model_error_length"} <= set(cor)
    assert cor["model_error"].shape == cor["model_error_length"].shape == (1, H, W)
    assert _kind(cor["info"]) == "correlated"
    for name in ("stderr", "stderr_noise", "model_error", "model_error_length"):
        assert np.all(np.isfinite(cor[name])), name
    assert np.all(cor["stderr"][:, ~ok] == 0) and np.all(cor["stderr"][INDEX] == 0)

    off_cover = _coverage(off, truth, ok)
    cor_cover = _coverage(cor, truth, ok)
    assert max(off_cover) <= 0.75 and off_cover[0] <= 0.5, off_cover
    assert min(cor_cover) >= 0.85, (cor_cover, off_cover)

    # the term adds to the noise's covariance: every error grows, by 1.5 or more typically
    grown = cor["stderr"][list(FREE)][:, ok] / cor["stderr_noise"][list(FREE)][:, ok]
    assert np.all(grown >= 1 - 1e-12)
    assert np.all(np.median(grown, axis=1) >= 1.5), np.median(grown, axis=1)

    s = cor["model_error"][0]
    assert np.mean(s[ok] > 0) >= 0.95
    assert SIGMA / 1.5 <= np.median(s[ok]) <= SIGMA * 1.5, np.median(s[ok])
    assert np.all(s >= 0) and np.all(s[~ok] == 0)
    length = cor["model_error_length"][0]
    for ys, xs in _tiles(H, W):
        shown = ok[ys, xs] & (s[ys, xs] > 0)
        lengths = np.unique(length[ys, xs][shown])
        assert len(lengths) == 1, (ys, xs, lengths)           # one ell per tile
        assert lengths[0] in (20.0, 40.0, 80.0), (ys, xs, lengths)

    summary = json.loads((cor_path / "summary.json").read_text())
    assert "correlated" in json.dumps(summary["model_error"])
    assert summarize_maps(cor_path)["model_error"] == summary["model_error"]


@pytest.fixture(scope="module")
def fast_tables(grey):
    """The maps' tables, built as the runs build them."""
    return build_tables(CLS, MEDIUM, grey["angles"], fixed=FIX,
                        grid={NAMES[SHAPE]: (0.25, 2.5, 16)}, accuracy="fast")


def _photos(manifest) -> np.ndarray:
    """(M, H, W) the values of the stack's photos, as written."""
    files = [manifest.parent / f"photo_{k:03d}.tif" for k in range(CONFIGS)]
    return np.stack([tifffile.imread(f).astype(np.float64) for f in files])


def _pixel(maps, photos, tables, py, px, usable=None) -> tuple:
    """(weighted residuals, f / sigma, J_w, C = (J_w^T J_w)^-1) of a pixel at its estimate
    over its ``usable`` samples (all by default), sigma = NOISE f_1, f_1 the model's values
    at the first solution (:func:`solve_pixels` of the samples' own noise); J_w of its free
    Pd, Ps and n."""
    pd, ps, n = maps["params"][list(FREE), py, px]
    h = 1e-5 * n
    b, bp, bm = (tables.basis({NAMES[SHAPE]: v}) for v in (n, n + h, n - h))

    def model(cols):
        return pd * cols[:, 0] + ps * cols[:, 1] + cols[:, 2]

    f = model(b)
    jac = np.stack([b[:, 0], b[:, 1], (model(bp) - model(bm)) / (2 * h)], axis=1)
    y = photos[:, py, px]
    keep = np.ones(len(y), bool) if usable is None else usable
    # the noise of the model's values at a first solution, that of the samples' own
    # (docs/maps-noise.md)
    first = solve_pixels(tables, y[None, :], keep[None, :], noise=(NOISE, 0.0))
    assert first.status[0] == CONVERGED
    fd, fs, fn = first.params[list(FREE), 0]
    b1 = tables.basis({NAMES[SHAPE]: fn})
    w = 1 / (NOISE * (fd * b1[:, 0] + fs * b1[:, 1] + b1[:, 2])[keep])
    jw = jac[keep] * w[:, None]
    return (y[keep] - f[keep]) * w, f[keep] * w, jw, np.linalg.inv(jw.T @ jw)


def _check_term(maps, photos, tables, dist, py, px, usable=None) -> None:
    """The pixel's noise-only errors are sqrt(diag C); its s is the restricted likelihood's
    estimate at its ell (veil.fitting.model_error.estimate); its errors sqrt(diag) of the
    sandwich with that s and ell."""
    r, a, jw, cov = _pixel(maps, photos, tables, py, px, usable)
    if usable is not None:
        dist = dist[np.ix_(usable, usable)]
    where = (slice(None), py, px)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), maps["stderr_noise"][list(FREE)][where],
                               rtol=2e-3, err_msg=f"pixel {(py, px)}")
    s = float(maps["model_error"][0, py, px])
    ell = float(maps["model_error_length"][0, py, px])
    assert s > 0 and ell in me.LENGTHS[1:], (py, px, s, ell)
    own, _ = me.estimate(r, a, len(r) - len(FREE), dist, (ell,), jw)
    assert own == pytest.approx(s, rel=1e-2), (py, px)
    full = me.sandwich(cov, jw, a, s, me.correlation(dist, ell))
    np.testing.assert_allclose(np.sqrt(np.diag(full)), maps["stderr"][list(FREE)][where],
                               rtol=1e-2, err_msg=f"pixel {(py, px)}")


def test_the_term_is_the_sandwich_of_each_pixels_own_reml_estimate(grey, erred_correlated,
                                                                   fast_tables):
    """Recomputed from the photos and the tables: the first tile's ell maximizes the
    restricted likelihood summed over its pixels; for a dozen pixels the noise-only errors,
    s (veil.fitting.model_error.estimate at that ell, restricted to the complement of J_w)
    and the errors (veil.fitting.model_error.sandwich) are the pixel's own."""
    _, cor = erred_correlated
    photos = _photos(grey["erred"])
    dist = me.distances(grey["angles"])
    ok = cor["status"] == CONVERGED

    # the first tile (8 x 8, at most 64 converged pixels: all of them in its sample): its
    # ell maximizes the restricted likelihood summed over its pixels, each at its best s
    first = np.argwhere(ok[:TILE, :TILE])
    assert len(first) >= 56
    total = np.zeros(len(me.LENGTHS))
    for py, px in first:
        r, a, jw, _ = _pixel(cor, photos, fast_tables, py, px)
        basis = np.linalg.svd(jw, full_matrices=True)[0][:, len(FREE):]
        z = basis.T @ r
        for j, ell in enumerate(me.LENGTHS):
            s, _ = me.estimate(r, a, CONFIGS - 3, dist, (ell,), jw)
            assert s > 0
            corr = np.eye(CONFIGS) if ell == 0 else me.correlation(dist, ell)
            cov = np.eye(CONFIGS - 3) + s**2 * basis.T @ (a[:, None] * corr * a) @ basis
            total[j] += 0.5 * (np.linalg.slogdet(cov)[1] + z @ np.linalg.solve(cov, z))
    chosen = me.LENGTHS[int(np.argmin(total))]
    assert np.all(cor["model_error_length"][0, :TILE, :TILE][ok[:TILE, :TILE]] == chosen), (
        chosen, total)

    pixels = np.argwhere(ok)[:: max(1, int(ok.sum()) // 12)][:12]
    assert len(pixels) >= 10
    for py, px in pixels:
        _check_term(cor, photos, fast_tables, dist, py, px)


def test_a_pixel_with_saturated_photos_has_the_term_of_its_usable_samples(grey, fast_tables,
                                                                          erred_correlated):
    """The brightest 2 % of the samples saturated (--saturation): a pixel's term is that of
    its usable samples alone - its dof, residuals, Jacobian and distances without the others."""
    manifest = grey["erred"]
    photos = _photos(manifest)
    level = float(np.quantile(photos, 0.98))
    out = grey["root"] / "erred-saturated.zarr"
    _fit(manifest.parent, manifest, MEDIUM, out, model_error="correlated", saturation=level)
    maps = open_maps(out)
    ok = maps["status"] == CONVERGED
    partial = np.argwhere(ok & (maps["n_points"] < CONFIGS))
    assert len(partial) >= 3, maps["n_points"]
    dist = me.distances(grey["angles"])
    for py, px in partial[:6]:
        usable = photos[:, py, px] < level
        assert maps["n_points"][py, px] == usable.sum()
        _check_term(maps, photos, fast_tables, dist, py, px, usable)
    # the other pixels are those of the map without saturation (their term too, where
    # their tile chose the same ell)
    _, whole = erred_correlated
    full = ok & (maps["n_points"] == CONFIGS)
    for name in ("params", "stderr_noise"):
        assert np.array_equal(maps[name][:, full], whole[name][:, full]), name
    same_ell = full & (maps["model_error_length"][0] == whole["model_error_length"][0])
    assert same_ell.sum() >= 0.5 * full.sum()
    for name in ("stderr", "model_error"):
        assert np.array_equal(maps[name][:, same_ell], whole[name][:, same_ell]), name


def test_independent_uses_no_correlation_and_does_not_move_the_estimates(grey, erred_off):
    _, off = erred_off
    _, ind = _grey_map(grey, "erred", "independent", model_error="independent")
    assert _kind(ind["info"]) == "independent"
    ok = ind["status"] == CONVERGED
    for name in ("params", "chi2_reduced", "status"):
        assert np.array_equal(ind[name], off[name]), name
    assert np.array_equal(ind["stderr_noise"], off["stderr"])
    assert np.all(ind["model_error_length"] == 0)
    assert np.mean(ind["model_error"][0][ok] > 0) >= 0.95
    assert np.all(ind["stderr"][list(FREE)][:, ok] > ind["stderr_noise"][list(FREE)][:, ok])


def test_data_with_the_noise_alone_keep_the_noise_errors(plain_correlated):
    """The term is 0 where the pixel's reduced chi-square is not above 1 + 2 sqrt(2 / dof)
    - most pixels of data that carry only their declared noise - and there the errors are
    the noise's, bit for bit; s > 0 exactly where the chi-square is above the limit."""
    _, maps = plain_correlated
    ok = maps["status"] == CONVERGED
    assert ok.mean() >= 0.9
    s = maps["model_error"][0]
    zero = ok & (s == 0)
    assert zero.sum() >= 0.9 * ok.sum(), (zero.sum(), ok.sum())
    assert np.array_equal(maps["stderr"][:, zero], maps["stderr_noise"][:, zero])
    dof = maps["n_points"] - len(FREE)
    limit = np.vectorize(me.chi2_threshold)(np.maximum(dof, 1))
    chi2 = maps["chi2_reduced"]
    assert not np.any(ok & (s > 0) & (chi2 <= limit * (1 - 1e-9)))
    assert not np.any(ok & (s == 0) & (chi2 > limit * (1 + 1e-9)))


def test_off_is_the_map_of_before_bit_for_bit(erred_off, erred_default):
    (off_path, off), (default_path, default, before) = erred_off, erred_default
    assert default["info"]["fingerprint"] == before[False]
    assert set(off) == set(default) == BASE_KEYS
    for name in BASE_KEYS - {"info"}:
        assert np.array_equal(off[name], default[name]), name
    assert off["info"] == default["info"]
    assert off["info"]["fingerprint"] == default["info"]["fingerprint"]
    assert "model_error" not in off["info"]
    assert (off_path / "summary.json").read_text() == (default_path / "summary.json").read_text()


# --------------------------------------------------------------------------------------
# the command: bad input, and the kind is one of the store's inputs
# --------------------------------------------------------------------------------------
def _cli_args(manifest, out, *extra):
    return ["fit", "maps", manifest.parent, "--manifest", manifest, "--medium", "BTDF2",
            "--fix", f"{NAMES[INDEX]}={FIX[NAMES[INDEX]]}", "--grid", GRID, "--tile", TILE,
            "--accuracy", "fast", "-o", out, *extra]


def test_bad_kinds_and_a_term_without_noise_exit_2_writing_nothing(grey, tmp_path):
    manifest = grey["erred"]
    out = tmp_path / "bad.zarr"
    bogus = run(*_cli_args(manifest, out, "--noise", NOISE, "--model-error", "bogus"))
    assert bogus.exit_code == 2, bogus.output
    for kind in me.KINDS:
        assert kind in bogus.output, bogus.output
    for kind in ("correlated", "independent"):
        no_noise = run(*_cli_args(manifest, out, "--model-error", kind))
        assert no_noise.exit_code == 2, no_noise.output
        assert "noise" in no_noise.output and "Traceback" not in no_noise.output
        with pytest.raises(InputError):
            fit_maps(manifest.parent, manifest, MEDIUM, out, fixed=FIX, grid=[GRID],
                     tile=TILE, accuracy="fast", model_error=kind)
    with pytest.raises(InputError):
        _fit(manifest.parent, manifest, MEDIUM, out, model_error="bogus")
    assert not out.exists()
    # "off" needs no noise: an unweighted map as before
    plain = run(*_cli_args(manifest, out, "--model-error", "off", "--roi", "0,0,4,4"))
    assert plain.exit_code in (0, 1) and "nothing to compute" not in plain.output, plain.output
    assert set(open_maps(out)) == BASE_KEYS


def test_a_store_of_another_kind_is_refused_and_left_untouched(grey, erred_off,
                                                               erred_correlated, tmp_path):
    """The kind is one of the store's inputs: an "off" store rerun with a term, or one with
    a term rerun with "off", exits 2 and nothing is touched; the same kind again has
    nothing to compute."""
    manifest = grey["erred"]
    for (src, _), kind, other in ((erred_off, "off", "correlated"),
                                  (erred_correlated, "correlated", "off")):
        store = tmp_path / f"{kind}.zarr"
        shutil.copytree(src, store)
        failed = json.loads((store / "summary.json").read_text())["failed"]
        same = run(*_cli_args(manifest, store, "--noise", NOISE, "--model-error", kind))
        assert same.exit_code == (1 if failed else 0), same.output
        assert "nothing to compute" in same.output, same.output
        before = _snapshot(store)
        refused = run(*_cli_args(manifest, store, "--noise", NOISE, "--model-error", other))
        assert refused.exit_code == 2, (kind, other, refused.output)
        assert "Traceback" not in refused.output
        assert _snapshot(store) == before, (kind, other)
    # the default kind of the command is "off": it resumes the "off" store
    default = run(*_cli_args(manifest, tmp_path / "off.zarr", "--noise", NOISE))
    assert "nothing to compute" in default.output, default.output


# --------------------------------------------------------------------------------------
# a map over channels: one term per channel
# --------------------------------------------------------------------------------------
HC = WC = 8


def test_over_channels_one_term_per_channel(tmp_path_factory):
    """RGB photos, each channel through its medium, the injected error in red only: s > 0
    in red on most pixels, 0 in green and blue on most; red's errors grow, the estimates
    are those of "off"."""
    root = tmp_path_factory.mktemp("model_error_rgb")
    configs = _configs()
    angles = angles_of(configs)
    maps = {c: _channel_materials(c) for c in "rgb"}
    values = np.stack([_render(_medium(c), angles, maps[c].reshape(len(NAMES), -1).T)
                       for c in "rgb"], axis=-1)                         # (H*W, M, 3)
    values[:, :, 0] *= 1 + _draws(angles, HC * WC, np.random.default_rng(7))
    manifest = write_photos(root / "photos", configs, values, (HC, WC), NOISE, seed=3)
    medium = medium_result()
    off = open_maps(_rgb(manifest, medium, root, "off"))
    cor = open_maps(_rgb(manifest, medium, root, "correlated"))
    ok = cor["status"] == CONVERGED
    assert ok.mean() >= 0.85
    assert not {"stderr_noise", "channel_stderr_noise", "model_error"} & set(off)
    for name in ("params", "channel_params", "chi2_reduced", "status"):
        assert np.array_equal(cor[name], off[name]), name
    assert np.array_equal(cor["stderr_noise"], off["stderr"])
    assert np.array_equal(cor["channel_stderr_noise"], off["channel_stderr"])
    assert cor["channel_stderr_noise"].shape == cor["channel_stderr"].shape == (2, 3, HC, WC)
    assert cor["stderr_noise"].shape == cor["stderr"].shape
    assert cor["model_error"].shape == cor["model_error_length"].shape == (3, HC, WC)
    s = cor["model_error"]
    assert np.mean(s[0][ok] > 0) >= 0.9, s[0]
    assert SIGMA / 1.5 <= np.median(s[0][ok]) <= SIGMA * 1.5, np.median(s[0][ok])
    for k in (1, 2):  # (measured 0.89 in green: the residuals of the noise of the model's
        # values, docs/maps-noise.md, are not damped as those of the samples' own were)
        assert np.mean(s[k][ok] == 0) >= 0.85, ("rgb"[k], s[k])
    # red's scales and the shared n carry the term
    red = cor["channel_stderr"][:, 0][:, ok] / cor["channel_stderr_noise"][:, 0][:, ok]
    assert np.all(np.median(red, axis=1) >= 1.5), np.median(red, axis=1)
    shared = cor["stderr"][0][ok] / cor["stderr_noise"][0][ok]
    assert np.median(shared) >= 1.2, np.median(shared)
    # where no channel shows an error every error is the noise's, bit for bit
    none = ok & np.all(s == 0, axis=0)
    assert np.array_equal(cor["channel_stderr"][..., none], cor["channel_stderr_noise"][..., none])
    assert np.array_equal(cor["stderr"][:, none], cor["stderr_noise"][:, none])
    lengths = cor["model_error_length"][0][ok & (s[0] > 0)]
    assert len(np.unique(lengths)) == 1 and lengths[0] in (20.0, 40.0, 80.0), lengths


def _rgb(manifest, medium, root, kind) -> Path:
    out = root / f"{kind}.zarr"
    _fit(manifest.parent, manifest, medium, out, channel="rgb", model_error=kind)
    return out


def test_a_store_of_an_earlier_veil_is_not_resumed_with_a_term(grey, erred_default, tmp_path):
    """A store written by a veil before content keys (its fingerprint the legacy key: the
    photos' paths, sizes and modification times) resumes with the same settings; it was
    written without a term, so with --model-error correlated it is refused and untouched,
    as a store of this veil is."""
    import zarr

    src, _, keys = erred_default
    manifest = grey["erred"]
    store = tmp_path / "legacy.zarr"
    shutil.copytree(src, store)
    group = zarr.open_group(str(store), mode="r+")
    group.attrs["veil_maps"] = dict(group.attrs["veil_maps"], fingerprint=keys[True])
    failed = json.loads((store / "summary.json").read_text())["failed"]
    same = run(*_cli_args(manifest, store, "--noise", NOISE))
    assert same.exit_code == (1 if failed else 0) and "nothing to compute" in same.output, (
        same.output)
    before = _snapshot(store)
    refused = run(*_cli_args(manifest, store, "--noise", NOISE, "--model-error", "correlated"))
    assert refused.exit_code == 2, refused.output
    assert _snapshot(store) == before
    # a store weighted by the samples' values (a veil before docs/maps-noise.md) is refused
    group.attrs["veil_maps"] = dict(group.attrs["veil_maps"], fingerprint=keys["old"])
    before = _snapshot(store)
    older = run(*_cli_args(manifest, store, "--noise", NOISE))
    assert older.exit_code == 2 and "other settings" in older.output, older.output
    assert _snapshot(store) == before


def test_an_interrupted_map_with_a_term_resumes_to_the_same_bits(grey, erred_correlated,
                                                                 tmp_path, monkeypatch):
    """Tiles are written with their term: a run interrupted after two tiles resumes with the
    other two, to the uninterrupted map bit for bit; a chunk of a new array missing from the
    complete store is damage, named."""
    import veil.maps.run as mr
    from veil.maps.store import DamagedStoreError

    manifest = grey["erred"]
    _, whole = erred_correlated
    part = tmp_path / "part.zarr"
    calls = []
    real = mr.solve_tile

    def flaky(*args, **kw):
        calls.append(1)
        if len(calls) > 2:
            raise KeyboardInterrupt
        return real(*args, **kw)

    monkeypatch.setattr(mr, "solve_tile", flaky)
    with pytest.raises(KeyboardInterrupt):
        _fit(manifest.parent, manifest, MEDIUM, part, model_error="correlated", workers=1)
    monkeypatch.setattr(mr, "solve_tile", real)
    resumed = _fit(manifest.parent, manifest, MEDIUM, part, model_error="correlated")
    assert resumed.tiles_reused == 2 and resumed.tiles_computed == 2
    again = open_maps(part)
    assert set(again) == set(whole)
    for name in set(whole) - {"info"}:
        assert np.array_equal(again[name], whole[name]), name
    exported = run("maps", "export", part, "-o", tmp_path / "export")
    assert exported.exit_code == 0, exported.output
    assert "model_error" in json.loads((tmp_path / "export" / "summary.json").read_text())
    for name in ("model_error", "stderr_noise"):
        damaged = tmp_path / f"damaged-{name}.zarr"
        shutil.copytree(part, damaged)
        chunk = next(p for p in sorted((damaged / name).rglob("*"))
                     if p.is_file() and p.name != "zarr.json")
        chunk.unlink()
        with pytest.raises(DamagedStoreError, match=name):
            open_maps(damaged)


def test_the_term_is_exported_and_drawn(erred_correlated, erred_off, tmp_path):
    """`veil maps export` writes the relative error s and each free parameter's noise-only
    standard errors beside the others (those of a map without a term: not written); the
    figure has a panel of s, NaN where a pixel did not converge."""
    from veil.maps.show import _panels, export_maps, maps_figure

    out, maps = erred_correlated
    ok = maps["status"] == CONVERGED
    written = {p.name for p in export_maps(out, tmp_path / "exp", formats=("tiff",))}
    s = tifffile.imread(tmp_path / "exp" / "model_error.tif")
    assert np.array_equal(s, np.where(ok, maps["model_error"][0], 0.0).astype(np.float32))
    for k in FREE:
        noise = tifffile.imread(tmp_path / "exp" / f"{NAMES[k]}_stderr_noise.tif")
        want = np.where(ok, maps["stderr_noise"][k], 0.0).astype(np.float32)
        assert np.array_equal(noise, want), NAMES[k]
        with_term = tifffile.imread(tmp_path / "exp" / f"{NAMES[k]}_stderr.tif")
        assert np.all(with_term[ok] >= noise[ok]) and np.any(with_term[ok] > noise[ok])
    plain = {p.name for p in export_maps(erred_off[0], tmp_path / "plain", formats=("tiff",))}
    assert written - plain == {"model_error.tif"} | {f"{NAMES[k]}_stderr_noise.tif" for k in FREE}
    [(title, image, _, _)] = [p for p in _panels(maps) if p[0].startswith("model error")]
    assert title == "model error s"
    assert np.array_equal(image[ok], maps["model_error"][0][ok]) and np.all(np.isnan(image[~ok]))
    assert not [p for p in _panels(erred_off[1]) if p[0].startswith("model error")]
    assert maps_figure(out, tmp_path / "maps.png").stat().st_size > 0


def test_an_independent_term_takes_no_length_from_a_correlated_given_one():
    """step_term with kind "independent" and a given medium's correlated term larger than
    its own: the given s, and ell 0 (the kind's promise), where a correlated kind keeps the
    given length."""
    rng = np.random.default_rng(3)
    angles = angles_of(_configs())
    m = len(angles[0])
    values = np.ones(m)
    residuals = 0.2 * rng.standard_normal(m)  # no excess: the own s is 0
    given = me.ModelError(0.05, 40.0, 0.05, None, "own residuals", 1.2)
    term = me.step_term(residuals, values, 1 / NOISE * values, m - 3, angles, given=given,
                        kind="independent")
    assert (term.sigma, term.length, term.source) == (0.05, 0.0, "given medium")
    term = me.step_term(residuals, values, 1 / NOISE * values, m - 3, angles, given=given,
                        kind="correlated")
    assert (term.sigma, term.length) == (0.05, 40.0)


def test_a_weighted_map_without_the_term_says_when_the_model_misses(grey, tmp_path):
    """Without --model-error the command notes a median reduced chi-square above the test's
    limit (the photos with the injected error) and says how to add the term; on photos with
    the noise alone it says nothing; with the term it prints the term's line instead."""
    note = "standard errors count the noise alone"
    erred = run(*_cli_args(grey["erred"], tmp_path / "e.zarr", "--noise", NOISE))
    assert erred.exit_code in (0, 1) and note in erred.output, erred.output
    assert "--model-error correlated" in erred.output
    plain = run(*_cli_args(grey["plain"], tmp_path / "p.zarr", "--noise", NOISE))
    assert plain.exit_code in (0, 1) and note not in plain.output, plain.output
    term = run(*_cli_args(grey["erred"], tmp_path / "t.zarr", "--noise", NOISE,
                          "--model-error", "correlated"))
    assert note not in term.output and "model error (correlated" in term.output, term.output
