"""``jax``, ``jax.numpy`` and ``numpy`` for modules that must import without them.

The model declarations (``veil.models``) and the angle conventions are read by the command
line's help texts, ``veil models`` and ``veil ingest``, which do no numerics; importing JAX
costs 1.5-3 s. Their functions, which do numerics, reach JAX through these stand-ins: the
first attribute read (``jnp.exp``) imports :mod:`veil._jax` - JAX in float64 with veil's
compilation cache, exactly what ``from veil._jax import jnp`` gives - and every attribute
read is then kept on the stand-in, so later reads cost what a module's do. ``np`` does the
same for numpy (0.13 s of the 0.3 s that ``veil --help`` may take).
"""

from __future__ import annotations

import importlib


class _Deferred:
    """A stand-in for the object ``<module>.<name>`` (``veil._jax.jnp``; numpy itself when
    ``name`` is empty), imported on first use."""

    def __init__(self, name: str, module: str = "veil._jax"):
        self.__dict__["_veil_name"] = name
        self.__dict__["_veil_module"] = module

    def __getattr__(self, attr: str):
        if attr.startswith("__") and attr.endswith("__"):
            raise AttributeError(attr)  # probes by copy, pickle, inspect: not a reason to import
        module = importlib.import_module(self.__dict__["_veil_module"])
        target = (
            getattr(module, self.__dict__["_veil_name"]) if self.__dict__["_veil_name"] else module
        )
        value = getattr(target, attr)
        self.__dict__[attr] = value
        return value

    def __repr__(self) -> str:
        name = self.__dict__["_veil_name"] or self.__dict__["_veil_module"]
        return f"<veil deferred import of {name}>"


jax = _Deferred("jax")
jnp = _Deferred("jnp")
np = _Deferred("", "numpy")

__all__ = ["jax", "jnp", "np"]
