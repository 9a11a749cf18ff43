"""veil's per-pixel solve against optimistix + lineax on the same pixels (docs/architecture.md
"One least-squares core"): should the batched Levenberg-Marquardt be a well-kept library's?

    .venv/bin/python benchmarks/bench_maps_optimistix.py [--pixels 20000] [--repeat 3]

The tables, pixels and starting nodes of bench_maps.py's part 1 (Torrance-Sparrow and
rough-plastic through BTDF2 at the paper's 111 configurations, index fixed; synthetic pixels,
1 % noise). Both solvers start from veil's best node; optimistix runs
``optx.LevenbergMarquardt`` (lineax's QR for the damped step) under ``jax.vmap`` in the same
batches of 512 pixels, on the same spline, with the table's bounds as a clip inside the
residual (optimistix has no bounds), and at most veil's :data:`veil.maps.solve.ITERATIONS`
steps. Reported: pixels/s of each, and the median and 99th percentile of the difference in
the nonlinear parameter, in veil's standard errors, over the pixels veil reports converged.
Needs ``pip install optimistix`` (not a dependency of veil).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from bench_maps import angles_of, protocol_configs, synthetic

FAMILIES = (("torrance-sparrow", {"eta": 1.5}), ("rough-plastic", {"eta": 1.5}))


def optimistix_solver(tables, rtol: float, atol: float):
    """A jitted batch solve with optimistix: (values, coef, y, w2) -> (p, steps)."""
    import jax
    import jax.numpy as jnp
    import optimistix as optx

    from veil.maps import solve as maps_solve

    q, d = len(tables.free_scales), len(tables.axes)
    pixel = maps_solve._PixelSolver(q, d, tuple(a.count for a in tables.axes), False, False)
    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def one(coef, y, w2, p0):
        w = jnp.sqrt(w2)

        def residual(p, _):
            p = jnp.clip(p, pixel.lo, pixel.hi)
            val, _ = pixel.columns(coef, None, p[:q], p[q:])
            return (y - val) * w

        sol = optx.least_squares(residual, lm, p0, max_steps=maps_solve.ITERATIONS, throw=False)
        return jnp.clip(sol.value, pixel.lo, pixel.hi), sol.stats["num_steps"]

    def batch(values, coef, y, w2):
        s0, u0 = pixel.node_stage(values, y, w2)
        return jax.vmap(one, in_axes=(None, 0, 0, 0))(
            coef, y, w2, jnp.concatenate([s0, u0], axis=1)
        )

    return jax.jit(batch)


def run_optimistix(tables, y, fn, batch: int = 512):
    import jax

    out, steps = [], []
    for start in range(0, len(y), batch):
        idx = np.minimum(np.arange(start, start + batch), len(y) - 1)
        p, n = fn(tables.values, tables.coef, y[idx], np.ones_like(y[idx]))
        jax.block_until_ready(p)
        k = min(batch, len(y) - start)
        out.append(np.asarray(p)[:k])
        steps.append(np.asarray(n)[:k])
    return np.concatenate(out), np.concatenate(steps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--atol", type=float, default=1e-9)
    args = ap.parse_args()

    import veil
    from veil.maps.solve import CONVERGED, solve_pixels
    from veil.maps.tables import build_tables
    from veil.models import model_class

    configs = protocol_configs()
    print(
        "| target | solver | pixels/s (median of runs) | steps (median) | "
        "|d nonlinear| / stderr: median, 99 % |"
    )
    print("|---|---|---:|---:|---|")
    for family, fixed in FAMILIES:
        tables = build_tables(
            model_class(family, "brdf"), veil.BTDF2, angles_of(configs), fixed=fixed
        )
        y = synthetic(tables, args.pixels)
        valid = np.ones_like(y, dtype=bool)
        solve_pixels(tables, y[:1024], valid[:1024])  # compile
        ours = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            fits = solve_pixels(tables, y, valid)
            ours.append(time.perf_counter() - t0)
        fn = optimistix_solver(tables, args.rtol, args.atol)
        run_optimistix(tables, y[:512], fn)  # compile
        theirs = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            p, steps = run_optimistix(tables, y, fn)
            theirs.append(time.perf_counter() - t0)
        q = len(tables.free_scales)
        ok = fits.status == CONVERGED
        diffs = []
        for c, a in enumerate(tables.axes):
            phys = a.physical(p[:, q + c])
            se = fits.stderr[a.index]
            diffs.append(np.abs(phys - fits.params[a.index])[ok] / se[ok])
        dev = np.max(np.stack(diffs), axis=0)
        n = len(y)
        print(
            f"| {family} | veil | {n / statistics.median(ours):,.0f} | "
            f"{np.median(fits.iterations):.0f} | - |"
        )
        print(
            f"| {family} | optimistix LM + lineax QR | {n / statistics.median(theirs):,.0f} | "
            f"{np.median(steps):.0f} | {np.median(dev):.2g}, {np.quantile(dev, 0.99):.2g} |"
        )


if __name__ == "__main__":
    main()
