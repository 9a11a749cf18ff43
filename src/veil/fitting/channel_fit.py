"""Fits of several colour channels at once (docs/channels.md; docs/model.md sec. 7).

A multi-channel table (docs/measurements.md, "Channels") is one session seen in several
channels. Its fit is one weighted least-squares problem (:mod:`veil.fitting.problem`, solved
by :mod:`veil.fitting.solver` as every fit), one :class:`~veil.fitting.problem.Block` per
channel, like a joint fit's sessions: the parameters the model declares per channel
(``Param.channels``: albedos, scales) have one slot per channel, named ``NAME[channel]``
(``Pd[r]``), the others one slot tied across the channels, named plainly (``n``).

Step 0 of the two-step method (f_r in clear water, docs/model.md sec. 2) fits this way;
the steps through a medium over channels are :mod:`veil.fitting.channel_steps`.
"""

from __future__ import annotations

import numpy as np

from ..errors import FitError
from ..models import BRDF, Model
from .problem import ITERATION_ACCURACY, Block, Problem, Session, Slot, model_slots
from .reported_uncertainty import model_floor, reported
from .result import FitResult
from .session_data import FitData, prepare
from .solver import check_fixed, linear_free, run, summarize
from .start_values import brdf_scales, grid_points, pick_starts


def channel_layout(
    cls: type[Model], channels: list[str], kind: str = "brdf"
) -> tuple[list[Slot], dict]:
    """(the slots of a fit of ``channels``, {channel: {parameter: slot name}}): per the
    declaration (:meth:`veil.models.Model.channel_sharing`) one slot per channel or one for
    all, in the model's parameter order; ``kind`` is the model's ("brdf" or "medium")."""
    sharing = cls.channel_sharing()
    layout: dict = {c: {} for c in channels}
    for spec, plain in zip(cls.PARAMS, model_slots(cls, kind, "*")):
        for c in channels:
            shared = sharing[spec.name] == "shared"
            layout[c][spec.name] = plain.name if shared else f"{plain.name}[{c}]"
    return layout_slots(cls, kind, layout), layout


def layout_slots(cls: type[Model], kind: str, layout: dict) -> list[Slot]:
    """The slots of a channels' ``layout`` ({channel: {parameter: slot name}}), in the
    model's parameter order: a name every channel shares is one slot (owner "*"), the others
    one per channel (owned by it)."""
    slots: list[Slot] = []
    for plain in model_slots(cls, kind, "*"):
        names = {c: layout[c][plain.spec.name] for c in layout}
        if len(set(names.values())) == 1:
            slots.append(
                Slot(next(iter(names.values())), kind, "*", plain.index, plain.spec, plain.scale)
            )
            continue
        for c, name in names.items():
            slots.append(Slot(name, kind, c, plain.index, plain.spec, plain.scale))
    return slots


def _fixed_values(slots: list[Slot], fixed: dict, cls: type[Model]) -> dict:
    """{slot name: value} of ``fixed``: a slot's name (``Pd[r]``) holds that slot, a
    parameter's own name (``eta``, ``Pd``) every slot of it."""
    out = {}
    for name, value in fixed.items():
        hits = [s for s in slots if s.name == name] or [s for s in slots if s.spec.name == name]
        if not hits:
            raise FitError(
                f"cannot fix {name!r} in the channels' fit: its parameters are "
                f"{', '.join(s.name for s in slots)} ({cls.NAME})"
            )
        check_fixed(name, value, hits[0].spec, cls.__name__)
        out.update({s.name: float(value) for s in hits})
    return out


def channel_problem(
    datas: dict[str, FitData], template: BRDF, fixed: dict, freed, what: str
) -> tuple[Problem, dict]:
    """The problem of a clear-water fit of every channel of ``datas`` (module docstring) and
    its layout; ``freed`` names held parameters (``Param.held``) to fit too."""
    cls = type(template)
    slots, layout = channel_layout(cls, list(datas))
    names = [s.name for s in slots]
    values = np.array([s.spec.start for s in slots], dtype=float)
    held = _fixed_values(slots, fixed, cls)
    for name, value in held.items():
        values[names.index(name)] = value
    free = np.array(
        [s.name not in held and (not s.spec.held or s.spec.name in freed) for s in slots]
    )
    if not free.any():
        raise FitError(f"every parameter of the {what} fit is fixed: nothing to fit")
    blocks = []
    for c, data in datas.items():
        ib = np.array([names.index(layout[c][p.name]) for p in cls.PARAMS])
        session = Session(data.table, "none", "target", name=f"channel {c}")
        blocks.append(Block(session, data, ib, None, template, None))
    weighted = {d.sigma is not None for d in datas.values()}
    problem = Problem(blocks, slots, values, free, weighted=weighted.pop())
    if problem.n_points <= problem.n_free:
        raise FitError(
            f"the {what} data have {problem.n_points} point(s) but the channels' "
            f"fit has {problem.n_free} free parameter(s): need more points than "
            f"free parameters"
        )
    return problem, layout


