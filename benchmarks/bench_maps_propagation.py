"""Cost of the medium's uncertainty in the maps (docs/maps-medium-error.md "Cost").

    .venv/bin/python benchmarks/bench_maps_propagation.py [--roi 0,0,32,32] [--repeat 2] \
        [--doc docs/maps-medium-error.md]

The path-traced photo stack of validation/data/rgb_stack (a region of it, distant geometry
or with ``--near-field`` the stack's camera, no blur correction) mapped with
`veil.fit_maps` through the step-1 medium fitted over r, g, b
(validation/results/rgb_medium.json): over the three channels at once and in channel g
alone (that channel's medium), each with ``propagation`` "off" and "linear", in alternating
rounds after one of each that compiles; the median of ``--repeat`` runs per row. Printed per
map: the medium's parameters propagated, the seconds of the tables, of the tables at the
moved media, of the tiles (solve and terms), the whole run, and the ratio of the whole run
to the map without it (table maps-propagation-cost).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
STACK = ROOT / "validation" / "data" / "rgb_stack"
MEDIUM = ROOT / "validation" / "results" / "rgb_medium.json"


def run(medium, channel: str, propagation: str, roi: str, out: Path, near: bool) -> dict:
    """One map: its stages' seconds and the whole run's (``near``: per-pixel angles, the
    stack's camera)."""
    import veil

    truth = json.loads((STACK / "truth.json").read_text())
    camera = (truth["camera_distance_cm"], truth["pixel_pitch_cm"]) if near else None
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    result = veil.fit_maps(
        STACK / "photos",
        STACK / "manifest.csv",
        medium,
        out,
        brdf_model="rough-plastic",
        fixed={"eta": truth["eta"], "ks": truth["ks"]},
        grid=["alpha=0.05:0.4:12"],
        black_photos=STACK / "black",
        channel=channel,
        roi=roi,
        noise=(0.078, 0.0),
        accuracy="fast",
        propagation=propagation,
        geometry=camera,
        near_field=near,
    )
    seconds = dict(result.seconds, total=time.perf_counter() - t0)
    seconds["parameters"] = len(result.summary.get("propagation", {}).get("parameters", ()))
    return seconds


def main(argv=None) -> int:
    from doc_tables import add_options, markdown, printed_tables

    from veil.fitting.result import FitResult

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roi", default="0,0,32,32", help="the region mapped (default %(default)s)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument(
        "--near-field",
        action="store_true",
        help="the maps with per-pixel angles (the stack's camera), whose tables cost more "
        "(their table maps-propagation-cost-near)",
    )
    add_options(ap, "maps-propagation-cost")
    args = ap.parse_args(argv)
    if args.near_field and args.doc_table == "maps-propagation-cost":  # the default's own
        args.doc_table = "maps-propagation-cost-near"
    rgb = FitResult.from_json(MEDIUM)
    where = ", near field" if args.near_field else ""
    maps = [(f"r, g, b{where}", "rgb", rgb), (f"g alone{where}", "g", rgb.of_channel("g"))]
    times: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.repeat + 1):  # round 0 compiles
            for label, channel, medium in maps:
                for how in ("off", "linear"):
                    out = Path(tmp) / "maps.zarr"
                    one = run(medium, channel, how, args.roi, out, args.near_field)
                    if k:
                        times.setdefault((label, how), []).append(one)
                    print(f"round {k}: {label}, {how}: {one['total']:.1f} s", file=sys.stderr)
    rows = []
    for label, _, _ in maps:
        off = statistics.median(t["total"] for t in times[(label, "off")])
        for how in ("off", "linear"):
            runs = times[(label, how)]

            def med(key, runs=runs):
                return statistics.median(t.get(key, 0.0) for t in runs)

            rows.append(
                [
                    label,
                    how,
                    str(int(med("parameters"))),
                    f"{med('tables'):.1f}",
                    f"{med('propagation'):.1f}" if how != "off" else "-",
                    f"{med('solve'):.2f}",
                    f"{med('total'):.1f}",
                    f"{med('total') / off:.2f}",
                ]
            )
    head = [
        "map",
        "propagation",
        "medium parameters",
        "tables (s)",
        "tables at the moved media (s)",
        "tiles (s; with the medium's part)",
        "whole run (s)",
        "ratio to off",
    ]
    with printed_tables(args):
        print(
            f"The stack's region {args.roi} ({os.cpu_count()} cores), median of "
            f"{args.repeat} runs after one that compiles:\n"
        )
        print(markdown(head, rows, set(range(2, len(head)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
