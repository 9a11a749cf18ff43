"""``veil export --verify``: the exported Mitsuba scene fragment rendered at goniometer
configurations and compared with veil's own prediction (docs/interop.md).

The fragment's own text is loaded (so the check covers the file as written): a square plate
with the exported material at the origin, a directional light of unit irradiance from I and
a one-ray radiance meter looking at the plate's centre from R. With a medium, the plate sits
at the axis of a cylinder of radius ``path_length`` (the set-up of docs/model.md sec. 8.1) filled
with the exported medium, and the render is a path-traced Monte Carlo estimate.

Mitsuba 3 is an optional dependency (``pip install 'veil[mitsuba]'``); the variant is
``scalar_rgb``, which needs no system libraries. Without it: an InputError (exit status 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

import numpy as np

from ..data.channels import RGB
from ..engine.angles import direction
from ..errors import InputError
from .writers import IDS

VARIANT = "scalar_rgb"
#: Configurations where veil's value is below this fraction of its largest are left out of
#: the relative difference (a conductor's lobe falls to zero away from the mirror direction).
NEGLIGIBLE = 1e-4
#: Where the meter stands, in units of the plate's half width (clear scenes).
METER_DISTANCE = 5.0


def load_mitsuba() -> ModuleType:
    """The mitsuba module set to :data:`VARIANT`; an InputError when it is not installed."""
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise InputError(
            f"--verify renders with Mitsuba 3, which is not installed here "
            f"({exc}); install it with: pip install 'veil[mitsuba]' (or pip "
            f"install mitsuba)"
        ) from None
    try:
        mi.set_variant(VARIANT)
    except Exception as exc:
        raise InputError(
            f"--verify needs Mitsuba's {VARIANT} variant, which this Mitsuba does not have ({exc})"
        ) from None
    return mi


@dataclass(frozen=True)
class Verification:
    """Renders against veil's values at ``configs`` (theta_i, theta_r, phi_i, phi_r rows):
    ``rms_relative`` = RMS of render / veil - 1 where veil's value is not negligible
    (:data:`NEGLIGIBLE`), ``max_relative`` the largest there."""

    rendered: np.ndarray
    predicted: np.ndarray
    configs: np.ndarray
    spp: int
    medium: bool
    stderr: np.ndarray | None = None

    @property
    def used(self) -> np.ndarray:
        return self.predicted > NEGLIGIBLE * np.max(self.predicted)

    @property
    def relative(self) -> np.ndarray:
        used = self.used
        return self.rendered[used] / self.predicted[used] - 1.0

    @property
    def rms_relative(self) -> float:
        return float(np.sqrt(np.mean(self.relative**2)))

    @property
    def max_relative(self) -> float:
        return float(np.max(np.abs(self.relative)))

    @property
    def rms_noise(self) -> float | None:
        """RMS of the renders' relative Monte Carlo standard errors (None: deterministic)."""
        if self.stderr is None:
            return None
        used = self.used
        return float(np.sqrt(np.mean((self.stderr[used] / self.predicted[used]) ** 2)))

    def sentence(self) -> str:
        what = "path-traced through the medium" if self.medium else "rendered"
        left = len(self.predicted) - int(np.sum(self.used))
        noise = self.rms_noise
        return (
            f"Mitsuba {VARIANT} {what} at {len(self.predicted)} configurations ({self.spp} "
            f"spp): RMS relative difference from veil {100 * self.rms_relative:.3g} % "
            f"(largest {100 * self.max_relative:.3g} %)"
            + (
                f", of which Monte Carlo noise (RMS relative standard error) {100 * noise:.3g} %"
                if noise is not None
                else ""
            )
            + (
                f"; {left} configurations where veil's value is below {NEGLIGIBLE:g} of "
                f"its largest left out"
                if left
                else ""
            )
        )


def _vec(tag: str, name: str, v) -> str:
    x, y, z = (repr(float(c)) for c in v)
    return f'<{tag} name="{name}" x="{x}" y="{y}" z="{z}"/>'


def _scene(fragment: str, wi, wr, spp: int, medium: dict | None) -> str:
    """The fragment with a plate, a light from ``wi`` and a meter at ``wr`` added."""
    body = fragment.rsplit("</scene>", 1)[0]
    if medium is None:
        origin = METER_DISTANCE * np.asarray(wr)
        integrator = '<integrator type="path"><integer name="max_depth" value="2"/></integrator>'
        extra = ""
        plate = ""
    else:
        rc, half = float(medium["length"]), float(medium["half_width"])
        max_depth = int(medium["max_depth"])
        origin = (rc * 1.2) * np.asarray(wr)
        integrator = (
            f'<integrator type="volpath"><integer name="max_depth" value="{max_depth}"'
            f"/></integrator>"
        )
        ref = f'<ref name="interior" id="{IDS["medium"]}"/>'
        length = 4.0 * rc
        extra = (
            f'<shape type="cylinder"><point name="p0" x="0" y="{-length!r}" z="0"/>'
            f'<point name="p1" x="0" y="{length!r}" z="0"/><float name="radius" '
            f'value="{rc!r}"/><bsdf type="null"/>{ref}</shape>'
            f'<shape type="disk"><transform name="to_world"><rotate x="1" angle="-90"/>'
            f'<scale value="{rc!r}"/><translate y="{length!r}"/></transform>'
            f'<bsdf type="null"/>{ref}</shape>'
            f'<shape type="disk"><transform name="to_world"><rotate x="1" angle="90"/>'
            f'<scale value="{rc!r}"/><translate y="{-length!r}"/></transform>'
            f'<bsdf type="null"/>{ref}</shape>'
        )
        plate = f'<transform name="to_world"><scale x="{half!r}" y="{half!r}"/></transform>'
        # the plate is inside the medium on both sides
        plate += ref + f'<ref name="exterior" id="{IDS["medium"]}"/>'
    light = (
        f'<emitter type="directional">{_vec("vector", "direction", -np.asarray(wi))}'
        f'<rgb name="irradiance" value="1"/></emitter>'
    )
    sensor = (
        f'<sensor type="radiancemeter">{_vec("point", "origin", origin)}'
        f"{_vec('vector', 'direction', -np.asarray(wr))}"
        f'<film type="hdrfilm"><integer name="width" value="1"/><integer name="height" '
        f'value="1"/><rfilter type="box"/><string name="pixel_format" value="rgb"/></film>'
        f'<sampler type="independent"><integer name="sample_count" value="{spp}"/>'
        f"</sampler></sensor>"
    )
    shape = f'<shape type="rectangle">{plate}<ref id="{IDS["bsdf"]}"/></shape>'
    return body + integrator + light + sensor + shape + extra + "</scene>\n"


