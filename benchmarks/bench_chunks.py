"""Programs and run time by call size, this checkout against another source tree (--src).

    .venv/bin/python benchmarks/bench_chunks.py --src /old/checkout/src [--rounds 2]

The engine runs every call of up to veil.engine.forward.CHUNK configurations with one
program, and pads f_r to veil.engine.apparent.DIRECT_CHUNK or the power of two above,
where it used to compile a program per padded size (8, 16, 32, then multiples of 64).
Each round runs, in fresh processes, the other veil first, each with an empty program
store and compilation cache of its own:

- cold: ``veil.apparent`` (Torrance-Sparrow x Henyey-Greenstein, fast rule, in-plane) at
  5, 12, 40, 64, 111, 200 and 700 configurations, one after the other, at the default rule
  at 1 and 12, and f_r of the rough plastic at 111, 700 and 5000: the engine programs
  compiled and the seconds of the whole sequence;
- warm, in the same process: each call again, the median of five (milliseconds).

The table gives both and their ratio (this checkout over --src); on a shared machine
compare within a round.
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
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import veil
from veil.engine import compiling
from veil.models import model_class
compiled = []
compiling.listen(lambda event, c, t: compiled.append(c.label) if event == "end" else None)
rp = model_class("rough-plastic")(rho=0.3, alpha=0.2, eta=1.5, ks=1.0)
rng = np.random.default_rng(0)
calls = []
for n in (5, 12, 40, 64, 111, 200, 700):
    ti, tr = rng.uniform(0, 80, n), rng.uniform(0, 80, n)
    calls.append((f"apparent, {n} configurations",
                  lambda ti=ti, tr=tr: veil.apparent("BRDF1", "BTDF1", ti, tr, accuracy="fast")))
for n in (1, 12):
    ti, tr = rng.uniform(0, 80, n), rng.uniform(0, 80, n)
    calls.append((f"apparent, default rule, {n} configuration{'s' if n > 1 else ''}",
                  lambda ti=ti, tr=tr: veil.apparent("BRDF1", "BTDF1", ti, tr)))
for n in (111, 700, 5000):
    ti, tr = rng.uniform(0, 80, n), rng.uniform(0, 80, n)
    calls.append((f"f_r of a rough plastic, {n} configurations",
                  lambda ti=ti, tr=tr: veil.reflectance(rp, ti, tr)))
w = time.perf_counter()
for _, call in calls:
    call()
out = {"cold s": time.perf_counter() - w, "programs": len(compiled)}
for label, call in calls:
    times = []
    for _ in range(5):
        t = time.perf_counter()
        call()
        times.append(time.perf_counter() - t)
    out[label] = 1000 * statistics.median(times)
print("RESULT " + json.dumps(out))
"""


def run(src: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-chunks-") as cache:
        env = dict(os.environ, VEIL_CACHE_DIR=cache, PYTHONWARNINGS="ignore")
        done = subprocess.run([sys.executable, "-c", CHILD, src], env=env, text=True,
                              capture_output=True, check=False)
    line = [ln for ln in done.stdout.splitlines() if ln.startswith("RESULT ")]
    if done.returncode != 0 or not line:
        raise SystemExit(f"the run with {src} failed:\n{done.stderr[-3000:]}")
    return json.loads(line[0][7:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--src", required=True, help="the other veil's src/ folder")
    parser.add_argument("--rounds", type=int, default=1)
    sys.path.insert(0, str(HERE))
    from doc_tables import add_options, markdown, printed_tables
    add_options(parser, "chunks")
    args = parser.parse_args()
    if not (Path(args.src) / "veil").is_dir():
        print(f"--src {args.src}: no veil package there", file=sys.stderr)
        raise SystemExit(2)
    here = str(HERE.parent / "src")
    doc = printed_tables(args).start()
    rows = []
    for r in range(args.rounds):
        other, this = run(args.src), run(here)
        load = os.getloadavg()[0]
        for key in this:
            unit = "" if key == "programs" else (" (s)" if key == "cold s" else " (ms, warm)")
            name = "cold sequence" if key == "cold s" else key
            fmt = "{:.0f}" if key == "programs" else "{:.2f}"
            ratio = this[key] / other[key] if other[key] else float("nan")
            rows.append([str(r + 1), name + unit, fmt.format(other[key]), fmt.format(this[key]),
                         f"{ratio:.2f}", f"{load:.1f}"])
    print(markdown(["round", "what", "--src", "this checkout", "ratio", "load"], rows,
                   right={2, 3, 4, 5}))
    doc.finish()


if __name__ == "__main__":
    main()
