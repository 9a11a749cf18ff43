"""Each engine program of a pipeline compiled alone (docs/performance-compile.md).

`bench_compile.py` times the programs inside a cold `veil fit pipeline`, where up to four
compile at once beside the fits: there a program's seconds are its share of two busy cores.
This benchmark asks what one program costs by itself. For each family pair, in a fresh
process with no program store (``VEIL_CACHE_DIR=off``), it builds the programs the pipeline
uses on the m05 session's first 64 configurations, the chunk a fit's engine calls are
made of (the medium's at the validation set-up's geometry) and, one after the other with
nothing else running, traces and lowers each (StableHLO lines), compiles it (wall and CPU
seconds) and runs it (median of 5 calls).

    .venv/bin/python benchmarks/bench_compile_alone.py                  # every pair
    .venv/bin/python benchmarks/bench_compile_alone.py --pairs rough-plastic:forward-series
    .venv/bin/python benchmarks/bench_compile_alone.py --doc docs/performance-compile.md
    .venv/bin/python benchmarks/bench_compile_alone.py --channels 3 --pairs rough-plastic:forward-series
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "validation", "data")
#: The validation set-up's geometry (validation/README.md): the physical medium's options.
GEOMETRY = {"path_length": 15.0, "plate_width": 5.0}
SESSION = "m05_target"
LIMIT = 10.0  # issue 28's target: no program over 10 s to compile


def _programs(brdf_name: str, medium_name: str, channels: int = 1) -> list:
    """[(label, jitted function, arguments)] of the pipeline's programs for the pair; with
    ``channels`` > 1 those of a pipeline over that many colour channels whose media differ
    in non-scale parameters instead (veil.engine.channel_programs), where the medium has a
    sampling law."""
    import numpy as np

    from veil.engine.angles import direction
    from veil.engine.apparent import direct_padded, direct_programs
    from veil.engine.forward import CHUNK, Forward, _terms_fn
    from veil.engine.quadrature import RULES
    from veil.fitting.session_data import prepare
    from veil.models import model_class

    # a fit calls the engine in chunks of CHUNK configurations: one program per chunk size
    ti, pi_, tr, pr = (a[:CHUNK] for a in prepare(os.path.join(DATA, f"{SESSION}.csv")).angles)
    bcls, mcls = model_class(brdf_name, "brdf"), model_class(medium_name, "medium")
    brdf = bcls.template()
    medium = mcls.template(**(GEOMETRY if medium_name == "forward-series" else {}))
    out = []
    if channels > 1:
        return _channel_programs(brdf, medium, (ti, tr, pi_, pr), channels)
    for rule in ("fast", "default"):
        f = Forward(brdf, medium, ti, tr, pi_, pr, rule=RULES[rule])
        vb, vm = f._vectors(brdf.to_vector(), medium.to_vector())
        args = (vb, vm, f._wi, f._wr)
        out.append((f"values, {rule} rule", _terms_fn(f._kb, f._km, f.rule, f.half, f._mesh),
                    args))
        if rule == "fast":
            for kind, free in (("BRDF", (range(len(bcls.PARAMS)), ())),
                               ("medium", ((), range(len(mcls.PARAMS))))):
                fn, *_rest, nl_b, nl_m = f._jacobian_fn(*free)
                if fn is not None:
                    out.append((f"values and d/d({kind}), fast rule", fn, args))
    padded = direct_padded(np.asarray(direction(ti, pi_)), np.asarray(direction(tr, pr)))
    values, jacobian = direct_programs(brdf)
    v = np.asarray(brdf.to_vector(), dtype=float)
    out += [("f_r (clear medium)", values, (v, *padded)),
            ("f_r and its Jacobian", jacobian, (v, *padded))]
    return out


def _channel_programs(brdf, medium, angles, channels: int) -> list:
    """The channels' programs of a colour pipeline: values at both rules, the Jacobians in
    the BRDF's and in the medium's parameters at the fast rule (each channel's water its
    own optical depth)."""
    import numpy as np

    from veil.engine import channel_programs
    from veil.engine.forward import Forward
    from veil.engine.quadrature import RULES

    ti, tr, pi_, pr = angles
    out = []
    for rule in ("fast", "default"):
        f = Forward(brdf, medium, ti, tr, pi_, pr, rule=RULES[rule])
        if not channel_programs.shares_nodes(medium):
            return []
        vb, vm = f._vectors(brdf.to_vector(), medium.to_vector())
        vms = np.tile(vm, (channels, 1))
        vms[:, 0] *= np.linspace(1.0, 0.5, channels)
        args = (vb, vms, f._wi, f._wr)
        frees = [("values", None)] + ([("BRDF", (range(len(brdf.PARAMS)), ())),
                                       ("medium", ((), range(len(medium.PARAMS))))]
                                      if rule == "fast" else [])
        for kind, free in frees:
            found = channel_programs._programs(f, channels, free)
            if found is not None:
                what = "values" if free is None else f"values and d/d({kind})"
                out.append((f"{what} of {channels} channels, {rule} rule", found[1], args))
    return out


def measure_pair(brdf_name: str, medium_name: str, channels: int = 1) -> list[dict]:
    """Run in a fresh process (``--one``): each program traced, lowered, compiled, run."""
    import numpy as np

    from veil._jax import jax  # first: veil sets up JAX's devices (one per core) as commands do
    from veil.engine.programs import _OWN_KEY

    print(f"{jax.device_count()} devices", file=sys.stderr)

    rows = []
    for label, program, args in _programs(brdf_name, medium_name, channels):
        t0 = time.perf_counter()
        lowered = program.fn.lower(*args)
        lower = time.perf_counter() - t0
        lines = lowered.as_text().count("\n")
        t0, c0 = time.perf_counter(), time.process_time()
        compiled = lowered.compile({**_OWN_KEY, **program.options})
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        jax.block_until_ready(compiled(*args))
        runs = []
        for _ in range(5):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(*args))
            runs.append(time.perf_counter() - t0)
        rows.append({"program": label, "lines": lines, "lower": lower, "compile": wall,
                     "compile_cpu": cpu, "run_ms": 1e3 * float(np.median(runs))})
    return rows


def pairs_of(spec: str) -> list[str]:
    """The BRDF:MEDIUM pairs of ``--pairs`` ("all": every registered parametric pair; the
    nonparametric family's programs are its column model's)."""
    if spec != "all":
        return spec.split(",")
    from veil.models import names

    return [f"{b}:{m}" for b in names("brdf") for m in names("medium") if b != "nonparametric"]


def _load() -> str:
    one, five, _ = os.getloadavg()
    return f"{one:.1f} (5 min {five:.1f})"


def table(results: dict) -> str:
    """One row per pair: its programs' totals alone and the largest of them."""
    rows = ["| pair | programs | trace + lower s (sum) | compile s (sum) | largest program | "
            "its lines | its compile s | its run ms | load |",
            "|---|---:|---:|---:|---|---:|---:|---:|---:|"]
    for pair, (found, load) in results.items():
        top = max(found, key=lambda r: r["compile"])
        rows.append(f"| {pair} | {len(found)} | {sum(r['lower'] for r in found):.1f} | "
                    f"{sum(r['compile'] for r in found):.1f} | {top['program']} | "
                    f"{top['lines']} | {top['compile']:.1f} | {top['run_ms']:.1f} | {load} |")
    return "\n".join(rows)


