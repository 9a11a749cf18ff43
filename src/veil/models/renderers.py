"""How a model family says what a renderer's own plugin expresses it (docs/interop.md).

A family declares, next to its parameters, a class attribute

    RENDERERS = {"mitsuba": function(model, setting) -> Plugin, "pbrt": ...}

for the renderers that have the same model (Mitsuba 3's ``roughplastic``, pbrt-v4's
``conductor``, a homogeneous medium with a Henyey-Greenstein phase function), and/or

    PROXIES = {"mitsuba": ("family-name", {options}), ...}

for a renderer that has no such model: the exporter (:mod:`veil.interop`) then fits the named
family to the model's f_r and exports that, with the RMS difference. A renderer in neither
is refused with :class:`Unsupported` (exit status 2) and the function may refuse particular
values (an option the renderer lacks) the same way. Everything renderer-specific - plugin and
parameter names, unit and convention changes, what the conversion loses - lives in the
family's module; :mod:`veil.interop` only writes the :class:`Plugin` out (XML, Python dict,
pbrt scene text) and so stays the same when a family is added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import SupportsFloat, cast

from ..errors import InputError

RENDERER_NAMES = ("mitsuba", "pbrt")
#: Kinds of a plugin parameter: how the writers spell it.
VALUE_KINDS = ("float", "boolean", "string", "spectrum", "rgb")
#: The keys of a plugin's ``geometry``: one pass through the medium (scene units) and the
#: plate's half width.
GEOMETRY_LENGTH = "path_length"
GEOMETRY_HALF_WIDTH = "plate_half_width"
#: Largest magnitude a renderer reads: Mitsuba 3 and pbrt-v4 store their parameters as 32-bit
#: floats, in which anything above is infinite.
RENDERER_MAX = 3.4028234663852886e38


class Unsupported(InputError):
    """The renderer cannot express this model (or this value of one of its options)."""


@dataclass(frozen=True)
class Setting:
    """What the user gave the exporter besides the models.

    scale : intensity scale to divide out of a model's relative scale parameters (veil's
        rho, ks, P_d, P_s are products with the light's intensity and the camera's gain);
        None lets the family choose (its specular scale, so that the interface is physical).
    ext_ior : refractive index of the medium around the surface in the renderer's scene
        (plugins that take absolute indices get relative index x ext_ior).
    path_length : length of one pass through the medium in scene units (overrides the
        medium's own ``path_length`` option); None: the medium's.
    """

    scale: float | None = None
    ext_ior: float = 1.0
    path_length: float | None = None


@dataclass(frozen=True)
class Value:
    """One parameter of a plugin: its renderer name, kind (:data:`VALUE_KINDS`) and value.

    ``colour`` : the renderer takes a colour here (a reflectance, an index of a conductor,
    a medium's coefficients), so that a model fitted over the r, g, b channels may give it
    one value per channel; kinds "spectrum" and "rgb" always do. An "rgb" value of a colour
    export is a tuple (r, g, b) (:mod:`veil.interop.colour`); otherwise one number.
    """

    name: str
    kind: str
    value: object
    colour: bool = False

    def __post_init__(self) -> None:
        if self.kind not in VALUE_KINDS:
            raise ValueError(f"Value {self.name}: kind {self.kind!r}")
        if self.kind == "rgb" and isinstance(self.value, tuple):
            rgb = tuple(float(x) for x in self.value)
            if len(rgb) != 3 or not all(math.isfinite(x) for x in rgb):
                raise Unsupported(
                    f"{self.name} = {self.value!r}: expected three finite "
                    f"numbers (r, g, b); a renderer cannot take it"
                )
            for x in rgb:
                self._check_range(x)
            object.__setattr__(self, "value", rgb)
        elif self.kind in ("float", "spectrum", "rgb"):
            v = float(cast(SupportsFloat, self.value))  # these kinds hold a number
            if not math.isfinite(v):
                raise Unsupported(
                    f"{self.name} = {self.value!r} is not a finite number; a "
                    f"renderer cannot take it"
                )
            self._check_range(v)
            object.__setattr__(self, "value", v)

    def _check_range(self, v: float) -> None:
        """Unsupported when ``v`` is beyond a renderer's 32-bit floats (read as infinite)."""
        if abs(v) > RENDERER_MAX:
            raise Unsupported(
                f"{self.name} = {v:.3g} is beyond the 32-bit floats a renderer stores it in "
                f"(magnitude at most {RENDERER_MAX:.3g}; it would be infinite there): the "
                f"export's setting makes it so; give a larger intensity scale (--scale), a "
                f"smaller outside index (--ext-ior) or a longer pass (--path-length)"
            )

    @property
    def colourable(self) -> bool:
        """Whether the renderer takes one value per colour channel here."""
        return self.colour or self.kind in ("spectrum", "rgb")


@dataclass(frozen=True)
class Plugin:
    """A renderer plugin standing for one model.

    kind : the renderer's element ("bsdf", "medium", "phase"; pbrt: "material", "medium").
    type : the plugin's name ("roughplastic", "homogeneous", ...).
    values : its parameters, in the order they are written.
    children : nested plugins (a medium's phase function).
    lost : sentences saying what the conversion loses or changes.
    scale : the intensity scale divided out of the model (1: none); a render of the plugin
        under unit irradiance times ``scale`` is what veil predicts.
    extra : further plugins the scene needs (a medium's boundary as a dielectric BSDF).
    geometry : the scene the plugin assumes, for a check by rendering: "path_length" (one
        pass through a medium, scene units) and "plate_half_width".
    model : the model the plugin stands for when the setting changed it (a medium given
        another path length); None: the model itself.
    """

    kind: str
    type: str
    values: tuple = ()
    children: tuple = ()
    lost: tuple = ()
    scale: float = 1.0
    extra: tuple = field(default=())
    geometry: dict = field(default_factory=dict)
    model: object = None


def float_value(name: str, value, colour: bool = False) -> Value:
    return Value(name, "float", value, colour)


def require_ggx_for_pbrt(model, family: str) -> None:
    """Unsupported unless ``model`` (a microfacet family, ``family`` its name) uses the GGX
    distribution, the only one pbrt-v4 has."""
    if model.distribution != "ggx":
        raise Unsupported(
            f"pbrt-v4 has only the Trowbridge-Reitz (GGX) microfacet "
            f"distribution; this {family} result uses "
            f"{model.distribution} (export it to Mitsuba, which has both)"
        )


def intensity_scale(setting: Setting, default: float) -> float:
    """The scale to divide out: the setting's, else ``default`` (when positive), else 1."""
    scale = setting.scale if setting.scale is not None else default
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        return 1.0
    return float(scale)


__all__ = [
    "require_ggx_for_pbrt",
    "RENDERER_NAMES",
    "VALUE_KINDS",
    "Unsupported",
    "Setting",
    "Value",
    "Plugin",
    "float_value",
    "intensity_scale",
]
