"""JAX set-up shared by every module.

- float64 everywhere (docs/model.md demands 1e-3 accuracy on integrands that span eight decades,
  which float32 cannot carry);
- one CPU device per core, so that the integrator can spread configurations over all cores
  (XLA runs one computation per CPU device on one core). Set VEIL_CPU_DEVICES=1, or your own
  XLA_FLAGS device count before importing veil, to opt out;
- a persistent compilation cache (docs/performance.md "Compilation"): compiling the engine
  and its Jacobian takes seconds, a cached executable loads in milliseconds, so only the
  first process on a machine pays. Kept in ``$VEIL_CACHE_DIR`` or
  ``$XDG_CACHE_HOME/veil/jax`` (``~/.cache/veil/jax``), at most 1 GiB, least recently used
  entries evicted. ``VEIL_CACHE_DIR=off`` (or empty, 0, no, false, none) disables it. A
  directory that cannot be written is read if it holds entries (through a temporary view,
  :func:`_read_only_view`; new compilations are not kept) and otherwise not used, either
  with one line saying so. A cache directory configured for JAX itself
  (``JAX_COMPILATION_CACHE_DIR``) is left alone. It applies to every JAX compilation in
  the process that takes at least 0.5 s; entries are written while holding the lock the
  command line's interrupt handler takes, so an interrupt never leaves half of one.
"""

import os
import sys
from typing import Any


def _started_as_command_line() -> bool:
    """Whether this process is the ``veil`` console script (its main file is named veil)."""
    main_file = getattr(sys.modules.get("__main__"), "__file__", None) or ""
    name = os.path.basename(main_file).lower()
    return name in ("veil", "veil.exe", "veil-script.py")


def _guard_start_up() -> None:
    """Ctrl-C or SIGTERM while the command line imports veil and JAX (2-3 s; nothing has
    been written yet): exit at once with status 130 or 143 and one line, instead of a
    traceback, or a KeyboardInterrupt lost in a garbage-collection callback. The command
    line's :mod:`veil.cli.interrupts` replaces these handlers when it starts. (Before this
    runs, in the first few hundredths of a second of Python's own start-up, Ctrl-C is
    still Python's KeyboardInterrupt.)"""
    try:  # the C module, loaded with Python itself (``signal`` imports enum: 20 ms)
        # typeshed has no stub of the C module (signal's API)
        import _signal as signal  # type: ignore[import-not-found]
    except ImportError:
        import signal

    what = {signal.SIGINT: "interrupted (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)"}

    def stop(signum, frame):
        os.write(2, f"veil: {what[signum]} while starting; nothing was written.\n".encode())
        os._exit(128 + signum)

    for s in what:
        if signal.getsignal(s) != signal.SIG_IGN:
            signal.signal(s, stop)


# first, before anything slow is imported (os, sys and _signal come with Python itself)
if _started_as_command_line() and "veil.cli.interrupts" not in sys.modules:
    _guard_start_up()

import tempfile  # noqa: E402
import warnings  # noqa: E402

if "jax" not in sys.modules:
    # XLA's own log: its "Very slow compile? ... file a bug" alarm is noise to a user; what
    # compiles, and for how long, the compile display says (veil.engine.compiling)
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    _flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in _flags:
        _n = int(os.environ.get("VEIL_CPU_DEVICES", "0") or 0) or min(os.cpu_count() or 1, 8)
        if _n > 1:
            _count = f" --xla_force_host_platform_device_count={_n}"
            os.environ["XLA_FLAGS"] = (_flags + _count).strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

CACHE_OFF = ("", "0", "off", "no", "false", "none")


def cache_directory() -> str | None:
    """The persistent compilation cache veil uses, or None when it is disabled."""
    # JAX's Config declares its options at run time, unknown to its type information
    configured = jax.config.jax_compilation_cache_dir  # type: ignore[attr-defined]
    if configured:
        return configured
    setting = os.environ.get("VEIL_CACHE_DIR")
    if setting is not None:
        return None if setting.strip().lower() in CACHE_OFF else os.path.expanduser(setting)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "veil", "jax")


def _writable(path: str) -> str | None:
    """Why ``path`` cannot hold the cache (None when it can): created if missing, probed
    with a temporary file (JAX also writes lock and access-time files to read an entry)."""
    try:
        os.makedirs(path, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".veil-probe-")
        os.close(fd)
        os.remove(probe)
    except OSError as exc:
        return f"{type(exc).__name__}: {exc}"
    return None


