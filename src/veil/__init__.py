"""veil: reflectance of objects seen through scattering media.

Forward model (MODEL.md): :func:`apparent`, :func:`reflectance`; models and the paper's
presets: :class:`TorranceSparrow`, :class:`HenyeyGreenstein`, ``BRDF1``, ``BRDF2``,
``BTDF1``, ``BTDF2``, ``BTDF3``.
"""

from . import _jax  # noqa: F401  (float64 for JAX before anything else)
from .engine.apparent import apparent, reflectance
from .data.measurements import load_measurements, save_measurements, subtract_black
from .data.simulate import simulate
from .fitting.steps import FitResult, fit_medium, fit_reference, fit_target
from .pipeline import run_pipeline
from .fitting.joint import fit_joint
from .models import (BRDF, BTDF, PRESETS, REGISTRY, HenyeyGreenstein, Model, Param,
                     TorranceSparrow, preset)

BRDF1 = PRESETS["BRDF1"]
BRDF2 = PRESETS["BRDF2"]
BTDF1 = PRESETS["BTDF1"]
BTDF2 = PRESETS["BTDF2"]
BTDF3 = PRESETS["BTDF3"]

__version__ = "0.1.0"

__all__ = ["apparent", "reflectance", "BRDF", "BTDF", "Model", "Param", "TorranceSparrow",
           "HenyeyGreenstein", "PRESETS", "REGISTRY", "preset", "BRDF1", "BRDF2", "BTDF1",
           "BTDF2", "BTDF3", "load_measurements", "save_measurements", "subtract_black",
           "simulate", "fit_reference", "fit_medium", "fit_target", "FitResult", "run_pipeline",
           "fit_joint"]
