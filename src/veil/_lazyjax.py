"""``jax`` and ``jax.numpy`` for modules that must import without JAX.

The model declarations (``veil.models``) and the angle conventions are read by the command
line's help texts, ``veil models`` and ``veil ingest``, which do no numerics; importing JAX
costs 1.5-3 s. Their functions, which do numerics, reach JAX through these stand-ins: the
first attribute read (``jnp.exp``) imports :mod:`veil._jax` - JAX in float64 with veil's
compilation cache, exactly what ``from veil._jax import jnp`` gives - and every attribute
read is then kept on the stand-in, so later reads cost what a module's do.
"""

from __future__ import annotations


class _Deferred:
    """A stand-in for the object ``veil._jax.<name>`` (a module), imported on first use."""

    def __init__(self, name: str):
        self.__dict__["_veil_name"] = name

    def __getattr__(self, attr: str):
        if attr.startswith("__") and attr.endswith("__"):
            raise AttributeError(attr)  # probes by copy, pickle, inspect: not a reason to import
        from . import _jax

        value = getattr(getattr(_jax, self.__dict__["_veil_name"]), attr)
        self.__dict__[attr] = value
        return value

    def __repr__(self) -> str:
        return f"<veil deferred import of {self.__dict__['_veil_name']}>"


jax = _Deferred("jax")
jnp = _Deferred("jnp")

__all__ = ["jax", "jnp"]
