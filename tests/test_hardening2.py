"""Hardening, second round (issue 33): a maps store with one writer at a time and damage
detected, full disks, extreme finite values, absurd request sizes, a misfit that points to
the black cloth, wrong kinds of result, late signals; and concurrent writers of folders.

Item 1 (``veil warmup``) is tested in test_cli_commands.py with every other command.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import veil
from support.cli import run
from support.maps import configurations, write_stack
from veil import io as vio
from veil.errors import UnwritableError

H = W = 4
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [str(Path(veil.__file__).parents[1])] + [p for p in [os.environ.get("PYTHONPATH")] if p])}


def python(script: str, *args, **kw) -> subprocess.Popen:
    """A Python child with this checkout's veil, its stdout a pipe."""
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(script), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV, **kw)


# --------------------------------------------------------------------------------------
# small inputs, made once
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    root = tmp_path_factory.mktemp("stack")
    pm = np.repeat(veil.BRDF1.to_vector()[:, None, None], H, 1).repeat(W, 2)
    manifest = write_stack(root / "photos", veil.BRDF1, veil.BTDF2, configurations(8), pm,
                           noise=0.0)
    return root / "photos", manifest


def maps_args(stack, out, *extra):
    photos, manifest = stack
    return ["fit", "maps", photos, "--manifest", manifest, "--medium", "BTDF2", "--fix",
            "eta=1.5", "--grid", "n=0.3:3:6", "--tile", 8, "--accuracy", "fast", "-o", out,
            *extra]


@pytest.fixture(scope="module")
def store(stack, tmp_path_factory):
    out = tmp_path_factory.mktemp("store") / "maps.zarr"
    result = run(*maps_args(stack, out))
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    """A clear-water session of BRDF1 (coarse protocol) and its fit result."""
    root = tmp_path_factory.mktemp("table")
    path = root / "ref.csv"
    veil.save_measurements(veil.simulate(veil.BRDF1, None, fine_step=5, coarse_step=15,
                                         seed=4), path)
    result = run("fit", "reference", path, "-o", root / "ref.json")
    assert result.exit_code == 0, result.output
    return path, root / "ref.json"


# --------------------------------------------------------------------------------------
# item 2: one writer per maps store
# --------------------------------------------------------------------------------------
HOLD = """
    import sys, time
    from veil.maps.store import store_lock
    with store_lock(sys.argv[1]):
        print("locked", flush=True)
        time.sleep(120)
"""


def test_a_second_writer_of_a_store_exits_2_naming_the_holder_and_a_dead_ones_lock_is_taken_over(
        stack, tmp_path):
    out = tmp_path / "maps.zarr"
    holder = python(HOLD, out)
    try:
        assert holder.stdout.readline().strip() == "locked", holder.stderr.read()
        busy = run(*maps_args(stack, out))
        assert busy.exit_code == 2, busy.output
        assert f"{out} is being written by another 'veil fit maps' run" in busy.output
        assert f"process {holder.pid} on " in busy.output
        assert not out.exists()
    finally:
        holder.kill()  # SIGKILL: no chance to release the lock or clear its note
        holder.wait()
    taken = run(*maps_args(stack, out))
    assert taken.exit_code == 0, taken.output
    assert f"took over the lock left by process {holder.pid}" in taken.output
    maps = veil.maps.store.open_maps(out)
    assert np.all(maps["status"] == 0)
    assert (out.parent / f".{out.name}.veil-lock").read_text() == ""  # released


def test_two_fit_maps_runs_into_one_new_store_at_once(stack, tmp_path):
    """The issue's case: two real processes started together. One computes the store, the
    other is refused with status 2 (or, if it came second, finds it complete); the store is
    whole and every pixel converged."""
    out = tmp_path / "maps.zarr"
    args = [sys.executable, "-m", "veil.cli", *map(str, maps_args(stack, out))]
    procs = [subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, env=ENV) for _ in range(2)]
    outs = [p.communicate(timeout=300)[0] for p in procs]
    codes = sorted(p.returncode for p in procs)
    assert codes in ([0, 0], [0, 2]), outs
    if codes == [0, 2]:
        assert any("is being written by another 'veil fit maps' run" in o for o in outs)
    else:
        assert any("nothing to compute" in o for o in outs)
    maps = veil.maps.store.open_maps(out)
    assert np.all(maps["status"] == 0) and np.all(maps["n_points"] == 8)


