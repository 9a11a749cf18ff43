"""Reflectance maps (docs/maps.md): the fast per-pixel solve against the engine's full
least-squares fit, the command on a simulated stack (outputs, flags, resume, determinism),
a real two-worker dask.distributed cluster against the local run, and bad input."""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile
import zarr
from click.testing import CliRunner

import veil
from support.compiles import compilations
from support.maps import angles_of, configurations, render, write_stack
from veil._jax import jax
from veil.cli import main
from veil.engine.evaluator import ApparentModel
from veil.engine.quadrature import RULES
from veil.maps.run import fit_maps, is_complete, open_maps
from veil.maps.solve import CONVERGED, EDGE, MASKED, NOT_CONVERGED, UNDETERMINED, solve_pixels
from veil.maps.tables import build_tables

BRDF, MEDIUM = veil.BRDF1, veil.BTDF2
NAMES = type(BRDF).param_names()
INDEX = NAMES[3]            # held fixed in these tests (weakly determined through a medium)
SHAPE = NAMES[2]            # the tabulated nonlinear parameter
GRID = f"{SHAPE}=0.25:2.5:16"
FIX = {INDEX: float(BRDF.to_vector()[3])}


# --------------------------------------------------------------------------------------
# the fast solve against the full fit
# --------------------------------------------------------------------------------------
def test_fast_solve_agrees_with_full_fit_within_a_tenth_of_a_standard_error():
    """Same quadrature on both sides ("fast": the full fit then iterates with its own
    exact Jacobian; at "default" its polish keeps the fast rule's Jacobian, a chord method
    whose fixed point is up to ~0.1 standard error off the default rule's optimum - the
    second half checks that the fast solve's cost under the engine is then the lower)."""
    configs = configurations(20)
    angles = angles_of(configs)
    grid = {SHAPE: (0.25, 2.5, 24)}
    rng = np.random.default_rng(3)
    truth = []
    for k in range(3):  # off the grid nodes
        v = BRDF.to_vector().copy()
        v[2] *= np.exp(rng.uniform(-0.45, 0.45))
        v[0] *= np.exp(rng.uniform(-0.3, 0.3))
        truth.append(v)
    clean = render(BRDF, MEDIUM, configs, np.array(truth))
    y = clean * (1 + 0.01 * rng.standard_normal(clean.shape))
    weighted = [False, False, True]
    valid = np.ones_like(y, dtype=bool)
    pixels = {"fast": (0, 2), "default": (1,)}
    for accuracy in ("fast", "default"):
        tables = build_tables(type(BRDF), MEDIUM, angles, fixed=FIX, accuracy=accuracy,
                              grid=grid)
        fast_u = solve_pixels(tables, y, valid)
        fast_w = solve_pixels(tables, y, valid, noise=(0.01, 0.0))
        engine = ApparentModel(BRDF, MEDIUM, angles, RULES[accuracy])
        for k in pixels[accuracy]:
            fast = fast_w if weighted[k] else fast_u
            assert fast.status[k] == CONVERGED
            table = configs.assign(value=y[k])
            w = np.ones(len(y[k]))
            if weighted[k]:
                table = table.assign(sigma=0.01 * np.abs(y[k]))
                w = 1 / (0.01 * np.abs(y[k]))
            full = veil.fit_target(table, MEDIUM, fixed=FIX, accuracy=accuracy)
            assert full.converged
            full_vec = np.array([full.params[n] for n in NAMES])
            if accuracy == "default":
                cost = [float(np.sum(((y[k] - engine.values(p, MEDIUM.to_vector())) * w) ** 2))
                        for p in (fast.params[:, k], full_vec)]
                assert cost[0] <= cost[1] * (1 + 1e-9), cost
                continue
            for i, name in enumerate(NAMES):
                if name in FIX:
                    assert fast.params[i, k] == FIX[name]
                    continue
                se = full.stderr[name]
                z = (fast.params[i, k] - full.params[name]) / se
                assert abs(z) < 0.1, (k, name, fast.params[i, k], full.params[name], se)
                assert fast.stderr[i, k] == pytest.approx(se, rel=0.05)
            assert fast.chi2[k] == pytest.approx(full.chi2_reduced, rel=1e-3)


