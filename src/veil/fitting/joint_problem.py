"""The problem of a joint fit (:mod:`veil.fitting.joint`): its sessions read and checked
(media, objects, overlapping configurations, enough held to anchor the scales), the
parameters' slots - each object's f_r shared by its sessions, each medium's own, the
shareable ones shared or per medium as declared - and the stacked
:class:`~veil.fitting.problem.Problem`."""

from __future__ import annotations

import math

import numpy as np

from ..engine.angles import direction
from ..errors import FitError, InputError
from ..models import default_class, model_class
from ..models.base import VARIANT_OPTION
from .arguments import as_names, as_options, refuse_fixed_and_freed
from .channel_steps import shared_engines
from .given import as_given
from .joint_channels import (
    channel_layouts,
    expand_names,
    expand_slots,
    reference_models,
    session_channels,
)
from .problem import OBJECTS, Block, Problem, Session, model_slots
from .session_data import prepare
from .solver import as_fixed, check_fixed

#: Two configurations closer than this (deg, for both I and R) are the same one when
#: checking that sessions overlap (the black-cloth matching tolerance).
OVERLAP_TOL = 0.05


def as_sessions(sessions) -> list[Session]:
    """Sessions from a list of :class:`Session` / (table, medium[, object]) tuples, or a dict
    {medium label: target table}."""
    import pandas as pd

    if isinstance(sessions, dict):
        sessions = [Session(t, m, "target") for m, t in sessions.items()]
    if isinstance(sessions, (Session, pd.DataFrame, str)) or sessions is None:
        raise FitError(
            "sessions: expected a list of Session(table, medium, object) or a dict "
            "{medium label: target table}"
        )
    out = []
    for s in sessions:
        if isinstance(s, Session):
            out.append(s)
        elif isinstance(s, tuple) and 2 <= len(s) <= 3:
            out.append(Session(*s))
        else:
            raise FitError(
                f"sessions: {s!r} is neither a Session nor a (table, medium[, object]) tuple"
            )
    if not out:
        raise FitError(
            "no sessions given: a joint fit needs at least one session of the "
            "target measured in a medium"
        )
    return out


def shareable(medium_cls) -> tuple[str, ...]:
    """The medium's parameters (keys) that media may share, as declared."""
    return tuple(p.key for p in medium_cls.PARAMS if p.share is not None)


def _declarations(medium_cls, brdf_cls, shared, per_medium) -> tuple[str, ...]:
    """Which shareable medium parameters the media share (checked; contradictions are
    errors); by default those the model declares shared."""
    able = shareable(medium_cls)

    def names(arg, what):
        arg = as_names(arg, what)
        if arg is None:
            return None
        for a in arg:
            spec = next((p for p in medium_cls.PARAMS if a in (p.name, p.key)), None)
            if spec is not None and spec.key != a and a in brdf_cls.param_names():
                raise FitError(
                    f"{what} lists {a!r}: the medium's {a} is called {spec.key!r} "
                    f"here ({a!r} is the target's); choose among {', '.join(able)}"
                )
            if spec is not None and spec.share is None:
                raise FitError(
                    f"{what} lists {a!r}: {spec.key} is always per medium (each "
                    f"medium or concentration has its own); only "
                    f"{' and '.join(able)} can be shared"
                )
            if a not in able:
                raise FitError(
                    f"{what} lists {a!r}: not a medium parameter that can be shared; "
                    f"choose among {', '.join(able)}"
                )
        dup = [a for a in set(arg) if arg.count(a) > 1]
        if dup:
            raise FitError(f"{what} lists {dup[0]!r} twice")
        return arg

    s, p = names(shared, "shared"), names(per_medium, "per_medium")
    if s is not None and p is not None:
        both = [a for a in s if a in p]
        if both:
            raise FitError(
                f"contradictory sharing declarations: {', '.join(both)} declared "
                f"both shared by the media and free per medium; declare each of "
                f"{', '.join(able)} once"
            )
    if s is None and p is None:
        return tuple(q.key for q in medium_cls.PARAMS if q.share == "shared")
    if s is None:
        return tuple(a for a in able if a not in p)
    return tuple(a for a in able if a in s)


def _unit_vectors(angles) -> np.ndarray:
    ti, pi_, tr, pr = angles
    return np.concatenate([np.asarray(direction(ti, pi_)), np.asarray(direction(tr, pr))], axis=1)


