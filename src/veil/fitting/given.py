"""The model a fit holds fixed, its "given" model (MODEL.md sec. 7): the reference's f_r in
step 1, the medium's f_t in step 2, taken from a step's :class:`FitResult` or a model
instance and checked; :func:`model_dict` is its entry in a result file."""

from __future__ import annotations

import warnings

from ..errors import InputTypeError
from .result import FitError, FitResult
from ..models import BRDF, BTDF, Model, model_class
from ..models.henyey_greenstein import VARIANTS


def as_brdf_model(reference) -> BRDF:
    """The reference's f_r from a step-0 FitResult (warns if it did not converge) or a BRDF."""
    if isinstance(reference, FitResult):
        if model_class(reference.model).KIND != "brdf":
            raise FitError(f"the reference must be a BRDF fit (step 0, 'veil fit reference', "
                           f"model torrance-sparrow); got a {reference.model} result"
                           + (f" of step {reference.step!r}" if reference.step else ""))
        if not reference.converged:
            warnings.warn("the reference fit did not converge; its f_r is used as it is",
                          stacklevel=3)
        return reference.as_model()
    if isinstance(reference, BRDF):
        return reference
    if isinstance(reference, BTDF):
        raise FitError(f"the reference must be a BRDF (TorranceSparrow); got the medium "
                       f"{reference}")
    raise InputTypeError(f"reference: expected a FitResult of step 0 or a TorranceSparrow, got "
                    f"{type(reference).__name__}")


def as_medium_model(medium, variant) -> BTDF:
    """The medium from a step-1 FitResult (warns if it did not converge) or a BTDF; a
    ``variant`` other than None must be the medium's."""
    if isinstance(medium, FitResult):
        if model_class(medium.model).KIND != "btdf":
            raise FitError(f"the medium must be a medium fit (step 1, 'veil fit medium', model "
                           f"henyey-greenstein); got a {medium.model} result"
                           + (f" of step {medium.step!r}" if medium.step else ""))
        if not medium.converged:
            warnings.warn("the medium fit did not converge; its f_t is used as it is",
                          stacklevel=3)
        model = medium.as_model()
    elif isinstance(medium, BTDF):
        model = medium
    elif isinstance(medium, BRDF):
        raise FitError(f"the medium must be a BTDF (HenyeyGreenstein); got the BRDF {medium}")
    else:
        raise InputTypeError(f"medium: expected a FitResult of step 1 or a HenyeyGreenstein, got "
                        f"{type(medium).__name__}")
    if variant is not None and model.options().get("variant") != variant:
        raise FitError(f"variant = {variant!r} but the medium was fitted with variant "
                       f"{model.options().get('variant')!r}; leave variant unset to use the "
                       f"medium's")
    return model


def check_variant(variant) -> None:
    """A FitError unless ``variant`` is a Fresnel variant of the medium (MODEL.md sec. 3)."""
    if variant not in VARIANTS:
        raise FitError(f"variant = {variant!r}; expected one of {', '.join(VARIANTS)}")


def model_dict(model: Model) -> dict:
    """{"model": name, "params": {...}, options such as "variant"}: the "given" key of a result."""
    opts = model.options()
    return {"model": model.NAME, "params": model.as_dict(), **opts}


__all__ = ["as_brdf_model", "as_medium_model", "check_variant", "model_dict"]
