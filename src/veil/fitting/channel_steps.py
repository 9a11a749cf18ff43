"""Steps 1 and 2 through a medium over several colour channels at once (docs/fitting.md,
"Channels"; docs/model.md sec. 7).

A multi-channel table of the reference (step 1) or the target (step 2) in the medium is one
weighted least-squares problem (:class:`veil.fitting.problem.Problem`), one
:class:`~veil.fitting.problem.Block` per channel, as in
:mod:`veil.fitting.channel_fit`: the fitted model's parameters declared per channel
(``Param.channels``: the paper medium's T_d, T_t, forward-series' tau and omega, a BRDF's
albedos) have one slot per channel (``Td[r]``), the shared ones one slot tied across them
(``g``, ``eta_u``, ``n``). The model held fixed enters each channel's block with that
channel's values: the given fit's own slots, named as in its result (``Pd[r]``), so that its
covariance propagates into ``stderr_total`` per channel exactly as in a one-channel step
(:mod:`veil.fitting.propagation`, first order or sigma points). A given model instance (not
a fit) is the same in every channel.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import cast

import numpy as np

from ..errors import FitError
from ..models import BRDF, Medium, Model
from ..models.base import VARIANT_OPTION
from .channel_fit import _fixed_values, channel_layout, layout_slots
from .given import as_given
from .problem import ITERATION_ACCURACY, Block, Problem, Session, Slot, model_slots
from .reported_uncertainty import model_floor, reported
from .result import RESULTS, FitResult, model_entry
from .session_data import FitData
from .solver import (
    began_at_grid,
    check_start_family,
    linear_free,
    run_from,
    start_vector,
    summarize,
)
from .start_values import brdf_scales, column_scales_of, grid_points, medium_scales, pick_starts
from .step_fit import stats_and_message


def given_layout(
    given,
    kind: str,
    channels: list[str],
    role: str,
    source: str,
) -> tuple[list[Slot], list[float], dict[str, dict[str, str]], dict[str, Model]]:
    """(slots, values, layout, {channel: model}) of the model a step holds fixed in a fit of
    ``channels`` (module docstring); a fit of other channels, or of one channel, is a
    FitError naming both (``role`` names the given model, ``source`` the table)."""
    if isinstance(given, FitResult) and given.channels is not None and not given.JOINT:
        if given.kind != kind:
            raise FitError(
                f"{role} must be {RESULTS[kind]}; got a {given.model} result"
                + (f" of step {given.step!r}" if given.step else "")
            )
        have = list(given.channels)
        if sorted(have) != sorted(channels):
            raise FitError(
                f"{role} is a fit of channels {', '.join(have)} but {source} has "
                f"channels {', '.join(channels)}: give {role} fitted over the "
                f"table's channels, or fit one channel with --channel NAME "
                f"(channel= in Python)"
            )
        if not given.converged:
            warnings.warn(
                f"the fit of {role} did not converge; its model is used as it is", stacklevel=4
            )
        layout = {c: dict(given.channels[c]) for c in channels}
        slots = layout_slots(given.model_class, kind, layout)
        values = [given.params[s.name] for s in slots]
        return slots, values, layout, {c: given.as_model(channel=c) for c in channels}
    if isinstance(given, FitResult) and not given.JOINT:
        raise FitError(
            f"{role} is a fit of one channel but {source} has channels "
            f"{', '.join(channels)}: give {role} fitted over the same channels "
            f"(e.g. veil fit reference on a table of every channel), or fit one "
            f"channel with --channel NAME (channel= in Python)"
        )
    model = as_given(given, kind, role)
    slots = model_slots(model, kind, "*")
    layout = {c: {s.spec.name: s.name for s in slots} for c in channels}
    return slots, list(model.to_vector()), layout, {c: model for c in channels}


def _check_names(slots: list[Slot], fitted: Model, given_name: str) -> None:
    names = [s.name for s in slots]
    if len(set(names)) != len(names):
        raise FitError(
            f"the parameters of {given_name} and {fitted.NAME} share a name "
            f"({', '.join(names)}): one of them must declare an alias"
        )


def through_problem(
    datas: dict[str, FitData],
    fitted: Model,
    given,
    fixed: dict,
    freed,
    what: str,
    role: str,
    source: str,
) -> tuple[Problem, dict, dict]:
    """The problem of a step through the medium over every channel of ``datas`` (module
    docstring): ``fitted``'s parameters free (but ``fixed``; held ones unless ``freed``),
    ``given`` (a fit or a model) held. Returns (problem, the fitted model's layout, the given
    model by channel)."""
    cls = type(fitted)
    channels = list(datas)
    other = "brdf" if cls.KIND == "medium" else "medium"
    g_slots, g_values, g_layout, g_models = given_layout(given, other, channels, role, source)
    f_layout = channel_layout(cls, channels, cls.KIND)[1]
    f_slots = layout_slots(cls, cls.KIND, f_layout)
    slots = f_slots + g_slots if cls.KIND == "brdf" else g_slots + f_slots
    _check_names(slots, fitted, next(iter(g_models.values())).NAME)
    names = [s.name for s in slots]
    starts = [s.spec.start for s in f_slots]
    values = np.array(
        [*starts, *g_values] if cls.KIND == "brdf" else [*g_values, *starts], dtype=float
    )
    held = _fixed_values(f_slots, fixed, cls)
    for name, value in held.items():
        values[names.index(name)] = value
    mine = {s.name for s in f_slots}
    free = np.array(
        [
            s.name in mine and s.name not in held and (not s.spec.held or s.spec.name in freed)
            for s in slots
        ]
    )
    if not free.any():
        raise FitError(f"every parameter of the {what} fit is fixed: nothing to fit")
    blocks = []
    engines = shared_engines()
    for c, data in datas.items():
        b_layout, m_layout = (f_layout, g_layout) if cls.KIND == "brdf" else (g_layout, f_layout)
        brdf = cast(BRDF, fitted if cls.KIND == "brdf" else g_models[c])
        medium = cast(Medium, g_models[c] if cls.KIND == "brdf" else fitted)
        ib = np.array([names.index(b_layout[c][p.name]) for p in type(brdf).PARAMS])
        im = np.array([names.index(m_layout[c][p.name]) for p in type(medium).PARAMS])
        session = Session(
            data.table, "m", "reference" if cls.KIND == "medium" else "target", name=f"channel {c}"
        )
        blocks.append(Block(session, data, ib, im, brdf, medium, engines(data, brdf, medium)))
    weighted = {d.sigma is not None for d in datas.values()}
    if len(weighted) > 1:
        raise FitError(f"the {what} table has a sigma for some channels and not others")
    problem = Problem(blocks, slots, values, free, weighted=weighted.pop())
    if problem.n_points <= problem.n_free:
        raise FitError(
            f"the {what} data have {problem.n_points} point(s) but the channels' "
            f"fit has {problem.n_free} free parameter(s): need more points than "
            f"free parameters"
        )
    return problem, f_layout, g_models


def shared_engines() -> Callable[[FitData, BRDF, Medium | None], dict]:
    """A function giving each channel's block its engines: one dict (accuracy -> engine,
    :class:`~veil.fitting.problem.Block`) shared by the channels measured at the same
    configurations with models of the same structure, so that an iteration runs the engine's
    programs once for all of them where the channels differ only in scale parameters
    (``Forward._memo_run``; docs/channels.md, "Cost")."""
    seen: list = []

    def engines(data: FitData, brdf: BRDF, medium: Medium | None) -> dict:
        kinds = (brdf.structure(), None if medium is None else medium.structure())
        for angles, structures, shared in seen:
            if structures == kinds and all(
                np.array_equal(a, b) for a, b in zip(angles, data.angles)
            ):
                return shared
        seen.append((data.angles, kinds, {}))
        return seen[-1][2]

    return engines


def _grid_x(problem: Problem, b: Block, kind: str, v: np.ndarray) -> np.ndarray:
    """The problem's vector with block ``b``'s free parameters of ``kind`` at ``v``."""
    idx = b.ib if kind == "brdf" else b.im
    assert idx is not None  # a block through a medium
    x = problem.values.copy()
    own = x[idx].copy()
    mine = [j for j, k in enumerate(idx) if problem.free[k]]
    own[mine] = v[mine]
    x[idx] = own
    return x


def _block_point(problem: Problem, b: Block, kind: str, x: np.ndarray):
    """(cost, the fitted model's vector) of block ``b`` at ``x`` (:func:`_grid_x` of a grid
    vector), its free scales solved exactly (:mod:`veil.fitting.start_values`)."""
    idx = b.ib if kind == "brdf" else b.im
    assert idx is not None  # a block through a medium
    cls: type[Model] = type(b.brdf) if kind == "brdf" else type(cast(Medium, b.medium))
    own = x[idx]
    vb, vm = problem.split(b, x)
    held = {cls.PARAMS[j].name for j, k in enumerate(idx) if not problem.free[k]}
    terms = b.model(ITERATION_ACCURACY).terms(vb, vm)
    if kind == "medium":
        basis = np.einsum("mkb,b->mk", terms, column_scales_of(b, vb))
        out, cost = medium_scales(basis, own, cls, held, b.data.y, b.data.w)
    else:
        rows = b.model(ITERATION_ACCURACY).row_weights(vm)
        basis = np.einsum("mkb,k->mb", terms, rows)
        out, cost = brdf_scales(basis, own, cls, held, b.data.y, b.data.w)
    return cost, out


def through_starts(
    problem: Problem, kind: str, role: str, count: int, progress=None
) -> tuple[list[np.ndarray], int]:
    """Starting vectors of a step over channels, best first: the fitted model's grid for
    ``role``; for each value of its shared nonlinear parameters every channel takes its own
    best value of the per-channel ones, the scales solved exactly channel by channel (a scale
    tied across channels takes their mean). Returns (starts, number of grid points)."""
    first = problem.blocks[0]
    cls = type(first.brdf if kind == "brdf" else first.medium)
    idx_of = [b.ib if kind == "brdf" else b.im for b in problem.blocks]
    n = len(cls.PARAMS)
    free = [j for j in range(n) if any(problem.free[idx[j]] for idx in idx_of)]
    points = grid_points(cls, role, free, problem.values[idx_of[0]])
    grid, scales, sharing = cls.start_grid(role), set(cls.scale_names()), cls.channel_sharing()
    axes = [j for j in free if cls.PARAMS[j].name not in scales and cls.PARAMS[j].name in grid]
    tied = [k for k, j in enumerate(axes) if sharing[cls.PARAMS[j].name] == "shared"]
    found = []
    shared = [b.models is first.models for b in problem.blocks]  # the first block's engine
    for k, (_, v) in enumerate(points):
        xs = [_grid_x(problem, b, kind, v) for b in problem.blocks]
        pairs = [problem.split(b, x) for b, x, s in zip(problem.blocks, xs, shared) if s]
        first.model(ITERATION_ACCURACY).anticipate(pairs)  # the channels at once
        found.append([_block_point(problem, b, kind, x) for b, x in zip(problem.blocks, xs)])
        if progress:
            progress("starting grid", k + 1, len(points))
    groups: dict = {}
    for k, (combo, _) in enumerate(points):
        groups.setdefault(tuple(combo[a] for a in tied), []).append(k)
    scored = []
    for key, members in groups.items():
        x = problem.values.copy()
        cost, solved = 0.0, cast(dict[int, list[float]], {})
        for i, idx in enumerate(idx_of):
            best = min(members, key=lambda p: float(found[p][i][0]))
            cost += found[best][i][0]
            for j, slot in enumerate(idx):
                solved.setdefault(int(slot), []).append(float(found[best][i][1][j]))
        for slot, vals in solved.items():
            if problem.free[slot]:
                x[slot] = float(np.mean(vals))
        scored.append((cost, key, x))
    return [x for _, _, x in pick_starts(scored, count)], len(points)


def _rename(names: list[str]):
    """The ``rename`` of :func:`veil.fitting.reported_uncertainty.reported`: the fitted
    model's slots alone (the given model's are held)."""
    keep = set(names)

    def rename(se, corr):
        return (
            {n: se[n] for n in names},
            {
                a: {b: r for b, r in row.items() if b in keep}
                for a, row in corr.items()
                if a in keep
            },
        )

    return rename


def given_entry(given, g_models: dict) -> dict:
    """The result's ``given`` key: a model, or a fit of several channels with its layout."""
    if isinstance(given, FitResult) and given.channels is not None:
        first = next(iter(g_models.values()))
        return {
            "model": given.model,
            "params": dict(given.params),
            "channels": {c: dict(m) for c, m in given.channels.items()},
            **first.options(),
        }
    return model_entry(next(iter(g_models.values())))


