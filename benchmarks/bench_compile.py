"""Compile cost of the engine (docs/performance-compile.md).

For each registered family pair (BRDF x medium), ``veil fit pipeline`` runs as a fresh
process on a path-traced session (validation/data, medium m05: the reference plate in clear
water and in the medium, the target in the medium, the black cloth), first with a new, empty
VEIL_CACHE_DIR ("cold": every engine program is compiled), then again with that folder
("warm": every program is loaded). Each compilation is logged (VEIL_COMPILE_LOG) with its
size and seconds. Printed: the cold and warm pipeline per pair (wall and CPU seconds, the
programs compiled, the largest), and every program's compile seconds. CPU seconds are
printed beside wall seconds: the machine may be shared, and CPU time is the figure load
inflates least.

    .venv/bin/python benchmarks/bench_compile.py                       # every pair
    .venv/bin/python benchmarks/bench_compile.py --pairs rough-plastic:forward-series
    .venv/bin/python benchmarks/bench_compile.py --doc docs/performance-compile.md   # the page's tables
    .venv/bin/python benchmarks/bench_compile.py --src /old/checkout/src   # another veil's code
    .venv/bin/python benchmarks/bench_compile.py --explore   # and the explorer's first page
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time

import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "validation", "data")
VEIL = os.path.join(os.path.dirname(sys.executable), "veil")
#: The validation set-up's geometry (validation/README.md): the physical medium's options.
GEOMETRY = ["--path-length", "15", "--plate-width", "5"]
MEDIUM = "m05"


def registered_pairs() -> list[tuple[str, str]]:
    from veil.models import names

    return [(b, m) for b in names("brdf") for m in names("medium")]


def sessions(folder: str) -> list[str]:
    """The pipeline's input options on the m05 sessions (the clear reference without its
    zero sigma column, which a weighted fit refuses)."""
    clear = os.path.join(folder, "reference_clear.csv")
    pd.read_csv(os.path.join(DATA, "water_ref.csv")).drop(columns=["sigma"]).to_csv(
        clear, index=False)
    return ["--reference-clear", clear,
            "--reference-medium", os.path.join(DATA, f"{MEDIUM}_ref.csv"),
            "--target-medium", os.path.join(DATA, f"{MEDIUM}_target.csv"),
            "--black", os.path.join(DATA, f"{MEDIUM}_black.csv")]


def run_pipeline(pair, inputs, cache: str, out: str, log: str, src=None) -> dict:
    """One ``veil fit pipeline`` process; wall and CPU seconds, its compilations."""
    brdf, medium = pair
    args = [VEIL, "fit", "pipeline", *inputs, "-o", out, "--no-figures",
            "--brdf-model", brdf, "--medium-model", medium]
    if medium == "forward-series":
        args += GEOMETRY
    env = {**os.environ, "VEIL_CACHE_DIR": cache, "VEIL_COMPILE_LOG": log}
    if src:  # another checkout's veil, run with this environment's packages
        env["PYTHONPATH"] = os.path.abspath(src)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    compiled = []
    if os.path.exists(log):
        with open(log, encoding="utf-8") as fh:
            logged = [json.loads(line) for line in fh if line.strip()]
        # the log also has a line per program read from the store (event "load")
        compiled = [e for e in logged if e.get("event", "compile") == "compile"]
        os.unlink(log)
    store = os.path.join(cache, "programs")
    stored = len([f for f in os.listdir(store) if f.endswith(".program")]) \
        if os.path.isdir(store) else 0
    return {"wall": wall, "cpu": cpu, "status": done.returncode, "compiled": compiled,
            "programs": len(compiled) or stored, "stderr": done.stderr}


def run_explore(result: str, cache: str, out: str, src=None, timeout=600.0) -> dict:
    """``veil explore RESULT --static`` as a fresh process with the program store ``cache``:
    the explorer's first page (its precomputations compiled unless the store has them)."""
    env = {**os.environ, "VEIL_CACHE_DIR": cache}
    if src:
        env["PYTHONPATH"] = os.path.abspath(src)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        done = subprocess.run([VEIL, "explore", result, "--static", "-o", out],
                              capture_output=True, text=True, env=env, timeout=timeout)
        status = done.returncode
    except subprocess.TimeoutExpired:
        status = "timeout"
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "status": status}


