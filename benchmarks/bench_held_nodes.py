"""The engine's Jacobians in the medium's parameters with the phase grids held, against the
grids moving (docs/engine.md, "Derivatives").

A Jacobian program draws its phase grids at its own point and holds them there
(``integrator.apparent_terms(..., hold_phase_grids=True)``): the derivative of the
quadrature on those nodes. The alternative differentiates the nodes' positions too (the
exact derivative of the values the engine returns). For each family pair, in a fresh
process with no program store, on the m05 session's first 64 configurations (a fit's
chunk) and the validation set-up's geometry, this compiles both at the fast rule in the
medium's non-scale parameters, one after the other with nothing else running, and prints
side by side: StableHLO lines, compile seconds and run milliseconds; the largest and the
median distance of a column from the default rule's derivative (central differences of
its values: the finer quadrature, the accuracy reference) over that column's largest
value; and the largest relative difference of the standard errors (1 % noise, every free
parameter of the medium, its scales included) from the default rule's.

    .venv/bin/python benchmarks/bench_held_nodes.py
    .venv/bin/python benchmarks/bench_held_nodes.py --pairs rough-plastic:forward-series
    .venv/bin/python benchmarks/bench_held_nodes.py --doc docs/engine.md
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import doc_tables
import numpy as np
from bench_compile_alone import _load, pairs_of

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "validation", "data")
GEOMETRY = {"path_length": 15.0, "plate_width": 5.0}  # validation/README.md
SESSION = "m05_target"


def _jacobian(bt, mt, rule, half, nl_b, nl_m, hold: bool):
    """The jitted Jacobian (terms and d terms / d free) as the engine builds it, with the
    nodes held or moving."""
    from veil._jax import jax, jnp
    from veil.engine import integrator

    ib, im = np.asarray(nl_b, dtype=int), np.asarray(nl_m, dtype=int)
    nb = len(nl_b)

    def fn(vb, vm, wi, wr):
        def g(x):
            b = vb.at[ib].set(x[:nb])
            m = vm.at[im].set(x[nb:])
            return integrator.apparent_terms(bt, mt, rule, b, m, wi, wr, half,
                                             hold_phase_grids=hold)

        x = jnp.concatenate([vb[ib], vm[im]])
        return jax.vmap(lambda d: jax.jvp(g, (x,), (d,)), out_axes=(None, -1))(
            jnp.eye(x.size, dtype=x.dtype))

    return jax.jit(fn)


def _central(f, vb, vm, free) -> np.ndarray:
    """Central differences of ``f(vb, vm)`` in the medium's parameters ``free``."""
    cols = []
    for i in free:
        h = 1e-6 * max(abs(vm[i]), 1e-3)
        up, down = vm.copy(), vm.copy()
        up[i] += h
        down[i] -= h
        cols.append((f(vb, up) - f(vb, down)) / (2 * h))
    return np.stack(cols, axis=1)


def _stderr(jac, values) -> np.ndarray:
    """Standard errors of a fit with these columns and 1 % noise."""
    a = jac / (0.01 * np.abs(values))[:, None]
    return np.sqrt(np.diag(np.linalg.inv(a.T @ a)))


