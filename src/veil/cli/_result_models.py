"""The models of one or two result files, channel by channel, for the commands that take
fitted models rather than fit them (``veil export``, ``veil render``; docs/channels.md).

A result fitted over several channels gives one model per channel; with ``--channel NAME``
only that channel's. A result of one channel beside one of several is every channel's
model (a grey medium under a coloured plate, say). Models are keyed by channel, ``None``
for a one-channel export or render, which behaves exactly as before channels existed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ._common import UserError

if TYPE_CHECKING:
    from ..models import Model


@dataclass
class ResultModels:
    """{channel: model} of the BRDF and of the medium (None: not given), keyed ``None``
    when one channel is used; ``source`` names the files, ``notes`` says what was shared,
    ``brought`` {kind: the result file whose fit was made through (or against) that model}
    for a kind no file of its own gave."""

    brdf: dict | None
    medium: dict | None
    source: str
    channels: tuple
    notes: list = field(default_factory=list)
    brought: dict = field(default_factory=dict)
    #: {kind: (file, key of its parameters in it or None, its channels layout or None)}
    origin: dict = field(default_factory=dict)
    #: the channel of --channel (as a table names it), or None
    chosen: str | None = None

    @property
    def colour(self) -> bool:
        return self.channels != (None,)

    def where(self, kind: str, key, param: str) -> str:
        """Where parameter ``param`` of the ``kind`` model of channel ``key`` (a key of
        :attr:`brdf`, :attr:`medium`) is in its file: "FILE: key 'params.Ps[r]'"."""
        path, prefix, layout = self.origin[kind]
        channel = self.chosen if key is None else key
        if prefix is None:  # a joint fit's target: its parameters' names are its layout's
            return f"{path}: parameter {param}" + (f" of channel {channel}" if channel else "")
        name = (layout or {}).get(channel, {}).get(param, param)
        return f"{path}: key '{prefix}.{name}'"

    def one(self, kind: str) -> Model | None:
        """The one-channel model of ``kind`` (None when not given)."""
        models = self.brdf if kind == "brdf" else self.medium
        return None if models is None else models[None]


def _channels_of(result) -> tuple:
    return tuple(getattr(result, "channel_names", ()) or ())


def _keys(loaded, channel: str | None) -> tuple:
    """The channels to use: (None,) for one, else those every multi-channel result has."""
    from ..data.channels import channel_label

    if channel is not None:
        channel = channel_label(channel) or channel
    for path, result in loaded:
        names = _channels_of(result)
        if channel is not None and names and channel not in names:
            raise UserError(
                f"--channel {channel}: {path} is a fit of channels "
                f"{', '.join(names)}; it has no channel {channel!r}"
            )
    if channel is not None:
        _check_some_channels(loaded, channel)
        return (None,)
    multi = [(path, _channels_of(r)) for path, r in loaded if _channels_of(r)]
    if not multi:
        return (None,)
    (first_path, first), rest = multi[0], multi[1:]
    for path, names in rest:
        if sorted(names) != sorted(first):
            raise UserError(
                f"{first_path} is a fit of channels {', '.join(first)} and {path} "
                f"of channels {', '.join(names)}: give results of the same channels "
                f"(or one channel of both with --channel NAME)"
            )
    return first


def _check_some_channels(loaded, channel: str) -> None:
    """A UserError for ``--channel`` when no result is a fit of several channels (nor
    brings a model of several along, its ``given`` entry): there is no channel to choose."""
    for _, result in loaded:
        given = getattr(result, "given", None)
        if _channels_of(result) or (isinstance(given, dict) and given.get("channels")):
            return
    files = " and ".join(str(path) for path, _ in loaded)
    one = "is a fit" if len(loaded) == 1 else "are fits"
    raise UserError(
        f"--channel {channel}: {files} {one} of one channel, with no channels to choose "
        f"from; leave --channel out (it takes one channel of a result fitted over several)"
    )


def _model(result, key, channel):
    if _channels_of(result):
        return result.as_model(channel=channel if key is None else key)
    return result.as_model()


def result_models(
    result_path, other_path=None, channel: str | None = None, given: bool = True
) -> ResultModels:
    """The BRDF and medium of ``result_path`` and the optional ``other_path`` (one of each
    kind at most; with ``given``, a target result brings the medium it was fitted through, a
    medium result its reference BRDF), channel by channel (module docstring)."""
    from ..fitting.result import load_result

    loaded = [(result_path, load_result(result_path))]
    if other_path is not None:
        loaded.append((other_path, load_result(other_path)))
    keys = _keys(loaded, channel)
    brdf = medium = None
    notes = []
    origin = {}
    for path, result in loaded:
        models = {k: _model(result, k, channel) for k in keys}
        origin[next(iter(models.values())).KIND] = (
            (path, None, None) if result.JOINT else (path, "params", result.channels)
        )
        if keys != (None,) and not _channels_of(result):
            notes.append(f"{path} is a fit of one channel: its model is every channel's")
        kind = next(iter(models.values())).KIND
        if kind == "brdf":
            if brdf is not None:
                raise UserError(f"{path}: a second BRDF result; give one BRDF and one medium")
            brdf = models
        else:
            if medium is not None:
                raise UserError(f"{path}: a second medium result; give one BRDF and one medium")
            medium = models
    brought = {}
    if other_path is None and given:
        had = {"brdf": brdf is not None, "medium": medium is not None}
        brdf, medium = _with_given(loaded[0][1], keys, channel, brdf, medium)
        now = {"brdf": brdf is not None, "medium": medium is not None}
        brought = {kind: result_path for kind in had if now[kind] and not had[kind]}
        stored = loaded[0][1].given or {}
        origin.update(
            (kind, (result_path, "given.params", stored.get("channels"))) for kind in brought
        )
    source = str(result_path) + (f" and {other_path}" if other_path is not None else "")
    unconverged = [str(path) for path, result in loaded if not getattr(result, "converged", True)]
    for path, result in loaded:
        if not getattr(result, "converged", True):
            notes.append(unconverged_warning(result, path))
    if unconverged:
        source += f" (not converged: {', '.join(unconverged)})"
    from ..data.channels import channel_label

    chosen = None if channel is None else channel_label(channel) or channel
    return ResultModels(brdf, medium, source, keys, notes, brought, origin, chosen)


def unconverged_warning(result, path) -> str:
    """The warning for a ``result`` whose values are not all estimates
    (:func:`veil.fitting.result.unfinished`)."""
    from ..fitting.result import unfinished

    which = "its" if getattr(result, "determined", True) else "those"
    return f"warning: {path} is {unfinished(result)}: {which} values are not estimates"


def _with_given(result, keys, channel, brdf, medium):
    """(brdf, medium) completed by the model ``result`` was fitted through, if any."""
    if (
        not hasattr(result, "given_model")
        or result.given_model(channel if keys == (None,) else keys[0]) is None
    ):
        return brdf, medium
    given = {k: result.given_model(channel if k is None else k) for k in keys}
    kind = next(iter(given.values())).KIND
    if kind == "brdf" and brdf is None:
        brdf = given
    elif kind == "medium" and medium is None:
        medium = given
    return brdf, medium


__all__ = ["ResultModels", "result_models"]
