"""What every test module shares. The suite's utilities are the package tests/support
(tests/, tests/plugins and validation/ are on the path through pyproject's
``[tool.pytest.ini_options] pythonpath``; no test edits ``sys.path``)."""

from __future__ import annotations

from pathlib import Path


def pytest_report_header(config) -> str:
    """Which veil the suite tests (a worktree's src/ through PYTHONPATH, or the installed)."""
    import veil

    return f"veil from {Path(veil.__file__).parent}"
