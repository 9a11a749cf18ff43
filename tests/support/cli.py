"""The command line, run in-process by click's test runner."""

from __future__ import annotations

from click.testing import CliRunner, Result

from veil.cli import main


def run(*args, **kw) -> Result:
    """``veil ARGS`` (each argument turned into a string); ``kw`` go to ``CliRunner.invoke``."""
    return CliRunner().invoke(main, [str(a) for a in args], **kw)


def run_checked(args) -> Result:
    """``veil ARGS``, failing the test on a traceback in the output and re-raising an
    exception other than the command's exit."""
    result = CliRunner().invoke(main, [str(a) for a in args])
    assert "Traceback" not in result.output
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise result.exception
    return result
