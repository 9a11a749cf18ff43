"""Ahead-of-time preparation of the engine programs a machine needs (``veil warmup``).

Each task runs the very code path a command takes - the fits' chunked evaluator
(:class:`~veil.engine.evaluator.ApparentModel`, 64 in-plane configurations a chunk, values
and the three Jacobians of the fits at the iteration accuracy - in the medium's parameters
(step 1), the object's (step 2), both (joint fits) - values at the reported one), ``veil
eval`` of one configuration (:func:`~veil.engine.apparent.apparent` with its error estimate)
and the object's own f_r (step 0 of the fits) - so that what it stores in the program store
(:mod:`veil.engine.programs`) and JAX's compilation cache is exactly what those commands
look up later. The families get the model options the commands will be given (a plate's
geometry makes other programs), and a channel count adds the programs that run that many
channels of a medium together (:mod:`veil.engine.channel_programs`). Out-of-plane
configurations and other chunk sizes are compiled on first use, as before.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..models import DEFAULTS, model_class, names
from .apparent import apparent, reflectance
from .channel_programs import shares_nodes
from .evaluator import CHUNK, WRT, ApparentModel, DirectModel
from .forward import non_default_options
from .quadrature import RULES

#: The accuracy the fits iterate at (veil.fitting.problem.ITERATION_ACCURACY).
ITERATION = "fast"


@dataclass(frozen=True)
class Task:
    label: str
    run: Callable[[], None]


def _angles(size: int):
    """``size`` in-plane configurations (the paper's protocol is in the plane of incidence)."""
    ti = np.linspace(5.0, 75.0, size)
    tr = np.linspace(70.0, 10.0, size)
    return ti, np.full(size, 180.0), tr, np.zeros(size)


#: The Jacobians the fits take: step 1 (the medium's parameters), step 2 (the object's),
#: joint fits (both).
JACOBIANS = (("medium",), ("brdf",), WRT)


def _fits(brdf, medium, accuracy: str, jacobian: bool):
    def run():
        model = ApparentModel(brdf, medium, _angles(CHUNK), RULES[accuracy])
        model.prepare(values=True, jacobians=JACOBIANS if jacobian else ())
        vb, vm = brdf.to_vector(), medium.to_vector()
        model.terms(vb, vm)
        for wrt in JACOBIANS if jacobian else ():
            model.value_and_jacobian(vb, vm, wrt)

    return run


def _channel_fits(brdf, medium, accuracy: str, jacobian: bool, channels: int):
    """The programs that run ``channels`` channels of ``medium`` together (the fits of a
    colour table, veil.engine.channel_programs): values, and at the iteration accuracy the
    fits' Jacobians; a compilation that fails raises here."""

    def run():
        model = ApparentModel(brdf, medium, _angles(CHUNK), RULES[accuracy])
        for future in model.prepare(True, JACOBIANS if jacobian else (), channels):
            future.result()

    return run


def _eval(brdf, medium, accuracy: str):
    def run():
        apparent(brdf, medium, 45.0, 50.0, accuracy=accuracy, return_error=True)
        reflectance(brdf, 45.0, 50.0)

    return run


def _direct(brdf):
    def run():
        model = DirectModel(brdf, _angles(CHUNK))
        model.value_and_jacobian(brdf.to_vector())

    return run


def _medium_jacobian(brdf, medium):
    def run():
        model = ApparentModel(brdf, medium, _angles(CHUNK), RULES[ITERATION])
        model.prepare(values=False, jacobians=[("medium",)])
        model.value_and_jacobian(brdf.to_vector(), medium.to_vector(), ("medium",))

    return run


def _linear_tasks(brdf, medium, pair: str, accuracies) -> list[Task]:
    """A linear family's programs through ``medium``: its column model's values at the
    iteration rule (a candidate's quick fit) and each reported rule (its step fit), its
    derivative in the medium's parameters (the medium's covariance propagated), and ``veil
    eval`` of the family itself."""
    column = type(brdf).columns()[0].template()
    out = []
    for acc in dict.fromkeys((ITERATION, *accuracies)):
        out.append(Task(f"{pair}: step fit columns ({acc})", _fits(column, medium, acc, False)))
    out.append(
        Task(f"{pair}: the medium's covariance propagated", _medium_jacobian(column, medium))
    )
    for acc in accuracies:
        out.append(
            Task(f"{pair}: veil eval ({acc}, with its error estimate)", _eval(brdf, medium, acc))
        )
    return out


def families(selected=None) -> tuple[list[str], list[str]]:
    """(BRDF families, medium families) to prepare: ``selected`` names (a kind not named
    gets its default, the paper's), ``["all"]`` every registered family; None the paper's
    pair. Unknown names raise an InputError listing the known ones."""
    if not selected:
        return [DEFAULTS["brdf"]], [DEFAULTS["medium"]]
    if [s.strip().lower() for s in selected] == ["all"]:
        return names("brdf"), names("medium")
    chosen: dict[str, list] = {"brdf": [], "medium": []}
    for name in selected:
        cls = model_class(name)
        if cls.NAME not in chosen[cls.KIND]:
            chosen[cls.KIND].append(cls.NAME)
    return (chosen["brdf"] or [DEFAULTS["brdf"]], chosen["medium"] or [DEFAULTS["medium"]])


def _templates(names_: list[str], kind: str, options: dict | None) -> list:
    """The families' templates with the ``options`` each declares."""
    out = []
    for name in names_:
        cls = model_class(name, kind)
        declared = set(cls.option_names())
        out.append(cls.template(**{k: v for k, v in (options or {}).items() if k in declared}))
    return out


def _named(model) -> str:
    """A family's name with the options it was given that differ from the declared defaults."""
    given = [(o.name, model.options()[o.name]) for o in model.OPTIONS]
    shown = non_default_options((type(model),), given)
    return model.NAME + (f" ({', '.join(shown)})" if shown else "")


def _pair_tasks(brdf, medium, accuracies, channels: int) -> list[Task]:
    """The fits', simulations' and ``veil eval``'s programs of one parametric pair, and
    those of ``channels`` channels run together where the medium's family shares its
    nodes across channels."""
    pair = f"{_named(brdf)} x {_named(medium)}"
    out = [
        Task(
            f"{pair}: fit iterations ({ITERATION}, values and Jacobian)",
            _fits(brdf, medium, ITERATION, True),
        )
    ]
    for acc in accuracies:
        if acc != ITERATION:
            out.append(
                Task(
                    f"{pair}: fit results and simulations ({acc})", _fits(brdf, medium, acc, False)
                )
            )
        out.append(
            Task(f"{pair}: veil eval ({acc}, with its error estimate)", _eval(brdf, medium, acc))
        )
    if channels > 1 and shares_nodes(medium):
        for acc in dict.fromkeys((ITERATION, *accuracies)):
            what = "values and Jacobians" if acc == ITERATION else "values"
            out.append(
                Task(
                    f"{pair}: {channels} channels together ({acc}, {what})",
                    _channel_fits(brdf, medium, acc, acc == ITERATION, channels),
                )
            )
    return out


def tasks(
    selected=None,
    accuracies=("fast", "default"),
    brdf_options: dict | None = None,
    medium_options: dict | None = None,
    channels: int = 1,
) -> list[Task]:
    """Everything to prepare for the families ``selected`` (see :func:`families`) at the
    reported ``accuracies`` (the fits iterate at "fast" whatever they report), each family
    with the options of ``brdf_options`` / ``medium_options`` it declares (a plate's
    geometry changes the programs), and for tables of ``channels`` channels."""
    brdf_names, medium_names = families(selected)
    media = _templates(medium_names, "medium", medium_options)
    out = []
    for brdf in _templates(brdf_names, "brdf", brdf_options):
        out.append(Task(f"{_named(brdf)}: f_r and its Jacobian (fit step 0)", _direct(brdf)))
        for medium in media:
            if brdf.LINEAR:  # its step fits evaluate the column model (docs/nonparametric.md)
                pair = f"{_named(brdf)} x {_named(medium)}"
                out += _linear_tasks(brdf, medium, pair, accuracies)
            else:
                out += _pair_tasks(brdf, medium, accuracies, channels)
    return out


__all__ = ["Task", "tasks", "families", "ITERATION"]