def test_flags_dark_saturated_and_edge_pixels_are_never_converged():
    configs = configurations(16)
    tables = build_tables(type(BRDF), MEDIUM, angles_of(configs), fixed=FIX,
                          grid={SHAPE: (0.25, 2.5, 16)})
    good = render(BRDF, MEDIUM, configs, BRDF.to_vector()[None, :])[0]
    rough = BRDF.to_vector().copy()
    rough[2] = 0.05  # far below the table's range
    y = np.stack([good, np.zeros_like(good), good, good,
                  render(BRDF, MEDIUM, configs, rough[None, :])[0]])
    valid = np.ones_like(y, dtype=bool)
    valid[2] = False          # saturated in every photo
    valid[3, 2:] = False      # only two usable photos
    fits = solve_pixels(tables, y, valid)
    assert fits.status[0] == CONVERGED
    assert fits.status[1] == UNDETERMINED
    assert fits.status[2] == MASKED
    assert fits.status[3] != CONVERGED
    assert fits.status[4] in (EDGE, UNDETERMINED, NOT_CONVERGED)
    for arr in (fits.params, fits.stderr, fits.chi2):
        assert np.all(np.isfinite(arr))
    assert np.all(fits.stderr[:, 1:4] == 0)


def test_iterations_stop_per_pixel_and_a_stopped_pixel_is_frozen(monkeypatch):
    """Each pixel stops when its Gauss-Newton step is below LM_TOL standard errors and is
    then frozen: its result does not depend on the other pixels of its batch (their order,
    a dark or a saturated neighbour, being alone), on whether its last iterations ran in a
    batch of slow pixels, nor on how many more iterations the batch may run."""
    from veil.maps import solve as maps

    configs = configurations(16)
    tables = build_tables(type(BRDF), MEDIUM, angles_of(configs), fixed=FIX,
                          grid={SHAPE: (0.25, 2.5, 16)})
    rng = np.random.default_rng(11)
    truth = []
    for _ in range(12):
        v = BRDF.to_vector().copy()
        v[2] *= np.exp(rng.uniform(-0.6, 0.6))
        v[0] *= np.exp(rng.uniform(-0.3, 0.3))
        truth.append(v)
    clean = render(BRDF, MEDIUM, configs, np.array(truth))
    y = np.concatenate([clean * (1 + 0.01 * rng.standard_normal(clean.shape)),
                        np.zeros((1, clean.shape[1])), clean[:1]])
    valid = np.ones_like(y, dtype=bool)
    valid[-1] = False  # saturated in every photo
    fits = solve_pixels(tables, y, valid)
    ok = fits.status == CONVERGED
    assert ok[:12].all() and fits.status[12] == UNDETERMINED and fits.status[13] == MASKED
    assert np.all(fits.iterations[ok] < maps.ITERATIONS)
    assert np.median(fits.iterations[ok]) <= 5, fits.iterations
    assert fits.iterations[12] == 0  # nothing to fit: stopped at once

    def same(a, b, index):
        for name in ("params", "stderr", "chi2", "n_points", "status", "iterations"):
            x, z = getattr(a, name), getattr(b, name)
            assert np.array_equal(x[..., index], z), name

    order = rng.permutation(len(y))
    same(fits, solve_pixels(tables, y[order], valid[order]), order)
    for k in np.argsort(fits.iterations[:12])[[0, 5, -1]]:  # alone: a batch of one pixel
        same(fits, solve_pixels(tables, y[k:k + 1], valid[k:k + 1]), np.array([k]))
    # slow pixels finish in batches of their own: the same bits as in one pass
    # (with a first pass of 1 iteration most pixels finish in the second)
    assert np.sum(fits.iterations > 1) >= 10
    monkeypatch.setattr(maps, "FIRST_ITERATIONS", 1)
    monkeypatch.setattr(maps, "_SOLVERS", {})
    # the warm-up compiles both programs the solve runs, the slow pixels' resume too (its
    # state once came back from numpy typed otherwise, and a second resume was compiled):
    # the start and the iterations, whose limit is an input, so that a batch's first
    # iterations and the slow pixels' rest are one program per device, not two
    with compilations() as warmed:
        maps.warm_up(tables)
    assert sorted(set(warmed)) == ["jit(resume)", "jit(start)"], warmed
    assert warmed.count("jit(resume)") == len(jax.devices()), warmed
    with compilations() as compiled:
        same(fits, solve_pixels(tables, y, valid), np.arange(len(y)))
    assert not [n for n in compiled if n in ("jit(start)", "jit(resume)")], compiled
    monkeypatch.setattr(maps, "ITERATIONS", 2 * maps.ITERATIONS)
    monkeypatch.setattr(maps, "_SOLVERS", {})
    same(fits, solve_pixels(tables, y, valid), np.arange(len(y)))


