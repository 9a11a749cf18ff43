"""Would a view side right in theta_r close the 10 cm plate's gap? An oracle check (docs/validity-plate.md).

validation/mc_view_directions.py measures, weighted by the plates' own f_r, the ratio
Monte Carlo / model of the view side as nearly a function of the view angle theta_r alone,
the same for both plates to 0.001 (docs/physics-orders.md sec. 8): the model is too dark at normal
view and too bright towards grazing. If that trend is what leaves the estimate outside its
uncertainty, a forward model that had it right would fix it. The oracle: fitting model x r
to the data is fitting the model to data / r, so the medium sessions' values and standard
errors (reference and target) are divided by r(|theta_r|), a quadratic in theta_r through
the four measured ratios of that case (below; the target plate, light at 30 deg, 10^6
paths), and the pipeline is run as bench_validity.py runs it. Uses the truth (r is
measured at the true tau and g): it says whether building the conditional landing fraction
is worth it, not how well a model would do.

    PYTHONPATH=src python validation/view_trend_oracle.py [--media m10_w10,m10,m10_r10,m15]
        [--orders cylinder]
"""
import os
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
import bench_validity as bv  # noqa: E402

#: MC / model of the view side at theta_r = 0, 30, 60, 75 deg (mc_view_directions.py, the
#: target plate, light at 30 deg; docs/physics-orders.md sec. 8's table).
MEASURED_ANGLES = np.array([0.0, 30.0, 60.0, 75.0])
MEASURED = {"m10": [1.0067, 1.0056, 1.0022, 0.9988],
            "m10_w10": [1.0124, 1.0096, 0.9999, 0.9928],
            "m10_r10": [1.0100, 1.0072, 1.0012, 0.9967],
            "m15": [1.0167, 1.0132, 1.0044, 0.9952]}


def ratio(medium: str):
    """r(theta_r): the quadratic least-squares fit through the case's four ratios."""
    coef = np.polyfit(MEASURED_ANGLES, MEASURED[medium], 2)
    return lambda theta_r: np.polyval(coef, np.abs(theta_r))


def main(argv=None) -> int:
    ap = bv.study_parser(__doc__, "m10_w10,m10,m10_r10,m15")
    args = ap.parse_args(argv)
    bv.ORDERS = args.orders
    truth = bv.load_truth()
    plain_table = bv.table
    rows = []
    for medium in args.media.split(","):
        if medium not in MEASURED:
            ap.error(f"no measured view-side ratios for {medium}; known: {', '.join(MEASURED)}")
        names = bv.sessions_of(truth, medium, "target")
        corrected = {names["reference_medium"], names["target_medium"]}
        r = ratio(medium)

        def divided(name, unweighted=False, r=r, corrected=corrected):
            t = plain_table(name, unweighted)
            if name in corrected:
                factor = r(t["theta_r"].to_numpy(float))
                t["value"] = t["value"] / factor
                t["sigma"] = t["sigma"] / factor
            return t

        for label, fn in (("as measured", plain_table), ("divided by r(theta_r)", divided)):
            bv.table = fn
            try:
                row = bv.run_case(truth, medium, "target", "physical",
                                  os.path.join(tempfile.mkdtemp(prefix="veil-oracle-"), "out"))
            finally:
                bv.table = plain_table
            row["target"] = label
            rows.append(row)
            print(f"{medium} {label}: est vs direct {100 * row['est_vs_direct']:.2f} %, "
                  f"within 2 se {100 * row['fr_within_2se']:.0f} %, max |z| "
                  f"{row['fr_max_z']:.2f}, tau {row['tau']:.4f}, g {row['g']:.4f}",
                  file=sys.stderr, flush=True)
    bv.print_table(rows)
    bv.write_doc(args, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
