"""The medium's blur across the plate (veil.maps.blur, docs/maps-blur.md; ``veil fit maps
--blur-from``). The kernel's share on a square plate seen from its centre against the
model's own plate weight J_v (eq. 8.1b), integrated here over the scattering direction
independently of the kernel's quadrature (tests/support/blur.py); the side the kernel
leans to in an oblique view and the image orientation of its rows and columns; the kernel
deterministic and normalised over the endless plane, each medium's and view direction's
the same alone as beside others; bad input to ``veil fit maps --blur-from`` (exit 2,
nothing written); and a near-field plate rendered with the blur, whose boundary bias the
fit from the blur-corrected photos removes round by round."""

from __future__ import annotations

import numpy as np
import pytest

import veil
from support.blur import plate_shares
from support.cli import run
from support.maps import angles_of, configurations, render_near, write_photos
from veil.maps.blur import view_kernels
from veil.maps.near import NearGeometry
from veil.maps.store import open_maps

#: the medium of the brief: optical depth 0.9 over a path of 15 units, a plate 5 wide
MEDIUM = veil.ForwardSeries(tau=0.9, omega=0.95, g=0.9, path_length=15.0, plate_width=5.0)
HALF_WIDTH = 2.5


def kernel(theta_r, phi_r, pitch, half, media=(MEDIUM,)):
    return view_kernels(np.array([float(theta_r)]), np.array([float(phi_r)]), list(media),
                        pitch, half)[0, 0]


def ring_mean(k: np.ndarray, part) -> float:
    """``part`` (a function of a kernel and its half size) of the kernel within ``half``
    pixels and within ``half - 1``, averaged: the share within ``half`` pitches rather than
    ``half + 1/2`` (a kernel of ``half`` bins |offset| < (half + 1/2) pitch)."""
    h = k.shape[0] // 2
    outer, inner = part(k, h), part(k[1:-1, 1:-1], h - 1)
    if isinstance(outer, dict):
        return {key: 0.5 * (outer[key] + inner[key]) for key in outer}
    return 0.5 * (outer + inner)


def sides(k: np.ndarray, h: int) -> dict:
    """The kernel's share towards the plate's +x (columns right of the centre), -x, +y
    (rows above: image rows run down) and -y, half of the centre column or row to each."""
    col, row = k[:, h].sum(), k[h].sum()
    return {"+x": k[:, h + 1:].sum() + col / 2, "-x": k[:, :h].sum() + col / 2,
            "+y": k[:h].sum() + row / 2, "-y": k[h + 1:].sum() + row / 2}


# --------------------------------------------------------------------------------------
# (1) the kernel against the model's J_v
# --------------------------------------------------------------------------------------
#: |kernel's share on the plate - F| (measured at pitch a/60: at most 7.7e-4, theta_r 65;
#: 3e-4 and 1e-4 at 10 and 40; without the ring mean the half pixel beyond the edge adds
#: 2.4e-3). Perturbed copies of blur.py, measured: without e^{-beta t} 0.034-0.042 off;
#: mu_R' / mu_R for mu_R / mu_R' 0.030-0.077; order weights without the 1/k! 0.14-0.15;
#: t over half the path 0.14-0.20. (The sign of v and the rows and columns do not change a
#: square's share: the next two tests see them.)
SHARE_TOL = 3e-3


@pytest.mark.parametrize("theta_r,phi_r", [(10, 0), (40, 0), (65, 0), (65, 180)])
def test_kernel_share_on_the_plate_is_the_models_plate_weight(theta_r, phi_r):
    """The share of the kernel within the plate's half width a of the centre (a square,
    a / pitch = 60 pixels) equals F = Sum_k w_k Int p(g^k) J_v,plate / Sum_k w_k Int p(g^k)
    J_v,endless over mu_R' > 0, the model's own weight of its finite plate (measured F:
    0.741, 0.712, 0.618 at theta_r 10, 40, 65)."""
    n = 60
    k = kernel(theta_r, phi_r, HALF_WIDTH / n, n)
    got = ring_mean(k, lambda k, h: k.sum())
    want = plate_shares(MEDIUM, theta_r, phi_r)["plate"]
    assert 0.55 < want < 0.8  # the plate holds a part of the scattered light, not all
    assert abs(got - want) < SHARE_TOL, (got, want)


