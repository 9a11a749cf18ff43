"""Maps over colour channels (issue 30 item 4; docs/maps-channels.md): every channel of a
pixel one least-squares problem, the scales per channel through each channel's medium and
the roughness shared; the tables of every channel each channel's own, the engine run once
for channels whose media differ in scales; the fast solve against the full fit over
channels; the command on an RGB stack, its store and its RGB EXR/TIFF export; one channel
of a medium fitted over several; bad input."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import tifffile

import veil
from support.cli import run
from support.maps import angles_of, configurations, render, write_colour_stack, write_stack
from veil.engine.evaluator import ApparentModel
from veil.fitting import FitResult
from veil.fitting.channel_fit import channel_layout
from veil.maps.channels import build_channel_tables
from veil.maps.run import fit_maps, open_maps
from veil.maps.solve import CONVERGED, solve_pixels
from veil.maps.solve_channels import solve_channel_pixels
from veil.maps.tables import build_tables

BRDF, MEDIUM = veil.BRDF1, veil.BTDF2
CLS = type(BRDF)
NAMES = CLS.param_names()                 # Pd, Ps, n, eta
PD, PS, SHAPE, INDEX = range(4)
FIX = {NAMES[INDEX]: float(BRDF.to_vector()[INDEX])}
GRID = {NAMES[SHAPE]: (0.25, 2.5, 16)}
#: the medium's scales (T_d, T_t) per channel: a water that dims red
DIM = {"r": 0.6, "g": 1.0, "b": 1.5}
#: the target's scales per channel: a bluish surface, its specular scale less coloured
ALBEDO = {"r": 0.5, "g": 1.0, "b": 2.0}
SPECULAR = {"r": 0.8, "g": 1.0, "b": 1.25}


def _medium(c: str, dim=DIM):
    return MEDIUM.replace(Td=MEDIUM.Td * dim[c], Tt=MEDIUM.Tt * dim[c])


def medium_result(dim=DIM) -> FitResult:
    """A step-1 result over the channels of ``dim``, each channel's medium :func:`_medium`."""
    cls = type(MEDIUM)
    slots, layout = channel_layout(cls, list(dim), "medium")
    params = {}
    for s in slots:
        m = _medium(next(iter(dim)) if s.owner == "*" else s.owner, dim)
        params[s.name] = float(getattr(m, s.spec.name))
    return FitResult(model=cls.NAME, params=params, stderr={k: 0.0 for k in params},
                     correlation={}, residuals=tuple([0.0] * 10), chi2_reduced=1.0,
                     rms_relative=0.0, n_points=10, converged=True, message="synthetic",
                     step="medium", options=MEDIUM.options(), channels=layout)


def _vector(c: str, n: float, pd: float = 1.0):
    v = BRDF.to_vector().copy()
    v[PD] *= ALBEDO[c] * pd
    v[PS] *= SPECULAR[c]
    v[SHAPE] = n
    return v


# --------------------------------------------------------------------------------------
# the tables
# --------------------------------------------------------------------------------------
def test_each_channels_tables_are_its_own_and_scales_share_the_engine(monkeypatch):
    """The tables over channels hold, channel by channel, exactly (bit for bit) the tables
    of that channel alone; channels whose media differ only in scales run the engine once
    per node, media differing in g once per channel and node."""
    angles = angles_of(configurations(12))
    calls = []
    real = ApparentModel.terms

    def counted(self, vb, vm):
        calls.append(1)
        return real(self, vb, vm)

    monkeypatch.setattr(ApparentModel, "terms", counted)
    media = {c: _medium(c) for c in "rgb"}
    tables = build_channel_tables(CLS, media, angles, fixed=FIX, grid=GRID, accuracy="fast")
    assert len(calls) == GRID[NAMES[SHAPE]][2]          # one engine call per node
    assert tables.values.shape == (16, 3, 12, 3) and tables.channels == ("r", "g", "b")
    for k, c in enumerate("rgb"):
        alone = build_tables(CLS, media[c], angles, fixed=FIX, grid=GRID, accuracy="fast")
        assert np.array_equal(tables.values[:, k], alone.values), c
        assert np.array_equal(tables.coef[:, k], alone.coef), c
    assert not np.array_equal(tables.values[:, 0], tables.values[:, 2])
    calls.clear()
    other = {c: media[c].replace(g=g) for c, g in zip("rgb", (0.9, 0.93, 0.95))}
    tables = build_channel_tables(CLS, other, angles, fixed=FIX, grid=GRID, accuracy="fast")
    assert len(calls) == 3 * 16
    alone = build_tables(CLS, other["b"], angles, fixed=FIX, grid=GRID, accuracy="fast")
    assert np.array_equal(tables.values[:, 2], alone.values)


