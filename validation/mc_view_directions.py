"""Where the view side's remaining error sits (docs/physics-orders.md sec. 8, docs/validity-orders.md): the
per-order Monte Carlo of the lab set-up's view side (validation/mc_orders.py) against
veil's e^{-tau} (omega tau)^k/k! p(g^k; R'.R) J_v(R', R) lambda_k, resolved two ways.

1. By direction: per order k, MC / model in bins of the in-plane angle between the plate's
   outgoing direction R' and the camera's R (negative: R' nearer the plate's normal than R).
2. Weighted by a plate: MC / model of sum_k Int K_k(R') f_r(I, R') dR' (orders 0..12, the
   unscattered beam included) with the true rough-plastic f_r of the reference and the
   target plate (validation/data/truth.json), for in-plane lights I (theta_i < 0: the far
   side, the specular at theta_i = -theta_r). What the fit sees, per configuration.

    PYTHONPATH=src python validation/mc_view_directions.py [--n 1000000] [--media m10,m10_w10]
        [--angles 30,60,75] [--lights=-60,-30,0,30,50]
"""
import argparse
import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import mc_orders as M  # noqa: E402

from veil._jax import jnp  # noqa: E402  (float64)
from veil.models.forward_series import landing_factors  # noqa: E402
from veil.models.rough_plastic import rough_plastic  # noqa: E402

#: In-plane angle of R' from R (radians), the bins' edges.
EDGES = np.array([-0.6, -0.3, -0.15, -0.05, 0.05, 0.15, 0.3, 0.6])


def plate_vector(plate: dict):
    """veil's rough-plastic parameter vector (rho, alpha, eta, ks) of a rendered plate."""
    return jnp.array([plate["diffuse_reflectance"], plate["alpha"], plate["relative_index"],
                      plate["specular_reflectance"]])


def model_samples(tau, g, rc, a, R, lam, m, rng):
    """Per order k = 1..KMAX, (R' drawn from p(g^k) about R, veil's weight per sample:
    e^{-tau} (omega tau)^k/k! J_v lambda_k, 0 below the plate)."""
    out = []
    for k, rp, up in M.model_directions(g, R, m, rng):
        wk = math.exp(-tau) * (M.OMEGA * tau) ** k / math.factorial(k)
        out.append((np.where(up[:, None], rp, R), wk * up * M.jv(tau, rc, a, rp, R)
                    * lam[min(k, len(lam) - 1)]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--media", default="m10,m10_w10")
    ap.add_argument("--angles", default="30,60,75")
    ap.add_argument("--lights", default="-60,-30,0,30,50")
    sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
    from doc_tables import add_options, printed_tables
    add_options(ap, "view-directions,view-weighted")
    args = ap.parse_args(argv)
    doc = printed_tables(args).start()
    with open(os.path.join(HERE, "data", "truth.json")) as f:
        plates = json.load(f)["plates"]
    vectors = {p: plate_vector(plates[p]) for p in ("ref", "target")}
    lights = [float(t) for t in args.lights.split(",")]
    by_dir, weighted = [], []
    for med in args.media.split(","):
        tau, g, rc, a = M.CASES[med]
        for th in [float(t) for t in args.angles.split(",")]:
            t = math.radians(th)
            R, e1 = np.array([math.sin(t), 0.0, math.cos(t)]), np.array([math.cos(t), 0.0,
                                                                          -math.sin(t)])
            rng = np.random.default_rng(7)
            hits = list(M.view_paths(tau, g, rc, a, R, args.n, rng))
            lam = np.concatenate([[1.0], np.asarray(landing_factors(g, rc, a, math.cos(t)))])
            model = model_samples(tau, g, rc, a, R, lam, args.n, rng)

            def bins(rp, w):
                b = np.digitize(np.arctan2(rp @ e1, rp @ R), EDGES)
                return np.bincount(b, weights=w, minlength=EDGES.size + 1)

            for k in (1, 2, 3):
                mc, mo = bins(*hits[k]) / args.n, bins(*model[k - 1]) / args.n
                by_dir.append(f"| {med} | {th:g} | {k} | " + " ".join(
                    f"{u / v:.2f}" if v > 0 and u > 0 else "-" for u, v in zip(mc, mo))
                    + f" | {mc.sum() / mo.sum():.3f} |")
            row = [f"| {med} | {th:g} | {sum(w.sum() for _, w in hits) / args.n / (math.exp(-tau) + sum(w.mean() for _, w in model)):.4f}"]
            for p, v in vectors.items():
                for ti in lights:
                    u = math.radians(ti)
                    wi = np.array([math.sin(u), 0.0, math.cos(u)])

                    def fr(rp, wi=wi, v=v):
                        return np.asarray(rough_plastic(
                            v, jnp.asarray(np.broadcast_to(wi, rp.shape)), jnp.asarray(rp)))

                    mc = sum((w * fr(rp)).sum() for rp, w in hits) / args.n
                    mo = math.exp(-tau) * float(fr(R[None])[0]) + sum(
                        (w * fr(rp)).mean() for rp, w in model)
                    row.append(f"{mc / mo:.4f}")
            weighted.append(" | ".join(row) + " |")
            print(f"  {med} theta_r = {th:g} done", file=sys.stderr, flush=True)
    print("By direction: MC / (e^-tau (omega tau)^k/k! p(g^k) J_v lambda_k), bins of the in-plane "
          "angle R' - R (rad):", " ".join(f"{e:+.2f}" for e in EDGES))
    print("| case | theta_r | k | per bin (below, between, above the edges) | all |")
    print("|---|---:|---:|---|---:|")
    print("\n".join(by_dir))
    print("\nWeighted by the plate: MC / model of sum_k Int K_k f_r(I, R') dR', orders 0-12")
    print("| case | theta_r | unweighted | " + " | ".join(
        f"{p} {ti:g}" for p in vectors for ti in lights) + " |")
    print("|---|---:|---:|" + "---:|" * (len(vectors) * len(lights)))
    print("\n".join(weighted))
    doc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