def channel_starts(
    problem: Problem, role: str, count: int, progress=None
) -> tuple[list[np.ndarray], int]:
    """Starting vectors of a channels' problem, best first: the model's grid for ``role``
    over its free nonlinear parameters (the same value in every channel), the scales solved
    exactly channel by channel (a scale tied across channels takes their mean). Returns
    (starts, number of grid points)."""
    first = problem.blocks[0]
    cls = type(first.brdf)
    n = len(cls.PARAMS)
    free = [j for j in range(n) if any(problem.free[b.ib[j]] for b in problem.blocks)]
    points = grid_points(cls, role, free, problem.values[first.ib])
    scored = []
    for k, (combo, v) in enumerate(points):
        x = problem.values.copy()
        solved: dict[int, list[float]] = {}
        cost = 0.0
        for b in problem.blocks:
            vb = x[b.ib].copy()
            mine = [j for j in free if problem.free[b.ib[j]]]
            vb[mine] = v[mine]
            held = {cls.PARAMS[j].name for j in range(n) if not problem.free[b.ib[j]]}
            terms = b.model(ITERATION_ACCURACY).terms(vb)
            basis = np.einsum("mkb,k->mb", terms, np.ones(terms.shape[1]))
            vb, part = brdf_scales(basis, vb, cls, held, b.data.y, b.data.w)
            cost += part
            for j, slot in enumerate(b.ib):
                solved.setdefault(int(slot), []).append(float(vb[j]))
        for slot, found in solved.items():
            x[slot] = float(np.mean(found))
        scored.append((cost, combo, x))
        if progress:
            progress("starting grid", k + 1, len(points))
    return [x for _, _, x in pick_starts(scored, count)], len(points)


def fit_channels(
    table,
    black,
    template: BRDF,
    channels: list[str],
    *,
    step: str,
    what: str,
    fixed: dict,
    freed,
    max_nfev,
    progress,
    model_error: str,
    starts: int,
) -> FitResult:
    """f_r of every channel of a multi-channel ``table`` fitted at once in clear water
    (module docstring; docs/model.md sec. 2), ``step`` "reference" or "direct"."""
    datas = {c: prepare(table, black, f"{what}, channel {c}", channel=c) for c in channels}
    problem, layout = channel_problem(datas, template, fixed, freed, what)
    linear_free(problem)
    begin, n_grid = channel_starts(problem, "reference", starts, progress)
    outcome = run(
        problem,
        begin,
        accuracy=ITERATION_ACCURACY,
        max_nfev=max_nfev,
        progress=progress,
        every=True,
    )
    summary = summarize(problem, outcome)
    x = outcome.solution.x
    rep = reported(
        problem, x, summary, outcome.values, kind=model_error, floor=model_floor(template)
    )
    cls = type(template)
    return FitResult(
        model=cls.NAME,
        params={n: float(v) for n, v in zip(problem.names, x)},
        stderr=rep.stderr,
        correlation=rep.correlation,
        residuals=tuple(float(r) for r in summary.residuals),
        chi2_reduced=summary.chi2_reduced,
        rms_relative=summary.rms_relative,
        n_points=problem.n_points,
        converged=summary.converged,
        message=summary.message,
        variant=None,
        fixed={n: float(x[k]) for k, n in enumerate(problem.names) if not problem.free[k]},
        step=step,
        weighted=problem.weighted,
        accuracy=outcome.accuracy,
        stats=dict(outcome.stats, grid_points=n_grid),
        options=template.options(),
        determined=summary.determined,
        model_error=rep.model_error,
        channels=layout,
    )


__all__ = ["channel_layout", "layout_slots", "channel_problem", "channel_starts", "fit_channels"]
