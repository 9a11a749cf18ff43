"""Benchmark ``veil.data.ingest``: time per photo and peak memory on 24-megapixel photos.

Writes N synthetic 6000 x 4000 photos per format into a temporary directory (16-bit RGB TIFF,
uncompressed and deflate; 16-bit RGB PNG; a 16-bit DNG colour-filter mosaic read by LibRaw),
ingests each series in a fresh subprocess and prints a table: the one-off setup (manifest check,
which also starts JAX), seconds per photo (median and worst), the subprocess's peak resident
memory during ingest above its resident memory after setup (Linux: the kernel's peak mark,
reset after setup; it includes LibRaw's and the codecs' own buffers), and the tracemalloc
peak (Python/numpy allocations) of a second run. Files sit in the page cache
(just written): the times are decoding and statistics, not disk reads.

    .venv/bin/python benchmarks/bench_ingest.py [--photos 20] [--width 6000] [--height 4000]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FORMATS = ("tiff", "tiff-deflate", "png", "dng")


def base_image(width, height, seed=0):
    """A smooth gradient plus Gaussian noise, 16-bit RGB (noise keeps PNG/deflate honest)."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 1.0, width, dtype=np.float32)
    y = np.linspace(0.0, 1.0, height, dtype=np.float32)[:, None]
    image = np.empty((height, width, 3), np.uint16)
    for c, scale in enumerate((8000.0, 20000.0, 12000.0)):
        plane = 2000.0 + scale * (0.5 * x + 0.5 * y)
        plane += rng.standard_normal((height, width), dtype=np.float32) * 200.0
        image[..., c] = np.clip(np.rint(plane), 0, 60000)
    return image


def write_series(fmt, folder, count, image):
    import imagecodecs
    import tifffile

    files = []
    first = None
    for k in range(count):
        name = f"photo{k:03d}." + {"tiff": "tif", "tiff-deflate": "tif", "png": "png",
                                   "dng": "dng"}[fmt]
        path = folder / name
        if first is not None:
            shutil.copyfile(first, path)  # same content: decoding cost is the same
        elif fmt == "tiff":
            tifffile.imwrite(path, image, photometric="rgb")
        elif fmt == "tiff-deflate":
            tifffile.imwrite(path, image, photometric="rgb", compression="zlib",
                             compressionargs={"level": 1}, rowsperstrip=64)
        elif fmt == "png":
            path.write_bytes(imagecodecs.png_encode(image, level=1))
        else:
            write_dng(path, image)
        first = first or path
        files.append(name)
    return files


