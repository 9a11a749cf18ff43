"""``veil ingest --channel rgb`` (issue 30; docs/ingest.md "Channels"): every channel of a
colour photo stack in one measurement table, each channel's rows bit for bit those of the
one-channel ingest of that channel; raw white balance recorded, not applied; stacks mixing
colour and grey photos refused; the table fitted over its channels."""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd
import pytest

import veil as veil_api
from support.cli import run as cli
from test_ingest import (
    BLACK_TEXT,
    ROI_SL,
    ROI_TEXT,
    H,
    W,
    gaussian,
    hash_tree,
    mosaic_image,
    run,
    write_dng,
    write_manifest,
    write_png,
    write_tiff,
)
from veil.data.channels import RGB
from veil.data.ingest import ingest
from veil.data.measurements import load_measurements
from veil.data.simulate import simulate_channels
from veil.fitting import FitResult

#: Per-channel levels of the synthetic photos.
LEVELS = ((1000, 5000, 30000), (1200, 5500, 28000), (900, 6000, 31000))


@pytest.fixture
def photos(tmp_path):
    d = tmp_path / "photos"
    d.mkdir()
    return d


def rgb_stack(photos, tmp_path, kind="png"):
    """Three colour photos of known per-channel levels (plus a black patch), a manifest."""
    files = []
    for k, levels in enumerate(LEVELS):
        image = np.stack(
            [gaussian(v, 40 + 10 * c, (H, W), 100 * k + c) for c, v in enumerate(levels)],
            axis=-1,
        )
        image[24:34, 2:14] = gaussian(300, 20, (10, 12, 3), 50 + k)  # the black cloth
        name = f"p{k}.{'png' if kind == 'png' else 'tif'}"
        if kind == "png":
            write_png(photos / name, image)
        else:
            write_tiff(photos / name, image, photometric="rgb")
        files.append(name)
    return write_manifest(tmp_path / "m.csv", files)


def split(table, channel):
    """The rows of one channel without the column, as a one-channel ingest writes them."""
    rows = table[table["channel"] == channel].drop(columns=["channel"])
    return rows.reset_index(drop=True)


def assert_channels_are_the_one_channel_ingests(table, photos, manifest, **options):
    for c in RGB:
        alone, _ = run(photos, manifest, ROI_TEXT, channel=c, **options)
        mine = split(table, c).drop(columns=["white_balance"], errors="ignore")
        pd.testing.assert_frame_equal(mine, alone, check_exact=True)
        for col in ("value", "sigma"):  # bit for bit, not only equal as floats
            assert mine[col].to_numpy().tobytes() == alone[col].to_numpy().tobytes()


# --------------------------------------------------------------------------------------
# the table: every channel, each the one-channel ingest's rows
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["png", "tiff"])
def test_rgb_table_holds_each_channel_of_the_one_channel_ingests(photos, tmp_path, kind):
    manifest = rgb_stack(photos, tmp_path, kind)
    table, msgs = run(photos, manifest, ROI_TEXT, channel="rgb", black_roi=BLACK_TEXT)
    assert msgs == []
    assert list(table.columns) == [
        "file",
        "psi",
        "rho",
        "session",
        "channel",
        "value",
        "sigma",
        "black",
        "black_sigma",
        "saturated",
        "clipped",
        "n_pixels",
    ]
    # channel after channel, each photo once per channel, as veil simulate --channels
    assert table["channel"].tolist() == ["r"] * 3 + ["g"] * 3 + ["b"] * 3
    suffix = "png" if kind == "png" else "tif"
    assert table["file"].tolist() == [f"p{k}.{suffix}" for k in range(3)] * 3
    assert_channels_are_the_one_channel_ingests(table, photos, manifest, black_roi=BLACK_TEXT)
    for c, ch in enumerate(RGB):  # the known levels of each channel
        got = split(table, ch)["value"].to_numpy()
        assert got == pytest.approx([levels[c] for levels in LEVELS], rel=0.01)
    # the table reads back as a measurement table of three channels
    path = tmp_path / "rgb.csv"
    veil_api.save_measurements(table, path)
    back = load_measurements(path)
    assert back["value"].to_numpy().tobytes() == table["value"].to_numpy().tobytes()
    assert list(dict.fromkeys(back["channel"])) == ["r", "g", "b"]


