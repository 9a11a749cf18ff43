"""Benchmark ``veil.viz.render``: time to render spheres and the interpolation error.

Two measurements:

1. cold: ``veil render --brdf BRDF1 --medium BTDF3 --size 256`` in a fresh subprocess, wall
   time including Python start-up, imports and the engine's compilation (the project's
   budget: 20 s);
2. warm: in one process, after a first render has compiled the engine, each size and
   object/medium pair rendered with ``check`` pixels re-evaluated directly by the engine.
   The table gives the seconds (table + image + check), the number of table nodes (engine
   evaluations) and the interpolation error: max relative error at checked pixels with both
   polar angles <= 80 deg, over all checked pixels (terminator and rim included), and the
   largest error in units of the image's peak.

    .venv/bin/python benchmarks/bench_render.py [--sizes 128,256,512] [--check 256]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PAIRS = (("BRDF1", "BTDF1"), ("BRDF1", "BTDF2"), ("BRDF1", "BTDF3"), ("BRDF2", "BTDF3"))


def cold(size: int) -> float:
    veil = Path(sys.executable).with_name("veil")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([str(veil), "render", "--brdf", "BRDF1", "--medium", "BTDF3", "--size",
                        str(size), "-o", f"{tmp}/s.png", "--quiet"], check=True,
                       stdout=subprocess.DEVNULL)
        return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="128,256,512")
    parser.add_argument("--check", type=int, default=256)
    parser.add_argument("--accuracy", default="fast")
    from doc_tables import add_options, printed_tables
    add_options(parser, "render")
    args = parser.parse_args()
    doc = printed_tables(args).start()
    sizes = [int(s) for s in args.sizes.split(",")]

    print(f"cold: veil render --brdf BRDF1 --medium BTDF3 --size 256 (fresh process): "
          f"{cold(256):.1f} s", flush=True)

    from veil.viz.render import render

    t0 = time.perf_counter()
    render("BRDF1", "BTDF3", 45.0, 0.0, 16, accuracy=args.accuracy, check=0)
    print(f"warm-up (imports done, engine compiled in this process): "
          f"{time.perf_counter() - t0:.1f} s\n")
    print(f"accuracy {args.accuracy!r}, light at 45 deg, {args.check} checked pixels per image\n")
    print("| size | pair | seconds | table nodes | max rel. error (angles <= 80 deg) "
          "| max rel. error (all) | max error / peak |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for size in sizes:
        for b, m in PAIRS:
            r = render(b, m, 45.0, 0.0, size, accuracy=args.accuracy, check=args.check)
            print(f"| {size} | {b} x {m} | {r.seconds:.1f} | {r.table_nodes} | "
                  f"{100 * r.max_rel_error:.3f} % | {100 * r.max_rel_error_all:.2f} % | "
                  f"{100 * r.max_peak_error:.4f} % |", flush=True)
    doc.finish()


if __name__ == "__main__":
    main()