# --------------------------------------------------------------------------------------
# item 3: damaged stores
# --------------------------------------------------------------------------------------
def _copy(store, tmp_path) -> Path:
    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    return copy


def test_a_store_missing_a_chunk_file_is_damaged_for_every_reader(store, stack, tmp_path):
    copy = _copy(store, tmp_path)
    (copy / "params" / "c" / "0" / "0" / "0").unlink()
    export = run("maps", "export", copy, "-o", tmp_path / "export")
    assert export.exit_code == 2, export.output
    assert "is damaged: array params lacks chunk file(s) c/0/0/0" in export.output
    assert not (tmp_path / "export").exists()
    show = run("maps", "show", copy, "-o", tmp_path / "maps.png")
    assert show.exit_code == 2 and "damaged" in show.output
    assert not (tmp_path / "maps.png").exists()
    rerun = run(*maps_args(stack, copy))  # never "complete; nothing to compute"
    assert rerun.exit_code == 2 and "damaged" in rerun.output, rerun.output


def test_corrupt_array_metadata_and_a_lost_tile_marker_are_damage(store, tmp_path):
    copy = _copy(store, tmp_path)
    (copy / "params" / "zarr.json").write_text('{"zarr_format": 3, "node_type": "ar')
    show = run("maps", "show", copy, "-o", tmp_path / "maps.png")
    assert show.exit_code == 2, show.output
    assert "array params (params/zarr.json) cannot be read" in show.output
    other = tmp_path / "other"
    other.mkdir()
    copy = _copy(store, other)
    (copy / ".veil" / "tiles" / "0_0").unlink()
    export = run("maps", "export", copy, "-o", tmp_path / "export")
    assert export.exit_code == 2, export.output
    assert "marked complete but 1 tile marker(s) are missing (.veil/tiles/0_0)" in export.output


# --------------------------------------------------------------------------------------
# item 7: a failed or interrupted first run leaves no store skeleton
# --------------------------------------------------------------------------------------
def test_a_corrupt_photo_leaves_no_store(stack, tmp_path):
    photos = tmp_path / "photos"
    shutil.copytree(stack[0], photos)
    victim = sorted(photos.glob("*.tif"))[5]
    victim.write_bytes(victim.read_bytes()[:300])
    out = tmp_path / "maps.zarr"
    result = run(*maps_args((photos, photos / "manifest.csv"), out))
    assert result.exit_code == 2, result.output
    assert victim.name in result.output
    assert sorted(os.listdir(tmp_path)) == ["photos"]  # no store, no lock file


def test_interrupted_while_staging_leaves_no_store_and_a_kept_partial_store_is_named(
        stack, tmp_path, monkeypatch):
    import veil.maps.photos as photos
    import veil.maps.run as mr

    real = photos._read_pixels
    seen = []

    def interrupted(*args, **kw):
        seen.append(args[0])
        if len(seen) == 3:
            raise KeyboardInterrupt
        return real(*args, **kw)

    monkeypatch.setattr(photos, "_read_pixels", interrupted)
    out = tmp_path / "maps.zarr"
    kw = dict(fixed={"eta": 1.5}, grid=["n=0.3:3:6"], tile=8, accuracy="fast")
    with pytest.raises(KeyboardInterrupt):
        mr.fit_maps(stack[0], stack[1], veil.BTDF2, out, **kw)
    assert not out.exists()
    # what the command line says when it is interrupted with such a store
    vio.register_partial(tmp_path, mr.RESUME)
    try:
        assert f"is {mr.RESUME}" in vio.abandon() and "nothing was written" not in vio.abandon()
    finally:
        vio.forget_partial(tmp_path)


# --------------------------------------------------------------------------------------
# item 4: a full disk
# --------------------------------------------------------------------------------------
def test_a_failing_write_replaces_none_of_a_commands_files(tmp_path, monkeypatch):
    old = {tmp_path / "a.png": b"old a", tmp_path / "b.npy": b"old b"}
    for path, data in old.items():
        path.write_bytes(data)
    real = os.fsync
    calls = []

    def full(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd)

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(UnwritableError, match=r"cannot write .*b\.npy: No space left on "
                                              r"device \(ENOSPC\)"):
        vio.write_many_atomic({p: b"new" for p in old})
    assert {p: p.read_bytes() for p in old} == old
    assert sorted(os.listdir(tmp_path)) == ["a.png", "b.npy"]


