"""
The paper's failure, reproduced and fixed
=========================================

The paper's failure, reproduced and fixed (docs/model.md sec. 7; docs/ambiguity.md).

A smooth target (n = 0.8, a PVC-like plate) is measured through a strongly scattering drink
(BTDF3). The two-step estimate (docs/model.md sec. 7) takes step 1's medium as exact; a medium
slightly off - inside step 1's own 95 % confidence region, or biased by a forgotten
black-cloth subtraction - turns the smooth target into a rough one, as in the paper
(red PVC: n 0.83 measured directly, 0.20 through the drink). The diagnostics flag the
estimate; a joint fit over three concentrations (the paper's thin, medium and thick media
BTDF1-3, docs/model.md sec. 6) recovers n within its reported uncertainty.

    .venv/bin/python examples/ambiguity.py            # the table of docs/ambiguity.md
    .venv/bin/python examples/ambiguity.py --quick    # smaller protocol, "fast" quadrature

Prints progress and, at the end, the markdown table (also written to --table if given).
Deterministic: fixed seeds, deterministic quadrature and fits.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

import veil
from veil import HenyeyGreenstein, TorranceSparrow
from veil.analysis.diagnostics import diagnose
from veil.analysis.uncertainty import budget_table, propagate
from veil.data.black_cloth import subtract_black
from veil.fitting import Session, fit_joint, fit_medium, fit_reference, fit_target
from veil.io import write_text_atomic

TARGET = TorranceSparrow(Pd=4.57e2, Ps=1.58e6, n=0.8, eta=1.5)     # smooth PVC-like plate
REFERENCE = TorranceSparrow(Pd=2.91e3, Ps=1.34e6, n=0.8, eta=1.5)  # white acrylic
MEDIA = {"x1": veil.BTDF1, "x2": veil.BTDF2, "x3": veil.BTDF3}     # thin -> thick drink
DRINK = "x3"
NOISE = 0.03        # relative noise of a photographed value
#: Mahalanobis distances of the "slightly wrong" media from step 1's estimate; step 1 has four
#: parameters, so its 95 % confidence region reaches 3.08 (chi-square, 4 degrees of freedom).
CONFIDENCE = (2.0, 3.0)


def log(msg, t0=[time.time()]):
    print(f"[{time.time() - t0[0]:6.1f} s] {msg}", flush=True)


def simulate_all(protocol_kw, accuracy):
    """Every session, black cloth subtracted (and the raw reference session of the drink)."""
    kw = dict(noise=NOISE, accuracy=accuracy, **protocol_kw)
    out = {"ref_water": veil.simulate(REFERENCE, None, seed=1, **kw)}
    for k, (label, medium) in enumerate(MEDIA.items()):
        ref, ref_black = veil.simulate(REFERENCE, medium, seed=10 + k, black=True, **kw)
        tgt, tgt_black = veil.simulate(TARGET, medium, seed=20 + k, black=True, **kw)
        out[f"ref_{label}_raw"] = ref
        out[f"ref_{label}"] = subtract_black(ref, ref_black)
        out[f"tgt_{label}"] = subtract_black(tgt, tgt_black)
    return out


def worst_medium(r1, r2, target_table, distance):
    """The medium at Mahalanobis ``distance`` from step 1's estimate (its total covariance)
    in the direction that lowers the target's n the most (linearized, veil.analysis.uncertainty)."""
    p = propagate(r2, r1, target_table)
    names, cov = r1.covariance(total=True)
    a = np.array([p.stats["sensitivity"]["n"][m] for m in names])  # d n / d medium
    step = cov @ a / math.sqrt(a @ cov @ a)
    values = dict(r1.params)
    for m, d in zip(names, -distance * step):
        values[m] += d
    return HenyeyGreenstein(**values, variant=r1.variant), p


def row(label, medium_text, result, se_total=None, flags="", truth=TARGET.n):
    n, se = result.params["n"], result.stderr["n"]
    total = se if se_total is None else se_total
    z = (n - truth) / total if total else float("nan")
    return (f"| {label} | {medium_text} | {n:.3f} | {se:.3f} | {total:.3f} | {z:+.1f} "
            f"| {result.chi2_reduced:.2f} | {flags} |")


