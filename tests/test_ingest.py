"""veil.data.ingest and ``veil ingest``: photos the tests write themselves, with known values."""

from __future__ import annotations

import hashlib
import math
import os
import warnings

import imagecodecs
import numpy as np
import pandas as pd
import pytest
import tifffile
from click.testing import CliRunner

import veil
from veil.cli import main
from veil.data.ingest import ROI, IngestWarning, ingest, load_response, parse_roi

H, W = 40, 60  # image height, width (pixels)
ROI_TEXT = "30,10,20,16"  # x, y, w, h: columns 30..49, rows 10..25 (not symmetric in x/y)
BLACK_TEXT = "2,24,12,10"  # columns 2..13, rows 24..33
ROI_SL = (slice(10, 26), slice(30, 50))
BLACK_SL = (slice(24, 34), slice(2, 14))


# -- writers -------------------------------------------------------------------------------

def write_png(path, image):
    path.write_bytes(imagecodecs.png_encode(np.ascontiguousarray(image)))


def write_jpeg(path, image):
    path.write_bytes(imagecodecs.jpeg8_encode(np.ascontiguousarray(image), level=95))


def write_tiff(path, image, **kwargs):
    tifffile.imwrite(path, image, **kwargs)


def write_dng(path, mosaic, black=64, white=4095, as_shot=(1, 1, 1, 1, 1, 1)):
    """A minimal, real DNG (RGGB colour-filter mosaic) that LibRaw reads; ``as_shot`` is the
    AsShotNeutral tag (R, G, B as numerator, denominator pairs)."""
    tags = [
        (271, "s", 0, "Veil", True), (272, "s", 0, "Test", True),
        (50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
        (50708, "s", 0, "Veil Test", True),
        (33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
        (50710, "B", 3, (0, 1, 2), True), (50711, "H", 1, 1, True),
        (50714, "H", 1, black, True), (50717, "H", 1, white, True),
        (50721, "2i", 9, (10000, 10000, 0, 10000, 0, 10000, 10000, 0, 10000, 0, 10000, 10000,
                          0, 10000, 0, 10000, 10000, 10000), True),
        (50728, "2I", 3, as_shot, True),
    ]
    tifffile.imwrite(path, mosaic.astype(np.uint16), photometric=32803, extratags=tags,
                     subfiletype=0, metadata=None)


def write_manifest(path, files, extra=None):
    """Goniometer form (psi, rho) plus a passthrough column."""
    table = pd.DataFrame({"file": files, "psi": [60.0] * len(files),
                          "rho": [5.0 * k for k in range(len(files))],
                          "session": ["target"] * len(files)})
    if extra:
        for k, v in extra.items():
            table[k] = v
    table.to_csv(path, index=False)
    return path


def gaussian(mean, sigma, shape, seed, dtype=np.uint16):
    rng = np.random.default_rng(seed)
    values = np.rint(rng.normal(mean, sigma, shape))
    return values.astype(dtype)


def hash_tree(root):
    digest = hashlib.sha256()
    for folder, dirs, files in sorted(os.walk(root)):
        dirs.sort()
        for name in sorted(files):
            p = os.path.join(folder, name)
            st = os.stat(p)
            digest.update(f"{os.path.relpath(p, root)}|{st.st_mode}|{st.st_mtime_ns}|".encode())
            with open(p, "rb") as fh:
                digest.update(fh.read())
        digest.update(f"dir {folder} {sorted(dirs)}".encode())
    return digest.hexdigest()


def run(*args, **kwargs):
    """Call :func:`ingest` turning IngestWarnings into a list."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", IngestWarning)
        table = ingest(*args, **kwargs)
    return table, [str(w.message) for w in caught if issubclass(w.category, IngestWarning)]


@pytest.fixture
def photos(tmp_path):
    d = tmp_path / "photos"
    d.mkdir()
    return d


# -- values and sigmas against the truth ---------------------------------------------------

def test_gaussian_noise_value_and_sigma_16bit_png(photos, tmp_path):
    mean, sd = 20000.0, 300.0
    image = gaussian(mean, sd, (H, W), 1)
    image[:, :30] = 60000  # outside the ROI, distinct: a wrong ROI shows
    image[:10] = 100
    write_png(photos / "a.png", image)
    table, msgs = run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT)
    assert msgs == []
    roi = image[ROI_SL].astype(float)
    n = roi.size
    assert table["n_pixels"][0] == n == 320
    assert table["value"][0] == pytest.approx(roi.mean(), rel=1e-12)
    assert table["sigma"][0] == pytest.approx(roi.std(ddof=1) / math.sqrt(n), rel=1e-12)
    # against the truth: the mean within 4 standard errors, sigma within 4 x its own spread
    assert abs(table["value"][0] - mean) < 4 * sd / math.sqrt(n)
    assert table["sigma"][0] == pytest.approx(sd / math.sqrt(n), rel=4 / math.sqrt(2 * (n - 1)))
    assert list(table.columns) == ["file", "psi", "rho", "session", "value", "sigma",
                                   "saturated", "clipped", "n_pixels"]
    assert table["saturated"][0] == 0 and table["clipped"][0] == 0


def test_8bit_png_gray_and_alpha_dropped(photos, tmp_path):
    image = np.zeros((H, W, 2), np.uint8)
    image[..., 0] = gaussian(120, 5, (H, W), 2, np.uint8)
    image[..., 1] = 255  # alpha, ignored (not saturation either)
    write_png(photos / "a.png", image)
    table, _ = run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT)
    assert table["value"][0] == pytest.approx(image[ROI_SL][..., 0].mean(), rel=1e-12)
    assert table["saturated"][0] == 0


def test_channel_choice_rgb(photos, tmp_path):
    image = np.zeros((H, W, 3), np.uint16)
    for c, level in enumerate((1000, 5000, 30000)):
        image[..., c] = gaussian(level, 50, (H, W), 10 + c)
    write_png(photos / "a.png", image)
    write_manifest(tmp_path / "m.csv", ["a.png"])
    got = {ch: run(photos, tmp_path / "m.csv", ROI_TEXT, channel=ch)[0] for ch in "rgb"}
    for c, ch in enumerate("rgb"):
        assert got[ch]["value"][0] == pytest.approx(image[ROI_SL][..., c].mean(), rel=1e-12)
        assert got[ch]["value"][0] == pytest.approx((1000, 5000, 30000)[c], abs=15)
    gray = run(photos, tmp_path / "m.csv", ROI_TEXT, channel="gray")[0]
    per_pixel = image[ROI_SL].astype(float).mean(axis=2)
    assert gray["value"][0] == pytest.approx(per_pixel.mean(), rel=1e-12)
    assert gray["value"][0] == pytest.approx(12000, abs=10)
    assert gray["sigma"][0] == pytest.approx(per_pixel.std(ddof=1) / math.sqrt(320), rel=1e-12)


@pytest.mark.parametrize("planar", [False, True])
def test_16bit_tiff_rgb(photos, tmp_path, planar):
    image = np.stack([gaussian(v, 40, (H, W), 20 + v) for v in (700, 800, 900)], axis=-1)
    if planar:
        write_tiff(photos / "a.tif", np.moveaxis(image, -1, 0), photometric="rgb",
                   planarconfig="separate")
    else:
        write_tiff(photos / "a.tif", image, photometric="rgb", compression="zlib")
    table, _ = run(photos, write_manifest(tmp_path / "m.csv", ["a.tif"]), ROI_TEXT, channel="b")
    assert table["value"][0] == pytest.approx(image[ROI_SL][..., 2].mean(), rel=1e-12)


def test_float_tiff_negative_values_and_no_default_saturation(photos, tmp_path):
    rng = np.random.default_rng(3)
    image = rng.normal(0.02, 0.05, (H, W)).astype(np.float32)  # dark: some values negative
    image[ROI_SL][0, 0] = 1e6
    write_tiff(photos / "a.tiff", image)
    table, msgs = run(photos, write_manifest(tmp_path / "m.csv", ["a.tiff"]), ROI_TEXT)
    assert table["value"][0] == pytest.approx(image[ROI_SL].astype(float).mean(), rel=1e-9)
    assert table["saturated"][0] == 0 and table["clipped"][0] == 0
    assert any("saturation is not checked" in m for m in msgs)
    # with a level, float data are checked too
    with pytest.raises(ValueError, match="all 1 photos were excluded"):
        run(photos, tmp_path / "m.csv", ROI_TEXT, saturation=1.0)


def test_float_tiff_nan_in_roi_is_an_error(photos, tmp_path):
    image = np.ones((H, W), np.float32)
    image[12, 33] = np.nan
    write_tiff(photos / "a.tif", image)
    with pytest.raises(ValueError, match=r"a\.tif.*1 non-finite sample"):
        run(photos, write_manifest(tmp_path / "m.csv", ["a.tif"]), ROI_TEXT, saturation=10)


def test_float_samples_whose_statistics_overflow_name_the_photo(photos, tmp_path):
    """Finite float64 samples near 1e200 overflow the standard error: the message names the
    photo and its ROI (it named 'row 0 (index label) of the table', column sigma)."""
    image = np.full((H, W), 1e200) * (1 + np.random.default_rng(0).random((H, W)))
    write_tiff(photos / "a.tif", image)
    with pytest.raises(ValueError, match=r"a\.tif \(line 2 of .*\), ROI: the mean or standard "
                       r"error of the samples overflows float64"):
        run(photos, write_manifest(tmp_path / "m.csv", ["a.tif"]), ROI_TEXT, saturation=10)


@pytest.mark.parametrize("photometric, shape, named", [
    ("separated", (H, W, 4), "SEPARATED (ink separations such as CMYK"),
    ("miniswhite", (H, W), "MINISWHITE (gray inverted, 0 is white)"),
])
def test_a_tiff_of_ink_or_inverted_samples_is_refused(photos, tmp_path, photometric, shape,
                                                      named):
    """A CMYK TIFF was read as R, G, B (its C, M, Y inks), a min-is-white one as gray
    values, silently: each is refused naming the photo and its interpretation."""
    write_tiff(photos / "a.tif", np.full(shape, 1000, np.uint16), photometric=photometric)
    channel = "rgb" if len(shape) == 3 else "gray"
    with pytest.raises(veil.errors.InputError) as info:
        run(photos, write_manifest(tmp_path / "m.csv", ["a.tif"]), ROI_TEXT, channel=channel)
    assert f"a.tif: TIFF of photometric interpretation {named}" in str(info.value)


# -- JPEG and response curves --------------------------------------------------------------

def gamma_curve(path):
    codes = np.arange(256)
    pd.DataFrame({"code": codes, "linear": 1000 * (codes / 255) ** 2.2}).to_csv(path, index=False)
    return path


def test_jpeg_warns_not_linear(photos, tmp_path):
    write_jpeg(photos / "a.jpg", np.full((H, W), 128, np.uint8))
    table, msgs = run(photos, write_manifest(tmp_path / "m.csv", ["a.jpg"]), ROI_TEXT)
    assert table["value"][0] == 128.0
    assert any("not linear" in m and "a.jpg" in m for m in msgs)


def test_jpeg_with_response_is_linearized_without_warning(photos, tmp_path):
    write_jpeg(photos / "a.jpg", np.full((H, W, 3), 128, np.uint8))
    table, msgs = run(photos, write_manifest(tmp_path / "m.csv", ["a.jpg"]), ROI_TEXT,
                      response=gamma_curve(tmp_path / "curve.csv"))
    assert msgs == []
    assert table["value"][0] == pytest.approx(1000 * (128 / 255) ** 2.2, rel=1e-12)


def test_response_interpolates_and_rejects_codes_outside(photos, tmp_path):
    pd.DataFrame({"code": [0, 100, 200], "linear": [0.0, 10.0, 110.0]}).to_csv(
        tmp_path / "c.csv", index=False)
    write_png(photos / "a.png", np.full((H, W), 150, np.uint8))
    write_manifest(tmp_path / "m.csv", ["a.png"])
    table, _ = run(photos, tmp_path / "m.csv", ROI_TEXT, response=tmp_path / "c.csv")
    assert table["value"][0] == pytest.approx(60.0)
    write_png(photos / "a.png", np.full((H, W), 201, np.uint8))
    with pytest.raises(ValueError, match=r"code value 201 is outside the range of response curve"):
        run(photos, tmp_path / "m.csv", ROI_TEXT, response=tmp_path / "c.csv")


@pytest.mark.parametrize("rows, match", [
    ({"code": [0, 5, 5], "linear": [0, 1, 2]},
     r"line 4 of .*c\.csv, column 'code'.*strictly increasing"),
    ({"code": [0, 5, 9], "linear": [0, 2, 1]},
     r"line 4 of .*c\.csv, column 'linear'.*must not decrease"),
    ({"code": [0, 5, 9], "linear": [0, "x", 1]},
     r"line 3 of .*c\.csv, column 'linear'.*'x' is not a finite"),
    ({"code": [0, 5], "lin": [0, 1]}, r"missing column\(s\) 'linear'"),
])
def test_response_file_errors(tmp_path, rows, match):
    pd.DataFrame(rows).to_csv(tmp_path / "c.csv", index=False)
    with pytest.raises(ValueError, match=match):
        load_response(tmp_path / "c.csv")


# -- dark frame, black ROI -----------------------------------------------------------------

def test_dark_frame_subtracted_pixel_by_pixel(photos, tmp_path):
    rng = np.random.default_rng(4)
    pattern = rng.integers(100, 600, (H, W)).astype(np.uint16)  # fixed-pattern offset
    write_png(photos / "a.png", pattern + 1000)
    write_png(tmp_path / "dark.png", pattern)
    write_manifest(tmp_path / "m.csv", ["a.png"])
    plain, _ = run(photos, tmp_path / "m.csv", ROI_TEXT)
    assert plain["sigma"][0] > 5  # the pattern shows without the dark frame
    table, _ = run(photos, tmp_path / "m.csv", ROI_TEXT, dark=tmp_path / "dark.png")
    assert table["value"][0] == 1000.0
    assert table["sigma"][0] == 0.0


def test_dark_frame_inside_photo_dir_is_not_an_unlisted_photo(photos, tmp_path):
    write_png(photos / "a.png", np.full((H, W), 500, np.uint16))
    write_png(photos / "dark.png", np.full((H, W), 20, np.uint16))
    table, msgs = run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT,
                      dark=photos / "dark.png")
    assert table["value"][0] == 480.0
    assert msgs == []


def test_dark_frame_must_match_the_photo(photos, tmp_path):
    write_png(photos / "a.png", np.full((H, W), 500, np.uint16))
    write_png(tmp_path / "dark.png", np.full((H, W + 2), 20, np.uint16))
    with pytest.raises(ValueError, match=r"dark frame .*does not match.*62 x 40.*60 x 40"):
        run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT,
            dark=tmp_path / "dark.png")
    write_png(tmp_path / "dark.png", np.full((H, W), 20, np.uint8))  # 8-bit for a 16-bit photo
    with pytest.raises(ValueError, match=r"does not match .*60 x 40 8-bit integer 1-channel png, "
                                         r"photo 60 x 40 16-bit integer"):
        run(photos, tmp_path / "m.csv", ROI_TEXT, dark=tmp_path / "dark.png")


def test_black_roi_columns(photos, tmp_path):
    image = gaussian(9000, 100, (H, W), 5)
    image[BLACK_SL] = gaussian(300, 20, (10, 12), 6)
    write_png(photos / "a.png", image)
    table, _ = run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT,
                   black_roi=BLACK_TEXT)
    black = image[BLACK_SL].astype(float)
    assert table["black"][0] == pytest.approx(black.mean(), rel=1e-12)
    assert table["black_sigma"][0] == pytest.approx(black.std(ddof=1) / math.sqrt(120), rel=1e-12)
    assert table["value"][0] == pytest.approx(image[ROI_SL].mean(), rel=1e-12)
    assert table["n_pixels"][0] == 320
    assert list(table.columns)[-7:] == ["value", "sigma", "black", "black_sigma", "saturated",
                                        "clipped", "n_pixels"]


# -- saturation and clipping ---------------------------------------------------------------

def test_saturated_photo_excluded_by_default_and_kept_on_request(photos, tmp_path):
    good = gaussian(30000, 100, (H, W), 7)
    bad = good.copy()
    bad[12, 35] = bad[20, 40] = 65535  # two saturated pixels in the ROI
    bad[0, 0] = 65535  # outside every ROI: not counted
    bad[BLACK_SL][0, 0] = 0  # clipped in the black ROI
    write_png(photos / "good.png", good)
    write_png(photos / "bad.png", bad)
    write_manifest(tmp_path / "m.csv", ["good.png", "bad.png"])
    table, msgs = run(photos, tmp_path / "m.csv", ROI_TEXT, black_roi=BLACK_TEXT)
    assert table["file"].tolist() == ["good.png"]
    assert any("bad.png" in m and "2 saturated" in m and "1 clipped" in m and "excluded" in m
               for m in msgs)
    kept, msgs = run(photos, tmp_path / "m.csv", ROI_TEXT, black_roi=BLACK_TEXT,
                     keep_saturated=True)
    assert kept["file"].tolist() == ["good.png", "bad.png"]
    assert kept["saturated"].tolist() == [0, 2] and kept["clipped"].tolist() == [0, 1]
    assert any("kept" in m for m in msgs)


def test_saturation_option_and_8bit_maximum(photos, tmp_path):
    image = np.full((H, W), 200, np.uint8)
    image[11, 31] = 255
    write_png(photos / "a.png", image)
    write_manifest(tmp_path / "m.csv", ["a.png"])
    assert run(photos, tmp_path / "m.csv", ROI_TEXT, keep_saturated=True)[0]["saturated"][0] == 1
    lowered = run(photos, tmp_path / "m.csv", ROI_TEXT, keep_saturated=True, saturation=200)[0]
    assert lowered["saturated"][0] == 320


def test_saturation_counts_only_the_channels_used(photos, tmp_path):
    image = np.full((H, W, 3), 1000, np.uint16)
    image[15, 45, 2] = 65535  # only blue saturated
    write_png(photos / "a.png", image)
    write_manifest(tmp_path / "m.csv", ["a.png"])
    counts = {ch: run(photos, tmp_path / "m.csv", ROI_TEXT, channel=ch,
                      keep_saturated=True)[0]["saturated"][0] for ch in ("gray", "r", "g", "b")}
    assert counts == {"gray": 1, "r": 0, "g": 0, "b": 1}


# -- camera raw (a real DNG read by LibRaw) ------------------------------------------------

def mosaic_image(levels, black, seed, shape=(32, 48), noise=30.0):
    """RGGB mosaic: R at (even, even), G at (even, odd) and (odd, even), B at (odd, odd)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.indices(shape)
    colour = np.where(rows % 2 == 0, np.where(cols % 2 == 0, 0, 1), np.where(cols % 2 == 0, 1, 2))
    truth = np.asarray(levels, float)[colour] + black
    return np.rint(truth + rng.normal(0, noise, shape)).astype(np.uint16), colour


def test_raw_dng_per_channel_black_subtracted(photos, tmp_path):
    mosaic, colour = mosaic_image((400, 1500, 900), 64, 8)
    write_dng(photos / "a.dng", mosaic)
    write_manifest(tmp_path / "m.csv", ["a.dng"])
    roi = "4,6,20,12"
    sl = (slice(6, 18), slice(4, 24))
    crop, cc = mosaic[sl].astype(float) - 64, colour[sl]
    means = []
    for c, ch in enumerate("rgb"):
        table, msgs = run(photos, tmp_path / "m.csv", roi, channel=ch)
        samples = crop[cc == c]
        means.append(samples.mean())
        assert table["value"][0] == pytest.approx(samples.mean(), rel=1e-12)
        assert table["sigma"][0] == pytest.approx(samples.std(ddof=1) / math.sqrt(samples.size),
                                                  rel=1e-12)
        assert table["n_pixels"][0] == samples.size == (120 if ch == "g" else 60)
        assert table["value"][0] == pytest.approx((400, 1500, 900)[c], abs=20)
    gray, _ = run(photos, tmp_path / "m.csv", roi, channel="gray")
    assert gray["value"][0] == pytest.approx(sum(means) / 3, rel=1e-12)
    se = [crop[cc == c].std(ddof=1) / math.sqrt(crop[cc == c].size) for c in range(3)]
    assert gray["sigma"][0] == pytest.approx(math.sqrt(sum(s * s for s in se)) / 3, rel=1e-12)
    assert gray["n_pixels"][0] == 240


def test_raw_dng_white_level_saturation_and_dark_frame(photos, tmp_path):
    mosaic, _ = mosaic_image((400, 1500, 900), 64, 9, noise=0.0)
    mosaic[7, 5] = 4095  # a B photosite at the white level
    write_dng(photos / "a.dng", mosaic)
    dark, _ = mosaic_image((10, 20, 30), 64, 10, noise=0.0)
    write_dng(tmp_path / "dark.dng", dark)
    write_manifest(tmp_path / "m.csv", ["a.dng"])
    table, msgs = run(photos, tmp_path / "m.csv", "4,6,20,12", channel="r",
                      dark=tmp_path / "dark.dng")
    assert table["value"][0] == 390.0 and table["saturated"][0] == 0  # B not used for r
    with pytest.raises(ValueError, match="all 1 photos were excluded"):
        run(photos, tmp_path / "m.csv", "4,6,20,12", channel="b")
    with pytest.raises(ValueError, match="camera raw is already linear"):
        run(photos, tmp_path / "m.csv", "4,6,20,12", response=gamma_curve(tmp_path / "c.csv"))


# -- errors --------------------------------------------------------------------------------

@pytest.fixture
def one_photo(photos, tmp_path):
    write_png(photos / "a.png", np.full((H, W), 500, np.uint16))
    return photos, write_manifest(tmp_path / "m.csv", ["a.png"])


def test_roi_outside_image(one_photo):
    photos, manifest = one_photo
    with pytest.raises(ValueError, match=r"a\.png: ROI 50,10,20,16 .*outside the image, which "
                                         r"is 60 x 40 pixels"):
        run(photos, manifest, "50,10,20,16")
    with pytest.raises(ValueError, match=r"black ROI 0,30,5,11 .*outside"):
        run(photos, manifest, ROI_TEXT, black_roi="0,30,5,11")


@pytest.mark.parametrize("text, match", [
    ("1,2,3", "expected 4 integers"), ("1,2,x,4", "W = 'x' is not an integer"),
    ("1.5,2,3,4", "X = '1.5' is not an integer"), ("-1,2,3,4", "must be >= 0"),
    ("1,2,0,4", "W and H must be >= 1"),
])
def test_roi_parse_errors(text, match):
    with pytest.raises(ValueError, match=match):
        parse_roi(text)


def test_roi_parse_and_single_pixel_roi(one_photo):
    assert parse_roi(" 3, 4,5 ,6") == ROI(3, 4, 5, 6)
    photos, manifest = one_photo
    with pytest.raises(ValueError, match="only 1 pixels in the ROI; at least 2"):
        run(photos, manifest, "3,3,1,1")


def test_unreadable_photo(photos, tmp_path):
    (photos / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    with pytest.raises(ValueError, match=r"a\.png: cannot decode as PNG"):
        run(photos, write_manifest(tmp_path / "m.csv", ["a.png"]), ROI_TEXT)
    (photos / "b.tif").write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match=r"b\.tif: cannot read as TIFF"):
        run(photos, write_manifest(tmp_path / "m.csv", ["b.tif"]), ROI_TEXT)
    (photos / "c.nef").write_bytes(b"not a raw file at all")
    with pytest.raises(ValueError, match=r"c\.nef: cannot read as camera raw"):
        run(photos, write_manifest(tmp_path / "m.csv", ["c.nef"]), ROI_TEXT)
    (photos / "d.bmp").write_bytes(b"BM")
    with pytest.raises(ValueError, match=r"d\.bmp: unsupported file type '\.bmp'"):
        run(photos, write_manifest(tmp_path / "m.csv", ["d.bmp"]), ROI_TEXT)


def test_manifest_photo_missing_on_disk(one_photo, tmp_path):
    photos, _ = one_photo
    manifest = write_manifest(tmp_path / "m2.csv", ["a.png", "gone.png", "also.png"])
    with pytest.raises(FileNotFoundError, match=r"2 photo\(s\) .*not in .*'gone\.png' \(line 3 of "
                                                r".*m2\.csv\); 'also\.png' \(line 4 of"):
        run(photos, manifest, ROI_TEXT)


def test_photo_on_disk_missing_from_manifest_warns(one_photo):
    photos, manifest = one_photo
    write_png(photos / "stray.png", np.zeros((H, W), np.uint8))
    (photos / "notes.txt").write_text("not a photo")
    table, msgs = run(photos, manifest, ROI_TEXT)
    assert len(table) == 1
    assert msgs == [m for m in msgs if "stray.png" in m and "not in" in m] and len(msgs) == 1


@pytest.mark.parametrize("table, match", [
    ({"name": ["a.png"], "psi": [60], "rho": [0]}, r"no column 'file'"),
    ({"file": ["a.png", ""], "psi": [60, 60], "rho": [0, 1]},
     r"line 3 of .*m\.csv, column 'file': empty"),
    ({"file": ["a.png", "a.png"], "psi": [60, 60], "rho": [0, 1]},
     r"line 3 of .*'a\.png' is listed again \(first on line 2 of"),
    ({"file": ["../a.png"], "psi": [60], "rho": [0]}, r"not a path inside PHOTO_DIR"),
    ({"file": ["a.png"], "psi": [60], "rho": [0], "value": [1]}, r"'value' would be overwritten"),
    ({"file": ["a.png"], "colour": ["red"]}, r"m\.csv has no angle columns"),
    ({"file": ["a.png", "b.png"], "psi": [60, 60], "rho": [0, "x"]},
     r"line 3 of .*m\.csv, column 'rho': 'x' is not a number"),
    ({"file": ["a.png", "b.png"], "psi": [60, 60], "rho": [5, 5]},
     r"duplicate configurations .*line 2 of .*m\.csv and line 3 of"),
    ({"file": ["a.png"], "psi": [60], "rho": [70]}, r"line 2 of .*m\.csv: psi = 60, rho = 70"),
])
def test_manifest_errors(one_photo, tmp_path, table, match):
    photos, _ = one_photo
    pd.DataFrame(table).to_csv(tmp_path / "m.csv", index=False)
    with pytest.raises(ValueError, match=match):
        run(photos, tmp_path / "m.csv", ROI_TEXT)


@pytest.mark.parametrize("header, row, dup", [
    ("file,theta_i,theta_r,theta_i", "a.png,10,20,10", "'theta_i'"),
    ("file,psi,rho,file", "a.png,60,0,a.png", "'file'"),
    ("file, psi,rho ,psi,rho", "a.png,60,0,60,0", "'psi', 'rho'"),
])
def test_cli_manifest_duplicate_column_names_exit_2(one_photo, tmp_path, header, row, dup):
    # pandas renamed the second one (theta_i.1) and ingest wrote it through
    photos, _ = one_photo
    manifest, out = tmp_path / "dup.csv", tmp_path / "out.csv"
    manifest.write_text(f"{header}\n{row}\n")
    result = CliRunner().invoke(main, ["ingest", str(photos), "--manifest", str(manifest),
                                       "--roi", ROI_TEXT, "-o", str(out)])
    assert result.exit_code == 2, result.output
    assert f"{manifest} has duplicate column names: {dup}" in result.output
    assert "Traceback" not in result.output and not out.exists()


def test_manifest_blank_header_cell_keeps_its_name(one_photo, tmp_path):
    photos, _ = one_photo
    (tmp_path / "m2.csv").write_text("file,psi,rho,,note\na.png,60,0,,x\n")
    table, _ = run(photos, tmp_path / "m2.csv", ROI_TEXT)
    assert table.columns.tolist()[:5] == ["file", "psi", "rho", "Unnamed: 3", "note"]


def test_manifest_signed_inplane_form_and_subfolder(photos, tmp_path):
    (photos / "day1").mkdir()
    write_png(photos / "day1" / "a.png", np.full((H, W), 500, np.uint16))
    pd.DataFrame({"file": ["day1/a.png"], "theta_i": [40.0], "theta_r": [-10.0]}).to_csv(
        tmp_path / "m.csv", index=False)
    table, msgs = run(photos, tmp_path / "m.csv", ROI_TEXT)
    assert msgs == []
    assert table.loc[0, ["theta_i", "theta_r", "value"]].tolist() == [40.0, -10.0, 500.0]


def test_gray_image_has_no_colour_channel(one_photo):
    photos, manifest = one_photo
    with pytest.raises(ValueError, match=r"single-channel .* no channel 'r'"):
        run(photos, manifest, ROI_TEXT, channel="r")


# -- PHOTO_DIR untouched, streaming, the command line --------------------------------------

def make_series(photos, tmp_path):
    files = []
    for k in range(3):
        write_png(photos / f"p{k}.png", gaussian(10000 + 1000 * k, 50, (H, W, 3), 30 + k))
        files.append(f"p{k}.png")
    write_tiff(photos / "t.tif", gaussian(5000, 50, (H, W, 3), 40), photometric="rgb")
    write_jpeg(photos / "j.jpg", np.full((H, W, 3), 90, np.uint8))
    mosaic, _ = mosaic_image((300, 600, 900), 64, 41, shape=(H, W))
    write_dng(photos / "r.dng", mosaic)
    files += ["t.tif", "j.jpg", "r.dng"]
    return write_manifest(tmp_path / "m.csv", files)


def test_photo_dir_untouched_and_output_written(photos, tmp_path):
    manifest = make_series(photos, tmp_path)
    before = hash_tree(photos)
    manifest_hash = hashlib.sha256(manifest.read_bytes()).hexdigest()
    result = CliRunner().invoke(main, ["ingest", str(photos), "--manifest", str(manifest),
                                       "--roi", ROI_TEXT, "--black-roi", BLACK_TEXT,
                                       "--channel", "g", "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 0, result.output
    assert hash_tree(photos) == before
    assert hashlib.sha256(manifest.read_bytes()).hexdigest() == manifest_hash
    assert "not linear" in result.output  # the JPEG warning reaches the user
    out = pd.read_csv(tmp_path / "out.csv")
    assert out["file"].tolist() == ["p0.png", "p1.png", "p2.png", "t.tif", "j.jpg", "r.dng"]
    assert out["value"].iloc[:3].to_numpy() == pytest.approx([10000, 11000, 12000], abs=15)
    assert out["value"].iloc[4] == 90.0
    assert out["value"].iloc[5] == pytest.approx(600, abs=15)
    assert {"black", "black_sigma", "sigma", "saturated", "clipped", "n_pixels",
            "session"} <= set(out.columns)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".out")] == []


def test_one_photo_in_memory_at_a_time(tmp_path):
    """Peak memory does not grow with the number of photos (streaming, ROIs kept only)."""
    import tracemalloc

    photo_bytes = 300 * 500 * 3 * 2  # one decoded photo, 0.9 MB
    series = {}
    for count in (2, 8):
        d = tmp_path / f"s{count}"
        d.mkdir()
        files = [f"p{k}.png" for k in range(count)]
        for k, f in enumerate(files):
            write_png(d / f, gaussian(20000, 300, (300, 500, 3), k))
        series[count] = (d, write_manifest(tmp_path / f"m{count}.csv", files))
    run(*series[2], ROI_TEXT)  # warm-up: imports and first-call caches are not measured
    peaks = {}
    for count, (d, manifest) in series.items():
        tracemalloc.start()
        run(d, manifest, ROI_TEXT)
        peaks[count] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peaks[2] > photo_bytes  # a photo is decoded whole (PNG) ...
    assert peaks[8] < peaks[2] + 0.5 * photo_bytes  # ... but only one at a time


def invoke(args):
    return CliRunner().invoke(main, ["ingest", *map(str, args)])


@pytest.mark.parametrize("case", ["roi_outside", "missing_photo", "bad_roi", "no_file_column",
                                  "output_is_manifest", "bad_channel", "unreadable",
                                  "all_saturated", "output_in_photo_dir",
                                  "new_output_in_photo_dir", "photo_sizes",
                                  "negative_saturation"])
def test_cli_user_errors_exit_2_without_traceback(photos, tmp_path, case):
    write_png(photos / "a.png", np.full((H, W), 500, np.uint16))
    manifest = write_manifest(tmp_path / "m.csv", ["a.png"])
    out = tmp_path / "out.csv"
    args = [photos, "--manifest", manifest, "--roi", ROI_TEXT, "-o", out]
    expect = {"roi_outside": "outside the image", "missing_photo": "not in",
              "bad_roi": "expected 4 integers", "no_file_column": "no column 'file'",
              "output_is_manifest": "never overwrites", "bad_channel": "'x' is not one of",
              "unreadable": "cannot decode as PNG", "all_saturated": "were excluded",
              "output_in_photo_dir": "never modifies PHOTO_DIR",
              "new_output_in_photo_dir": "never modifies PHOTO_DIR",
              # the odd photo, both sizes and the first photo named (accepted before)
              "photo_sizes": "61 x 40 pixels, but the stack's first photo",
              # the valid range named (before: every photo excluded as saturated)
              "negative_saturation": "saturation level -5 (--saturation): expected a code "
                                     "value > 0"}[case]
    if case == "roi_outside":
        args[4] = "0,0,61,5"
    elif case == "missing_photo":
        write_manifest(manifest, ["a.png", "b.png"])
    elif case == "bad_roi":
        args[4] = "1,2,3"
    elif case == "no_file_column":
        pd.DataFrame({"photo": ["a.png"], "psi": [60], "rho": [0]}).to_csv(manifest, index=False)
    elif case == "output_is_manifest":
        args[-1] = manifest
    elif case == "bad_channel":
        args += ["--channel", "x"]
    elif case == "unreadable":
        (photos / "a.png").write_bytes(b"garbage")
    elif case == "all_saturated":
        args += ["--saturation", "400"]
    elif case == "output_in_photo_dir":
        args[-1] = photos / "a.png"
    elif case == "new_output_in_photo_dir":  # a new file there too: PHOTO_DIR is read only
        args[-1] = photos / "new.csv"
    elif case == "photo_sizes":
        write_png(photos / "b.png", np.full((H, W + 1), 500, np.uint16))
        write_manifest(manifest, ["a.png", "b.png"])
    elif case == "negative_saturation":
        args += ["--saturation", "-5"]
    result = invoke(args)
    assert result.exit_code == 2, result.output
    assert expect in result.output
    assert "Traceback" not in result.output
    assert not out.exists() and not (photos / "new.csv").exists()
    if case == "photo_sizes":
        assert "b.png" in result.output and "a.png" in result.output


@pytest.mark.parametrize("sep, said", [(";", "';'"), ("\t", "tabs")])
def test_a_table_separated_otherwise_than_by_commas_is_named(one_photo, tmp_path, sep, said):
    """A spreadsheet's semicolons (or tabs) read as one column: the error says why."""
    photos, _ = one_photo
    manifest, table = tmp_path / "m.csv", tmp_path / "t.csv"
    manifest.write_text(sep.join(["file", "psi", "rho"]) + "\n" + sep.join(["a.png", "60", "0"]))
    table.write_text(sep.join(["theta_i", "theta_r", "value"]) + "\n30" + sep + "30" + sep + "1.5\n")
    hint = f"the header looks separated by {said}"
    result = CliRunner().invoke(main, ["ingest", str(photos), "--manifest", str(manifest),
                                       "--roi", ROI_TEXT, "-o", str(tmp_path / "out.csv")])
    assert result.exit_code == 2 and hint in result.output, result.output
    with pytest.raises(veil.errors.MeasurementError, match=hint):
        veil.load_measurements(table)
    # a comma-separated table whose names hold a semicolon is not taken for one
    (tmp_path / "ok.csv").write_text("theta_i,theta_r,value,note;x\n30,30,1.5,a\n")
    assert "note;x" in veil.load_measurements(tmp_path / "ok.csv").columns


def test_a_fit_warns_of_a_black_column_it_does_not_subtract(tmp_path):
    """A table of `veil ingest --black-roi` has the black cloth's light beside the object in
    its column `black`; a fit without a black-cloth table fitted the values as they are, the
    medium's glow in them, without a word. It now says so; with the black cloth given, or a
    black column of zeros, nothing is said."""
    from veil.fitting.session_data import prepare

    table = pd.DataFrame({"theta_i": [30.0, 30.0, 45.0], "theta_r": [20.0, 40.0, 45.0],
                          "value": [2.0, 3.0, 5.0], "black": [0.5, 0.4, 0.6]})
    path = tmp_path / "meas.csv"
    table.to_csv(path, index=False)
    with pytest.warns(UserWarning, match=r"meas\.csv has a 'black' column .* which the fit "
                                         r"does not subtract: subtract it first .*--black"):
        data = prepare(str(path))
    with warnings.catch_warnings():  # once: not again for every candidate that refits it
        warnings.simplefilter("error")
        prepare(data.table)
    black = table[["theta_i", "theta_r"]].assign(value=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        prepare(str(path), black=black)
        prepare(table.assign(black=0.0))
