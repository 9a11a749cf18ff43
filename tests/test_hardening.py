"""Hardening (issue 11): interrupts, transactional outputs, memory, NaN, and the last bad inputs.

The interrupt tests send real signals to real ``veil`` processes, with the default SIGINT
disposition restored in the child (a test runner may start its workers with SIGINT
ignored, which a child would inherit), at several moments: while veil and JAX are being
imported, while the engine compiles or runs, and while an output folder is being written.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import veil
from veil import io as vio
from veil.cli import main
from veil.errors import InputError, UnwritableError

VEIL = shutil.which("veil", path=os.path.dirname(sys.executable)) or "veil"
LEFTOVER = (".tmp", ".veil-partial-", ".veil-replaced-")


def invoke(args, **kw):
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def tree(root: Path) -> dict:
    """{relative path: bytes} of every file under ``root`` (hidden ones included)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def leftovers(*folders: Path) -> list:
    """Temporary files or folders of veil's writers anywhere under ``folders``."""
    found = []
    for folder in folders:
        for p in folder.rglob("*"):
            if p.name.endswith(".tmp") or any(m in p.name for m in LEFTOVER[1:]):
                found.append(str(p))
    return found


@contextlib.contextmanager
def read_only(path: Path):
    """Make a folder unwritable, also for root (chattr +i); undo afterwards."""
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(
                ["chattr", "+i", str(path)], capture_output=True).returncode != 0:
            pytest.skip("running as root without chattr +i: cannot make a folder read-only")
        try:
            yield path
        finally:
            subprocess.run(["chattr", "-i", str(path)], check=True)
    else:
        mode = path.stat().st_mode
        path.chmod(0o555)
        try:
            yield path
        finally:
            path.chmod(mode)


# --------------------------------------------------------------------------------------
# item 2: one atomic writer, transactional folders
# --------------------------------------------------------------------------------------
def test_atomic_writer_keeps_the_mode_of_a_replaced_file_and_gives_a_new_one_the_umask(tmp_path):
    old = tmp_path / "kept.txt"
    old.write_text("old")
    old.chmod(0o640)
    vio.write_bytes_atomic(old, b"new")
    assert old.read_bytes() == b"new" and (old.stat().st_mode & 0o777) == 0o640
    umask = os.umask(0o027)
    try:
        vio.write_text_atomic(tmp_path / "new.txt", "x")
    finally:
        os.umask(umask)
    assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o640
    assert not leftovers(tmp_path)


def test_every_text_writer_is_the_one_atomic_writer(tmp_path, monkeypatch):
    from veil.cli._common import write_atomic
    from veil.data.measurements import atomic_write_text

    calls = []
    monkeypatch.setattr(vio, "write_bytes_atomic", lambda p, d: calls.append((p, d)))
    write_atomic(tmp_path / "a.txt", "é")
    atomic_write_text(tmp_path / "b.txt", "b")
    assert [Path(p).name for p, _ in calls] == ["a.txt", "b.txt"]
    assert calls[0][1] == "é".encode()


