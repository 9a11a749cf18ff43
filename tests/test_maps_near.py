"""Near-field reflectance maps (docs/maps-geometry.md "Geometry"): per-pixel angles of a pinhole
camera at a finite distance, tabulated over a grid of plate points. The geometry by hand,
the interpolated columns against the engine at each pixel's exact angles, a plate
photographed from close by recovered with the option while the distant approximation is
biased, the option at a very large distance equal to the distant maps, bad input, and a
map of r, g, b at once with per-pixel angles."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tifffile

import veil
from support.cli import run
from support.maps import (
    angles_of,
    configurations,
    render,
    render_near,
    write_colour_stack,
    write_photos,
)
from veil.data.ingest import ROI
from veil.maps.channels import build_channel_tables
from veil.maps.near import NearGeometry
from veil.maps.solve import CONVERGED, solve_pixels
from veil.maps.store import open_maps
from veil.maps.tables import build_tables

BRDF, MEDIUM = veil.BRDF1, veil.BTDF2
CLS = type(BRDF)
NAMES = CLS.param_names()
INDEX, SHAPE = NAMES[3], NAMES[2]
FIX = {INDEX: float(BRDF.to_vector()[3])}
GRID = (0.25, 2.5, 16)
H = W = 16
#: camera 100 units from the plate centre, pixels 0.65 apart: the field spans 8.4 deg of view
#: direction, 126 fifths of the narrowest lobe (the facet lobe at n = 2.5, 0.33 deg) and
#: 9 fifths of the apparent lobe (4.6 deg) the field grid follows
DISTANCE, PITCH = 100.0, 0.65
KW = dict(fixed=FIX, grid={SHAPE: GRID}, accuracy="fast")


# --------------------------------------------------------------------------------------
# the geometry
# --------------------------------------------------------------------------------------
def test_view_direction_by_hand():
    """A camera at theta_r 45 deg, phi_r 0, distance 10: the pixel at the optical centre sees
    the manifest's angles; one pixel-pitch-scaled unit towards +x (the camera's side) sees
    it at atan((10 cos 45 - 1) / (10 sin 45)) = 40.65 deg; a unit in image y (rows down,
    the plate's -y) moves the azimuth to +y; the light is unchanged."""
    g = NearGeometry(10.0, 0.5, (20, 40))  # optical centre (20, 10) px
    angles = (np.array([30.0]), np.array([180.0]), np.array([45.0]), np.array([0.0]))
    ti, pi_, tr, pr = g.angles(angles, 19.5, 9.5)
    assert (ti[0], pi_[0], tr[0], pr[0]) == (30.0, 180.0, pytest.approx(45.0, abs=1e-12),
                                            pytest.approx(0.0, abs=1e-12))
    c = 10 * math.cos(math.radians(45))
    _, _, tr, pr = g.angles(angles, 21.5, 9.5)  # plate x = +1
    assert tr[0] == pytest.approx(math.degrees(math.atan((c - 1) / c)), abs=1e-10)
    assert pr[0] == pytest.approx(0.0, abs=1e-12)
    _, _, tr, pr = g.angles(angles, 19.5, 11.5)  # plate y = -1: the camera is towards +y
    assert tr[0] == pytest.approx(math.degrees(math.acos(c / math.sqrt(2 * c * c + 1))),
                                  abs=1e-10)
    assert pr[0] == pytest.approx(math.degrees(math.atan2(1, c)), abs=1e-10)
    ti, pi_, _, _ = g.angles(angles, 0, 0)
    assert ti[0] == 30.0 and pi_[0] == 180.0


# --------------------------------------------------------------------------------------
# (b) the interpolated columns against the engine at each pixel's exact angles
# --------------------------------------------------------------------------------------
#: tolerance of the field interpolation, relative to a column's maximum over the
#: configurations (measured: 1.1e-3 at the worst cell centres; 1 % noise is the scale
#: that matters)
FIELD_TOL = 3e-3


def test_interpolated_columns_match_the_engine_at_each_pixels_angles():
    configs = configurations(16)
    angles = angles_of(configs)
    g = NearGeometry(DISTANCE, PITCH, (H, W))
    near = build_tables(CLS, MEDIUM, angles, near=g, roi=ROI(0, 0, W, H), **KW)
    assert near.near.shape[0] >= 6 and near.near.shape[1] >= 6
    assert 0 < near.field_error < FIELD_TOL
    far = build_tables(CLS, MEDIUM, angles, **KW)
    axis = near.axes[0]
    rng = np.random.default_rng(3)
    pixels = [(0, 0), (W - 1, H - 1), (W - 1, 0), (3, 11)] + \
        [tuple(int(v) for v in rng.integers(0, W, 2)) for _ in range(2)]
    worst = 0.0
    for x, y in pixels:
        exact = build_tables(CLS, MEDIUM, g.angles(angles, x, y), **KW)
        for j in (2, 7, 13):  # table nodes: the nonlinear spline is exact there
            value = axis.nodes()[j]
            got = near.basis({SHAPE: value}, pixel=(x, y))
            want = exact.values[j]
            scale = np.max(np.abs(want), axis=0)
            scale = np.where(scale > 0, scale, 1.0)  # the known part: 0 (both scales free)
            worst = max(worst, float(np.max(np.abs(got - want) / scale)))
        if (x, y) in pixels[:3]:  # at a corner the pixel's angles matter: the columns are
            # far more than the tolerance apart from the distant ones
            off = np.abs(exact.values - far.values)[..., :2] / np.max(
                np.abs(far.values), axis=-2, keepdims=True)[..., :2]
            assert np.max(off) > 30 * FIELD_TOL
    assert worst < FIELD_TOL, worst


# --------------------------------------------------------------------------------------
# (a) a plate seen from close by: recovered with the option, biased without
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def near_photos(tmp_path_factory):
    """Two materials (left: BRDF1, right: smoother and glossier), every pixel rendered at its
    exact angles, 1 % noise."""
    root = tmp_path_factory.mktemp("near")
    v = BRDF.to_vector()
    pm = np.repeat(v[:, None, None], H, 1).repeat(W, 2).copy()
    pm[2, :, W // 2:] = 1.1
    pm[1, :, W // 2:] *= 1.5
    configs = configurations(16)
    values = render_near(BRDF, MEDIUM, configs, pm, NearGeometry(DISTANCE, PITCH, (H, W)))
    manifest = write_photos(root / "photos", configs, values, (H, W), noise=0.01, seed=5)
    return root, manifest, pm


def fit_args(root, manifest, out, *extra):
    lo, hi, n = GRID
    return ["fit", "maps", root / "photos", "--manifest", manifest, "--medium", "BTDF2",
            "--fix", f"{INDEX}={FIX[INDEX]}", "--grid", f"{SHAPE}={lo}:{hi}:{n}",
            "--accuracy", "fast", "--noise", "0.01", "--tile", 8, "-o", out, *extra]


def z_scores(maps, truth):
    ok = maps["status"] == CONVERGED
    free = [NAMES.index(n) for n in maps["info"]["free"]]
    z = np.stack([(maps["params"][k] - truth[k])[ok] / maps["stderr"][k][ok] for k in free])
    return ok, z


def test_near_camera_recovered_with_the_option_and_biased_without(near_photos, tmp_path):
    root, manifest, truth = near_photos
    out = tmp_path / "near.zarr"
    result = run(*fit_args(root, manifest, out, "--near-field", "--camera-distance", DISTANCE,
                           "--pixel-pitch", PITCH))
    assert result.exit_code == 0, result.output
    assert "near field" in result.output and "does not apply" in result.output
    maps = open_maps(out)
    ok, z = z_scores(maps, truth)
    assert ok.all()
    # every pixel within ~2 standard errors: the errors are honest (z ~ N(0, 1))
    assert np.mean(np.abs(z) < 2) > 0.9, np.abs(z).max(axis=1)
    assert np.all(np.abs(z.mean(axis=1)) < 0.3), z.mean(axis=1)
    assert np.all((0.7 < z.std(axis=1)) & (z.std(axis=1) < 1.3)), z.std(axis=1)
    chi2 = np.median(maps["chi2_reduced"])
    assert 0.8 < chi2 < 1.2
    # the geometry is recorded
    geo = maps["info"]["geometry"]
    assert geo["kind"] == "near-field" and geo["camera_distance"] == DISTANCE
    assert geo["pixel_pitch"] == PITCH and geo["optical_centre"] == [W / 2, H / 2]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["geometry"] == geo

    # a region off the centre: its pixels keep their place in the photo (optical centre of
    # the full photo), so they get the full map's values (other field nodes, same angles)
    part = tmp_path / "roi.zarr"
    result = run(*fit_args(root, manifest, part, "--near-field", "--camera-distance",
                           DISTANCE, "--pixel-pitch", PITCH, "--roi", "9,2,7,6"))
    assert result.exit_code == 0, result.output
    sub = open_maps(part)
    assert sub["info"]["geometry"]["optical_centre"] == [W / 2, H / 2]
    full = maps["params"][:, 2:8, 9:16]
    se = maps["stderr"][:, 2:8, 9:16]
    free = [NAMES.index(n) for n in maps["info"]["free"]]
    diff = np.abs(sub["params"][free] - full[free]) / se[free]
    assert diff.max() < 0.1, diff.max()

    # the distant approximation (every pixel at the manifest's angles): biased
    far = tmp_path / "far.zarr"
    result = run(*fit_args(root, manifest, far, "--camera-distance", DISTANCE,
                           "--pixel-pitch", PITCH))
    assert "distant-camera approximation" in result.output and "--near-field" in result.output
    fmaps = open_maps(far)
    assert fmaps["info"]["geometry"]["kind"] == "distant"
    fok, fz = z_scores(fmaps, truth)
    assert np.median(fmaps["chi2_reduced"][fok]) > 10
    # the roughness off by several standard errors on average (measured: about -5)
    n_row = maps["info"]["free"].index(SHAPE)
    assert abs(fz[n_row].mean()) > 3, fz.mean(axis=1)
    assert np.sqrt(np.mean(fz ** 2)) > 3 * np.sqrt(np.mean(z ** 2))


# --------------------------------------------------------------------------------------
# (c) a very distant camera: the near-field maps are the distant ones
# --------------------------------------------------------------------------------------
def test_very_distant_camera_gives_the_distant_result():
    configs = configurations(12)
    angles = angles_of(configs)
    kw = dict(fixed=FIX, grid={SHAPE: (0.25, 2.5, 8)}, accuracy="fast")
    far = build_tables(CLS, MEDIUM, angles, **kw)
    g = NearGeometry(1e12, 1.0, (H, W))
    near = build_tables(CLS, MEDIUM, angles, near=g, roi=ROI(2, 3, 12, 10), **kw)
    assert near.near.shape == (4, 4)
    for ix in range(4):
        for iy in range(4):
            np.testing.assert_allclose(near.values[ix, iy], far.values, rtol=1e-9, atol=0)
    rng = np.random.default_rng(1)
    truth = np.repeat(BRDF.to_vector()[None, :], 6, axis=0)
    truth[:, 2] *= np.exp(rng.uniform(-0.4, 0.4, 6))
    clean = render(BRDF, MEDIUM, configs, truth)
    y = clean * (1 + 0.01 * rng.standard_normal(clean.shape))
    valid = np.ones_like(y, dtype=bool)
    xs, ys = np.array([2, 13, 7, 2, 13, 9]), np.array([3, 12, 8, 12, 3, 5])
    a = solve_pixels(far, y, valid, noise=(0.01, 0.0))
    b = solve_pixels(near, y, valid, noise=(0.01, 0.0), pixels=(xs, ys))
    assert np.array_equal(a.status, b.status) and np.all(a.status == CONVERGED)
    np.testing.assert_allclose(b.params, a.params, rtol=1e-7)
    np.testing.assert_allclose(b.stderr, a.stderr, rtol=1e-6)
    np.testing.assert_allclose(b.chi2, a.chi2, rtol=1e-6)


# --------------------------------------------------------------------------------------
# (d) bad input: exit 2, nothing written
# --------------------------------------------------------------------------------------
def test_bad_geometry_exits_2(near_photos, tmp_path):
    root, manifest, _ = near_photos
    out = tmp_path / "bad.zarr"

    def bad(*extra):
        result = run(*fit_args(root, manifest, out, *extra))
        assert result.exit_code == 2, result.output
        assert not out.exists()
        return result.output

    for d, p in ((0, 1), (-5, 1), ("nan", 1), (100, 0), (100, "inf"), (100, -1)):
        text = bad("--near-field", "--camera-distance", d, "--pixel-pitch", p)
        assert "finite number" in text, text
    assert "--camera-distance" in bad("--near-field")
    assert "go together" in bad("--near-field", "--camera-distance", 100)
    # a camera so close that a pixel sees the camera of the 80 deg configuration beyond
    # 89 deg from the normal
    text = bad("--near-field", "--camera-distance", 0.5, "--pixel-pitch", 1)
    assert "larger than the plate allows" in text and "theta_r 80" in text
    # distant geometry checks its numbers too
    assert "positive finite number" in bad("--camera-distance", 0, "--pixel-pitch", 1)


# --------------------------------------------------------------------------------------
# (e) progress: the near-field tables (the engine at every field node, seconds a node)
# --------------------------------------------------------------------------------------
def test_near_field_tables_report_each_node_from_the_start():
    """build_tables(near=...) calls progress(done, total) before its first node (done 0)
    and after each node of the nonlinear axes, up to the total, as distant tables do."""
    angles = angles_of(configurations(8))
    kw = dict(fixed=FIX, grid={SHAPE: (0.25, 2.5, 4)}, accuracy="fast")
    calls: dict = {"near": [], "far": []}
    build_tables(CLS, MEDIUM, angles, near=NearGeometry(DISTANCE, PITCH, (H, W)),
                 roi=ROI(0, 0, 8, 8), progress=lambda d, t: calls["near"].append((d, t)), **kw)
    build_tables(CLS, MEDIUM, angles, progress=lambda d, t: calls["far"].append((d, t)), **kw)
    assert calls["near"] == calls["far"] == [(k, 4) for k in range(5)]


def test_near_field_fit_says_its_stages_off_a_terminal(near_photos, tmp_path, monkeypatch):
    """Off a terminal (CliRunner's stderr is no tty) `veil fit maps --near-field` writes one
    line per stage as the stage starts - the tables with their node count first - where it
    wrote nothing until the tables were done. (No repeated line of a long stage: a loaded
    machine would add one.)"""
    monkeypatch.setattr("veil.cli._common.STAGE_LINE_SECONDS", float("inf"))
    root, manifest, _ = near_photos
    out = tmp_path / "lines.zarr"
    result = run("fit", "maps", root / "photos", "--manifest", manifest, "--medium", "BTDF2",
                 "--fix", f"{INDEX}={FIX[INDEX]}", "--grid", f"{SHAPE}=0.25:2.5:4",
                 "--accuracy", "fast", "--roi", "0,0,8,8", "--tile", 8, "-o", out,
                 "--near-field", "--camera-distance", DISTANCE, "--pixel-pitch", PITCH)
    assert result.exit_code in (0, 1), result.output
    lines = [ln for ln in result.output.splitlines() if ln.startswith("veil maps: ")]
    assert lines == ["veil maps: tables (0/4)", "veil maps: staging photos (0/16)",
                     "veil maps: solving tiles (0/1)"], result.output
    text = result.output
    assert text.index("veil maps: tables (0/4)") < text.index("tables: ") < text.index(
        "veil maps: staging photos")


def test_near_field_family_without_a_nonlinear_parameter(monkeypatch):
    """No table axis but the two field axes: a plugin family with one scale through a
    plugin medium, pixels rendered at their exact angles, recovered."""
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "plugins"))
    import veil_test_models

    brdf_cls = veil_test_models.LambertianTest
    medium = veil_test_models.FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    configs = configurations(12)
    g = NearGeometry(DISTANCE, PITCH, (H, W))
    tables = build_tables(brdf_cls, medium, angles_of(configs), near=g,
                          roi=ROI(0, 0, W, H), accuracy="fast")
    assert tables.axes == [] and tables.near.shape == (4, 4)
    xs, ys = np.array([0, 15, 7, 2]), np.array([0, 15, 3, 12])
    truth = np.array([2.0, 0.5, 1.0, 3.0])
    exact = np.stack([build_tables(brdf_cls, medium, g.angles(angles_of(configs), x, y),
                                   accuracy="fast").values[:, 0] for x, y in zip(xs, ys)])
    y = exact * truth[:, None]
    y = y * (1 + 0.01 * np.random.default_rng(0).standard_normal(y.shape))
    fits = solve_pixels(tables, y, np.ones_like(y, dtype=bool), pixels=(xs, ys))
    assert np.all(fits.status == CONVERGED)
    assert np.all(np.abs(fits.params[0] - truth) < 4 * fits.stderr[0])


# --------------------------------------------------------------------------------------
# (e) several channels at once: every channel of a pixel at the pixel's own angles, each
# through its channel's medium
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def near_rgb(tmp_path_factory):
    """RGB photos of the two materials of ``near_photos`` with per-channel scales (a bluish
    albedo, a less coloured specular scale), each channel through its medium, every pixel
    at its exact angles, 1 % noise; the medium fitted over r, g, b as a result file."""
    from test_maps_channels import ALBEDO, SPECULAR, _medium, medium_result

    root = tmp_path_factory.mktemp("near-rgb")
    v = BRDF.to_vector()
    base = np.repeat(v[:, None, None], H, 1).repeat(W, 2).copy()
    base[2, :, W // 2:] = 1.1
    base[1, :, W // 2:] *= 1.5
    truth = {}
    for c in "rgb":
        truth[c] = base.copy()
        truth[c][0] *= ALBEDO[c]
        truth[c][1] *= SPECULAR[c]
    media = {c: _medium(c) for c in "rgb"}
    configs = configurations(16)
    manifest = write_colour_stack(root / "photos", BRDF, media, configs, truth, seed=7,
                                  geometry=NearGeometry(DISTANCE, PITCH, (H, W)))
    medium_result().to_json(root / "medium.json")
    return root, manifest, truth, media, configs


def rgb_args(root, manifest, out, *extra):
    args = fit_args(root, manifest, out, "--channel", "rgb", *extra)
    args[args.index("--medium") + 1] = root / "medium.json"
    return args


def test_near_field_tables_over_channels_are_each_channels_own(near_rgb):
    """Near-field tables over r, g, b hold, channel by channel, bit for bit the near-field
    tables of that channel's medium alone (the same field grid, values, coefficients)."""
    _, _, _, media, configs = near_rgb
    angles = angles_of(configs)
    g, roi = NearGeometry(DISTANCE, PITCH, (H, W)), ROI(0, 0, W, H)
    kw = dict(fixed=FIX, grid={SHAPE: (0.25, 2.5, 8)}, accuracy="fast")
    tables = build_channel_tables(CLS, media, angles, near=g, roi=roi, **kw)
    assert tables.channels == ("r", "g", "b")
    assert tables.values.shape == tables.near.shape + (8, 3, 16, 3)
    assert 0 < tables.field_error < FIELD_TOL
    for k, c in ((0, "r"), (2, "b")):
        alone = build_tables(CLS, media[c], angles, near=g, roi=roi, **kw)
        assert alone.near == tables.near
        assert np.array_equal(tables.values[..., k, :, :], alone.values), c
        assert np.array_equal(tables.coef[..., k, :, :], alone.coef), c
    assert not np.array_equal(tables.values[..., 0, :, :], tables.values[..., 2, :, :])


def test_near_field_rgb_map_recovered_and_biased_without(near_rgb, tmp_path):
    """``--channel rgb --near-field``: every channel's Pd and Ps and the shared n within
    their standard errors (z ~ N(0, 1)); each pixel's scales are, channel by channel, the
    exact weighted least-squares optimum of the columns at its own position at its n (and
    not of those of the mirrored pixel); the same stack mapped at the manifest's angles is
    biased as one channel is."""
    root, manifest, truth, media, configs = near_rgb
    out = tmp_path / "near.zarr"
    result = run(*rgb_args(root, manifest, out, "--near-field", "--camera-distance", DISTANCE,
                           "--pixel-pitch", PITCH))
    assert result.exit_code == 0, result.output
    assert "near field" in result.output and "channels r, g, b" in result.output
    maps = open_maps(out)
    info = maps["info"]
    assert info["channels"] == ["r", "g", "b"] and info["geometry"]["kind"] == "near-field"
    assert info["geometry"]["camera_distance"] == DISTANCE
    ok = maps["status"] == CONVERGED
    assert ok.all()
    zs = {}
    for k, c in enumerate("rgb"):
        for j, name in enumerate(info["channel_params"]):
            i = NAMES.index(name)
            zs[f"{name}[{c}]"] = (maps["channel_params"][j, k] - truth[c][i]) / \
                maps["channel_stderr"][j, k]
    zs[SHAPE] = (maps["params"][0] - truth["r"][2]) / maps["stderr"][0]
    for name, z in zs.items():
        assert np.mean(np.abs(z) < 2) > 0.9, (name, np.abs(z).max())
        assert abs(z.mean()) < 0.3 and 0.7 < z.std() < 1.3, (name, z.mean(), z.std())
    assert 0.8 < np.median(maps["chi2_reduced"]) < 1.2

    # the pixel's own columns: the tables the command built, rebuilt here
    lo, hi, n = GRID
    tables = build_channel_tables(CLS, media, angles_of(configs), near=NearGeometry(
        DISTANCE, PITCH, (H, W)), roi=ROI(0, 0, W, H), fixed=FIX, grid={SHAPE: GRID},
        accuracy="fast")
    photos = np.stack([tifffile.imread(root / "photos" / f) for f in
                       pd.read_csv(manifest)["file"]], axis=-1).astype(float)  # (H, W, 3, M)
    for x, y in ((0, 0), (W - 1, 0), (2, H - 1), (11, 6)):
        n_hat = maps["params"][0, y, x]
        for px, want_equal in (((x, y), True), ((W - 1 - x, y), False)):
            basis = tables.basis({SHAPE: n_hat}, pixel=px)  # (3, M, 3)
            for k in range(3):
                yk = photos[y, x, k]
                got = maps["channel_params"][:, k, y, x]
                # the noise of the model's values (docs/maps-noise.md), here at the map's
                # solution, there at a first one: the two differ by O(noise^2) of them
                f = basis[k, :, :2] @ got + basis[k, :, 2]
                w = 1 / (0.01 * f)
                s, *_ = np.linalg.lstsq(basis[k, :, :2] * w[:, None],
                                        (yk - basis[k, :, 2]) * w, rcond=None)
                if want_equal:
                    np.testing.assert_allclose(got, s, rtol=1e-5)
                else:
                    assert np.max(np.abs(got / s - 1)) > 1e-3

    # the distant approximation: the shared n biased by several standard errors
    far = tmp_path / "far.zarr"
    result = run(*rgb_args(root, manifest, far, "--camera-distance", DISTANCE, "--pixel-pitch",
                           PITCH))
    assert result.exit_code == 0 and "--near-field" in result.output, result.output
    fmaps = open_maps(far)
    fok = fmaps["status"] == CONVERGED
    fz = ((fmaps["params"][0] - truth["r"][2]) / fmaps["stderr"][0])[fok]
    assert np.median(fmaps["chi2_reduced"][fok]) > 10
    assert abs(fz.mean()) > 3, fz.mean()


def test_near_field_propagation_over_channels_is_the_refits_response(near_rgb, monkeypatch):
    """The medium's uncertainty in a near-field map over r, g, b (docs/maps-medium-error.md):
    with only g uncertain (shared by the channels), each parameter's medium part is
    |d estimate / d g| times g's standard error, the derivative taken by refitting the map
    through the media at g +- 0.05 % (central differences): the median ratio within 5 % for
    the shared roughness and the red albedo. The differences are tabulated over a coarser
    field grid than the map's (4 x 4 against 8 x 9 plate points) and interpolated onto it;
    a table built with ``field=`` keeps the given grid, which a medium of another lobe would
    not choose. On the map's own grid the parts are the same within 1 % at the median,
    within 2 % of the standard error at every pixel."""
    import dataclasses

    import veil.maps.medium_error as me

    from test_maps_channels import medium_result

    root, manifest, _, _, _ = near_rgb
    base = medium_result()
    se_g = 1e-3 * base.params["g"]
    result = dataclasses.replace(base, stderr={k: se_g if k == "g" else 0.0 for k in base.stderr})
    kw = dict(fixed=FIX, grid=[f"{SHAPE}=0.25:2.5:8"], accuracy="fast", tile=8,
              channel="rgb", geometry=(DISTANCE, PITCH), near_field=True, noise=(0.01, 0.0))
    veil.fit_maps(root / "photos", manifest, result, root / "prop.zarr", propagation="linear",
                  **kw)
    maps = open_maps(root / "prop.zarr")
    assert maps["info"]["propagation"]["parameters"] == ["g"]
    assert maps["info"]["geometry"]["field_nodes"] == [8, 9]  # coarse: 4 x 4
    monkeypatch.setattr(me, "COARSE", 1)
    veil.fit_maps(root / "photos", manifest, result, root / "fine.zarr", propagation="linear",
                  **kw)
    fine = open_maps(root / "fine.zarr")
    for key, total in (("stderr_medium", "stderr"), ("channel_stderr_medium", "channel_stderr")):
        on = (fine[key] > 0) & (maps["status"] == CONVERGED)
        assert np.median(np.abs(maps[key][on] / fine[key][on] - 1)) < 0.01, key
        # where the part is a tiny share its relative difference grows, not what it adds
        assert np.all(np.abs(maps[key][on] - fine[key][on]) < 0.02 * fine[total][on]), key
    moved = []
    d = 5e-4 * base.params["g"]
    for sign in (1, -1):
        at = dataclasses.replace(base, params={**base.params, "g": base.params["g"] + sign * d})
        out = root / f"g{sign:+d}.zarr"
        veil.fit_maps(root / "photos", manifest, at, out, **kw)
        moved.append(open_maps(out))
    ok = maps["status"] == CONVERGED
    assert ok.mean() > 0.9
    shape = maps["info"]["params"].index(SHAPE)
    slope = (moved[0]["params"][shape] - moved[1]["params"][shape]) / (2 * d)
    ratio = maps["stderr_medium"][shape][ok] / (np.abs(slope[ok]) * se_g)
    assert abs(np.median(ratio) - 1) < 0.05, np.median(ratio)
    angles, g = angles_of(configurations(16)), NearGeometry(DISTANCE, PITCH, (H, W))
    own = build_tables(CLS, MEDIUM, angles, near=g, roi=ROI(0, 0, W, H), **KW)
    wide = MEDIUM.replace(g=0.6)  # a wider lobe: a coarser grid of its own
    assert build_tables(CLS, wide, angles, near=g, roi=ROI(0, 0, W, H), **KW).near != own.near
    pinned = build_tables(CLS, wide, angles, near=g, roi=ROI(0, 0, W, H), field=own.near, **KW)
    assert pinned.near == own.near and pinned.coef.shape == own.coef.shape
    pd_ = maps["info"]["channel_params"].index(NAMES[0])
    slope = (moved[0]["channel_params"][pd_, 0] - moved[1]["channel_params"][pd_, 0]) / (2 * d)
    ratio = maps["channel_stderr_medium"][pd_, 0][ok] / (np.abs(slope[ok]) * se_g)
    assert abs(np.median(ratio) - 1) < 0.05, np.median(ratio)
