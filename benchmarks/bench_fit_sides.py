"""Two veils' single fits side by side: this checkout's and another source tree's (--src).

    .venv/bin/python benchmarks/bench_fit_sides.py --src /old/checkout/src [--rounds 3]

Alternating fresh processes, the other veil first in each round, each with a persistent
compilation cache of its own (VEIL_CACHE_DIR under the system's temporary folder). In each
process, the wall and CPU seconds (process time, all threads) of the second, warm, run of:
the joint fit at "fast" and at "default" (bench_joint.py's sessions), step 1 and step 2 at
"default" (bench_fit.py's sessions), the whole pipeline (bench_fit.py's), and step 2 at "fast"
on the two pixels of bench_maps.py's full fit (BRDF1 through BTDF2, index fixed). The table
gives both and their ratios (this checkout over --src) per round, with the function /
Jacobian evaluations and the load average at the start of each process: on a shared machine
the CPU seconds are the steadier measure.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, sys, tempfile, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import veil, bench_fit, bench_joint, bench_maps
from support.maps import render
out = {}
def timed(label, f):
    f()
    w, c = time.perf_counter(), time.process_time()
    r = f()
    out[label] = [time.perf_counter() - w, time.process_time() - c, r]
def evals(fit):
    return [fit.stats.get("nfev"), fit.stats.get("njev")]
tables = bench_joint.sessions()
for acc in ("fast", "default"):
    timed(f"joint {acc}", lambda: [bench_joint.one_fit(tables, acc)[k] for k in ("nfev", "njev")])
d = tempfile.mkdtemp()
bench_fit.simulate_sessions(d)
ref = veil.fit_reference(f"{d}/reference_clear.csv")
step1 = lambda: veil.fit_medium(f"{d}/reference_medium.csv", ref, black=f"{d}/black.csv")
timed("step 1 (medium)", lambda: evals(step1()))
med = step1()
timed("step 2 (target)", lambda: evals(veil.fit_target(f"{d}/target_medium.csv", med,
                                                       black=f"{d}/black.csv")))
timed("pipeline", lambda: veil.run_pipeline(
    f"{d}/reference_clear.csv", f"{d}/reference_medium.csv", f"{d}/target_medium.csv",
    black=f"{d}/black.csv", outdir=tempfile.mkdtemp()) and None)
configs = bench_maps.protocol_configs()
brdf, medium = veil.BRDF1, veil.BTDF2
names = type(brdf).param_names()
fixed = {names[3]: float(brdf.to_vector()[3])}
rng = np.random.default_rng(5)
truth = []
for _ in range(2):
    v = brdf.to_vector().copy()
    v[2] *= np.exp(rng.uniform(-0.4, 0.4))
    truth.append(v)
y = render(brdf, medium, configs, np.array(truth))
y = y * (1 + 0.01 * rng.standard_normal(y.shape))
for k in range(2):
    timed(f"bench_maps' full fit, pixel {k + 1}", lambda: evals(veil.fit_target(
        configs.assign(value=y[k]), medium, fixed=fixed, accuracy="fast")))
print(json.dumps(out))
"""


def label_of(src: Path) -> str:
    """The commit of a source tree's checkout (short), or its path."""
    proc = subprocess.run(["git", "-C", str(src), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True)
    return proc.stdout.strip() or str(src)


def one(src: Path, cache: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "VEIL_CACHE_DIR": cache}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(HERE)], env=env,
                          capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"the run of {src} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--src", required=True, type=Path,
                        help="the other veil's source folder (its src/), e.g. an older checkout")
    parser.add_argument("--rounds", type=int, default=3)
    from doc_tables import add_options, printed_tables
    add_options(parser, "fit-sides")
    args = parser.parse_args()
    doc = printed_tables(args).start()
    trees = {"other": args.src.resolve(), "this": HERE.parent / "src"}
    labels = {k: label_of(v) for k, v in trees.items()}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-fit-sides-") as tmp:
        for r in range(1, args.rounds + 1):
            load, rec = {}, {}
            for side, src in trees.items():
                load[side] = os.getloadavg()[0]
                rec[side] = one(src, f"{tmp}/cache-{side}")
                print(f"round {r}, {labels[side]}: {json.dumps(rec[side])}", flush=True)
            rows.append((r, load, rec))
    print(f"\n{labels['this']} (this checkout) against {labels['other']} (--src); "
          f"{os.cpu_count()} CPUs\n")
    print(f"| what | round | wall s {labels['other']} / {labels['this']} | CPU s "
          f"{labels['other']} / {labels['this']} | ratio wall | ratio CPU | evals "
          f"{labels['other']} / {labels['this']} | load at the starts |")
    print("|---|---:|---|---|---:|---:|---|---|")
    for what in rows[0][2]["this"]:
        for r, load, rec in rows:
            (ow, oc, oe), (nw, nc, ne) = rec["other"][what], rec["this"][what]
            print(f"| {what} | {r} | {ow:.2f} / {nw:.2f} | {oc:.2f} / {nc:.2f} | {nw / ow:.2f} "
                  f"| {nc / oc:.2f} | {oe or '-'} / {ne or '-'} | {load['other']:.1f}, "
                  f"{load['this']:.1f} |")
    doc.finish()


if __name__ == "__main__":
    main()
