"""The joint fit over several colour channels (docs/channels.md, "The joint fit"; the joint
fit itself: :mod:`veil.fitting.joint`).

Sessions whose tables hold the same several channels (a ``channel`` column) are one
weighted least-squares problem: one :class:`~veil.fitting.problem.Block` per session and
channel, session after session and, within a session, channel after channel (in the
order of :func:`veil.data.channels.channel_order`). The slots are those of the joint fit
of one channel (:mod:`veil.fitting.joint_problem`) with every parameter that its family
declares per channel (``Param.channels``: albedos, scales, a medium's T_d and T_t or tau
and omega) taken once per channel, named ``NAME[channel]`` after its one-channel name
(``Pd[r]``, ``ref.Pd[r]``, ``Td[low][r]``); the others stay one slot tied across the
channels (``n``, ``g[low]``, ``eta_u``). A joint fit of one channel is that of
:mod:`veil.fitting.joint_problem`, unchanged.

The result's ``layout["channels"]`` holds, per channel, the ``objects`` and ``media`` maps
a joint fit of one channel holds at the top of its layout.
"""

from __future__ import annotations

import numpy as np

from ..errors import FitError
from ..models import Model
from .channel_steps import given_entry, given_layout
from .problem import Block, Problem, Session, Slot
from .result import FitResult, model_entry
from .session_data import channels_of


def session_channels(sessions: list[Session]) -> tuple[list[Session], list[str] | None]:
    """(the sessions, their tables loaded, the channels they hold) when some table holds
    several channels, each session then holding the same ones (a FitError naming two
    sessions that differ); (the sessions as given, None) when each table is of one channel
    (the joint fit of one channel, as before)."""
    found = []
    for s in sessions:
        table, channels = channels_of(s.table, s.name or "session")
        found.append((s, table, channels))
    several = next(((s, c) for s, _, c in found if c is not None and len(c) > 1), None)
    if several is None:
        _check_one_channel(found)
        return sessions, None
    first, channels = several
    for s, _, own in found:
        if own is None or set(own) != set(channels):
            held = "no channel column" if own is None else f"channels {', '.join(own)}"
            raise FitError(
                f"session {s.name!r} has {held} but session {first.name!r} has channels "
                f"{', '.join(channels)}: every session of a joint fit over channels is "
                f"measured in the same channels (or fit one channel with --channel NAME, "
                f"channel= in Python)"
            )
    loaded = [Session(t, s.medium, s.object, s.name, s.black) for s, t, _ in found]
    return loaded, channels


def _check_one_channel(found: list) -> None:
    """Tables of one channel each: those that name their channel name the same one (a
    FitError naming two sessions of different channels; a table without the column is of
    whichever channel the others name)."""
    named = [(s, c[0]) for s, _, c in found if c is not None]
    for s, c in named[1:]:
        if c != named[0][1]:
            first = named[0][0]
            raise FitError(
                f"session {s.name!r} is of channel {c} but session {first.name!r} of "
                f"channel {named[0][1]}: the sessions of a joint fit are measured in the "
                f"same channels"
            )


def expand_slots(
    params: list[Slot], sharing: dict[str, dict[str, str]], channels: list[str]
) -> tuple[list[Slot], dict[str, dict[str, str]]]:
    """(the slots of the fit over ``channels``, {channel: {one-channel slot name: its name in
    that channel}}): a slot of a parameter declared per channel (``sharing[kind][name]``,
    :meth:`veil.models.Model.channel_sharing`) once per channel, ``NAME[channel]``, in
    place; the others as they are."""
    out: list[Slot] = []
    names: dict[str, dict[str, str]] = {c: {} for c in channels}
    for s in params:
        if sharing[s.kind][s.spec.name] == "shared":
            out.append(s)
            for c in channels:
                names[c][s.name] = s.name
            continue
        for c in channels:
            name = f"{s.name}[{c}]"
            out.append(Slot(name, s.kind, s.owner, s.index, s.spec, s.scale))
            names[c][s.name] = name
    return out, names


def channel_layouts(objects: dict, media: dict, names: dict) -> dict:
    """{channel: {"objects": ..., "media": ...}}: the one-channel layout's maps with each
    channel's names (``names`` of :func:`expand_slots`)."""
    return {
        c: {
            "objects": {o: {p: own[n] for p, n in m.items()} for o, m in objects.items()},
            "media": {label: {p: own[n] for p, n in m.items()} for label, m in media.items()},
        }
        for c, own in names.items()
    }