def test_waters_differing_in_optical_depth_share_one_program_per_node(monkeypatch):
    """Forward-series waters whose tau and omega differ per channel: one run of the
    channels' program per node of the table for all three (veil.engine.channel_programs),
    each channel's tables within 0.5 % of its water's alone, not another's."""
    from veil.engine import channel_programs, forward
    from veil.models import model_class

    series = model_class("forward-series")
    media = {c: series(tau=t, omega=w, g=0.9, path_length=15.0, plate_width=5.0)
             for c, t, w in zip("rgb", (0.45, 0.3, 0.15), (0.95, 0.97, 0.99))}
    angles = angles_of(configurations(12))
    runs = []
    real = forward.Forward._run

    def counted(self, fn, vb, vm):
        runs.append(fn)
        return real(self, fn, vb, vm)

    monkeypatch.setattr(forward.Forward, "_run", counted)
    grid = {NAMES[SHAPE]: (0.25, 2.5, 4)}
    tables = build_channel_tables(CLS, media, angles, fixed=FIX, grid=grid, accuracy="fast")
    assert len(runs) == 4 and all(channel_programs.is_channel_program(f) for f in runs)
    for k, c in enumerate("rgb"):
        alone = build_tables(CLS, media[c], angles, fixed=FIX, grid=grid, accuracy="fast")
        scale = np.max(np.abs(alone.values))
        assert np.max(np.abs(tables.values[:, k] - alone.values)) < 5e-3 * scale, c
    assert np.max(np.abs(tables.values[:, 0] - tables.values[:, 2])) > 0.05 * scale


# --------------------------------------------------------------------------------------
# the solve
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pixels():
    """Pixels of per-channel scales and a shared n off the table's nodes, each channel
    through its medium, 1 % noise: (configurations, media, truth {c: (P, 4)}, y (P, 3, M))."""
    configs = configurations(20)
    media = {c: _medium(c) for c in "rgb"}
    rng = np.random.default_rng(5)
    ns = np.exp(rng.uniform(np.log(0.4), np.log(1.6), 4))
    pds = np.exp(rng.uniform(-0.3, 0.3, 4))
    truth = {c: np.array([_vector(c, n, pd) for n, pd in zip(ns, pds)]) for c in "rgb"}
    clean = np.stack([render(BRDF, media[c], configs, truth[c]) for c in "rgb"], axis=1)
    y = clean * (1 + 0.01 * rng.standard_normal(clean.shape))
    return configs, media, truth, y


def test_per_channel_scales_and_shared_roughness_recovered(pixels):
    """Each pixel's scales per channel and its one n; each channel's scales the exact
    non-negative least-squares optimum of that channel at the shared n (on the tables'
    own columns), and within 1e-4 of a one-channel fit of that channel with n fixed there
    (the engine's columns at that n)."""
    configs, media, truth, y = pixels
    angles = angles_of(configs)
    tables = build_channel_tables(CLS, media, angles, fixed=FIX, grid=GRID, accuracy="fast")
    fits = solve_channel_pixels(tables, y, np.ones_like(y, bool), noise=(0.01, 0.0))
    assert np.all(fits.status == CONVERGED)
    assert fits.shared == (SHAPE, INDEX) and fits.per_channel == (PD, PS)
    assert fits.channel_params.shape == (2, 3, len(y)) and fits.params.shape == (2, len(y))
    assert np.all(fits.params[1] == FIX[NAMES[INDEX]])
    for k, c in enumerate("rgb"):
        for j, i in enumerate((PD, PS)):
            z = (fits.channel_params[j, k] - truth[c][:, i]) / fits.channel_stderr[j, k]
            assert np.all(np.abs(z) < 4), (c, NAMES[i], z)
    z = (fits.params[0] - truth["r"][:, SHAPE]) / fits.stderr[0]
    assert np.all(np.abs(z) < 4), z
    for p in range(len(y)):
        n_hat = fits.params[0, p]
        basis = tables.basis({NAMES[SHAPE]: n_hat})                 # (3, M, 3)
        for k, c in enumerate("rgb"):
            w = 1 / (0.01 * y[p, k])
            s, *_ = np.linalg.lstsq(basis[k, :, :2] * w[:, None], (y[p, k] - basis[k, :, 2]) * w,
                                    rcond=None)
            np.testing.assert_allclose(fits.channel_params[:, k, p], s, rtol=1e-9)
            fixed = build_tables(CLS, media[c], angles, fixed=FIX | {NAMES[SHAPE]: n_hat},
                                 accuracy="fast")
            one = solve_pixels(fixed, y[p:p + 1, k], np.ones((1, y.shape[2]), bool),
                               noise=(0.01, 0.0))
            np.testing.assert_allclose(fits.channel_params[:, k, p], one.params[[PD, PS], 0],
                                       rtol=1e-4)


