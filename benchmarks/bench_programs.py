"""Run time of the engine's programs for two or more versions of veil, side by side.

What a fit spends its time on: the values at the "default" rule (the polish and the reported
curves) and the Jacobians at the "fast" rule, in the BRDF's parameters and in the medium's
(the iterations), at 64 in-plane configurations (one chunk of a fit), after compilation.
Each ``--src`` folder (a checkout's ``src/``, e.g. ``git archive REV src | tar -x -C DIR``)
is run in a fresh process with its own program store; the versions alternate, round after
round, so that the host's load falls on all of them alike. The table gives the median over
the rounds in milliseconds per call and the ratio to the first ``--src``.

    python benchmarks/bench_programs.py --src /tmp/before/src --src src --rounds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

#: The pairs timed: the paper's presets and the physical models of the validation set-up.
PAIRS = ("BRDF1 x BTDF2", "BRDF2 x BTDF3", "rough-plastic x forward-series")
COLUMNS = ("values, default rule", "d/d BRDF, fast rule", "d/d medium, fast rule")

#: The child: one version of veil, every pair, one line of JSON {pair: [ms, ms, ms]}.
CHILD = r"""
import json, time
import numpy as np
import veil
from veil.engine.forward import Forward
from veil.engine.quadrature import RULES
from veil.models.registry import model_class

def models(name):
    if name == "rough-plastic x forward-series":
        return (model_class("rough-plastic", "brdf")(rho=0.3, alpha=0.2, eta=1.5, ks=1.0),
                model_class("forward-series", "medium")(tau=0.6, omega=0.98, g=0.95,
                                                         path_length=15.0, plate_width=5.0))
    b, m = name.split(" x ")
    return veil.preset(b), veil.preset(m)

def per_call(fn, calls):
    fn()  # compiled (or loaded) and run once
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls * 1e3

theta = np.linspace(5.0, 70.0, 64)
out = {}
for name in PAIRS:
    b, m = models(name)
    vb, vm = b.to_vector(), m.to_vector()
    values = Forward(b, m, theta, theta[::-1], rule=RULES["default"])
    fast = Forward(b, m, theta, theta[::-1], rule=RULES["fast"])
    every_b, every_m = tuple(range(len(vb))), tuple(range(len(vm)))
    out[name] = [per_call(lambda: values(vb, vm), 10),
                 per_call(lambda: fast.value_and_jacobian(vb, vm, every_b, ()), 15),
                 per_call(lambda: fast.value_and_jacobian(vb, vm, (), every_m), 15)]
print(json.dumps(out))
"""


def run(src: str, store: str) -> dict:
    env = {**os.environ, "PYTHONPATH": os.path.abspath(src), "VEIL_CACHE_DIR": store}
    done = subprocess.run([sys.executable, "-c", f"PAIRS = {PAIRS!r}\n" + CHILD],
                          capture_output=True, text=True, env=env)
    if done.returncode != 0:
        sys.exit(f"bench_programs: the veil of {src} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def table(srcs: list, medians: dict) -> str:
    first = srcs[0]
    lines = ["| pair | program | " + " | ".join(f"`{s}` ms" for s in srcs)
             + "".join(f" | `{s}` / `{first}`" for s in srcs[1:]) + " |",
             "|---|---|" + "---:|" * (2 * len(srcs) - 1)]
    for pair in PAIRS:
        for k, column in enumerate(COLUMNS):
            ms = [medians[s][pair][k] for s in srcs]
            lines.append(f"| {pair} | {column} | " + " | ".join(f"{v:.1f}" for v in ms)
                         + "".join(f" | {v / ms[0]:.2f}" for v in ms[1:]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", action="append", required=True,
                    help="a veil source folder (its src/); give two or more")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of alternating runs")
    a = ap.parse_args(argv)
    if len(a.src) < 2 or a.rounds < 1:
        ap.error("give at least two --src folders and at least one round")
    for src in a.src:
        if not os.path.isdir(os.path.join(src, "veil")):
            ap.error(f"--src {src}: no veil package there (expected {src}/veil)")
    results: dict = {s: [] for s in a.src}
    with tempfile.TemporaryDirectory(prefix="veil-bench-programs-") as work:
        for r in range(a.rounds):
            for k, src in enumerate(a.src):
                results[src].append(run(src, os.path.join(work, f"store-{k}")))
                print(f"round {r + 1}/{a.rounds}: {src} done, load "
                      f"{os.getloadavg()[0]:.1f}", flush=True)
    medians = {s: {p: [statistics.median(run[p][k] for run in results[s])
                       for k in range(len(COLUMNS))] for p in PAIRS} for s in a.src}
    one, five, _ = os.getloadavg()
    print(f"\n`{' '.join(['benchmarks/bench_programs.py'] + (argv or sys.argv[1:]))}`, "
          f"{os.cpu_count()} cores, medians of {a.rounds} rounds, load {one:.1f} "
          f"(5 min {five:.1f}) at the end\n")
    print(table(a.src, medians))
    return 0


if __name__ == "__main__":
    sys.exit(main())
