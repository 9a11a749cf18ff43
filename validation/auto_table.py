"""What `veil fit pipeline --models auto` picks on the path-traced sessions (issue 29, item 7).

Each case is the two-step pipeline of benchmarks/bench_validity.py on validation/data (the
reference plate ``ref`` in clear water for step 0 and in the medium for step 1, the target in
the medium for step 2, the black cloth subtracted, the target's clear-water session as the
direct fit and the truth; ``--path-length`` and ``--plate-width`` from the session's geometry),
run in process by ``veil.run_pipeline(..., models="auto")``, the same call as

    veil fit pipeline --reference-clear water_ref.csv --reference-medium m05_ref.csv \
        --target-medium m05_target.csv --black m05_black.csv --target-clear water_target.csv \
        --path-length 15 --plate-width 5 --models auto --no-figures -o OUT

(the clear-water files without their all-zero sigma column, as bench_validity.py reads them).
Per case and step (reference, medium, target) it records what auto picks, the runner-up and
the delta-BIC between them, and whether the pick is what generated the data
(validation/data/truth.json: every plate but ``clearcoat`` is Mitsuba's ``roughplastic`` with a
Beckmann or GGX distribution and linear diffuse, i.e. veil's ``rough-plastic`` with that
``distribution``; ``clearcoat``, Mitsuba's ``principled`` BSDF with a clear coat, is in no
family;
every medium is a Henyey-Greenstein medium with an unscattered beam, i.e. the physical
``forward-series``, whose ``orders`` option is an approximation of the series and was not
"generated" by anything, so any of its values counts). Then the final target estimate against
the truth's clear curves: relative RMS over the clear session's configurations, with the
estimate's reported uncertainty there (its curves' standard errors, widened by the close
call's spread when auto reports one) as an RMS relative standard error, and the share of the
configurations where the truth is within two of them.

With ``--clear`` it also ranks the BRDF families on each clear-water plate directly
(``veil fit reference FILE --brdf-model auto``: step 0 on every water session).

Rows go to ``--json`` (default validation/results/auto_table.json) after every case, so a
run can be stopped and resumed (``--resume`` skips the cases already there); ``--doc PAGE``
writes the table of every row in the JSON, with the command, date and load, between the
page's markers ``<!-- table:auto ... -->`` (benchmarks/doc_tables.py).

    PYTHONPATH=src python validation/auto_table.py [--cases m05:target,m05:ggx,...]
        [--clear] [--resume] [--propagation auto|off] [--doc docs/validity-auto.md]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
import bench_validity as bv  # noqa: E402

#: Every path-traced case with the reference ``ref``: the four media with both plates in
#: the registry's families, and the two other geometries of m10.
ALL_CASES = ("m05:target,m05:ggx,m10:target,m10:ggx,m01:target,m01:ggx,m15:target,m15:ggx,"
             "m10_w10:target,m10_r10:target,m05:clearcoat")
#: The clear-water plates ranked alone (--clear).
CLEAR = ("ref", "target", "ggx", "smooth", "clearcoat")
JSON = os.path.join(HERE, "results", "auto_table.json")
STEPS = ("reference", "medium", "target")


def generating(truth: dict, step: str, plate: str | None) -> dict:
    """What generated a step's data: {"family", "options" (those that must match),
    "label" (as the table writes it)}."""
    if step == "medium":
        return {"family": "forward-series", "options": {},
                "label": "forward-series (HG medium with its unscattered beam; any orders)"}
    p = truth["plates"][plate]
    if p["type"] != "roughplastic" or p.get("nonlinear"):
        return {"family": None, "options": {}, "label": f"{p['type']} (no family)"}
    return {"family": "rough-plastic", "options": {"distribution": p["distribution"]},
            "label": f"rough-plastic[distribution={p['distribution']}]"}


def is_generating(row: dict, gen: dict) -> bool:
    if row is None or gen["family"] is None or row["family"] != gen["family"]:
        return False
    opts = row.get("options") or {}
    # an option the label omits has the family's only (or default) value
    from veil.models import model_class

    defaults = {o.name: o.default for o in model_class(row["family"]).OPTIONS}
    return all(opts.get(k, defaults.get(k)) == v for k, v in gen["options"].items())


def step_record(ranking, gen: dict) -> dict:
    """One step's ranking summarized: the pick, the runner-up, delta-BIC, generating?"""
    ranked = [r for r in ranking.rows if r["bic"] is not None and r["converged"]]
    chosen = ranking.row(ranking.chosen) if ranking.chosen else None
    runner = next((r for r in ranked if r["label"] != ranking.chosen), None)
    gen_row = next((r for r in ranking.rows if is_generating(r, gen)), None)
    return {
        "pick": ranking.chosen, "runner_up": runner["label"] if runner else None,
        "delta_bic": (runner["bic"] - chosen["bic"]) if runner and chosen else None,
        "close_call": ranking.close_call, "close": list(ranking.close),
        "generating": gen["label"], "pick_is_generating": is_generating(chosen, gen),
        "generating_delta_bic": (gen_row["bic"] - chosen["bic"])
        if gen_row is not None and gen_row["bic"] is not None and chosen else None,
        "pick_rms_residual": chosen["rms_relative"] if chosen else None,
        "candidates": ranking.to_dict()["candidates"],
    }


