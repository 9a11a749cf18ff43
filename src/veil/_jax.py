"""JAX set-up shared by every module: float64 everywhere (MODEL.md demands 1e-3 accuracy
on integrands that span eight decades, which float32 cannot carry), and one CPU device per
core so that the integrator can spread configurations over all cores (XLA runs one
computation per CPU device on one core). Set VEIL_CPU_DEVICES=1, or your own XLA_FLAGS
device count before importing veil, to opt out.
"""

import os

if "jax" not in __import__("sys").modules:
    _flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in _flags:
        _n = int(os.environ.get("VEIL_CPU_DEVICES", "0") or 0) or min(os.cpu_count() or 1, 8)
        if _n > 1:
            os.environ["XLA_FLAGS"] = (_flags + f" --xla_force_host_platform_device_count={_n}").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

__all__ = ["jax", "jnp"]
