"""Where a colour map's solve spends its time: one batch of the per-pixel solve, one channel
against three, part by part (docs/maps-channels.md "Cost").

    .venv/bin/python benchmarks/bench_maps_solve_parts.py [--repeat 20] [--doc PAGE]

The tables are bench_maps.py's --channels case: Torrance-Sparrow with per-channel scales
through BTDF2 whose T_d and T_t differ per channel, at the paper's 111 configurations, the
index fixed, 48 roughness nodes ("default" rule). A batch of veil.maps.solve.BATCH pixels is
made from the three-channel tables' own spline at random roughness and scales, 1 % noise,
weighted by that noise; the one-channel solve fits those pixels' green channel, through the
green channel's tables. Each part is jitted alone and timed in CPU seconds of this process,
on one core with XLA's intra-op threads off (the machine's load then matters less than to
wall seconds); the best of three rounds of ``--repeat`` calls is reported.
"""

from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "")
    + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
).strip()
os.environ.setdefault("JAX_PLATFORMS", "cpu")
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import doc_tables  # noqa: E402


def tables():
    """(three-channel tables, green-channel tables) of bench_maps.py's --channels case."""
    from bench_maps import angles_of, channel_medium, protocol_configs

    import veil
    from veil.maps.channels import build_channel_tables
    from veil.maps.tables import build_tables

    angles = angles_of(protocol_configs())
    _, media = channel_medium()
    names = type(veil.BRDF1).param_names()
    fixed = {names[3]: float(veil.BRDF1.to_vector()[3])}
    three = build_channel_tables(type(veil.BRDF1), media, angles, fixed=fixed)
    return three, build_tables(type(veil.BRDF1), media["g"], angles, fixed=fixed)


def pixels(three, seed=0):
    """A batch of three-channel pixels (BATCH, 3 * M) and their weights, from the tables'
    spline at random roughness and scales, 1 % noise."""
    import jax
    import jax.numpy as jnp

    from veil.maps.grid import interp
    from veil.maps.solve import BATCH

    rng = np.random.default_rng(seed)
    top = three.axes[0].count - 1
    u = jnp.asarray(rng.uniform(2, top - 2, (BATCH, 1)))
    b = np.asarray(jax.vmap(lambda x: interp(jnp.asarray(three.coef), x, 1)[0])(u))
    s = rng.uniform(0.5, 1.5, b.shape[:2] + (b.shape[-1] - 1,))
    y = np.einsum("pcmk,pck->pcm", b[..., :-1], s) + b[..., -1]
    y = y * (1 + 0.01 * rng.standard_normal(y.shape))
    return y, 1.0 / (0.01 * y) ** 2, u


def cpu_ms(fn, args, repeat):
    """Best of three rounds of ``repeat`` calls: CPU milliseconds a call."""
    import jax

    jax.block_until_ready(fn(*args))
    best = []
    for _ in range(3):
        t0 = time.process_time()
        for _ in range(repeat):
            jax.block_until_ready(fn(*args))
        best.append((time.process_time() - t0) / repeat * 1e3)
    return min(best)