def against_truth(names: dict, estimate) -> dict:
    """The estimate's curves against the truth's clear curves, with its reported
    uncertainty (curve standard errors, widened by a close call's spread)."""
    from veil.analysis.uncertainty import curve_stderr
    from veil.data.protocol import protocol

    angles, clear, est, rendered, rms = bv._against_truth(names, estimate.as_model())
    _, se = curve_stderr(estimate, angles)
    spread = ((estimate.stats or {}).get("selection") or {}).get("spread")
    widened = False
    if spread is not None:
        configs = protocol()
        same = (len(configs) == len(clear)
                and np.allclose(configs["psi"].to_numpy(), clear["psi"].to_numpy())
                and np.allclose(configs["rho"].to_numpy(), clear["rho"].to_numpy()))
        if not same:
            raise SystemExit("auto_table: the clear session's configurations are not the "
                             "protocol's; the close call's spread cannot be added")
        w = np.asarray(spread["spread"], dtype=float)
        se = w if se is None else np.hypot(se, w)
        widened = True
    out = {"est_vs_truth": rms, "se_rms_relative": math.nan, "truth_within_2se": math.nan,
           "widened_by_spread": widened,
           "max_relative": float(np.max(np.abs(est / rendered - 1.0)))}
    if se is not None:
        out["se_rms_relative"] = float(np.sqrt(np.mean((se / est) ** 2)))
        out["truth_within_2se"] = float(np.mean(np.abs(est - rendered) <= 2.0 * se))
    return out


def run_case(truth: dict, medium: str, target: str, outdir: str, propagation: str) -> dict:
    from veil import run_pipeline

    names = bv.sessions_of(truth, medium, target)
    sess = truth["sessions"][names["session"]]
    t0 = time.perf_counter()
    res = run_pipeline(
        bv.table(names["reference_clear"], True), bv.table(names["reference_medium"]),
        bv.table(names["target_medium"]), black=bv.table(names["black"]),
        target_clear=bv.table(names["target_clear"], True), outdir=outdir, figures=False,
        models="auto", propagation=propagation,
        medium_options={"path_length": sess["path_length_cm"],
                        "plate_width": sess["plate_width_cm"]},
        progress=lambda what, done, total: print(
            f"    {what}" + (f" {done}/{total}" if total else ""), file=sys.stderr,
            flush=True) if done is None or done == total else None)
    seconds = time.perf_counter() - t0
    plates = {"reference": "ref", "medium": None, "target": target}
    steps = {s: step_record(res.rankings[s], generating(truth, s, plates[s])) for s in STEPS}
    direct_rms = bv._against_truth(names, res.direct)[4] if res.direct is not None else math.nan
    med = res.medium.params
    return {"case": f"{medium}:{target}", "medium": medium, "target": target,
            "tau_true": truth["media"][medium.partition("_")[0]]["tau"],
            "steps": steps, **against_truth(names, res.target),
            "direct_vs_truth": direct_rms,
            "est_vs_direct": (res.comparison or {}).get("rms_fr_relative", math.nan),
            "tau": med.get("tau", math.nan),
            "g": med.get("g", math.nan), "converged": res.converged, "seconds": seconds,
            "propagation": propagation}


def run_clear(truth: dict, plate: str) -> dict:
    """Step 0 alone on one clear-water plate: the BRDF families ranked on it, as the
    pipeline's step 0 ranks them (veil.fitting.selection)."""
    from veil.fitting import fit_reference, prepare, screening, selection
    from veil.fitting.model_error import check_kind

    data = prepare(bv.table(f"water_{plate}", True), None, "reference (clear medium)")
    error = check_kind(None)

    def fit(c):
        return fit_reference(data.table, brdf_model=c.family, options=c.model_options({}),
                             model_error=error)

    t0 = time.perf_counter()
    ranking, _ = screening.select("reference", selection.candidates("brdf"), data, fit,
                                  "reference (clear medium)")
    seconds = time.perf_counter() - t0
    return {"case": f"water:{plate}", "medium": "water", "target": plate,
            "steps": {"reference": step_record(ranking, generating(truth, "reference", plate))},
            "seconds": seconds}


