"""Step 2 given the true medium, with the model-discrepancy term forced to given sizes
(docs/validity-reference.md "The series' declared error: a floor under the term").

The target plate of one path-traced session (validation/data, default m01) is fitted through
the physical models (rough-plastic through the forward-series medium) with the medium held
at its true parameters (truth.json: tau, omega, g; no step 1), and compared with the direct
fit of its clear-water session (veil.pipeline.compare): the share of the paper's protocol's
curves within two standard errors and the largest |z|. The fit's model-discrepancy term is
replaced by the one of each row (veil has no public switch for this: the script wraps
veil.fitting.model_error.step_term, which every weighted fit calls):

- none: no term (the model's declared floor removed, the chi-square test as it is: under its
  limit no term is estimated);
- the limit removed: the chi-square test's limit set to 0, so REML estimates (s, ell) from
  the residuals, without the floor;
- s@ell: the term forced to s (relative) and correlation length ell (deg).

The estimate does not move with the term (the weights stay 1/sigma^2, docs/model.md sec. 7):
only its covariance does.

    PYTHONPATH=src python validation/forced_term.py [--medium m01] [--terms 0.003@40,...]
        [--orders poisson] [--doc docs/validity-reference.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
import bench_validity as bv  # noqa: E402
import doc_tables  # noqa: E402

#: The forced terms of the table: (relative s, correlation length ell in degrees).
TERMS = "0.003@40,0.003@80,0.005@40,0.005@80"


def forcing(mode, sigma=0.0, length=0.0):
    """A replacement of veil.fitting.model_error.step_term: ``mode`` "none" (no floor),
    "reml" (no floor, the chi-square limit 0) or "forced" (the term ``sigma``@``length``)."""
    from veil.fitting import model_error as me

    original = me.step_term

    def step_term(residuals, values, weights, dof, angles, given=None, kind=me.DEFAULT,
                  weighted_jacobian=None, floor=None):
        if mode == "reml":
            threshold = me.chi2_threshold
            me.chi2_threshold = lambda dof: 0.0
            try:
                return original(residuals, values, weights, dof, angles, given, kind,
                                weighted_jacobian, None)
            finally:
                me.chi2_threshold = threshold
        term = original(residuals, values, weights, dof, angles, given, kind,
                        weighted_jacobian, None)
        if mode == "none":
            return term
        return me.ModelError(float(sigma), float(length), term.own, term.given,
                             "model's floor", term.chi2_threshold)

    return original, step_term


def run(medium: str, orders: str, terms: list[tuple[float, float]]) -> list[list[str]]:
    from veil.fitting import fit_direct, fit_target
    from veil.fitting import model_error as me
    from veil.models import model_class
    from veil.pipeline import compare

    bv.ORDERS = orders
    truth = bv.load_truth()
    names, kw = bv._case(truth, medium, "target", "physical")
    true = truth["media"][medium.partition("_")[0]]
    model = model_class(kw["medium_model"], "medium")(
        tau=true["tau"], omega=true["albedo"], g=true["g"], **kw["medium_options"])
    target, black = bv.table(names["target_medium"]), bv.table(names["black"])
    direct = fit_direct(bv.table(names["target_clear"], True), brdf_model=kw["brdf_model"])
    rows = [("none (chi-square under the limit)", "none", 0.0, 0.0),
            ("the limit removed: REML's {s}, ell {ell}", "reml", 0.0, 0.0)]
    rows += [(f"{100 * s:g} %, {ell:g} deg", "forced", s, ell) for s, ell in terms]
    out = []
    for label, mode, s, ell in rows:
        original, patched = forcing(mode, s, ell)
        me.step_term = patched
        t0 = time.perf_counter()
        try:
            est = fit_target(target, model, black=black, brdf_model=kw["brdf_model"],
                             model_error="correlated")
        finally:
            me.step_term = original
        c = compare(est, direct)
        term = est.model_error
        if mode == "none" and term is not None and term.sigma > 0:
            label = f"none: the chi-square ({est.chi2_reduced:.3f}) shows a term all the same"
        if mode == "reml":
            label = label.format(s=f"{100 * term.sigma:.2g} %", ell=f"{term.length:g}")
        print(f"{label}: reduced chi-square {est.chi2_reduced:.4f} (limit "
              f"{term.chi2_threshold if term else float('nan'):.4f}), within 2 se "
              f"{100 * c['fr_within_2se']:.0f} %, max |z| {c['fr_max_z']:.2f}, "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        if mode == "none":
            zs = ", ".join(f"{k} {r['estimated']:.4g} against {r['direct']:.4g} (z "
                           f"{r['z']:.2f})" for k, r in c["params"].items()
                           if r["z"] is not None)
            print(f"  the estimate: {100 * c['rms_fr_relative']:.2f} % RMS off the direct fit; "
                  f"{zs}", file=sys.stderr, flush=True)
        out.append([label, f"{100 * c['fr_within_2se']:.0f} %", f"{c['fr_max_z']:.2f}"])
    return out


def main(argv=None) -> int:
    from veil.models.forward_series import ORDER_WEIGHTS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--medium", default="m01", help="the session's medium (validation/data)")
    ap.add_argument("--orders", default="poisson", choices=ORDER_WEIGHTS,
                    help="the physical medium's order weights")
    ap.add_argument("--terms", default=TERMS, metavar="S@ELL,...",
                    help="the forced terms: relative s and length ell (deg)")
    doc_tables.add_options(ap, "forced-term")
    args = ap.parse_args(argv)
    terms = [tuple(float(v) for v in t.split("@")) for t in args.terms.split(",") if t]
    with doc_tables.printed_tables(args):
        rows = run(args.medium, args.orders, terms)
        print(doc_tables.markdown(["term", "within 2 se", "max \\|z\\|"], rows, {1, 2}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
