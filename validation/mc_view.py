"""The view side's landing factors lambda_k (docs/physics-orders.md sec. 8,
veil.models.forward_series.landing_factors) against the per-order Monte Carlo of the lab
set-up (validation/mc_orders.py, same seeds): per order k, the Monte Carlo's view kernel
Int K_k dR' over the model's e^{-tau} (omega tau)^k/k! Int p(g^k) J_v dR' (J_v alone) and over
the same times lambda_k (J_v lambda_k), and all orders including 0.

    PYTHONPATH=src python validation/mc_view.py [--n 1000000] [--media m05,m10,...] [--angles 0,60,80]
"""
import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import mc_orders  # noqa: E402

from veil._jax import jax  # noqa: E402,F401  (float64)
from veil.models.forward_series import landing_factors  # noqa: E402

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--media", default="m05,m10,m15,m10_w10,m10_r10")
    ap.add_argument("--angles", default="0,60,80")
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks"))
    from doc_tables import add_options, printed_tables
    add_options(ap, "mc-view")
    a = ap.parse_args()
    doc = printed_tables(a).start()
    print("| case | theta_r | MC / J_v, k = 1 2 3 4 | MC / (J_v lambda_k), k = 1 2 3 4 | lambda_k, k = 2 3 4 "
          "| all orders MC / J_v | MC / (J_v lambda) | se k = 2 3 4 |")
    print("|---|---:|---|---|---|---:|---:|---|")
    for med in a.media.split(","):
        tau, g, rc, hw = mc_orders.CASES[med]
        for th in [float(t) for t in a.angles.split(",")]:
            t0 = time.time()
            mc, mo, _, se = mc_orders.view_side(tau, g, rc, hw, th, a.n, np.random.default_rng(2))
            mc, mo, se = mc[:, 0], mo[:, 0], se[:, 0]
            lam = np.concatenate([[1.0], np.asarray(landing_factors(g, rc, hw, math.cos(math.radians(th))))])
            lam = lam[:len(mc)]
            r1 = mc / mo
            r2 = mc / (mo * lam)
            print(f"| {med} | {th:g} | " + " ".join(f"{r1[k]:.3f}" for k in range(1, 5))
                  + " | " + " ".join(f"{r2[k]:.3f}" for k in range(1, 5))
                  + " | " + " ".join(f"{lam[k]:.3f}" for k in range(2, 5))
                  + f" | {mc.sum() / mo.sum():.4f} | {mc.sum() / (mo * lam).sum():.4f} | "
                  + " ".join(f"{se[k] / mc[k]:.3f}" for k in range(2, 5)) + " |", flush=True)
            print(f"  ({time.time() - t0:.0f} s)", file=sys.stderr)
    doc.finish()
