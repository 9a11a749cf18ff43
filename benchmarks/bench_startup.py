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
    .venv/bin/python benchmarks/bench_startup.py --jacobians    # one chunk's programs

--jacobians profiles the engine programs of one chunk instead (docs/performance-startup.md
"The pipeline's own work, less of it"): the apparent reflectance of the paper's models (BRDF1
through BTDF1) at the first CHUNK (64) configurations of the paper's protocol, "fast" rule,
with the Jacobian in both models' parameters (joint fits), in the medium's (step 1), in the
object's (step 2), and values only. Each program is compiled into a new empty store by one
process; then ``--runs`` fresh processes load it from the store (the seconds of
veil.engine.programs.read: deserializing the executable) and run it warm ``--calls`` times.
Printed: the median warm call (min-max over all calls) and its CPU seconds (both cores'
threads: what load does not inflate), the stored executable's size and the load time
(median over the fresh processes, min-max).
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


#: The programs --jacobians profiles: (label, ``wrt`` of ApparentModel.value_and_jacobian,
#: "values" for values alone).
JACOBIANS = [("both models (joint fits)", "brdf+medium"),
             ("the medium's parameters (step 1)", "medium"),
             ("the object's parameters (step 2)", "brdf"),
             ("values only, for comparison", "values")]

#: One process of --jacobians: build (or load) one chunk's program, time its calls; prints
#: one JSON line.
CHUNK_PROFILE = r"""
import json, statistics, sys, time
mode, calls = sys.argv[1], int(sys.argv[2])
import veil
from veil.engine import programs
loading = []
_read = programs.read
def read(*args, **kwargs):
    t0 = time.perf_counter()
    out = _read(*args, **kwargs)
    loading.append((time.perf_counter() - t0, out is not None))
    return out
programs.read = read
from veil.data.protocol import protocol
from veil.engine.evaluator import CHUNK, ApparentModel
from veil.engine.quadrature import RULES
configs = protocol().iloc[:CHUNK]
angles = tuple(configs[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
brdf, medium = veil.BRDF1, veil.BTDF1
model = ApparentModel(brdf, medium, angles, RULES["fast"])
vb, vm = brdf.to_vector(), medium.to_vector()
if mode == "values":
    call = lambda: model.values(vb, vm)
else:
    call = lambda: model.value_and_jacobian(vb, vm, tuple(mode.split("+")))
t0 = time.perf_counter()
call()
first = time.perf_counter() - t0
times, cpu = [], []
for _ in range(calls):
    t0, c0 = time.perf_counter(), time.process_time()
    call()
    times.append(time.perf_counter() - t0)
    cpu.append(time.process_time() - c0)
print(json.dumps({"first": first, "load": sum(t for t, hit in loading if hit),
                  "loaded": sum(hit for _, hit in loading), "times": times, "cpu": cpu}))
"""


def profile_jacobians(runs: int, calls: int, base_env: dict, work: str) -> None:
    """--jacobians (module docstring): the table of one chunk's programs."""
    import json

    def child(mode, store):
        proc = subprocess.run([sys.executable, "-c", CHUNK_PROFILE, mode, str(calls)],
                              env={**base_env, "VEIL_CACHE_DIR": store}, capture_output=True,
                              text=True)
        if proc.returncode:
            raise SystemExit(f"the chunk profile ({mode}) failed:\n{proc.stderr[-3000:]}")
        return json.loads(proc.stdout.strip().splitlines()[-1])

    print(f"one chunk's engine programs: {sys.executable}; {os.cpu_count()} cores, load "
          f"average {os.getloadavg()[0]:.1f} at the start")
    rows = []
    for label, mode in JACOBIANS:
        store = os.path.join(work, f"store-{mode}")
        built = child(mode, store)  # compiles and stores the program
        folder = os.path.join(store, "programs")
        size = sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder)
                   if f.endswith(".program"))
        fresh = [child(mode, store) for _ in range(runs)]
        if not all(r["loaded"] for r in fresh):
            raise SystemExit(f"the chunk profile ({mode}): a fresh process found no program")
        times = [t for r in fresh for t in r["times"]]
        cpu = [t for r in fresh for t in r["cpu"]]
        loads = [r["load"] for r in fresh]
        rows.append((label, times, cpu, size, loads))
        print(f"  measured {label} (compiled and ran in {built['first']:.1f} s)",
              file=sys.stderr, flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.1f}\n")
    print(f"| Jacobian in | seconds, median of {runs} x {calls} (min-max) | CPU seconds "
          f"(median) | executable | load in a fresh process, median of {runs} (min-max) |")
    print("|---|---:|---:|---:|---:|")
    for label, times, cpu, size, loads in rows:
        print(f"| {label} | {statistics.median(times):.3f} ({min(times):.3f}-{max(times):.3f})"
              f" | {statistics.median(cpu):.3f} | {size / 1e6:.2f} MB | "
              f"{statistics.median(loads):.2f} s ({min(loads):.2f}-{max(loads):.2f}) |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--veil", default=DEFAULT_VEIL, help="the veil program to measure")
    parser.add_argument("--runs", type=int, default=5, help="runs with the cache filled")
    parser.add_argument("--cold-runs", type=int, default=1,
                        help="runs with a cold cache (each in a new empty cache)")
    parser.add_argument("--warmup", action="store_true",
                        help="run 'veil warmup' on the filled cache before measuring it")
    parser.add_argument("--only", default=None, help="measure commands whose label has this")
    parser.add_argument("--jacobians", action="store_true",
                        help="profile one chunk's engine programs instead (values, Jacobians; "
                             "table startup-jacobian); --runs fresh processes")
    parser.add_argument("--calls", type=int, default=7,
                        help="--jacobians: warm calls in each fresh process")
    from doc_tables import add_options, printed_tables
    add_options(parser, "startup")
    opts = parser.parse_args()
    if opts.jacobians and opts.doc_table == "startup":
        opts.doc_table = "startup-jacobian"
    doc = printed_tables(opts).start()

    work = tempfile.mkdtemp(prefix="bench-startup-")
    base_env = {k: v for k, v in os.environ.items()
                if k not in ("VEIL_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR")}
    try:
        if opts.jacobians:
            profile_jacobians(opts.runs, opts.calls, base_env, work)
            doc.finish()
            return
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
