"""Benchmark: a three-channel pipeline against a one-channel one (issue 30's cost target,
docs/channels.md; docs/model.md sec. 7).

The paper's protocol (111 configurations a session) simulated per channel: the reference
BRDF2 and the target BRDF1 with their diffuse albedo per channel, the medium BTDF2 with T_d
and T_t scaled per channel (water that dims red). The one-channel sessions are the g
channel's alone. Both pipelines run in one process, each once to compile (not timed), then
alternately ``--rounds`` times; the table prints the median wall and CPU seconds per step and
the ratio three channels / one channel, measured side by side.

    .venv/bin/python benchmarks/bench_channels.py [--rounds 3] [--accuracy fast] \\
        [--physical] [--doc docs/channels.md --doc-table channels-paper]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time

CHANNELS = {"r": 0.6, "g": 1.0, "b": 1.5}
REF_PD = {"r": 800.0, "g": 1000.0, "b": 1200.0}
TGT_PD = {"r": 100.0, "g": 200.0, "b": 400.0}
STEPS = ("step 0, reference", "step 1, medium", "step 2, target")


#: --physical: rough plastics (rho per channel) through forward-series water whose optical
#: depth and albedo differ per channel (its per-channel parameters are not scales)
PHYSICAL = {"brdf_model": "rough-plastic", "medium_model": "forward-series",
            "medium_options": {"path_length": 15.0, "plate_width": 5.0}}
TAU = {"r": 0.45, "g": 0.3, "b": 0.15}
OMEGA = {"r": 0.95, "g": 0.97, "b": 0.99}


def _models(physical: bool):
    """(reference by channel, medium by channel, target by channel) as functions of c."""
    import veil
    from veil.models import model_class

    if physical:
        plastic, series = model_class("rough-plastic"), model_class("forward-series")
        return (lambda c: plastic(rho=REF_PD[c] / 1000.0, alpha=0.1, eta=1.5, ks=1.0),
                lambda c: series(tau=TAU[c], omega=OMEGA[c], g=0.9, **PHYSICAL[
                    "medium_options"]),
                lambda c: plastic(rho=TGT_PD[c] / 500.0, alpha=0.2, eta=1.5, ks=1.0))
    m = veil.BTDF2
    return (lambda c: veil.BRDF2.replace(Pd=REF_PD[c]),
            lambda c: m.replace(Td=m.Td * CHANNELS[c], Tt=m.Tt * CHANNELS[c]),
            lambda c: veil.BRDF1.replace(Pd=TGT_PD[c]))


def sessions(channels: list[str], accuracy: str, physical: bool) -> dict:
    """{name: DataFrame} of the four sessions over ``channels``."""
    from veil.data.simulate import simulate_channels

    reference, medium, target = _models(physical)
    ref = {c: reference(c) for c in channels}
    tgt = {c: target(c) for c in channels}
    clear = simulate_channels({c: (ref[c], None) for c in channels}, seed=1, accuracy=accuracy)
    ref_m, black = simulate_channels({c: (ref[c], medium(c)) for c in channels}, seed=2,
                                     black=True, accuracy=accuracy)
    tgt_m = simulate_channels({c: (tgt[c], medium(c)) for c in channels}, seed=3,
                              accuracy=accuracy)
    return {"reference_clear": clear, "reference_medium": ref_m, "black": black,
            "target_medium": tgt_m}


def run_once(data: dict, accuracy: str, physical: bool) -> dict:
    """{step: (wall s, CPU s, engine calls)} of one pipeline without figures."""
    import veil

    marks: list = []

    def progress(stage, done, total):
        step = stage.split(":")[0]
        if not marks or marks[-1][0] != step:
            marks.append((step, time.perf_counter(), time.process_time()))

    out = tempfile.mkdtemp(prefix="bench-channels-")
    marks.append(("start", time.perf_counter(), time.process_time()))
    result = veil.run_pipeline(data["reference_clear"], data["reference_medium"],
                               data["target_medium"], black=data["black"],
                               outdir=os.path.join(out, "run"), accuracy=accuracy,
                               figures=False, progress=progress,
                               **(PHYSICAL if physical else {}))
    marks.append(("end", time.perf_counter(), time.process_time()))
    shutil.rmtree(out)
    fits = dict(zip(STEPS, (result.reference, result.medium, result.target)))
    times: dict = {}
    for (name, w, c), (_, w2, c2) in zip(marks, marks[1:]):
        if name in fits:
            times[name] = (w2 - w, c2 - c, fits[name].stats.get("engine_calls"))
    times["whole pipeline"] = (marks[-1][1] - marks[0][1], marks[-1][2] - marks[0][2], None)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--accuracy", default="default", choices=("fast", "default", "high"))
    parser.add_argument("--physical", action="store_true",
                        help="rough plastics through forward-series water (default: the "
                        "paper's models)")
    from doc_tables import add_options, printed_tables

    add_options(parser, "channels-paper")
    args = parser.parse_args()
    doc = printed_tables(args).start()
    data = {"one channel (g)": sessions(["g"], args.accuracy, args.physical),
            "three channels (r, g, b)": sessions(list(CHANNELS), args.accuracy,
                                                 args.physical)}
    for label, d in data.items():
        print(f"compiling and a first run: {label} ...", flush=True)
        run_once(d, args.accuracy, args.physical)
    runs: dict = {label: [] for label in data}
    for k in range(args.rounds):
        for label, d in data.items():
            runs[label].append(run_once(d, args.accuracy, args.physical))
        print(f"round {k + 1}/{args.rounds} done", flush=True)
    load = os.getloadavg()[0]
    models = "rough-plastic x forward-series" if args.physical else "the paper's models"
    print(f"\nwarm pipelines of {models}, median of {args.rounds} alternating rounds, "
          f"accuracy {args.accuracy}, load {load:.1f}, {os.cpu_count()} cores\n")
    one, three = data
    print(f"| step | {one} wall / CPU s | {three} wall / CPU s | ratio wall / CPU | "
          "engine calls (one; three) |")
    print("|---|---|---|---|---|")
    for step in (*STEPS, "whole pipeline"):
        cells = []
        for label in data:
            wall = statistics.median(r[step][0] for r in runs[label])
            cpu = statistics.median(r[step][1] for r in runs[label])
            cells.append((wall, cpu, runs[label][-1][step][2]))
        (w1, c1, e1), (w3, c3, e3) = cells
        print(f"| {step} | {w1:.2f} / {c1:.2f} | {w3:.2f} / {c3:.2f} | "
              f"{w3 / w1:.2f} / {c3 / c1:.2f} | {e1 or ''}; {e3 or ''} |")
    doc.finish()


if __name__ == "__main__":
    main()
