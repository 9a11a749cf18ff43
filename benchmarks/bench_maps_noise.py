"""The maps' noise weights (docs/maps-noise.md): cost and bias of one solve with the
samples' own values against the map's two (the second with the model's values at the
first solution), side by side in one process.

    .venv/bin/python benchmarks/bench_maps_noise.py [--pixels 20000] [--noise 0.05,0.1,0.2]
        [--repeat 3] [--doc docs/maps-noise.md]

Distant tables of a Torrance-Sparrow target through the paper's BTDF2 at the paper's 111
configurations, the index fixed (as benchmarks/bench_maps.py part 1); pixels from the
tables' own spline at random roughness and scales, each sample times (1 + REL e), e standard
normal. Per REL: the solve's wall and CPU seconds unweighted (one solve), weighted by the
samples (one solve, the old rule) and weighted by the model's values (two solves and the
model's values between them, the map's rule; the median of ``--repeat`` runs), and each
rule's mean ratio of the estimated diffuse scale Pd to the true one over the converged
pixels.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def timed(fn, repeat):
    """(result of the last run, median wall seconds, median CPU seconds)."""
    runs, out = [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        runs.append((time.perf_counter() - w0, time.process_time() - c0))
    runs.sort()
    return out, runs[len(runs) // 2][0], sorted(c for _, c in runs)[len(runs) // 2]


def scale_ratio(tables, fits, s_true):
    """(mean ratio of the first free scale (the diffuse one) to its truth over the
    converged pixels, their count). The specular scale is left out: where the lobe's width
    and height trade off, single pixels are off by factors that would swamp a bias of a
    per cent."""
    ok = fits.status == 0
    first = np.asarray(fits.params)[tables.free_scales[0]][ok]
    return float(np.mean(first / s_true[ok, 0])), int(ok.sum())


def main(argv=None) -> int:
    import bench_maps as bm
    import doc_tables

    import veil
    from veil.maps.model_error import noise_basis
    from veil.maps.solve import solve_pixels
    from veil.maps.tables import build_tables
    from veil.models import model_class

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=20000)
    ap.add_argument("--noise", default="0.05,0.1,0.2")
    ap.add_argument("--repeat", type=int, default=3)
    doc_tables.add_options(ap, "maps-noise-cost")
    args = ap.parse_args(argv)

    configs = bm.protocol_configs()
    t0 = time.perf_counter()
    cls = model_class("torrance-sparrow", "brdf")
    index = [p.name for p in cls.PARAMS if not p.log_scale and p.name not in
             cls.scale_names()][0]
    tables = build_tables(cls, veil.BTDF2, bm.angles_of(configs),
                          fixed={index: float(cls.param(index).start)})
    t_tables = time.perf_counter() - t0
    rows = []
    for rel in (float(r) for r in args.noise.split(",")):
        y, s_true = bm.synthetic(tables, args.pixels, rel=rel, with_scales=True)
        valid = np.ones_like(y, dtype=bool)
        noise = (rel, 0.0)
        solve_pixels(tables, y[:512], valid[:512], noise)  # compile the weighted program
        solve_pixels(tables, y[:512], valid[:512])

        def two_pass(y=y, valid=valid, noise=noise):
            first = solve_pixels(tables, y, valid, noise)
            basis = noise_basis(tables, first, y, None)
            return solve_pixels(tables, y, valid, noise, basis=basis)

        plain, w_plain, c_plain = timed(partial(solve_pixels, tables, y, valid), args.repeat)
        old, w_old, c_old = timed(partial(solve_pixels, tables, y, valid, noise), args.repeat)
        new, w_new, c_new = timed(two_pass, args.repeat)
        r_plain, _ = scale_ratio(tables, plain, s_true)
        r_old, _ = scale_ratio(tables, old, s_true)
        r_new, n_new = scale_ratio(tables, new, s_true)
        rows.append([f"{rel:g}", f"{w_plain:.2f} ({c_plain:.2f})", f"{w_old:.2f} ({c_old:.2f})",
                     f"{w_new:.2f} ({c_new:.2f})", f"{w_new / w_old:.2f}",
                     f"{r_plain:.4f}", f"{r_old:.4f}", f"{r_new:.4f}", f"{n_new}"])
    header = ["relative noise", "unweighted: wall s (CPU s)", "samples' weights, one solve",
              "model's weights, two solves", "two / one (wall)",
              "Pd / truth (mean), unweighted", "samples' weights", "model's weights",
              "converged (model's weights)"]
    with doc_tables.printed_tables(args):
        print(doc_tables.markdown(header, rows, right=set(range(1, len(header)))))
        print()
        print(f"- {args.pixels} synthetic pixels, Torrance-Sparrow through BTDF2 at "
              f"{len(configs)} configurations, tables {t_tables:.1f} s (built once); "
              f"median of {args.repeat} runs; {platform.machine()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