# ---- the table ------------------------------------------------------------------------------
def _pct(x, digits: int = 2) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else \
        f"{100 * x:.{digits}f} %"


def _dbic(x) -> str:
    return "-" if x is None else f"{x:.1f}"


def _short(label: str | None) -> str:
    if label is None:
        return "-"
    return (label.replace("[distribution=", " ").replace("[orders=", " orders ")
            .replace("[variant=", " variant ").replace(",", ", ").replace("]", "")
            .replace("=", " "))


COLUMNS = ["session", "step", "auto's pick", "runner-up", "delta-BIC", "pick = generating?",
           "estimate vs truth", "reported se (RMS)", "truth within 2 se",
           "direct fit vs truth", "s"]


def doc_rows(rows: list[dict]) -> list[list[str]]:
    out = []
    for r in rows:
        water = r["medium"] == "water"
        session = (f"water, {r['target']} plate (clear)" if water else
                   f"{r['medium']} (tau {r['tau_true']:g}), {r['target']}")
        for step, s in r["steps"].items():
            last = step == ("reference" if water else "target")
            gen = "yes" if s["pick_is_generating"] else "none in the registry" if \
                s["generating"].endswith("(no family)") else (
                f"**no** ({_short(s['generating'].split(' (')[0])}: "
                f"dBIC {_dbic(s['generating_delta_bic'])})")
            pick = _short(s["pick"]) + (" (close call)" if s["close_call"] else "")
            est = last and not water
            out.append([session if step == "reference" else "", step, pick,
                        _short(s["runner_up"]), _dbic(s["delta_bic"]), gen,
                        f"**{_pct(r['est_vs_truth'])}**" if est else "",
                        _pct(r["se_rms_relative"]) +
                        (" (widened)" if r.get("widened_by_spread") else "") if est else "",
                        _pct(r["truth_within_2se"], 0) if est else "",
                        _pct(r["direct_vs_truth"]) if est else "",
                        f"{r['seconds']:.0f}" if last else ""])
    return out


def print_table(rows: list[dict]) -> str:
    from doc_tables import markdown

    text = markdown(COLUMNS, doc_rows(rows), {4, 6, 7, 8, 9, 10})
    print(text)
    return text


def summary(rows: list[dict]) -> list[str]:
    """Against the issue's targets, in words (printed under the table)."""
    lines = []
    cases = [r for r in rows if r["medium"] != "water"]
    inside = [(r["case"], s, x) for r in rows for s, x in r["steps"].items()
              if not x["generating"].endswith("(no family)")]
    picks = [(c, s) for c, s, x in inside if not x["pick_is_generating"]]
    n = len(inside)
    lines.append(f"- picks of the generating family and option: {n - len(picks)} of {n} steps"
                 + ("" if not picks else "; not in " + ", ".join(f"{c} {s}" for c, s in picks)))
    outside = [r for r in cases if r["steps"]["target"]["generating"].endswith("(no family)")]
    cases = [r for r in cases if r not in outside]
    if cases:
        ok = [r for r in cases if r["est_vs_truth"] <= 0.02]
        lines.append(f"- target estimate within 2 % RMS of the truth's clear curves: "
                     f"{len(ok)} of {len(cases)} pipelines ("
                     f"{100 * min(r['est_vs_truth'] for r in cases):.2f}-"
                     f"{100 * max(r['est_vs_truth'] for r in cases):.2f} %)")
    for r in outside:
        t = r["steps"]["target"]
        lines.append(
            f"- {r['case']} (a plate outside every family): auto picks {t['pick']}; the "
            f"estimate is {_pct(r['est_vs_truth'])} RMS from the truth and "
            f"{_pct(r.get('est_vs_direct', math.nan))} from the chosen family's direct clear "
            f"fit, which is itself {_pct(r['direct_vs_truth'])} from the truth (its misfit); "
            f"reported uncertainty {_pct(r['se_rms_relative'])} RMS, the truth within two "
            f"standard errors at {_pct(r['truth_within_2se'], 0)} of the configurations")
    return lines


CANDIDATE_COLUMNS = ["session", "step, ranked on", "candidate", "RMS resid.", "dBIC", "weight",
                     "df"]


