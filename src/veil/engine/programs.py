"""Engine programs kept on disk, so that a new process starts without tracing (issue 16).

Tracing and lowering the engine's functions (the integrator written in ``jax.numpy``) takes
1-5 s per function, rule and chunk size in every process, and even a lowered program kept
on disk (:mod:`jax.export`) costs 0.5-1 s to bring back: its module is parsed, lowered again
inside a wrapper and looked up in JAX's compilation cache. A :class:`Program` wraps one
jitted engine function: the first time it is called with arguments of a given shape it
looks for its compiled executable in the program store; found, the executable is loaded
(:mod:`jax.experimental.serialize_executable`) and run as it is, with no tracing, lowering
or compilation; not found, the function is compiled (afresh: :func:`compile_afresh`), the
executable stored, and used the same way. Every process therefore runs the
same executable, whether it built it or loaded it: the numbers are identical.

The store is the folder ``programs`` next to the compilation cache: ``$VEIL_CACHE_DIR/programs``
or ``$XDG_CACHE_HOME/veil/programs`` (``~/.cache/veil/programs``); ``VEIL_CACHE_DIR=off``
disables both. An entry is one file, named by a hash of what the program is (function,
model structures, rule, shapes, devices), holding a header and the serialized executable:

- the header records the environment the entry was made in - veil's version, the source
  code of the engine and of the models involved, JAX, jaxlib, numpy and Python versions, the
  CPU (architecture and feature flags) and the device count - and a checksum of the
  executable. An entry whose environment differs from this process's (another veil or JAX
  version, changed code, another CPU) or that fails any check (truncated, checksum,
  undecodable, shapes other than the call's) is never used: it is built again and
  replaced, with one line saying so. Executables are machine code: like JAX's own
  compilation cache, the store must be the user's own folder (the checksum guards against
  damage, not against someone who can write there);
- writes are atomic (a temporary file renamed into place under :data:`veil.io.COMMIT`, so an
  interrupt never leaves half an entry); a store that cannot be written is read, and
  programs it lacks are built in memory for this process only (one line says so);
- a program is built by one process at a time: processes that need the same missing entry
  (the workers of a Dask cluster on one machine, the test suite's workers) wait on a lock
  file beside it (``<entry>.<environment>.lock``, an advisory ``flock``, released when the
  build ends or its holder exits) with one line saying so, and then read what the first one
  stored, instead of compiling the same program side by side. Without a lock (Windows, a
  store that cannot be written, a file system without ``flock``: one line) or after
  WAIT_LIMIT seconds of waiting, each process builds its own, as before.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import platform
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache, lru_cache
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import __version__, _jax
from .._jax import _notice, jax
from .store_files import directory, put_file

if TYPE_CHECKING:
    from jax.stages import Compiled

#: First line of every entry; a new layout gets a new number.
FORMAT = b"veil.program/2\n"
SUFFIX = ".program"

_MESSAGES: set = set()
_MESSAGES_LOCK = threading.Lock()


def _say_once(key, message: str) -> None:
    with _MESSAGES_LOCK:
        if key in _MESSAGES:
            return
        _MESSAGES.add(key)
    _notice(message)


def _cpu() -> str:
    """The processor: architecture and, on Linux, the model name and feature flags (what an
    executable built for it may use)."""
    described = [platform.machine(), platform.processor()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() in ("flags", "Features", "model name", "vendor_id"):
                    described.append(f"{key.strip()}={' '.join(sorted(value.split()))}")
                elif not line.strip() and len(described) > 2:
                    break  # the first processor is enough
    except OSError:
        pass
    return hashlib.sha256("\n".join(described).encode()).hexdigest()[:16]


@cache
def _source_digest(files: tuple) -> str:
    """A digest of ``files`` ((name, path) pairs): each name and its file's bytes. Names,
    not paths, so that the same code in another checkout or environment finds its
    programs."""
    digest = hashlib.sha256()
    for name, path in files:
        digest.update(name.encode())
        try:
            with open(path, "rb") as fh:
                digest.update(fh.read())
        except OSError:
            digest.update(b"<unreadable>")
    return digest.hexdigest()[:16]


def _veil_sources() -> tuple:
    """The files whose code a program is made of: veil's engine and models, as (name
    relative to the package, path) pairs."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    names = ["_jax.py", "_lazy.py"]
    for folder in ("engine", "models"):
        names += sorted(
            f"{folder}/{f}" for f in os.listdir(os.path.join(root, folder)) if f.endswith(".py")
        )
    return tuple((name, os.path.join(root, *name.split("/"))) for name in names)


