"""Optional dependencies: which extra of ``pip install veil[...]`` brings which module.

The core (``pip install veil``) computes, simulates and fits; the heavy packages are extras:
``veil[maps]`` (Dask, Zarr, OpenEXR: reflectance maps), ``veil[explore]`` (Panel: the
interactive page), ``veil[ingest]`` (rawpy, tifffile, imagecodecs: photographs), ``veil[all]``.
Code that needs one imports it through :func:`require` where it is used, never at the top of a
module, so that ``import veil`` and every other command work without it. A missing one raises
:class:`veil.errors.MissingExtraError` (an input error: the command line exits with status 2)
whose message is the pip line to run.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingExtraError

#: Top-level module -> the extra that installs it (pyproject.toml, [project.optional-dependencies]).
EXTRA_OF = {
    "dask": "maps",
    "distributed": "maps",
    "zarr": "maps",
    "OpenEXR": "maps",
    "panel": "explore",
    "bokeh": "explore",
    "rawpy": "ingest",
    "tifffile": "ingest",
    "imagecodecs": "ingest",
}


def pip_line(extra: str) -> str:
    """The command that installs an extra, as the user types it."""
    return f"pip install 'veil[{extra}]'"


def require(module: str, purpose: str | None = None) -> ModuleType:
    """Import ``module`` (``"zarr"``, ``"dask.array"``) and return it; if its package is not
    installed, raise :class:`MissingExtraError` naming the extra and the pip line."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.split(".")[0]
        if top not in EXTRA_OF:
            raise  # not an optional package: a bug in veil, shown as it is
        extra = EXTRA_OF[top]
        what = f"{purpose} needs" if purpose else "this needs"
        missing = (exc.name or top).split(".")[0]
        why = "is not installed" if missing == top else f"cannot be imported ({exc})"
        raise MissingExtraError(
            f"{what} the optional package {top}, which {why}; install veil's {extra!r} "
            f"extra: {pip_line(extra)}"
        ) from None


__all__ = ["EXTRA_OF", "pip_line", "require"]
