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
import re
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
    import veil.cli._common as common
    import veil.data.measurements as measurements

    assert not hasattr(common, "write_atomic") and not hasattr(measurements,
                                                                "atomic_write_text")
    calls = []
    monkeypatch.setattr(vio, "write_bytes_atomic", lambda p, d: calls.append((p, d)))
    vio.write_text_atomic(tmp_path / "a.txt", "é")
    table = veil.simulate(veil.BRDF1, None, psi=(60,), fine_step=10, coarse_step=20)
    measurements.save_measurements(table, tmp_path / "b.csv")
    assert [Path(p).name for p, _ in calls] == ["a.txt", "b.csv"]
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


def test_nested_output_folders_as_veil_demo_writes_them(tmp_path):
    """demo: a folder holding reproduce's folder and the pipeline's files, all one
    transaction; afterwards only the final folder is listed as written."""
    out = tmp_path / "demo"
    with vio.output_folder(out, owned=["paper-figures", "data", "report.md"]) as folder:
        with vio.output_folder(folder / "paper-figures") as figures:
            _write(figures, {"fig.png": "f"})
        _write(folder, {"data/a.csv": "a"})
        with vio.output_folder(folder, owned=["report.md"]) as same:
            _write(same, {"report.md": "r"})
        assert not out.exists()
    assert tree(out) == {"paper-figures/fig.png": b"f", "data/a.csv": b"a", "report.md": b"r"}
    assert str(out) in vio.written() and not leftovers(tmp_path)
    assert not [w for w in vio.written() if ".veil-partial-" in w]


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
# The child gets the default SIGINT disposition back (a test worker may ignore SIGINT, and
# an ignored signal stays ignored across exec) from a small launcher that then execs the
# command: a preexec_fn would run Python in a child forked from a multithreaded (JAX) parent.
LAUNCH = ("import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); "
          "os.execv(sys.argv[1], sys.argv[1:])")


