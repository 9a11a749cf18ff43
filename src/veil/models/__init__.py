"""Model registry: every BRDF and BTDF veil knows, by name, and the paper's presets.

Adding a model is one new module with a frozen dataclass (see :mod:`veil.models.base`) and
one line in ``REGISTRY``.
"""

from __future__ import annotations

from ..errors import InputError
from .base import BRDF, BTDF, Model, Param
from .henyey_greenstein import HenyeyGreenstein
from .torrance_sparrow import TorranceSparrow

REGISTRY: dict[str, type[Model]] = {
    TorranceSparrow.NAME: TorranceSparrow,
    HenyeyGreenstein.NAME: HenyeyGreenstein,
}

#: The paper's simulated objects (Table 2) and media (Table 3), MODEL.md sec. 6.
PRESETS: dict[str, Model] = {
    "BRDF1": TorranceSparrow(Pd=2.00e2, Ps=5.00e5, n=0.80, eta=1.55),
    "BRDF2": TorranceSparrow(Pd=1.00e3, Ps=5.00e5, n=0.50, eta=1.55),
    "BTDF1": HenyeyGreenstein(Td=1.00e-3, Tt=0.01, g=0.98, eta=1.3),
    "BTDF2": HenyeyGreenstein(Td=1.00e-3, Tt=0.13, g=0.93, eta=1.3),
    "BTDF3": HenyeyGreenstein(Td=1.00e-3, Tt=0.38, g=0.88, eta=1.3),
}


def model_class(name: str) -> type[Model]:
    try:
        return REGISTRY[name]
    except KeyError:
        raise InputError(f"unknown model {name!r}; known: {', '.join(sorted(REGISTRY))}") from None


def preset(name: str) -> Model:
    try:
        return PRESETS[name.upper()]
    except KeyError:
        raise InputError(f"unknown preset {name!r}; known: {', '.join(PRESETS)}") from None


__all__ = ["BRDF", "BTDF", "Model", "Param", "TorranceSparrow", "HenyeyGreenstein",
           "REGISTRY", "PRESETS", "model_class", "preset"]
