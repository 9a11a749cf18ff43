"""
Reflectance maps with a known answer
====================================

Reflectance maps with a known answer (docs/maps.md).

A plate of two Torrance-Sparrow materials (a matte left half, a glossy right half), with a
roughness gradient from top to bottom and a diagonal scratch whose facets are tilted by
TILT degrees in the plane of incidence (a surface the per-pixel model, whose normal is the
plate's, cannot describe; simulated by evaluating the apparent BRDF at the angles measured
from the tilted normal), is photographed through the
paper's medium BTDF2 at the paper's 111 configurations with 1 % noise, as float32 TIFFs
with a manifest. `veil fit maps` then recovers the maps; the figure shows the truth, the
estimate, the error in standard errors and the chi-square map, which finds the scratch.

    .venv/bin/python examples/maps.py [-o maps-example] [--size 48]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


TILT = 10.0


def tilted(configs, tilt):
    """In-plane configurations (azimuths 0 or 180 deg) seen from a facet whose normal is
    tilted by ``tilt`` degrees towards +x: each direction's signed angle from the normal
    shifts by ``tilt`` (crossing the normal flips its azimuth); held at 89 deg."""
    out = configs.copy()
    for theta, phi in (("theta_i", "phi_i"), ("theta_r", "phi_r")):
        signed = np.where(configs[phi].to_numpy() == 0.0, 1.0, -1.0) * configs[theta].to_numpy()
        moved = signed - tilt
        out[theta] = np.minimum(np.abs(moved), 89.0)
        out[phi] = np.where(moved >= 0, 0.0, 180.0)
    return out


def plate(size: int, brdf):
    """(truth (P, H, W) of the plate, scratch mask (H, W))."""
    h, w = size, int(size * 4 / 3)
    v = brdf.to_vector()
    truth = np.repeat(v[:, None, None], h, 1).repeat(w, 2).copy()
    left = np.arange(w) < w // 2
    truth[0][:, left] *= 2.0           # matte: more diffuse
    truth[1][:, left] *= 0.3           # ... less specular
    gradient = np.round(np.exp(np.linspace(-0.5, 0.5, h)), 2)  # quantized: fewer renders
    truth[2] *= gradient[:, None]
    yy, xx = np.mgrid[0:h, 0:w]
    scratch = np.abs((yy - 0.15 * h) - 0.6 * (xx - 0.1 * w)) < 1.0
    return truth, scratch


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--outdir", default="maps-example")
    ap.add_argument("--size", type=int, default=48)
    ap.add_argument("--image", default=None, help="also write the figure here")
    args = ap.parse_args()

    import tifffile

    import veil
    from support.maps import render
    from veil.maps.solve import CONVERGED

    out = Path(args.outdir)
    (out / "photos").mkdir(parents=True, exist_ok=True)
    brdf, medium = veil.BRDF1, veil.BTDF2
    names = type(brdf).param_names()
    configs = veil.simulate(brdf, medium, noise=0.0, seed=0)[
        ["theta_i", "phi_i", "theta_r", "phi_r"]]
    truth, scratch = plate(args.size, brdf)
    p, h, w = truth.shape
    print(f"rendering {h} x {w} pixels at {len(configs)} configurations through BTDF2 ...")
    values = render(brdf, medium, configs, truth.reshape(p, -1).T).reshape(h, w, -1)
    values[scratch] = render(brdf, medium, tilted(configs, TILT),
                             truth[:, scratch].T)
    rng = np.random.default_rng(0)
    values *= 1 + 0.01 * rng.standard_normal(values.shape)
    files = []
    for k in range(len(configs)):
        name = f"photo_{k:03d}.tif"
        tifffile.imwrite(out / "photos" / name, values[:, :, k].astype(np.float32))
        files.append(name)
    manifest = out / "manifest.csv"
    configs.assign(file=files)[["file", "theta_i", "phi_i", "theta_r", "phi_r"]].to_csv(
        manifest, index=False)

    store = out / "maps.zarr"
    index = names[3]
    print(f"veil fit maps {out / 'photos'} --manifest {manifest} --medium BTDF2 "
          f"--fix {index}={brdf.to_vector()[3]} --noise 0.01 -o {store}")
    run = veil.fit_maps(out / "photos", manifest, medium, store,
                        fixed={index: float(brdf.to_vector()[3])}, noise=(0.01, 0.0),
                        tile=32, log=print)
    print(f"{run.summary['converged']} of {run.summary['pixels']} pixels converged; "
          f"seconds: {run.seconds}")
    maps = veil.open_maps(store)
    ok = maps["status"] == CONVERGED
    k = 2  # the roughness parameter
    z = np.where(ok & ~scratch, (maps["params"][k] - truth[k]) / np.where(ok, maps["stderr"][k],
                                                                         1.0), np.nan)
    zs = z[np.isfinite(z)]
    print(f"{names[k]}: error / stderr off the scratch: median {np.median(zs):+.2f}, "
          f"rms {np.sqrt(np.mean(zs ** 2)):.2f} ({zs.size} pixels)")
    chi = maps["chi2_reduced"]
    print(f"reduced chi-square: median {np.median(chi[~scratch]):.2f} off the scratch, "
          f"{np.median(chi[scratch]):.1f} on it")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    fig, axes = plt.subplots(1, 4, figsize=(17, 3.6))
    lo, hi = truth[k].min() * 0.9, truth[k].max() * 1.1
    for ax, image, title in ((axes[0], truth[k], f"true {names[k]}"),
                             (axes[1], np.where(ok, maps["params"][k], np.nan),
                              f"estimated {names[k]}")):
        im = ax.imshow(image, vmin=lo, vmax=hi, cmap="viridis")
        fig.colorbar(im, ax=ax, label=f"{names[k]} [1/deg]")
        ax.set_title(title)
    im = axes[2].imshow(z, vmin=-4, vmax=4, cmap="RdBu_r")
    fig.colorbar(im, ax=axes[2], label="(estimate - truth) / stderr")
    axes[2].set_title("error in standard errors (scratch blank)")
    im = axes[3].imshow(np.where(chi > 0, chi, np.nan), norm=LogNorm(0.3, max(chi.max(), 10)),
                        cmap="magma")
    fig.colorbar(im, ax=axes[3], label="reduced chi-square")
    axes[3].set_title("reduced chi-square: the scratch")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "maps_example.png", dpi=100)
    if args.image:
        fig.savefig(args.image, dpi=100)
    print(f"wrote {out / 'maps_example.png'}")


if __name__ == "__main__":
    main()
