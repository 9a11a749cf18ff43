"""The compile display: what the engine compiles while a command waits for it.

Every command shows it (``VeilGroup.invoke``). On a terminal each program being compiled is
a row of a live display - what it is, a bar of its elapsed time against the estimate, the
seconds - nested in the command's own progress display when there is one (they share
:func:`console`). Otherwise (a log, a pipe, CI) one line per program when it starts, with
its rough estimate, and one summary line at the end of the command.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from typing import Any

import click

_CONSOLE = None


def console():
    """The one rich console on stderr that every progress display of a command uses."""
    global _CONSOLE
    if _CONSOLE is None:
        from rich.console import Console

        _CONSOLE = Console(stderr=True)
    return _CONSOLE


def _seconds(estimate: float) -> str:
    if estimate < 1.0:
        return "under a second"
    return f"about {estimate:.0f} s" if estimate < 90 else f"about {estimate / 60:.0f} min"


class CompileDisplay:
    """Listener of :mod:`veil.engine.compiling` for one command."""

    def __init__(self, live: bool | None):
        self.live = live
        self.count = 0
        self.total = 0.0
        self._lock = threading.Lock()
        self._rows: dict = {}
        self._progress: Any = None  # a rich Progress, made at the first compilation
        self._ticker: threading.Thread | None = None

    def __call__(self, event: str, compilation, seconds: float) -> None:
        with self._lock:
            if event == "start":
                self._start(compilation)
            else:
                self._end(compilation, seconds, event == "end")

    def _start(self, c) -> None:
        if self.live is None:  # decided at the first compilation: no rich import before
            self.live = console().is_terminal
        if not self.live:
            click.echo(
                f"veil: compiling {c.label} ({_seconds(c.estimate)}; once: kept in the "
                f"program store for later runs)",
                err=True,
            )
            return
        if self._progress is None:
            from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn

            self._progress = Progress(
                SpinnerColumn(),
                TextColumn("compiling {task.description}"),
                BarColumn(),
                TextColumn("{task.fields[seconds]}"),
                console=console(),
                transient=True,
            )
            self._progress.start()
        estimate = max(c.estimate, 1.0)
        self._rows[c] = self._progress.add_task(
            c.label, total=estimate, seconds=f"0 s of ~{estimate:.0f} s"
        )
        if self._ticker is None:
            self._ticker = threading.Thread(
                target=self._tick, daemon=True, name="veil-compile-display"
            )
            self._ticker.start()

    def _end(self, c, seconds: float, ok: bool) -> None:
        if ok:
            self.count += 1
            self.total += seconds
        if not self.live:
            return
        task = self._rows.pop(c, None)
        if task is not None and self._progress is not None:
            self._progress.remove_task(task)
            if ok:
                self._progress.console.print(
                    f"  compiled {c.label} in {seconds:.1f} s", highlight=False, style="dim"
                )

    def _tick(self) -> None:
        while True:
            time.sleep(0.25)
            with self._lock:
                if self._progress is None:
                    return
                now = time.perf_counter()
                for c, task in self._rows.items():
                    elapsed = now - c.started
                    total = max(c.estimate, 1.0)
                    self._progress.update(
                        task,
                        completed=min(elapsed, 0.99 * total),
                        seconds=f"{elapsed:.0f} s of ~{total:.0f} s",
                    )

    def close(self) -> None:
        with self._lock:
            if self._progress is not None:
                self._progress.stop()
                self._progress = None
        if self.count and not self.live:
            click.echo(
                f"veil: compiled {self.count} engine program"
                f"{'s' if self.count > 1 else ''} in {self.total:.0f} s of compile "
                f"time; later runs load them",
                err=True,
            )


_ACTIVE: list = []


@contextlib.contextmanager
def shown(live: bool | None = None) -> Iterator[CompileDisplay]:
    """Show the engine's compilations during the block (``live``: a terminal display;
    default: when stderr is a terminal). Nested blocks share the outermost display."""
    if _ACTIVE:
        yield _ACTIVE[0]
        return
    from ..engine import compiling

    display = CompileDisplay(live)
    stop = compiling.listen(display)
    _ACTIVE.append(display)
    try:
        yield display
    finally:
        _ACTIVE.remove(display)
        stop()
        display.close()
