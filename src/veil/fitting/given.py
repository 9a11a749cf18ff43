"""The model a fit holds fixed, its "given" model (docs/model.md sec. 7): the reference's f_r in
step 1, the medium's f_t in step 2, from a step's :class:`FitResult` or a model instance,
checked to be of the kind the fit needs."""

from __future__ import annotations

import warnings

from ..errors import FitError, InputTypeError
from ..models import Model
from .result import RESULTS, FitResult, JointResult

#: How errors name what a fit needs, by kind: a model, a fit result.
NEEDS = {
    "brdf": "a BRDF (the step-0 result of 'veil fit reference', or a BRDF model)",
    "medium": "a medium (the step-1 result of 'veil fit medium', or a medium model)",
}


def as_given(obj, kind: str, role: str) -> Model:
    """The model of kind ``kind`` ("brdf" or "medium") from a FitResult (warns if it did not
    converge) or a model instance; ``role`` names it in errors ("the reference", "the
    medium")."""
    if isinstance(obj, JointResult):
        raise FitError(
            f"{role} must be {NEEDS[kind]}; got a joint fit result (take one of its "
            f"models with .brdf(object) or .medium(label))"
        )
    if isinstance(obj, FitResult):
        if obj.kind != kind:
            raise FitError(
                f"{role} must be {RESULTS[kind]}; got a {obj.model} result"
                + (f" of step {obj.step!r}" if obj.step else "")
            )
        if not obj.converged:
            warnings.warn(
                f"the fit of {role} did not converge; its model is used as it is", stacklevel=3
            )
        return obj.one_model()
    if isinstance(obj, Model):
        if obj.KIND != kind:
            raise FitError(f"{role} must be {NEEDS[kind]}; got the {obj.KIND} model {obj}")
        return obj
    raise InputTypeError(f"{role}: expected {NEEDS[kind]}, got {type(obj).__name__}")


def check_options(model: Model, options: dict | None, role: str) -> Model:
    """``model`` unless ``options`` (those given explicitly) contradict its own: a FitError
    then (a fit through a medium uses the medium's options)."""
    for k, v in (options or {}).items():
        if v is None:
            continue
        if k not in model.options():
            raise FitError(f"{role} ({model.NAME}) has no option {k!r}")
        if model.options()[k] != v:
            raise FitError(
                f"{k} = {v!r} but {role} was fitted with {k} "
                f"{model.options()[k]!r}; leave {k} unset to use {role}'s"
            )
    return model


__all__ = ["as_given", "check_options", "NEEDS"]
