"""The program store (veil.engine.programs, issue 16): engine programs kept on disk are used
only when they can be trusted; a damaged, foreign or stale entry is built again with one line
saying so, an unwritable store keeps working, and the numbers never change."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from veil.engine import forward, programs
from veil.engine.quadrature import RULES


def make_engine_call():
    """An engine program (term matrices, 'fast', 8 in-plane configurations padded to the
    64 of the smallest program, spread over the devices) and its inputs. The store does the
    same for every pair; the test-only families of tests/plugins compile in about a second,
    where the paper's pair took 3 s for each of the 26 builds in empty stores here."""
    from veil_test_models import FisherTest, LambertianTest

    b, m = LambertianTest(rho=0.8), FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    fw = forward.Forward(b, m, np.linspace(10, 70, 8), np.linspace(5, 60, 8), 180.0, 0.0,
                         RULES["fast"])
    program = forward._terms_fn(fw._kb, fw._km, fw.rule, fw.half, fw._mesh)
    args = (*fw._vectors(b.to_vector(), m.to_vector()), fw._wi, fw._wr)
    return program, args


@pytest.fixture(scope="module")
def engine_call():
    return make_engine_call()


def fresh(program):
    """The same program as a new process sees it (nothing built or loaded yet)."""
    return programs.Program(program.fn, program.identity, program.classes)


