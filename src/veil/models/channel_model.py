"""A model of several colour channels evaluated at once (docs/fitting.md, "Channels").

A fit over the channels r, g, b (or wavelengths) has one model per channel: the same family
and options, the parameters declared per channel its own, the shared ones equal.
:class:`ChannelModel` holds them in the channels' order; ``veil.reflectance`` and
``veil.apparent`` evaluate every channel of it at once and return the values with a
trailing channel axis (``values[..., k]`` is channel ``k``), the layout of the colour
images ``veil render`` writes.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

from ..errors import InputError, InputTypeError
from .base import Model


class ChannelModel:
    """The one-channel models of a fit over several channels, in the channels' order
    (module docstring): ``models`` maps each channel ("r", "g", "b" or a wavelength) to its
    model, all of one family with the same options.

    ``veil.reflectance(model, ...)`` and ``veil.apparent(model, medium, ...)`` give an array
    of the angles' broadcast shape plus a trailing axis of length ``len(model)``, channel
    ``model.channels[k]`` at ``[..., k]``; each channel's values are those of its one-channel
    model (``model[c]``, what ``as_model(channel=c)`` gives), bit for bit.
    """

    def __init__(self, models: Mapping[str, Model]):
        if not isinstance(models, Mapping) or not models:
            raise InputTypeError(
                f"ChannelModel: expected {{channel: model}} with at least one channel, "
                f"got {models!r}"
            )
        for c, m in models.items():
            if not isinstance(m, Model):
                raise InputTypeError(
                    f"ChannelModel: channel {c!r} maps to {m!r}; expected a model instance"
                )
        first = next(iter(models.values()))
        for c, m in models.items():
            if m.structure() != first.structure():
                raise InputError(
                    f"ChannelModel: channel {c!r} is {m}, channel "
                    f"{next(iter(models))!r} is {first}: the channels' models must be one "
                    f"family with the same options"
                )
        self._models = {str(c): m for c, m in models.items()}

    @property
    def channels(self) -> tuple[str, ...]:
        """The channels, in the order of the values' trailing axis."""
        return tuple(self._models)

    @property
    def models(self) -> dict[str, Model]:
        """{channel: its one-channel model} (a copy)."""
        return dict(self._models)

    @property
    def KIND(self) -> str:
        """The kind, "brdf" or "medium", as the channels' models."""
        return self.first.KIND

    @property
    def NAME(self) -> str:
        """The family's registry name."""
        return self.first.NAME

    @property
    def first(self) -> Model:
        """The first channel's model (the family, options and structure of every one)."""
        return next(iter(self._models.values()))

    def __getitem__(self, channel: str) -> Model:
        try:
            return self._models[str(channel)]
        except KeyError:
            raise InputError(
                f"no channel {channel!r}; the channels are {', '.join(self._models)}"
            ) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def __len__(self) -> int:
        return len(self._models)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ChannelModel):
            return NotImplemented
        return list(self._models.items()) == list(other._models.items())

    def __repr__(self) -> str:
        inner = ", ".join(f"{c}={m}" for c, m in self._models.items())
        return f"ChannelModel({inner})"

    __str__ = __repr__


def channels_of(*models: object) -> tuple[str, ...] | None:
    """The channels of the :class:`ChannelModel` among ``models`` (None when there is none);
    an InputError when two name different channels."""
    found = [m for m in models if isinstance(m, ChannelModel)]
    if not found:
        return None
    names = found[0].channels
    for other in found[1:]:
        if sorted(other.channels) != sorted(names):
            raise InputError(
                f"the models are of channels {', '.join(names)} and "
                f"{', '.join(other.channels)}: give models of the same channels"
            )
    return names


def channel_member(model: object, channel: str) -> object:
    """``model``'s model of ``channel`` when it is a :class:`ChannelModel`, else ``model``
    itself (a one-channel model is every channel's; None stays None)."""
    return model[channel] if isinstance(model, ChannelModel) else model


__all__ = ["ChannelModel", "channels_of", "channel_member"]
