"""veil: reflectance of objects seen through scattering media.

Forward model (docs/model.md): :func:`apparent`, :func:`reflectance`; the registered model
families (``veil.TorranceSparrow``, ``veil.HenyeyGreenstein``, ... by class name, listed in
``veil.REGISTRY``) and the paper's presets ``BRDF1``, ``BRDF2``, ``BTDF1``, ``BTDF2``,
``BTDF3``; measurement tables, simulation, the fits of the two-step method, the joint fit
and the pipeline. Names are imported on first use, so ``import veil`` is cheap.
"""

from __future__ import annotations

import importlib

#: Public name -> the module that defines it.
_API = {
    "apparent": "engine.apparent",
    "reflectance": "engine.apparent",
    "load_measurements": "data.measurements",
    "save_measurements": "data.measurements",
    "subtract_black": "data.black_cloth",
    "simulate": "data.simulate",
    "fit_reference": "fitting.steps",
    "fit_medium": "fitting.steps",
    "fit_target": "fitting.steps",
    "FitResult": "fitting.result",
    "run_pipeline": "pipeline",
    "fit_joint": "fitting.joint",
    "fit_maps": "maps.run",
    "open_maps": "maps.store",
    "BRDF": "models",
    "BTDF": "models",
    "Medium": "models",
    "Model": "models",
    "Param": "models",
    "PRESETS": "models",
    "REGISTRY": "models",
    "preset": "models",
    "register": "models",
    "ChannelModel": "models",
}
_PRESETS = ("BRDF1", "BRDF2", "BTDF1", "BTDF2", "BTDF3")


def _version() -> str:
    """The installed distribution's version (written once, in pyproject.toml)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("veil")
    except PackageNotFoundError:  # a source tree on sys.path, never installed
        return "0+unknown"


def __getattr__(name: str) -> object:
    value: object
    if name == "__version__":
        value = globals()["__version__"] = _version()
        return value
    if name == "__all__":  # ``from veil import *``: the API and every registered family
        return sorted(set(_API) | set(_PRESETS) | {"__version__"} | set(_families()))
    if name in _API:
        value = getattr(importlib.import_module(f".{_API[name]}", __name__), name)
    elif name in _PRESETS:
        value = importlib.import_module(".models", __name__).PRESETS[name]
    else:
        # Family classes are CamelCase; anything else (a submodule being imported, a dunder
        # probed by a tool) is not looked up, so that no import loads the models or plugins.
        value = _families().get(name) if name[:1].isupper() else None
        if value is None:
            raise AttributeError(f"module 'veil' has no attribute {name!r}")
    globals()[name] = value
    return value


def _families() -> dict:
    """The registered families by class name (plugins included)."""
    models = importlib.import_module(".models", __name__)
    return {c.__name__: c for c in map(models.model_class, models.names())}


def __dir__():
    return sorted(set(globals()) | set(_API) | set(_PRESETS) | set(_families()))
