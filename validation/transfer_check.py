"""Tried and not kept (docs/validity-plate.md): correcting the target's data in the medium by the
reference's relative residual of step 1, smoothed by step 1's own model-discrepancy process.

If the forward model's miss were the same relative error for both plates (the view side's
is nearly so, validation/mc_view_directions.py), the part of it that the medium's
parameters cannot absorb shows in step 1's residuals and would reach step 2 unchanged,
where the target's BRDF parameters absorb it. The check: rho_i, the posterior mean of the
relative error at configuration i given step 1's weighted residuals r (the Gaussian process
of veil.fitting.model_error with step 1's s and ell: K (I + K)^-1 r / a, K = s^2 A R A),
divides the target's values and standard errors, and step 2 is fitted again. Prints the
estimate against the direct fit and the truth, with and without the correction.

    PYTHONPATH=src python validation/transfer_check.py --media m10_w10,m10 [--orders cylinder]
"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
import bench_validity as bv  # noqa: E402

from veil.data.measurements import canonical_angles  # noqa: E402
from veil.fitting import (fit_direct, fit_medium, fit_reference, fit_target,  # noqa: E402
                          model_values, prepare)
from veil.fitting.model_error import correlation, distances  # noqa: E402

CANONICAL = ("theta_i", "phi_i", "theta_r", "phi_r")


def _keys(angles):
    return [tuple(np.round(v, 6)) for v in zip(*angles)]


def check(truth: dict, medium: str) -> list[str]:
    names, kw = bv._case(truth, medium, "target", "physical")
    black = bv.table(names["black"])
    ref = fit_reference(bv.table(names["reference_clear"], True), brdf_model=kw["brdf_model"])
    med = fit_medium(bv.table(names["reference_medium"]), ref, black=black,
                     medium_model=kw["medium_model"], options=kw["medium_options"])
    me = med.model_error
    if me is None or me.residuals is None or me.sigma == 0.0:
        return [f"| {medium} | step 1 shows no correlated model error: nothing to transfer |"]
    r, a = np.asarray(me.residuals), np.asarray(me.scaled)
    k = me.sigma ** 2 * a[:, None] * correlation(distances(me.angles), me.length) * a[None, :]
    rho = k @ np.linalg.solve(np.eye(r.size) + k, r) / a
    target = prepare(bv.table(names["target_medium"]), black, "target").table
    canon = canonical_angles(target)
    where = {key: i for i, key in enumerate(_keys(me.angles))}
    factor = 1.0 + rho[[where[key] for key in _keys(
        tuple(canon[c].to_numpy(float) for c in CANONICAL))]]
    clear = bv.table(names["target_clear"], True)
    cc = canonical_angles(clear)
    angles = tuple(cc[c].to_numpy(float) for c in CANONICAL)
    direct = model_values(fit_direct(clear, brdf_model=kw["brdf_model"]), None, angles)
    rendered = clear["value"].to_numpy(float)
    grazing = np.maximum(angles[0], angles[2]) > 64.0
    rows = []
    for label, scale in (("as measured", 1.0), ("corrected", factor)):
        data = target.copy()
        data["value"] = target["value"] / scale
        data["sigma"] = target["sigma"] / scale
        fitted = fit_target(data, med, brdf_model=kw["brdf_model"])
        est = model_values(fitted, None, angles)
        rel = (est - direct) / direct
        p = fitted.params
        rows.append(
            f"| {medium} | {label} | {100 * np.sqrt(np.mean(rel ** 2)):.2f} % | "
            f"{100 * np.sqrt(np.mean(((est - rendered) / rendered) ** 2)):.2f} % | "
            f"{100 * rel[grazing].mean():+.2f} % | {100 * rel[~grazing].mean():+.2f} % | "
            f"{p['ks']:.3f} | {p['eta']:.4f} |")
        print(rows[-1], file=sys.stderr, flush=True)
    return rows


def main(argv=None) -> int:
    ap = bv.study_parser(__doc__, "m10_w10,m10")
    args = ap.parse_args(argv)
    from doc_tables import printed_tables
    doc = printed_tables(args).start()  # --doc PAGE --doc-table NAME: the table printed below
    bv.ORDERS = args.orders
    truth = bv.load_truth()
    rows = [row for m in args.media.split(",") for row in check(truth, m)]
    print(f"orders = {args.orders}; grazing: a direction beyond 64 deg; true ks 1, eta 1.1178")
    print("| session | target data | estimate vs direct fit | vs truth | mean difference, grazing "
          "| elsewhere | ks | eta |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    doc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