def start(args, cwd, env=None):
    full = dict(os.environ)
    full.update(env or {})
    args = [str(a) for a in args]
    return subprocess.Popen([sys.executable, "-c", LAUNCH, *args], cwd=cwd, env=full,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _caught(pid) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("SigCgt:"):
                return int(line.split()[1], 16)
    return 0


def wait_until_importing(proc, timeout=60.0) -> float:
    """Wait until veil's start-up guard is in place (the process catches SIGTERM, which
    Python alone does not): veil is importing itself and JAX. Returns the seconds waited."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        if proc.poll() is not None:
            raise AssertionError(f"veil ended early: {proc.communicate()}")
        with contextlib.suppress(OSError):
            if _caught(proc.pid) & (1 << (signal.SIGTERM - 1)):
                return time.perf_counter() - t0
        time.sleep(0.005)
    raise AssertionError("veil did not start within the timeout")


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
    """The one line of ``err`` besides the progress lines a fit writes off a terminal
    ("veil pipeline: step 0, ...")."""
    lines = [line for line in err.splitlines()
             if line.strip() and not re.match(r"veil [\w ]+: ", line)]
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
    wait_until_importing(proc)  # about 0.1 s after the start on a quiet machine
    time.sleep(0.2)  # importing veil and JAX
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
    wait_until_importing(proc)
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


def test_interrupt_while_an_output_folder_is_written(tmp_path, sig=signal.SIGINT, status=130):
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


# --------------------------------------------------------------------------------------
# item 5: no NaN or inf leaves veil
# --------------------------------------------------------------------------------------
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

GRAZING = 90.0 - 1e-9
N_CONFIGS = 8  # one shape, so the engine compiles once per code path (in-plane or not)


def _box(lo, hi, *, open_lo=False, open_hi=False, extremes=()):
    """Floats over a parameter's whole interval, with its extreme values tried first."""
    return st.one_of(st.sampled_from(extremes), st.floats(lo, hi, exclude_min=open_lo,
                                                          exclude_max=open_hi)) \
        if extremes else st.floats(lo, hi, exclude_min=open_lo, exclude_max=open_hi)


ONE = 1.0 - 2.0 ** -53  # the largest float below 1
SCALE = _box(0.0, 1e300, extremes=(0.0, 1e-300, 1.0, 1e300))
BRDF_BOX = st.tuples(SCALE, SCALE, _box(0.0, 50.0, open_lo=True, extremes=(1e-300, 1e-3, 50.0)),
                     _box(0.0, 10.0, open_lo=True, extremes=(1e-300, 1.0, 10.0)))
BTDF_BOX = st.tuples(SCALE, SCALE, _box(-1.0, 1.0, open_lo=True, open_hi=True,
                                        extremes=(-ONE, -0.999999999, 0.0, 0.999999999, ONE)),
                     _box(0.0, 10.0, open_lo=True, extremes=(1e-300, 1.0, 10.0)))
POLAR = _box(0.0, GRAZING, extremes=(0.0, 89.9999999, GRAZING))
ANGLES = st.lists(st.tuples(POLAR, POLAR, st.floats(0.0, 360.0)), min_size=N_CONFIGS,
                  max_size=N_CONFIGS)


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(BRDF_BOX, BTDF_BOX, ANGLES, st.sampled_from(["paper", "exit"]))
def test_apparent_is_finite_over_the_whole_parameter_box(brdf, medium, angles, variant):
    """Both paper models over their whole parameter box (scale coefficients up to 1e300),
    angles up to 90 deg - 1e-9, in the plane of incidence and out of it: the value and the
    clear f_r are finite and >= 0; or, when the result is beyond
    float64, an InputError names the scale parameters; or, for a smoothness n so small
    that the facet law underflows, an InputError says so."""
    b = veil.TorranceSparrow(*brdf)
    m = veil.HenyeyGreenstein(*medium, variant=variant)
    ti, tr, dphi = (np.array(a) for a in zip(*angles))
    for phi_r in (0.0 * dphi, dphi):  # in-plane (the integrator's half grids), and not
        try:
            # (the error estimate is the same engine at a finer rule: checked below and in
            # the CLI test, not here, to keep to one compilation per code path)
            value = veil.apparent(b, m, ti, tr, 180.0, phi_r, accuracy="fast")
            clear = veil.reflectance(b, ti, tr, 180.0, phi_r)
        except InputError as exc:
            if "overflows float64" in str(exc):  # names the scale coefficients
                assert "Pd = " in str(exc) and "Ps = " in str(exc), exc
                assert max(brdf[0], brdf[1], medium[0], medium[1]) > 1e100, exc
            else:  # a facet law flatter than float64 holds (n below about 1e-140 / deg)
                assert "facet distribution is too wide" in str(exc) and brdf[2] < 1e-100, exc
            continue
        for a in (value, clear):
            assert np.all(np.isfinite(a)) and np.all(a >= 0), (a, ti, tr, phi_r)


def test_the_grazing_extreme_g_case_of_the_issue_is_finite():
    b, m = veil.BRDF1, veil.HenyeyGreenstein(0.001, 0.13, -0.999999999, 1.3)
    value, error = veil.apparent(b, m, 89.9999999, 89.9999999, return_error=True)
    assert np.isfinite(value) and np.isfinite(error) and value > 0
    # continuous with a less extreme medium at the same angles
    near = veil.apparent(b, veil.HenyeyGreenstein(0.001, 0.13, -0.99999, 1.3), 89.9999999,
                         89.9999999)
    assert value == pytest.approx(near, rel=1e-3)


def test_fresnel_of_a_matched_index_is_zero_up_to_grazing():
    from veil.models import fresnel

    c = np.array([1.0, 0.5, 1e-7, 1e-9, 1e-12, 0.0])
    assert np.all(np.asarray(fresnel.reflectance(c, 1.0)) == 0.0)
    f = np.asarray(fresnel.reflectance(c, 1e-200))  # a vanishing index reflects everything
    assert np.all(np.isfinite(f)) and np.allclose(f, 1.0)


def test_overflow_is_a_clear_input_error_and_json_is_always_json():
    with pytest.raises(InputError, match=r"overflows float64.*Td = 1e\+300, Tt = 1e\+300"):
        veil.apparent(veil.BRDF1, veil.HenyeyGreenstein(1e300, 1e300, 0.9, 1.3), 30, 30)
    r = invoke(["eval", "--brdf", "BRDF1", "--medium", "1e300,1e300,0.9,1.3",
                "--theta-i", "30", "--theta-r", "30"])
    assert r.exit_code == 2 and "overflows float64" in r.output and "Td = 1e+300" in r.output
    assert "inf" not in r.output.replace("float64", "")
    r = invoke(["eval", "--brdf", "BRDF1", "--medium", "0.001,0.13,-0.999999999,1.3",
                "--theta-i", "89.9999999", "--theta-r", "89.9999999", "--json"])
    assert r.exit_code == 0, r.output
    obj = json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert all(np.isfinite(obj[k][0]) for k in ("apparent", "clear", "error"))


# --------------------------------------------------------------------------------------
# items 6 and 7: veil eval --configs, radians warning
# --------------------------------------------------------------------------------------
def test_eval_configs_rejects_disagreeing_angle_forms_as_veil_fit_does(tmp_path):
    bad = tmp_path / "both.csv"
    bad.write_text("theta_i,phi_i,theta_r,phi_r,psi,rho,value\n45,180,50,0,95,-2.5,1\n"
                   "30,180,30,0,10,0,1\n")
    r = invoke(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", bad])
    assert r.exit_code == 2 and "ambiguous angles" in r.output and "line 3" in r.output
    r = invoke(["fit", "reference", bad, "-o", tmp_path / "r.json"])
    assert r.exit_code == 2 and "ambiguous angles" in r.output
    good = tmp_path / "agree.csv"
    good.write_text("theta_i,phi_i,theta_r,phi_r,psi,rho\n45,180,50,0,95,-2.5\n")
    r = invoke(["eval", "--brdf", "BRDF1", "--medium", "none", "--configs", good])
    assert r.exit_code == 0 and r.output.count("\n") == 2


def test_eval_configs_runs_in_chunks_with_progress(monkeypatch):
    from veil.cli import eval_cmd

    monkeypatch.setattr(eval_cmd, "CHUNK", 8)
    rng = np.random.default_rng(1)
    ti, tr = rng.uniform(0, 80, 20), rng.uniform(0, 80, 20)
    pi_, pr = np.full(20, 180.0), np.zeros(20)  # in-plane, 8 a call: compiled by other tests
    calls = []
    value, error = eval_cmd.evaluate_configs(veil.BRDF1, veil.BTDF2, ti, tr, pi_, pr, "fast",
                                             lambda done, total, s: calls.append((done, total)))
    assert calls == [(8, 20), (16, 20), (20, 20)]
    for part in (slice(0, 8), slice(8, 16), slice(16, 20)):
        alone, alone_err = veil.apparent(veil.BRDF1, veil.BTDF2, ti[part], tr[part], 180.0, 0.0,
                                         accuracy="fast", return_error=True)
        np.testing.assert_array_equal(value[part], alone)
        np.testing.assert_array_equal(error[part], alone_err)
    bar = eval_cmd._Progress()
    bar(8, 20, 10.0)  # two more chunks of 10 s: worth a bar
    assert bar.bar is not None
    bar.stop()
    quick = eval_cmd._Progress()
    quick(8, 20, 0.1)
    assert quick.bar is None


def test_radians_warning_is_printed_once_per_table(tmp_path):
    table = tmp_path / "rad.csv"
    table.write_text("theta_i,phi_i,theta_r,phi_r,value\n" + "".join(
        f"{a},3.14159,{b},0,{1 + a * b}\n" for a in (0.2, 0.4, 0.6, 0.8, 1.0)
        for b in (0.1, 0.3, 0.5, 0.7)))
    r = invoke(["fit", "reference", table, "-o", tmp_path / "r.json"])
    assert r.output.count("written in radians?") == 1, r.output


def test_corrupt_tiffs_name_the_photo_and_what_was_expected(tmp_path):
    import tifffile

    from veil.data.ingest import ROI, read_photo

    good = tmp_path / "good.tif"
    tifffile.imwrite(good, np.arange(64 * 64, dtype=np.uint16).reshape(64, 64))
    short = tmp_path / "short.tif"
    short.write_bytes(good.read_bytes()[:-2000])  # the pixel data cut short: mmap too long
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"this is not a TIFF file at all" * 10)
    rois = [("roi", ROI(4, 4, 8, 8))]
    assert read_photo(good, rois).patches
    for path in (short, junk):
        with pytest.raises(InputError) as info:
            read_photo(path, rois)
        text = str(info.value)
        assert text.startswith(str(path)) and "expected a complete TIFF file" in text, text


CACHE_SCRIPT = """
    import numpy as np
    import veil
    from veil._jax import jax, jnp
    events = []
    jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
    jax.jit(lambda x: jnp.sin(x) * 2.0 + 1.0)(np.arange(5.0)).block_until_ready()
    print(events.count("/jax/compilation_cache/cache_hits"), jax.config.jax_compilation_cache_dir)
"""


def _python(script, env):
    full = {k: v for k, v in os.environ.items()
            if k not in ("VEIL_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")}
    full.update(env)
    proc = subprocess.run([sys.executable, "-W", "always", "-c", textwrap.dedent(script)],
                          env=full, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split(), proc.stderr


def test_read_only_cache_directory_is_read_with_one_line_saying_so(tmp_path):
    cache = tmp_path / "cache"
    env = {"VEIL_CACHE_DIR": str(cache), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    (hits, where), _ = _python(CACHE_SCRIPT, env)
    assert hits == "0" and where == str(cache)
    entries = sorted(p.name for p in cache.iterdir())
    with read_only(cache):
        (hits, where), err = _python(CACHE_SCRIPT, env)
        assert int(hits) >= 1 and where != str(cache)  # read through a temporary view
        notes = [line for line in err.splitlines() if "read-only" in line]
        assert len(notes) == 1 and str(cache) in notes[0] and "reading its" in notes[0]
        assert sorted(p.name for p in cache.iterdir()) == entries  # untouched
    assert not os.path.exists(where)  # the view is removed at exit


# --------------------------------------------------------------------------------------
# item 3: memory of veil render
# --------------------------------------------------------------------------------------
def test_render_works_in_bands_of_bounded_memory(monkeypatch):
    import tracemalloc

    from veil.viz import render as r

    whole = r.render("BRDF1", "BTDF3", 50.0, 20.0, 96, samples=8, check=16)
    monkeypatch.setattr(r, "PIXEL_CHUNK", 8192)
    tracemalloc.start()
    try:
        banded = r.render("BRDF1", "BTDF3", 50.0, 20.0, 96, samples=8, check=16)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(banded.image, whole.image)
    assert banded.max_rel_error == whole.max_rel_error and banded.checked == whole.checked
    # 96 x 96 pixels x 64 samples = 590k samples: unbanded, 24 bytes of normals alone each
    print(f"peak traced memory of the banded render: {peak / 1e6:.1f} MB")
    assert peak < 8e6, peak
    # 4096 px with 8 x 8 samples: bounded by the image, not by the 1.07e9 samples
    assert r.memory_estimate(4096, 8) < 2 << 30
    assert r.memory_estimate(4096, 8) - r.memory_estimate(4096, 1) < 200 << 20


def test_render_refuses_what_would_not_fit_in_memory(monkeypatch, tmp_path):
    from veil.viz import render as r

    monkeypatch.setattr(r, "available_memory", lambda: 300 << 20)
    out = tmp_path / "big.png"
    res = invoke(["render", "--brdf", "BRDF1", "--medium", "BTDF3", "--size", "4096",
                  "--samples", "8", "-o", out])
    assert res.exit_code == 2, res.output
    assert "GiB of memory" in res.output and "0.29 GiB available" in res.output
    assert "lower --size" in res.output and not out.exists()
    with pytest.raises(InputError, match="lower size"):
        r.render("BRDF1", None, 45.0, size=4096)
    assert r.available_memory() is None or r.available_memory() > 0
