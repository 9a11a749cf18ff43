"""Where the tiles of a map run (docs/maps.md "Streaming, tiles, Dask and resuming"): local
threads, or a dask.distributed cluster named by an address or ``$VEIL_DASK_SCHEDULER``."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from .._extras import require
from ..errors import InputError

if TYPE_CHECKING:
    from distributed import Client

SCHEDULER_ENV = "VEIL_DASK_SCHEDULER"
CONNECT_TIMEOUT = 5.0


def connect(address, timeout: float = CONNECT_TIMEOUT) -> Client:
    """A dask.distributed client for ``address``; an InputError within ``timeout`` seconds
    when no scheduler answers there."""
    Client = require("distributed", "a Dask cluster").Client

    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"dask scheduler {address!r}: cannot connect within {timeout:g} s "
            f"({type(exc).__name__}: {exc}); nothing was written. Start the "
            f"scheduler, correct --scheduler / ${SCHEDULER_ENV}, or leave both "
            f"out to run locally"
        ) from None


def run_local(tasks, progress, workers) -> list:
    """The dask ``tasks`` on ``workers`` local threads, ``progress("solving tiles", done,
    total)`` after each."""
    dask = require("dask", "veil maps")
    from dask.callbacks import Callback

    keys = {t.key for t in tasks}
    done = [0]

    class Ticker(Callback):
        def _posttask(self, key, result, dsk, state, id):
            if key in keys:
                done[0] += 1
                if progress is not None:
                    progress("solving tiles", done[0], len(tasks))

    with Ticker():
        return list(dask.compute(*tasks, scheduler="threads", num_workers=workers))


def run_distributed(client, tasks, progress) -> list:
    """The dask ``tasks`` on ``client``'s cluster, ``progress`` as :func:`run_local`'s."""
    as_completed = require("distributed", "a Dask cluster").as_completed

    out = []
    with client.as_current():
        futures = client.compute(tasks)
        for k, future in enumerate(as_completed(futures), 1):
            out.append(future.result())
            if progress is not None:
                progress("solving tiles", k, len(futures))
    return out


@contextmanager
def client_of(scheduler) -> Iterator[Any]:
    """A dask.distributed client of ``scheduler`` or ``$VEIL_DASK_SCHEDULER`` (closed
    afterwards), or None to run locally."""
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    client = connect(address) if address else None
    try:
        yield client
    finally:
        if client is not None:
            client.close()


__all__ = [
    "SCHEDULER_ENV",
    "CONNECT_TIMEOUT",
    "connect",
    "run_local",
    "run_distributed",
    "client_of",
]