@pytest.fixture
def full_disk(tmp_path):
    """A 256 kB tmpfs filled but for one page (needs root and mount): room for a lock
    file's note or a tiny PNG, not for a table, a result or a store."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(disk)],
            capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs (needs root)")
    try:
        with open(disk / "filler", "wb", buffering=0) as fh:
            try:
                while True:
                    fh.write(b"x" * 4096)
            except OSError:
                pass
        os.truncate(disk / "filler", (disk / "filler").stat().st_size - 4096)
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_full_disk_is_status_2_naming_the_path_with_nothing_left(full_disk, table, stack):
    """The issue's case: each command's write fails with ENOSPC; status 2 names the path,
    nothing is left. With no page free: simulate (two files) and a fit; with one: render
    (its PNG would fit, its .npy not: neither is written) and fit maps (the lock's note fits,
    the store not: removed)."""
    before = sorted(os.listdir(full_disk))
    pad = full_disk / "pad"
    try:
        pad.write_bytes(b"x" * 4096)
    except OSError:
        pass
    sim = run("simulate", "--brdf", "BRDF1", "--medium", "none", "--fine-step", 1, "-o",
              full_disk / "sim.csv", "--black", full_disk / "black.csv")
    assert sim.exit_code == 2, sim.output
    assert "No space left on device" in sim.output and str(full_disk) in sim.output
    fit = run("fit", "reference", table[0], "-o", full_disk / "ref.json")
    assert fit.exit_code == 2, fit.output
    assert f"cannot write {full_disk / 'ref.json'}: No space left on device" in fit.output
    pad.unlink()
    render = run("render", "--brdf", "BRDF1", "--size", 16, "--check", 4, "--quiet",
                 "--linear", full_disk / "s.npy", "-o", full_disk / "s.png")
    assert render.exit_code == 2 and "No space left on device" in render.output, render.output
    maps = run(*maps_args(stack, full_disk / "maps.zarr"))
    assert maps.exit_code == 2, maps.output
    assert f"cannot write {full_disk / 'maps.zarr'}: No space left on device" in maps.output
    assert sorted(os.listdir(full_disk)) == before


# --------------------------------------------------------------------------------------
# item 5: extreme finite values
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("column,factor,expected", [
    ("value", 1e-300, "column 'value': the largest magnitude is"),
    ("value", 1e300, "column 'value': "),
    ("sigma", 1e-200, "column 'sigma': the largest magnitude is")])
def test_extreme_values_are_refused_naming_the_column(table, tmp_path, column, factor,
                                                     expected):
    data = pd.read_csv(table[0])
    data[column] *= factor
    path = tmp_path / "extreme.csv"
    data.to_csv(path, index=False)
    result = run("fit", "reference", path, "-o", tmp_path / "out.json")
    assert result.exit_code == 2, result.output
    assert expected in result.output and "rescale" in result.output
    assert not (tmp_path / "out.json").exists()


@pytest.mark.parametrize("factor", [1e-150, 1e150])
def test_one_channel_out_of_range_is_named(tmp_path, factor):
    """One channel of a table scaled far from the others: the message names the channel
    and says to rescale its rows (rescaling the whole table by one factor cannot help)."""
    from veil.data.simulate import simulate_channels

    table = simulate_channels({c: (veil.BRDF1, None) for c in "rgb"}, noise=0.01, seed=0)
    blue = table["channel"] == "b"
    table.loc[blue, ["value", "sigma"]] *= factor
    path = tmp_path / "rgb.csv"
    table.to_csv(path, index=False)
    result = run("fit", "reference", path, "-o", tmp_path / "out.json")
    assert result.exit_code == 2, result.output
    text = " ".join(result.output.split())
    assert "rgb.csv, column 'value' of channel 'b'" in text
    lines = [int(k) for k in re.findall(r"line (\d+) of", text)]
    assert lines and all(224 <= k <= 334 for k in lines)  # channel b's lines
    assert "rescale the rows of channel 'b'" in text and not (tmp_path / "out.json").exists()


def test_export_of_a_result_with_extreme_parameters_names_them(table, tmp_path):
    result = json.loads(table[1].read_text())
    result["params"]["Pd"] = 2e302
    path = tmp_path / "big.json"
    path.write_text(json.dumps(result))
    out = run("export", path, "--to", "mitsuba", "-o", tmp_path / "m.xml")
    assert out.exit_code == 2, out.output
    said = " ".join(out.output.split())  # the file and the key named
    assert "big.json: key 'params.Pd' = 2e+302" in said and not (tmp_path / "m.xml").exists()


# --------------------------------------------------------------------------------------
# item 6: absurd request sizes
# --------------------------------------------------------------------------------------
def test_an_absurd_protocol_is_refused_up_front_with_its_size(tmp_path):
    from veil.data.protocol import _count, rho_values

    t0 = time.perf_counter()
    result = run("simulate", "--brdf", "BRDF1", "--medium", "BTDF2", "--fine-step", 1e-7,
                 "-o", tmp_path / "x.csv")
    assert time.perf_counter() - t0 < 5
    assert result.exit_code == 2, result.output
    assert "would make 6e+08 configurations" in result.output
    for psi, fine, coarse, window in [(30, 1, 5, 10), (90, 2.5, 13, 0), (60, 0.3, 1, 33)]:
        assert _count(85 - psi / 2, fine, coarse, window) == len(
            rho_values(psi, fine, coarse, window, 85))


# --------------------------------------------------------------------------------------
# item 8: a misfit points to the black cloth
# --------------------------------------------------------------------------------------
def test_a_huge_reduced_chi_square_warns_and_points_to_the_black_cloth(table, tmp_path):
    data = pd.read_csv(table[0])
    data["value"] -= 0.5 * data["value"].median()  # glow-like offset: negative values
    negative = int((data["value"] < 0).sum())
    path = tmp_path / "offset.csv"
    data.to_csv(path, index=False)
    bad = run("fit", "reference", path, "-o", tmp_path / "bad.json")
    assert bad.exit_code in (0, 1), bad.output
    assert "Warning: the reference (clear medium) fit's reduced chi-square is" in bad.output
    assert f"{negative} of {len(data)} values are negative" in bad.output
    assert "--black" in bad.output
    good = run("fit", "reference", table[0], "-o", tmp_path / "good.json")
    assert good.exit_code == 0 and "Warning" not in good.output


# --------------------------------------------------------------------------------------
# item 9: a result of the wrong kind
# --------------------------------------------------------------------------------------
def test_diagnose_names_the_option_and_the_file_of_a_wrong_kind(table, tmp_path):
    """The issue's `veil diagnose target.json --medium target.json` (a step-2 result stands
    in: the reference fit relabelled)."""
    csv, result = table
    doc = json.loads(result.read_text())
    doc["step"] = "target"
    target = tmp_path / "target.json"
    target.write_text(json.dumps(doc))
    out = run("diagnose", target, "--data", csv, "--medium", target)
    assert out.exit_code == 2, out.output
    assert (f"--medium {target}: the file is a torrance-sparrow (brdf) fit result of step "
            f"target; --medium takes the medium's fit result") in out.output


# --------------------------------------------------------------------------------------
# item 10: a signal after every output is in place
# --------------------------------------------------------------------------------------
LATE = """
    import os, signal, sys, time
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a test runner's worker may ignore it
    mark = sys.argv[1]
    class Finalized:  # runs in Python's shutdown, if the process gets there
        def __del__(self, open=open, sleep=time.sleep):
            open(mark, "w").close()
            sleep(5)
    keep = Finalized()
    if sys.argv[3] == "atexit":
        import atexit
        atexit.register(lambda: (open(mark + ".atexit", "w").close(), time.sleep(5)))
    sys.argv = ["veil", "simulate", "--brdf", "BRDF1", "--medium", "none", "--fine-step", "10",
                "-o", sys.argv[2]]
    from veil.cli import main
    main()