def _check_overlap(sessions, datas) -> None:
    """Every session must share a configuration with another (module constant OVERLAP_TOL)."""
    if len(sessions) < 2:
        return
    from scipy.spatial import cKDTree

    vecs = [_unit_vectors(d.angles) for d in datas]
    radius = 2.0 * math.sqrt(2.0) * math.sin(math.radians(OVERLAP_TOL) / 2.0) * (1 + 1e-9)
    for k, s in enumerate(sessions):
        others = np.concatenate([v for j, v in enumerate(vecs) if j != k])
        dist, _ = cKDTree(others).query(vecs[k], k=1)
        if not np.any(dist <= radius):
            raise FitError(
                f"session {s.name!r} shares no configuration (within {OVERLAP_TOL:g} deg) with "
                f"any other session: a joint fit compares the same object or medium under "
                f"the same configurations; check its angle columns (degrees, docs/model.md sec. 1)"
            )


def _anchor_check(
    sessions, fixed_names, reference_given, params, brdf_cls, medium_cls, channel=None
) -> None:
    """The overall scale (the BRDF's scales times the medium's, docs/model.md sec. 2-3) must be
    pinned in every connected set of objects and media (of each ``channel``: ``params``
    that channel's slots), or the fit has an exact degeneracy."""
    parent: dict = {}

    def find(a):
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    for s in sessions:
        find(("obj", s.object))
        if not s.clear:
            parent[find(("obj", s.object))] = find(("med", s.medium))
    anchored = set()
    for s in sessions:
        if s.clear:
            anchored.add(find(("obj", s.object)))
    if reference_given and any(s.object == "reference" for s in sessions):
        anchored.add(find(("obj", "reference")))
    for p in params:
        if p.name in fixed_names and p.scale:
            key = ("obj", p.owner) if p.kind == "brdf" else ("med", p.owner)
            anchored.add(find(key))
    if not brdf_cls.SCALES or not (medium_cls.SCALES or medium_cls.GAIN):
        return  # a model without scales pins the overall scale itself
    roots = {find(("obj", s.object)) for s in sessions}
    for r in roots:
        if r not in anchored:
            members = sorted(
                f"{a[0] == 'obj' and 'object' or 'medium'} {a[1]}" for a in parent if find(a) == r
            )
            scale_m = next(iter(medium_cls.scale_names() or (medium_cls.GAIN,)))
            raise FitError(
                f"the overall scale is not determined"
                f"{'' if channel is None else f' in channel {channel}'} for "
                f"{', '.join(members)}: the apparent "
                f"value is proportional to the object's scales "
                f"({', '.join(brdf_cls.scale_names())}) times the medium's "
                f"({', '.join(medium_cls.scale_names() or (medium_cls.GAIN,))}), so scaling "
                f"the media up and "
                f"the object down fits equally well (docs/model.md sec. 2-3). Add the reference "
                f"measured in clear water (object 'reference', medium 'none') and in the "
                f"media, give reference=, or fix one scale, e.g. "
                f"fixed={{'{scale_m}[label]': ...}} (--fix '{scale_m}[label]=...')"
            )


def _check_sessions(sessions) -> list:
    """The media of a joint fit's sessions, checked: a target through a medium, one
    session per object and medium, a target session in every medium."""
    if not any(s.object == "target" for s in sessions):
        raise FitError(
            "no session of the target: a joint fit estimates the target object "
            "through the media; add at least one session with object 'target'"
        )
    if not any(s.object == "target" and not s.clear for s in sessions):
        raise FitError(
            "every target session is in clear water: there is no medium to fit "
            "jointly; fit the target's f_r directly with veil fit reference "
            "(veil.fit_reference) instead"
        )
    seen: dict[tuple, str] = {}
    for s in sessions:
        key = (s.object, s.medium)
        if key in seen:
            raise FitError(
                f"two sessions of the {s.object} in medium {s.medium!r} (object "
                f"{s.object!r}, medium {s.medium!r}): {seen[key]!r} and {s.name!r}; merge "
                f"them into one table"
            )
        seen[key] = s.name
    media = list(dict.fromkeys(s.medium for s in sessions if not s.clear))
    for m in media:
        if not any(s.medium == m and s.object == "target" for s in sessions):
            raise FitError(
                f"medium {m!r} has a session of the reference (object 'reference', medium "
                f"{m!r}) but none of the target (object 'target', medium {m!r}): "
                f"every medium of a joint fit must have a session of the target "
                f"(fit that medium alone with veil fit medium)"
            )
    return media


def _reference_of(reference, bcls, sessions, channels=None) -> dict | None:
    """The reference's given BRDF by channel ({None: model} for a fit of one channel; None
    when not given), checked against the sessions."""
    ref_sessions = [s for s in sessions if s.object == "reference"]
    if reference is None:
        if ref_sessions and not any(s.clear for s in ref_sessions):
            raise FitError(
                "reference sessions in a medium need the reference's f_r: give "
                "reference= (the step-0 result or a BRDF model) or add its "
                "clear-water session (object 'reference', medium 'none')"
            )
        return None
    models: dict = (
        {None: as_given(reference, "brdf", "the reference")}
        if channels is None
        else reference_models(reference, channels)[0]
    )
    for model in models.values():
        if type(model) is not bcls:
            raise FitError(
                f"the reference is a {model.NAME} model but the joint fit "
                f"uses the BRDF family {bcls.NAME} for its objects"
            )
    if not ref_sessions:
        raise FitError(
            "reference= given but no session of the reference object: the "
            "reference's f_r only matters through its sessions (object "
            "'reference')"
        )
    return models


