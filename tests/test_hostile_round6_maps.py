"""Hostile use of ``veil fit maps`` and ``veil ingest``, sixth round: a grey dark frame for
one colour channel of colour photos (``ingest --channel g``: an IndexError, status 3); -o a
folder that is no maps store (a lock file left beside it; with --blur-rounds refused after
every round but the last); a --noise whose square is no float (an OverflowError, status 3,
or every pixel "too few points"); photo values beyond float32 (read as saturated). Each is
status 2 naming the file or option, nothing written."""

from __future__ import annotations

import numpy as np
import pytest

from support.cli import run_checked
from test_ingest import write_manifest, write_png

H, W = 12, 16
ROI = "2,2,8,6"


def _said(r) -> str:
    return " ".join(r.output.split())


def _maps_of_no_photos(tmp_path, *options, out=None):
    """``veil fit maps`` of an empty photo folder and manifest, with ``options`` and -o
    ``out`` (o.zarr by default): for refusals that come before any photo is read."""
    (tmp_path / "photos").mkdir()
    (tmp_path / "m.csv").write_text("file,theta_i,phi_i,theta_r,phi_r\n")
    out = tmp_path / "o.zarr" if out is None else out
    return run_checked(["fit", "maps", tmp_path / "photos", "--manifest", tmp_path / "m.csv",
                        "--medium", "BTDF2", *options, "-o", out])