"""


def _late(tmp_path, mode, wait_for):
    mark, out = tmp_path / "mark", tmp_path / "out.csv"
    for p in (mark, out, Path(f"{mark}.atexit")):
        p.unlink(missing_ok=True)
    proc = python(LATE, mark, out, mode, cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not wait_for.exists() and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    return proc.returncode, err, mark, out


def test_a_signal_after_the_outputs_are_in_place_is_answered(tmp_path):
    """Python's shutdown (module teardown, the engine's destructors) runs with signal
    handling gone: a Ctrl-C there went unanswered. The veil program never gets there: an
    object finalized in the shutdown is never finalized (and a signal sent if it were must
    be answered), and a SIGINT during the atexit functions, after the output is complete,
    ends it with status 130 and the line naming the output."""
    mark = tmp_path / "mark"
    status, err, mark, out = _late(tmp_path, "plain", mark)
    assert status == 0 and not mark.exists(), (status, err)
    assert out.stat().st_size > 0
    status, err, mark, out = _late(tmp_path, "atexit", Path(f"{mark}.atexit"))
    assert status == 130, err
    assert "veil: interrupted (Ctrl-C); complete: out.csv." in err
    assert not mark.exists() and out.stat().st_size > 0


# --------------------------------------------------------------------------------------
# concurrency: two processes writing one output folder
# --------------------------------------------------------------------------------------
WRITER = """
    import os, sys, time
    from veil.io import output_folder, write_text_atomic
    target, me, go = sys.argv[1], sys.argv[2], sys.argv[3]
    with output_folder(target, owned=[f"f{k:03d}" for k in range(300)]) as folder:
        for k in range(300):
            write_text_atomic(folder / f"f{k:03d}", me)
        print("ready", flush=True)
        while not os.path.exists(go):
            time.sleep(0.001)
