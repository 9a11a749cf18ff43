"""
From photographs to the target's true BRDF
==========================================

From photographs to the target's true BRDF, end to end on synthetic photos.

A goniometer session is what a user's disk holds: one photo per stage rotation, the object
patch and a black cloth beside it, both seen through the medium. This example

1. makes such a session: for each configuration of the paper's protocol (psi = 30, 60, 90
   deg) a 16-bit TIFF whose object patch has the radiance veil predicts for BRDF1 seen
   through BTDF2 plus the medium's own glow, and whose black-cloth patch has the glow alone,
   with a camera offset, photon-like noise and a dark frame;
2. ingests the folder (``veil.data.ingest.ingest``: ROI means, standard errors, saturation check);
3. subtracts the black cloth and fits the target's Torrance-Sparrow parameters with the
   medium known (step 2 of docs/model.md sec. 7), and prints them beside the truth.

    .venv/bin/python examples/photos_to_fit.py [OUTDIR]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import tifffile

import veil
from veil.data.black_cloth import subtract_black
from veil.data.ingest import ingest

GAIN = 2000.0      # camera code values per unit of apparent reflectance
OFFSET = 400.0     # camera black level (code values), removed by the dark frame
READ_NOISE = 30.0  # code values, per pixel
SHAPE = (60, 80)   # photo height, width
OBJECT_ROI = (10, 10, 24, 24)   # X, Y, W, H
BLACK_ROI = (46, 10, 24, 24)


def make_session(folder: Path, brdf, medium, seed=0):
    """Write one TIFF per configuration, a dark frame and the manifest; return the apparent
    reflectance without glow (what black-cloth subtraction should recover)."""
    truth, glow = veil.simulate(brdf, medium, noise=0.0, seed=seed, black=True)
    rng = np.random.default_rng(seed)
    rows = []
    for k, (obj, blk) in enumerate(zip(truth["value"], glow["value"])):
        img = np.full(SHAPE, OFFSET)
        x, y, w, h = OBJECT_ROI
        img[y:y + h, x:x + w] += GAIN * obj
        x, y, w, h = BLACK_ROI
        img[y:y + h, x:x + w] += GAIN * blk
        signal = np.maximum(img - OFFSET, 0.0)
        img = img + rng.normal(0.0, 1.0, SHAPE) * np.sqrt(READ_NOISE ** 2 + signal)
        name = f"rot_{k:03d}.tif"
        tifffile.imwrite(folder / name, np.clip(np.rint(img), 0, 65535).astype(np.uint16))
        rows.append({"file": name, "psi": truth["psi"].iloc[k], "rho": truth["rho"].iloc[k]})
    dark = np.clip(np.rint(OFFSET + rng.normal(0.0, 1.0, SHAPE)), 0, 65535).astype(np.uint16)
    tifffile.imwrite(folder.parent / "dark.tif", dark)
    pd.DataFrame(rows).to_csv(folder.parent / "manifest.csv", index=False)
    return truth.assign(value=truth["value"] - glow["value"])


def main(outdir=None):
    out = Path(outdir or tempfile.mkdtemp(prefix="veil-photos-"))
    photos = out / "photos"
    photos.mkdir(parents=True, exist_ok=True)
    brdf, medium = veil.BRDF1, veil.BTDF2
    truth = make_session(photos, brdf, medium)
    print(f"{len(truth)} photos of BRDF1 through BTDF2 written to {photos}")

    table = ingest(photos, out / "manifest.csv", roi=",".join(map(str, OBJECT_ROI)),
                   black_roi=",".join(map(str, BLACK_ROI)), dark=out / "dark.tif", channel="gray")
    print(f"ingested {len(table)} photos; saturated pixels: {int(table['saturated'].sum())}")
    # one table of object values, one of black-cloth values, in camera units -> reflectance
    obj = table[["psi", "rho"]].assign(value=table["value"] / GAIN, sigma=table["sigma"] / GAIN)
    blk = table[["psi", "rho"]].assign(value=table["black"] / GAIN,
                                       sigma=table["black_sigma"] / GAIN)
    data = subtract_black(obj, blk)
    resid = (data["value"].to_numpy() - truth["value"].to_numpy()) / data["sigma"].to_numpy()
    print(f"after black subtraction: (value - truth) / sigma has mean {resid.mean():+.2f}, "
          f"std {resid.std():.2f}")

    fit = veil.fit_target(data, medium)
    print()
    print(f"{'param':6s} {'true':>12s} {'estimate':>12s} {'stderr':>10s} {'|diff|/stderr':>14s}")
    for name in brdf.param_names():
        t, e, s = getattr(brdf, name), fit.params[name], fit.stderr[name]
        print(f"{name:6s} {t:12.5g} {e:12.5g} {s:10.3g} {abs(e - t) / s:14.2f}")
    print(f"\nconverged: {fit.converged}; reduced chi-square {fit.chi2_reduced:.2f}; "
          f"outputs in {out}")
    return 0 if fit.converged else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else None))