def code_digest(classes=()) -> str:
    """A digest of the source code a program is traced from: veil's engine and models, and
    the modules of ``classes`` (model families outside veil, e.g. plugins, by module
    name)."""
    files = list(_veil_sources())
    paths = {path for _, path in files}
    for cls in classes:
        name = getattr(cls, "__module__", "")
        module = sys.modules.get(name, None)
        path = getattr(module, "__file__", None)
        if path and os.path.abspath(path) not in paths:
            paths.add(os.path.abspath(path))
            files.append((name, os.path.abspath(path)))
    return _source_digest(tuple(files))


@lru_cache(maxsize=1)
def _environment_base() -> dict:
    import jaxlib

    return {
        "veil": __version__,
        "jax": jax.__version__,
        "jaxlib": getattr(jaxlib, "__version__", "?"),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "cpu": _cpu(),
        "platform": jax.default_backend(),
        "devices": len(jax.devices()),
    }


def environment(classes=()) -> dict:
    """What an entry must have been made with to be used in this process."""
    return {**_environment_base(), "code": code_digest(classes)}


def structure_name(structure: tuple) -> str:
    """A model structure (class and options, ``Model.structure()``) as text for an identity."""
    cls, options = structure[0], structure[1:]
    return " ".join([f"{cls.__module__}.{cls.__qualname__}"] + [repr(o) for o in options])


def _signature(args) -> tuple:
    return tuple((tuple(np.shape(a)), str(getattr(a, "dtype", np.asarray(a).dtype))) for a in args)


def _path(identity: str) -> str | None:
    folder = directory()
    if folder is None:
        return None
    return os.path.join(folder, hashlib.sha256(identity.encode()).hexdigest()[:40] + SUFFIX)


def read(identity: str, env: dict, signature: tuple) -> Compiled | None:
    """The stored program for ``identity``, loaded and ready to run (a
    ``jax.stages.Compiled``), or None when there is none or it cannot be trusted (then one
    line says why and that it is built again)."""
    path = _path(identity)
    if path is None:
        return None
    try:
        with open(path, "rb") as fh:
            blob = fh.read()
    except (FileNotFoundError, NotADirectoryError):  # nothing stored
        return None
    except OSError as exc:
        _say_once(
            ("unreadable", path),
            f"cannot read the stored engine program {path} "
            f"({type(exc).__name__}: {exc}); building it again",
        )
        return None

    def damaged(why):
        _say_once(
            ("damaged", path),
            f"the stored engine program {path} is damaged ({why}); building it again",
        )
        return None

    if not blob.startswith(FORMAT):
        if blob.startswith(b"veil.program/"):
            layout = blob[len(b"veil.program/") :].split(b"\n", 1)[0].decode("ascii", "replace")
            _say_once(
                ("layout", layout),
                f"stored engine programs in {os.path.dirname(path)} "
                f"were made by another veil (store layout {layout}, this veil's "
                f"{FORMAT.decode().strip().rsplit('/', 1)[1]}); building them again",
            )
            return None
        return damaged("not a veil program file")
    head, newline, payload = blob[len(FORMAT) :].partition(b"\n")
    try:
        header = json.loads(head.decode("utf-8"))
        stored_env, stored_identity = header["environment"], header["identity"]
        checksum, size = header["sha256"], header["size"]
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return damaged("unreadable header")
    if not newline or len(payload) != size or hashlib.sha256(payload).hexdigest() != checksum:
        return damaged("truncated or altered: its checksum does not match")
    if stored_identity != identity:
        return damaged("it holds another program")
    if stored_env != env:
        changed = sorted(k for k in set(env) | set(stored_env) if env.get(k) != stored_env.get(k))
        what = ", ".join(f"{k} {stored_env.get(k)} -> {env.get(k)}" for k in changed)
        _say_once(
            ("stale", tuple(changed)),
            f"stored engine programs in {os.path.dirname(path)} "
            f"were made by another veil, JAX, code or CPU ({what}); building them again",
        )
        return None
    try:
        from jax.experimental import serialize_executable

        executable, in_tree, out_tree, device_ids = pickle.loads(payload)
        by_id = {d.id: d for d in jax.devices()}
        compiled = serialize_executable.deserialize_and_load(
            executable, in_tree, out_tree, execution_devices=[by_id[i] for i in device_ids]
        )
    except Exception as exc:
        return damaged(f"{type(exc).__name__}: {exc}")
    if _compiled_signature(compiled) != signature:
        return damaged("its inputs are not the call's")
    return compiled


