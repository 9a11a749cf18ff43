"""A pytest plugin for benchmarks/bench_suite.py: each test's engine compilations and program
reads logged to a file of its own (veil appends to the file ``VEIL_COMPILE_LOG`` names,
looked up at every entry), and each test's start, end and the seconds JAX reported for every
compilation in it (its monitoring events: tracing, lowering, and XLA's compile, which counts
a read from JAX's own cache as one; veil's engine programs and every other jit alike).

    pytest -p suite_census_plugin ...   (benchmarks/ on PYTHONPATH, CENSUS_DIR set)
"""

from __future__ import annotations

import json
import os
import re
import time

import pytest

_LOGS = os.environ.get("CENSUS_DIR", "")
#: JAX's monitoring events of a compilation -> the census's short names.
JAX_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
    "/jax/core/compile/backend_compile_duration": "xla",
    "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read",
}
_SPENT: dict[str, float] = {}


def _listen(event: str, seconds: float, **_) -> None:
    name = JAX_EVENTS.get(event)
    if name:
        _SPENT[name] = _SPENT.get(name, 0.0) + seconds


def pytest_configure(config) -> None:
    if _LOGS:
        from veil._jax import jax  # first: veil sets the device count before JAX starts

        jax.monitoring.register_event_duration_secs_listener(_listen)


def log_name(nodeid: str) -> str:
    """The log file's name of a test (its id made safe for a file name)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid)[:200] + ".jsonl"


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures, whose compilations count
def pytest_runtest_setup(item) -> None:
    if _LOGS:
        os.environ["VEIL_COMPILE_LOG"] = os.path.join(_LOGS, log_name(item.nodeid))
        item.census_started = time.time()
        _SPENT.clear()


def pytest_runtest_teardown(item, nextitem) -> None:
    if _LOGS:
        entry = {"test": item.nodeid, "start": getattr(item, "census_started", 0.0),
                 "end": time.time(), "worker": os.environ.get("PYTEST_XDIST_WORKER", "main"),
                 "jax": dict(_SPENT)}
        with open(os.path.join(_LOGS, f"_tests_{os.getpid()}.jsonl"), "a") as fh:
            fh.write(json.dumps(entry) + "\n")