def _slots(bcls, mcls, sessions, media, shared_names) -> tuple[list, dict, dict]:
    """(the joint fit's parameter slots, {object: {parameter: slot}}, {medium: {parameter
    key: slot}}): one BRDF per object, the medium's shared parameters once, the others per
    medium."""
    params = []
    objects_layout: dict = {}
    for obj, prefix in zip(OBJECTS, ("", "ref.")):
        if not any(s.object == obj for s in sessions):
            continue
        slots = model_slots(bcls, "brdf", obj, lambda p, prefix=prefix: prefix + p.key)
        params += slots
        objects_layout[obj] = {p.name: s.name for p, s in zip(bcls.PARAMS, slots)}
    media_layout: dict = {m: {} for m in media}
    if media:
        params += [s for s in model_slots(mcls, "medium", "*") if s.name in shared_names]
    for m in media:
        slots = model_slots(mcls, "medium", m, lambda p, m=m: f"{p.key}[{m}]")
        for p, s in zip(mcls.PARAMS, slots):
            if p.key in shared_names:
                media_layout[m][p.key] = p.key
            else:
                params.append(s)
                media_layout[m][p.key] = s.name
    return params, objects_layout, media_layout


def _fixed_and_freed(
    params, fixed, free, mcls, shared_names
) -> tuple[dict, np.ndarray, np.ndarray]:
    """(the fixed values checked, the starting values, which slots are free) from ``fixed``
    and the held parameters to ``free``."""
    names = [p.name for p in params]
    index = {n: k for k, n in enumerate(names)}
    fixed = as_fixed(fixed)
    for k, v in fixed.items():
        if k not in index:
            hint = ""
            if k in shareable(mcls) and k not in shared_names:
                hint = f" ({k} is free per medium here: fix {k}[label] for each medium)"
            raise FitError(
                f"cannot fix {k!r}: the joint fit's parameters are {', '.join(names)}{hint}"
            )
        check_fixed(k, v, params[index[k]].spec, k)
    values = np.array([p.spec.start for p in params], dtype=float)
    freed = list(free or ())
    unknown = [n for n in freed if n not in index]
    if unknown:
        raise FitError(
            f"cannot free {', '.join(map(repr, unknown))}: the joint fit's "
            f"parameters are {', '.join(names)}"
        )
    refuse_fixed_and_freed(fixed, freed)
    free = np.array([not p.spec.held or p.name in freed for p in params], dtype=bool)
    return fixed, values, free


def _templates(brdf_model, medium_model, brdf_options, medium_options, variant) -> tuple:
    """The BRDF's and the medium's family, and each at its starting values with its
    options."""
    bcls = default_class("brdf") if brdf_model is None else model_class(brdf_model, "brdf")
    mcls = default_class("medium") if medium_model is None else model_class(medium_model, "medium")
    medium_options = as_options(medium_options, "medium_options")
    if variant is not None:
        medium_options[VARIANT_OPTION] = variant
    try:
        return (
            bcls,
            mcls,
            bcls.template(**as_options(brdf_options, "brdf_options")),
            mcls.template(**medium_options),
        )
    except InputError as exc:
        raise FitError(str(exc)) from None


def _hold(
    values: np.ndarray,
    free: np.ndarray,
    fixed: dict,
    index: dict,
    references: list,
) -> None:
    """Hold the ``fixed`` values and a given reference's parameters (as a whole):
    ``references`` pairs each objects' map (of a channel) with the reference's model
    there."""
    for objects_layout, reference_model in references:
        for pname, gname in objects_layout["reference"].items():
            if gname in fixed:
                raise FitError(
                    f"cannot fix {gname!r}: the reference is given (reference=) "
                    f"and held fixed as a whole"
                )
            values[index[gname]] = getattr(reference_model, pname)
            free[index[gname]] = False
    for k, v in fixed.items():
        values[index[k]] = float(v)
        free[index[k]] = False