def run(program, args, expect=None):
    """Values of a fresh copy of ``program``; the veil warnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        values = np.asarray(fresh(program)(*args))
    said = [str(w.message) for w in caught if str(w.message).startswith("veil:")]
    if expect is None:
        assert said == []
    else:
        assert len(said) == 1 and expect in said[0], said
    return values


def entries(folder):
    return sorted(p for p in os.listdir(folder) if p.endswith(programs.SUFFIX))


def test_stored_program_is_used_and_gives_the_same_numbers(tmp_path, monkeypatch, engine_call):
    program, args = engine_call
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path / "store"))
    log = tmp_path / "log.jsonl"
    monkeypatch.setenv("VEIL_COMPILE_LOG", str(log))
    first = run(program, args)                       # built and stored
    store = tmp_path / "store" / "programs"
    [name] = entries(store)
    built = os.path.getmtime(store / name)
    again = run(program, args)                       # read back
    assert os.path.getmtime(store / name) == built
    np.testing.assert_array_equal(first, again)
    # the log has the compilation, then the read (benchmarks/bench_auto.py sums the reads)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    assert [e["event"] for e in logged] == ["compile", "load"]
    assert logged[1]["label"] == fresh(program).label and 0 < logged[1]["seconds"] < 60
    monkeypatch.setenv("VEIL_CACHE_DIR", "off")      # no store: the plain jitted function
    np.testing.assert_array_equal(first, run(program, args))
    # compiled for this process, nothing read
    assert [json.loads(line)["event"] for line in log.read_text().splitlines()][2:] == ["compile"]


def _rewrite(path, edit):
    blob = path.read_bytes()
    head, _, payload = blob[len(programs.FORMAT):].partition(b"\n")
    header = json.loads(head)
    header, payload = edit(header, payload)
    path.write_bytes(programs.FORMAT + json.dumps(header).encode() + b"\n" + payload)


@pytest.mark.parametrize("damage, message", [
    (lambda h, p: (h, p[:-100]), "is damaged (truncated or altered"),
    (lambda h, p: (h, p[:50] + bytes([p[50] ^ 1]) + p[51:]), "is damaged (truncated or altered"),
    (lambda h, p: ({**h, "sha256": __import__("hashlib").sha256(b"x" + p[1:]).hexdigest()},
                   b"x" + p[1:]), "is damaged"),
    (lambda h, p: ({**h, "identity": "something else"}, p), "holds another program"),
    (lambda h, p: ({**h, "environment": {**h["environment"], "cpu": "0123456789abcdef"}}, p),
     "made by another veil, JAX, code or CPU (cpu 0123456789abcdef ->"),
    (lambda h, p: ({**h, "environment": {**h["environment"], "jax": "0.0.1"}}, p),
     "(jax 0.0.1 ->"),
    (lambda h, p: ({**h, "environment": {**h["environment"], "code": "0" * 16}}, p),
     "(code 0000000000000000 ->"),
], ids=["truncated", "bit flipped", "undecodable", "another program", "other CPU",
        "other JAX", "changed code"])
def test_untrusted_entry_is_rebuilt_with_one_line(tmp_path, monkeypatch, engine_call, damage,
                                                  message):
    program, args = engine_call
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(programs, "_MESSAGES", set())
    good = run(program, args)
    [name] = entries(tmp_path / "programs")
    _rewrite(tmp_path / "programs" / name, damage)
    np.testing.assert_array_equal(good, run(program, args, expect=message))
    np.testing.assert_array_equal(good, run(program, args))   # replaced by a good entry


def test_entry_of_another_layout_is_rebuilt_with_one_line(tmp_path, monkeypatch, engine_call):
    program, args = engine_call
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(programs, "_MESSAGES", set())
    good = run(program, args)
    [name] = entries(tmp_path / "programs")
    path = tmp_path / "programs" / name
    path.write_bytes(b"veil.program/1\n" + path.read_bytes()[len(programs.FORMAT):])
    np.testing.assert_array_equal(good, run(program, args, expect="store layout 1, this veil's 2"))
    np.testing.assert_array_equal(good, run(program, args))


def test_garbage_file_is_rebuilt(tmp_path, monkeypatch, engine_call):
    program, args = engine_call
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(programs, "_MESSAGES", set())
    good = run(program, args)
    [name] = entries(tmp_path / "programs")
    (tmp_path / "programs" / name).write_bytes(b"\x00garbage")
    np.testing.assert_array_equal(good, run(program, args, expect="not a veil program file"))


def test_unwritable_store_keeps_working(tmp_path, monkeypatch, engine_call):
    program, args = engine_call
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("VEIL_CACHE_DIR", str(blocker))   # programs/ cannot be made under it
    monkeypatch.setattr(programs, "_MESSAGES", set())
    values = run(program, args, expect="cannot store engine programs")
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    np.testing.assert_array_equal(values, run(program, args))


def test_code_digest_follows_the_code_not_where_it_lives(tmp_path, monkeypatch):
    """The same engine and models in another checkout (another path) give the same digest,
    so their stored programs are found; a changed byte in a model gives another."""
    here = programs.code_digest()
    root = os.path.dirname(os.path.dirname(os.path.abspath(programs.__file__)))
    copy = tmp_path / "elsewhere" / "veil"
    for name, path in programs._veil_sources():
        target = copy / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(open(path, "rb").read())
    assert all(p.startswith(root) for _, p in programs._veil_sources())
    monkeypatch.setattr(programs, "__file__", str(copy / "engine" / "programs.py"))
    assert all(p.startswith(str(copy)) for _, p in programs._veil_sources())
    assert programs.code_digest() == here
    model = copy / "models" / "henyey_greenstein.py"
    model.write_bytes(model.read_bytes() + b"\n")
    programs._source_digest.cache_clear()     # a process reads its code once
    assert programs.code_digest() != here


def _child_env(**extra) -> dict:
    """The environment of a child Python that imports this checkout's veil and this module."""
    here = os.path.dirname(os.path.abspath(__file__))
    paths = [os.path.dirname(os.path.dirname(os.path.dirname(programs.__file__))), here,
             os.path.join(here, "plugins"), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in paths if p), **extra}


_BUILD_SCRIPT = r"""
import hashlib, os, sys, time
import numpy as np
from test_programs import make_engine_call
from veil.engine import programs

compiled = []
original = programs.compile_afresh
def counting(fn, args, *rest):
    compiled.append(1)
    return original(fn, args, *rest)
programs.compile_afresh = counting

program, args = make_engine_call()
barrier, me = sys.argv[1], sys.argv[2]
open(os.path.join(barrier, me), "w").close()
deadline = time.monotonic() + 120
while len(os.listdir(barrier)) < 2:  # both processes reach the call together
    if time.monotonic() > deadline:
        sys.exit("the other process never reached the barrier")
    time.sleep(0.01)
values = np.asarray(program(*args))
print(len(compiled), hashlib.sha256(values.tobytes()).hexdigest())
"""


