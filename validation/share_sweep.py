"""Where does the estimate leave its uncertainty, and how does that depend on the share c?

Step 2's total covariance has a cross term with step 1's correlated model error, scaled by
the session correlation c that step 2 estimates (veil.fitting.model_error.session_correlation;
docs/validity-plate.md). This script runs the physical pipeline on one path-traced
session as benchmarks/bench_validity.py does (target plate, model error "correlated",
propagation "auto"), then:

1. recomputes the target's total uncertainty (veil.analysis.uncertainty.propagate) with c
   replaced by each value of --shares (step 2's own covariance unchanged: only the cross
   term moves) and prints, for each, the share of the protocol's 111 configurations whose
   curve lies within two standard errors of the direct fit, and the largest |z|;
2. lists the configurations outside two standard errors at the fitted c, with the relative
   difference estimate - direct and the estimate's relative standard error.

Run:  .venv/bin/python validation/share_sweep.py [--media m10_w10] [--orders cylinder]
      [--reference ref|smooth] [--shares 0,0.25,0.5,0.75,fitted,1]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "benchmarks"))

import bench_validity as bv  # noqa: E402  (the benchmark's cases and tables)


def sweep(medium: str, orders: str, shares: list) -> dict:
    from veil import run_pipeline
    from veil.analysis.uncertainty import curve_stderr, propagate
    from veil.data.protocol import protocol
    from veil.pipeline import compare

    bv.ORDERS = orders
    truth = bv.load_truth()
    names, kw = bv._case(truth, medium, "target", "physical")
    t = {k: bv.table(v, k.endswith("clear")) for k, v in names.items() if k != "session"}
    with tempfile.TemporaryDirectory() as out:
        res = run_pipeline(t["reference_clear"], t["reference_medium"], t["target_medium"],
                           black=t["black"], target_clear=t["target_clear"], outdir=out,
                           figures=False, model_error="correlated", propagation="auto", **kw)
    target, direct = res.target, res.direct
    fitted = target.model_error.session_correlation if target.model_error else None
    rows = []
    for c in dict.fromkeys(fitted if c == "fitted" else float(c) for c in shares):
        if c is None:
            continue
        term = dataclasses.replace(target.model_error, session_correlation=c)
        again = propagate(dataclasses.replace(target, model_error=term), res.medium,
                          t["target_medium"], black=t["black"], reference_result=res.reference,
                          reference_table=t["reference_medium"], reference_black=t["black"])
        cmp = compare(again, direct)
        rows.append({"c": c, "within_2se": cmp["fr_within_2se"], "max_z": cmp["fr_max_z"]})
    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    est, se = curve_stderr(target, angles)
    ref, se_direct = curve_stderr(direct, angles)
    z = (est - ref) / np.hypot(se, 0.0 if se_direct is None else se_direct)
    outside = configs.assign(z=z, difference=(est - ref) / ref, se_relative=se / est)
    return {"fitted": fitted, "rows": rows, "outside": outside[np.abs(z) > 2.0],
            "target": target.params, "direct": direct.params}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--media", default="m10_w10")
    ap.add_argument("--orders", default="cylinder",
                    choices=("poisson", "cylinder", "light-side", "view-side"))
    ap.add_argument("--reference", default="ref", choices=("ref", "smooth"),
                    help="the reference plate (bench_validity --reference)")
    ap.add_argument("--shares", default="0,0.25,0.5,0.75,fitted,1",
                    help="values of c, comma-separated; 'fitted' is step 2's estimate")
    bv.add_doc_options(ap, "share-sweep")
    args = ap.parse_args(argv)
    bv.REFERENCE = args.reference
    shares = [s.strip() for s in args.shares.split(",")]
    doc_columns, doc_cells = ["c"], {s: [] for s in shares}  # for --doc: one row per share
    for s in shares:
        if s != "fitted":
            try:
                ok = 0.0 <= float(s) <= 1.0
            except ValueError:
                ok = False
            if not ok:
                ap.error(f"--shares: {s!r} is not a number in [0, 1] or 'fitted'")
    for medium in args.media.split(","):
        out = sweep(medium.strip(), args.orders, shares)
        print(f"\n{medium} ({args.orders} orders): fitted c = {out['fitted']}")
        print("target", {k: round(v, 4) for k, v in out["target"].items()},
              "\ndirect", {k: round(v, 4) for k, v in out["direct"].items()})
        print("| c | curves within 2 se | max |z| |\n|---:|---:|---:|")
        for r in out["rows"]:
            print(f"| {r['c']:.2f} | {100 * r['within_2se']:.0f} % | {r['max_z']:.2f} |")
        doc_columns += [f"{medium}: curves within 2 se", "max \\|z\\|"]
        by_c = {r["c"]: r for r in out["rows"]}
        for s in doc_cells:
            r = by_c.get(out["fitted"] if s == "fitted" else float(s))
            fitted = f" (c = {r['c']:.2f})" if r and s == "fitted" else ""
            doc_cells[s] += ([f"{100 * r['within_2se']:.0f} %{fitted}", f"{r['max_z']:.2f}"]
                             if r else ["-", "-"])
        cols = ["psi", "rho", "theta_i", "theta_r", "z", "difference", "se_relative"]
        print(f"\noutside two standard errors at the fitted c ({len(out['outside'])}):")
        if len(out["outside"]):
            print(out["outside"][[c for c in cols if c in out["outside"]]]
                  .to_string(index=False))
    if args.doc:
        from doc_tables import markdown, write

        write(args.doc, args.doc_table, markdown(
            doc_columns, [[s] + cells for s, cells in doc_cells.items()],
            set(range(1, len(doc_columns)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