def test_fast_solve_agrees_with_the_full_fit_over_channels(pixels):
    """veil.fit_target over the channels (one problem, each channel through its medium, n
    tied) and the per-pixel solve over channels agree within 0.1 standard error, their
    standard errors within 5 % and their reduced chi-square within 0.1 % (same quadrature)."""
    configs, media, _, y = pixels
    tables = build_channel_tables(CLS, media, angles_of(configs), fixed=FIX,
                                  grid={NAMES[SHAPE]: (0.25, 2.5, 24)}, accuracy="fast")
    fits = solve_channel_pixels(tables, y[:1], np.ones_like(y[:1], bool), noise=(0.01, 0.0))
    table = pd_concat([configs.assign(channel=c, value=y[0, k], sigma=0.01 * y[0, k])
                       for k, c in enumerate("rgb")])
    full = veil.fit_target(table, medium_result(), fixed=FIX, accuracy="fast")
    assert full.converged and full.channel_names == ("r", "g", "b")
    pairs = [(f"{NAMES[i]}[{c}]", fits.channel_params[j, k, 0], fits.channel_stderr[j, k, 0])
             for j, i in enumerate((PD, PS)) for k, c in enumerate("rgb")]
    pairs.append((NAMES[SHAPE], fits.params[0, 0], fits.stderr[0, 0]))
    for name, value, se in pairs:
        assert abs(value - full.params[name]) < 0.1 * full.stderr[name], name
        assert se == pytest.approx(full.stderr[name], rel=0.05), name
    assert fits.chi2[0] == pytest.approx(full.chi2_reduced, rel=1e-3)


def pd_concat(parts):
    import pandas as pd

    return pd.concat(parts, ignore_index=True)


# --------------------------------------------------------------------------------------
# the command on an RGB stack
# --------------------------------------------------------------------------------------
H, W = 8, 10


@pytest.fixture(scope="module")
def rgb_stack(tmp_path_factory):
    """RGB photos of a plate whose albedo varies down the plate and differs per channel and
    whose n varies across it, each channel through its medium; the medium's result file."""
    root = tmp_path_factory.mktemp("rgb")
    yy, xx = np.mgrid[0:H, 0:W]
    ns = np.round(0.5 * np.exp(np.log(3.0) * xx / (W - 1)), 3)
    maps = {}
    for c in "rgb":
        v = _vector(c, 1.0)
        m = np.repeat(v[:, None, None], H, 1).repeat(W, 2).astype(float)
        m[PD] *= np.round(1 + yy / H, 2)
        m[SHAPE] = ns
        maps[c] = m
    media = {c: _medium(c) for c in "rgb"}
    manifest = write_colour_stack(root / "photos", BRDF, media, configurations(16), maps)
    medium_result().to_json(root / "medium.json")
    return root, manifest, maps


def fit_args(root, manifest, out, *extra):
    return ["fit", "maps", root / "photos", "--manifest", manifest, "--medium",
            root / "medium.json", "--fix", f"{NAMES[INDEX]}={FIX[NAMES[INDEX]]}", "--grid",
            f"{NAMES[SHAPE]}=0.25:2.5:16", "--tile", 8, "--noise", 0.01, "-o", out, *extra]


