"""Fitting: the data of a session (:mod:`.session_data`), the least-squares problem
(:mod:`.problem`), its solver (:mod:`.solver`) and the rules it shares with the per-pixel maps
(:mod:`.least_squares`), starting values (:mod:`.start_values`), results and
their JSON files (:mod:`.result`) and reports (:mod:`.fit_report`), the steps of the two-step
method (:mod:`.steps`) and the joint fit (:mod:`.joint`)."""

from __future__ import annotations

from ..errors import FitError
from .joint import Session, build, fit_joint
from .problem import Problem, session_problem
from .result import FitResult, JointResult, load_result
from .session_data import FitData, prepare
from .steps import fit_direct, fit_medium, fit_reference, fit_target, model_values

__all__ = [
    "FitError",
    "FitData",
    "prepare",
    "Session",
    "build",
    "fit_joint",
    "Problem",
    "session_problem",
    "FitResult",
    "JointResult",
    "load_result",
    "fit_direct",
    "fit_medium",
    "fit_reference",
    "fit_target",
    "model_values",
]
