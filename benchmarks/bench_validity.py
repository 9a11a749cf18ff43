"""Validity on path-traced data: the paper's models against the physical ones (issue 12).

The two-step method (docs/model.md sec. 7) on the Mitsuba 3 renders of the paper's lab set-up in
validation/data (validation/README.md): the reference plate in clear water (step 0) and in
the medium (step 1), the target in the medium (step 2), the black cloth subtracted; the
target's clear-water session is fitted directly and is also the truth (it is the renderer's
own value of the plate seen without the medium). One table per medium:

- est-vs-direct: relative RMS of the estimate's clear-water curve against the direct fit's,
  over the paper's protocol (what the paper's method promises: the object as if the medium
  were not there);
- est-vs-truth: relative RMS of the estimate's curve against the rendered clear-water values;
- max |z|: the largest difference estimate - direct of a target parameter in units of the
  combined standard error (<= 2: the reported uncertainty covers the difference);
- curves |z|, within 2 se: the same for the f_r curves, configuration by configuration
  (both fits' covariances through f_r's Jacobian): the largest, and the share of the
  protocol's configurations within two standard errors;
- tau, g: the medium's recovered optical depth per pass and asymmetry against the truth
  (the paper's medium has no optical depth; its g is shown for comparison);
- s: seconds of the whole pipeline;
- model error (--model-error, default correlated): the relative model error sigma of step 1
  and the one step 2 used (veil.fitting.model_error), rho how far step 2's error is step
  1's (model_error.session_correlation; "-" where nothing is shared); "before" the curves'
  max |z| and share
  within 2 se without it (the uncertainties of the data's noise alone, the same fits), and
  the median over the configurations of the curves' standard error with it / without it;
  "truth within 2 se": the share of the clear-water session's configurations where the
  estimate's curve is within two of its own standard errors of the rendered value.

With --joint, each medium and model set also gets a row "(joint)": steps 1 and 2 as one
joint fit (veil.fit_joint) of the reference and the target in the medium, the reference's
f_r of step 0 held (no direct fit is compared there: the columns against it are empty).

Run:  .venv/bin/python benchmarks/bench_validity.py [--media m01,m05,m10] [--targets target]
      [--models paper,physical] [--orders poisson|cylinder|light-side|view-side] [--joint]
      [--model-error off|independent|correlated] [--propagation auto|linear|sigma-points]
      [--reference ref|smooth] [--figure docs/validity.png] [--json out.json]
      [--doc docs/validity.md]
The clear-water tables have sigma = 0 (deterministic renders, validation/README.md); they are
fitted unweighted.
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
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "validation", "data")

#: The two model sets compared: the paper's and the physical ones of docs/model.md sec. 8.
MODELS = {
    "paper": dict(brdf_model="torrance-sparrow", medium_model="henyey-greenstein"),
    "physical": dict(brdf_model="rough-plastic", medium_model="forward-series"),
}


def load_truth() -> dict:
    """validation/data/truth.json: every plate's and medium's parameters and the geometry."""
    with open(os.path.join(DATA, "truth.json")) as f:
        return json.load(f)


def study_parser(doc: str, media: str) -> argparse.ArgumentParser:
    """The command line of a validation study of the physical pipeline (validation/*.py):
    --media and --orders (the cylinder's by default; the study sets ORDERS from it)."""
    from veil.models.forward_series import ORDER_WEIGHTS

    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--media", default=media)
    ap.add_argument("--orders", default="cylinder", choices=ORDER_WEIGHTS)
    add_doc_options(ap, "validity")
    return ap


def add_doc_options(ap: argparse.ArgumentParser, table: str) -> None:
    """--doc PAGE, --doc-table NAME and --doc-format: where the rows' table is written."""
    ap.add_argument("--doc", default=None, metavar="PAGE",
                    help="write the table, with this command, the date, the machine and its "
                         "load, into PAGE between its markers <!-- table:NAME ... --> and "
                         "<!-- /table:NAME --> (benchmarks/doc_tables.py)")
    ap.add_argument("--doc-table", default=table, metavar="NAME",
                    help="the NAME of those markers (default: %(default)s)")
    ap.add_argument("--doc-format", default="main", choices=("main", "seconds"),
                    help="main: the columns of docs/validity.md's table; seconds: each "
                         "medium's pipeline seconds, paper's models against physical")


def seconds_rows(rows: list[dict]) -> list[list[str]]:
    """Per medium (and target): the paper's and the physical pipeline's wall seconds."""
    out, seen = [], {}
    for r in rows:
        if not r["models"].endswith("(joint)"):
            seen.setdefault((r["medium"], r["target"]), {})[r["models"]] = r["seconds"]
    for (medium, target), s in seen.items():
        paper, physical = s.get("paper", math.nan), s.get("physical", math.nan)
        label = medium if target == "target" else f"{medium}, {target}"
        out.append([label, f"{paper:.1f}", f"{physical:.1f}", f"{physical / paper:.2f}"])
    return out


def write_doc(args, rows: list[dict]) -> None:
    """The rows' table into ``args.doc`` (nothing without --doc)."""
    if not getattr(args, "doc", None):
        return
    from doc_tables import markdown, write

    if getattr(args, "doc_format", "main") == "seconds":
        table = markdown(["medium", "paper models, s", "physical models, s", "ratio"],
                         seconds_rows(rows), {1, 2, 3})
    else:
        table = markdown(DOC_COLUMNS, doc_rows(rows), set(range(2, 11)))
    write(args.doc, getattr(args, "doc_table", "validity"), table)


def table(name: str, unweighted: bool = False) -> pd.DataFrame:
    t = pd.read_csv(os.path.join(DATA, f"{name}.csv"))
    if unweighted:
        t = t.drop(columns=["sigma"])
    t.attrs["veil_name"] = f"validation/data/{name}.csv"
    return t


#: The reference plate's object name (--reference): "ref" (alpha 0.1, rho 0.5) or "smooth"
#: (alpha 0.03, rho 0.1: a clear specular peak; rendered in the 5 cm plate's geometry only).
REFERENCE = "ref"


def sessions_of(truth: dict, medium: str, target: str, reference: str | None = None):
    """File stems of one case: medium 'm10' or 'm10_w10' (a geometry variant); the reference
    plate ``reference`` (default REFERENCE)."""
    base, _, geom = medium.partition("_")
    suffix = f"_{geom}" if geom else ""
    ref = REFERENCE if reference is None else reference
    stem = f"{base}_{ref}{suffix}"
    if not os.path.exists(os.path.join(DATA, f"{stem}.csv")):
        raise SystemExit(f"bench_validity: no session {stem}.csv in validation/data (the "
                         f"reference {ref!r} was not rendered in medium {medium!r})")
    return {"reference_clear": f"water_{ref}", "reference_medium": stem,
            "target_medium": f"{base}_{target}{suffix}", "black": f"{base}_black{suffix}",
            "target_clear": f"water_{target}", "session": f"{base}_{target}{suffix}"}


#: The physical medium's order weights (forward-series option ``orders``; --orders).
ORDERS = "poisson"
#: How step 1's covariance enters step 2's (--propagation).
PROPAGATION = "auto"


def _case(truth: dict, medium: str, target: str, models: str):
    """(file stems, the pipeline's model keywords) of one case: the physical medium gets the
    session's geometry as its options."""
    names = sessions_of(truth, medium, target)
    sess = truth["sessions"][names["session"]]
    kw = dict(MODELS[models])
    if models == "physical":
        kw["medium_options"] = {"path_length": sess["path_length_cm"],
                                "plate_width": sess["plate_width_cm"]}
        if ORDERS != "poisson":
            kw["medium_options"]["orders"] = ORDERS
    return names, kw


def _against_truth(names: dict, brdf) -> tuple:
    """(angles of the clear-water session, its table, the estimate's f_r there, the
    rendered truth, RMS relative estimate - truth) for a fitted BRDF (result or model)."""
    from veil.data.measurements import canonical_angles
    from veil.fitting import model_values

    clear = table(names["target_clear"], True)
    canon = canonical_angles(clear)
    angles = tuple(canon[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r",
                                                              "phi_r"))
    est = model_values(brdf, None, angles)
    rendered = clear["value"].to_numpy(dtype=float)
    rms = float(np.sqrt(np.mean(((est - rendered) / rendered) ** 2)))
    return angles, clear, est, rendered, rms


def _curves(clear, est, rendered) -> dict:
    return {"psi": clear["psi"].tolist(), "rho": clear["rho"].tolist(),
            "estimate": est.tolist(), "truth": rendered.tolist()}


#: The fits' model-discrepancy term (--model-error).
MODEL_ERROR = "correlated"


def _against_direct(names: dict, estimate, direct, medium_term, target_term) -> dict:
    """The columns of an estimate (a step-2 or joint result) against the direct fit and the
    truth: RMS differences, |z| of parameters and curves with the model-discrepancy terms
    (``medium_term`` of step 1, ``target_term`` the estimate's) and without them
    ("before"), the median ratio of the curves' standard errors, the curves drawn."""
    from veil.analysis.uncertainty import curve_stderr
    from veil.data.protocol import protocol
    from veil.fitting.model_error import noise_only
    from veil.pipeline import compare

    after, before = compare(estimate, direct), compare(noise_only(estimate), noise_only(direct))
    configs = protocol()
    proto = tuple(configs[c].to_numpy() for c in ("theta_i", "phi_i", "theta_r", "phi_r"))
    _, se_new = curve_stderr(estimate, proto)
    _, se_old = curve_stderr(noise_only(estimate), proto)
    ratio = math.nan if se_new is None or se_old is None else float(np.median(se_new / se_old))
    angles, clear, est, rendered, est_vs_truth = _against_truth(names, estimate.as_model())
    _, se_truth = curve_stderr(estimate, angles)
    truth_within = (math.nan if se_truth is None
                    else float(np.mean(np.abs(est - rendered) <= 2.0 * se_truth)))
    zs = [abs(r["z"]) for r in after["params"].values() if r["z"] is not None]
    return {
        "est_vs_direct": after["rms_fr_relative"], "est_vs_truth": est_vs_truth,
        "direct_vs_truth": _against_truth(names, direct)[4],
        "max_z": max(zs) if zs else math.nan, "fr_max_z": _nan(after["fr_max_z"]),
        "fr_within_2se": _nan(after["fr_within_2se"]),
        "fr_max_z_before": _nan(before["fr_max_z"]),
        "fr_within_2se_before": _nan(before["fr_within_2se"]), "se_ratio": ratio,
        "truth_within_2se": truth_within,
        "sigma_medium": math.nan if medium_term is None else medium_term.sigma,
        "sigma_target": math.nan if target_term is None else target_term.sigma,
        "length_target": math.nan if target_term is None else target_term.length,
        "rho": math.nan if target_term is None or target_term.session_correlation is None
        else target_term.session_correlation,
        "curves": _curves(clear, est, rendered),
    }


def run_case(truth: dict, medium: str, target: str, models: str, outdir: str) -> dict:
    from veil import run_pipeline

    names, kw = _case(truth, medium, target, models)
    t0 = time.perf_counter()
    res = run_pipeline(table(names["reference_clear"], True), table(names["reference_medium"]),
                       table(names["target_medium"]), black=table(names["black"]),
                       target_clear=table(names["target_clear"], True), outdir=outdir,
                       figures=False, model_error=MODEL_ERROR, propagation=PROPAGATION, **kw)
    seconds = time.perf_counter() - t0
    med = res.medium.params
    true_medium = truth["media"][medium.partition("_")[0]]
    return {
        "medium": medium, "target": target, "models": models,
        **_against_direct(names, res.target, res.direct, res.medium.model_error,
                          res.target.model_error),
        "tau_stderr": _nan((res.medium.stderr_total or res.medium.stderr).get("tau")),
        "chi2_medium": res.medium.chi2_reduced, "chi2_target": res.target.chi2_reduced,
        "tau": med.get("tau", math.nan), "tau_true": true_medium["tau"],
        "g": med.get("g", math.nan), "g_true": true_medium["g"],
        "converged": res.converged, "seconds": seconds,
        "propagation": (res.target.stats.get("propagation") or {}).get("method", "-"),
    }


def run_joint(truth: dict, medium: str, target: str, models: str) -> dict:
    """Steps 1 and 2 as one joint fit (veil.fit_joint): the reference and the target in the
    medium, one medium for both, the reference's f_r from step 0 held (its covariance
    propagated); the target's estimate against the truth and the direct fit as in
    :func:`run_case`, the model-discrepancy term the joint fit's own."""
    from veil import fit_joint
    from veil.fitting import fit_direct, fit_reference, prepare

    names, kw = _case(truth, medium, target, models)
    black = table(names["black"])
    t0 = time.perf_counter()
    ref = fit_reference(table(names["reference_clear"], True), brdf_model=kw["brdf_model"])
    label = medium.partition("_")[0]
    sessions = [(prepare(table(names["reference_medium"]), black, "reference").table, label,
                 "reference"),
                (prepare(table(names["target_medium"]), black, "target").table, label,
                 "target")]
    res = fit_joint(sessions, reference=ref, model_error=MODEL_ERROR, propagation=PROPAGATION,
                    **kw)
    seconds = time.perf_counter() - t0
    direct = fit_direct(table(names["target_clear"], True), brdf_model=kw["brdf_model"])
    med = res.medium(label).as_dict()
    true_medium = truth["media"][label]
    tau_name = (res.layout.get("media") or {}).get(label, {}).get("tau")
    return {
        "medium": medium, "target": target, "models": models + " (joint)",
        **_against_direct(names, res, direct, res.model_error, res.model_error),
        "tau": med.get("tau", math.nan), "tau_true": true_medium["tau"],
        "tau_stderr": _nan((res.stderr_total or res.stderr).get(tau_name))
        if tau_name else math.nan,
        "g": med.get("g", math.nan), "g_true": true_medium["g"],
        "chi2_medium": res.chi2_reduced, "chi2_target": res.chi2_reduced,
        "converged": res.converged, "seconds": seconds,
        "propagation": (res.stats.get("propagation") or {}).get("method", "-"),
    }


def _nan(x) -> float:
    return math.nan if x is None else float(x)


def _pct(x: float, digits: int = 2) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.{digits}f} %"


def _num(x: float) -> str:
    return "-" if math.isnan(x) else f"{x:.2f}"


def print_table(rows: list[dict]) -> None:
    from rich.console import Console
    from rich.table import Table

    for medium in dict.fromkeys(r["medium"] for r in rows):
        t = Table(title=f"medium {medium}")
        for col in ("target", "models", "est-vs-direct", "est-vs-truth", "direct-vs-truth",
                    "max |z|", "curves |z|", "within 2 se", "tau (true)", "g (true)",
                    "conv.", "s"):
            t.add_column(col, justify="right")
        for r in (r for r in rows if r["medium"] == medium):
            t.add_row(r["target"], r["models"], _pct(r["est_vs_direct"]),
                      _pct(r["est_vs_truth"]), _pct(r["direct_vs_truth"]),
                      _num(r["max_z"]), _num(r.get("fr_max_z", math.nan)),
                      _pct(r.get("fr_within_2se", math.nan), 0),
                      "-" if math.isnan(r["tau"]) else
                      f"{r['tau']:.4f} ± {r.get('tau_stderr', math.nan):.3f} ({r['tau_true']:g})",
                      f"{r['g']:.4f} ({r['g_true']:g})", "yes" if r["converged"] else "NO",
                      f"{r['seconds']:.1f}")
        Console(width=160).print(t)
    covered = [r for r in rows if "se_ratio" in r]
    if covered:
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"model-discrepancy term ({MODEL_ERROR}): curves before -> after")
        for col in ("session", "models", "est-vs-direct", "sigma step 1", "sigma step 2",
                    "ell", "rho", "propagation", "max |z| before", "after", "within 2 se before",
                    "after", "median se ratio", "truth within 2 se"):
            t.add_column(col, justify="right")
        for r in covered:
            t.add_row(f"{r['medium']} {r['target']}", r["models"], _pct(r["est_vs_direct"]),
                      _pct(r["sigma_medium"]), _pct(r["sigma_target"]),
                      _num(r["length_target"]), _num(r.get("rho", math.nan)),
                      r.get("propagation", "-"),
                      _num(r["fr_max_z_before"]),
                      _num(r["fr_max_z"]), _pct(r["fr_within_2se_before"], 0),
                      _pct(r["fr_within_2se"], 0), _num(r["se_ratio"]),
                      _pct(r.get("truth_within_2se", math.nan), 0))
        Console(width=160).print(t)


#: The columns of docs/validity.md's main table (``--doc``), one row per estimate.
DOC_COLUMNS = ["medium (tau per pass, g)", "models", "estimate vs direct fit", "estimate vs truth",
               "direct fit vs truth", "max \\|z\\| params", "max \\|z\\| curves",
               "curves within 2 se", "tau ± se (true)", "g (true)", "s"]


def _true(x: float) -> str:
    """A true value as the tables write it: 1.0, 0.5, 0.97."""
    return f"{x:.1f}" if round(x, 1) == x else f"{x:g}"


def doc_rows(rows: list[dict]) -> list[list[str]]:
    """The rows of the main table of docs/validity.md: the physical models' estimates in
    bold, a joint fit's columns against the direct fit empty."""
    out = []
    for r in rows:
        joint = r["models"].endswith("(joint)")
        bold = (lambda s: f"**{s}**") if r["models"].startswith("physical") else (lambda s: s)
        models = r["models"] if r["target"] == "target" else f"{r['models']}, {r['target']}"
        tau = ("-" if math.isnan(_nan(r.get("tau"))) else
               f"{r['tau']:.3f} ± {_nan(r.get('tau_stderr')):.3f} ({_true(r['tau_true'])})")
        out.append([
            f"{r['medium']} ({_true(r['tau_true'])}, {_true(r['g_true'])})", models,
            "-" if joint else bold(_pct(r["est_vs_direct"])), bold(_pct(r["est_vs_truth"])),
            "-" if joint else _pct(r["direct_vs_truth"]),
            "-" if joint else _num(r["max_z"]),
            "-" if joint else _num(_nan(r.get("fr_max_z"))),
            "-" if joint else _pct(_nan(r.get("fr_within_2se")), 0),
            tau, f"{r['g']:.4f} ({_true(r['g_true'])})", f"{r['seconds']:.0f}"])
    return out


def figure(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    media = list(dict.fromkeys(r["medium"] for r in rows))
    fig, axes = plt.subplots(1, len(media), figsize=(4.2 * len(media), 3.6), squeeze=False)
    for ax, medium in zip(axes[0], media):
        first = True
        for r in (r for r in rows if r["medium"] == medium):
            psi, rho = np.asarray(r["curves"]["psi"]), np.asarray(r["curves"]["rho"])
            sel = np.isclose(psi, 60.0)
            order = np.argsort(rho[sel])
            x = rho[sel][order]
            if first:
                ax.plot(x, np.asarray(r["curves"]["truth"])[sel][order], "k.", ms=3,
                        label="truth (path traced, clear water)")
                first = False
            ax.plot(x, np.asarray(r["curves"]["estimate"])[sel][order],
                    "-" if r["models"] == "physical" else "--",
                    label=f"{r['models']} estimate ({r['target']}): "
                          f"{100 * r['est_vs_truth']:.1f} % RMS")
        ax.set_yscale("log")
        ax.set_title(f"{medium}, psi = 60 deg")
        ax.set_xlabel("plate rotation rho (deg)")
        ax.legend(fontsize=6)
    axes[0][0].set_ylabel("value (1/sr)")
    fig.tight_layout()
    import io

    from veil.io import write_bytes_atomic

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    write_bytes_atomic(path, buf.getvalue())


def main(argv=None) -> int:
    from veil.models.forward_series import ORDER_WEIGHTS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--media", default="m01,m05,m10")
    ap.add_argument("--targets", default="target")
    ap.add_argument("--cases", default=None, metavar="MEDIUM:TARGET,...",
                    help="these medium and target pairs instead of every --media x --targets")
    ap.add_argument("--models", default="paper,physical")
    ap.add_argument("--figure", default=None)
    ap.add_argument("--json", default=None)
    add_doc_options(ap, "validity")
    ap.add_argument("--joint", action="store_true",
                    help="also steps 1 and 2 as one joint fit per medium and model set")
    ap.add_argument("--replot", default=None, metavar="JSON",
                    help="draw --figure from the rows of an earlier --json run, fit nothing")
    ap.add_argument("--orders", default="poisson", choices=ORDER_WEIGHTS,
                    help="the physical medium's order weights (forward-series option orders)")
    ap.add_argument("--model-error", default="correlated",
                    choices=("off", "independent", "correlated"),
                    help="the fits' model-discrepancy term (veil.fitting.model_error)")
    ap.add_argument("--propagation", default="auto", choices=("auto", "linear", "sigma-points"),
                    help="how step 1's covariance enters step 2's (veil.fitting.propagation)")
    ap.add_argument("--reference", default="ref", choices=("ref", "smooth"),
                    help="the reference plate (validation/README.md): ref (alpha 0.1) or "
                         "smooth (alpha 0.03, a clear specular peak; 5 cm plate only)")
    args = ap.parse_args(argv)
    global ORDERS, MODEL_ERROR, PROPAGATION, REFERENCE
    REFERENCE = args.reference
    ORDERS = args.orders
    MODEL_ERROR = args.model_error
    PROPAGATION = args.propagation
    if args.replot:
        with open(args.replot) as f:
            rows = json.load(f)
        print_table(rows)
        if args.figure:
            figure(rows, args.figure)
        write_doc(args, rows)
        return 0
    truth = load_truth()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = ([tuple(c.split(":")) for c in args.cases.split(",")] if args.cases else
                 [(m, t) for m in args.media.split(",") for t in args.targets.split(",")])
        for medium, target in cases:
            for models in args.models.split(","):
                out = os.path.join(tmp, f"{medium}-{target}-{models}")
                r = run_case(truth, medium, target, models, out)
                print(f"{medium} {target} {models}: est-vs-direct "
                      f"{100 * r['est_vs_direct']:.2f} %, {r['seconds']:.1f} s",
                      file=sys.stderr, flush=True)
                rows.append(r)
                if args.joint:
                    r = run_joint(truth, medium, target, models)
                    print(f"{medium} {target} {models} joint: est-vs-truth "
                          f"{100 * r['est_vs_truth']:.2f} %, {r['seconds']:.1f} s",
                          file=sys.stderr, flush=True)
                    rows.append(r)
    print_table(rows)
    if args.figure:
        figure(rows, args.figure)
    write_doc(args, rows)
    if args.json:
        from veil.io import write_text_atomic

        write_text_atomic(args.json, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