#: the shares towards a side against the quadrature's (measured: within 2e-4 at theta_r 60
#: and 40. Perturbed copies of blur.py: v's sign flipped puts 0.263 on +x and 0.384 on
#: -x; rows and columns swapped 0.324 on either x side; rows running up 0.319 on +y)
SIDE_TOL = 3e-3


def test_oblique_view_leans_towards_the_camera():
    """theta_r 60, phi_r 0 (the camera towards +x): light arriving from R' leaves the plate
    at y = x + t v, v = R - (mu_R / mu_R') R' (B.1), so v_x > 0 exactly when R' is nearer
    the normal than R in the plane of R and the y axis (R'_x / mu_R' < R_x / mu_R). That
    great circle halves the lobe about R, but on the camera's side of it the lobe dips
    below the horizon (no light from the plate) and e^{-beta t} (beta > 0 when mu_R' <
    mu_R) dims what is left: the kernel leans towards +x, its columns right of the centre
    (measured 0.384 on the plate's right against 0.263 on its left). Seen from phi_r 180
    it is the mirror image; the y halves are equal."""
    n = 60
    pitch = HALF_WIDTH / n
    want = plate_shares(MEDIUM, 60, 0)
    got = ring_mean(kernel(60, 0, pitch, n), sides)
    assert got["+x"] > got["-x"] + 0.1, got
    for key in ("+x", "-x", "+y", "-y"):
        assert abs(got[key] - want[key]) < SIDE_TOL, (key, got, want)
    assert abs(got["+y"] - got["-y"]) < 1e-9
    mirror = kernel(60, 180, pitch, n)
    np.testing.assert_allclose(mirror[:, ::-1], kernel(60, 0, pitch, n), atol=1e-4)
    assert abs(want["+y"] - want["-y"]) < 1e-6


def test_rows_run_down_the_plate():
    """phi_r 90 (the camera towards the plate's +y): the kernel leans towards +y, which in
    the image is up (rows above the centre; image rows run down, the plate's -y; measured
    0.393 above, 0.319 below against 0.393 and 0.319 from the quadrature); the columns
    (+x and -x) are even."""
    n = 60
    k = kernel(40, 90, HALF_WIDTH / n, n)
    got = ring_mean(k, sides)
    want = plate_shares(MEDIUM, 40, 90)
    assert got["+y"] > got["-y"] + 0.05, got
    for key in ("+x", "-x", "+y", "-y"):
        assert abs(got[key] - want[key]) < SIDE_TOL, (key, got, want)
    assert abs(got["+x"] - got["-x"]) < 1e-6
    assert k[:n].sum() > k[n + 1:].sum() + 0.05  # the rows above the centre
    assert abs(k[:, :n].sum() - k[:, n + 1:].sum()) < 1e-6


# --------------------------------------------------------------------------------------
# (2) deterministic and normalised
# --------------------------------------------------------------------------------------
THETA = np.array([0.0, 10.0, 40.0, 65.0, 80.0])
PHI = np.array([0.0, 30.0, 180.0, 270.0, 45.0])
OTHER = veil.ForwardSeries(tau=0.5, omega=0.9, g=0.7, path_length=15.0, plate_width=5.0)


def test_kernels_deterministic_and_normalised_over_the_endless_plane():
    """Two calls give the same bits. Within 60 units (4 R_c, 120 pixels of 0.5) of the
    centre a kernel holds all but 3e-5 - 1.2e-3 of its weight (measured; the rest lands
    beyond, from R' near the horizon); within 300 units all but 2e-12 (g 0.9) and 2e-8
    (g 0.7). No kernel sums to
    more than 1, and none has a negative cell."""
    a = view_kernels(THETA, PHI, [MEDIUM, OTHER], 0.5, 120)
    b = view_kernels(THETA, PHI, [MEDIUM, OTHER], 0.5, 120)
    assert a.shape == (2, 5, 241, 241)
    assert np.array_equal(a, b)
    total = a.sum(axis=(2, 3))
    assert np.all(total <= 1 + 1e-12), total
    assert np.all(1 - total < 3e-3), total
    assert np.all(a >= 0)
    wide = view_kernels(THETA, PHI, [MEDIUM, OTHER], 1.0, 300).sum(axis=(2, 3))
    assert np.all(wide <= 1 + 1e-12) and np.all(1 - wide < 1e-7), wide
    # a smaller window holds less: 1 - sum 0.011-0.053 within 15 units (measured)
    near = view_kernels(THETA, PHI, [MEDIUM, OTHER], 0.25, 60).sum(axis=(2, 3))
    assert np.all(near < total - 5e-3)