def candidate_rows(rows: list[dict]) -> list[list[str]]:
    """Every candidate of the steps whose plate is in no family (its family's misfit shown,
    not hidden): RMS residual, delta-BIC, weight and the degrees of freedom counted."""
    out = []
    for r in rows:
        for step, x in r["steps"].items():
            if not x["generating"].endswith("(no family)"):
                continue
            on = "clear data" if r["medium"] == "water" or step == "target" else "medium"
            for j, c in enumerate(x["candidates"]):
                fit = (_pct(c["rms_relative"]) if c["converged"] and c["rms_relative"] is not None
                       else "not converged")
                out.append([r["case"] if j == 0 else "", f"{step}, {on}", _short(c["label"]),
                            fit, _dbic(c["delta_bic"]), f"{c['weight']:.3f}",
                            "" if c["k"] is None else f"{c['k']:.1f}"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default=ALL_CASES, metavar="MEDIUM:TARGET,...",
                    help="the pipelines to run (default: every path-traced case)")
    ap.add_argument("--clear", action="store_true",
                    help="also rank the BRDF families on each clear-water plate (step 0)")
    ap.add_argument("--propagation", default="auto", choices=("auto", "linear",
                                                              "sigma-points", "off"))
    ap.add_argument("--json", default=JSON)
    ap.add_argument("--resume", action="store_true",
                    help="keep the rows in --json and skip their cases")
    ap.add_argument("--table-only", action="store_true",
                    help="run nothing: print (and --doc) the table of the rows in --json")
    bv.add_doc_options(ap, "auto")
    ap.add_argument("--candidates-doc", default=None, metavar="PAGE",
                    help="write every candidate of the plates in no family (table "
                         "'nonparametric') into PAGE's markers")
    args = ap.parse_args(argv)
    truth = bv.load_truth()
    rows = []
    if (args.resume or args.table_only) and os.path.exists(args.json):
        with open(args.json) as f:
            rows = json.load(f)
    done = {r["case"] for r in rows}
    todo = [] if args.table_only else (
        [tuple(c.split(":")) for c in args.cases.split(",") if c] +
        ([("water", p) for p in CLEAR] if args.clear else []))

    def save():
        from veil.io import write_text_atomic

        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        write_text_atomic(args.json, json.dumps(rows, indent=1, default=float))

    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i, (medium, target) in enumerate(todo):
            case = f"{medium}:{target}"
            if case in done:
                print(f"[{i + 1}/{len(todo)}] {case}: in {args.json}, skipped", file=sys.stderr)
                continue
            load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
            print(f"[{i + 1}/{len(todo)}] {case} (load {load}, "
                  f"{time.perf_counter() - t_all:.0f} s so far)", file=sys.stderr, flush=True)
            if medium == "water":
                r = run_clear(truth, target)
            else:
                r = run_case(truth, medium, target, os.path.join(tmp, case.replace(":", "-")),
                             args.propagation)
            r["load_after"] = list(os.getloadavg())
            rows.append(r)
            save()
            s = r["steps"]
            said = {True: "generating", False: "NOT generating"}
            print("    -> " + "; ".join(f"{k} {x['pick']} (dBIC {_dbic(x['delta_bic'])}, "
                                       f"{said[x['pick_is_generating']]})"
                                       for k, x in s.items())
                  + (f"; estimate vs truth {_pct(r['est_vs_truth'])}"
                     f" ± {_pct(r['se_rms_relative'])}" if "est_vs_truth" in r else "")
                  + f"; {r['seconds']:.0f} s", file=sys.stderr, flush=True)
    order = {c: i for i, c in enumerate(
        ALL_CASES.split(",") + [f"water:{p}" for p in CLEAR])}
    rows.sort(key=lambda r: order.get(r["case"], len(order)))
    text = print_table(rows)
    notes = summary(rows)
    print("\n".join(notes))
    if args.doc:
        from doc_tables import write

        covered = ", ".join(r["case"] for r in rows)
        loads = [r["load_after"][0] for r in rows if r.get("load_after")]
        load = (f" The machine's load average (1 min) after each case: {min(loads):.1f} to "
                f"{max(loads):.1f}; \"s\" is each case's wall time under it, the first "
                f"pipeline's including the compilation of every candidate's programs."
                if loads else "")
        write(args.doc, args.doc_table,
              f"Sessions covered: {covered}.{load}\n\n" + text + "\n\n" + "\n".join(notes))
    if args.candidates_doc:
        from doc_tables import markdown, write

        table = markdown(CANDIDATE_COLUMNS, candidate_rows(rows), {3, 4, 5, 6})
        print(table)
        write(args.candidates_doc, "nonparametric",
              table + "\n\n" + "\n".join(n for n in notes if "outside every family" in n))
    return 0


if __name__ == "__main__":
    sys.exit(main())
