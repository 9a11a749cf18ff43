"""The program store's folder and its files (docs/performance-compile.md): where the store is
(``VEIL_CACHE_DIR``) and the atomic write of one of its files. Both the store
(:mod:`veil.engine.programs`) and the compile display (:mod:`veil.engine.compiling`) use
them, so neither imports the other for them."""

from __future__ import annotations

import contextlib
import os
import tempfile

from .._jax import CACHE_OFF


def directory() -> str | None:
    """The program store's folder, or None when it is disabled (``VEIL_CACHE_DIR=off``)."""
    setting = os.environ.get("VEIL_CACHE_DIR")
    if setting is not None:
        if setting.strip().lower() in CACHE_OFF:
            return None
        return os.path.join(os.path.abspath(os.path.expanduser(setting)), "programs")
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "veil", "programs")


def put_file(path: str, data: bytes) -> None:
    """Write a file of the store atomically (a temporary renamed into place under
    :data:`veil.io.COMMIT`; never listed among a command's outputs); OSError if it cannot."""
    from ..io import COMMIT, forget_temporary, register_temporary

    folder = os.path.dirname(path)
    tmp = None
    try:
        os.makedirs(folder, exist_ok=True)
        with COMMIT:  # no temporary is created once an interrupt is being handled
            fd, tmp = tempfile.mkstemp(dir=folder, prefix=".program-", suffix=".tmp")
            register_temporary(tmp, "file")
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        with COMMIT:
            os.replace(tmp, path)
            forget_temporary(tmp)
    except OSError:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            forget_temporary(tmp)
        raise


__all__ = ["directory", "put_file"]