def parts(solver, values, coef, y, w2, u, repeat):
    """{part: CPU ms of one batch} of ``solver`` on pixels ``y`` with weights ``w2``."""
    import jax
    import jax.numpy as jnp

    from veil.fitting import least_squares as lsq

    n, fu = y.shape[0], jnp.zeros((y.shape[0], 0))
    w = jnp.sqrt(w2)
    p = jnp.concatenate([jnp.ones((n, solver.q)), u], axis=1)
    vm = jax.vmap
    refit = vm(lambda f, yy, ww, pp: solver.refit(coef, f, yy, ww, pp))
    _, val, jac = refit(fu, y, w, p)
    r = (y - val) * w
    a, g = vm(solver.normal)(jac, w, r)
    state = vm(solver.initial, in_axes=(None, 0, 0, 0, 0, 0))(
        coef, fu, u, jnp.ones((n, solver.q)), y, w2
    )
    lam = jnp.full(n, lsq.DAMPING_START)
    step = vm(lambda pp, aa, gg, ll: lsq.lm_step(pp, aa, gg, ll, solver.lo, solver.hi, jnp))
    calls = {
        "node stage": (jax.jit(solver.node_stage), (values, y, w2)),
        "interpolation (basis and slope)": (
            jax.jit(vm(lambda f, x: solver.interp(coef, f, x))),
            (fu, u),
        ),
        "refit (interpolation, scales by NNLS, Jacobian)": (jax.jit(refit), (fu, y, w, p)),
        "normal matrix": (jax.jit(vm(solver.normal)), (jac, w, r)),
        "Levenberg-Marquardt step": (jax.jit(step), (p, a, g, lam)),
        "one iteration": (
            jax.jit(vm(lambda f, yy, ww, st: solver.iterate(coef, f, yy, ww, st))),
            (fu, y, w, state),
        ),
        "covariance": (jax.jit(vm(solver.covariance)), (jac, w, r)),
        "batch (node stage, at most 4 iterations, statistics)": (
            jax.jit(solver.batch),
            (values, coef, y, w2),
        ),
    }
    return {name: cpu_ms(fn, args, repeat) for name, (fn, args) in calls.items()}


def solver_cases() -> tuple[dict, np.ndarray]:
    """({"one": ..., "three": ...}: (a function making a new solver, its tables, pixels,
    weights) of the green channel alone and of the three channels, each pixel's channels one
    after the other; the pixels' roughness coordinates)."""
    from veil.maps.solve import _PixelSolver
    from veil.maps.solve_channels import _ChannelSolver

    three, one = tables()
    y, w2, u = pixels(three)
    m = three.n_configs
    q, sizes = len(three.free_scales), tuple(a.count for a in three.axes)
    cases = {
        "one": (lambda: _PixelSolver(q, 1, sizes, True, False), one, y[:, 1], w2[:, 1]),
        "three": (
            lambda: _ChannelSolver(3, q, 1, sizes, True),
            three,
            y.reshape(-1, 3 * m),
            w2.reshape(-1, 3 * m),
        ),
    }
    return cases, u


def iterations(solver, values, coef, y, w2) -> str:
    """The batch solved as a map solves it (the first iterations, then the slow pixels'
    rest): its pixels' iteration counts, the mean and the largest."""
    from veil.maps.solve import compiled

    first, rest = compiled(solver)
    _, state = first(values, coef, y, w2)
    counts = np.asarray(rest(coef, y, w2, state)[0][6])
    return f"iterations per pixel: mean {counts.mean():.2f}, largest {counts.max()}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=20)
    doc_tables.add_options(ap, "maps-solve-parts")
    args = ap.parse_args(argv)
    import jax.numpy as jnp

    cases, u = solver_cases()
    n, m = len(u), cases["one"][1].n_configs
    ms = {}
    for kind, (make, tab, yy, ww) in cases.items():
        values, coef = (jnp.asarray(a) for a in tab.solver_arrays)
        ms[kind] = parts(make(), values, coef, jnp.asarray(yy), jnp.asarray(ww), u, args.repeat)
        print(kind, iterations(make(), values, coef, jnp.asarray(yy), jnp.asarray(ww)))
    rows = [
        [
            name,
            f"{ms['one'][name]:.2f}",
            f"{ms['three'][name]:.2f}",
            f"{ms['three'][name] / ms['one'][name]:.2f}",
        ]
        for name in ms["one"]
    ]
    text = doc_tables.markdown(
        [
            f"a batch of {n} pixels, {m} configurations: CPU ms on one core",
            "one channel (g)",
            "three channels (r, g, b)",
            "ratio",
        ],
        rows,
        right={1, 2, 3},
    )
    with doc_tables.printed_tables(args):
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
