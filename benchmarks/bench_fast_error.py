"""How far the "fast" quadrature is from "default" and "high", every registered pair.

    .venv/bin/python benchmarks/bench_fast_error.py [--doc docs/engine.md]

For every registered BRDF family x medium model at their template values (the declared
starting values, default options), the paper's six preset pairs, and the rough plastic
through the forward series in the lab's geometry (path length 15, plate width 5) with each
of the series' order weightings, at a path-traced session's fitted values: the apparent
reflectance at the protocol's 111 configurations at each rule, and the largest relative
difference of "fast" and of "default" from "high", relative to the value or to 1e-3 of the
largest value, whichever is larger. veil.fitting.screening.FAST_ERROR, the fast rule's
error the screening of model selection allows for, must bound the "fast" column.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import doc_tables  # noqa: E402


def pairs() -> list[tuple[str, object, object]]:
    from veil.models.registry import PRESETS, REGISTRY, names

    out = [(f"{b} x {m}", PRESETS[b], PRESETS[m]) for b in ("BRDF1", "BRDF2")
           for m in ("BTDF1", "BTDF2", "BTDF3")]
    out += [(f"{b} x {m} (template)", REGISTRY[b].template(), REGISTRY[m].template())
            for b in names("brdf") for m in names("medium")]
    # session m05's fitted plate and water (validation/data), every order weighting
    plate = REGISTRY["rough-plastic"].from_params(
        {"rho": 0.5, "ks": 1.0, "alpha": 0.1, "eta": 1.12})
    for orders in ("poisson", "light-side", "view-side", "cylinder"):
        water = REGISTRY["forward-series"].from_params(
            {"tau": 0.5, "omega": 0.99, "g": 0.93, "eta_u": 1.33, "s": 1.0},
            {"path_length": 15.0, "plate_width": 5.0, "orders": orders})
        out.append((f"rough-plastic x forward-series, m05, orders {orders}", plate, water))
    return out


def worst(values: np.ndarray, reference: np.ndarray) -> float:
    scale = np.maximum(np.abs(reference), 1e-3 * np.abs(reference).max())
    return float(np.max(np.abs(values - reference) / scale))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    doc_tables.add_options(ap, "fast-error")
    args = ap.parse_args(argv)
    from veil.data.protocol import protocol
    from veil.engine.apparent import apparent
    from veil.fitting.screening import FAST_ERROR

    configs = protocol()
    angles = [configs[c].to_numpy() for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    rows, largest = [], 0.0
    for label, brdf, medium in pairs():
        f = {a: apparent(brdf, medium, *angles, accuracy=a) for a in ("fast", "default", "high")}
        fast, default = worst(f["fast"], f["high"]), worst(f["default"], f["high"])
        largest = max(largest, fast, worst(f["fast"], f["default"]))
        rows.append([label, f"{fast:.2e}", f"{default:.2e}", f"{worst(f['fast'], f['default']):.2e}"])
        print(f"  {label}: fast {fast:.2e}, default {default:.2e}", file=sys.stderr)
    with doc_tables.printed_tables(args):
        print(doc_tables.markdown(["pair", "fast vs high", "default vs high", "fast vs default"],
                                  rows, {1, 2, 3}))
        print(f"\nLargest fast-rule difference {largest:.2e}; FAST_ERROR = {FAST_ERROR:g}.")
    if largest > FAST_ERROR:
        print("bench_fast_error: FAST_ERROR does not bound the fast rule's error", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
