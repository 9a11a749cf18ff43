"""What compiling a map's per-pixel solve costs: the start and the iterations as two programs
(veil.maps.solve.compiled, the limit of iterations an input of the second) against a
program per stage, a batch's (start and first iterations) and the slow pixels' rest (each
with its own copy of the iterations), the arrangement before; and the small matrices'
LDL^T unrolled against a loop over the columns above veil.fitting.least_squares.UNROLLED_MAX
rows (docs/performance-maps.md).

    .venv/bin/python benchmarks/bench_maps_solve_compile.py [--rounds 3] [--doc PAGE]

The solvers are bench_maps_solve_parts.py's: one channel (green) and three channels (r, g,
b) of Torrance-Sparrow through BTDF2 at the paper's 111 configurations. Each program is
traced and lowered first, then compiled by XLA with JAX's compilation cache off; the CPU
seconds of the compilations are reported (the best of ``--rounds``, the arrangements
alternating), and the run time of one batch of 512 pixels through each arrangement (CPU ms,
best of three rounds of 20 calls).
"""

from __future__ import annotations

import os

os.environ["JAX_ENABLE_COMPILATION_CACHE"] = "false"

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import doc_tables  # noqa: E402
from bench_maps_solve_parts import cpu_ms, solver_cases  # noqa: E402


def compile_cpu(fn, *args) -> tuple[float, object]:
    """(CPU seconds of XLA's compilation of ``fn`` at ``args``, the executable)."""
    import jax

    lowered = jax.jit(fn).lower(*args)
    t0 = time.process_time()
    executable = lowered.compile()
    return time.process_time() - t0, executable


def arrangements(make, values, coef, y, w2) -> dict:
    """Compile seconds of both arrangements of a new solver ``make()``, and the run time of a
    batch through each."""
    from veil.maps.solve import ITERATIONS, compiled

    solver = make()  # a new solver: nothing of it compiled in this process
    per_stage, batch = compile_cpu(solver.batch, values, coef, y, w2)
    _, state = batch(values, coef, y, w2)
    rest, _ = compile_cpu(lambda c, yy, ww, st: solver.resume(c, yy, ww, st, ITERATIONS),
                          coef, y, w2, state)
    start, _ = compile_cpu(solver.start, values, coef, y, w2)
    iterations, _ = compile_cpu(solver.resume, coef, y, w2, state, np.int64(ITERATIONS))
    first, _ = compiled(solver)
    return {"per stage": per_stage + rest, "split": start + iterations,
            "run per stage": cpu_ms(batch, (values, coef, y, w2), 20),
            "run split": cpu_ms(first, (values, coef, y, w2), 20)}


def measure(make, values, coef, y, w2) -> dict:
    """Before: a program per stage, every LDL^T unrolled; now: start and iterations, the
    LDL^T a loop above UNROLLED_MAX rows (and the split alone, unrolled)."""
    from veil.fitting import least_squares as lsq

    now = lsq.UNROLLED_MAX
    try:
        lsq.UNROLLED_MAX = 1 << 30
        unrolled = arrangements(make, values, coef, y, w2)
    finally:
        lsq.UNROLLED_MAX = now
    looped = arrangements(make, values, coef, y, w2)
    return {"before": unrolled["per stage"], "split": unrolled["split"],
            "now": looped["split"], "run before": unrolled["run per stage"],
            "run now": looped["run split"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    doc_tables.add_options(ap, "maps-solve-compile")
    args = ap.parse_args(argv)
    import jax.numpy as jnp

    found, _ = solver_cases()
    cases = {"one channel (g)": found["one"], "three channels (r, g, b)": found["three"]}
    rows = []
    for name, (make, tab, yy, ww) in cases.items():
        values, coef = (jnp.asarray(a) for a in tab.solver_arrays)
        got = [measure(make, values, coef, jnp.asarray(yy), jnp.asarray(ww))
               for _ in range(args.rounds)]
        best = {k: min(g[k] for g in got) for k in got[0]}
        rows.append([name, f"{best['before']:.2f}", f"{best['split']:.2f}",
                     f"{best['now']:.2f}", f"{best['now'] / best['before']:.2f}",
                     f"{best['run before']:.1f}", f"{best['run now']:.1f}"])
    text = doc_tables.markdown(
        ["solver, 111 configurations", "compile CPU s: a program per stage, LDL unrolled",
         "start + iterations", "and the LDL a loop", "ratio",
         "batch CPU ms: a program per stage, LDL unrolled", "start + iterations, LDL a loop"],
        rows, right={1, 2, 3, 4, 5, 6})
    with doc_tables.printed_tables(args):
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