# --------------------------------------------------------------------------------------
# the command on a simulated stack
# --------------------------------------------------------------------------------------
H, W = 12, 10


def test_an_axis_that_cannot_move_the_model_is_held_and_the_pixel_stops():
    """A pixel whose specular scale is 0 at its best node (a matte patch: a lobe of zero
    height has no width): the roughness column is rounding noise (these numbers are such a
    pixel's, benchmarks/bench_maps_solve_parts.py's pixels), whose ratio to itself predicts
    a decrease of 2.2 that no step finds; such a pixel damped its way through every
    iteration. Held as at a bound, it stops at its first test; an axis that moves the model
    is left as it is."""
    from veil.fitting import least_squares as lsq
    from veil.maps import solve as maps
    from veil.maps.solve import _PixelSolver

    solver = _PixelSolver(2, 1, (48,), True, False)
    p = np.array([0.72306626, 0.0, 0.0])  # diffuse, specular at its bound 0, roughness
    a = np.array([[2.12287048e06, 1.27332485e05, -1.70575200e-09],
                  [1.27332485e05, 9.29060545e03, -1.02444757e-10],
                  [-1.70575200e-09, -1.02444757e-10, 1.40058589e-24]])
    g = np.array([-1.62269459e-09, -3.72980305e01, 2.55482824e-13])

    def step(a, g):
        trial, dec = lsq.lm_step(p, a, g, 1e-3, solver.lo, solver.hi, np)
        return trial, bool(lsq.stopped(dec, maps.LM_TOL, 1.0, 1e4, np))

    assert step(a, g)[1] is False  # as the iterations saw it
    held_a, held_g = (np.asarray(x) for x in solver.without_silent_axes(a, g, 1.0))
    trial, stop = step(held_a, held_g)
    assert stop and trial[2] == p[2]
    # a roughness that moves the model by a standard error over its range stays free
    a[2, 2] = (1.0 / 47) ** 2
    kept_a, kept_g = (np.asarray(x) for x in solver.without_silent_axes(a, g, 1.0))
    assert np.array_equal(kept_a, a) and np.array_equal(kept_g, g)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    root = tmp_path_factory.mktemp("maps")
    v = BRDF.to_vector()
    pm = np.repeat(v[:, None, None], H, 1).repeat(W, 2).copy()
    pm[2] = pm[2] * np.round(np.exp(np.linspace(-0.4, 0.4, W)), 2)[None, :]
    pm[0, : H // 2] *= 1.5
    manifest = write_stack(root / "photos", BRDF, MEDIUM, configurations(16), pm, noise=0.01)
    # a dark pixel and a pixel saturated in every photo (float TIFFs: --saturation)
    for path in sorted((root / "photos").glob("*.tif")):
        img = tifffile.imread(path)
        img[0, 0] = 0.0
        img[1, 1] = 1e9
        tifffile.imwrite(path, img)
    return root, manifest, pm


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def fit_args(root, manifest, out, *extra):
    return ["fit", "maps", root / "photos", "--manifest", manifest, "--medium", "BTDF2",
            "--fix", f"{INDEX}={FIX[INDEX]}", "--grid", GRID, "--tile", 8,
            "--saturation", 1e8, "-o", out, *extra]


def test_command_maps_outputs_and_resume(stack, tmp_path, monkeypatch):
    root, manifest, truth = stack
    out = tmp_path / "maps.zarr"
    result = run(*fit_args(root, manifest, out))
    # the dark and the saturated pixel were not fitted: the store is complete, exit 1
    assert result.exit_code == 1, result.output
    assert "pixels were not fitted" in result.output
    assert is_complete(out)
    maps = open_maps(out)
    status = maps["status"]
    assert status[0, 0] == UNDETERMINED and status[1, 1] == MASKED
    ok = status == CONVERGED
    assert ok.sum() >= H * W - 4
    k = NAMES.index(SHAPE)
    z = (maps["params"][k] - truth[k]) / np.where(ok, maps["stderr"][k], 1.0)
    assert np.median(np.abs(z[ok])) < 2.0
    for name in ("params", "stderr", "chi2_reduced"):
        assert np.all(np.isfinite(maps[name]))
    assert np.all(maps["stderr"][:, ~ok] == 0)
    assert not (out / "stack").exists()

    # a rerun of a complete store computes nothing
    again = run(*fit_args(root, manifest, out, "--camera-distance", 100, "--pixel-pitch", 1))
    assert again.exit_code == 1 and "nothing to compute" in again.output
    assert "spans" in again.output and "distant-camera approximation" in again.output

    # an interrupted run resumes with the missing tiles only, to the same bits
    import veil.maps.run as mr

    part = tmp_path / "part.zarr"
    calls = []
    real = mr.solve_tile

    def flaky(block, tables, store, iy, ix, *rest):
        calls.append((iy, ix))
        if len(calls) > 3:
            raise KeyboardInterrupt
        return real(block, tables, store, iy, ix, *rest)

    monkeypatch.setattr(mr, "solve_tile", flaky)
    with pytest.raises(KeyboardInterrupt):
        fit_maps(root / "photos", manifest, MEDIUM, part, fixed=FIX, grid=[GRID], tile=8,
                 saturation=1e8, workers=1)
    monkeypatch.setattr(mr, "solve_tile", real)
    assert not is_complete(part)
    with pytest.raises(veil.errors.InputError, match="partial"):
        open_maps(part)
    messages = []
    resumed = fit_maps(root / "photos", manifest, MEDIUM, part, fixed=FIX, grid=[GRID],
                       tile=8, saturation=1e8, log=messages.append)
    assert resumed.tiles_reused == 3 and resumed.tiles_computed == resumed.tiles_total - 3
    assert any("resuming" in m and "3 of" in m for m in messages)
    other = open_maps(part)
    for name in ("params", "stderr", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(other[name], maps[name]), name

    # outputs a person can use
    png = tmp_path / "maps.png"
    assert run("maps", "show", out, "-o", png).exit_code == 0
    assert png.stat().st_size > 10_000
    folder = tmp_path / "export"
    shown = run("maps", "export", out, "-o", folder)
    assert shown.exit_code == 0, shown.output
    img = tifffile.imread(folder / f"{SHAPE}.tif")
    assert img.dtype == np.float32
    assert np.allclose(img, np.where(ok, maps["params"][k], 0.0), rtol=1e-6)
    assert (folder / f"{SHAPE}_stderr.exr").stat().st_size > 0
    import OpenEXR
    with OpenEXR.File(str(folder / f"{SHAPE}.exr")) as f:
        exr = f.channels()["Y"].pixels
    assert np.array_equal(exr, img)
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["pixels"] == H * W
    assert 0 < summary["undetermined_fraction"] < 0.05
    assert summary["params"][SHAPE]["p05"] <= summary["params"][SHAPE]["median"]

    # the store is an input: neither command writes into it; a figure needs its suffix
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    chunk = next(p for p in sorted(out.rglob("*")) if p.is_file() and "status" in p.parts)
    for args in (("show", out, "-o", out / "x.png"), ("show", out, "-o", chunk),
                 ("export", out, "-o", out), ("export", out, "-o", out / "sub")):
        refused = run("maps", *args)
        assert refused.exit_code == 2, (args, refused.output)
        assert "inside the maps store" in refused.output
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before
    for name in ("maps.txt", "maps"):
        refused = run("maps", "show", out, "-o", tmp_path / name)
        assert refused.exit_code == 2 and ".png" in refused.output, refused.output
        assert not (tmp_path / name).exists()


def test_a_touched_photo_keeps_the_store_and_a_changed_one_does_not(stack, tmp_path,
                                                                   monkeypatch):
    """The store keys each photo by its content (size and SHA-256), not its modification
    time: a complete store of touched photos is reused (it was refused as "another
    acquisition"); a photo whose content changed is refused; a store written with the old
    key (path, size, modification time) still resumes while those are unchanged."""
    import veil.maps.run as mr

    root, _, _ = stack
    shutil.copytree(root / "photos", tmp_path / "photos")
    manifest = tmp_path / "photos" / "manifest.csv"
    out = tmp_path / "maps.zarr"
    args = fit_args(tmp_path, manifest, out, "--roi", "2,2,8,8")
    seen = []
    real = mr.store_attributes

    def spy(acq, tables, cls, noise, tile, *rest):
        seen.append((acq, tables, noise, tile))
        return real(acq, tables, cls, noise, tile, *rest)

    monkeypatch.setattr(mr, "store_attributes", spy)
    first = run(*args)
    assert first.exit_code == 0, first.output

    def set_key(key):
        group = zarr.open_group(str(out), mode="r+")
        group.attrs["veil_maps"] = dict(group.attrs["veil_maps"], fingerprint=key)

    one = sorted((tmp_path / "photos").glob("*.tif"))[5]
    later = one.stat().st_mtime_ns + 10**10
    os.utime(one, ns=(later, later))  # `touch`: the same bytes, another time
    again = run(*args)
    assert again.exit_code == 0 and "nothing to compute" in again.output, again.output
    from veil.maps.tile import store_fingerprint

    key = zarr.open_group(str(out), mode="r").attrs["veil_maps"]["fingerprint"]
    set_key(store_fingerprint(*seen[0], legacy=True))  # as an earlier veil wrote it
    old = run(*args)
    assert old.exit_code == 0 and "nothing to compute" in old.output, old.output
    set_key(key)
    tifffile.imwrite(one, tifffile.imread(one) * 1.01)  # another content
    changed = run(*args)
    assert changed.exit_code == 2 and "another acquisition" in changed.output, changed.output


def test_pixels_not_fitted_are_flagged_counted_and_exit_1(stack, tmp_path):
    """A pixel saturated in every photo (status 1) and a dark one (status 3) are flagged in
    the status map, counted by status on the command line and in summary.json, and make
    the command exit 1 (docs/errors.md: results written, a fit did not converge); pixels
    outside the mask are status 1 too but not failures; a region without such pixels
    exits 0."""
    root, manifest, _ = stack
    mask = np.ones((H, W), np.uint8)
    mask[:, -2:] = 0
    tifffile.imwrite(tmp_path / "mask.tif", mask)
    out = tmp_path / "masked.zarr"
    result = run(*fit_args(root, manifest, out, "--mask", tmp_path / "mask.tif"))
    assert result.exit_code == 1, result.output
    maps = open_maps(out)
    status = maps["status"]
    assert status[0, 0] == UNDETERMINED and status[1, 1] == MASKED
    assert np.all(status[:, -2:] == MASKED)
    inside = mask.astype(bool)
    failed = (status != CONVERGED) & inside
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outside_mask"] == 2 * H
    assert summary["failed"] == failed.sum() >= 2
    by_code = {int(k.split(":")[0]): n for k, n in summary["failed_by_status"].items()}
    expected = {k: int(np.sum(status[inside] == k)) for k in range(1, 6)}
    assert by_code == {k: n for k, n in expected.items() if n}
    assert by_code[MASKED] == 1 and by_code[UNDETERMINED] >= 1
    text = result.output
    assert f"Error: {failed.sum()} of {inside.sum()} pixels were not fitted" in text
    assert "status 1: no usable photo (saturated or clipped in every photo) - 1 pixels" in text
    assert f"status 3: not determined - {by_code[UNDETERMINED]} pixels" in text
    assert f"outside the mask (status 1, not fitted): {2 * H} pixels" in text
    assert np.all(maps["stderr"][:, failed] == 0)
    for name in ("params", "stderr", "chi2_reduced"):
        assert np.all(np.isfinite(maps[name]))
    # a region of pixels that all converge: exit 0, nothing reported as failed
    good = run(*fit_args(root, manifest, tmp_path / "good.zarr", "--roi", "2,2,6,6"))
    assert good.exit_code == 0, good.output
    assert "not fitted" not in good.output
    assert json.loads((tmp_path / "good.zarr" / "summary.json").read_text())["failed"] == 0


def test_distributed_cluster_equals_local(stack, tmp_path):
    from distributed import LocalCluster

    root, manifest, _ = stack
    local = tmp_path / "local.zarr"
    fit_maps(root / "photos", manifest, MEDIUM, local, fixed=FIX, grid=[GRID], tile=8,
             saturation=1e8)
    remote = tmp_path / "remote.zarr"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        run = fit_maps(root / "photos", manifest, MEDIUM, remote, fixed=FIX, grid=[GRID],
                       tile=8, saturation=1e8, scheduler=cluster.scheduler_address)
    assert run.tiles_computed == run.tiles_total
    a, b = open_maps(local), open_maps(remote)
    for name in ("params", "stderr", "chi2_reduced", "n_points", "status"):
        assert np.array_equal(a[name], b[name]), name


# --------------------------------------------------------------------------------------
# bad input: exit 2, nothing written
# --------------------------------------------------------------------------------------
def test_bad_input_exits_2(stack, tmp_path):
    root, manifest, _ = stack
    out = tmp_path / "bad.zarr"

    def bad(*extra, photos=None, man=None, medium="BTDF2"):
        args = fit_args(root, man or manifest, out, *extra)
        if photos is not None:
            args[2] = photos
        args[args.index("--medium") + 1] = medium
        result = run(*args)
        assert result.exit_code == 2, result.output
        assert not out.exists()
        return result.output

    # photos of different sizes
    odd = tmp_path / "odd"
    shutil.copytree(root / "photos", odd)
    first = sorted(odd.glob("*.tif"))[3]
    tifffile.imwrite(first, np.ones((H + 1, W), np.float32))
    assert "same size" in bad(photos=odd)
    # a manifest row without its photo
    lines = manifest.read_text().splitlines()
    missing = tmp_path / "missing.csv"
    missing.write_text("\n".join(lines + ["nowhere.tif,30,180,40,0"]) + "\n")
    assert "nowhere.tif" in bad(man=missing)
    # a medium result of the wrong kind
    ref = veil.fit_reference(veil.simulate(veil.BRDF2, None, noise=0.01, seed=1))
    ref.to_json(tmp_path / "ref.json")
    assert "medium" in bad(medium=tmp_path / "ref.json")
    # a mask of the wrong size
    mask = tmp_path / "mask.tif"
    tifffile.imwrite(mask, np.ones((H, W + 2), np.uint8))
    assert "mask" in bad("--mask", mask)
    # an unreachable scheduler: a clear error within seconds
    t0 = time.perf_counter()
    text = bad("--scheduler", "tcp://127.0.0.1:9")
    assert time.perf_counter() - t0 < 20 and "scheduler" in text
    # an existing file that is not a store: refused, untouched, no lock file left beside it
    afile = tmp_path / "afile"
    afile.write_text("mine")
    refused = run(*fit_args(root, manifest, afile))
    assert refused.exit_code == 2, refused.output
    assert afile.read_text() == "mine" and not (tmp_path / ".afile.veil-lock").exists()
    # a store of another acquisition given to resume
    other = tmp_path / "other.zarr"
    first = run(*fit_args(root, manifest, other, "--roi", "0,0,4,4"))
    assert first.exit_code == 1, first.output  # holds the dark and the saturated pixel
    before = sorted(p.name for p in other.rglob("*"))
    second = run(*fit_args(root, manifest, other, "--roi", "0,0,4,5"))
    assert second.exit_code == 2 and "another acquisition" in second.output
    assert sorted(p.name for p in other.rglob("*")) == before


def test_an_existing_file_as_output_is_refused_before_any_work(stack, tmp_path, monkeypatch):
    """-o FILE (a store is a folder) is refused with the message of any path that is not a
    store, before the medium is loaded, the photos read or the tables built (it was refused
    only after them)."""
    import veil.cli.maps_cmd as cmd
    import veil.maps.run as mr

    def work(*args, **kwargs):
        raise AssertionError("work done before the output was checked")

    for module, name in ((cmd, "load_medium"), (mr, "load_acquisition"), (mr, "_tables")):
        monkeypatch.setattr(module, name, work)
    root, manifest, _ = stack
    afile = tmp_path / "afile"
    afile.write_text("mine")
    refused = run(*fit_args(root, manifest, afile))
    assert refused.exit_code == 2, refused.output
    assert f"{afile} exists and is not a veil maps store" in refused.output
    with pytest.raises(veil.errors.InputError, match="exists and is not a veil maps store"):
        fit_maps(root / "photos", manifest, MEDIUM, afile, fixed=FIX, grid=[GRID])
    assert afile.read_text() == "mine" and not (tmp_path / ".afile.veil-lock").exists()


def test_any_registered_family_even_without_a_nonlinear_parameter(monkeypatch):
    """The tables and the solver read only the declarations: a plugin family with one
    scale and no nonlinear parameter (no table axis), through a plugin medium."""
    monkeypatch.syspath_prepend(str(Path(__file__).parent / "plugins"))
    import veil_test_models  # registers the two families

    brdf_cls = veil_test_models.LambertianTest
    medium = veil_test_models.FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    configs = configurations(12)
    tables = build_tables(brdf_cls, medium, angles_of(configs))
    assert tables.axes == [] and tables.free_names == brdf_cls.param_names()
    truth = np.array([2.0, 0.5])
    y = tables.values[:, 0][None, :] * truth[:, None]
    y = y * (1 + 0.01 * np.random.default_rng(0).standard_normal(y.shape))
    fits = solve_pixels(tables, y, np.ones_like(y, dtype=bool))
    assert np.all(fits.status == CONVERGED)
    assert np.all(np.abs(fits.params[0] - truth) < 4 * fits.stderr[0])


def test_a_large_relative_noise_leaves_the_scales_unbiased(tmp_path):
    """10 % relative noise on a uniform plate (16 x 16 pixels, 24 photos): the diffuse
    scale's mean over the pixels within 0.6 % of the truth. Weights of the samples' own
    values (sigma = REL * sample) favour the samples the noise pulled low and put it about
    2 % low (2 REL^2: measured -2.0 % here before the second solve); weights of the model's
    values at a first solution do not (docs/maps-noise.md)."""
    v = BRDF.to_vector()
    pm = np.repeat(v[:, None, None], 16, 1).repeat(16, 2).copy()
    manifest = write_stack(tmp_path / "photos", BRDF, MEDIUM, configurations(24), pm,
                           noise=0.1, seed=5)
    out = tmp_path / "maps.zarr"
    fit_maps(tmp_path / "photos", manifest, MEDIUM, out, fixed=FIX, noise=(0.1, 0.0),
             grid={SHAPE: (0.1, 6.0, 24)}, accuracy="fast")
    maps = open_maps(out)
    ok = maps["status"] == CONVERGED
    assert ok.mean() > 0.9  # (measured 240 of 256; the others' shape at an end of the grid)
    ratio = maps["params"][0][ok] / v[0]
    print("mean ratio of the diffuse scale:", ratio.mean(), "over", ok.sum(), "pixels")
    assert abs(ratio.mean() - 1) < 6e-3, ratio.mean()
    assert maps["info"]["noise_of"] == "the model's values at a first solution"