def test_each_medium_and_direction_its_own():
    """Of several media and view directions, each kernel is the one of that medium and
    direction alone: bit for bit for the first medium (it sets the orders), within 1e-6
    for another (its orders' cut-off follows the largest omega tau; measured 4e-7)."""
    tr, pr = np.array([10.0, 65.0]), np.array([30.0, 270.0])
    third = veil.ForwardSeries(tau=0.6, omega=0.95, g=0.9, path_length=15.0, plate_width=5.0)
    both = view_kernels(tr, pr, [MEDIUM, OTHER, third], 0.5, 40)
    for c, m in enumerate((MEDIUM, OTHER, third)):
        for j in range(2):
            alone = view_kernels(tr[j:j + 1], pr[j:j + 1], [m], 0.5, 40)[0, 0]
            if c == 0:
                assert np.array_equal(both[c, j], alone)
            else:
                assert np.max(np.abs(both[c, j] - alone)) < 1e-6
    assert np.max(np.abs(both[0] - both[1])) > 1e-3  # g 0.9 and 0.7: different kernels


# --------------------------------------------------------------------------------------
# (3) bad input: exit 2, nothing written
# --------------------------------------------------------------------------------------
BRDF = veil.BRDF1
NAMES = type(BRDF).param_names()
INDEX, SHAPE = NAMES[3], NAMES[2]
ETA = float(BRDF.to_vector()[3])
#: a plate 1.5 wide: 6 of the stack's 8 pixels of 0.25, pixels 1 to 7 about the centre (4, 4)
FORWARD = ["--medium-model", "forward-series", "--medium", "0.9,0.95,0.9,1,1", "--path-length",
           15, "--plate-width", 1.5]
DISTANCE, PITCH = 100.0, 0.25
NEAR = ["--near-field", "--camera-distance", DISTANCE, "--pixel-pitch", PITCH]


def maps_args(root, manifest, out, medium, *extra, grid="0.25:2.5:4"):
    return ["fit", "maps", root / "photos", "--manifest", manifest, *medium, "--fix",
            f"{INDEX}={ETA}", "--grid", f"{SHAPE}={grid}", "--accuracy", "fast", "--tile", 16,
            "-o", out, *extra]


@pytest.fixture(scope="module")
def small_stack(tmp_path_factory):
    """8 x 8 pixels of 8 configurations (values that need not fit: the checks come before
    the fit) and a complete map of them through the paper's medium at the manifest's
    angles (its pixels at the table's edge, exit 1: the map is complete all the same;
    measured 3.7 s, 8.6 s with the engine's compile)."""
    root = tmp_path_factory.mktemp("blur-bad")
    configs = configurations(8)
    values = 0.05 * (1 + 0.1 * np.random.default_rng(0).random((64, len(configs))))
    manifest = write_photos(root / "photos", configs, values, (8, 8), noise=0.0)
    prior = root / "prior.zarr"
    result = run(*maps_args(root, manifest, prior, ["--medium", "BTDF2"]))
    assert result.exit_code in (0, 1), result.output
    open_maps(prior)  # complete
    return root, manifest, prior