def test_raw_rgb_records_the_white_balance_and_does_not_apply_it(photos, tmp_path):
    files = []
    for k in range(2):
        mosaic, _ = mosaic_image((400 + 10 * k, 1500, 900), 64, 60 + k, shape=(H, W))
        write_dng(photos / f"r{k}.dng", mosaic, as_shot=(1, 2, 1, 1, 4, 5))  # 0.5, 1, 0.8
        files.append(f"r{k}.dng")
    manifest = write_manifest(tmp_path / "m.csv", files)
    table, _ = run(photos, manifest, ROI_TEXT, channel="rgb")
    # the camera's as-shot multipliers (1 / AsShotNeutral, green = 1), one per row's channel
    assert table["white_balance"].tolist() == [2.0, 2.0, 1.0, 1.0, 1.25, 1.25]
    assert_channels_are_the_one_channel_ingests(table, photos, manifest)  # not applied
    assert split(table, "r")["value"].to_numpy() == pytest.approx([400, 410], abs=15)
    assert split(table, "g")["n_pixels"].tolist() == [160, 160]  # both greens of 20 x 16
    assert split(table, "r")["n_pixels"].tolist() == [80, 80]


def test_a_photo_saturated_in_one_channel_leaves_every_channel(photos, tmp_path):
    manifest = rgb_stack(photos, tmp_path)
    image = np.stack([gaussian(v, 40, (H, W), 7 + c) for c, v in enumerate(LEVELS[1])], -1)
    image[ROI_SL][3, 4, 2] = 65535  # one blue sample at the format's maximum
    write_png(photos / "p1.png", image)
    table, msgs = run(photos, manifest, ROI_TEXT, channel="rgb")
    assert table["file"].tolist() == ["p0.png", "p2.png"] * 3
    assert len(msgs) == 1 and "p1.png" in msgs[0]
    assert "channel b: 1 saturated pixel(s) (code >= 65535)" in msgs[0]
    assert "excluded from every channel" in msgs[0]
    kept, msgs = run(photos, manifest, ROI_TEXT, channel="rgb", keep_saturated=True)
    assert "kept as asked" in msgs[0]
    assert kept.loc[kept["file"] == "p1.png", "saturated"].tolist() == [0, 0, 1]
    assert_channels_are_the_one_channel_ingests(kept, photos, manifest, keep_saturated=True)


# --------------------------------------------------------------------------------------
# bad input: exit 2 naming the file, nothing written
# --------------------------------------------------------------------------------------
def test_a_grey_image_has_no_rgb(photos, tmp_path):
    write_png(photos / "grey.png", np.full((H, W), 500, np.uint16))
    manifest = write_manifest(tmp_path / "m.csv", ["grey.png"])
    with pytest.raises(ValueError, match=r"grey\.png .*line 2 of .*no colour channels"):
        ingest(photos, manifest, ROI_TEXT, channel="rgb")
    out = tmp_path / "out.csv"
    result = cli(
        "ingest",
        photos,
        "--manifest",
        manifest,
        "--roi",
        ROI_TEXT,
        "--channel",
        "rgb",
        "-o",
        out,
    )
    assert result.exit_code == 2, result.output
    assert "grey.png" in result.output and "read with channel gray" in result.output
    assert "Traceback" not in result.output and not out.exists()


@pytest.mark.parametrize("channel", ["gray", "rgb"])
def test_a_stack_mixing_colour_and_grey_photos_is_refused(photos, tmp_path, channel):
    manifest = rgb_stack(photos, tmp_path)
    write_png(photos / "p2.png", np.full((H, W), 500, np.uint16))  # the third one grey
    before = hash_tree(photos)
    out = tmp_path / "out.csv"
    result = cli(
        "ingest",
        photos,
        "--manifest",
        manifest,
        "--roi",
        ROI_TEXT,
        "--channel",
        channel,
        "-o",
        out,
    )
    assert result.exit_code == 2, result.output
    assert "p2.png (line 4 of" in result.output
    if channel == "gray":  # the mix itself, naming the stack's first photo too
        assert "p0.png (line 2 of" in result.output and "all colour" in result.output
    assert "Traceback" not in result.output and not out.exists()
    assert hash_tree(photos) == before