def test_atomic_writer_into_a_read_only_folder_says_not_writable(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    with read_only(folder), pytest.raises(UnwritableError, match="not writable"):
        vio.write_bytes_atomic(folder / "x.png", b"x")


def _write(folder: Path, files: dict) -> None:
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        vio.write_text_atomic(folder / name, text)


def test_output_folder_appears_whole_at_the_end(tmp_path):
    out = tmp_path / "out"
    with vio.output_folder(out) as folder:
        _write(folder, {"a.json": "1", "sub/b.png": "2"})
        assert not out.exists() and folder.parent == tmp_path
    assert tree(out) == {"a.json": b"1", "sub/b.png": b"2"}
    assert not leftovers(tmp_path)
    assert (out.stat().st_mode & 0o777) == (0o777 & ~_umask())


def _umask():
    u = os.umask(0)
    os.umask(u)
    return u


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_output_folder_failed_rerun_leaves_the_earlier_result_as_it_was(tmp_path, error):
    out = tmp_path / "out"
    with vio.output_folder(out, owned=["a.json", "b.png", "old.csv"]) as folder:
        _write(folder, {"a.json": "old a", "b.png": "old b", "old.csv": "old"})
    (out / "mine.txt").write_text("the user's own file")
    before = tree(out)
    with pytest.raises(error):
        with vio.output_folder(out, owned=["a.json", "b.png", "old.csv"]) as folder:
            _write(folder, {"a.json": "new a"})
            raise error()
    assert tree(out) == before and not leftovers(tmp_path)
    # a first run that fails leaves nothing at all
    with pytest.raises(error):
        with vio.output_folder(tmp_path / "fresh") as folder:
            _write(folder, {"a.json": "a"})
            raise error()
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_output_folder_rerun_replaces_veils_files_together_and_keeps_the_users(tmp_path):
    out = tmp_path / "out"
    owned = ["a.json", "b.png", "direct.json", "spheres"]
    with vio.output_folder(out, owned=owned) as folder:
        _write(folder, {"a.json": "1", "b.png": "1", "direct.json": "1", "spheres/x.png": "1",
                        "spheres/y.png": "1"})
    (out / "notes.txt").write_text("mine")
    with vio.output_folder(out, owned=owned) as folder:
        _write(folder, {"a.json": "2", "b.png": "2", "spheres/x.png": "2"})
    # no stale mix: direct.json and spheres/y.png of the earlier run are gone
    assert tree(out) == {"a.json": b"2", "b.png": b"2", "spheres/x.png": b"2",
                         "notes.txt": b"mine"}
    assert not leftovers(tmp_path)


def test_output_folder_in_a_read_only_place_says_not_writable(tmp_path):
    parent = tmp_path / "p"
    parent.mkdir()
    (parent / "exists").mkdir()
    with read_only(parent):
        with pytest.raises(UnwritableError, match="not writable"):
            with vio.output_folder(parent / "new"):
                pass
    with read_only(parent / "exists"):
        with pytest.raises(UnwritableError, match="not writable"):
            with vio.output_folder(parent / "exists"):
                pass
    (tmp_path / "file").write_text("")
    with pytest.raises(UnwritableError, match="not a directory"):
        vio.check_output_folder(tmp_path / "file")


def test_read_only_output_folder_is_a_clear_error_in_pipeline_reproduce_and_demo(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    table = tmp_path / "t.csv"
    table.write_text("theta_i,theta_r,value\n10,20,1\n")
    runs = {"reproduce": ["reproduce", "-o", ro, "--quiet"],
            "demo": ["demo", "-o", ro],
            "fit pipeline": ["fit", "pipeline", "--reference-clear", table,
                             "--reference-medium", table, "--target-medium", table,
                             "-o", ro]}
    with read_only(ro):
        for name, args in runs.items():
            r = invoke(args)
            assert r.exit_code == 2, (name, r.output)
            assert "not writable" in r.output and "Errno" not in r.output, (name, r.output)


# --------------------------------------------------------------------------------------
# item 1: interrupts, with real signals on real processes
# --------------------------------------------------------------------------------------
def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(args, cwd, env=None):
    full = dict(os.environ)
    full.update(env or {})
    return subprocess.Popen(args, cwd=cwd, env=full, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, preexec_fn=_default_sigint)


def _pipes(pid) -> int:
    count = 0
    for fd in os.listdir(f"/proc/{pid}/fd"):
        with contextlib.suppress(OSError):
            count += os.readlink(f"/proc/{pid}/fd/{fd}").startswith("pipe:")
    return count


def wait_until_started(proc, timeout=60.0) -> float:
    """Wait until veil's interrupt handling is installed (its wake-up pipe adds two pipe
    descriptors to the stdout and stderr pipes); returns the seconds waited."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        if proc.poll() is not None:
            raise AssertionError(f"veil ended early: {proc.communicate()}")
        with contextlib.suppress(OSError):
            if _pipes(proc.pid) >= 4:
                return time.perf_counter() - t0
        time.sleep(0.02)
    raise AssertionError("veil did not start within the timeout")


def stop(proc, sig, limit=2.0):
    """Send ``sig``; (exit status, seconds to exit, stderr). Fails if the exit is slow."""
    t0 = time.perf_counter()
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise AssertionError(f"veil did not stop within 30 s of signal {sig}")
    took = time.perf_counter() - t0
    err = err.decode()
    assert took < limit, (took, err)
    print(f"signal {int(sig)} -> exit {proc.returncode} in {took:.2f} s: {err.strip()}")
    return proc.returncode, took, err


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "Exception ignored" not in err and "Aborted" not in err
    return lines[0]


@pytest.fixture
def configs_csv(tmp_path):
    rng = np.random.default_rng(0)
    ti, tr = rng.uniform(0, 80, 4000), rng.uniform(0, 80, 4000)
    path = tmp_path / "big.csv"
    path.write_text("theta_i,phi_i,theta_r,phi_r\n" + "".join(
        f"{a:.3f},180,{b:.3f},0\n" for a, b in zip(ti, tr)))
    return path


def test_ctrl_c_while_starting_and_sigterm_while_compiling_stop_veil_eval(tmp_path, configs_csv):
    args = [VEIL, "eval", "--brdf", "BRDF1", "--medium", "BTDF2", "--configs", configs_csv,
            "-o", tmp_path / "out.csv"]
    env = {"VEIL_CACHE_DIR": "off"}  # the engine compiles, however warm the test cache is
    proc = start(args, tmp_path, env)
    time.sleep(0.3)  # importing veil and JAX
    code, _, err = stop(proc, signal.SIGINT)
    assert code == 130 and "nothing was written" in _one_line(err)
    proc = start(args, tmp_path, env)
    wait_until_started(proc)
    time.sleep(0.5)  # compiling or running the engine
    code, _, err = stop(proc, signal.SIGTERM)
    assert code == 143 and "terminated" in _one_line(err) and "nothing was written" in err
    assert sorted(os.listdir(tmp_path)) == ["big.csv"]


def _junk_session(path: Path) -> Path:
    from veil.data.protocol import protocol

    table = protocol()[["theta_i", "phi_i", "theta_r", "phi_r"]].copy()
    table["value"] = 1.0 + 0.1 * np.arange(len(table)) % 7
    table.to_csv(path, index=False)
    return path


def test_ctrl_c_during_fit_pipeline_leaves_the_earlier_results_as_they_were(tmp_path):
    table = _junk_session(tmp_path / "session.csv")
    out = tmp_path / "results"
    out.mkdir()
    for name in ("reference.json", "medium.json", "report.md", "target.png"):
        (out / name).write_text(f"earlier {name}")
    (out / "notes.txt").write_text("the user's own file")
    before = tree(out)
    args = [VEIL, "fit", "pipeline", "--reference-clear", table, "--reference-medium", table,
            "--target-medium", table, "--accuracy", "fast", "-o", out]
    proc = start(args, tmp_path)
    time.sleep(0.3)
    code, _, err = stop(proc, signal.SIGINT)
    assert code == 130 and "nothing was written" in _one_line(err)
    proc = start(args, tmp_path)
    wait_until_started(proc)
    time.sleep(1.0)  # fitting
    code, _, err = stop(proc, signal.SIGINT)
    assert code == 130 and _one_line(err).startswith("veil: interrupted (Ctrl-C)")
    assert tree(out) == before and not leftovers(tmp_path)


def test_sigterm_during_reproduce_leaves_the_earlier_figures_as_they_were(tmp_path):
    out = tmp_path / "figures"
    out.mkdir()
    (out / "report.md").write_text("earlier report")
    proc = start([VEIL, "reproduce", "-o", out, "--size", "16", "--quiet"], tmp_path)
    wait_until_started(proc)
    time.sleep(1.0)
    code, _, err = stop(proc, signal.SIGTERM)
    assert code == 143 and "terminated (SIGTERM)" in _one_line(err)
    assert tree(out) == {"report.md": b"earlier report"} and not leftovers(tmp_path)


WRITER = """
import sys, time
from veil import io
from veil.cli import interrupts
interrupts.install()
with io.output_folder(sys.argv[1], owned=[f"f{k}.txt" for k in range(1000)]) as folder:
    for k in range(1000):
        io.write_text_atomic(folder / f"f{k}.txt", "new " * 10000)
        time.sleep(0.01)
"""


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_while_an_output_folder_is_written(tmp_path, sig, status):
    """The moment that matters most for outputs: half of a folder written. Veil's own
    writer (io.output_folder) under the command line's handlers, in a small script."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "f0.txt").write_text("old")
    script = tmp_path / "writer.py"
    script.write_text(textwrap.dedent(WRITER))
    proc = start([sys.executable, script, out], tmp_path)
    t0 = time.perf_counter()
    while not any(p.name.startswith(".veil-partial-") and len(os.listdir(p)) > 5
                  for p in out.iterdir() if p.is_dir()):
        assert proc.poll() is None and time.perf_counter() - t0 < 60, proc.communicate()
        time.sleep(0.01)
    code, _, err = stop(proc, sig)
    assert code == status
    line = _one_line(err)
    assert "nothing was written" in line and "as the earlier run left it" in line
    assert tree(out) == {"f0.txt": b"old"} and not leftovers(tmp_path)
