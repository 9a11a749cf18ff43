"""What XLA compiles inside a block (jax.monitoring's backend-compile events)."""

from __future__ import annotations

import contextlib

from veil._jax import jax
from veil.engine.forward import wait_for_compilations

BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def compilations():
    """The names of the programs XLA compiles (or loads from the cache) inside the block
    (``jit(name)``), once the background compilations started before it have finished."""
    wait_for_compilations()
    names: list = []

    def listen(name, secs, **kw):
        if name == BACKEND_COMPILE:
            names.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
