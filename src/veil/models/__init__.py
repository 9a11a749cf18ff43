"""Models: what each family declares (:mod:`.base`), the registry and the paper's presets
(:mod:`.registry`), the physics they share (:mod:`.fresnel`, :mod:`.phase`) and one module
per family."""

from __future__ import annotations

from .base import BRDF, BTDF, Medium, Model, Option, Param
from .channel_model import ChannelModel
from .registry import (
    APPARATUS_OPTIONS,
    AUTO,
    DEFAULTS,
    PAPER,
    PRESETS,
    REGISTRY,
    candidates,
    default_class,
    model_class,
    names,
    preset,
    register,
)

__all__ = [
    "BRDF",
    "BTDF",
    "Medium",
    "Model",
    "Option",
    "Param",
    "ChannelModel",
    "REGISTRY",
    "PRESETS",
    "DEFAULTS",
    "AUTO",
    "PAPER",
    "APPARATUS_OPTIONS",
    "candidates",
    "model_class",
    "default_class",
    "names",
    "preset",
    "register",
]
