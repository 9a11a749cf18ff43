"""JAX set-up shared by every module.

- float64 everywhere (MODEL.md demands 1e-3 accuracy on integrands that span eight decades,
  which float32 cannot carry);
- one CPU device per core, so that the integrator can spread configurations over all cores
  (XLA runs one computation per CPU device on one core). Set VEIL_CPU_DEVICES=1, or your own
  XLA_FLAGS device count before importing veil, to opt out;
- a persistent compilation cache (docs/performance.md "Compilation"): compiling the engine
  and its Jacobian takes seconds, a cached executable loads in milliseconds, so only the
  first process on a machine pays. Kept in ``$VEIL_CACHE_DIR`` or
  ``$XDG_CACHE_HOME/veil/jax`` (``~/.cache/veil/jax``), at most 1 GiB, least recently used
  entries evicted. ``VEIL_CACHE_DIR=off`` disables it; a cache directory configured for JAX
  itself (``JAX_COMPILATION_CACHE_DIR``) is left alone. It applies to every JAX compilation
  in the process.
"""

import os
import sys

if "jax" not in sys.modules:
    _flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in _flags:
        _n = int(os.environ.get("VEIL_CPU_DEVICES", "0") or 0) or min(os.cpu_count() or 1, 8)
        if _n > 1:
            os.environ["XLA_FLAGS"] = (_flags + f" --xla_force_host_platform_device_count={_n}").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

CACHE_OFF = ("", "0", "off", "no", "false", "none")


def cache_directory() -> str | None:
    """The persistent compilation cache veil uses, or None when it is disabled."""
    configured = jax.config.jax_compilation_cache_dir
    if configured:
        return configured
    setting = os.environ.get("VEIL_CACHE_DIR")
    if setting is not None:
        return None if setting.strip().lower() in CACHE_OFF else os.path.expanduser(setting)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "veil", "jax")


def _enable_cache() -> None:
    if jax.config.jax_compilation_cache_dir:
        return  # the user configured JAX's cache: theirs to manage
    path = cache_directory()
    if path is None:
        return
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ:
        jax.config.update("jax_compilation_cache_max_size", 1 << 30)


_enable_cache()

__all__ = ["jax", "jnp", "cache_directory"]