def measure_pair(brdf_name: str, medium_name: str) -> list[dict]:
    """Run in a fresh process (``--one``)."""
    from veil._jax import jax  # first: veil sets up JAX's devices as commands do
    from veil.engine import integrator
    from veil.engine.forward import CHUNK, Forward
    from veil.engine.programs import _OWN_KEY, JACOBIAN_OPTIONS
    from veil.engine.quadrature import RULES
    from veil.fitting.session_data import prepare
    from veil.models import model_class

    ti, pi_, tr, pr = (a[:CHUNK] for a in prepare(os.path.join(DATA, f"{SESSION}.csv")).angles)
    bcls, mcls = model_class(brdf_name, "brdf"), model_class(medium_name, "medium")
    brdf = bcls.template()
    medium = mcls.template(**(GEOMETRY if medium_name == "forward-series" else {}))
    fast, default = (Forward(brdf, medium, ti, tr, pi_, pr, rule=RULES[r])
                     for r in ("fast", "default"))
    vb, vm = fast._vectors(brdf.to_vector(), medium.to_vector())
    free = tuple(i for i, p in enumerate(mcls.PARAMS) if not p.held)
    *_, nl_b, nl_m = fast._jacobian_fn((), free)
    values, held = fast.value_and_jacobian(vb, vm, (), free)
    moving = _central(fast, vb, vm, free)
    truth = _central(default, vb, vm, free)
    se_truth = _stderr(truth, default(vb, vm))
    wi, wr = np.asarray(fast._wi)[: fast.size], np.asarray(fast._wr)[: fast.size]
    bt, mt = integrator.template_for(fast._kb), integrator.template_for(fast._km)
    rows = []
    for hold, jac in ((True, held), (False, moving)):
        fn = _jacobian(bt, mt, RULES["fast"], fast.half, nl_b, nl_m, hold)
        lowered = fn.lower(vb, vm, wi, wr)
        t0 = time.perf_counter()
        compiled = lowered.compile({**_OWN_KEY, **JACOBIAN_OPTIONS})
        compile_s = time.perf_counter() - t0
        jax.block_until_ready(compiled(vb, vm, wi, wr))
        runs = []
        for _ in range(5):
            t0 = time.perf_counter()
            jax.block_until_ready(compiled(vb, vm, wi, wr))
            runs.append(time.perf_counter() - t0)
        worst = (0.0, 0.0, "")
        for k, i in enumerate(free):
            off = np.abs(jac[:, k] - truth[:, k]) / (np.max(np.abs(truth[:, k])) + 1e-300)
            if off.max() >= worst[0]:
                worst = (float(off.max()), float(np.median(off)), mcls.PARAMS[i].name)
        se = np.max(np.abs(_stderr(jac, values) / se_truth - 1.0))
        rows.append({"free": ", ".join(mcls.PARAMS[i].name for i in nl_m), "held": hold,
                     "lines": lowered.as_text().count("\n"), "compile": compile_s,
                     "run_ms": 1e3 * float(np.median(runs)), "max_off": worst[0],
                     "median_off": worst[1], "worst": worst[2], "se": float(se)})
    return rows


def table(results: dict) -> str:
    """Held and moving side by side, one row per pair."""
    out = ["| pair | d/d | lines held / moving | compile s held / moving | run ms held / "
           "moving | off the default rule's derivative, held: max, median (column) | "
           "moving | standard errors off the default rule's, held / moving |",
           "|---|---|---:|---:|---:|---|---|---:|"]
    for pair, found in results.items():
        h, m = (next(r for r in found if r["held"] is hold) for hold in (True, False))
        out.append(
            f"| {pair} | {h['free']} | {h['lines']} / {m['lines']} | {h['compile']:.1f} / "
            f"{m['compile']:.1f} | {h['run_ms']:.1f} / {m['run_ms']:.1f} | "
            f"{h['max_off']:.1e}, {h['median_off']:.1e} ({h['worst']}) | "
            f"{m['max_off']:.1e}, {m['median_off']:.1e} ({m['worst']}) | "
            f"{100 * h['se']:.1f} % / {100 * m['se']:.1f} % |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", default="all",
                    help="comma-separated BRDF:MEDIUM pairs (default: every registered pair)")
    doc_tables.add_options(ap, "held-nodes")
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)  # the child process
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(measure_pair(*a.one.split(":", 1))))
        return 0
    print(f"benchmarks/bench_held_nodes.py, {os.cpu_count()} cores, load {_load()}", flush=True)
    results = {}
    for pair in pairs_of(a.pairs):
        env = {**os.environ, "VEIL_CACHE_DIR": "off"}
        done = subprocess.run([sys.executable, __file__, "--one", pair], capture_output=True,
                              text=True, env=env)
        if done.returncode != 0:
            print(done.stderr[-3000:], file=sys.stderr)
            return 3
        results[pair.replace(":", " x ")] = json.loads(done.stdout.strip().splitlines()[-1])
        print(f"{pair}: done, load {_load()}", flush=True)
    with doc_tables.printed_tables(a):
        print("\n" + table(results) + f"\n\nLoad at the end {_load()}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
