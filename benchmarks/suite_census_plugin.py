"""A pytest plugin for benchmarks/bench_suite.py: each test's engine compilations and program
reads logged to a file of its own (veil appends to the file ``VEIL_COMPILE_LOG`` names,
looked up at every entry), and each test's start and end.

    pytest -p suite_census_plugin ...   (benchmarks/ on PYTHONPATH, CENSUS_DIR set)
"""

from __future__ import annotations

import json
import os
import re
import time

_LOGS = os.environ.get("CENSUS_DIR", "")


def log_name(nodeid: str) -> str:
    """The log file's name of a test (its id made safe for a file name)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", nodeid)[:200] + ".jsonl"


def pytest_runtest_setup(item) -> None:
    if _LOGS:
        os.environ["VEIL_COMPILE_LOG"] = os.path.join(_LOGS, log_name(item.nodeid))
        item.census_started = time.time()


def pytest_runtest_teardown(item, nextitem) -> None:
    if _LOGS:
        entry = {"test": item.nodeid, "start": getattr(item, "census_started", 0.0),
                 "end": time.time(), "worker": os.environ.get("PYTEST_XDIST_WORKER", "main")}
        with open(os.path.join(_LOGS, f"_tests_{os.getpid()}.jsonl"), "a") as fh:
            fh.write(json.dumps(entry) + "\n")
