"""Where the test suite's time goes: veil's engine compilations against everything else,
per test and per program (issue 28: `make test` within 10 minutes on 2 cores).

    .venv/bin/python benchmarks/bench_suite.py [--top 15] [--doc docs/performance-suite.md]
        [--durations CSV] [--programs CSV] [--keep DIR] [-- PYTEST ARGS]

Runs the suite as `make test` does (``pytest -n 2 --dist worksteal``, or the pytest
arguments after ``--``) with an empty program store in a temporary folder, as a clean clone
has, and with benchmarks/suite_census_plugin.py, which gives each test a compile log of its
own. It prints the wall time, the worker-seconds (the tests' durations summed), the seconds
veil spent compiling programs and reading them from the store, the seconds JAX spent
compiling anything (tracing, lowering and XLA's compilation of every jit, the engine's
programs among them: "all JAX compiling"), the tests that take longest beside the part of
it that was compilation, and the programs that took longest to compile
with the number of tests that used them. A test that waits for a program another worker is
compiling counts that wait as its own execution.
"""

from __future__ import annotations

import argparse
import collections
import csv
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import doc_tables  # noqa: E402
from suite_census_plugin import log_name  # noqa: E402

MAKE_TEST = ["-n", "2", "--dist", "worksteal", "-q"]


def run_suite(pytest_args: list[str], work: Path) -> tuple[float, int, str]:
    """(wall seconds, exit status, output) of the suite with per-test logs in ``work``."""
    logs = work / "logs"
    logs.mkdir()
    env = dict(os.environ, CENSUS_DIR=str(logs), VEIL_CACHE_DIR=str(work / "cache"),
               PYTHONPATH=os.pathsep.join(filter(None, [str(HERE), os.environ.get("PYTHONPATH")])))
    env.pop("VEIL_COMPILE_LOG", None)
    cmd = [sys.executable, "-m", "pytest", "-p", "suite_census_plugin", "--durations=0",
           "--durations-min=0", *pytest_args]
    started = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True,
                          stdin=subprocess.DEVNULL)
    return time.perf_counter() - started, done.returncode, done.stdout + done.stderr


def durations(output: str) -> dict[str, float]:
    """{test id: seconds of setup, call and teardown} from pytest's ``--durations=0``
    (with ``--durations-min=0``, every test's)."""
    out: dict[str, float] = collections.Counter()
    for line in output.splitlines():
        parts = line.split(None, 2)  # (a test's id may hold spaces)
        if len(parts) == 3 and parts[0].endswith("s") and parts[1] in ("setup", "call", "teardown"):
            try:
                out[parts[2]] += float(parts[0][:-1])
            except ValueError:
                continue
    return out


def logs_of(folder: Path) -> dict[str, list[dict]]:
    """{log file name: its entries} of the tests' compile logs."""
    out = {}
    for path in glob.glob(str(folder / "logs" / "*.jsonl")):
        name = os.path.basename(path)
        if name.startswith("_tests_"):
            continue
        entries = []
        for line in Path(path).read_text().splitlines():
            try:
                entries.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        out[name] = entries
    return out


def jax_seconds(folder: Path) -> dict[str, float]:
    """{test id: seconds JAX spent compiling in it (tracing, lowering and XLA, every jit)}
    from the plugin's records of each test."""
    out: dict[str, float] = {}
    for path in glob.glob(str(folder / "logs" / "_tests_*.jsonl")):
        for line in Path(path).read_text().splitlines():
            try:
                entry = json.loads(line)
            except json.JSONDecodeError:
                continue
            spent = entry.get("jax", {})
            out[entry["test"]] = sum(spent.get(k, 0.0) for k in ("trace", "lower", "xla"))
    return out