def _datas(sessions, channel, channels) -> list[dict]:
    """Each session's data by channel ({channel: data}; {None: data} of one channel, or of
    the one ``channel`` chosen), one
    weighting for all (a FitError naming the sessions without sigma otherwise), every
    session sharing a configuration with another."""
    picks = channels or [channel]
    datas = [
        {(c if channels else None): prepare(s.table, s.black, s.name, channel=c) for c in picks}
        for s in sessions
    ]
    weighted = {d.sigma is not None for by in datas for d in by.values()}
    if len(weighted) > 1:
        which = [
            s.name for s, by in zip(sessions, datas) if any(d.sigma is None for d in by.values())
        ]
        raise FitError(
            f"session(s) {', '.join(which)} have no sigma column but the others "
            f"do: weighted and unweighted residuals cannot be mixed in one fit; "
            f"give every session a sigma column or none"
        )
    _check_overlap(sessions, [next(iter(by.values())) for by in datas])
    return datas


def _blocks(sessions, datas, index, maps, mcls, templates) -> list[Block]:
    """The blocks: session after session, and of several channels channel after channel,
    the channels of a session sharing their engines (``maps`` {channel: {"objects",
    "media"}}, {None: ...} of one channel)."""
    template_b, template_m = templates
    blocks = []
    for s, by_channel in zip(sessions, datas):
        engines = shared_engines()
        for c, d in by_channel.items():
            objects, media = maps[c]["objects"], maps[c]["media"]
            ib = np.array([index[n] for n in objects[s.object].values()])
            medium = None if s.clear else template_m
            im = None if s.clear else np.array([index[media[s.medium][p.key]] for p in mcls.PARAMS])
            if c is None:  # one channel: the session as given
                blocks.append(Block(s, d, ib, im, template_b, medium))
                continue
            session = Session(d.table, s.medium, s.object, name=f"{s.name}, channel {c}")
            shared = engines(d, template_b, medium)
            blocks.append(Block(session, d, ib, im, template_b, medium, shared))
    return blocks


def build(
    sessions,
    *,
    reference=None,
    shared=None,
    per_medium=None,
    fixed=None,
    variant: str | None = None,
    brdf_model=None,
    medium_model=None,
    brdf_options=None,
    medium_options=None,
    free=None,
    channel: str | None = None,
) -> tuple[Problem, dict]:
    """The stacked :class:`Problem` of a joint fit and its layout (see
    :func:`veil.fitting.joint.fit_joint`); of every channel of tables with several, or of
    ``channel`` (:mod:`veil.fitting.joint_channels`)."""
    free = as_names(free, "free")
    bcls, mcls, template_b, template_m = _templates(
        brdf_model, medium_model, brdf_options, medium_options, variant
    )
    sessions = as_sessions(sessions)
    shared_names = _declarations(mcls, bcls, shared, per_medium)
    media = _check_sessions(sessions)
    channels = None
    if channel is None:
        sessions, channels = session_channels(sessions)
    references = _reference_of(reference, bcls, sessions, channels)
    datas = _datas(sessions, channel, channels)

    params, objects_layout, media_layout = _slots(bcls, mcls, sessions, media, shared_names)
    maps: dict = {None: {"objects": objects_layout, "media": media_layout}}
    if channels is not None:
        sharing = {"brdf": bcls.channel_sharing(), "medium": mcls.channel_sharing()}
        params, names = expand_slots(params, sharing, channels)
        maps = channel_layouts(objects_layout, media_layout, names)
        fixed = expand_names(fixed, params, names) if isinstance(fixed, dict) else fixed
        free = expand_names(free, params, names) if free is not None else None
    index = {p.name: k for k, p in enumerate(params)}

    fixed, values, free = _fixed_and_freed(params, fixed, free, mcls, shared_names)
    pairs = [(maps[c]["objects"], m) for c, m in (references or {}).items()]
    _hold(values, free, fixed, index, pairs)
    if not free.any():
        raise FitError("every parameter of the joint fit is fixed: nothing to fit")
    held = {p.name for p, f in zip(params, free) if not f}
    for c, m in maps.items():
        own = {n for part in m.values() for names_ in part.values() for n in names_.values()}
        mine = params if c is None else [p for p in params if p.name in own]
        _anchor_check(sessions, held, references is not None, mine, bcls, mcls, c)

    blocks = _blocks(sessions, datas, index, maps, mcls, (template_b, template_m))
    weighted = next(iter(datas[0].values())).sigma is not None  # one for all (_datas)
    problem = Problem(blocks, params, values, free, weighted=weighted)
    if problem.n_points <= problem.n_free:
        raise FitError(
            f"the sessions have {problem.n_points} points but the joint fit has "
            f"{problem.n_free} free parameters: measure more configurations or fix "
            f"some"
        )
    layout = {
        "models": {"brdf": bcls.NAME, "medium": mcls.NAME},
        "options": {"brdf": template_b.options(), "medium": template_m.options()},
        **(maps[None] if channels is None else {"channels": maps}),
        "shared": list(shared_names),
        "reference_given": references is not None,
    }
    return problem, layout


__all__ = ["as_sessions", "shareable", "build", "OVERLAP_TOL"]
