"""Start-up benchmark of the command line (issue 16; docs/performance-startup.md "Start-up").

Each command runs as a fresh process of the ``veil`` program, as a user would run it:

- "cold cache": VEIL_CACHE_DIR is a new, empty folder (no stored engine programs, no
  compiled executables: what the very first run on a machine pays);
- "cache filled": the same folder after that first run (and, with --warmup, after
  ``veil warmup``), median of ``--runs`` (5) runs, with the lowest and highest.

The sessions of ``veil fit pipeline`` (the paper's protocol: reference BRDF2 in clear water and
in BTDF1 with a black cloth, target BRDF1 in BTDF1, 1 % noise) are simulated first, not
timed. CPU seconds (user + system of the process, both cores) are printed beside the wall
seconds: the machine is shared, and CPU time is the figure that load does not inflate.

    .venv/bin/python benchmarks/bench_startup.py                 # this checkout's veil
    .venv/bin/python benchmarks/bench_startup.py --veil /other/.venv/bin/veil   # compare
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_VEIL = os.path.join(os.path.dirname(sys.executable), "veil")

#: (label, arguments, target seconds with the cache filled or None)
COMMANDS = [
    ("veil --help", ["--help"], 0.3),
    ("veil eval --help", ["eval", "--help"], 0.3),
    ("veil fit pipeline --help", ["fit", "pipeline", "--help"], 0.3),
    ("veil --version", ["--version"], 0.3),
    ("veil eval --brdf BRDF1 (a bad option)", ["eval", "--brdf"], 0.3),
    ("veil models", ["models"], None),
    ("veil eval (one configuration)", ["eval", "--brdf", "BRDF1", "--medium", "BTDF1",
                                       "--theta-i", "45", "--theta-r", "50"], 1.5),
    ("veil fit pipeline (paper's protocol)", ["fit", "pipeline", "--reference-clear",
                                              "{data}/reference_clear.csv",
                                              "--reference-medium",
                                              "{data}/reference_medium.csv",
                                              "--target-medium", "{data}/target_medium.csv",
                                              "--black", "{data}/black.csv",
                                              "-o", "{out}"], 4.0),
]


def simulate_sessions(directory: str, veil: str, env: dict) -> None:
    for args in (["--brdf", "BRDF2", "--medium", "none", "--seed", "0",
                  "-o", f"{directory}/reference_clear.csv"],
                 ["--brdf", "BRDF2", "--medium", "BTDF1", "--seed", "1",
                  "-o", f"{directory}/reference_medium.csv", "--black", f"{directory}/black.csv"],
                 ["--brdf", "BRDF1", "--medium", "BTDF1", "--seed", "2",
                  "-o", f"{directory}/target_medium.csv"]):
        subprocess.run([veil, "simulate", *args], env=env, check=True, capture_output=True)


def timed(veil: str, args: list, env: dict) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds, exit status) of one fresh process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([veil, *args], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode not in (0, 2):
        sys.stderr.write(f"{' '.join(args)} exited {proc.returncode}:\n{proc.stderr[-2000:]}\n")
    return wall, cpu, proc.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--veil", default=DEFAULT_VEIL, help="the veil program to measure")
    parser.add_argument("--runs", type=int, default=5, help="runs with the cache filled")
    parser.add_argument("--cold-runs", type=int, default=1,
                        help="runs with a cold cache (each in a new empty cache)")
    parser.add_argument("--warmup", action="store_true",
                        help="run 'veil warmup' on the filled cache before measuring it")
    parser.add_argument("--only", default=None, help="measure commands whose label has this")
    from doc_tables import add_options, printed_tables
    add_options(parser, "startup")
    opts = parser.parse_args()
    doc = printed_tables(opts).start()

    work = tempfile.mkdtemp(prefix="bench-startup-")
    base_env = {k: v for k, v in os.environ.items()
                if k not in ("VEIL_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR")}
    try:
        data = os.path.join(work, "data")
        os.makedirs(data)
        simulate_sessions(data, opts.veil, {**base_env,
                                            "VEIL_CACHE_DIR": os.path.join(work, "sim-cache")})
        filled = os.path.join(work, "filled-cache")
        load = os.getloadavg()[0]
        print(f"veil start-up benchmark: {opts.veil}; {os.cpu_count()} cores, load average "
              f"{load:.1f} at the start")
        rows = []
        for label, args, target in COMMANDS:
            if opts.only and opts.only not in label:
                continue
            cold = []
            for k in range(opts.cold_runs):
                cache = os.path.join(work, f"cold-{len(rows)}-{k}")
                out = os.path.join(work, f"out-cold-{len(rows)}-{k}")
                argv = [a.format(data=data, out=out) for a in args]
                cold.append(timed(opts.veil, argv, {**base_env, "VEIL_CACHE_DIR": cache}))
                shutil.rmtree(cache, ignore_errors=True)
            env = {**base_env, "VEIL_CACHE_DIR": filled}
            fill_args = [a.format(data=data, out=os.path.join(work, "out-fill")) for a in args]
            timed(opts.veil, fill_args, env)  # fills the cache (also every later command's)
            if opts.warmup:
                subprocess.run([opts.veil, "warmup", "--quiet"], env=env, capture_output=True)
            warm = []
            for k in range(opts.runs):
                out = os.path.join(work, f"out-{len(rows)}-{k}")
                warm.append(timed(opts.veil, [a.format(data=data, out=out) for a in args], env))
            rows.append((label, cold, warm, target))
            print(f"  measured {label}", file=sys.stderr)
        print(f"load average at the end {os.getloadavg()[0]:.1f}\n")
        print("| command | fresh process, cold cache: s (CPU s) | fresh process, cache filled: "
              "s, median of %d (min-max) | CPU s (median) | target s | exit |" % opts.runs)
        print("|---|---:|---:|---:|---:|---:|")
        for label, cold, warm, target in rows:
            cold_s = ", ".join(f"{w:.2f} ({c:.2f})" for w, c, _ in cold)
            walls = [w for w, _, _ in warm]
            cpus = [c for _, c, _ in warm]
            codes = sorted({code for _, _, code in cold + warm})
            print(f"| {label} | {cold_s} | {statistics.median(walls):.2f} "
                  f"({min(walls):.2f}-{max(walls):.2f}) | {statistics.median(cpus):.2f} | "
                  f"{'-' if target is None else f'{target:g}'} | "
                  f"{','.join(map(str, codes))} |")
        doc.finish()
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
