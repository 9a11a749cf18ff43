"""Colour on path-traced data (issue 30, item 6): `veil fit pipeline` over the RGB sessions of
validation/render_rgb.py, each channel against the truth.

The sessions (validation/data/rgb_*.csv, three channels r, g, b each): the coloured reference
plate in clear water (step 0) and in the coloured water `cw` (step 1), the coloured target in
`cw` (step 2), the black cloth in `cw` subtracted, the target in clear water fitted directly.
The pipeline is the command

    veil fit pipeline --reference-clear rgb_water_ref.csv --reference-medium rgb_cw_ref.csv \
        --target-medium rgb_cw_target.csv --black rgb_cw_black.csv \
        --target-clear rgb_water_target.csv --brdf-model rough-plastic \
        --medium-model forward-series --path-length 15 --plate-width 5 --no-figures -o OUT

run as a subprocess with this checkout's veil (the clear-water files without their all-zero
sigma column, as benchmarks/bench_validity.py reads them: their renders are exact). Then per
channel:

- the estimate's f_r against two truths over the clear session's 111 configurations (relative
  RMS): the Mitsuba target plate's clear-water session (the renderer's own value) and veil's
  rough-plastic with the plate's true parameters (validation/data/truth_rgb.json); and the
  direct fit against the Mitsuba truth;
- the shared alpha and eta of the estimate against the truth in units of their reported
  standard error (``stderr_total``: steps 0 and 1 included);
- the medium's per-channel optical depth tau and albedo omega, and the shared g, against the
  rendered water's.

``--doc PAGE`` writes the tables between the page's markers (benchmarks/doc_tables.py) with
the command, date and load; the numbers also go to ``--json``
(default validation/results/rgb_table.json).

    PYTHONPATH=src python validation/rgb_table.py [--doc docs/validity-colour.md]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(HERE, "data")
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
JSON = os.path.join(HERE, "results", "rgb_table.json")
MEDIUM = os.path.join(HERE, "results", "rgb_medium.json")  # step 1's fit, for rgb_maps.py
CHANNELS = ("r", "g", "b")
SESSIONS = {
    "reference_clear": "rgb_water_ref",
    "reference_medium": "rgb_cw_ref",
    "target_medium": "rgb_cw_target",
    "black": "rgb_cw_black",
    "target_clear": "rgb_water_target",
}
FLAGS = {
    "reference_clear": "--reference-clear",
    "reference_medium": "--reference-medium",
    "target_medium": "--target-medium",
    "black": "--black",
    "target_clear": "--target-clear",
}


def command(files: dict, out: str, truth: dict, orders: str | None = None) -> list[str]:
    args = ["fit", "pipeline"]
    for k, flag in FLAGS.items():
        args += [flag, files[k]]
    geo = truth["geometry_numbers"]
    return args + [
        "--brdf-model",
        "rough-plastic",
        "--medium-model",
        "forward-series",
        "--path-length",
        f"{geo['path_length_cm']:g}",
        "--plate-width",
        f"{geo['plate_width_cm']:g}",
        *(["--orders", orders] if orders else []),
        "--no-figures",
        "-o",
        out,
    ]


def medium_path(orders: str | None) -> str:
    """Where step 1's medium is kept for validation/rgb_maps.py (per orders option)."""
    return MEDIUM if not orders else MEDIUM.replace(".json", f"_{orders}.json")


def load_truth() -> dict:
    with open(os.path.join(DATA, "truth_rgb.json")) as f:
        t = json.load(f)
    t["geometry_numbers"] = {
        "path_length_cm": t["path_length_cm"],
        "plate_width_cm": 2 * t["plate_half_width_cm"],
    }
    return t


def run_pipeline(tmp: str, truth: dict, orders: str | None = None) -> tuple[str, float, list[str]]:
    """The pipeline as a subprocess; (its output folder, wall seconds, the command)."""
    files = {}
    for k, stem in SESSIONS.items():
        src = os.path.join(DATA, f"{stem}.csv")
        if k in ("reference_clear", "target_clear"):  # exact renders: unweighted
            dst = os.path.join(tmp, f"{stem}.csv")
            pd.read_csv(src).drop(columns=["sigma"]).to_csv(dst, index=False)
            files[k] = dst
        else:
            files[k] = src
    out = os.path.join(tmp, "fit-rgb")
    args = command(files, out, truth, orders)
    t0 = time.perf_counter()
    code = (
        "import sys; from veil.cli import main; sys.argv = ['veil'] + sys.argv[1:]; "
        "sys.exit(main())"
    )
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    sys.stderr.write(proc.stderr[-4000:])
    if proc.returncode not in (0, 1):
        raise SystemExit(f"rgb_table: veil fit pipeline exited {proc.returncode}")
    shown = ["veil"] + [
        os.path.relpath(a, ROOT)
        if os.path.isabs(a) and a.startswith(DATA)
        else (os.path.basename(a) if os.path.isabs(a) else a)
        for a in args
    ]
    return out, seconds, shown