def test_bad_blur_input_exits_2(small_stack, tmp_path):
    """Checked before any table is built (each measured < 0.1 s): --blur-from without
    --near-field; through the paper's medium (not forward-series) or a forward-series one
    without its path length and plate width; a store that does not exist, or a folder that
    is no maps store."""
    root, manifest, prior = small_stack
    out = tmp_path / "bad.zarr"

    def bad(medium, *extra):
        result = run(*maps_args(root, manifest, out, medium, *extra))
        assert result.exit_code == 2, result.output
        assert "Traceback" not in result.output
        assert "veil maps: tables" not in result.output and "tables:" not in result.output
        assert not out.exists()
        return result.output

    text = bad(FORWARD, "--blur-from", prior)
    assert "--near-field" in text and "--blur-from" in text, text
    text = bad(FORWARD, "--blur-from", prior, "--camera-distance", DISTANCE, "--pixel-pitch",
               PITCH)  # the distant camera's geometry: still no near field
    assert "--near-field" in text, text
    text = bad(["--medium", "BTDF2"], *NEAR, "--blur-from", prior)
    assert "forward-series" in text and "henyey-greenstein" in text, text
    text = bad(["--medium-model", "forward-series", "--medium", "0.9,0.95,0.9,1,1"], *NEAR,
               "--blur-from", prior)
    assert "forward-series" in text and "path_length 0" in text, text
    missing = tmp_path / "nothere.zarr"
    text = bad(FORWARD, *NEAR, "--blur-from", missing)
    assert "nothere.zarr" in text and "no such maps store" in text, text
    text = bad(FORWARD, *NEAR, "--blur-from", root / "photos")
    assert "not a veil maps store" in text, text


def test_prior_of_another_region_exits_2(small_stack, tmp_path):
    """A prior map of the region 0,0,8,8 for a fit of 1,1,6,6 (which covers the plate):
    refused naming both regions before any table is built, nothing written."""
    root, manifest, prior = small_stack
    out = tmp_path / "shape.zarr"
    result = run(*maps_args(root, manifest, out, FORWARD, *NEAR, "--blur-from", prior,
                            "--roi", "1,1,6,6"))
    assert result.exit_code == 2, result.output
    assert "roi" in result.output and "'0,0,8,8'" in result.output, result.output
    assert "'1,1,6,6'" in result.output, result.output
    assert "tables" not in result.output, result.output  # refused before any table
    assert not out.exists()


def test_blur_rounds_check_the_last_rounds_model_error_first(small_stack, tmp_path):
    """--blur-rounds with --model-error but no --noise: refused (exit 2) before the first
    round's tables, not after every round but the last."""
    root, manifest, _ = small_stack
    out = tmp_path / "rounds.zarr"
    result = run(*maps_args(root, manifest, out, FORWARD, *NEAR, "--blur-rounds", 2,
                            "--model-error", "correlated"))
    assert result.exit_code == 2, result.output
    assert "--noise" in result.output and "tables" not in result.output, result.output
    assert not out.exists()


def test_the_priors_manifest_by_another_path_is_the_same(tmp_path, monkeypatch):
    """A prior map whose manifest was given as an absolute path, refitted with the same
    manifest by a relative one (or through a symbolic link): accepted; another file of the
    same name elsewhere: refused, naming both."""
    from veil.errors import InputError
    from veil.maps.blur import _same

    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "manifest.csv").write_text("file,psi,rho\n")
    (tmp_path / "link").symlink_to(tmp_path / "a")
    monkeypatch.chdir(tmp_path)
    stored = {"manifest": str(tmp_path / "a" / "manifest.csv"), "photos": 3}
    _same("prior.zarr", stored, {"manifest": "a/manifest.csv", "photos": 3})
    _same("prior.zarr", stored, {"manifest": "link/manifest.csv", "photos": 3})
    with pytest.raises(InputError, match="manifest") as err:
        _same("prior.zarr", stored, {"manifest": "b/manifest.csv", "photos": 3})
    assert "'b/manifest.csv'" in str(err.value) and str(tmp_path / "a") in str(err.value)
    with pytest.raises(InputError, match="photos"):
        _same("prior.zarr", stored, {"manifest": "a/manifest.csv", "photos": 4})