def expand_names(entries, params: list[Slot], names: dict) -> dict | list | None:
    """``fixed`` ({name: value}) or ``free`` (names) of a fit over channels with each
    one-channel name of a parameter per channel replaced by every channel's (``Td[low]``
    holds ``Td[low][r]``, ``Td[low][g]``, ...); a channel's own name (``Td[low][r]``) and
    a tied name stay, the own name's value winning over the one-channel name's; an unknown
    one is left for the checks to name."""
    if entries is None:
        return None
    have = {s.name for s in params}

    def each(name: str) -> list[str]:
        if name in have:
            return [name]
        found = list(dict.fromkeys(own[name] for own in names.values() if name in own))
        return found or [name]

    if isinstance(entries, dict):
        # a channel's own name wins over its parameter's one-channel name, in any order
        out = {n: v for name, v in entries.items() if name not in have for n in each(name)}
        out.update({name: v for name, v in entries.items() if name in have})
        return out
    return [n for name in entries for n in each(name)]


def reference_models(reference, channels: list[str]) -> tuple[dict[str, Model], dict]:
    """({channel: the given reference's model}, {name in the given fit: (channel,
    parameter)}): a fit over the same channels gives each channel's model, a model is every
    channel's; a fit of one channel or of other channels is a FitError
    (:func:`veil.fitting.channel_steps.given_layout`)."""
    _, _, layout, models = given_layout(
        reference, "brdf", channels, "the reference", "each session"
    )
    names = {n: (c, p) for c in channels for p, n in layout[c].items()}
    return models, names


def reference_names(layout: dict, reference) -> dict:
    """{name of a parameter in the given reference: its name in the joint fit} (the
    reference's covariance enters the joint fit's by these)."""
    if "channels" not in layout:
        return dict(layout["objects"].get("reference", {}))
    out = {}
    by_channel = reference.channels if isinstance(reference, FitResult) else None
    for c, maps in layout["channels"].items():
        for p, name in maps["objects"].get("reference", {}).items():
            out[p if by_channel is None else by_channel[c][p]] = name
    return out


def reference_entry(reference, layout: dict) -> dict | None:
    """The result's ``given`` key of the reference held fixed (None when not given)."""
    if reference is None:
        return None
    if "channels" not in layout:
        from .given import as_given

        return model_entry(as_given(reference, "brdf", "the reference"))
    models, _ = reference_models(reference, list(layout["channels"]))
    return given_entry(reference, models)


def block_channels(problem: Problem, layout: dict) -> list[str | None]:
    """The channel of each block of a joint problem (None for a fit of one channel): the
    blocks run session after session, channel after channel (module docstring)."""
    channels = list(layout.get("channels") or ())
    if not channels:
        return [None] * len(problem.blocks)
    return [channels[k % len(channels)] for k in range(len(problem.blocks))]


def channel_view(problem: Problem, layout: dict, channel: str) -> tuple[Problem, dict, list[int]]:
    """The joint problem of one ``channel`` (its blocks and slots, sharing their engines),
    its one-channel layout, and the joint problem's index of each of its slots."""
    maps = layout["channels"][channel]
    names = [n for part in ("objects", "media") for m in maps[part].values() for n in m.values()]
    cols = sorted({problem.index(n) for n in names})
    pos = {g: j for j, g in enumerate(cols)}
    blocks = [
        Block(
            b.session,
            b.data,
            np.array([pos[int(k)] for k in b.ib]),
            None if b.im is None else np.array([pos[int(k)] for k in b.im]),
            b.brdf,
            b.medium,
            b.models,
        )
        for b, c in zip(problem.blocks, block_channels(problem, layout))
        if c == channel
    ]
    sub = Problem(
        blocks,
        [problem.params[g] for g in cols],
        problem.values[cols],
        problem.free[cols],
        weighted=problem.weighted,
    )
    own = {k: v for k, v in layout.items() if k != "channels"}
    return sub, dict(own, objects=maps["objects"], media=maps["media"]), cols


def channel_starts(problem: Problem, layout: dict, starts_of) -> list[np.ndarray]:
    """Starting vectors of a joint fit over channels, best first: each channel's own
    (``starts_of(problem, layout)`` of its :func:`channel_view`, the joint fit's starts of
    one channel), the k-th of every channel together; a slot tied across the channels takes
    their mean."""
    found = []
    for c in layout["channels"]:
        sub, own, cols = channel_view(problem, layout, c)
        found.append((cols, starts_of(sub, own)))
    out = []
    for k in range(min(len(starts) for _, starts in found)):
        x = problem.values.copy()
        values: dict[int, list[float]] = {}
        for cols, starts in found:
            for j, g in enumerate(cols):
                values.setdefault(g, []).append(float(starts[k][j]))
        for g, vals in values.items():
            if problem.free[g]:
                x[g] = float(np.mean(vals))
        out.append(x)
    return out


__all__ = [
    "session_channels",
    "expand_slots",
    "channel_layouts",
    "expand_names",
    "reference_models",
    "reference_names",
    "reference_entry",
    "block_channels",
    "channel_view",
    "channel_starts",
]