def _run_through(problem, cls, what: str, count: int, start, kw: dict) -> tuple:
    """(the run's outcome, the grid's size, 0 if not evaluated) of :func:`fit_through`: from
    ``start`` first when given (the grid after it only when needed, without its best start
    when the start ran it), else from the grid."""
    if start is not None:
        check_start_family(start, cls.NAME)
    first = None if start is None else start_vector(problem, start.params, "the start")
    ran_best = start is not None and began_at_grid(start)
    grid = {"points": 0}

    def from_grid() -> list:
        begin, grid["points"] = through_starts(problem, cls.KIND, what, count, kw["progress"])
        return begin

    return run_from(problem, first, ran_best, from_grid, **kw), grid["points"]


def fit_through(
    step: str,
    datas: dict[str, FitData],
    fitted: Model,
    given,
    *,
    fixed: dict,
    freed,
    accuracy: str,
    max_nfev,
    progress,
    model_error: str,
    propagation: str,
    starts: int,
    role: str,
    source: str,
    screen: bool = False,
    start: FitResult | None = None,
) -> FitResult:
    """Step 1 (``step`` "medium") or 2 ("target") over every channel of ``datas`` (module
    docstring; docs/model.md sec. 7); ``given`` the reference (a fit or a BRDF) or the
    medium held fixed; ``screen`` as :func:`veil.fitting.step_fit.fit_step`, ``start`` a fit
    of the same model over the same channels to continue from (as its ``start``)."""
    propagation = "off" if screen else propagation  # (a screen's rules: solver.run)
    cls = type(fitted)
    what = "medium" if step == "medium" else "target"
    problem, layout, g_models = through_problem(
        datas, fitted, given, fixed, freed, what, role, source
    )
    linear_free(problem)
    problem.blocks[0].model(ITERATION_ACCURACY).prepare(
        values=True, jacobians=[(cls.KIND,)], channels=len(datas)
    )
    kw = dict(accuracy=accuracy, max_nfev=max_nfev, progress=progress, screen=screen)
    outcome, n_grid = _run_through(problem, cls, what, starts, start, kw)
    summary = summarize(problem, outcome)
    x = outcome.solution.x
    mine = [n for n in dict.fromkeys(layout[c][p.name] for p in cls.PARAMS for c in layout)]
    result_given = given if isinstance(given, FitResult) else None
    first_given = next(iter(g_models.values()))
    rep = reported(
        problem,
        x,
        summary,
        outcome.values,
        kind=model_error,
        rename=_rename(mine),
        given_result=result_given,
        given_column=problem.index,
        propagation=propagation,
        keep_influence=step == "medium",
        floor=model_floor(problem.blocks[0].brdf, problem.blocks[0].medium),
    )
    stats, message = stats_and_message(outcome, summary, rep, given, n_grid)
    medium = fitted if cls.KIND == "medium" else first_given
    return FitResult(
        model=cls.NAME,
        params={n: float(x[problem.index(n)]) for n in mine},
        stderr=rep.stderr,
        correlation=rep.correlation,
        residuals=tuple(float(r) for r in summary.residuals),
        chi2_reduced=summary.chi2_reduced,
        rms_relative=summary.rms_relative,
        n_points=problem.n_points,
        converged=summary.converged,
        message=message,
        variant=medium.options().get(VARIANT_OPTION),
        fixed={n: float(x[problem.index(n)]) for n in mine if not problem.free[problem.index(n)]},
        step=step,
        weighted=problem.weighted,
        accuracy=outcome.accuracy,
        given=given_entry(given, g_models),
        stderr_total=rep.stderr_total,
        correlation_total=rep.correlation_total,
        stats=stats,
        options=fitted.options(),
        determined=summary.determined,
        model_error=rep.model_error,
        channels=layout,
    )


__all__ = [
    "given_layout",
    "through_problem",
    "through_starts",
    "fit_through",
    "shared_engines",
    "given_entry",
]
