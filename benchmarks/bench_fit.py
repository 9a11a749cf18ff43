"""Benchmark of the whole estimation (veil.run_pipeline, docs/model.md sec. 7; docs/fitting.md).

The paper's protocol (psi = 30, 60, 90 deg; 111 configurations a session): reference BRDF2
in clear water and in BTDF1 with a black cloth, target BRDF1 in BTDF1; 1 % noise. The
sessions are simulated first (not timed). Then three measurements, all with a persistent JAX
compilation cache in a new temporary directory (VEIL_CACHE_DIR; veil keeps one by default):
"first run" is a fresh process with the cache empty (JAX compiles the engine: what the very
first pipeline on a machine pays), "fresh process" a second process that finds the
executables in the cache (every later `veil fit pipeline`), "warm" a second pipeline in the
first process (everything compiled and traced).

    .venv/bin/python benchmarks/bench_fit.py

Per step: wall seconds, process CPU seconds (both cores), least-squares runs, function and
Jacobian evaluations, and engine calls by quadrature ("values/Jacobians", each over the
session's configurations padded to 64-configuration chunks through a medium, and to 256
or the power of two above in clear water).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

SESSIONS = ("reference_clear", "reference_medium", "black", "target_medium")
REFERENCE, MEDIUM, TARGET = "BRDF2", "BTDF1", "BRDF1"


def simulate_sessions(directory: str) -> None:
    import veil
    ref, med, tgt = veil.preset(REFERENCE), veil.preset(MEDIUM), veil.preset(TARGET)
    veil.save_measurements(veil.simulate(ref, None, seed=0), f"{directory}/reference_clear.csv")
    table, black = veil.simulate(ref, med, seed=1, black=True)
    veil.save_measurements(table, f"{directory}/reference_medium.csv")
    veil.save_measurements(black, f"{directory}/black.csv")
    veil.save_measurements(veil.simulate(tgt, med, seed=2),
                           f"{directory}/target_medium.csv")


def child(directory: str, runs: int) -> None:
    """Run the pipeline ``runs`` times in this process; print one JSON line per run."""
    t_import = time.perf_counter()
    import veil
    import_s = time.perf_counter() - t_import
    for k in range(runs):
        marks = []

        def progress(stage, done, total):
            step = stage.split(":")[0]
            if not marks or marks[-1][0] != step:
                marks.append((step, time.perf_counter(), time.process_time()))

        t0, c0 = time.perf_counter(), time.process_time()
        marks.append(("read and check the sessions", t0, c0))
        out = tempfile.mkdtemp(prefix="bench-fit-")
        result = veil.run_pipeline(f"{directory}/reference_clear.csv",
                                   f"{directory}/reference_medium.csv",
                                   f"{directory}/target_medium.csv",
                                   black=f"{directory}/black.csv", outdir=out,
                                   progress=progress)
        t1, c1 = time.perf_counter(), time.process_time()
        marks.append(("end", t1, c1))
        steps = {}
        for (name, w, c), (_, w2, c2) in zip(marks, marks[1:]):
            steps["figures and report.md" if name == "figures" else name] = [w2 - w, c2 - c]
        shutil.rmtree(out)
        fits = {"step 0, reference": result.reference, "step 1, medium": result.medium,
                "step 2, target": result.target}
        rows = []
        for name, (wall, cpu) in steps.items():
            fit = fits.get(name)
            stats = fit.stats if fit is not None else {}
            rows.append({"step": name, "wall": wall, "cpu": cpu,
                         "runs": len(stats.get("runs", [])), "nfev": stats.get("nfev"),
                         "njev": stats.get("njev"), "engine": stats.get("engine_calls"),
                         "configs": fit.n_points if fit is not None else None,
                         "converged": fit.converged if fit is not None else None})
        params = {k: f.params for k, f in fits.items()}
        print(json.dumps({"run": k, "import": import_s, "total": [t1 - t0, c1 - c0],
                          "rows": rows, "params": params}), flush=True)


def run_child(directory: str, runs: int, env=None) -> list[dict]:
    cmd = [sys.executable, __file__, "--child", directory, "--runs", str(runs)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True,
                         env={**os.environ, **(env or {})})
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def table(label: str, record: dict) -> str:
    lines = [f"{label}: pipeline {record['total'][0]:.1f} s wall, {record['total'][1]:.1f} s "
             f"CPU (import veil {record['import']:.1f} s, not included)", "",
             "| step | wall s | CPU s | LSQ runs | fun evals | Jacobian evals | engine calls "
             "(values/Jacobians) | configurations | converged |",
             "|---|---:|---:|---:|---:|---:|---|---:|---|"]
    for r in record["rows"]:
        engine = "; ".join(f"{acc} {v[0]}/{v[1]}" for acc, v in (r["engine"] or {}).items()) \
            or ("direct f_r (no integral)" if r["nfev"] else "-")
        lines.append(f"| {r['step']} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['runs'] or '-'} | "
                     f"{r['nfev'] if r['nfev'] is not None else '-'} | "
                     f"{r['njev'] if r['njev'] is not None else '-'} | {engine} | "
                     f"{r['configs'] or '-'} | "
                     f"{'-' if r['converged'] is None else ('yes' if r['converged'] else 'NO')} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--runs", type=int, default=2, help=argparse.SUPPRESS)
    from doc_tables import add_options, printed_tables
    add_options(parser, "fit-first,fit-fresh,fit-warm")
    args = parser.parse_args()
    if args.child:
        child(args.child, args.runs)
        return
    doc = printed_tables(args).start()
    with tempfile.TemporaryDirectory(prefix="bench-fit-data-") as directory:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, "
                        f"{os.path.dirname(os.path.abspath(__file__))!r}); import bench_fit; "
                        f"bench_fit.simulate_sessions({directory!r})"], check=True)
        print(f"fit benchmark: reference {REFERENCE} (clear water, {MEDIUM} + black cloth), "
              f"target {TARGET} in {MEDIUM}; paper's protocol, 1 % noise; sessions simulated "
              f"in {time.perf_counter() - t0:.1f} s (not timed below); "
              f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start\n")
        with tempfile.TemporaryDirectory(prefix="bench-fit-jax-cache-") as cache:
            env = {"VEIL_CACHE_DIR": cache}
            records = run_child(directory, 2, env)
            fresh = run_child(directory, 1, env)[0]
        print(table("first run (fresh process, empty compilation cache: JAX compiles)",
                    records[0]) + "\n")
        print(table("fresh process (compilation cache filled by the first run)", fresh) + "\n")
        print(table("warm (the first process, second run)", records[1]) + "\n")
        truth = {"step 0, reference": REFERENCE, "step 1, medium": MEDIUM,
                 "step 2, target": TARGET}
        import veil
        print("recovered (warm run):")
        for step, params in records[1]["params"].items():
            true = veil.preset(truth[step])
            print(f"  {step}: " + ", ".join(f"{k} {v:.5g} (true {getattr(true, k):.5g})"
                                           for k, v in params.items()))
        print(f"load average at end {os.getloadavg()[0]:.1f}")
    doc.finish()


if __name__ == "__main__":
    main()
