"""What the engine is compiling, for whoever shows it (the command line's compile display).

A program that is not in the program store (:mod:`veil.engine.programs`) is compiled on
first use, which takes from one to tens of seconds. :func:`announced` wraps each such
compilation: listeners (:func:`listen`) are told when it starts, with a rough estimate of
its time, and when it ends. The estimate is the size of the lowered program (lines of its
StableHLO text) times the seconds a line of that kind of program (values, or values with a
Jacobian) took in this store's earlier compilations (``compile-times.json`` beside the
programs; :data:`SECONDS_PER_LINE` before the first).
Estimates are rough by design: compile time grows with the program and with the load of
the machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

#: Seconds of compilation per line of a program's StableHLO text, by kind of program, before
#: this store has measured its own: a Jacobian's lines take about twice a value's
#: (benchmarks/bench_compile.py, 2 cores with other work beside it, load about 5).
SECONDS_PER_LINE = {"values": 2e-3, "jacobian": 4e-3}
#: How much one new measurement moves the store's rate (an exponential average).
LEARNING_RATE = 0.3
TIMES_FILE = "compile-times.json"
#: The environment variable naming a file that gets one JSON line per compilation.
LOG_VARIABLE = "VEIL_COMPILE_LOG"


@dataclass(frozen=True)
class Compilation:
    """One program being compiled: ``label`` says what it is, ``estimate`` roughly how
    long it takes (seconds), ``lines`` the size it was estimated from."""

    label: str
    identity: str
    lines: int
    estimate: float
    started: float

    @property
    def kind(self) -> str:
        return kind_of(self.identity)


def kind_of(identity: str) -> str:
    """ "jacobian" or "values": what a program computes, from its identity's first part."""
    return "jacobian" if "jacobian" in identity.split(" | ")[0] else "values"


Listener = Callable[[str, Compilation, float], None]
_LISTENERS: list[Listener] = []
_LOCK = threading.Lock()


def listen(listener: Listener) -> Callable[[], None]:
    """Call ``listener(event, compilation, seconds)`` for every compilation: event "start"
    (seconds 0) and "end" (the seconds it took), from the compiling thread. Returns the
    function that stops listening."""
    with _LOCK:
        _LISTENERS.append(listener)

    def stop() -> None:
        with _LOCK:
            if listener in _LISTENERS:
                _LISTENERS.remove(listener)

    return stop


def _tell(event: str, compilation: Compilation, seconds: float) -> None:
    with _LOCK:
        listeners = list(_LISTENERS)
    for listener in listeners:
        listener(event, compilation, seconds)


def _times_path() -> str | None:
    from .store_files import directory

    folder = directory()
    return None if folder is None else os.path.join(folder, TIMES_FILE)


def _rates() -> dict:
    path = _times_path()
    if path is None:
        return {}
    try:
        with open(path, encoding="utf-8") as fh:
            stored = json.load(fh)["seconds_per_line"]
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    if not isinstance(stored, dict):
        return {}
    return {
        k: float(v)
        for k, v in stored.items()
        if k in SECONDS_PER_LINE and isinstance(v, (int, float)) and 0.0 < v < 1.0
    }


def seconds_per_line(kind: str = "values") -> float:
    """This store's measured compile rate for ``kind``, or :data:`SECONDS_PER_LINE`'s."""
    return _rates().get(kind, SECONDS_PER_LINE[kind])


def _learn(kind: str, lines: int, seconds: float) -> None:
    """Move the store's rate of ``kind`` towards this compilation's (best effort: a store
    that cannot be written keeps the defaults)."""
    path = _times_path()
    if path is None or lines <= 0 or seconds <= 0:
        return
    rates = {**SECONDS_PER_LINE, **_rates()}
    rates[kind] = (1.0 - LEARNING_RATE) * rates[kind] + LEARNING_RATE * seconds / lines
    from .store_files import put_file

    with contextlib.suppress(OSError):
        put_file(path, (json.dumps({"seconds_per_line": rates}, sort_keys=True) + "\n").encode())


def program_lines(lowered) -> int:
    """The size of a lowered program: lines of its StableHLO text."""
    try:
        return lowered.as_text().count("\n")
    except Exception:
        return 0


@contextlib.contextmanager
def announced(label: str, identity: str, lowered) -> Iterator[Compilation]:
    """The block compiles ``lowered``: listeners hear of its start and its end."""
    lines = program_lines(lowered)
    compilation = Compilation(
        label, identity, lines, lines * seconds_per_line(kind_of(identity)), time.perf_counter()
    )
    _tell("start", compilation, 0.0)
    ok = False
    try:
        yield compilation
        ok = True
    finally:
        seconds = time.perf_counter() - compilation.started
        _tell("end" if ok else "failed", compilation, seconds)
        if ok:
            _learn(compilation.kind, lines, seconds)
            _log(compilation, seconds)


def _log(compilation: Compilation, seconds: float) -> None:
    """One JSON line per compilation appended to the file named by ``VEIL_COMPILE_LOG``
    (benchmarks/bench_compile.py reads it); nothing without it."""
    _append(
        {
            "event": "compile",
            "label": compilation.label,
            "identity": compilation.identity,
            "lines": compilation.lines,
            "estimate": round(compilation.estimate, 2),
            "seconds": round(seconds, 3),
        }
    )


def log_load(label: str, seconds: float) -> None:
    """One JSON line (event "load") for a program read from the store and made ready to
    run, to the same file (benchmarks/bench_auto.py sums them); nothing without it."""
    _append({"event": "load", "label": label, "seconds": round(seconds, 3)})


def _append(entry: dict) -> None:
    path = os.environ.get(LOG_VARIABLE)
    if not path:
        return
    with _LOCK, contextlib.suppress(OSError), open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")


__all__ = [
    "Compilation",
    "announced",
    "listen",
    "log_load",
    "seconds_per_line",
    "program_lines",
    "kind_of",
]