def test_processes_that_need_the_same_program_build_it_once(tmp_path):
    """Two processes calling the same missing program at the same moment: one compiles, the
    other waits on the entry's lock and reads it (the same numbers, bit for bit)."""

    barrier = tmp_path / "barrier"
    barrier.mkdir()
    log = tmp_path / "log.jsonl"
    env = _child_env(VEIL_CACHE_DIR=str(tmp_path / "cache"), VEIL_COMPILE_LOG=str(log))
    procs = [subprocess.Popen([sys.executable, "-c", _BUILD_SCRIPT, str(barrier), str(i)],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for i in range(2)]
    try:
        outs = [p.communicate(timeout=300) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    counts, digests = zip(*(o[0].split() for o in outs))
    assert sorted(counts) == ["0", "1"], outs
    assert digests[0] == digests[1]
    assert entries(tmp_path / "cache" / "programs") and \
        len(list((tmp_path / "cache" / "programs").glob("*.lock"))) == 1
    # the waiting process's read of what the other stored is logged as a read
    events = sorted(json.loads(line)["event"] for line in log.read_text().splitlines())
    assert events == ["compile", "load"], events


def test_store_without_file_locks_builds_as_before(tmp_path, monkeypatch, engine_call):
    """A file system without flock (NFS without lockd: ENOLCK): one line, the program built
    and stored without the lock, the same numbers."""

    program, args = engine_call
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    expected = run(program, args)                                   # built, with the lock
    for name in entries(tmp_path / "programs"):
        os.unlink(tmp_path / "programs" / name)

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    monkeypatch.setattr(programs, "_MESSAGES", set())
    np.testing.assert_array_equal(run(program, args, expect="cannot lock files"), expected)
    assert entries(tmp_path / "programs")


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # the child only sleeps
def test_lock_is_released_for_a_forked_child(tmp_path, monkeypatch):
    """The lock is released when the build ends, not when every process sharing its open
    file has closed it: a child forked during a build (multiprocessing's default on Linux)
    does not keep it."""

    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    env = {"test": 1}
    with programs.building("an identity", env) as waited:
        assert waited is False
        child = os.fork()
        if child == 0:  # the child holds the open lock file for 30 s
            time.sleep(30)
            os._exit(0)
    try:
        script = ("import time; from veil.engine "
                  "import programs; t = time.monotonic()\nwith programs.building('an "
                  "identity', {'test': 1}) as w: print(w, round(time.monotonic() - t, 1))")

        out = subprocess.run([sys.executable, "-c", script], env=_child_env(),
            capture_output=True, text=True, timeout=25)
        assert out.returncode == 0, out.stderr
        waited, seconds = out.stdout.split()
        assert waited == "False" and float(seconds) < 5
    finally:
        os.kill(child, 9)
        os.waitpid(child, 0)


def test_a_wait_for_another_process_is_bounded(tmp_path, monkeypatch):
    """While another process holds an entry's lock this one waits; after WAIT_LIMIT it says
    so and goes on (``building`` yields True: it waited, and builds without the lock)."""

    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(programs, "WAIT_LIMIT", 1.0)
    env = {"test": 2}
    path = programs._lock_path("an identity", env)
    os.makedirs(os.path.dirname(path))
    holder = subprocess.Popen(
        [sys.executable, "-c", "import fcntl, os, sys, time; fd = os.open(sys.argv[1], "
         "os.O_RDWR | os.O_CREAT); fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); "
         "time.sleep(60)", path], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            start = time.monotonic()
            with programs.building("an identity", env) as waited:
                assert waited is True
            elapsed = time.monotonic() - start
        assert 1.0 <= elapsed < 10.0
        said = [str(w.message) for w in caught if str(w.message).startswith("veil:")]
        assert len(said) == 1 and "waited 1 s for another process" in said[0], said
    finally:
        holder.kill()
        holder.wait()