def _notice(message: str) -> None:
    """One line on stderr for the command line; a RuntimeWarning for a Python caller."""
    if _started_as_command_line():
        sys.stderr.write(f"veil: {message}\n")
    else:
        warnings.warn(f"veil: {message}", RuntimeWarning, stacklevel=3)


def _read_only_view(path: str) -> tuple[str, int] | None:
    """A temporary, writable cache directory that reads the entries of the read-only cache
    ``path``: a symbolic link to each entry and a copy of its small access-time file (JAX
    takes a lock file and rewrites access times to read an entry, which a read-only
    directory refuses). Returns (folder, entries), or None when ``path`` has no entry or
    the view cannot be made. New compilations go to the view and are lost at exit; the view
    is removed at exit and, on an interrupt, by the command line's handler."""
    import atexit
    import shutil
    import time

    from .io import register_temporary

    try:
        entries = sorted(e for e in os.listdir(path) if e.endswith("-cache"))
    except OSError:
        return None
    if not entries:
        return None
    try:
        view = tempfile.mkdtemp(prefix="veil-jax-cache-")
    except OSError:
        return None
    register_temporary(view)
    atexit.register(shutil.rmtree, view, True)
    now = time.time_ns().to_bytes(8, "little")
    try:
        for entry in entries:
            os.symlink(os.path.join(path, entry), os.path.join(view, entry))
            key = entry[: -len("-cache")]
            try:
                with open(os.path.join(path, f"{key}-atime"), "rb") as fh:
                    stamp = fh.read(8)
            except OSError:
                stamp = now
            with open(os.path.join(view, f"{key}-atime"), "wb") as fh:
                fh.write(stamp if len(stamp) == 8 else now)
    except OSError:
        shutil.rmtree(view, ignore_errors=True)
        return None
    return view, len(entries)


def _guard_cache_writes() -> None:
    """Make JAX's writes of cache entries hold :data:`veil.io.COMMIT`, the lock the command
    line's interrupt handler takes before it ends the process: an interrupt then never
    leaves a half-written entry (JAX writes entries in place, and a truncated one would be
    read, rejected with a warning and never replaced). Skipped if JAX's cache class is not
    the one this was written for."""
    try:
        from jax._src import lru_cache
    except ImportError:
        return
    put = getattr(getattr(lru_cache, "LRUCache", None), "put", None)
    if put is None or getattr(put, "_veil_guarded", False):
        return
    from .io import COMMIT

    def guarded_put(self, key, value):
        with COMMIT:
            return put(self, key, value)

    # a patch of JAX's private class, by design: typed as such (Any), not as its method
    patched: Any = guarded_put
    patched._veil_guarded = True
    cache_class: Any = lru_cache.LRUCache
    cache_class.put = patched


#: Set when the cache directory was found unwritable (and a line said so): the program store
#: next to it (veil.engine.programs) then says nothing more about it.
CACHE_UNWRITABLE = False


def _enable_cache() -> None:
    global CACHE_UNWRITABLE
    if jax.config.jax_compilation_cache_dir:  # type: ignore[attr-defined]  # (cache_directory)
        return  # the user configured JAX's cache: theirs to manage
    path = cache_directory()
    if path is None:
        return
    path = os.path.abspath(path)
    problem = _writable(path)
    if problem is not None:
        CACHE_UNWRITABLE = True
        view = _read_only_view(path)
        if view is None:
            _notice(
                f"the compilation cache directory {path} is not writable ({problem}); "
                f"running without a persistent cache, so every process compiles the "
                f"engine again. Set VEIL_CACHE_DIR to a writable directory, or "
                f"VEIL_CACHE_DIR=off to silence this."
            )
            return
        path, count = view
        _notice(
            f"the compilation cache directory {cache_directory()} is read-only: reading "
            f"its {count} entries, not keeping new ones"
        )
    _guard_cache_writes()
    if "JAX_PERSISTENT_CACHE_ENABLE_XLA_CACHES" not in os.environ:
        # JAX otherwise adds the GPU autotuning cache's folder, inside the cache directory,
        # to the compile options it hashes into every key: a cache read through another
        # path (a read-only one's view, a moved one) would never hit. veil runs on the CPU,
        # where that autotuning cache does nothing.
        jax.config.update("jax_persistent_cache_enable_xla_caches", "none")
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ:
        jax.config.update("jax_compilation_cache_max_size", 1 << 30)


_enable_cache()

__all__ = ["jax", "jnp", "cache_directory"]