def rel_rms(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) / np.asarray(b) - 1.0) ** 2)))


def evaluate(out: str, truth: dict) -> dict:
    from veil.data.measurements import canonical_angles
    from veil.fitting import FitResult, model_values
    from veil.models import model_class

    target = FitResult.from_json(os.path.join(out, "target.json"))
    medium = FitResult.from_json(os.path.join(out, "medium.json"))
    direct = FitResult.from_json(os.path.join(out, "target_direct.json"))
    clear = pd.read_csv(os.path.join(DATA, f"{SESSIONS['target_clear']}.csv"))
    plate = truth["plates"]["target"]
    med_true = truth["media"]["cw"]
    rows = []
    for k, ch in enumerate(CHANNELS):
        t = clear[clear["channel"] == ch].reset_index(drop=True)
        canon = canonical_angles(t)
        angles = tuple(
            canon[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_r", "phi_r")
        )
        rendered = t["value"].to_numpy(dtype=float)
        true_model = model_class("rough-plastic").from_params(
            {
                "rho": plate["diffuse_reflectance"][k],
                "alpha": plate["alpha"],
                "eta": plate["relative_index"],
                "ks": plate["specular_reflectance"],
            },
            {"distribution": plate["distribution"], "nonlinear": plate["nonlinear"]},
        )
        veil_truth = model_values(true_model, None, angles)
        est = model_values(target.as_model(channel=ch), None, angles)
        dfit = model_values(direct.as_model(channel=ch), None, angles)
        se_t = target.stderr_total or target.stderr
        se_m = medium.stderr_total or medium.stderr
        name = target.channels[ch]
        mname = medium.channels[ch]
        tau, omega = medium.params[mname["tau"]], medium.params[mname["omega"]]
        rows.append(
            {
                "channel": ch,
                "est_vs_mitsuba": rel_rms(est, rendered),
                "est_vs_veil_truth": rel_rms(est, veil_truth),
                "direct_vs_mitsuba": rel_rms(dfit, rendered),
                "veil_truth_vs_mitsuba": rel_rms(veil_truth, rendered),
                "max_est_vs_mitsuba": float(np.max(np.abs(est / rendered - 1))),
                "rho": target.params[name["rho"]],
                "rho_se": (se_t or {}).get(name["rho"]),
                "rho_true": plate["diffuse_reflectance"][k],
                "ks": target.params[name["ks"]],
                "ks_se": (se_t or {}).get(name["ks"]),
                "tau": tau,
                "tau_se": (se_m or {}).get(mname["tau"]),
                "tau_true": med_true["tau"][k],
                "omega": omega,
                "omega_se": (se_m or {}).get(mname["omega"]),
                "omega_true": med_true["albedo"][k],
            }
        )
    shared = []
    for p, true in (("alpha", plate["alpha"]), ("eta", plate["relative_index"])):
        name = target.channels[CHANNELS[0]][p]
        se = (target.stderr_total or target.stderr or {}).get(name)
        shared.append(
            {
                "param": p,
                "estimate": target.params[name],
                "se": se,
                "true": true,
                "direct": direct.params[direct.channels[CHANNELS[0]][p]],
                "z": (target.params[name] - true) / se if se else math.nan,
            }
        )
    gname = medium.channels[CHANNELS[0]]["g"]
    g = {
        "estimate": medium.params[gname],
        "se": (medium.stderr_total or medium.stderr or {}).get(gname),
        "true": med_true["g"],
    }
    return {
        "channels": rows,
        "shared": shared,
        "g": g,
        "converged": {
            "medium": medium.converged,
            "target": target.converged,
            "direct": direct.converged,
        },
        "chi2_reduced": {"medium": medium.chi2_reduced, "target": target.chi2_reduced},
    }


def _pct(x, d=2):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.{d}f} %"


def _pm(v, se, d=4):
    return f"{v:.{d}f}" + ("" if se is None else f" ± {se:.{d}f}")


