"""Is step 1's uncertainty, propagated into step 2 to first order, what leaves m01 uncovered?

Step 2's ``stderr_total`` adds step 1's covariance linearized, A Cov_m A^T
(veil.fitting.propagation.linear_part; the pipeline now uses sigma points there,
veil.fitting.propagation). At m01 (true tau 0.1) step 1 leaves tau at about its own
size in standard error, so the linearization may be far off. This script runs the physical
pipeline on a path-traced session as benchmarks/bench_validity.py does (target plate, model
error "independent"), then refits the target with the medium drawn from step 1's
distribution (the procedure of veil.analysis.uncertainty.sample_propagation, drawn from the
medium's total covariance, the one step 2 propagated) and puts the shifts' covariance in
place of the linear part:

    total = Cov_t (step 2's own: noise and model-error term) + Cov(shifts)

pushed through f_r's Jacobian at the 111 configurations of the protocol and compared with
the direct fit as veil.pipeline.compare does (direct's standard error in quadrature).

Draws ("--coords"):
- natural: normal in (tau, omega, g), draws outside the bounds redrawn (a truncated normal;
  what sample_propagation does);
- transformed: normal in log tau (tau > 0 always), omega and g natural, the covariance
  carried over to first order (the same linearized covariance); omega > 1 or g >= 1 redrawn.
  (A logit omega fails where step 1 puts omega at its bound 1, as at m05.)

Each draw also gets step 1's chi-square increase on its own data (the reference in the
medium, step 0's f_r held) against the normal's quadratic form (Mahalanobis^2 of the draw
under step 1's noise-only covariance): a ratio >> 1 means the normal puts the draw where
step 1's data rule it out (step 1's own likelihood is not normal either).

Rows: "linear" (what the pipeline reports), "<coords> cov" (centred covariance of the
shifts, sample_propagation's), "<coords> msq" (second moment about the nominal refit: the
shifts' mean, a bias of the nominal estimate, counted as error).

Run:  PYTHONPATH=src python validation/propagation_check.py [--media m01,m05] [--draws 40]
      [--seed 0] [--coords natural,transformed]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))

import bench_validity as bv  # noqa: E402

RHO_WIDE = 45.0


def _pipeline(truth: dict, medium: str):
    from veil import run_pipeline

    names, kw = bv._case(truth, medium, "target", "physical")
    with tempfile.TemporaryDirectory() as tmp:
        res = run_pipeline(bv.table(names["reference_clear"], True),
                           bv.table(names["reference_medium"]), bv.table(names["target_medium"]),
                           black=bv.table(names["black"]),
                           target_clear=bv.table(names["target_clear"], True),
                           outdir=os.path.join(tmp, "out"), figures=False,
                           model_error="independent", propagation="linear", **kw)
    return names, res


def _draws(rng, mean, cov, names, n, cls, coords):
    """n medium draws, normal in natural units or (``transformed``) in log tau with the other
    parameters natural, the covariance carried over to first order; draws outside the
    bounds redrawn (veil.analysis.uncertainty._draw's rejection). Returns (draws, number of
    normal draws made)."""
    k = list(names).index("tau")
    jac = np.eye(len(names))
    if coords == "transformed":
        jac[k, k] = 1.0 / mean[k]
    u0 = mean.copy()
    if coords == "transformed":
        u0[k] = np.log(mean[k])
    chol = np.linalg.cholesky(jac @ cov @ jac.T)
    specs = [cls.param(name) for name in names]
    out, made = [], 0
    while len(out) < n:
        made += 1
        d = u0 + chol @ rng.standard_normal(len(names))
        if coords == "transformed":
            d[k] = np.exp(d[k])
        if all(s.contains(float(v)) for s, v in zip(specs, d)):
            out.append(d)
    return np.array(out), made


def _curve_se(model, angles, names, cov):
    from veil.engine.evaluator import DirectModel

    values, jac = DirectModel(model, angles).value_and_jacobian(model.to_vector())
    order = type(model).param_names()
    j = jac[:, [order.index(n) for n in names]]
    return values, np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", j, cov, j), 0.0))


def check(truth: dict, medium: str, n_draws: int, seed: int, coords_list) -> dict:
    from veil.analysis.uncertainty import _medium_map, covariance_of, curve_stderr, sensitivity
    from veil.data.protocol import protocol
    from veil.fitting.model_error import noise_only
    from veil.fitting.problem import ITERATION_ACCURACY, session_problem
    from veil.fitting.solver import solve
    from veil.pipeline import compare

    t0 = time.perf_counter()
    names, res = _pipeline(truth, medium)
    tr, mr = res.target, res.medium
    theta, cov_own = covariance_of(tr, total=False)
    _, cov_tot = covariance_of(tr, total=True)
    m_names, cov_m = covariance_of(mr, total=True)
    mapped = _medium_map(mr, m_names)
    black = bv.table(names["black"])
    base = session_problem(bv.table(names["target_medium"]), tr.as_model(), mr.as_model(),
                           free=theta, black=black, what="target (in the medium)")
    nominal = solve(base, base.values, max_nfev=50)
    x0 = nominal.x
    it, im = [base.index(n) for n in theta], [base.index(n) for n in mapped]
    a = sensitivity(base, x0, theta, mapped, "fast")
    lin = a @ cov_m @ a.T
    # step 1's data: the reference in the medium, step 0's f_r held
    step1 = session_problem(bv.table(names["reference_medium"]), res.reference.as_model(),
                            mr.as_model(), free=mapped, black=black,
                            what="reference (in the medium)")
    m0 = step1.values[[step1.index(n) for n in mapped]]

    def chi2(mvals):
        x = step1.values.copy()
        x[[step1.index(n) for n in mapped]] = mvals
        return float(np.sum(((step1.model_values(x, ITERATION_ACCURACY) - step1.y)
                             * step1.w) ** 2))

    c0 = chi2(m0)
    _, cov_m_noise = covariance_of(noise_only(mr), total=False)
    prec = np.linalg.inv(cov_m_noise)

    configs = protocol()
    angles = tuple(configs[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    wide = np.abs(configs["rho"].to_numpy()) >= RHO_WIDE
    f_dir, se_dir = curve_stderr(res.direct, angles)
    model = tr.as_model()
    f_est = _curve_se(model, angles, theta, cov_own)[0]
    diff = f_est - f_dir

    def coverage(cov):
        _, se = _curve_se(model, angles, theta, cov)
        z = np.abs(diff) / np.hypot(se, 0.0 if se_dir is None else se_dir)
        return se, float(z.max()), float(np.mean(z <= 2.0)), np.sqrt(np.diag(cov))

    rows = []
    se_lin, zmax, within, p_se = coverage(cov_tot)
    ref = compare(tr, res.direct)
    rows.append(dict(row="linear", zmax=zmax, within=within, ratio_all=1.0, ratio_wide=1.0,
                     params=p_se, pipeline=(ref["fr_max_z"], ref["fr_within_2se"]),
                     lin_check=float(np.max(np.abs(cov_own + lin - cov_tot)
                                            / np.sqrt(np.outer(np.diag(cov_tot),
                                                               np.diag(cov_tot)))))))
    detail = {}
    for coords in coords_list:
        rng = np.random.default_rng(seed)
        draws, made = _draws(rng, m0, cov_m, m_names, n_draws, mr.model_class, coords)
        shifts, conv, ratio_chi = [], [], []
        for d in draws:
            sub = base.with_fixed(dict(zip(mapped, d)))
            start = x0.copy()
            start[im] = d
            sol = solve(sub, start, max_nfev=50)
            shifts.append(sol.x[it] - x0[it])
            conv.append(sol.status > 0)
            dm = d - m0
            ratio_chi.append((chi2(d) - c0) / float(dm @ prec @ dm))
        shifts = np.array(shifts)
        mean_shift = shifts.mean(axis=0)
        for kind, cov_s in (("cov", np.cov(shifts, rowvar=False)),
                            ("msq", shifts.T @ shifts / len(shifts))):
            se, zmax, within, p_se = coverage(cov_own + cov_s)
            rows.append(dict(row=f"{coords} {kind}", zmax=zmax, within=within,
                             ratio_all=float(np.median(se / se_lin)),
                             ratio_wide=float(np.median(se[wide] / se_lin[wide])),
                             params=p_se))
        bias_curve = _curve_se(model, angles, theta, np.outer(mean_shift, mean_shift))[1]
        detail[coords] = dict(accepted=f"{n_draws}/{made}", converged=int(np.sum(conv)),
                              draw_sd=np.sqrt(np.diag(np.cov(draws, rowvar=False))),
                              chi2_ratio=np.percentile(ratio_chi, [10, 50, 90]),
                              mean_shift=mean_shift,
                              shift_sd_vs_linear=np.sqrt(np.diag(np.cov(shifts, rowvar=False))
                                                         / np.diag(lin)),
                              bias_rel_wide=float(np.median(
                                  (bias_curve / np.abs(f_est))[wide])))
    return dict(medium=medium, theta=theta, m_names=m_names, medium_params=m0,
                medium_se=np.sqrt(np.diag(cov_m)), rows=rows, detail=detail,
                diff_rel_wide=float(np.median(np.abs(diff[wide] / f_dir[wide]))),
                seconds=time.perf_counter() - t0)


def report(out: dict) -> None:
    theta = out["theta"]
    med = ", ".join(f"{n} {v:.4f} ± {s:.4f}" for n, v, s in
                    zip(out["m_names"], out["medium_params"], out["medium_se"]))
    print(f"\n{out['medium']} target (physical, model error independent): step 1 {med}; "
          f"{out['seconds']:.0f} s")
    r0 = out["rows"][0]
    print(f"  pipeline's compare: max |z| {r0['pipeline'][0]:.2f}, within 2 se "
          f"{100 * r0['pipeline'][1]:.0f} %; own + A Cov_m A^T vs stderr_total: max rel. "
          f"diff {r0['lin_check']:.1e}")
    head = (f"  {'row':<18}{'max |z|':>8}{'in 2se':>8}{'se/lin':>8}{'|rho|>=45':>10}  "
            + "  ".join(f"se {n:<6}" for n in theta))
    print(head)
    for r in out["rows"]:
        print(f"  {r['row']:<18}{r['zmax']:>8.2f}{100 * r['within']:>7.0f}%"
              f"{r['ratio_all']:>8.2f}{r['ratio_wide']:>10.2f}  "
              + "  ".join(f"{v:<9.2e}" for v in r["params"]))
    for coords, d in out["detail"].items():
        print(f"  {coords}: draws kept {d['accepted']} (normal draws made), refits converged "
              f"{d['converged']}; draws' sd {np.array2string(d['draw_sd'], precision=4)}"
              f" (nominal {np.array2string(out['medium_se'], precision=4)})")
        print(f"    shifts' sd / linear sd {np.array2string(d['shift_sd_vs_linear'], precision=2)}"
              f"; mean shift {np.array2string(d['mean_shift'], formatter={'float': lambda v: f'{v:.1e}'})}; its f_r bias at "
              f"|rho|>=45 {100 * d['bias_rel_wide']:.2f} % (|est - direct| there "
              f"{100 * out['diff_rel_wide']:.2f} %, medians)")
        print(f"    step 1 chi2 increase / normal's quadratic form, 10/50/90 %: "
              f"{np.array2string(d['chi2_ratio'], precision=2)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--media", default="m01,m05")
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--coords", default="natural,transformed")
    bv.add_doc_options(ap, "propagation-check")
    args = ap.parse_args(argv)
    doc_rows = []
    truth = bv.load_truth()
    coords = args.coords.split(",")
    for c in coords:
        if c not in ("natural", "transformed"):
            ap.error(f"--coords {c}: natural or transformed")
    print(f"draws {args.draws} per coordinate system, seed {args.seed}")
    for medium in args.media.split(","):
        out = check(truth, medium, args.draws, args.seed, coords)
        report(out)
        sys.stdout.flush()
        doc_rows += [[out["medium"], r["row"], f"{r['zmax']:.2f}", f"{100 * r['within']:.0f} %",
                      f"{r['ratio_all']:.2f}", f"{r['ratio_wide']:.2f}"]
                     + [f"{v:.2e}" for v in r["params"]] for r in out["rows"]]
        theta = out["theta"]
    if args.doc:
        from doc_tables import markdown, write

        columns = ["session", "propagation", "max \\|z\\|", "within 2 se", "se ratio all",
                   "\\|rho\\| >= 45"] + [f"se {n}" for n in theta]
        write(args.doc, args.doc_table, markdown(columns, doc_rows, set(range(2, len(columns)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