def test_region_short_of_the_plate_and_rounds_checked_first(small_stack, tmp_path):
    """A region that leaves part of the plate out (2,2,4,4 of a plate over pixels 1 to 7):
    exit 2 naming the plate's pixels, before any table. --blur-rounds without the near
    field, or through the paper's medium, exits 2 before its first map is fitted; a prior
    whose pixels all stopped at the table's edge (the fixture's) has nothing to correct
    from."""
    root, manifest, prior = small_stack
    out = tmp_path / "short.zarr"
    result = run(*maps_args(root, manifest, out, FORWARD, *NEAR, "--blur-from", prior,
                            "--roi", "2,2,4,4"))
    assert result.exit_code == 2, result.output
    assert "does not cover the plate" in result.output and "1 to 7" in result.output
    assert "tables" not in result.output and not out.exists()
    for medium, extra in ((FORWARD, []), (["--medium", "BTDF2"], NEAR)):
        result = run(*maps_args(root, manifest, out, medium, *extra, "--blur-rounds", 1))
        assert result.exit_code == 2, result.output
        assert "--blur-rounds" in result.output, result.output
        assert "tables" not in result.output and not out.exists()
    assert not np.any(open_maps(prior)["status"] == 0)
    result = run(*maps_args(root, manifest, out, FORWARD, *NEAR, "--blur-from", prior))
    assert result.exit_code == 2, result.output
    assert "no converged pixel" in result.output and "tables" not in result.output
    assert not [p.name for p in tmp_path.iterdir() if p.name != "short.zarr"]


# --------------------------------------------------------------------------------------
# (4) the fixed point: a plate rendered with the blur, its boundary bias removed round by
# round
# --------------------------------------------------------------------------------------
H = W = 12


def _render_blurred(medium, truth, configs, geometry):
    """Photos (H*W, M) of the plate ``truth`` as (B.3) says the camera sees it: N(x) +
    S_plate(x) Sum_y K(y - x) S_inf(y) / (F_0 S_inf(x)), summed here pixel pair by pixel
    pair (S_inf 0 off the plate), F_0 the kernel's share on the plate from the quadrature
    of tests/support/blur.py (not veil.maps.blur.plate_share)."""
    none = render_near(BRDF, medium.replace(plate_width=1e-100), configs, truth, geometry)
    endless = render_near(BRDF, medium.replace(plate_width=1e100), configs, truth, geometry)
    plate = render_near(BRDF, medium, configs, truth, geometry)
    scattered = (endless - none).reshape(H, W, -1)
    own = (plate - none).reshape(H, W, -1)
    _, _, tr, pr = geometry.angles(angles_of(configs), (W - 1) / 2, (H - 1) / 2)
    h = max(H, W)
    k = view_kernels(tr, pr, [medium], PITCH, h)[0]  # (M, 2h + 1, 2h + 1)
    f0 = np.array([plate_shares(medium, t, p)["plate"] for t, p in zip(tr, pr)])
    photos = none.reshape(H, W, -1).copy()
    for r in range(H):
        for c in range(W):
            blurred = sum(
                k[:, h + rr - r, h + cc - c] * scattered[rr, cc]
                for rr in range(H)
                for cc in range(W)
            )  # light at pixel (r, c) from the plate at (rr, cc)
            photos[r, c] += own[r, c] * blurred / (f0 * scattered[r, c])
    return photos.reshape(H * W, -1)