def render_rgb(
    fragment: str, configs, spp: int = 1, medium: dict | None = None, seed: int = 0
) -> np.ndarray:
    """Rendered red, green and blue values, shape (n, 3), of the fragment at ``configs``
    (rows theta_i, theta_r, phi_i, phi_r in degrees) under a white light; ``medium`` =
    {"length", "half_width", "max_depth"} path-traces the plate inside the exported medium."""
    mi = load_mitsuba()
    configs = np.asarray(configs, dtype=float)
    wi = np.asarray(direction(configs[:, 0], configs[:, 2]))
    wr = np.asarray(direction(configs[:, 1], configs[:, 3]))
    out = np.empty((len(configs), 3))
    for k in range(len(configs)):
        scene = mi.load_string(_scene(fragment, wi[k].tolist(), wr[k].tolist(), spp, medium))
        image = np.asarray(mi.render(scene, spp=spp, seed=seed + k))
        out[k] = [float(x) for x in image.ravel()[:3]]
    if not np.all(np.isfinite(out)):
        raise FloatingPointError("Mitsuba rendered a non-finite value")
    return out


def render(
    fragment: str, configs, spp: int = 1, medium: dict | None = None, seed: int = 0
) -> np.ndarray:
    """Rendered values (first RGB channel) of the fragment at ``configs``
    (:func:`render_rgb`)."""
    return render_rgb(fragment, configs, spp, medium, seed)[:, 0]


def _check_predicted(predicted, what: str = "") -> np.ndarray:
    predicted = np.asarray(predicted, dtype=float)
    if not np.max(predicted) > 0:
        raise InputError(f"veil predicts no light at any configuration{what}: nothing to compare")
    return predicted


def verify(
    fragment: str,
    scale: float,
    predicted,
    configs,
    spp: int = 1,
    medium: dict | None = None,
    seed: int = 0,
    passes: int = 1,
) -> Verification:
    """:func:`render` times the exported intensity ``scale`` against ``predicted``; with
    ``passes`` > 1 the ``spp`` are split into independent passes whose spread gives each
    render's standard error."""
    configs = np.asarray(configs, dtype=float)
    predicted = _check_predicted(predicted)
    if passes <= 1:
        rendered = scale * render(fragment, configs, spp, medium, seed)
        return Verification(rendered, predicted, configs, spp, medium is not None)
    per = max(1, spp // passes)
    runs = np.array(
        [scale * render(fragment, configs, per, medium, seed + 100003 * k) for k in range(passes)]
    )
    stderr = runs.std(axis=0, ddof=1) / np.sqrt(passes)
    return Verification(
        runs.mean(axis=0), predicted, configs, per * passes, medium is not None, stderr
    )


def verify_channels(
    fragment: str,
    scales: dict,
    predicted: dict,
    configs,
    spp: int = 1,
    medium: dict | None = None,
    seed: int = 0,
    passes: int = 1,
) -> dict:
    """{channel: :class:`Verification`} of a colour export (channels r, g, b, keys of
    ``scales`` and ``predicted``): each channel of one render (:func:`render_rgb`) times
    that channel's intensity scale against veil's prediction of that channel. ``passes``
    as :func:`verify`."""
    configs = np.asarray(configs, dtype=float)
    wanted = {c: _check_predicted(v, f" in channel {c}") for c, v in predicted.items()}
    index = {c: RGB.index(c) for c in wanted}
    per = spp if passes <= 1 else max(1, spp // passes)
    runs = np.array(
        [
            render_rgb(fragment, configs, per, medium, seed + 100003 * k)
            for k in range(max(passes, 1))
        ]
    )
    out = {}
    for c, values in wanted.items():
        channel = scales[c] * runs[:, :, index[c]]
        stderr = None if passes <= 1 else channel.std(axis=0, ddof=1) / np.sqrt(passes)
        out[c] = Verification(
            channel.mean(axis=0), values, configs, per * max(passes, 1), medium is not None, stderr
        )
    return out


__all__ = [
    "VARIANT",
    "load_mitsuba",
    "render",
    "render_rgb",
    "verify",
    "verify_channels",
    "Verification",
]