def write_dng(path, image):
    """The green plane (as 14-bit values) under an RGGB mosaic, written as a real DNG."""
    import tifffile

    mosaic = (image[..., 1] // 4).astype(np.uint16)
    tags = [
        (271, "s", 0, "Veil", True), (272, "s", 0, "Bench", True),
        (50706, "B", 4, (1, 4, 0, 0), True), (50707, "B", 4, (1, 1, 0, 0), True),
        (50708, "s", 0, "Veil Bench", True),
        (33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
        (50710, "B", 3, (0, 1, 2), True), (50711, "H", 1, 1, True),
        (50714, "H", 1, 512, True), (50717, "H", 1, 16383, True),
        (50721, "2i", 9, (10000, 10000, 0, 10000, 0, 10000, 10000, 0, 10000, 0, 10000, 10000,
                          0, 10000, 0, 10000, 10000, 10000), True),
        (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True),
    ]
    tifffile.imwrite(path, mosaic, photometric=32803, extratags=tags, subfiletype=0,
                     metadata=None)


def worker(folder, manifest, roi, black_roi, trace):
    """Run in a subprocess: ingest the series, print JSON with times and memory."""
    import resource
    import tracemalloc
    import warnings

    import imagecodecs  # noqa: F401  (imports before the baseline: only ingest is measured)
    import rawpy  # noqa: F401
    import tifffile  # noqa: F401

    from veil.data.ingest import ingest, read_manifest

    t0 = time.perf_counter()
    read_manifest(manifest, folder)  # once per run: checks the manifest, starts JAX (angles)
    setup = time.perf_counter() - t0
    reset = _reset_peak_rss()
    baseline = _status_kib("VmRSS") if reset else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    stamps = [time.perf_counter()]
    if trace:
        tracemalloc.start()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        table = ingest(folder, manifest, roi, black_roi,
                       progress=lambda done, total, name: stamps.append(time.perf_counter()))
    peak_traced = tracemalloc.get_traced_memory()[1] if trace else None
    peak = _status_kib("VmHWM") if reset else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    times = np.diff(stamps)
    print(json.dumps({"n": len(table), "setup": setup, "median": float(np.median(times)),
                      "worst": float(times.max()), "total": float(stamps[-1] - stamps[0]),
                      "rss_mib": (peak - baseline) / 1024, "rss_total_mib": peak / 1024,
                      "traced_mib": None if peak_traced is None else peak_traced / 2**20}))


def _reset_peak_rss():
    """Reset the kernel's peak-RSS mark (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return _status_kib("VmHWM") is not None
    except OSError:
        return False


def _status_kib(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return None


def run_worker(folder, manifest, roi, black_roi, trace):
    cmd = [sys.executable, __file__, "--worker", str(folder), str(manifest), roi, black_roi]
    if trace:
        cmd.append("--trace")
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, default=20)
    parser.add_argument("--width", type=int, default=6000)
    parser.add_argument("--height", type=int, default=4000)
    parser.add_argument("--formats", default=",".join(FORMATS))
    parser.add_argument("--worker", nargs=4, metavar=("DIR", "MANIFEST", "ROI", "BLACK_ROI"))
    parser.add_argument("--trace", action="store_true")
    from doc_tables import add_options, printed_tables
    add_options(parser, "ingest")
    args = parser.parse_args()
    if args.worker:
        worker(*args.worker, trace=args.trace)
        return

    import pandas as pd

    w, h = args.width, args.height
    roi = f"{w // 2 - 100},{h // 2 - 100},200,200"
    black_roi = f"{w // 10},{h // 10},200,200"
    doc = printed_tables(args).start()
    t0 = time.perf_counter()
    image = base_image(w, h)
    print(f"ingest benchmark: {args.photos} photos of {w} x {h} ({w * h / 1e6:.0f} MP), 16-bit, "
          f"ROI {roi} + black ROI {black_roi}; base image made in {time.perf_counter() - t0:.1f} s")
    rows = []
    for fmt in args.formats.split(","):
        with tempfile.TemporaryDirectory(prefix="veil-bench-") as tmp:
            folder = Path(tmp) / "photos"
            folder.mkdir()
            t0 = time.perf_counter()
            files = write_series(fmt, folder, args.photos, image)
            size = (folder / files[0]).stat().st_size / 2**20
            manifest = Path(tmp) / "manifest.csv"
            pd.DataFrame({"file": files, "psi": 60.0,
                          "rho": np.linspace(-20, 20, len(files))}).to_csv(manifest, index=False)
            made = time.perf_counter() - t0
            timed = run_worker(folder, manifest, roi, black_roi, trace=False)
            traced = run_worker(folder, manifest, roi, black_roi, trace=True)
            rows.append((fmt, size, timed, traced, made))
    print()
    print("| format | file MiB | photos | setup s | s/photo (median) | s/photo (worst) | total s "
          "| peak RSS during ingest MiB | tracemalloc peak MiB |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for fmt, size, timed, traced, made in rows:
        print(f"| {fmt} | {size:.0f} | {timed['n']} | {timed['setup']:.2f} | "
              f"{timed['median']:.3f} | "
              f"{timed['worst']:.3f} | {timed['total']:.1f} | {timed['rss_mib']:.0f} | "
              f"{traced['traced_mib']:.0f} |")
    doc.finish()


if __name__ == "__main__":
    main()
