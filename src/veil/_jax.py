"""JAX set-up shared by every module: float64 everywhere (MODEL.md demands 1e-3 accuracy
on integrands that span eight decades, which float32 cannot carry)."""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402

__all__ = ["jax", "jnp"]
