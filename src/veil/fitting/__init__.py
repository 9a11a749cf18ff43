"""Fitting: the data of a session (:mod:`.session_data`), the least-squares problem
(:mod:`.problem`), its solver (:mod:`.solver`) and the rules it shares with the per-pixel maps
(:mod:`.least_squares`), starting values (:mod:`.start_values`), results and
their JSON files (:mod:`.result`) and reports (:mod:`.fit_report`), the steps of the two-step
method (:mod:`.steps`), the joint fit (:mod:`.joint`) and the data choosing the model
(:mod:`.selection`, :mod:`.screening`, :mod:`.auto`, :mod:`.joint_selection`)."""

from __future__ import annotations

from ..errors import FitError
from .joint import Session, build, fit_joint
from .joint_selection import fit_joint_ranked
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
    "fit_joint_ranked",
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