def programs_table(results: dict) -> str:
    """Every program (printed, not written into the page)."""
    rows = ["| pair | program | StableHLO lines | trace + lower s | compile s | compile CPU s "
            "| run ms |", "|---|---|---:|---:|---:|---:|---:|"]
    for pair, (found, _) in results.items():
        for r in found:
            rows.append(f"| {pair} | {r['program']} | {r['lines']} | {r['lower']:.1f} | "
                        f"{r['compile']:.1f} | {r['compile_cpu']:.1f} | {r['run_ms']:.1f} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", default="all",
                    help="comma-separated BRDF:MEDIUM pairs (default: every registered pair)")
    ap.add_argument("--doc", default=None, metavar="PAGE",
                    help="write the table into PAGE between its markers compile-alone "
                         "(benchmarks/doc_tables.py)")
    ap.add_argument("--channels", type=int, default=1,
                    help="the programs of a pipeline over this many colour channels whose "
                         "media differ in non-scale parameters (media with a sampling law)")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # the child process
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(measure_pair(*a.one.split(":", 1), channels=a.channels)))
        return 0
    pairs = pairs_of(a.pairs)
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    print(f"benchmarks/bench_compile_alone.py {' '.join(argv or sys.argv[1:])}: {started}, "
          f"{platform.machine()} with {os.cpu_count()} cores, load {_load()}", flush=True)
    results = {}
    for pair in pairs:
        load = _load()
        env = {**os.environ, "VEIL_CACHE_DIR": "off"}
        done = subprocess.run([sys.executable, __file__, "--one", pair, "--channels",
                               str(a.channels)], capture_output=True, text=True, env=env)
        if done.returncode != 0:
            print(done.stderr[-3000:], file=sys.stderr)
            return 3
        found = json.loads(done.stdout.strip().splitlines()[-1])
        if not found:  # --channels: a medium without a sampling law has no such programs
            print(f"{pair}: no channels' programs", flush=True)
            continue
        results[pair.replace(":", " x ")] = (found, load)
        worst = max(found, key=lambda r: r["compile"])
        print(f"{pair}: largest {worst['program']} {worst['compile']:.1f} s "
              f"(+{worst['lower']:.1f} s trace and lower), load {_load()}", flush=True)
    text = table(results)
    over = [(p, r["program"]) for p, (found, _) in results.items() for r in found
            if r["compile"] > LIMIT]
    footer = (f"Programs over {LIMIT:g} s to compile alone: "
              f"{', '.join(f'{p}: {q}' for p, q in over) if over else 'none'}. "
              f"Load at the end {_load()}.")
    print("\n" + programs_table(results) + "\n\n" + text + "\n\n" + footer)
    if a.doc:
        from doc_tables import write

        write(a.doc, "compile-alone", text + "\n\n" + footer)
    return 0


if __name__ == "__main__":
    sys.exit(main())
