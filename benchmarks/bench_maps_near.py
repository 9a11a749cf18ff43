"""The near-field reflectance maps on a small plate (docs/maps-geometry.md "Geometry"): the
field grid's step against its interpolation error, and a plate seen from close by fitted
with and without the per-pixel angles.

The set-up of tests/test_maps_near.py: Torrance-Sparrow (the paper's BRDF1, its index fixed)
through the paper's BTDF2 at 16 configurations of the paper's protocol, the shape n tabulated
from 0.25 to 2.5 at 16 nodes, "fast" quadrature; a photo of 16 x 16 pixels of pitch 0.65 seen
by a pinhole camera 100 units from the plate centre (8.4 deg of view direction across the
field).

1. ``maps-step``, for each step of the field grid (a fraction of the apparent lobe,
   veil.fitting.maps_near.STEP_FRACTION): the field nodes, the tables' seconds, their
   built-in check (the largest interpolation error at two corner cells' centres, relative
   to a column's maximum) and the worst error at 6 pixels x 16 nodes against exact tables
   built at each pixel's own angles.
2. ``maps-plate``: two materials (left BRDF1, right smoother and glossier), every pixel
   rendered by the engine at its exact angles, 1 % noise, fitted by veil.fit_maps with
   --near-field and with the distant approximation: the errors in standard errors (mean,
   sd) of each free parameter, the share within two standard errors, the median reduced
   chi-square, the mean relative error of Ps and n, the tables' seconds.

    PYTHONPATH=src python benchmarks/bench_maps_near.py [--steps 0.4,0.3,0.2,0.15,0.1]
        [--only step|plate] [--doc docs/maps-geometry.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import doc_tables  # noqa: E402

H = W = 16
DISTANCE, PITCH = 100.0, 0.65
GRID = (0.25, 2.5, 16)
STEPS = "0.4,0.3,0.2,0.15,0.1"


def configurations(count: int = 16):
    """``count`` in-plane configurations spread over the paper's protocol (psi = 30, 60,
    90 deg), denser near the mirror direction (as the maps tests choose them)."""
    import veil

    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.0, seed=0)
    idx = np.unique(np.linspace(0, len(table) - 1, count).round().astype(int))
    return table.iloc[idx][["theta_i", "phi_i", "theta_r", "phi_r"]].reset_index(drop=True)


def angles_of(configs):
    return tuple(configs[c].to_numpy(dtype=float)
                 for c in ("theta_i", "phi_i", "theta_r", "phi_r"))


def _sci(x: float) -> str:
    """2.3e-3, not 2.3e-03."""
    return f"{x:.1e}".replace("e-0", "e-").replace("e+0", "e+")


def setup():
    import veil

    cls = type(veil.BRDF1)
    names = cls.param_names()
    index, shape = names[3], names[2]
    kw = dict(fixed={index: float(veil.BRDF1.to_vector()[3])}, grid={shape: GRID},
              accuracy="fast")
    return cls, names, shape, kw


# ---- 1. the step of the field grid -----------------------------------------------------
def step_sweep(fractions: list[float]) -> None:
    import veil
    from veil.data.ingest import ROI
    from veil.fitting import maps_near
    from veil.fitting.maps import build_tables
    from veil.fitting.maps_near import NearGeometry

    cls, _, shape, kw = setup()
    angles = angles_of(configurations(16))
    g = NearGeometry(DISTANCE, PITCH, (H, W))
    rng = np.random.default_rng(3)
    pixels = [(0, 0), (W - 1, H - 1), (W - 1, 0), (3, 11)] + \
        [tuple(int(v) for v in rng.integers(0, W, 2)) for _ in range(2)]
    build_tables(cls, veil.BTDF2, angles, **kw)  # compiles the programs, not timed
    exact = {p: build_tables(cls, veil.BTDF2, g.angles(angles, *p), **kw) for p in pixels}
    default = maps_near.STEP_FRACTION
    rows = []
    try:
        for fraction in fractions:
            maps_near.STEP_FRACTION = fraction
            t0 = time.perf_counter()
            near = build_tables(cls, veil.BTDF2, angles, near=g, roi=ROI(0, 0, W, H), **kw)
            seconds = time.perf_counter() - t0
            axis, worst = near.axes[0], 0.0
            for p in pixels:
                for j, value in enumerate(axis.nodes()):
                    got = near.basis({shape: value}, pixel=p)
                    want = exact[p].values[j]
                    scale = np.max(np.abs(want), axis=0)
                    scale = np.where(scale > 0, scale, 1.0)  # the known part: 0
                    worst = max(worst, float(np.max(np.abs(got - want) / scale)))
            label = f"**{fraction:g}** (default)" if fraction == default else f"{fraction:g}"
            nodes = " x ".join(map(str, near.near.shape))
            rows.append([label, nodes, f"{seconds:.1f}", _sci(near.field_error), _sci(worst)])
            print(f"  step {fraction:g}: {nodes} nodes, {seconds:.1f} s", file=sys.stderr,
                  flush=True)
    finally:
        maps_near.STEP_FRACTION = default
    print(f"\nfield grid step: {len(angles[0])} configurations, BTDF2, n {GRID[0]:g}-{GRID[1]:g}"
          f", {W} x {H} pixels of {PITCH:g} at {DISTANCE:g}; worst of {len(pixels)} pixels x "
          f"{GRID[2]} nodes against exact per-pixel tables\n")
    print(doc_tables.markdown(["step (fraction of the apparent lobe)", "field nodes",
                               "tables (s)", "built-in check", f"worst of {len(pixels)} pixels"],
                              rows, {0, 1, 2, 3, 4}))


# ---- 2. a plate seen from close by -----------------------------------------------------
def render_near(brdf, medium, configs, param_maps, geometry, accuracy="fast"):
    """Apparent values (H*W, M) of a plate seen by a near camera: every pixel at its own
    exact angles, one engine evaluation per distinct parameter vector over its pixels."""
    from veil.engine.evaluator import ApparentModel
    from veil.engine.quadrature import RULES

    n, h, w = param_maps.shape
    yy, xx = np.mgrid[0:h, 0:w]
    pix = geometry.angles(angles_of(configs), xx.ravel(), yy.ravel())  # each (H*W, M)
    uniq, inverse = np.unique(param_maps.reshape(n, -1).T, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    out = np.empty(pix[0].shape)
    for k, v in enumerate(uniq):
        rows = np.flatnonzero(inverse == k)
        engine = ApparentModel(brdf, medium, tuple(a[rows].ravel() for a in pix),
                               RULES[accuracy])
        out[rows] = engine.values(v, medium.to_vector()).reshape(len(rows), -1)
    return out


def write_photos(folder: Path, configs, values, noise=0.01, seed=5) -> Path:
    """Float32 TIFFs of ``values`` (H*W, M) with relative Gaussian noise, and the manifest."""
    import tifffile

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    values = values * (1 + noise * rng.standard_normal(values.shape))
    names = []
    for k in range(len(configs)):
        names.append(f"photo_{k:03d}.tif")
        tifffile.imwrite(folder / names[-1], values[:, k].reshape(H, W).astype(np.float32))
    manifest = configs.assign(file=names)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]]
    manifest.to_csv(folder / "manifest.csv", index=False)
    return folder / "manifest.csv"


def plate() -> None:
    import veil
    from veil.fitting.maps import CONVERGED
    from veil.fitting.maps_near import NearGeometry
    from veil.fitting.maps_run import fit_maps, open_maps

    _, names, _, kw = setup()
    v = veil.BRDF1.to_vector()
    truth = np.repeat(v[:, None, None], H, 1).repeat(W, 2).copy()
    truth[2, :, W // 2:] = 1.1
    truth[1, :, W // 2:] *= 1.5
    configs = configurations(16)
    values = render_near(veil.BRDF1, veil.BTDF2, configs, truth,
                         NearGeometry(DISTANCE, PITCH, (H, W)))
    # the tables' programs compiled (or loaded) first: the seconds below are the tables' own
    from veil.data.ingest import ROI
    from veil.fitting.maps import build_tables
    angles = angles_of(configs)
    build_tables(type(veil.BRDF1), veil.BTDF2, angles, **kw)
    build_tables(type(veil.BRDF1), veil.BTDF2, angles, near=NearGeometry(DISTANCE, PITCH, (H, W)),
                 roi=ROI(0, 0, 4, 4), **kw)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        manifest = write_photos(Path(tmp) / "photos", configs, values)
        for label, near in (("`--near-field`", True), ("distant", False)):
            out = Path(tmp) / f"{label.strip('`-')}.zarr"
            run = fit_maps(Path(tmp) / "photos", manifest, veil.BTDF2, out, fixed=kw["fixed"],
                           grid=kw["grid"], accuracy="fast", noise=(0.01, 0.0), tile=8,
                           geometry=(DISTANCE, PITCH), near_field=near)
            maps = open_maps(out)
            ok = maps["status"] == CONVERGED
            free = [names.index(n) for n in maps["info"]["free"]]
            z = np.stack([(maps["params"][k] - truth[k])[ok] / maps["stderr"][k][ok]
                          for k in free])
            rel = {k: float(np.mean((maps["params"][k] - truth[k])[ok] / truth[k][ok]))
                   for k in free}
            cells = [label] + [f"{z[i].mean():+.2f}, {z[i].std():.2f}"
                               for i in range(len(free))]
            within = ", ".join(f"{100 * np.mean(np.abs(z[i]) < 2):.0f}"
                               for i in range(len(free)))
            cells += [f"{within} %", f"{np.median(maps['chi2_reduced'][ok]):.3g}",
                      ", ".join(f"{100 * rel[k]:+.2g} %" for k in free[1:]),
                      f"{run.seconds['tables']:.1f}", f"{np.mean(ok) * 100:.0f} %"]
            rows.append(cells)
            print(f"  {label}: {run.seconds}", file=sys.stderr, flush=True)
    free_names = [names[k] for k in free]
    print(f"\nplate of {W} x {H} pixels of {PITCH:g} at {DISTANCE:g}, two materials, 1 % "
          f"noise: errors in standard errors\n")
    headers = (["geometry"] + [f"{n}: mean, sd" for n in free_names]
               + [f"within 2 se ({', '.join(free_names)})", "reduced chi-square (median)",
                  f"{', '.join(free_names[1:])}: mean relative error", "tables (s)",
                  "converged"])
    print(doc_tables.markdown(headers, rows, {4, 5, 7, 8}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", default=STEPS, help="the field grid's steps, fractions of the "
                    "apparent lobe (default: %(default)s)")
    ap.add_argument("--only", default=None, choices=("step", "plate"))
    doc_tables.add_options(ap, "maps-step,maps-plate")
    args = ap.parse_args(argv)
    if args.only and args.doc_table == "maps-step,maps-plate":
        args.doc_table = f"maps-{args.only}"
    with doc_tables.printed_tables(args):
        if args.only in (None, "step"):
            step_sweep([float(s) for s in args.steps.split(",")])
        if args.only in (None, "plate"):
            plate()
    return 0


if __name__ == "__main__":
    sys.exit(main())