@pytest.mark.parametrize(
    "odd, samples",
    [
        (lambda image: (image // 256).astype(np.uint8), "8-bit integer samples"),
        (lambda image: image.astype(np.float32), "float samples"),
    ],
)
@pytest.mark.parametrize("channel", ["gray", "rgb"])
def test_a_stack_mixing_sample_types_is_warned_about(photos, tmp_path, channel, odd, samples):
    """An 8-bit or float photo among 16-bit ones may have code values of another scale:
    averaged into one table they were a silent factor of 257 (or a float's 0..1) off. The
    ingest says so, naming the photo and the stack's first photo."""
    manifest = rgb_stack(photos, tmp_path, kind="tiff")
    image = np.stack([gaussian(v, 40, (H, W), 7 + c) for c, v in enumerate(LEVELS[2])], -1)
    write_tiff(photos / "p2.tif", odd(image), photometric="rgb")
    _, msgs = run(photos, manifest, ROI_TEXT, channel=channel, saturation=60000)
    found = [m for m in msgs if "but the stack's first photo" in m]
    assert len(found) == 1 and f"p2.tif (line 4 of {manifest}): {samples}" in found[0]
    assert f"p0.tif (line 2 of {manifest}) has 16-bit integer samples" in found[0]


def test_a_manifest_with_a_channel_column_is_refused_for_rgb(photos, tmp_path):
    manifest = rgb_stack(photos, tmp_path)
    write_manifest(manifest, ["p0.png", "p1.png", "p2.png"], {"channel": ["r"] * 3})
    with pytest.raises(ValueError, match=r"column\(s\) 'channel' would be overwritten"):
        ingest(photos, manifest, ROI_TEXT, channel="rgb")


# --------------------------------------------------------------------------------------
# the command line: ingest every channel, then fit them as one problem
# --------------------------------------------------------------------------------------
def session_photos(photos, tmp_path):
    """A goniometer session of the paper's surface in r, g, b (simulated f_r, Pd per
    channel), one 16-bit RGB photo per configuration with 1 % noise on the ROI's mean."""
    truth = {"r": 400.0, "g": 1000.0, "b": 2500.0}
    table = simulate_channels(
        {c: (veil_api.BRDF1.replace(Pd=p), None) for c, p in truth.items()}, noise=0.0
    )
    configs = table[table["channel"] == "r"][["psi", "rho"]].reset_index(drop=True)
    values = np.stack([table.loc[table["channel"] == c, "value"].to_numpy() for c in RGB], -1)
    rng = np.random.default_rng(3)
    files = []
    for k, level in enumerate(values):  # ROI 4 x 4: 16 pixels, noise 4 % of the level
        pixels = level * (1 + 0.04 * rng.standard_normal((8, 8, 3)))
        write_png(photos / f"c{k:03d}.png", np.rint(pixels).astype(np.uint16))
        files.append(f"c{k:03d}.png")
    manifest = tmp_path / "manifest.csv"
    configs.assign(file=files)[["file", "psi", "rho"]].to_csv(manifest, index=False)
    return manifest, truth


def test_cli_ingests_every_channel_and_fit_reference_fits_them_at_once(photos, tmp_path):
    manifest, truth = session_photos(photos, tmp_path)
    before = hash_tree(photos)
    manifest_hash = hashlib.sha256(manifest.read_bytes()).hexdigest()
    out = tmp_path / "rgb.csv"
    result = cli(
        "ingest",
        photos,
        "--manifest",
        manifest,
        "--roi",
        "2,2,4,4",
        "--channel",
        "rgb",
        "-o",
        out,
    )
    assert result.exit_code == 0, result.output
    assert "333 measurement(s) written" in result.output and "channels r, g, b" in result.output
    assert hash_tree(photos) == before
    assert hashlib.sha256(manifest.read_bytes()).hexdigest() == manifest_hash
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".rgb")] == []
    result = cli("fit", "reference", out, "-o", tmp_path / "rgb.json")
    assert result.exit_code == 0, result.output
    fit = FitResult.from_json(tmp_path / "rgb.json")
    assert fit.converged and fit.channel_names == ("r", "g", "b")
    assert fit.n_points == 333
    for c, pd_true in truth.items():  # each channel's albedo, one shared roughness
        assert fit.as_model(channel=c).Pd == pytest.approx(pd_true, rel=0.03)
        assert abs(fit.params[f"Pd[{c}]"] - pd_true) < 4 * fit.stderr[f"Pd[{c}]"]
    assert fit.params["n"] == pytest.approx(veil_api.BRDF1.n, rel=0.03)
    colour = fit.as_model()  # every channel at once
    assert veil_api.reflectance(colour, 30, 40).shape == (3,)