def measure(pair, folder: str, src=None, explore: bool = False) -> dict:
    inputs = sessions(folder)
    cache = os.path.join(folder, "cache")
    log = os.path.join(folder, "compile.log")
    cold = run_pipeline(pair, inputs, cache, os.path.join(folder, "cold"), log, src)
    warm = run_pipeline(pair, inputs, cache, os.path.join(folder, "warm"), log, src)
    out = {"pair": pair, "cold": cold, "warm": warm}
    if explore:  # the first page on the cold pipeline's result, with an empty store
        out["explore"] = run_explore(os.path.join(folder, "cold", "target.json"),
                                     os.path.join(folder, "explore-cache"),
                                     os.path.join(folder, "page.html"), src)
    return out


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"load {one:.1f} (5 min {five:.1f})"


def tables(results: list[dict]) -> tuple[str, str]:
    """Markdown: the pipelines per pair, and every program's compile time."""
    rows = ["| pair | cold wall s | cold CPU s | programs | compile s (sum) | largest s | "
            "warm wall s | warm CPU s | exit |", "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    programs = ["| pair | program | StableHLO lines | estimate s | compile s |",
                "|---|---|---:|---:|---:|"]
    explore = any("explore" in r for r in results)
    if explore:
        rows[0] += " explorer's first page, cold: wall s | CPU s | exit |"
        rows[1] += "---:|---:|---|"
    for r in results:
        cold, warm = r["cold"], r["warm"]
        secs = [c["seconds"] for c in cold["compiled"]]
        name = " x ".join(r["pair"])
        rows.append(f"| {name} | {cold['wall']:.1f} | {cold['cpu']:.1f} | {cold['programs']} | "
                    f"{sum(secs):.1f} | {max(secs, default=0):.1f} | {warm['wall']:.1f} | "
                    f"{warm['cpu']:.1f} | {cold['status']}/{warm['status']} |")
        if explore:
            e = r.get("explore", {"wall": math.nan, "cpu": math.nan, "status": "-"})
            rows[-1] += f" {e['wall']:.1f} | {e['cpu']:.1f} | {e['status']} |"
        for c in sorted(cold["compiled"], key=lambda c: -c["seconds"]):
            label = c["label"].split(": ", 1)[-1]
            programs.append(f"| {name} | {label} | {c['lines']} | {c['estimate']:.1f} | "
                            f"{c['seconds']:.1f} |")
    return "\n".join(rows), "\n".join(programs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="all",
                    help="comma-separated BRDF:MEDIUM pairs (default: every registered pair)")
    ap.add_argument("--markdown", default=None, help="also write the tables to this file")
    ap.add_argument("--explore", action="store_true",
                    help="also time `veil explore TARGET.json --static` on each cold result "
                         "with an empty program store (the explorer's first page)")
    ap.add_argument("--doc", default=None, metavar="PAGE",
                    help="write the tables into PAGE between its markers compile-pipelines "
                         "and compile-programs (benchmarks/doc_tables.py), with the command, "
                         "date, machine and load")
    ap.add_argument("--src", default=None, help="run the veil of this source folder (its "
                    "src/), e.g. an older checkout, for a side-by-side comparison; without a "
                    "compile log there, its programs are counted from the store")
    a = ap.parse_args(argv)
    pairs = registered_pairs() if a.pairs == "all" else \
        [tuple(p.split(":", 1)) for p in a.pairs.split(",")]
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    header = (f"`{' '.join(['benchmarks/bench_compile.py'] + (argv or sys.argv[1:]))}`, "
              f"{started}, {platform.machine()} with {os.cpu_count()} cores, {_load()} at the "
              f"start")
    print(header, flush=True)
    results = []
    for pair in pairs:
        with tempfile.TemporaryDirectory(prefix="veil-bench-compile-") as folder:
            r = measure(pair, folder, a.src, a.explore)
        results.append(r)
        cold = r["cold"]
        print(f"{' x '.join(pair)}: cold {cold['wall']:.1f} s ({cold['programs']} "
              f"programs), warm {r['warm']['wall']:.1f} s, {_load()}", flush=True)
        if cold["status"] not in (0, 1):
            print(cold["stderr"][-2000:], file=sys.stderr)
    pipelines, programs = tables(results)
    footer = f"{_load()} at the end"
    print("\n" + pipelines + "\n\n" + programs + "\n\n" + footer)
    if a.doc:
        from doc_tables import write

        write(a.doc, "compile-pipelines", pipelines + f"\n\n{footer.capitalize()}.")
        write(a.doc, "compile-programs", programs)
    if a.markdown:
        with open(a.markdown, "w", encoding="utf-8") as fh:
            fh.write(f"{header}; {footer}.\n\n{pipelines}\n\n{programs}\n")
    return 0 if all(r["cold"]["status"] in (0, 1) for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