def _compiled_signature(compiled) -> tuple:
    args = jax.tree_util.tree_leaves(compiled.args_info[0])
    return tuple((tuple(a.shape), str(a.dtype)) for a in args)


def _devices_of(args) -> list:
    """The devices a program runs on: the mesh of its split arguments (one device else)."""
    for a in args:
        mesh = getattr(getattr(a, "sharding", None), "mesh", None)
        if mesh is not None:
            return list(mesh.devices.flat)
    return jax.devices()[:1]


#: A compile option at its default value that gives the store's compilations their own key
#: in JAX's compilation cache (so they never find an entry made elsewhere).
_OWN_KEY = {"xla_embed_ir_in_executable": False}
#: XLA's options for the Jacobian programs: its older loop emitters compile them in about two
#: thirds of the time at the same run time (the values programs run slower with them;
#: docs/performance-compile.md).
JACOBIAN_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def compile_afresh(
    fn, args, label: str = "engine program", identity: str = "", options: dict | None = None
):
    """``fn`` (jitted) compiled for ``args``, never through JAX's compilation cache: an
    executable JAX loaded from its cache cannot be serialized again (on jaxlib 0.10.2 the
    copy fails in the next process, "Function ... not found"), so the engine's executables
    live in the program store and none in JAX's cache (nothing is written there, and the
    compile key is the store's own). The compile display (:mod:`.compiling`) is told when
    the compilation starts, with a rough estimate of its time, and when it ends. ``options``
    are XLA compile options for this program only (:data:`JACOBIAN_OPTIONS`)."""
    from jax._src import config as jax_config

    from . import compiling

    sizes = [np.shape(a)[0] for a in args if np.ndim(a) == 2]  # configurations (M, 3)
    if sizes:
        label = f"{label}, {max(sizes)} configurations"
    with jax_config.persistent_cache_min_compile_time_secs(float("inf")):  # this thread only
        lowered = fn.lower(*args)
        with compiling.announced(label, identity or label, lowered):
            return lowered.compile({**_OWN_KEY, **(options or {})})


def serialize(compiled, devices) -> bytes | None:
    """A compiled program as bytes for the store (None if this backend cannot)."""
    from jax.experimental import serialize_executable

    try:
        executable, in_tree, out_tree = serialize_executable.serialize(compiled)
    except (ValueError, NotImplementedError):
        return None
    return pickle.dumps(
        (executable, in_tree, out_tree, [d.id for d in devices]), protocol=pickle.HIGHEST_PROTOCOL
    )


def write(identity: str, env: dict, payload: bytes) -> bool:
    """Store a serialized program atomically; False (and one line, once) when the store
    cannot be written."""
    path = _path(identity)
    if path is None:
        return False
    header = json.dumps(
        {
            "identity": identity,
            "environment": env,
            "size": len(payload),
            "sha256": hashlib.sha256(payload).hexdigest(),
        },
        sort_keys=True,
    )
    folder = os.path.dirname(path)
    try:
        put_file(path, FORMAT + header.encode("utf-8") + b"\n" + bytes(payload))
        return True
    except OSError as exc:
        if _jax.CACHE_UNWRITABLE:  # the cache directory's line has said it
            return False
        _say_once(
            ("unwritable", folder),
            f"cannot store engine programs in {folder} "
            f"({type(exc).__name__}: {exc}); using what it holds and tracing the rest "
            f"in every process",
        )
        return False


#: How long a process waits for another one building the same program before it builds
#: its own (seconds; a compilation takes seconds to minutes).
WAIT_LIMIT = 900.0
_POLL = 0.1


def _lock_path(identity: str, env: dict) -> str | None:
    """The lock file of an entry, per environment (two environments sharing a store build
    their own entries and never wait for each other)."""
    path = _path(identity)
    if path is None:
        return None
    digest = hashlib.sha256(json.dumps(env, sort_keys=True).encode()).hexdigest()[:12]
    return f"{path}.{digest}.lock"