def test_an_rgb_map_its_store_and_its_rgb_export(rgb_stack, tmp_path):
    OpenEXR = pytest.importorskip("OpenEXR")
    root, manifest, truth = rgb_stack
    out = tmp_path / "maps.zarr"
    result = run(*fit_args(root, manifest, out, "--channel", "rgb"))
    assert result.exit_code == 0, result.output
    assert "Pd[b]: median" in result.output
    maps = open_maps(out)
    info = maps["info"]
    assert info["channels"] == ["r", "g", "b"] and info["channel_params"] == ["Pd", "Ps"]
    assert info["params"] == ["n", "eta"] and info["channel"] == "rgb"
    assert maps["channel_params"].shape == (2, 3, H, W) and maps["params"].shape == (2, H, W)
    ok = maps["status"] == CONVERGED
    assert ok.all()
    for k, c in enumerate("rgb"):
        for j, i in enumerate((PD, PS)):
            z = (maps["channel_params"][j, k] - truth[c][i]) / maps["channel_stderr"][j, k]
            assert np.mean(np.abs(z) < 3) >= 0.95, (c, NAMES[i])
    z = (maps["params"][0] - truth["r"][SHAPE]) / maps["stderr"][0]
    assert np.mean(np.abs(z) < 3) >= 0.95
    for name in ("params", "stderr", "channel_params", "channel_stderr", "chi2_reduced"):
        assert np.all(np.isfinite(maps[name])), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["params"]["Pd[g]"]["median"] == pytest.approx(
        float(np.median(maps["channel_params"][0, 1])))

    exported = tmp_path / "export"
    assert run("maps", "export", out, "-o", exported).exit_code == 0
    for j, name in enumerate(("Pd", "Ps")):
        for suffix, values in (("", maps["channel_params"][j]),
                               ("_stderr", maps["channel_stderr"][j])):
            want = values.astype(np.float32)                      # (3, H, W)
            tif = tifffile.imread(exported / f"{name}{suffix}.tif")
            assert tif.shape == (H, W, 3) and tif.dtype == np.float32
            assert np.array_equal(np.moveaxis(tif, -1, 0), want)
            with OpenEXR.File(str(exported / f"{name}{suffix}.exr")) as f:
                planes = f.channels()  # the file's channels R, G, B, read as one "RGB"
                assert list(planes) == ["RGB"]
                assert np.array_equal(np.moveaxis(planes["RGB"].pixels, -1, 0), want)
    n_tif = tifffile.imread(exported / "n.tif")
    assert n_tif.shape == (H, W) and np.array_equal(n_tif, maps["params"][0].astype(np.float32))
    assert run("maps", "show", out, "-o", tmp_path / "maps.png").exit_code == 0


