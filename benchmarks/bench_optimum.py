"""How far a fit through a medium ends from its rule's exact optimum (docs/fitting.md,
"Convergence").

The fits' Jacobian in the medium's parameters holds the phase grids (docs/engine.md,
"Derivatives"), and the polish at "default" keeps the fast rule's Jacobian: neither is the
exact derivative of the values the fit minimizes, so a fit stops at a point whose distance
from the exact optimum is set by that difference. This benchmark fits the medium of the
paper's reference plate (BRDF2, 1 % noise) for each of its three media at "fast" and at
"default", then takes one Gauss-Newton step from the result with a central-difference
Jacobian of that rule's own values (the exact optimum's direction and distance) and prints
the step in standard errors, the largest over the free parameters.

    .venv/bin/python benchmarks/bench_optimum.py
    .venv/bin/python benchmarks/bench_optimum.py --doc docs/engine.md
"""

from __future__ import annotations

import argparse
import os
import sys

import doc_tables
import numpy as np


def distance(table, reference, result, accuracy: str) -> dict:
    """{parameter: the Gauss-Newton step to the exact optimum, in standard errors}."""
    from veil.engine.forward import Forward
    from veil.engine.quadrature import RULES

    medium = result.as_model()
    names = type(medium).param_names()
    free = [names.index(n) for n in result.free]
    angles = [table[c].to_numpy(float) for c in ("theta_i", "theta_r", "phi_i", "phi_r")]
    f = Forward(reference, medium, *angles, rule=RULES[accuracy])
    vb, vm = reference.to_vector(), medium.to_vector().copy()
    w = 1.0 / table["sigma"].to_numpy(float)
    r = (f(vb, vm) - table["value"].to_numpy(float)) * w
    cols = []
    for i in free:
        h = 1e-6 * max(abs(vm[i]), 1e-3)
        up, down = vm.copy(), vm.copy()
        up[i] += h
        down[i] -= h
        cols.append((f(vb, up) - f(vb, down)) / (2 * h) * w)
    jac = np.stack(cols, axis=1)
    cov = np.linalg.inv(jac.T @ jac)
    step = -cov @ (jac.T @ r)
    return dict(zip(result.free, step / np.sqrt(np.diag(cov))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    doc_tables.add_options(ap, "fit-optimum")
    a = ap.parse_args(argv)
    import veil

    rows = ["| medium | accuracy | converged | largest step to the exact optimum (standard "
            "errors) | parameter |", "|---|---|---|---:|---|"]
    for label in ("BTDF1", "BTDF2", "BTDF3"):
        medium = veil.preset(label)
        table = veil.simulate(veil.BRDF2, medium, noise=0.01, seed=5, glow=0.0)
        for accuracy in ("fast", "default"):
            result = veil.fit_medium(table, veil.BRDF2, accuracy=accuracy)
            d = distance(table, veil.BRDF2, result, accuracy)
            name = max(d, key=lambda k: abs(d[k]))
            rows.append(f"| {label} | {accuracy} | {result.converged} | {abs(d[name]):.1e} | "
                        f"{name} |")
            print(rows[-1], flush=True)
    one, five, _ = os.getloadavg()
    with doc_tables.printed_tables(a):
        print("\n" + "\n".join(rows) + f"\n\nLoad at the end {one:.1f} (5 min {five:.1f}).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
