"""Rounds of the medium's blur correction in one run (docs/maps-blur.md "The correction and
its rounds"; ``veil fit maps --blur-rounds N``): a map, then N maps each fitted from the
photos corrected at the one before, every table built once. The maps before the last are
kept in a temporary folder beside the output, removed when the last is written, when the
run fails and when it is interrupted."""

from __future__ import annotations

import shutil
import tempfile
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
    (its ``seconds["rounds"]``: every round's seconds) written to ``output``. The geometry
    and the medium are checked (:func:`veil.maps.blur.check_medium`) before the first map."""
    from .blur import check_medium, media_of
    from .channels import map_media
    from .medium_error import check_method
    from .model_error import discrepancy
    from .run import check_noise, check_output, fit_maps

    rounds = check_rounds(rounds)
    say = kwargs.get("log") or (lambda message: None)
    # before the first round, not after every round but the last
    output = check_output(Path(as_path(output, "output")), kwargs.get("blur_from"))
    model, media = map_media(medium, kwargs.get("channel", "gray"))
    near = bool(kwargs.get("near_field")) and kwargs.get("geometry") is not None
    check_medium(media_of(media or model), near)
    # the last round's model error and propagation, checked before the first round
    discrepancy(kwargs.get("model_error", "off"), check_noise(kwargs.get("noise")))
    check_method(kwargs.get("propagation", "off"), medium)
    prior = kwargs.pop("blur_from", None)
    given = prior
    cache: dict = {}
    times = []
    folder = None
    try:
        for k in range(1 if prior is not None else 0, rounds + 1):
            if k == rounds:
                target = output
            else:
                if folder is None and output.parent.is_dir():
                    folder = Path(tempfile.mkdtemp(prefix=f".{output.name}.", dir=output.parent))
                    register_temporary(folder, "folder")
                target = (folder or output.parent) / f"round-{k}.zarr"
            say(
                f"the medium's blur: round {k} of {rounds}"
                + (" (the map to correct)" if k == 0 else "")
            )
            record = None
            if k and (k > 1 or given is None):
                record = f"round {k - 1} of {rounds} in this run" + (
                    f", from {given}" if given else ""
                )
            # the rounds before the last give their parameters only: no model error, no
            # propagation
            run = fit_maps(
                photo_dir,
                manifest,
                medium,
                target,
                blur_from=prior,
                tables_cache=cache,
                blur_record=record,
                **(kwargs if k == rounds else dict(kwargs, model_error="off", propagation="off")),
            )
            times.append(sum(run.seconds.values()))
            prior = target
        run.seconds["rounds"] = sum(times)
        return run
    finally:
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
            forget_temporary(folder)


__all__ = ["fit_maps_rounds", "check_rounds", "MAX_ROUNDS"]
