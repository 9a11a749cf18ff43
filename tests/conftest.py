"""What every test module shares. The suite's utilities are the package tests/support
(tests/, tests/plugins and validation/ are on the path through pyproject's
``[tool.pytest.ini_options] pythonpath``; no test edits ``sys.path``)."""

from __future__ import annotations

import os
from pathlib import Path


def pytest_report_header(config) -> str:
    """Which veil the suite tests (a worktree's src/ through PYTHONPATH, or the installed)."""
    import veil

    return f"veil from {Path(veil.__file__).parent}"


def pytest_configure(config) -> None:
    """Tests spread over several workers (pytest-xdist's ``-n``, as ``make test`` runs them):
    numpy's and scipy's OpenBLAS one thread in each worker, unless OPENBLAS_NUM_THREADS is
    set. The workers already take every core; OpenBLAS's own threads, spinning while they
    wait, then fight the other worker for them (tests/test_model_error.py's session
    correlation: 2 s alone, 9-22 s beside another worker, 2 s with one thread). Set in the
    controller before it starts the workers, which inherit it (its own numpy is loaded)."""
    if hasattr(config, "workerinput"):
        return
    workers = getattr(config.option, "numprocesses", None)
    distributed = getattr(config.option, "dist", "no") != "no"
    if distributed and (workers in ("auto", "logical") or (workers or 0) > 1):
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
