"""What `--models auto` costs against one pinned pair, warm, side by side (issue 29).

    .venv/bin/python benchmarks/bench_auto.py [--rounds 2] [--cases paper,m05]
        [--doc docs/choosing-models.md]

Each case runs `veil fit pipeline ... --no-figures` in fresh processes, as a user would, with
the program store filled by a first run of each command (not timed): the pinned pair, then
auto, alternating for ``--rounds`` rounds, each with the target's clear session (step 2 is
then ranked on it) and without it (step 2 ranked through the medium). Cases:

- ``paper``: the paper's simulated sessions (BRDF2 reference, BRDF1 target, BTDF2 medium, as
  benchmarks/bench_fit.py, plus the target in clear water); pinned: the paper's pair.
- ``m05``: the path-traced session m05 (validation/data; rough plastics through a
  Henyey-Greenstein medium of optical depth 0.5), the clear-water sessions without their
  sigma column as validation/auto_table.py reads them; pinned: rough-plastic +
  forward-series with the session's path length and plate width.

The table gives the median wall and CPU seconds (this process's children: all threads) of
each command, auto's ratio to the pinned pair, the seconds each spent reading its engine
programs from the store (summed over threads; VEIL_COMPILE_LOG's "load" lines) and how many,
and what auto chose per step.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import doc_tables  # noqa: E402

DATA = ROOT / "validation" / "data"


def paper_sessions(folder: Path) -> dict:
    """The paper's simulated sessions of bench_fit.py, and the target in clear water."""
    import bench_fit
    import veil

    bench_fit.simulate_sessions(str(folder))
    veil.save_measurements(
        veil.simulate(veil.preset(bench_fit.TARGET), None, seed=3), folder / "target_clear.csv"
    )
    names = ("reference_clear", "reference_medium", "target_medium", "black", "target_clear")
    return {"files": {n: folder / f"{n}.csv" for n in names}, "pinned": "paper", "options": []}


def m05_sessions(folder: Path) -> dict:
    """Session m05 of validation/data, clear-water tables without their sigma column."""
    import pandas as pd

    truth = json.loads((DATA / "truth.json").read_text())["sessions"]["m05_target"]
    files = {}
    for key, stem, unweighted in (
        ("reference_clear", "water_ref", True),
        ("reference_medium", "m05_ref", False),
        ("target_medium", "m05_target", False),
        ("black", "m05_black", False),
        ("target_clear", "water_target", True),
    ):
        table = pd.read_csv(DATA / f"{stem}.csv")
        if unweighted:
            table = table.drop(columns=["sigma"])
        files[key] = folder / f"{stem}.csv"
        table.to_csv(files[key], index=False)
    geometry = ["--path-length", str(truth["path_length_cm"]), "--plate-width",
                str(truth["plate_width_cm"])]
    return {"files": files, "pinned": "rough-plastic+forward-series", "options": geometry}


CASES = {"paper": paper_sessions, "m05": m05_sessions}


def command(case: dict, models: str, clear: bool, out: Path) -> list[str]:
    f = case["files"]
    cmd = [sys.executable, "-m", "veil.cli", "fit", "pipeline",
           "--reference-clear", str(f["reference_clear"]),
           "--reference-medium", str(f["reference_medium"]),
           "--target-medium", str(f["target_medium"]), "--black", str(f["black"]),
           "--models", models, "--no-figures", "-o", str(out), *case["options"]]
    if clear:
        cmd += ["--target-clear", str(f["target_clear"])]
    return cmd


def timed(cmd: list[str], env: dict, log: Path) -> tuple[float, float, int, float, int]:
    """(wall s, CPU s of the child, exit status, seconds and number of the engine programs
    it read from the store) of one run; ``log`` the VEIL_COMPILE_LOG it writes."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env={**env, "VEIL_COMPILE_LOG": str(log)},
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode not in (0, 1) or "Traceback" in done.stderr:
        sys.stderr.write(done.stderr[-3000:])
        raise SystemExit(f"bench_auto: {' '.join(cmd)} exited {done.returncode}")
    logged = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    loads = [e["seconds"] for e in logged if e.get("event") == "load"]
    return wall, cpu, done.returncode, sum(loads), len(loads)


def chosen(out: Path) -> str:
    """What auto chose per step, from ranking.json."""
    ranking = json.loads((out / "ranking.json").read_text())
    return "; ".join(f"{step}: {r['chosen']}" for step, r in ranking.items())


def run_case(name: str, rounds: int, env: dict, work: Path) -> list[list[str]]:
    folder = work / name
    folder.mkdir()
    case = CASES[name](folder)
    rows = []
    for clear in (True, False):
        times: dict = {"pinned": [], "auto": []}
        picks = ""
        for models in (case["pinned"], "auto"):  # fill the program store, untimed
            timed(command(case, models, clear, work / "warm"), env, work / "warm.log")
        for r in range(rounds):
            for kind, models in (("pinned", case["pinned"]), ("auto", "auto")):
                out = work / f"{name}-{kind}-{clear}-{r}"
                wall, cpu, status, load, n = timed(command(case, models, clear, out), env,
                                                   work / f"{out.name}.log")
                times[kind].append((wall, cpu, status, load, n))
                if kind == "auto":
                    picks = chosen(out)
                print(f"  {name} {'with' if clear else 'without'} target clear, {kind}: "
                      f"{wall:.1f} s wall, {cpu:.1f} s CPU, exit {status}, {n} programs loaded "
                      f"in {load:.1f} s", file=sys.stderr)
        med = {k: (*(statistics.median(t[i] for t in v) for i in (0, 1, 3)),
                   statistics.median_low(t[4] for t in v)) for k, v in times.items()}
        status = ",".join(str(s) for s in sorted({t[2] for v in times.values() for t in v}))
        rows.append([
            name, "yes" if clear else "no", case["pinned"],
            f"{med['pinned'][0]:.1f}", f"{med['pinned'][1]:.1f}",
            f"{med['auto'][0]:.1f}", f"{med['auto'][1]:.1f}",
            f"{med['auto'][0] / med['pinned'][0]:.2f}", f"{med['auto'][1] / med['pinned'][1]:.2f}",
            f"{med['pinned'][2]:.1f} ({med['pinned'][3]:.0f})",
            f"{med['auto'][2]:.1f} ({med['auto'][3]:.0f})", status, picks,
        ])
    return rows


HEADERS = ["case", "target clear", "pinned pair", "pinned wall s", "pinned CPU s",
           "auto wall s", "auto CPU s", "wall ratio", "CPU ratio", "pinned loads s (programs)",
           "auto loads s (programs)", "exit", "auto chose"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cases", default="paper,m05")
    doc_tables.add_options(ap, "auto-cost")
    args = ap.parse_args(argv)
    names = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in names if c not in CASES]
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; expected some of {', '.join(CASES)}")
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    env.setdefault("VEIL_CACHE_DIR", str(ROOT / ".veil-cache"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            rows += run_case(name, args.rounds, env, Path(tmp))
    with doc_tables.printed_tables(args):
        print(doc_tables.markdown(HEADERS, rows, set(range(3, 11))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
