"""Maps of several colour channels at once (docs/maps-channels.md; ``veil fit maps
--channel rgb``): which channels a run fits, the medium of each channel, the family's
parameters checked for a fit over channels, and the tables of every channel.

Every pixel's channels are one least-squares problem: the BRDF's parameters declared per
channel (``Param.channels``; its scales, the albedos and specular scales) take one value per
channel, the shared ones (roughness, index) one tied across the channels, as in the single
fits over channels (:mod:`veil.fitting.channel_fit`). For fixed configurations the apparent
value is linear in the scales, so a channel's columns are the term matrices of the engine
weighted by that channel's medium row weights (its scales, :func:`veil.engine.integrator.
row_scales`): the term matrices depend only on the non-scale parameters
(:func:`veil.engine.integrator.unit_scale_indices`), so channels whose media differ only in
scales (the paper medium's T_d and T_t) share one engine evaluation per node of the table.
"""

from __future__ import annotations

from typing import Any, cast

from ..data.ingest_channels import ALL_RGB
from ..errors import FitError, InputError
from ..models import Medium
from .photos import stacked_channels
from .tables import MapTables, tabulate


def channel_media(medium, channels: tuple[str, ...]) -> dict[str, Medium]:
    """{channel: its medium model} of ``medium``: a step-1 result fitted over the same
    channels gives each channel's model, a medium model is every channel's; a result of one
    channel, or of other channels, is an InputError naming both."""
    from ..fitting.channel_steps import given_layout

    try:
        models = given_layout(medium, "medium", list(channels), "the medium", "the photos")[3]
    except FitError as exc:
        raise InputError(f"--channel {'/'.join(channels)}: {exc}") from None
    return {c: cast(Medium, m) for c, m in models.items()}


def one_channel_medium(medium, channel: str) -> Any:
    """The medium of a map of one ``channel``: that channel's model of a result fitted over
    several (an InputError naming its channels when it has not that one), else ``medium``
    itself (checked by the caller as before channels existed)."""
    channels = getattr(medium, "channel_names", ())
    if not channels or getattr(medium, "JOINT", False):
        return medium
    if channel not in channels:
        raise InputError(
            f"the medium is a fit of channels {', '.join(channels)}, which has no channel "
            f"{channel!r}; map one of {', '.join(channels)} (--channel NAME), all of them "
            f"(--channel {ALL_RGB}), or give a medium fitted over {channel!r}"
        )
    return medium.one_model(channel)


def map_media(medium, channel) -> tuple[Medium, dict[str, Medium] | None]:
    """(the medium model, {channel: medium model} or None) of a map of ``channel``: over
    several channels each channel's (:func:`channel_media`), the first as the medium model;
    of one channel its model (:func:`one_channel_medium`, checked by kind)."""
    from ..fitting.given import as_given

    channels = stacked_channels(channel)
    if channels:
        media = channel_media(medium, channels)
        return next(iter(media.values())), media
    return cast(Medium, as_given(one_channel_medium(medium, channel), "medium", "the medium")), None


def check_family(brdf_cls, fixed: dict, freed: set) -> None:
    """A map over channels fits each channel's scales and shares the rest: a free parameter
    declared per channel that is not a scale (a conductor's complex index), or a scale
    declared shared, is an InputError saying what to fix."""
    sharing = brdf_cls.channel_sharing()
    scales = set(brdf_cls.scale_names())
    for p in brdf_cls.PARAMS:
        if p.name in fixed or (p.held and p.name not in freed):
            continue
        if sharing[p.name] == "per-channel" and p.name not in scales:
            raise InputError(
                f"{brdf_cls.NAME}.{p.name} is declared per channel and is not a scale: a map "
                f"over channels fits only the scales per channel; fix it "
                f"(--fix {p.name}=VALUE, the same in every channel) or map one channel"
            )
        if sharing[p.name] == "shared" and p.name in scales:
            raise InputError(
                f"{brdf_cls.NAME}.{p.name} is a scale declared shared across channels; a "
                f"map over channels fits every scale per channel: fix it or map one channel"
            )


def build_channel_tables(
    brdf_cls,
    media: dict[str, Medium],
    angles,
    *,
    fixed=None,
    options=None,
    free=None,
    grid=None,
    accuracy: str = "default",
    progress=None,
    near=None,
    roi=None,
    field=None,
) -> MapTables:
    """The tables of a map over the channels of ``media`` ({channel: medium model}): as
    :func:`veil.maps.tables.build_tables`, with a channel axis before the configurations'
    (each channel through its medium); the engine runs once per node for every group of
    channels whose media differ only in scales (module docstring). ``near`` and ``roi``:
    near-field tables as :func:`~veil.maps.tables.build_tables`', every channel at the
    field nodes' angles (docs/maps-geometry.md "Geometry"), over ``field`` when given."""
    fixed = dict(fixed or {})
    check_family(brdf_cls, fixed, set(free or ()))
    entry = media_entry(media)
    settings = (fixed, options, free, grid, accuracy, progress, near, roi, field)
    u, values, coef, angles, near_entries = tabulate(brdf_cls, dict(media), angles, *settings)
    return MapTables(
        brdf_cls.NAME,
        dict(u.template.options()),
        brdf_cls.param_names(),
        u.base,
        u.free_scales,
        u.axes,
        values,
        coef,
        fixed,
        entry,
        accuracy,
        angles,
        channels=tuple(media),
        **near_entries,
    )


def media_entry(media: dict[str, Medium]) -> dict[str, Any]:
    """The tables' (and the store's) record of the channels' media: the family, its
    options and each channel's parameters."""
    first = next(iter(media.values()))
    kinds = {type(m).NAME for m in media.values()}
    if len(kinds) != 1:
        raise InputError(
            f"the channels' media are of several families ({', '.join(sorted(kinds))}); a "
            f"map over channels takes one family"
        )
    return {
        "model": type(first).NAME,
        "options": first.options(),
        "channels": {c: m.as_dict() for c, m in media.items()},
    }


__all__ = [
    "ALL_RGB",
    "channel_media",
    "one_channel_medium",
    "map_media",
    "check_family",
    "build_channel_tables",
    "media_entry",
]