def census(output: str, logs: dict[str, list[dict]], jax: dict[str, float]) -> dict:
    """The totals, the tests and the programs of one run."""
    spent = durations(output)
    compiled = {name: sum(e["seconds"] for e in es if e["event"] == "compile")
                for name, es in logs.items()}
    programs: dict = collections.defaultdict(lambda: [0.0, 0, set()])
    readers = collections.defaultdict(set)
    for name, entries in logs.items():
        for e in entries:
            if e["event"] == "compile":
                row = programs[e["label"]]
                row[0] += e["seconds"]
                row[1] += 1
                row[2].add(name)
            else:
                readers[e["label"]].add(name)
    for label, row in programs.items():  # a read's label lacks the compile's chunk size
        row[2] |= readers.get(label.rsplit(",", 1)[0], set())
    tests = sorted(((t, s, compiled.get(log_name(t), 0.0), jax.get(t, 0.0))
                    for t, s in spent.items()), key=lambda r: -r[1])
    return {
        "worker_seconds": sum(spent.values()),
        "jax": sum(jax.values()),
        "compile": sum(compiled.values()),
        "compiles": sum(row[1] for row in programs.values()),
        "reads": sum(e["seconds"] for es in logs.values() for e in es if e["event"] == "load"),
        "tests": tests,
        "programs": sorted(programs.items(), key=lambda kv: -kv[1][0]),
    }


def tables(result: dict, wall: float, status: int, top: int) -> str:
    """The three tables in Markdown."""
    c = result
    totals = doc_tables.markdown(
        ["wall s", "exit", "tests", "worker-seconds", "compiling s (programs)", "reading s",
         "the rest s", "all JAX compiling s"],
        [[f"{wall:.0f}", str(status), str(len(c["tests"])), f"{c['worker_seconds']:.0f}",
          f"{c['compile']:.0f} ({c['compiles']})", f"{c['reads']:.0f}",
          f"{c['worker_seconds'] - c['compile'] - c['reads']:.0f}", f"{c['jax']:.0f}"]],
        right=set(range(8)))
    tests = doc_tables.markdown(
        ["test", "seconds", "of which compiling", "all JAX compiling"],
        [[f"`{t}`", f"{s:.1f}", f"{k:.1f}", f"{j:.1f}"] for t, s, k, j in c["tests"][:top]],
        right={1, 2, 3})
    programs = doc_tables.markdown(
        ["program", "compile s", "compiled", "tests using it"],
        [[label, f"{row[0]:.1f}", str(row[1]), str(len(row[2]))]
         for label, row in c["programs"][:top]], right={1, 2, 3})
    return "\n\n".join([totals, f"The {top} longest tests:", tests,
                        f"The {top} programs longest to compile:", programs])


def write_durations(path: Path, result: dict) -> None:
    """Every test's seconds and compile seconds, longest first, as CSV."""
    with path.open("w", newline="") as out:
        rows = csv.writer(out)
        rows.writerow(["test", "seconds", "compiling", "jax_compiling"])
        rows.writerows([name, f"{s:.2f}", f"{k:.2f}", f"{j:.2f}"]
                       for name, s, k, j in result["tests"])
    print(f"wrote {len(result['tests'])} tests' durations to {path}")


def write_programs(path: Path, result: dict) -> None:
    """Every program compiled, longest first, with the tests (their log names) that
    compiled or read it, as CSV: where a test could use a program another one compiles."""
    with path.open("w", newline="") as out:
        rows = csv.writer(out)
        rows.writerow(["program", "compile_seconds", "compiled", "tests"])
        rows.writerows([label, f"{row[0]:.2f}", row[1],
                        " ".join(sorted(n.removesuffix(".jsonl") for n in row[2]))]
                       for label, row in result["programs"])
    print(f"wrote {len(result['programs'])} programs to {path}")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else None
    own = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--doc", help="write the tables into this page's table:suite-census")
    ap.add_argument("--durations", help="write every test's seconds (and compile seconds) "
                    "to this CSV file")
    ap.add_argument("--programs", help="write every compiled program, its compile seconds "
                    "and the tests that used it to this CSV file")
    ap.add_argument("--keep", help="copy the tests' compile logs into this new folder")
    args = ap.parse_args(own)
    with tempfile.TemporaryDirectory(prefix="veil-suite-") as tmp:
        wall, status, output = run_suite(extra or MAKE_TEST, Path(tmp))
        result = census(output, logs_of(Path(tmp)), jax_seconds(Path(tmp)))
        if args.keep:
            shutil.copytree(Path(tmp) / "logs", args.keep)
    text = tables(result, wall, status, args.top)
    print(text)
    if args.durations:
        write_durations(Path(args.durations), result)
    if args.programs:
        write_programs(Path(args.programs), result)
    if status != 0:
        print(output[-3000:], file=sys.stderr)
    if args.doc:
        doc_tables.write(args.doc, "suite-census", text)
        print(f"wrote table suite-census into {args.doc}")
    return 0 if status == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
