"""Public entry points of the forward model: ``apparent`` (MODEL.md eq. 1) and ``reflectance``.

Angles are in degrees and broadcast like numpy arrays; results are numpy arrays.
"""

from __future__ import annotations

import numpy as np

from functools import lru_cache

from ..errors import InputError, InputTypeError
from .._jax import jax, jnp
from .forward import Forward
from .angles import check_angles, direction  # noqa: F401  (check_angles re-exported)
from ..models import BRDF, BTDF, preset
from .quadrature import ERROR_FACTOR, FINER, RULES, Rule  # noqa: F401  (re-exported)


def as_brdf(brdf) -> BRDF:
    model = preset(brdf) if isinstance(brdf, str) else brdf
    if not isinstance(model, BRDF):
        raise InputTypeError(f"expected a BRDF (e.g. veil.BRDF1), got {brdf!r}")
    return model


def as_btdf(medium) -> BTDF:
    model = preset(medium) if isinstance(medium, str) else medium
    if not isinstance(model, BTDF):
        raise InputTypeError(f"expected a BTDF medium (e.g. veil.BTDF1), got {medium!r}")
    return model


def reflectance(brdf, theta_i, theta_r, phi_i=180.0, phi_r=0.0) -> np.ndarray:
    """The object's own BRDF f_r (MODEL.md sec. 2) at the given angles (degrees)."""
    model = as_brdf(brdf)
    ti, tr, pi_, pr = check_angles(theta_i, theta_r, phi_i, phi_r)
    wi, wr = direction(ti, pi_), direction(tr, pr)
    return np.asarray(_evaluate_fn(type(model))(jnp.asarray(model.to_vector()), wi, wr))


@lru_cache(maxsize=None)
def _evaluate_fn(cls):
    return jax.jit(cls.evaluate)


def apparent(brdf, medium, theta_i, theta_r, phi_i=180.0, phi_r=0.0, *,
             accuracy: str = "default", return_error: bool = False):
    """Apparent reflectance f(I, R) of ``brdf`` seen through ``medium`` (MODEL.md eq. 1).

    Parameters
    ----------
    brdf, medium : model instances or preset names ("BRDF1", "BTDF2", ...). ``medium=None``
        means a clear medium and returns :func:`reflectance`.
    theta_i, theta_r, phi_i, phi_r : angles in degrees, numpy-broadcast. Polar angles in
        [0, 90); defaults put light and camera in the plane of incidence on opposite sides.
    accuracy : "fast", "default" or "high" quadrature.
    return_error : also return an error estimate (absolute): twice the difference to the
        same quadrature with 1.3 times the nodes per dimension (costs about three times the
        evaluation itself).
    """
    if accuracy not in RULES:
        raise InputError(f"accuracy = {accuracy!r}; expected one of {', '.join(RULES)}")
    if medium is None:
        value = reflectance(brdf, theta_i, theta_r, phi_i, phi_r)
        return (value, np.zeros_like(value)) if return_error else value
    b, m = as_brdf(brdf), as_btdf(medium)
    ti, tr, pi_, pr = check_angles(theta_i, theta_r, phi_i, phi_r)
    shape = ti.shape
    vb, vm = b.to_vector(), m.to_vector()
    value = Forward(b, m, ti, tr, pi_, pr, RULES[accuracy])(vb, vm).reshape(shape)
    if not return_error:
        return value
    finer = Forward(b, m, ti, tr, pi_, pr, FINER[accuracy])(vb, vm).reshape(shape)
    return value, np.asarray(ERROR_FACTOR * np.abs(value - finer))
