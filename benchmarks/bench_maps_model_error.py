"""Cost of the model's own error in the maps (docs/maps-model-error.md "Cost").

    .venv/bin/python benchmarks/bench_maps_model_error.py [--size 64] [--repeat 3] \
        [--doc docs/maps-model-error.md]

One tile of SIZE x SIZE pixels at the paper's 111 configurations, Torrance-Sparrow through
BTDF2 (the index fixed), grey and over r, g, b (BTDF2's T_d and T_t scaled per channel):
synthetic pixels, the tables' own values at random parameters times (1 + d), d a Gaussian
process over the configurations (s 3 %, ell 20 deg, a draw per pixel and channel), with 1 %
noise. The tile is solved as `veil fit maps` solves it (veil.maps.tile), without the term,
with an independent one and with a correlated one, in alternating rounds after one that
compiles (the median of ``--repeat`` is reported, wall and CPU seconds), and the share of
pixels whose true parameters lie within 2 standard errors; the correlated term once more on
the BLAS library's default threads instead of one.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_maps import angles_of, channel_medium, protocol_configs  # noqa: E402


def tables_of(colour: bool):
    """The tables of the grey or the colour map (default quadrature)."""
    import veil
    from veil.maps.channels import build_channel_tables
    from veil.maps.tables import build_tables

    cls = type(veil.BRDF1)
    fixed = {cls.param_names()[3]: float(veil.BRDF1.to_vector()[3])}
    angles = angles_of(protocol_configs())
    if colour:
        return build_channel_tables(cls, channel_medium()[1], angles, fixed=fixed)
    return build_tables(cls, veil.BTDF2, angles, fixed=fixed)


def pixels_of(tables, n: int, seed: int = 0):
    """(values (n, C * M), true solver parameters (n, C * q + d)): the tables at random
    parameters, each channel's values times (1 + d) and 1 % noise (module docstring)."""
    from veil._jax import jnp
    from veil.fitting.model_error import correlation, distances
    from veil.maps.model_error import _program

    rng = np.random.default_rng(seed)
    c, q = max(1, len(tables.channels)), len(tables.free_scales)
    us = np.stack([rng.uniform(0.15, 0.85, n) * (a.count - 1) for a in tables.axes], axis=1)
    ones = np.concatenate([np.ones((n, c * q)), us], axis=1)
    # scales that give each free column a similar share of the signal
    b = np.asarray(_program(tables)(jnp.asarray(tables.coef), None, jnp.asarray(ones))[1])
    size = 1.0 / np.maximum(np.median(np.abs(b[:, :, :q]).sum(1), axis=0), 1e-300)
    scales = np.tile(size, c) * np.exp(rng.uniform(-0.5, 0.5, (n, c * q)))
    p = np.concatenate([scales, us], axis=1)
    f = np.asarray(_program(tables)(jnp.asarray(tables.coef), None, jnp.asarray(p))[0])
    m = tables.n_configs
    chol = np.linalg.cholesky(correlation(distances(tables.angles), 20.0) + 1e-10 * np.eye(m))
    d = np.einsum("ij,ncj->nci", chol, rng.standard_normal((n, c, m))).reshape(n, c * m)
    y = f * (1 + 0.03 * d) * (1 + 0.01 * rng.standard_normal(f.shape))
    return y, p


def block_of(tables, y, size: int) -> np.ndarray:
    """A tile's block ((C,) M, size, size) of pixels ``y`` (size^2, C * M)."""
    m = tables.n_configs
    if not tables.channels:
        return y.T.reshape(m, size, size)
    c = len(tables.channels)
    return np.moveaxis(y.reshape(-1, c, m), 0, -1).reshape(c, m, size, size)


def covered(tables, fits, p) -> float:
    """The share of converged pixels whose true scales and axis values (solver coordinates)
    all lie within 2 of their standard errors."""
    from veil.maps.model_error import solver_parameters, solver_stderr

    est, se = solver_parameters(tables, fits), solver_stderr(tables, fits)
    inside = np.all(np.abs(est - p) <= 2 * np.where(se > 0, se, np.inf), axis=1)
    return float(np.mean(inside[fits.status == 0]))


#: The rows: the kind, and whether the terms run on one BLAS thread (veil's way) or on the
#: library's default threads (the comparison that chose it).
KINDS = (
    ("off", True),
    ("independent", True),
    ("correlated", True),
    ("correlated, BLAS's default threads", False),
)


def run(colour: bool, size: int, repeat: int) -> list:
    """One table row per kind: (kind, wall, cpu, share within 2 se, median s)."""
    import contextlib

    import veil.maps.model_error as me
    from veil.maps.tile import _fits, _tile_pixels, _values

    tables = tables_of(colour)
    y, p = pixels_of(tables, size * size)
    block = block_of(tables, y, size)
    tile_rows = (*_values(block, tables), _tile_pixels(tables, 0, 0, size, size, size))
    noise = (0.01, 0.0)
    kinds = [k for k, _ in KINDS]
    times: dict = {k: [] for k in kinds}
    found: dict = {}
    one = me.one_blas_thread
    for r in range(repeat + 1):  # round 0 compiles
        for kind, single in KINDS:
            setting = me.discrepancy(kind.split(",")[0], noise)
            me.one_blas_thread = one if single else contextlib.nullcontext
            w0, c0 = time.perf_counter(), time.process_time()
            fits, _, terms, _ = _fits(tile_rows, tables, noise, setting)
            me.one_blas_thread = one
            if r:
                times[kind].append((time.perf_counter() - w0, time.process_time() - c0))
            found[kind] = (fits, terms)
    rows = []
    for kind in kinds:
        wall, cpu = sorted(times[kind])[len(times[kind]) // 2]
        fits, terms = found[kind]
        s = "-" if terms is None else f"{np.median(terms[0][:, fits.status == 0]):.3f}"
        rows.append((kind, wall, cpu, covered(tables, fits, p), s))
    return rows


def main() -> int:
    from doc_tables import add_options, printed_tables

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=64, help="the tile's side in pixels")
    ap.add_argument("--repeat", type=int, default=3)
    add_options(ap, "maps-model-error-cost")
    args = ap.parse_args()
    with printed_tables(args):
        print(
            f"\n| tile of {args.size} x {args.size} pixels, 111 configurations | model error "
            "| wall (s) | CPU (s) | wall / without | true parameters within 2 se | median s |"
        )
        print("|---|---|---:|---:|---:|---:|---:|")
        for colour in (False, True):
            rows = run(colour, args.size, args.repeat)
            base = rows[0][1]
            for kind, wall, cpu, share, s in rows:
                print(
                    f"| {'r, g, b' if colour else 'grey'} | {kind} | {wall:.2f} | {cpu:.2f} "
                    f"| {wall / base:.2f} | {100 * share:.1f} % | {s} |"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
