"""Benchmark of the reflectance maps (docs/maps.md, docs/performance-maps.md "Reflectance maps").

    .venv/bin/python benchmarks/bench_maps.py [--pixels 20000] [--size 200] [--rss-size 1000]
    .venv/bin/python benchmarks/bench_maps.py --solve-only [--repeat 3] [--tables-cache DIR]
    .venv/bin/python benchmarks/bench_maps.py --near 1000,0.5 [--near-size 200] [--pixels N]

1. tables and the per-pixel solve for a Torrance-Sparrow and a rough-plastic target through
   the paper's BTDF2, at the paper's 111 configurations, the index fixed: seconds for the
   tables, pixels/s of the solve (synthetic pixels: the tables' own values with 1 % noise);
2. the full least-squares fit through the engine (veil.fit_target) on a few pixels
   rendered by the engine: seconds per pixel, and the fast solve's distance from it in
   standard errors (both at the "fast" quadrature, where both use exact Jacobians);
3. a map of SIZE x SIZE pixels from 111 float32 TIFFs, end to end: locally (threads) and on
   a dask.distributed LocalCluster of two worker processes; equal bit for bit?
4. peak RSS of a map of RSS_SIZE^2 pixels from 10 and from 50 photos (a fresh process each;
   --rss-only runs just this part, --rss-photos chooses the photo counts).

--solve-only runs part 1 alone: the solve ``--repeat`` times (the median run is reported,
with its wall and CPU seconds: CPU is the process's time over all its threads).
--tables-cache DIR keeps the tables of part 1 in DIR (pickles, keyed by family and
configurations) so that several runs, e.g. of two versions of the solver, share them.

--channels runs a map of every colour channel (``--channel rgb``) and a one-channel map
(the green channel) of the same RGB photos side by side, warm, in one process
(docs/maps-channels.md): SIZE x SIZE float32 RGB TIFFs at the 111 configurations,
Torrance-Sparrow with per-channel scales through BTDF2 whose T_d and T_t differ per channel
(a step-1 result over r, g, b), the index fixed, unweighted or with ``--noise REL``; a
first round of both compiles, then
``--repeat`` alternating rounds (the median is reported): seconds of the tables, staging and
solve, the whole map's wall and CPU seconds, and the engine calls of the tables.

--near D,P runs the near-field comparison alone (docs/maps-geometry.md "Geometry"): a photo of
NEAR_SIZE x NEAR_SIZE pixels of pitch P seen by a camera at distance D, Torrance-Sparrow
through BTDF2 at the 111 configurations, index fixed, tables at --near-accuracy (default
"fast"): the distant and the near-field tables (seconds, field grid), the interpolation
error of the near-field columns against exact per-pixel tables at a few pixels, and the
solve's pixels/s with and without (synthetic pixels from each set of tables, 1 % noise).
--step-fraction F sets the field grid's step (a fraction of the apparent lobe; default
veil.maps.near.STEP_FRACTION).
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import pickle
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def protocol_configs():
    import veil
    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.0, seed=0)
    return table[["theta_i", "phi_i", "theta_r", "phi_r"]].reset_index(drop=True)


def angles_of(configs):
    return tuple(configs[c].to_numpy(dtype=float)
                 for c in ("theta_i", "phi_i", "theta_r", "phi_r"))


def synthetic(tables, n, seed=0, rel=0.01, with_scales=False):
    """Pixels from the tables' own spline at random nonlinear values and scales, relative
    Gaussian noise ``rel``; with ``with_scales`` (pixels, their true scales)."""
    import jax.numpy as jnp

    from veil.maps.grid import interp as _interp

    rng = np.random.default_rng(seed)
    d = len(tables.axes)
    q = len(tables.free_scales)
    us = [rng.uniform(0.15 * (a.count - 1), 0.85 * (a.count - 1), 64) for a in tables.axes]
    basis = np.stack([np.asarray(_interp(jnp.asarray(tables.coef),
                                         jnp.asarray([u[k] for u in us]), d)[0])
                      for k in range(64)])[np.arange(n) % 64]
    # scales that make each free column carry a similar share of the signal
    size = 1.0 / np.maximum(np.median(np.abs(basis[..., :q]).sum(1), axis=0), 1e-300)
    s = size * np.exp(rng.uniform(-0.5, 0.5, (n, q)))
    y = np.einsum("nmk,nk->nm", basis[..., :q], s) + basis[..., q]
    y = y * (1 + rel * rng.standard_normal(y.shape))
    return (y, s) if with_scales else y


def bench_solve(family, fixed, n_pixels, configs, repeat=1, cache=None):
    """Tables (or the cached ones: seconds then NaN) and the solve of ``n_pixels``
    synthetic pixels, ``repeat`` times: (tables, table seconds, [(wall, cpu) per run],
    fits of the last run)."""
    import veil
    from veil.maps.solve import solve_pixels
    from veil.maps.tables import build_tables
    from veil.models import model_class

    cls = model_class(family, "brdf")
    path = None
    if cache is not None:
        key = hashlib.sha256(repr((family, sorted(fixed.items()))).encode()
                             + b"".join(a.tobytes() for a in angles_of(configs))).hexdigest()
        path = Path(cache) / f"tables-{family}-{key[:16]}.pkl"
    if path is not None and path.is_file():
        tables, t_tables = pickle.loads(path.read_bytes()), float("nan")
    else:
        t0 = time.perf_counter()
        tables = build_tables(cls, veil.BTDF2, angles_of(configs), fixed=fixed)
        t_tables = time.perf_counter() - t0
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(pickle.dumps(tables))
    y = synthetic(tables, n_pixels)
    valid = np.ones_like(y, dtype=bool)
    import jax
    warm = min(len(y), 512 * len(jax.devices()))  # compile on every device
    solve_pixels(tables, y[:warm], valid[:warm])
    runs = []
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fits = solve_pixels(tables, y, valid)
        runs.append((time.perf_counter() - w0, time.process_time() - c0))
    return tables, t_tables, runs, fits


def bench_near(distance, pitch, size, n_pixels, configs, accuracy="fast", fraction=None):
    """Distant against near-field tables and solve (see the module's docstring)."""
    import jax
    import jax.numpy as jnp

    import veil
    from veil.data.ingest import ROI
    from veil.maps import near as maps_near
    from veil.maps.grid import interp_near as _interp_near
    from veil.maps.near import NearGeometry
    from veil.maps.solve import solve_pixels
    from veil.maps.tables import build_tables

    if fraction is not None:
        maps_near.STEP_FRACTION = fraction
    cls = type(veil.BRDF1)
    names = cls.param_names()
    kw = dict(fixed={names[3]: 1.5}, accuracy=accuracy)
    angles = angles_of(configs)
    geometry = NearGeometry(distance, pitch, (size, size))
    rows = {}
    t0 = time.perf_counter()
    far = build_tables(cls, veil.BTDF2, angles, **kw)
    rows["distant"] = [far, time.perf_counter() - t0]
    t0 = time.perf_counter()
    near = build_tables(cls, veil.BTDF2, angles, near=geometry, roi=ROI(0, 0, size, size),
                        **kw)
    rows["near-field"] = [near, time.perf_counter() - t0]
    spread = 2 * math.degrees(math.atan(0.5 * math.hypot(size, size) * pitch / distance))
    print(f"near field: {size} x {size} pixels of {pitch:g} at {distance:g}: spread "
          f"{spread:.3g} deg; {near.near.describe()}; built-in check "
          f"{near.field_error:.2g}", flush=True)
    # interpolation error against exact per-pixel tables (the columns at every table node)
    rng = np.random.default_rng(2)
    pixels = [(0, 0), (size - 1, size - 1), (size - 1, 0)] + [
        tuple(int(v) for v in rng.integers(0, size, 2)) for _ in range(2)]
    worst, t_exact = [], time.perf_counter()
    for x, y in pixels:
        exact = build_tables(cls, veil.BTDF2, geometry.angles(angles, x, y), **kw)
        fu = jnp.asarray(near.field_coords(x, y)[0])
        err = 0.0
        for j in range(near.axes[0].count):
            got = np.asarray(_interp_near(jnp.asarray(near.coef), fu, jnp.asarray([float(j)]),
                                          1)[0])
            want = exact.values[j]
            scale = np.max(np.abs(want), axis=0)
            scale = np.where(scale > 0, scale, 1.0)
            err = max(err, float(np.max(np.abs(got - want) / scale)))
        worst.append(err)
    print(f"interpolation error against exact per-pixel tables at pixels {pixels}: "
          + ", ".join(f"{e:.2g}" for e in worst) + f" of a column's maximum (exact tables "
          f"{(time.perf_counter() - t_exact) / len(pixels):.1f} s per pixel)", flush=True)
    print("\n| geometry | field nodes | tables (s) | pixels | solve (s) | pixels/s | converged |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for kind, (tables, t_tab) in rows.items():
        xs = rng.integers(0, size, n_pixels)
        ys = rng.integers(0, size, n_pixels)
        y = synthetic_at(tables, xs, ys, n_pixels)
        valid = np.ones_like(y, dtype=bool)
        pix = (xs, ys) if tables.near is not None else None
        warm = min(len(y), 512 * len(jax.devices()))
        solve_pixels(tables, y[:warm], valid[:warm],
                     pixels=None if pix is None else (xs[:warm], ys[:warm]))
        w0 = time.perf_counter()
        fits = solve_pixels(tables, y, valid, pixels=pix)
        t_solve = time.perf_counter() - w0
        nodes = "1" if tables.near is None else " x ".join(map(str, tables.near.shape))
        print(f"| {kind} | {nodes} | {t_tab:.1f} | {n_pixels} | {t_solve:.2f} | "
              f"{n_pixels / t_solve:,.0f} | {100 * np.mean(fits.status == 0):.1f} % |",
              flush=True)


def synthetic_at(tables, xs, ys, n, seed=0):
    """Pixels (at xs, ys for near-field tables) from the tables' own spline at random
    nonlinear values and scales, 1 % noise."""
    import jax.numpy as jnp

    from veil.maps.grid import interp_near as _interp_near

    if tables.near is None:
        return synthetic(tables, n, seed)
    rng = np.random.default_rng(seed)
    d, q = len(tables.axes), len(tables.free_scales)
    fu = tables.field_coords(xs, ys)
    coef = jnp.asarray(tables.coef)
    us = np.stack([rng.uniform(0.15 * (a.count - 1), 0.85 * (a.count - 1), n)
                   for a in tables.axes], axis=1)
    import jax
    f = jax.jit(jax.vmap(lambda a, b: _interp_near(coef, a, b, d)[0]))
    basis = np.asarray(f(jnp.asarray(fu), jnp.asarray(us)))
    size = 1.0 / np.maximum(np.median(np.abs(basis[..., :q]).sum(1), axis=0), 1e-300)
    s = size * np.exp(rng.uniform(-0.5, 0.5, (n, q)))
    y = np.einsum("nmk,nk->nm", basis[..., :q], s) + basis[..., q]
    y = y * (1 + rel * rng.standard_normal(y.shape))
    return (y, s) if with_scales else y


def bench_full(configs, n=2):
    import veil
    from support.maps import render
    from veil.maps.solve import solve_pixels
    from veil.maps.tables import build_tables

    brdf, medium = veil.BRDF1, veil.BTDF2
    names = type(brdf).param_names()
    fixed = {names[3]: float(brdf.to_vector()[3])}
    rng = np.random.default_rng(5)
    truth = []
    for _ in range(n):
        v = brdf.to_vector().copy()
        v[2] *= np.exp(rng.uniform(-0.4, 0.4))
        truth.append(v)
    y = render(brdf, medium, configs, np.array(truth))
    y = y * (1 + 0.01 * rng.standard_normal(y.shape))
    tables = build_tables(type(brdf), medium, angles_of(configs), fixed=fixed, accuracy="fast")
    fast = solve_pixels(tables, y, np.ones_like(y, dtype=bool))
    worst, seconds = 0.0, []
    for k in range(n):
        t0 = time.perf_counter()
        full = veil.fit_target(configs.assign(value=y[k]), medium, fixed=fixed,
                               accuracy="fast")
        seconds.append(time.perf_counter() - t0)
        for i, name in enumerate(names):
            if name not in fixed:
                worst = max(worst, abs(fast.params[i, k] - full.params[name])
                            / full.stderr[name])
    return float(np.median(seconds)), worst


def bench_map(size, configs, root):
    from distributed import LocalCluster

    import veil
    from support.maps import write_stack
    from veil.maps.run import fit_maps, open_maps

    brdf, medium = veil.BRDF1, veil.BTDF2
    names = type(brdf).param_names()
    v = brdf.to_vector()
    pm = np.repeat(v[:, None, None], size, 1).repeat(size, 2).copy()
    pm[2] *= np.round(np.exp(np.linspace(-0.4, 0.4, size)), 2)[None, :]
    pm[0, : size // 2] *= 1.5
    manifest = write_stack(root / "photos", brdf, medium, configs, pm, noise=0.01)
    fixed = {names[3]: float(v[3])}
    out = {}
    t0 = time.perf_counter()
    run = fit_maps(root / "photos", manifest, medium, root / "local.zarr", fixed=fixed)
    out["local"] = (time.perf_counter() - t0, run)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        t0 = time.perf_counter()
        run = fit_maps(root / "photos", manifest, medium, root / "cluster.zarr", fixed=fixed,
                       scheduler=cluster.scheduler_address)
        out["cluster"] = (time.perf_counter() - t0, run)
    a, b = open_maps(root / "local.zarr"), open_maps(root / "cluster.zarr")
    equal = all(np.array_equal(a[k], b[k]) for k in ("params", "stderr", "chi2_reduced",
                                                       "status", "n_points"))
    return out, equal


def channel_medium():
    """A step-1 result over r, g, b of BTDF2 with T_d and T_t scaled per channel (a water
    that dims red), each channel's model as given."""
    import veil
    from veil.fitting import FitResult
    from veil.fitting.channel_fit import channel_layout

    dim = {"r": 0.6, "g": 1.0, "b": 1.5}
    m, cls = veil.BTDF2, type(veil.BTDF2)
    slots, layout = channel_layout(cls, list(dim), "medium")
    params = {}
    for s in slots:
        c = "g" if s.owner == "*" else s.owner
        params[s.name] = float(getattr(m.replace(Td=m.Td * dim[c], Tt=m.Tt * dim[c]),
                                       s.spec.name))
    result = FitResult(model=cls.NAME, params=params, stderr={k: 0.0 for k in params},
                       correlation={}, residuals=(0.0,) * 10, chi2_reduced=1.0,
                       rms_relative=0.0, n_points=10, converged=True, message="benchmark",
                       step="medium", options=m.options(), channels=layout)
    return result, {c: result.one_model(c) for c in dim}


def bench_channels(size, configs, root, repeat, noise=None):
    """A map of r, g, b and one of g from the same RGB photos, alternating, warm: {kind:
    [(wall, cpu, run, engine calls of the tables)]}; ``noise`` (relative, absolute) weights
    both maps (veil fit maps --noise; docs/maps-noise.md), None leaves them unweighted."""
    import veil
    from support.maps import write_colour_stack
    from veil.engine.evaluator import ApparentModel
    from veil.maps.run import fit_maps

    brdf = veil.BRDF1
    names = type(brdf).param_names()
    medium, media = channel_medium()
    v = brdf.to_vector()
    maps = {}
    for c, albedo in zip("rgb", (0.5, 1.0, 2.0)):
        pm = np.repeat(v[:, None, None], size, 1).repeat(size, 2).copy()
        pm[2] *= np.round(np.exp(np.linspace(-0.4, 0.4, size)), 2)[None, :]
        pm[0] *= albedo
        pm[0, : size // 2] *= 1.5
        maps[c] = pm
    manifest = write_colour_stack(root / "photos", brdf, media, configs, maps, noise=0.01)
    fixed = {names[3]: float(v[3])}
    calls = [0]
    real = ApparentModel.terms

    def counted(self, vb, vm):
        calls[0] += 1
        return real(self, vb, vm)

    ApparentModel.terms = counted
    out = {"g": [], "rgb": []}
    for k in range(repeat + 1):  # round 0 compiles the solvers: not reported
        for channel in ("g", "rgb"):
            store = root / f"{channel}{k}.zarr"
            calls[0] = 0
            w0, c0 = time.perf_counter(), time.process_time()
            run = fit_maps(root / "photos", manifest, medium, store, fixed=fixed,
                           channel=channel, noise=noise)
            if k:
                out[channel].append((time.perf_counter() - w0, time.process_time() - c0,
                                     run, calls[0]))
            shutil.rmtree(store)
    ApparentModel.terms = real
    return out


def _channels_table(args, configs, root):
    noise = None if args.noise is None else (args.noise, 0.0)
    runs = bench_channels(args.size, configs, root, args.repeat, noise)
    med = {kind: sorted(rs, key=lambda r: r[0])[len(rs) // 2] for kind, rs in runs.items()}
    weighted = "" if noise is None else f", --noise {args.noise:g}"
    print(f"\n| map {args.size} x {args.size} from {len(configs)} photos, warm{weighted} | "
          f"one channel (g) | three channels (r, g, b) | ratio |")
    print("|---|---:|---:|---:|")
    for stage in ("tables", "staging", "solve"):
        one, three = (med[k][2].seconds.get(stage, 0.0) for k in ("g", "rgb"))
        print(f"| {stage} (s) | {one:.1f} | {three:.1f} | {three / one:.2f} |")
    for label, i in (("whole map, wall (s)", 0), ("whole map, CPU (s)", 1)):
        one, three = med["g"][i], med["rgb"][i]
        print(f"| {label} | {one:.1f} | {three:.1f} | {three / one:.2f} |")
    print(f"| engine calls of the tables | {med['g'][3]} | {med['rgb'][3]} | "
          f"{med['rgb'][3] / med['g'][3]:.2f} |")
    for kind in ("g", "rgb"):
        print(f"\n{kind}: rounds (wall s, CPU s): "
              + "; ".join(f"{w:.1f}, {c:.1f}" for w, c, _, _ in runs[kind])
              + f"; converged {med[kind][2].summary['converged']} of "
              f"{med[kind][2].summary['pixels']}")


RSS_CHILD = r"""
import resource, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np, tifffile, veil
from veil.maps.run import fit_maps
root, photos, roi = sys.argv[2], int(sys.argv[3]), (sys.argv[4] or None)
import pathlib, pandas as pd
root = pathlib.Path(root)
names = type(veil.BRDF1).param_names()
t0 = time.perf_counter()
run = fit_maps(root / "photos", root / "manifest.csv", veil.BTDF2, root / f"rss{photos}.zarr",
               fixed={names[3]: 1.55}, roi=roi)
print(time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
      run.seconds.get("tables", 0), run.seconds.get("staging", 0), run.seconds.get("solve", 0))
"""


def bench_rss(shape, photos, configs, root, roi=None):
    """Peak RSS (MiB) and seconds of a map from ``photos`` photos of ``shape`` (rows,
    columns), all of it or its ``roi`` ("X,Y,W,H"): the same image (a plate of BRDF1
    values, noise) at ``photos`` configurations."""
    import tifffile

    import veil
    from support.maps import render

    folder = root / f"rss{photos}"
    (folder / "photos").mkdir(parents=True)
    cfg = configs.iloc[np.linspace(0, len(configs) - 1, photos).round().astype(int)]
    cfg = cfg.drop_duplicates().reset_index(drop=True)
    values = render(veil.BRDF1, veil.BTDF2, cfg, veil.BRDF1.to_vector()[None, :])[0]
    rng = np.random.default_rng(0)
    files = []
    for k, value in enumerate(values):
        img = (value * (1 + 0.01 * rng.standard_normal(shape, dtype=np.float32))).astype(np.float32)
        name = f"p{k:03d}.tif"
        tifffile.imwrite(folder / "photos" / name, img)
        files.append(name)
    cfg.assign(file=files)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]].to_csv(
        folder / "manifest.csv", index=False)
    out = subprocess.run([sys.executable, "-c", RSS_CHILD, str(HERE.parent / "tests"),
                          str(folder), str(len(files)), roi or ""],
                         capture_output=True, text=True, check=True)
    total, rss, t_tab, t_stage, t_solve = map(float, out.stdout.split()[-5:])
    return len(files), total, rss, t_tab, t_stage, t_solve


def _rss_table(args, configs, root):
    rows, cols = ((int(v) for v in args.rss_size.split("x")) if "x" in args.rss_size
                  else (int(args.rss_size),) * 2)
    pixels = rows * cols
    if args.rss_roi:
        pixels = int(np.prod([int(v) for v in args.rss_roi.split(",")[2:]]))
    where = f" (ROI {args.rss_roi})" if args.rss_roi else ""
    print(f"\n| photos of {cols} x {rows}{where} | seconds | peak RSS (MiB) |"
          f" tables | staging | solve | solve pixels/s |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for photos in (int(n) for n in args.rss_photos.split(",")):
        n, total, rss, t_tab, t_stage, t_solve = bench_rss((rows, cols), photos, configs, root,
                                                           args.rss_roi)
        print(f"| {n} | {total:.1f} | {rss:.0f} | {t_tab:.1f} | {t_stage:.1f} | "
              f"{t_solve:.1f} | {pixels / t_solve:,.0f} |", flush=True)
        shutil.rmtree(root / f"rss{photos}", ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=20000)
    ap.add_argument("--size", type=int, default=200)
    ap.add_argument("--rss-size", default="1000", metavar="N|ROWSxCOLS",
                    help="photo size of part 4 (default 1000: 1000 x 1000)")
    ap.add_argument("--rss-roi", default=None, metavar="X,Y,W,H",
                    help="map only this region of part 4's photos (all of each is staged)")
    ap.add_argument("--skip-rss", action="store_true")
    ap.add_argument("--rss-only", action="store_true",
                    help="only the megapixel maps of part 4 (end to end, fresh processes)")
    ap.add_argument("--rss-photos", default="10,50", metavar="N,N",
                    help="photo counts of part 4 (default 10,50)")
    ap.add_argument("--solve-only", action="store_true",
                    help="only part 1 (tables and the per-pixel solve)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="solves per family in part 1; the median is reported")
    ap.add_argument("--tables-cache", default=None, metavar="DIR",
                    help="keep part 1's tables in DIR and reuse them")
    ap.add_argument("--channels", action="store_true",
                    help="only the map of r, g, b against the map of g, side by side")
    ap.add_argument("--noise", type=float, default=None, metavar="REL",
                    help="with --channels: both maps weighted by a relative noise REL "
                         "(solved twice, docs/maps-noise.md); default unweighted")
    ap.add_argument("--near", default=None, metavar="D,P",
                    help="only the near-field comparison: camera distance D, pixel pitch P")
    ap.add_argument("--near-size", type=int, default=200)
    ap.add_argument("--near-accuracy", default="fast")
    ap.add_argument("--step-fraction", type=float, default=None)
    from doc_tables import add_options, printed_tables
    add_options(ap, "maps-solve,maps-map,maps-rss")
    args = ap.parse_args()
    if args.channels and args.doc_table == "maps-solve,maps-map,maps-rss":
        args.doc_table = "maps-channels"
    doc = printed_tables(args).start()
    import veil  # noqa: F401  (JAX set up by veil before the models)
    from veil.models import model_class

    configs = protocol_configs()
    print(f"# bench_maps: {platform.node()}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f}, {len(configs)} configurations\n")
    if args.near:
        distance, pitch = (float(v) for v in args.near.split(","))
        bench_near(distance, pitch, args.near_size, args.pixels, configs, args.near_accuracy,
                   args.step_fraction)
        print(f"\nload average at the end {os.getloadavg()[0]:.1f}")
        doc.finish()
        return
    if args.channels:
        with tempfile.TemporaryDirectory() as tmp:
            _channels_table(args, configs, Path(tmp))
        print(f"\nload average at the end {' / '.join(f'{x:.1f}' for x in os.getloadavg())}")
        doc.finish()
        return
    if args.rss_only:
        with tempfile.TemporaryDirectory() as tmp:
            _rss_table(args, configs, Path(tmp))
        print(f"\nload average at the end {os.getloadavg()[0]:.1f}")
        doc.finish()
        return
    print("| target | free | tables (s) | pixels | solve (s) | CPU (s) | pixels/s | converged |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for family in ("torrance-sparrow", "rough-plastic"):
        cls = model_class(family, "brdf")
        index = [p.name for p in cls.PARAMS if not p.log_scale and p.name not in
                 cls.scale_names()][0]
        fixed = {index: float(cls.param(index).start)}
        tables, t_tab, runs, fits = bench_solve(family, fixed, args.pixels, configs,
                                                args.repeat, args.tables_cache)
        t_solve, t_cpu = sorted(runs)[len(runs) // 2]
        tab = "cached" if math.isnan(t_tab) else f"{t_tab:.1f}"
        print(f"| {family} | {', '.join(tables.free_names)} | {tab} | {args.pixels} | "
              f"{t_solve:.2f} | {t_cpu:.2f} | {args.pixels / t_solve:,.0f} | "
              f"{100 * np.mean(fits.status == 0):.1f} % |", flush=True)
    if args.solve_only:
        print("\nsolve runs (wall s, CPU s): "
              + "; ".join(f"{w:.2f}, {c:.2f}" for w, c in runs)
              + f"\nload average at the end {os.getloadavg()[0]:.1f}")
        doc.finish()
        return
    per_pixel, worst = bench_full(configs)
    print(f"\nfull fit through the engine (veil.fit_target, fast quadrature): {per_pixel:.1f} s "
          f"per pixel ({1 / per_pixel:.2f} pixels/s); fast solve within {worst:.3f} standard "
          f"errors of it", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        runs, equal = bench_map(args.size, configs, Path(tmp))
        print(f"\n| map {args.size} x {args.size} from {len(configs)} photos | seconds | "
              f"tables | staging | solve | solve pixels/s |")
        print("|---|---:|---:|---:|---:|---:|")
        for where, (sec, run) in runs.items():
            s = run.seconds
            print(f"| {where} | {sec:.1f} | {s.get('tables', 0):.1f} | "
                  f"{s.get('staging', 0):.1f} | {s.get('solve', 0):.1f} | "
                  f"{args.size ** 2 / max(s.get('solve', 1e-9), 1e-9):,.0f} |")
        print(f"\nlocal and LocalCluster maps equal bit for bit: {equal}", flush=True)
        if not args.skip_rss:
            _rss_table(args, configs, Path(tmp))
    print(f"\nbenchmark process peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}"
          f" MiB; load average at the end {os.getloadavg()[0]:.1f}")
    doc.finish()


if __name__ == "__main__":
    main()