def test_blur_rounds_remove_the_boundary_bias(tmp_path):
    """A 12 x 12 plate (pitch 0.25, the medium's plate 3 wide: the region itself), the
    albedo 0.4 and 1.6 times BRDF1's on the left and right halves, the rest BRDF1's, each
    pixel at its near-field angles rendered as (B.3) says (:func:`_render_blurred`).
    Fitted per pixel the boundary is biased (the dark side high, the bright side low);
    fitted from the photos corrected at that map's parameters and again at the next's,
    the worst error shrinks round by round (the fixed point is the truth: the correction
    is exact there), by --blur-from twice and by --blur-rounds 2 in one run alike."""
    medium = veil.ForwardSeries(tau=0.9, omega=0.95, g=0.9, path_length=15.0,
                                plate_width=W * PITCH)
    truth = np.repeat(BRDF.to_vector()[:, None, None], H, 1).repeat(W, 2)
    truth[0, :, :W // 2] *= 0.4
    truth[0, :, W // 2:] *= 1.6
    configs = configurations(12)
    geometry = NearGeometry(DISTANCE, PITCH, (H, W))
    photos = _render_blurred(medium, truth, configs, geometry)
    root = tmp_path
    manifest = write_photos(root / "photos", configs, photos, (H, W), noise=0.0)
    medium_args = ["--medium-model", "forward-series", "--medium", "0.9,0.95,0.9,1,1",
                   "--path-length", 15, "--plate-width", W * PITCH]
    errors, prior = [], None
    for round_ in range(3):
        out = root / f"round{round_}.zarr"
        extra = [] if prior is None else ["--blur-from", prior]
        result = run(*maps_args(root, manifest, out, medium_args, *NEAR, *extra,
                                grid="0.25:2.5:16"))
        assert result.exit_code == 0, result.output
        maps = open_maps(out)
        assert np.all(maps["status"] == 0)
        if prior is not None:
            assert "the medium's blur from" in result.output, result.output
            assert maps["info"]["blur_from"]["store"] == str(prior)
        errors.append(maps["params"][0] / truth[0] - 1)
        prior = out
    first, _, last = (np.abs(e).max() for e in errors)
    # the boundary: dark side (column 5) high, bright side (column 6) low (measured: 0.09
    # at the plate's corners to 0.44 in its middle rows)
    assert np.all(errors[0][:, W // 2 - 1] > 0.05) and np.all(errors[0][:, W // 2] < -0.03)
    assert np.mean(errors[0][:, W // 2 - 1]) > 0.3
    worst = [float(np.abs(e[:, W // 2 - 1:W // 2 + 1]).max()) for e in errors]
    assert worst[0] > 0.4, worst
    assert worst[1] < worst[0] / 2 and worst[2] < worst[1] / 2, worst
    assert worst[2] < worst[0] / 5, worst  # measured 0.44, 0.15, 0.042
    assert last < first / 5, (first, last)
    # the same rounds in one run: the tables built once, the rounds' stores removed
    out = root / "rounds.zarr"
    result = run(*maps_args(root, manifest, out, medium_args, *NEAR, "--blur-rounds", 2,
                            grid="0.25:2.5:16"))
    assert result.exit_code == 0, result.output
    assert result.output.count("tables: ") == 3, result.output  # plate, none, endless
    assert "round 2 of 2" in result.output
    same = open_maps(out)
    np.testing.assert_array_equal(same["params"], open_maps(prior)["params"])
    assert same["info"]["blur_from"]["store"] == "round 1 of 2 in this run"
    left = [p.name for p in root.iterdir() if p.name.startswith(".rounds.zarr.")]
    assert left == [".rounds.zarr.veil-lock"], left  # the output's own lock, as every map's


def test_uniform_plate_needs_no_correction_at_its_centre():
    """(B.3) on arrays: a uniform plate mapped over exactly the plate (16 x 16 pixels of
    a 5 wide plate), any values with S_plate < S_inf: the correction is 0 at the centre
    (the kernel's share there is F_0 by definition, up to the half pixel the centre lies
    off the pixel grid), negative towards the edges and corners (less of the kernel on the
    plate), largest in magnitude at the corners, and mirror symmetric for phi_r 0."""
    from veil.maps.blur import correction_of, plate_share

    n, pitch = 16, 5.0 / 16
    tr, pr = np.array([40.0]), np.array([0.0])
    k = view_kernels(tr, pr, [MEDIUM], pitch, n)  # (1, 1, 2n + 1, 2n + 1)
    shares = plate_share(k, 2.5, pitch)
    rng = np.random.default_rng(0)
    none, own, endless = rng.uniform(0.2, 0.3), rng.uniform(0.1, 0.2), rng.uniform(0.25, 0.3)
    full = lambda v: np.full((1, 1, n, n), v)  # noqa: E731
    corr = correction_of(full(none + own), full(none), full(none + endless), k, shares)[0, 0]
    centre = corr[n // 2 - 1:n // 2 + 1, n // 2 - 1:n // 2 + 1]
    assert np.abs(centre).max() < 0.02 * own, (centre, own)
    assert corr[0, 0] < corr[0, n // 2] < 0 and corr[0, 0] < corr[n // 2, 0] < 0
    assert corr.min() == pytest.approx(min(corr[0, 0], corr[0, -1], corr[-1, 0], corr[-1, -1]))
    np.testing.assert_allclose(corr, corr[::-1], atol=1e-12)  # rows: the y mirror
