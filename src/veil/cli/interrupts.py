"""Ctrl-C and SIGTERM on the command line: stop at once, leave nothing partial (docs/errors.md).

A Python signal handler runs only in the main thread, between two bytecodes: not while the
main thread waits for JAX to compile or run the engine (seconds, in C++), and a
KeyboardInterrupt raised inside a garbage-collection callback is printed as "Exception
ignored" and lost. So :func:`install` makes the C-level signal handler write the signal's
number to a pipe (:func:`signal.set_wakeup_fd`) and a watchdog thread waits on that pipe.
XLA releases the GIL while it compiles and runs (measured: the longest hold during import,
compilation and evaluation is about 0.15 s), so the watchdog gets to run within that time
wherever the main thread is. It then

1. takes :data:`veil.io.COMMIT`, so that no output is being renamed into place (a commit is
   a few renames; the main thread never gets the lock back),
2. removes every temporary file and folder the atomic writers registered
   (:func:`veil.io.abandon`),
3. prints one line: what was interrupted and which complete outputs exist,
4. ends the process with :func:`os._exit`: status 130 after SIGINT, 143 after SIGTERM.

``os._exit`` runs no Python clean-up and no C++ static destructors, which is what makes a
process with XLA's threads still running exit without a crash. The Python-level handlers
installed alongside do nothing: no KeyboardInterrupt is ever raised. A signal that was
ignored when veil started (``nohup``, a background job of a non-interactive shell) stays
ignored.

Before :func:`install` runs, while the console script imports veil and JAX, the guard set
up by :mod:`veil._jax` handles the two signals (nothing has been written by then).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading

from .. import io as _io

#: Exit status by signal: 128 + the signal's number, as a shell reports a killed process.
EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
WHAT = {signal.SIGINT: "interrupted (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)"}
#: Longest wait for a commit in progress to finish before cleaning up anyway.
COMMIT_WAIT = 5.0

_state = {"installed": False}


def installed() -> bool:
    """Whether :func:`install` has set up the handlers in this process."""
    return _state["installed"]


def install() -> bool:
    """Handle SIGINT and SIGTERM as described in the module docstring (main thread only;
    a second call does nothing). Returns whether the handlers are in place."""
    if _state["installed"]:
        return True
    if threading.current_thread() is not threading.main_thread():
        return False
    handled = [s for s in EXIT_STATUS if signal.getsignal(s) is not signal.SIG_IGN]
    if not handled:
        return False
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)
    watchdog = threading.Thread(
        target=_watch, args=(read_end, frozenset(handled)), name="veil-interrupts", daemon=True
    )
    watchdog.start()
    signal.set_wakeup_fd(write_end, warn_on_full_buffer=False)
    for s in handled:
        signal.signal(s, _ignore_in_python)
    _state["installed"] = True
    return True


def _ignore_in_python(signum, frame) -> None:
    """The Python-level handler: nothing to do, the watchdog thread ends the process."""


def _watch(read_end: int, handled: frozenset) -> None:
    while True:
        try:
            data = os.read(read_end, 64)
        except InterruptedError:
            continue
        except OSError:
            return
        for signum in data:
            if signum in handled:
                _stop(signal.Signals(signum))


def finish(code) -> None:
    """End the process with the exit status ``code`` (as :class:`SystemExit` takes it) once
    the command is done: flush the output, run the :mod:`atexit` functions while the
    watchdog still answers signals, then :func:`os._exit`. Python's own shutdown (module
    teardown, the engine's destructors: a few hundred ms) runs with signal handling
    already gone, so a Ctrl-C there would end the process without a word; after this
    there is no such window: a signal that arrives once every output is in place is
    answered like any other ("complete: ..."), with status 130 or 143. Never returns."""
    import atexit
    import sys

    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message"): printed, status 1, as Python does
        with contextlib.suppress(Exception):
            print(code, file=sys.stderr)
        status = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with _io.COMMIT:  # not while an interrupt is being handled: that one ends the process
        os._exit(status & 0xFF)


def message(signum, left: str) -> str:
    """The one line printed on exit."""
    return f"veil: {WHAT.get(signum, f'stopped by signal {int(signum)}')}; {left}."


def _stop(signum) -> None:
    """Clean up and end the process (runs in the watchdog thread; never returns)."""
    try:
        _io.COMMIT.acquire(timeout=COMMIT_WAIT)
        left = _io.abandon()
    except BaseException as exc:
        left = f"clean-up failed ({type(exc).__name__}: {exc})"
    line = message(signum, left) + "\n"
    try:
        if os.isatty(2):  # end a progress bar's line and show the cursor it hid
            line = "\r\x1b[2K\x1b[?25h" + line
    except OSError:
        pass
    try:
        os.write(2, line.encode("utf-8", "replace"))
    except OSError:
        pass
    os._exit(EXIT_STATUS.get(signum, 128 + int(signum)))


__all__ = ["install", "installed", "finish", "message", "EXIT_STATUS"]