"""


@pytest.mark.parametrize("exists", [False, True], ids=["new-folder", "existing-folder"])
def test_two_processes_writing_one_folder_leave_one_whole_result(tmp_path, exists):
    """Every folder command (pipeline, reproduce, demo, diagnose -o, maps export) writes
    through veil.io.output_folder; two at once must leave one run's files, all of them,
    not a mix. (test_cli_commands checks that each of them commits through it.)"""
    target, go = tmp_path / "out", tmp_path / "go"
    if exists:
        target.mkdir()
        (target / "mine.txt").write_text("user's")
    for attempt in range(3):
        procs = [python(WRITER, target, name, go) for name in ("A", "B")]
        for p in procs:
            assert p.stdout.readline().strip() == "ready", p.stderr.read()
        go.touch()
        for p in procs:
            _, err = p.communicate(timeout=60)
            assert p.returncode == 0, err
        contents = {p.read_text() for p in target.glob("f*")}
        assert len(list(target.glob("f*"))) == 300 and len(contents) == 1, contents
        assert not [p for p in target.parent.rglob("*") if "veil-partial" in p.name
                    or "veil-replaced" in p.name or p.name.endswith(".tmp")]
        go.unlink()
    if exists:
        assert (target / "mine.txt").read_text() == "user's"


# --------------------------------------------------------------------------------------
# item 7, as the issue saw it: Ctrl-C while a real `veil fit maps` stages its photos
# --------------------------------------------------------------------------------------
def test_ctrl_c_while_staging_leaves_no_store(tmp_path):
    """48 photos of 160 x 160 pixels take a second or more to stage; the store's zarr.json
    appears when staging starts (after the tables). SIGINT then: status 130, "nothing was
    written", and no store (it said so before, and left a partial store)."""
    from support.maps import write_photos

    configs = configurations(48)
    rng = np.random.default_rng(0)
    manifest = write_photos(tmp_path / "photos", configs,
                            rng.uniform(1, 2, (160 * 160, len(configs))), (160, 160), 0.0)
    out = tmp_path / "maps.zarr"
    # the default SIGINT disposition restored in the child (a test runner may start its
    # workers with SIGINT ignored), without a fork hook in this JAX-threaded process
    launch = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
              "os.execv(sys.executable, [sys.executable, '-m', 'veil.cli', *sys.argv[1:]])")
    args = [sys.executable, "-c", launch, *map(str, maps_args(
        (tmp_path / "photos", manifest), out))]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=ENV, cwd=tmp_path)
    deadline = time.monotonic() + 120
    while not (out / "zarr.json").exists():
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    staged = (out / ".veil" / "staged").exists()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert not staged, "staging ended before the signal: make the photos larger"
    assert proc.returncode == 130, err
    assert "veil: interrupted (Ctrl-C); nothing was written." in err
    assert sorted(os.listdir(tmp_path)) == ["photos"]  # no store, no lock file