def test_one_channel_of_a_medium_fitted_over_channels(rgb_stack, tmp_path):
    """--channel b with a medium fitted over r, g, b maps through that channel's medium,
    exactly the map with the channel's medium model given; its store has no channel axis."""
    root, manifest, _ = rgb_stack
    kw = dict(fixed=FIX, grid=[f"{NAMES[SHAPE]}=0.25:2.5:16"], tile=8, noise=(0.01, 0.0))
    a = fit_maps(root / "photos", manifest, medium_result(), tmp_path / "a.zarr",
                 channel="b", **kw)
    b = fit_maps(root / "photos", manifest, _medium("b"), tmp_path / "b.zarr", channel="b",
                 **kw)
    assert a.summary == b.summary
    ma, mb = open_maps(tmp_path / "a.zarr"), open_maps(tmp_path / "b.zarr")
    for name in ("params", "stderr", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(ma[name], mb[name]), name
    # a map of one channel keeps the store of before channels: its arrays and attributes
    # (the bits of such a map were compared with the version before channels, 0fbcd9e^)
    assert set(ma) == {"params", "stderr", "chi2_reduced", "n_points", "status", "info"}
    assert set(ma["info"]) == {
        "format", "fingerprint", "model", "options", "params", "free", "fixed_values",
        "units", "medium", "accuracy", "roi", "shape", "tile", "photos", "channel", "noise",
        "weighted", "noise_of", "status_codes", "grid", "manifest", "outside_mask", "geometry",
        "chunks"}
    assert ma["info"]["params"] == list(NAMES) and ma["params"].shape == (4, H, W)


# --------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------
def test_bad_input_exits_2_naming_what_and_writes_nothing(rgb_stack, tmp_path):
    root, manifest, _ = rgb_stack
    out = tmp_path / "bad.zarr"

    # a grey stack mapped in every channel: the photos named
    grey = write_stack(tmp_path / "grey", BRDF, MEDIUM, configurations(16),
                       np.repeat(BRDF.to_vector()[:, None, None], 4, 1).repeat(4, 2))
    bad = run("fit", "maps", tmp_path / "grey", "--manifest", grey, "--medium",
              root / "medium.json", "--fix", f"{NAMES[INDEX]}=1.55", "--channel", "rgb",
              "-o", out)
    assert bad.exit_code == 2, bad.output
    assert "grey (single-channel)" in bad.output and "photo_000.tif" in bad.output

    # a medium fitted over other channels, or over one
    medium_result({"r": 0.6, "g": 1.0}).to_json(tmp_path / "rg.json")
    bad = run(*fit_args(root, manifest, out, "--channel", "rgb", "--medium",
                        tmp_path / "rg.json"))
    assert bad.exit_code == 2, bad.output
    assert "channels r, g but" in bad.output and "r, g, b" in bad.output
    bad = run(*fit_args(root, manifest, out, "--channel", "b", "--medium",
                        tmp_path / "rg.json"))
    assert bad.exit_code == 2 and "no channel 'b'" in bad.output, bad.output
    plain = dict(zip(type(MEDIUM).param_names(), map(float, MEDIUM.to_vector())))
    one = dataclasses.replace(medium_result(), channels=None, params=plain,
                              stderr={k: 0.0 for k in plain})
    one.to_json(tmp_path / "one.json")
    bad = run(*fit_args(root, manifest, out, "--channel", "rgb", "--medium",
                        tmp_path / "one.json"))
    assert bad.exit_code == 2 and "a fit of one channel" in bad.output, bad.output

    # near field over channels checks its geometry as over one: a camera so close that a
    # pixel sees it beyond 89 deg from the normal
    bad = run(*fit_args(root, manifest, out, "--channel", "rgb", "--camera-distance", 0.5,
                        "--pixel-pitch", 1, "--near-field"))
    assert bad.exit_code == 2 and "larger than the plate allows" in bad.output, bad.output
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "grey", "one.json", "rg.json"]

    # a free parameter per channel that is not a scale (a conductor's index)
    conductor = veil.models.model_class("rough-conductor", "brdf")
    with pytest.raises(veil.errors.InputError, match=r"rough-conductor\.n is declared per"):
        build_channel_tables(conductor, {c: _medium(c) for c in "rgb"},
                             angles_of(configurations(8)))
    with pytest.raises(veil.errors.InputError, match="two or more of r, g, b"):
        fit_maps(root / "photos", manifest, medium_result(), out, channel=("r", "r"))


def test_a_photo_of_other_samples_is_refused_and_leaves_no_store(rgb_stack, tmp_path):
    """A 16-bit photo among float32 ones has code values of another scale: the map was
    fitted (exit 0, reduced chi-square in the hundreds); it is refused naming both photos."""
    import shutil

    root, manifest, _ = rgb_stack
    photos = tmp_path / "photos"
    shutil.copytree(root / "photos", photos)
    odd = photos / "photo_003.tif"
    image = tifffile.imread(odd)
    tifffile.imwrite(odd, (image / image.max() * 60000).astype(np.uint16), photometric="rgb")
    out = tmp_path / "maps.zarr"
    args = fit_args(root, photos / "manifest.csv", out, "--channel", "rgb")
    args[2] = photos
    bad = run(*args)
    assert bad.exit_code == 2, bad.output
    text = " ".join(bad.output.split())
    assert "photo_003.tif (line 5 of" in text and "16-bit integer samples, but" in text
    assert "photo_000.tif (line 2 of" in text and "has float samples" in text
    assert not out.exists()
    # floats of another width have the same scale of values: no refusal on that count
    from veil.data.ingest_channels import sample_type
    from veil.data.photo_files import read_photo
    from veil.data.roi import ROI

    tifffile.imwrite(odd, image.astype(np.float64), photometric="rgb")
    corner = [("ROI", ROI(0, 0, 2, 2))]
    first = read_photo(photos / "photo_000.tif", corner)
    assert read_photo(odd, corner).dtype != first.dtype
    assert sample_type(read_photo(odd, corner)) == sample_type(first) == "float"
