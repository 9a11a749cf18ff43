"""The non-parametric family's step 2 through a medium, as veil fits it and as it did before
(docs/nonparametric.md "The fit"), side by side in one process.

    .venv/bin/python benchmarks/bench_nonparametric.py [--rounds 2] [--doc docs/nonparametric.md]

The paper's target (Torrance-Sparrow BRDF1) simulated through its medium BTDF2 at the 111
protocol configurations (1 % noise), fitted by the `nonparametric` family with the medium
given, warm (every program loaded first). Rows:

- the full fit at the default rule: the columns made at "fast" and only those in use again
  at "default" (veil's), against every column made at "default" (before);
- the quick fit of auto's screen: its rule error from the family evaluated one lobe width
  at a time (veil's), against one column per active coefficient (before).

Each pair alternates over the rounds; the table gives the median seconds, their ratio, and
how far the two results are apart (the fitted values in standard errors of the data, the
rule errors relative to their largest value).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import doc_tables  # noqa: E402


def every_column(problem, accuracy, d, dr, progress=None):
    """The design before the two rules: every column at ``accuracy``."""
    from veil.fitting import linear_fit as lf

    x, held = lf.design(problem, accuracy, progress)
    w = problem.w
    return x, held, lf.choose(x * w[:, None], (problem.y - held) * w, d, dr), {accuracy: x.shape[1]}


def per_column_rule_error(problem, sol, check, x):
    """The quick fit's rule error before: one engine call per active coefficient."""
    from veil.fitting import linear_fit as lf

    cols, held = lf.design(problem, check, only=sol.c > 0)
    return {"accuracy": check, "values": (cols @ sol.c + held - sol.values).tolist()}


def timed(fit, swap: dict):
    """(seconds, result) of ``fit()`` with ``veil.fitting.linear_fit``'s functions in
    ``swap`` replaced for the call."""
    from veil.fitting import linear_fit as lf

    kept = {name: getattr(lf, name) for name in swap}
    for name, fn in swap.items():
        setattr(lf, name, fn)
    try:
        started = time.perf_counter()
        result = fit()
        return time.perf_counter() - started, result
    finally:
        for name, fn in kept.items():
            setattr(lf, name, fn)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--doc", help="write the table into this page's table:nonparametric-cost")
    args = ap.parse_args(argv)
    import bench_fit

    import veil
    from veil.fitting import fit_target
    from veil.models import PRESETS

    medium = PRESETS["BTDF2"]
    table = veil.simulate(veil.preset(bench_fit.TARGET), medium, noise=0.01, seed=3)

    def full():
        return fit_target(table, medium, brdf_model="nonparametric", propagation="off")

    def quick():
        return fit_target(table, medium, brdf_model="nonparametric", screen=True)

    cases = [
        ("full fit at the default rule", full, {"_columns_at": every_column}),
        ("quick fit with its rule error", quick, {"rule_error": per_column_rule_error}),
    ]
    rows = []
    for label, fit, before in cases:
        timed(fit, {})  # the programs of both, loaded
        timed(fit, before)
        seconds: dict = {"now": [], "before": []}
        results: dict = {}
        for _ in range(args.rounds):
            for which, swap in (("now", {}), ("before", before)):
                s, results[which] = timed(fit, swap)
                seconds[which].append(s)
        now, old = results["now"], results["before"]
        if "rule_error" in before:
            a, b = (np.array(r.stats["rule_error"]["values"]) for r in (now, old))
            apart = f"rule errors {np.abs(a - b).max() / np.abs(b).max():.1e} of their largest"
        else:
            diff = np.abs(np.array(now.residuals) - np.array(old.residuals))
            apart = f"values {diff.max():.1e} standard errors"
        t_now, t_old = statistics.median(seconds["now"]), statistics.median(seconds["before"])
        made = now.stats["columns_at_rule"]
        rows.append([label, f"{t_old:.2f}", f"{t_now:.2f}", f"{t_old / t_now:.2f}",
                     ", ".join(f"{k} {v}" for k, v in made.items()), apart])
        print(label, rows[-1][1:], flush=True)
    text = doc_tables.markdown(
        ["step 2 of the paper's target, warm", "before s", "now s", "ratio",
         "columns made (now)", "the two results apart"], rows, right={1, 2, 3})
    print(text)
    if args.doc:
        doc_tables.write(args.doc, "nonparametric-cost", text)
        print(f"wrote table nonparametric-cost into {args.doc}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
