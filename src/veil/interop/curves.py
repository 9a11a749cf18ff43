"""Predicted curves as a tidy table (docs/interop.md): one row per configuration and
condition (the object's own f_r, ``medium`` = "none", and its apparent value through the
medium), for plotting elsewhere."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from ..data.channels import CHANNEL
from ..data.protocol import PSI, protocol
from ..engine.apparent import apparent, reflectance
from ..errors import InputError

#: Columns of the table, in order.
COLUMNS = ("brdf_model", "medium", "psi", "rho", "theta_i", "phi_i", "theta_r", "phi_r", "value")
NO_MEDIUM = "none"


def curves(
    brdf, medium=None, psi=PSI, accuracy: str = "default", **protocol_options
) -> pd.DataFrame:
    """f_r of ``brdf`` and, when ``medium`` is given, its apparent value through it, at the
    configurations of the paper's protocol (:func:`veil.data.protocol.protocol`)."""
    if brdf is None:
        raise InputError(
            "predicted curves need a BRDF (the object); a medium alone has none: "
            "give a BRDF result or preset too"
        )
    table = protocol(psi, **protocol_options)
    angles = [table[c].to_numpy() for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    blocks: list[tuple[str, Any]] = [(NO_MEDIUM, reflectance(brdf, *angles))]
    if medium is not None:
        blocks.append((medium.NAME, apparent(brdf, medium, *angles, accuracy=accuracy)))
    frames = []
    for label, values in blocks:
        values = np.asarray(values, dtype=float)
        if not np.all(np.isfinite(values)):
            raise FloatingPointError(f"non-finite predicted value ({label})")
        frame = table.copy()
        frame.insert(0, "medium", label)
        frame.insert(0, "brdf_model", brdf.NAME)
        frame["value"] = values
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)[list(COLUMNS)]


def channel_curves(
    brdfs: dict | None,
    media: dict | None = None,
    psi=PSI,
    accuracy: str = "default",
    **protocol_options,
) -> pd.DataFrame:
    """:func:`curves` of every channel ({channel: model} of the BRDF and the optional
    medium, docs/channels.md), channel after channel, with a ``channel`` column before
    ``value``."""
    if brdfs is None:
        return curves(None)
    frames = []
    for c, brdf in brdfs.items():
        frame = curves(brdf, None if media is None else media[c], psi, accuracy, **protocol_options)
        frame.insert(len(COLUMNS) - 1, CHANNEL, c)
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


def to_csv_text(frame: pd.DataFrame) -> str:
    """The table as CSV text, numbers written to full precision (deterministic)."""
    return frame.to_csv(index=False, float_format="%.17g", lineterminator="\n")


__all__ = ["curves", "channel_curves", "to_csv_text", "COLUMNS", "NO_MEDIUM"]
