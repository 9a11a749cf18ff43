"""Speed of the physical medium ``forward-series`` against the paper's ``henyey-greenstein``,
side by side in one process, for the same BRDF (issue 12, item 2: the physical medium must
evaluate at least as many configurations per second as the paper's).

Cases: BRDF TS (the paper's torrance-sparrow, preset BRDF2) and rough-plastic (alpha 0.1 in
water), each through
  HG      henyey-greenstein, preset BTDF2 (g = 0.93, eta = 1.3)
  FS      forward-series tau = 1, omega = 0.99, g = 0.93, eta_u = 1.3 (infinite plate)
  FS+pl   the same with the set-up geometry path_length = 15, plate_width = 5
on the in-plane configurations of bench_apparent.py (--quick: psi = 60, 90 deg), rule
"default", after compilation. The machine is shared: the cases are timed interleaved, round
after round, by the CPU time of this process (insensitive to other jobs, but it counts both
devices' threads), and the table reports medians over the rounds and the ratio FS/HG of the
medians within each BRDF.

    python benchmarks/bench_forward_series.py            # 184 configurations, 7 rounds
    python benchmarks/bench_forward_series.py --quick    # 98 configurations
    python benchmarks/bench_forward_series.py --accuracy # accuracy instead of speed

--accuracy: the engine at the default rule against (a) the independent reference
tests/reference_physical.py (docs/model.md sec. 8 in numpy; Gauss rules and QMC, with its standard
error) and (b) the engine itself at three times the nodes per dimension (its quadrature
error), for TS (BRDF2) through forward-series tau = 1, omega = 0.99, g = 0.88 with the
options of tests/test_model_contract.py (the paper's Fresnel variant, eta_u = 1; the exit
variant at eta_u = 1.33; the finite plate), at a few configurations.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

import veil  # noqa: F401  (sets up JAX: float64, one CPU device per core)
from veil.engine.forward import Forward
from veil.engine.quadrature import RULES
from veil.models import PRESETS, REGISTRY

sys.path.insert(0, os.path.dirname(__file__))
from bench_apparent import configurations
from doc_tables import add_options, printed_tables

BRDFS = {
    "TS": PRESETS["BRDF2"],
    "rough-plastic": REGISTRY["rough-plastic"](rho=0.5, alpha=0.1, eta=1.12, ks=1.0),
}
_FS = dict(tau=1.0, omega=0.99, g=0.93, eta_u=1.3, s=1.0)
MEDIA = {
    "HG": PRESETS["BTDF2"],
    "FS": REGISTRY["forward-series"](**_FS),
    "FS+plate": REGISTRY["forward-series"](**_FS, path_length=15.0, plate_width=5.0),
}


ACCURACY_CASES = {
    "paper, eta_u 1": ({}, {}),
    "exit, eta_u 1.33": ({"eta_u": 1.33}, {"variant": "exit"}),
    "plate 15/5": ({}, {"path_length": 15.0, "plate_width": 5.0}),
}
ACCURACY_CONFIGS = ((20.0, 25.0), (60.0, 10.0), (40.0, 40.0), (5.0, 70.0))


def accuracy(n_qmc: int, n_rep: int):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
    import reference as ref
    import reference_physical as rphys

    brdf = PRESETS["BRDF2"]
    pd, ps, n, eta = (float(x) for x in brdf.to_vector())

    def brdf_fn(wi, wo):
        ti = np.degrees(np.arccos(np.clip(wi[..., 2], -1, 1)))
        pi_ = np.degrees(np.arctan2(wi[..., 1], wi[..., 0]))
        tr = np.degrees(np.arccos(np.clip(wo[..., 2], -1, 1)))
        pr = np.degrees(np.arctan2(wo[..., 1], wo[..., 0]))
        return ref.reference_reflectance((pd, ps, n, eta), ti, pi_, tr, pr)
    brdf_fn.sampling_alpha = np.radians(np.sqrt(np.log(2)) / n)

    ti = np.array([c[0] for c in ACCURACY_CONFIGS])
    tr = np.array([c[1] for c in ACCURACY_CONFIGS])
    print("| case | theta_i | theta_r | engine | reference +- stderr | engine/reference - 1 "
          "| engine/engine(3x nodes) - 1 |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    worst_ref, worst_self = 0.0, 0.0
    for name, (values, opts) in ACCURACY_CASES.items():
        v = dict(tau=1.0, omega=0.99, g=0.88, eta_u=1.0, s=1.0)
        v.update(values)
        medium = REGISTRY["forward-series"].from_params(v, opts)
        vb, vm = brdf.to_vector(), medium.to_vector()
        got = Forward(brdf, medium, ti, tr, rule=RULES["default"])(vb, vm)
        fine = Forward(brdf, medium, ti, tr, rule=RULES["default"].scaled(3.0))(vb, vm)
        for k in range(ti.size):
            want, se = rphys.forward_series_apparent(
                brdf_fn, v["tau"], v["omega"], v["g"], v["eta_u"], ti[k], tr[k],
                variant=opts.get("variant", "paper"), path_length=opts.get("path_length"),
                plate_half_width=opts.get("plate_width", 0) / 2 or None, n_qmc=n_qmc,
                n_rep=n_rep)
            e_ref, e_self = got[k] / want - 1, got[k] / fine[k] - 1
            worst_ref, worst_self = max(worst_ref, abs(e_ref)), max(worst_self, abs(e_self))
            print(f"| {name} | {ti[k]:.0f} | {tr[k]:.0f} | {got[k]:.6g} | {want:.6g} +- "
                  f"{se / want:.1e} | {e_ref:+.1e} | {e_self:+.1e} |", flush=True)
    print(f"\nworst |engine/reference - 1| {worst_ref:.1e}; worst |engine/engine(3x) - 1| "
          f"{worst_self:.1e}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="psi = 60, 90 deg only")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    ap.add_argument("--calls", type=int, default=3, help="engine calls per case and round")
    ap.add_argument("--accuracy", action="store_true", help="accuracy against the reference")
    ap.add_argument("--qmc", type=int, default=2 ** 13, help="reference QMC points per rep")
    add_options(ap, "forward-series")
    args = ap.parse_args(argv)
    doc = printed_tables(args).start()
    if args.accuracy:
        status = accuracy(args.qmc, 8)
        doc.finish()
        return status

    cfg = configurations(args.quick)
    ti, tr = cfg[:, 0], cfg[:, 1]
    cases = {}
    for bn, b in BRDFS.items():
        for mn, m in MEDIA.items():
            fwd = Forward(b, m, ti, tr, rule=RULES["default"])
            vb, vm = b.to_vector(), m.to_vector()
            fwd(vb, vm)  # compile
            cases[(bn, mn)] = (fwd, vb, vm)
    print(f"# {len(cfg)} in-plane configurations, rule 'default', {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f}; {args.rounds} interleaved rounds of {args.calls} "
          f"calls per case", flush=True)
    cpu = {k: [] for k in cases}
    wall = {k: [] for k in cases}
    for _ in range(args.rounds):
        for key, (fwd, vb, vm) in cases.items():
            t0, w0 = time.process_time(), time.perf_counter()
            for _ in range(args.calls):
                fwd._last.clear()  # the engine would answer a repeated call from its memo
                fwd(vb, vm)
            cpu[key].append((time.process_time() - t0) / args.calls)
            wall[key].append((time.perf_counter() - w0) / args.calls)
    print()
    print("| BRDF | medium | configurations per CPU-second (median) | range over rounds "
          "| configurations/s wall (median) | ratio to HG: of the medians | ratio to HG: "
          "median over rounds (range) |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for bn in BRDFS:
        base = len(cfg) / statistics.median(cpu[(bn, "HG")])
        for mn in MEDIA:
            c = [len(cfg) / t for t in cpu[(bn, mn)]]
            rate = len(cfg) / statistics.median(cpu[(bn, mn)])
            w = len(cfg) / statistics.median(wall[(bn, mn)])
            # within a round the cases ran minutes apart at most: the round's own ratio
            r = [h / t for t, h in zip(cpu[(bn, mn)], cpu[(bn, "HG")])]
            print(f"| {bn} | {mn} | {rate:.0f} | {min(c):.0f}-{max(c):.0f} | {w:.0f} | "
                  f"{rate / base:.2f} | {statistics.median(r):.2f} ({min(r):.2f}-{max(r):.2f}) |")
    print(f"\nload after the run {os.getloadavg()[0]:.1f}")
    doc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