def flags_of(diag, name="n"):
    out = []
    for n, reason in diag.poorly_determined:
        if n == name:
            out.append("poorly determined: " + reason.split(" (")[0]
                       .replace("relative standard error", "rel. stderr"))
    for a, b, r in diag.tradeoffs:
        if name in (a, b):
            out.append(f"trades off with {b if a == name else a} (r = {r:+.2f})")
    return "; ".join(out) or "none"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="reduced protocol (2 deg / 10 deg steps) and 'fast' quadrature")
    parser.add_argument("--table", help="also write the markdown table to this file")
    args = parser.parse_args(argv)
    if args.quick:
        protocol_kw, accuracy = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10), "fast"
    else:
        protocol_kw, accuracy = dict(psi=(30, 60, 90)), "default"

    data = simulate_all(protocol_kw, accuracy)
    log(f"simulated {len(data)} sessions of {len(data['ref_water'])} configurations, "
        f"noise {100 * NOISE:g} %")
    tgt = data[f"tgt_{DRINK}"]
    rows = []

    # -- the two-step method through the drink -----------------------------------------
    r0 = fit_reference(data["ref_water"])
    r1 = fit_medium(data[f"ref_{DRINK}"], r0, accuracy=accuracy)
    r2 = fit_target(tgt, r1, accuracy=accuracy)
    log(f"two-step: medium g = {r1.params['g']:.4f} +/- {r1.stderr['g']:.4f}, "
        f"target n = {r2.params['n']:.3f} +/- {r2.stderr['n']:.3f} (own)")
    diag = diagnose(r2, tgt, medium=r1, profile=["n"])
    log("diagnostics of the two-step estimate (medium's uncertainty included):\n"
        + diag.report())
    p = propagate(r2, r1, tgt)
    budget = {b["parameter"]: b for b in budget_table(p)}["n"]
    log(f"n's error budget: step 2 {budget['step2_%']:.0f} %, step 1 {budget['step1_%']:.0f} %, "
        f"step 0 {budget.get('step0_%', 0):.0f} %")
    rows.append(row("two-step", f"step 1 estimate (g = {r1.params['g']:.3f})", r2,
                    p.stderr_total["n"], flags_of(diag)))

    # -- a slightly wrong medium: inside step 1's 95 % region ---------------------------
    for distance in CONFIDENCE:
        wrong, _ = worst_medium(r1, r2, tgt, distance)
        r2w = fit_target(tgt, wrong, accuracy=accuracy)
        log(f"medium at {distance:g} sigma (Mahalanobis) from step 1: {wrong}; target n = "
            f"{r2w.params['n']:.3f} +/- {r2w.stderr['n']:.3f} (own)")
        diag_w = diagnose(r2w, tgt, medium=r1)
        rows.append(row("two-step, medium slightly off",
                        f"{distance:g} sigma from step 1 (g = {wrong.g:.4f}, "
                        f"Tt = {wrong.Tt:.3f}, Td = {wrong.Td:.2g})",
                        r2w, None, flags_of(diag_w) + " (with step 1's uncertainty)"))

    # -- a biased step 1: black cloth forgotten in the reference session -----------------
    r1b = fit_medium(data[f"ref_{DRINK}_raw"], r0, accuracy=accuracy)
    r2b = fit_target(tgt, r1b, accuracy=accuracy)
    log(f"step 1 without black-cloth subtraction: g = {r1b.params['g']:.4f}, Td = "
        f"{r1b.params['Td']:.3g}; target n = {r2b.params['n']:.3f}")
    diag_b = diagnose(r2b, tgt, medium=r1b)
    rows.append(row("two-step, step 1 biased", f"black cloth not subtracted in step 1 "
                    f"(g = {r1b.params['g']:.3f}, Td = {r1b.params['Td']:.2g})", r2b, None,
                    flags_of(diag_b) + " (with step 1's uncertainty)"))

    # -- joint fits ------------------------------------------------------------------------
    def joint(labels):
        sessions = [Session(data["ref_water"], "none", "reference")]
        for label in labels:
            sessions += [Session(data[f"ref_{label}"], label, "reference"),
                         Session(data[f"tgt_{label}"], label, "target")]
        return fit_joint(sessions, accuracy=accuracy), sessions

    j1, s1 = joint([DRINK])
    d1 = diagnose(j1, s1)
    log(f"joint, drink only: n = {j1.params['n']:.3f} +/- {j1.stderr['n']:.3f}")
    rows.append(row("joint, one concentration", "reference and target in x3, reference in "
                    "water", j1, None, flags_of(d1)))
    j3, s3 = joint(list(MEDIA))
    d3 = diagnose(j3, s3)
    log(f"joint, three concentrations: n = {j3.params['n']:.3f} +/- {j3.stderr['n']:.3f}\n"
        + j3.report())
    rows.append(row("joint, three concentrations", "x1, x2, x3 (g per medium, eta_u shared)",
                    j3, None, flags_of(d3)))

    header = ("| estimate | medium | n | stderr (own) | stderr (total) | (n - 0.8) / total "
              "| chi2/dof | diagnostics on n |\n|---|---|---:|---:|---:|---:|---:|---|")
    table = header + "\n" + "\n".join(rows)
    print()
    print(f"True target: {TARGET}; noise {100 * NOISE:g} %; "
          f"{len(tgt)} configurations per session; accuracy {accuracy}")
    print(table)
    if args.table:
        write_text_atomic(args.table, table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