@contextmanager
def building(identity: str, env: dict) -> Iterator[bool]:
    """Hold the store's lock for ``identity`` while a missing entry is built, so that one
    process builds it and the others wait, then read it. Yields True if this process
    had to wait for another one (then, if the entry is still missing, the other could not
    store it, and this one builds without the lock). No lock (yields False) where there is
    no store, the lock file cannot be made, the file system has no ``flock`` (one line says
    so) or the platform has no ``fcntl``; after WAIT_LIMIT seconds of waiting (one line)."""
    path = _lock_path(identity, env)
    fcntl: ModuleType | None
    try:
        import fcntl
    except ImportError:  # not POSIX: no cross-process lock, each process builds its own
        fcntl = None
    fd = None
    if path is not None and fcntl is not None:
        try:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError:  # unwritable store: write() says so once
            fd = None
    locked = waited = False
    try:
        if fd is not None and path is not None:  # (fd is only opened at a path)
            locked, waited = _acquire(fcntl, fd, path)
        yield waited
    finally:
        if fd is not None:
            if locked and fcntl is not None:  # (locked only with fcntl)
                # unlock explicitly: a child forked meanwhile shares the open file and would
                # keep an unreleased lock until it exits
                fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def _acquire(fcntl, fd: int, path: str) -> tuple:
    """(locked, waited): the exclusive lock on ``fd``, polling while another process holds
    it (one line on the command line), up to WAIT_LIMIT seconds."""
    import errno

    deadline = None
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True, deadline is not None
        except BlockingIOError:
            pass
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                pass
            else:  # ENOLCK, ENOSYS...: a file system without flock
                _say_once(
                    ("no-flock", os.path.dirname(path)),
                    f"the program store "
                    f"{os.path.dirname(path)} cannot lock files ({exc.strerror}); "
                    f"processes that need the same program build it side by side",
                )
                return False, False
        if deadline is None:
            deadline = time.monotonic() + WAIT_LIMIT
            if _jax._started_as_command_line():  # a Python caller is not warned about a wait
                sys.stderr.write(
                    f"veil: waiting for another process that is building the "
                    f"same engine program ({os.path.basename(path)}); it is read "
                    f"from the store when done\n"
                )
        elif time.monotonic() > deadline:
            _notice(
                f"waited {WAIT_LIMIT:.0f} s for another process building the same engine "
                f"program; building it here too"
            )
            return False, True
        time.sleep(_POLL)


class Program:
    """A jitted engine function ``fn`` whose lowered form, per argument shape, is kept in
    the program store. ``identity`` names what the function computes (its name, the model
    structures, rule and devices it was made for); ``classes`` are the model families it
    traces, whose source code the entries are keyed on; ``label`` says what it is to people
    (the compile display, :mod:`veil.engine.compiling`). Called like ``fn``; thread-safe
    (background compilations, :meth:`veil.engine.forward.Forward.prepare`)."""

    def __init__(
        self, fn, identity: str, classes=(), label: str | None = None, options: dict | None = None
    ):
        self.fn = fn
        self.options = dict(options or {})
        if self.options:  # compiled otherwise, so stored apart
            identity = f"{identity} | options {sorted(self.options.items())}"
        self.identity = identity
        self.label = label or identity.split(" | ")[0]
        self.classes = tuple(classes)
        self._ready: dict = {}
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"Program({self.identity})"

    def callable_for(self, *args) -> Callable[..., Any]:
        """The function this program runs for ``args`` (loading or building it first)."""
        signature = _signature(args)
        ready = self._ready.get(signature)
        if ready is None:
            with self._lock:
                ready = self._ready.get(signature)
                if ready is None:
                    ready = self._ready[signature] = self._build(signature, args)
        return ready

    def __call__(self, *args):
        return self.callable_for(*args)(*args)

    def _build(self, signature, args):
        if directory() is None:  # nothing kept: compiled for this process, still announced
            return compile_afresh(self.fn, args, self.label, self.identity, self.options)
        identity = f"{self.identity} | inputs {signature}"
        env = environment(self.classes)
        compiled = self._read(identity, env, signature)
        if compiled is not None:
            return compiled
        with building(identity, env) as waited:
            compiled = self._read(identity, env, signature)  # another process may have built it
            if compiled is None and not waited:
                compiled = self._compile_and_store(identity, env, args)
        if compiled is None:  # the process waited for stored nothing: no queue behind it
            compiled = self._compile_and_store(identity, env, args)
        return compiled

    def _read(self, identity, env, signature):
        """:func:`read`, each program read logged with its seconds (``VEIL_COMPILE_LOG``)."""
        from .compiling import log_load

        started = time.perf_counter()
        compiled = read(identity, env, signature)
        if compiled is not None:
            log_load(self.label, time.perf_counter() - started)
        return compiled

    def _compile_and_store(self, identity, env, args):
        compiled = compile_afresh(self.fn, args, self.label, identity, self.options)
        payload = serialize(compiled, _devices_of(args))
        if payload is not None:
            write(identity, env, payload)
        return compiled


__all__ = [
    "Program",
    "building",
    "directory",
    "environment",
    "code_digest",
    "read",
    "write",
    "serialize",
    "structure_name",
    "FORMAT",
    "JACOBIAN_OPTIONS",
]
