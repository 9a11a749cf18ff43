"""Rounds of the medium's blur correction in one run (docs/maps-blur.md "Rounds";
``veil fit maps --blur-rounds N``): a map, then N maps each fitted from the photos
corrected at the one before, every table built once. The maps before the last are kept in
temporary stores beside the output and removed when the last is written (or the run
fails)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InputError
from ..io import as_path, forget_temporary, register_temporary

if TYPE_CHECKING:
    from .run import MapsRun

#: At most this many rounds (each after the first changes the maps by a fraction of the
#: one before: docs/maps-blur.md).
MAX_ROUNDS = 8


def check_rounds(rounds) -> int:
    """``rounds`` as an int in 1 .. :data:`MAX_ROUNDS`, else an InputError."""
    if isinstance(rounds, bool) or not isinstance(rounds, int) or not 1 <= rounds <= MAX_ROUNDS:
        raise InputError(f"blur rounds {rounds!r}: expected a whole number from 1 to {MAX_ROUNDS}")
    return rounds


def fit_maps_rounds(photo_dir, manifest, medium, output, rounds: int, **kwargs) -> MapsRun:
    """:func:`veil.fit_maps` ``rounds`` times more after a first map (after ``blur_from``
    when given, which then counts as the first), each from the photos corrected for the
    medium's blur at the map before; returns the last run's :class:`~veil.maps.run.MapsRun`
    (its ``seconds["rounds"]``: every round's seconds) written to ``output``."""
    from .run import fit_maps
    from .store import lock_path

    rounds = check_rounds(rounds)
    say = kwargs.get("log") or (lambda message: None)
    output = Path(as_path(output, "output"))
    prior = kwargs.pop("blur_from", None)
    first = 1 if prior is not None else 0
    cache: dict = {}
    temporaries: list[Path] = []
    times = []
    try:
        for k in range(first, rounds + 1):
            last = k == rounds
            target = output if last else output.parent / f".{output.name}.blur-round-{k}"
            if not last:
                shutil.rmtree(target, ignore_errors=True)
                register_temporary(target, "folder")
                temporaries.append(target)
            what = " (the map to correct)" if k == 0 else ""
            say(f"the medium's blur: round {k} of {rounds}{what}")
            record = None if prior is None or prior not in temporaries else f"round {k - 1}"
            run = fit_maps(
                photo_dir,
                manifest,
                medium,
                target,
                blur_from=prior,
                tables_cache=cache,
                blur_record=record,
                **kwargs,
            )
            times.append(sum(run.seconds.values()))
            prior = target
        run.seconds["rounds"] = sum(times)
        return run
    finally:
        for path in temporaries:
            shutil.rmtree(path, ignore_errors=True)
            lock_path(path).unlink(missing_ok=True)
            forget_temporary(path)


__all__ = ["fit_maps_rounds", "check_rounds", "MAX_ROUNDS"]