def tables(res: dict) -> str:
    from doc_tables import markdown

    ch = markdown(
        [
            "channel",
            "estimate vs Mitsuba truth",
            "estimate vs veil truth",
            "direct fit vs Mitsuba",
            "veil truth vs Mitsuba",
            "max \\|estimate / truth - 1\\|",
            "rho ± se (true)",
            "ks ± se (true 1)",
            "tau ± se (true)",
            "tau error",
            "omega ± se (true)",
        ],
        [
            [
                r["channel"],
                f"**{_pct(r['est_vs_mitsuba'])}**",
                _pct(r["est_vs_veil_truth"]),
                _pct(r["direct_vs_mitsuba"]),
                _pct(r["veil_truth_vs_mitsuba"], 4),
                _pct(r["max_est_vs_mitsuba"]),
                f"{_pm(r['rho'], r['rho_se'])} ({r['rho_true']:g})",
                _pm(r["ks"], r["ks_se"], 3),
                f"{_pm(r['tau'], r['tau_se'], 3)} ({r['tau_true']:g})",
                f"**{100 * (r['tau'] / r['tau_true'] - 1):+.1f} %**",
                f"{_pm(r['omega'], r['omega_se'], 4)} ({r['omega_true']:g})",
            ]
            for r in res["channels"]
        ],
        set(range(1, 11)),
    )
    sh = markdown(
        [
            "shared parameter",
            "estimate ± se (stderr_total)",
            "true",
            "(estimate - true) / se",
            "direct fit",
        ],
        [
            [
                s["param"],
                _pm(s["estimate"], s["se"]),
                f"{s['true']:.4f}",
                f"**{s['z']:+.2f}**",
                f"{s['direct']:.4f}",
            ]
            for s in res["shared"]
        ]
        + [
            [
                "g (medium)",
                _pm(res["g"]["estimate"], res["g"]["se"]),
                f"{res['g']['true']:g}",
                f"{(res['g']['estimate'] - res['g']['true']) / res['g']['se']:+.2f}"
                if res["g"]["se"]
                else "-",
                "-",
            ]
        ],
        {1, 2, 3, 4},
    )
    return ch + "\n\n" + sh


def summary(res: dict) -> list[str]:
    rows = res["channels"]
    est = [r["est_vs_mitsuba"] for r in rows]
    tau = [abs(r["tau"] / r["tau_true"] - 1) for r in rows]
    shared = res["shared"]
    lines = [
        f"- estimate within 2 % RMS of the Mitsuba truth's clear curves: "
        f"{sum(e <= 0.02 for e in est)} of 3 channels ({', '.join(_pct(e) for e in est)})",
        f"- per-channel tau within 5 % of the truth: {sum(t <= 0.05 for t in tau)} of 3 "
        f"({', '.join(f'{100 * t:.1f} %' for t in tau)} off)",
        "- shared "
        + "; ".join(
            f"{s['param']} {'within' if abs(s['z']) <= 1 else 'NOT within'} one reported "
            f"standard error of the truth ({s['z']:+.2f} se)"
            for s in shared
        ),
        f"- converged: medium {res['converged']['medium']}, target {res['converged']['target']}, "
        f"direct {res['converged']['direct']}; pipeline {res['seconds']:.0f} s wall",
    ]
    return lines


def main(argv=None) -> int:
    import bench_validity as bv

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--json",
        default=None,
        help=f"default {os.path.relpath(JSON, ROOT)}, with --orders results/rgb_table_ORDERS.json",
    )
    ap.add_argument(
        "--orders",
        default=None,
        help="forward-series' orders option (default: the family's); step 1's medium is "
        "kept for rgb_maps.py in results/rgb_medium.json, with --orders in "
        "results/rgb_medium_ORDERS.json",
    )
    ap.add_argument("--table-only", action="store_true", help="run nothing: the table of --json")
    ap.add_argument("--keep", default=None, metavar="DIR", help="keep the pipeline's output here")
    bv.add_doc_options(ap, "colour-goniometer")
    args = ap.parse_args(argv)
    truth = load_truth()
    if args.json is None:
        args.json = JSON if not args.orders else JSON.replace(".json", f"_{args.orders}.json")
    if args.table_only:
        with open(args.json) as f:
            res = json.load(f)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            work = args.keep or tmp
            os.makedirs(work, exist_ok=True)
            out, seconds, cmd = run_pipeline(work, truth, args.orders)
            res = evaluate(out, truth)
            # step 1's medium, for validation/rgb_maps.py
            with open(os.path.join(out, "medium.json")) as f:
                medium_text = f.read()
        res.update(seconds=seconds, command=cmd, load_after=list(os.getloadavg()))
        from veil.io import write_text_atomic

        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        write_text_atomic(args.json, json.dumps(res, indent=1, default=float) + "\n")
        write_text_atomic(medium_path(args.orders), medium_text)
    text = tables(res)
    notes = summary(res)
    print(text + "\n\n" + "\n".join(notes))
    if args.doc:
        from doc_tables import write

        write(
            args.doc,
            args.doc_table,
            "The pipeline: `" + " ".join(res["command"]) + "` (the clear-water files without "
            f"their sigma column). Load average (1 min) after it: {res['load_after'][0]:.1f}.\n\n"
            + text
            + "\n\n"
            + "\n".join(notes),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