@pytest.fixture
def colour_stack(tmp_path):
    """Three 16-bit RGB photos of noise, their manifest, and a grey and a colour dark frame."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(6)
    names = [f"p{k}.png" for k in range(3)]
    for k, name in enumerate(names):
        write_png(photos / name, rng.normal(500 + 50 * k, 10, (H, W, 3)).astype(np.uint16))
    write_png(tmp_path / "dark_grey.png", rng.normal(20, 2, (H, W)).astype(np.uint16))
    write_png(tmp_path / "dark_rgb.png", rng.normal(20, 2, (H, W, 3)).astype(np.uint16))
    return photos, write_manifest(tmp_path / "m.csv", names)


# -- 1. ingest: a grey dark frame for one channel of colour photos -------------------------
@pytest.mark.parametrize("channel", ["r", "g", "b"])
def test_a_grey_dark_frame_for_one_colour_channel_is_named(colour_stack, tmp_path, channel):
    """Its hot pixels were counted in the channel it does not have: IndexError, status 3."""
    photos, manifest = colour_stack
    out = tmp_path / "out.csv"
    r = run_checked(["ingest", photos, "--manifest", manifest, "--roi", ROI, "--channel",
                     channel, "--dark", tmp_path / "dark_grey.png", "-o", out])
    assert r.exit_code == 2, r.output
    said = _said(r)
    assert "dark frame" in said and "dark_grey.png" in said, said
    assert f"no channel '{channel}'" in said and "channel gray" in said, said
    assert not out.exists()
    ok = run_checked(["ingest", photos, "--manifest", manifest, "--roi", ROI, "--channel",
                      channel, "--dark", tmp_path / "dark_rgb.png", "-o", out])
    assert ok.exit_code == 0, ok.output


# -- 2. fit maps: -o an existing folder that is no maps store ------------------------------
@pytest.mark.parametrize("rounds", [[], ["--blur-rounds", "2"]])
def test_a_folder_that_is_no_store_is_refused_first_and_no_lock_left(tmp_path, monkeypatch,
                                                                     rounds):
    """It was refused only once the photos were read (with --blur-rounds N: after N maps
    fitted into a temporary folder), leaving a lock file .NAME.veil-lock beside it."""
    import veil.cli.maps_cmd as cmd
    import veil.maps.run as mr
    from veil.errors import InputError
    from veil.maps.blur_rounds import fit_maps_rounds

    def work(*args, **kwargs):
        raise AssertionError("work done before the output was checked")

    for module, name in ((cmd, "load_medium"), (mr, "load_acquisition"), (mr, "_tables"),
                         (mr, "fit_maps")):
        monkeypatch.setattr(module, name, work)
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    r = _maps_of_no_photos(tmp_path, *rounds, out=folder)
    assert r.exit_code == 2, r.output
    assert f"{folder} exists and is not a veil maps store" in _said(r), r.output
    with pytest.raises(InputError, match="exists and is not a veil maps store"):
        fit_maps_rounds(tmp_path / "photos", tmp_path / "m.csv", None, folder, rounds=2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.csv", "mine", "photos"]
    assert [p.name for p in folder.iterdir()] == ["notes.txt"]


# -- 3. fit maps: a noise whose square is no float -----------------------------------------
@pytest.mark.parametrize("noise", ["1e200", "0.01,1e300", "1e-160", "0,1e-300"])
def test_a_noise_beyond_a_floats_square_is_refused_by_the_option(tmp_path, noise):
    """--noise 1e200: (1e200)^2 raised an OverflowError in the weights (status 3) after the
    tables and the staging; 1e-160 gave every pixel weight 0 ("too few points", status 1)."""
    from veil.errors import InputError
    from veil.maps.run import check_noise

    out = tmp_path / "o.zarr"
    r = _maps_of_no_photos(tmp_path, "--noise", noise)
    assert r.exit_code == 2, r.output
    said = _said(r)
    assert f"--noise '{noise}'" in said and "0 or from 1e-150 to 1e+150" in said, said
    assert not out.exists()
    parts = tuple(float(v) for v in noise.split(","))
    with pytest.raises(InputError, match="each part 0 or from 1e-150 to 1e"):
        check_noise(parts)
    assert check_noise((0.01, 1e-6)) == (0.01, 1e-6)


# -- 4. fit maps: values beyond float32 ----------------------------------------------------
@pytest.mark.parametrize("where", ["photo", "black frame"])
def test_values_beyond_float32_are_named_not_taken_for_saturated(tmp_path, where):
    """A float64 photo (or a black frame) with values beyond float32's range: staged as
    infinities, its pixels came out "no usable photo (saturated or clipped in every photo)"
    with an "overflow encountered in cast" warning per photo; now the photo is named, status
    2, and no store is left."""
    import tifffile

    from support.maps import configurations

    configs = configurations(4)
    photos = tmp_path / "photos"
    photos.mkdir()
    names = []
    for k in range(len(configs)):
        image = np.full((8, 8), 2.0 + k)
        if where == "photo" and k == 2:
            image[3, 4] = 1e39
        names.append(f"p{k}.tif")
        tifffile.imwrite(photos / names[-1], image)
    manifest = tmp_path / "m.csv"
    configs.assign(file=names)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]].to_csv(
        manifest, index=False)
    dark = np.zeros((8, 8))
    dark[1, 1] = -1e300 if where == "black frame" else 0.0
    tifffile.imwrite(tmp_path / "dark.tif", dark)
    out = tmp_path / "o.zarr"
    r = run_checked(["fit", "maps", photos, "--manifest", manifest, "--medium", "BTDF2",
                     "--fix", "eta=1.5", "--grid", "n=0.25:2.5:4", "--accuracy", "fast",
                     "--black-frame", tmp_path / "dark.tif", "-o", out])
    assert r.exit_code == 2, r.output
    said = _said(r)
    assert "1 value(s)" in said and "beyond float32's range" in said, said
    if where == "photo":
        assert "p2.tif (line 4 of" in said and "largest 1e+39" in said, said
    else:
        assert "p0.tif (line 2 of" in said and "after the black's subtraction" in said, said
    assert "overflow" not in said
    assert not out.exists()


# -- 5. maps export: a map beyond float32 --------------------------------------------------
def test_an_export_keeps_values_beyond_float32_finite_and_says_so(tmp_path):
    """A map weighted by --noise 0,1e-150 (in the range, far below the photos' own noise):
    its reduced chi-square is about 1e300, which the float32 files held as infinity (with a
    raw "overflow encountered in cast"); now float32's largest, with a warning naming the
    map, and the store keeps the value."""
    import tifffile

    from veil.maps.run import open_maps

    from support.maps import configurations

    configs = configurations(6)
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(3)
    names = []
    for k in range(len(configs)):
        names.append(f"p{k}.tif")
        tifffile.imwrite(photos / names[-1], rng.normal(2.0 + k, 0.1, (8, 8)))
    manifest = tmp_path / "m.csv"
    configs.assign(file=names)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]].to_csv(
        manifest, index=False)
    out = tmp_path / "o.zarr"
    r = run_checked(["fit", "maps", photos, "--manifest", manifest, "--medium", "BTDF2",
                     "--fix", "eta=1.5", "--grid", "n=0.25:2.5:4", "--accuracy", "fast",
                     "--noise", "0,1e-150", "-o", out])
    assert r.exit_code in (0, 1), r.output
    folder = tmp_path / "export"
    shown = run_checked(["maps", "export", out, "-o", folder])
    assert shown.exit_code == 0, shown.output
    said = _said(shown)
    assert "Warning: chi2_reduced:" in said and "beyond float32's range" in said, said
    assert "overflow" not in said
    top = float(np.finfo(np.float32).max)
    for path in folder.glob("*.tif"):
        image = tifffile.imread(path)
        assert np.all(np.isfinite(image)), path.name
    chi2 = tifffile.imread(folder / "chi2_reduced.tif")
    assert chi2.max() == np.float32(top)
    assert np.max(open_maps(out)["chi2_reduced"]) > 1e100


# -- 6. fit maps: --blur-from the output itself --------------------------------------------
def test_blur_from_the_output_is_refused_before_anything_is_read(tmp_path, monkeypatch):
    """It was refused (as a store of other settings) only after the photos were read and
    corrected for the blur of the store it was about to replace."""
    import veil.maps.run as mr

    def work(*args, **kwargs):
        raise AssertionError("work done before the output was checked")

    monkeypatch.setattr(mr, "load_acquisition", work)
    out = tmp_path / "o.zarr"
    r = _maps_of_no_photos(tmp_path, "--blur-from", out)
    assert r.exit_code == 2, r.output
    assert f"--blur-from {out} is the output: write the map to a new store" in _said(r), r.output
    # with rounds too: the first rounds' maps were fitted before the last one was refused
    monkeypatch.setattr(mr, "fit_maps", work)
    again = run_checked(["fit", "maps", tmp_path / "photos", "--manifest", tmp_path / "m.csv",
                         "--medium", "BTDF2", "--blur-from", out, "--blur-rounds", "2",
                         "-o", out])
    assert again.exit_code == 2, again.output
    assert f"--blur-from {out} is the output" in _said(again), again.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.csv", "photos"]
