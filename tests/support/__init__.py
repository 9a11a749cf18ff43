"""Utilities the tests share (importable because pyproject's ``[tool.pytest.ini_options]``
puts tests/ on the path): :mod:`.cli` (the command line in-process), :mod:`.chain` (a small
three-step chain of fits), :mod:`.maps` (simulated photo stacks for the maps), :mod:`.compiles`
(what XLA compiles inside a block). Fixtures are in tests/conftest.py; the independent reference implementations the docs name stay beside
the tests (tests/reference.py, tests/reference_physical.py)."""
