"""Colour maps on a path-traced photo stack (issue 30, item 6): `veil fit maps --channel rgb`
over validation/data/rgb_stack (validation/render_rgb.py --stack), each pixel against the
plate's truth.

The stack: a 5 cm plate of 4 x 4 tiles of rough plastic, each its own RGB diffuse reflectance
and roughness, photographed through the coloured water `cw` by a pinhole camera at distance D
(one ray from the pinhole to each pixel's plate point: the near-field geometry of
docs/maps-geometry.md, photos registered to the plate), with the black cloth photographed the
same way. The maps are the command

    veil fit maps validation/data/rgb_stack/photos \
        --manifest validation/data/rgb_stack/manifest.csv --medium MEDIUM.json \
        --black-photos validation/data/rgb_stack/black --channel rgb \
        --near-field --camera-distance D --pixel-pitch P --brdf-model rough-plastic \
        --fix eta=ETA --fix ks=1 --noise REL -o OUT/maps.zarr

run as a subprocess with this checkout's veil. D, P, the index ETA (the plates' acrylic in
water) and ks = 1 (Mitsuba's specular_reflectance) come from the stack's truth.json, REL from
the render's own Monte Carlo noise (the median relative standard error of a pixel's value after
the black photo's subtraction over pixels and configurations, truth.json: over every channel
for --channel rgb, the channel's own for a map of one channel). MEDIUM is
the coloured water fitted in step 1 of validation/rgb_table.py over the goniometer sessions
(validation/results/rgb_medium.json): what a user has; `--medium` names another.

Per channel it compares the albedo map rho and the shared roughness alpha with the truth per
pixel: the share of converged pixels within 3 standard errors (target: 95 %), the error in
standard errors (mean, sd), the median relative error and standard error; and the same by ring
(distance of the pixel from the plate centre), since the medium's path lengths through the
cylinder change across the plate and the model's do not. ``--doc PAGE`` writes the table
between the page's markers (benchmarks/doc_tables.py); the numbers also go to ``--json``
(default validation/results/rgb_maps.json).

    PYTHONPATH=src python validation/rgb_maps.py [--medium FILE] \
        [--doc docs/validity-colour-maps.md]
    PYTHONPATH=src python validation/rgb_maps.py --per-channel \
        [--doc docs/validity-colour-controls.md]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
STACK = os.path.join(HERE, "data", "rgb_stack")
MEDIUM = os.path.join(HERE, "results", "rgb_medium.json")
JSON = os.path.join(HERE, "results", "rgb_maps.json")
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
CHANNELS = ("r", "g", "b")


def channel_medium(medium: str, channel: str) -> list[str]:
    """The --medium options of one channel of a step-1 result fitted over channels: its
    forward-series parameters as a literal list (TAU,OMEGA,G,ETA_U,S) and its options."""
    from veil.fitting import FitResult

    res = FitResult.from_json(medium)
    model = res.as_model(channel=channel)
    values = ",".join(f"{getattr(model, p.name):.6g}" for p in type(model).PARAMS)
    opts = []
    for name, value in (res.options or {}).items():
        if value is not None:
            opts += [
                f"--{name.replace('_', '-')}",
                f"{value:g}" if isinstance(value, float) else str(value),
            ]
    return ["--medium", values, "--medium-model", res.model, *opts]


def truth_medium(medium: str, truth: dict, path: str) -> str:
    """``medium``'s result file with the stack's own medium (truth.json) as its parameters,
    written to ``path``."""
    with open(medium) as f:
        res = json.load(f)
    med = truth["medium"]
    for k, c in enumerate(CHANNELS):
        res["params"][f"tau[{c}]"] = med["tau"][k]
        res["params"][f"omega[{c}]"] = med["albedo"][k]
    res["params"]["g"] = med["g"]
    with open(path, "w") as f:
        json.dump(res, f)
    return path


def command(
    truth: dict, medium: str, out: str, rel: float, extra: list[str], channel: str = "rgb"
) -> list[str]:
    med = ["--medium", medium] if channel == "rgb" else channel_medium(medium, channel)
    return [
        "fit",
        "maps",
        os.path.join(STACK, "photos"),
        "--manifest",
        os.path.join(STACK, "manifest.csv"),
        *med,
        "--black-photos",
        os.path.join(STACK, "black"),
        "--channel",
        channel,
        "--near-field",
        "--camera-distance",
        f"{truth['camera_distance_cm']:g}",
        "--pixel-pitch",
        f"{truth['pixel_pitch_cm']:g}",
        "--brdf-model",
        "rough-plastic",
        "--fix",
        f"eta={truth['eta']:.6g}",
        "--fix",
        f"ks={truth['ks']:g}",
        "--noise",
        f"{rel:.4g}",
        *extra,
        "-o",
        out,
    ]


def shown(args: list[str]) -> str:
    return " ".join(
        ["veil"]
        + [os.path.relpath(a, ROOT) if os.path.isabs(a) and a.startswith(ROOT) else a for a in args]
    )


def run_maps(args: list[str]) -> tuple[int, float, str]:
    code = (
        "import sys; from veil.cli import main; sys.argv = ['veil'] + sys.argv[1:]; "
        "sys.exit(main())"
    )
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    sys.stderr.write(proc.stderr[-6000:])
    if proc.returncode not in (0, 1):
        raise SystemExit(f"rgb_maps: veil fit maps exited {proc.returncode}")
    return proc.returncode, seconds, proc.stderr


def compare(store: str, truth: dict, channel: str = "rgb") -> dict:
    import veil

    maps = veil.open_maps(store)
    names = list(maps["info"]["params"])
    status = np.asarray(maps["status"])
    ok = status == 0
    size = truth["size"]
    c = size / 2
    y, x = np.mgrid[0:size, 0:size]
    radius = np.hypot(x + 0.5 - c, y + 0.5 - c) * truth["pixel_pitch_cm"]
    rings = [(0.0, 1.0), (1.0, 2.0), (2.0, 4.0)]

    def one(label, est, se, true, se_noise=None, se_medium=None):
        est, se, true = (np.asarray(a, dtype=float) for a in (est, se, true))
        good = ok & (se > 0)
        z = (est - true) / np.where(good, se, 1.0)
        rec = {} if se_noise is None else noise_alone(est, np.asarray(se_noise), true, good)
        if se_medium is not None:  # docs/maps-medium-error.md: with and without its part
            part = np.asarray(se_medium, dtype=float)
            rec |= without_medium(est, np.sqrt(np.maximum(se**2 - part**2, 0.0)), part, true, good)
        rec |= {
            "param": label,
            "pixels": int(good.sum()),
            "within_3se": float(np.mean(np.abs(z[good]) <= 3)) if good.any() else math.nan,
            "within_2se": float(np.mean(np.abs(z[good]) <= 2)) if good.any() else math.nan,
            "z_mean": float(np.mean(z[good])),
            "z_sd": float(np.std(z[good])),
            "median_rel_error": float(np.median(np.abs(est[good] / true[good] - 1))),
            "median_rel_se": float(np.median(se[good] / true[good])),
            "by_ring": [],
        }
        for lo, hi in rings:
            m = good & (radius >= lo) & (radius < hi)
            if m.any():
                rec["by_ring"].append(
                    {
                        "ring_cm": [lo, hi],
                        "pixels": int(m.sum()),
                        "within_3se": float(np.mean(np.abs(z[m]) <= 3)),
                        "z_mean": float(np.mean(z[m])),
                    }
                )
        return rec

    rows = []
    info = maps["info"]
    for ch in CHANNELS if channel == "rgb" else (channel,):
        se_noise = se_medium = None
        if channel != "rgb":  # a map of one channel: rho is its albedo
            k = names.index("rho")
            est, se = maps["params"][k], maps["stderr"][k]
            if "stderr_noise" in maps:
                se_noise = maps["stderr_noise"][k]
            if "stderr_medium" in maps:
                se_medium = maps["stderr_medium"][k]
        elif "channel_params" in maps:  # (Q, C, H, W): per-channel parameters
            q, c = list(info["channel_params"]).index("rho"), list(info["channels"]).index(ch)
            est, se = maps["channel_params"][q, c], maps["channel_stderr"][q, c]
            if "channel_stderr_noise" in maps:
                se_noise = maps["channel_stderr_noise"][q, c]
            if "channel_stderr_medium" in maps:
                se_medium = maps["channel_stderr_medium"][q, c]
        else:  # names like rho[r] in params
            k = names.index(next(n for n in names if re.fullmatch(rf"rho\[{ch}\]", n)))
            est, se = maps["params"][k], maps["stderr"][k]
        rows.append(one(f"rho[{ch}]", est, se, np.asarray(truth["rho"][ch]), se_noise, se_medium))
        tile = np.asarray(truth["tile"])
        rt = np.asarray(truth["rho"][ch])
        rows[-1]["_ratio_by_tile"] = {
            int(t): float(np.median(np.asarray(est)[ok & (tile == t)] / rt[ok & (tile == t)]))
            if (ok & (tile == t)).any()
            else math.nan
            for t in np.unique(tile)
        }
    # per tile: the medians of estimate / truth over its converged pixels
    tile = np.asarray(truth["tile"])
    k = names.index("alpha")
    tiles = []
    for t in (int(t) for t in np.unique(tile)):
        m = ok & (tile == t)
        rec = {
            "tile": t,
            "alpha_true": float(np.asarray(truth["alpha"])[tile == t][0]),
            "alpha_ratio": float(np.median(maps["params"][k][m] / np.asarray(truth["alpha"])[m]))
            if m.any()
            else math.nan,
        }
        for r in rows:
            ch = r["param"][4]
            rt = np.asarray(truth["rho"][ch])
            rec[f"rho_true[{ch}]"] = float(rt[tile == t][0])
            rec[f"rho_ratio[{ch}]"] = r["_ratio_by_tile"][t]
        tiles.append(rec)
    for r in rows:
        del r["_ratio_by_tile"]
    rows.append(
        one(
            "alpha" if channel == "rgb" else f"alpha ({channel} alone)",
            maps["params"][k],
            maps["stderr"][k],
            np.asarray(truth["alpha"]),
            maps["stderr_noise"][k] if "stderr_noise" in maps else None,
            maps["stderr_medium"][k] if "stderr_medium" in maps else None,
        )
    )
    chi2 = np.asarray(maps["chi2_reduced"])[ok]
    out = {
        "rows": rows,
        "tiles": tiles,
        "params": names,
        "converged": int(ok.sum()),
        "pixels": int(status.size),
        "status_counts": {int(s): int((status == s).sum()) for s in np.unique(status)},
        "chi2_median": float(np.median(chi2)) if chi2.size else math.nan,
    }
    if "stderr_medium" in maps:  # docs/maps-medium-error.md: the summary
        from veil.maps.store import summarize_maps

        out["propagation"] = summarize_maps(store, maps)["propagation"]
    if "model_error" in maps:  # docs/maps-model-error.md: the summary, s per tile
        from veil.maps.store import summarize_maps

        out["model_error"] = summarize_maps(store, maps)["model_error"]
        chans = list(info.get("channels") or [channel])
        for rec in tiles:
            m = ok & (tile == rec["tile"])
            for c, ch in enumerate(chans):
                rec[f"s_median[{ch}]"] = float(np.median(maps["model_error"][c][m]))
    return out


def noise_alone(est, se, true, good) -> dict:
    """A store with the model's error (docs/maps-model-error.md): the share within 3 of
    the standard errors of the noise alone and their median relative size."""
    z = (est - true) / np.where(good & (se > 0), se, 1.0)
    return {
        "within_3se_noise": float(np.mean(np.abs(z[good]) <= 3)) if good.any() else math.nan,
        "median_rel_se_noise": float(np.median(se[good] / true[good])),
    }


def without_medium(est, se_rest, part, true, good) -> dict:
    """A store with the medium's uncertainty (docs/maps-medium-error.md): the share within
    3 of the standard errors without the medium's part, and that part's median relative
    size."""
    z = (est - true) / np.where(good & (se_rest > 0), se_rest, 1.0)
    return {
        "within_3se_without_medium": float(np.mean(np.abs(z[good]) <= 3))
        if good.any()
        else math.nan,
        "median_rel_se_medium": float(np.median(part[good] / true[good])),
    }


def _pct(x, d=0):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.{d}f} %"


def table(res: dict) -> str:
    from doc_tables import markdown

    rows = []
    noise = all("within_3se_noise" in r for r in res["rows"])
    medium = all("within_3se_without_medium" in r for r in res["rows"])
    for r in res["rows"]:
        rings = ", ".join(
            f"{g['ring_cm'][0]:g}-{g['ring_cm'][1]:g} cm: {_pct(g['within_3se'])} "
            f"({g['z_mean']:+.2f})"
            for g in r["by_ring"]
        )
        rows.append(
            [
                r["param"],
                str(r["pixels"]),
                f"**{_pct(r['within_3se'], 1)}**",
                _pct(r["within_2se"], 1),
                f"{r['z_mean']:+.2f}, {r['z_sd']:.2f}",
                _pct(r["median_rel_error"], 1),
                _pct(r["median_rel_se"], 1),
                rings,
            ]
            + ([_pct(r["within_3se_noise"], 1), _pct(r["median_rel_se_noise"], 1)] if noise else [])
            + (
                [_pct(r["within_3se_without_medium"], 1), _pct(r["median_rel_se_medium"], 1)]
                if medium
                else []
            )
        )
    head = [
        "parameter",
        "converged pixels",
        "within 3 se",
        "within 2 se",
        "error / se: mean, sd",
        "median \\|relative error\\|",
        "median relative se",
        "within 3 se (mean error / se) by distance from the centre",
    ]
    head += ["within 3 se of the noise alone", "median relative se, noise alone"] if noise else []
    head += (
        ["within 3 se without the medium's part", "median relative se, the medium's part"]
        if medium
        else []
    )
    return markdown(head, rows, set(range(1, len(head))) - {4, 7})


def rounds_table(rounds: list) -> str:
    """One row per round of the blur: each parameter's share within 3 standard errors and
    median relative error, the converged pixels, the reduced chi-square, the time."""
    from doc_tables import markdown

    params = [r["param"] for r in rounds[0]["rows"]]
    rows = [
        [str(k), str(r["converged"])]
        + [f"{_pct(x['within_3se'], 1)} ({_pct(x['median_rel_error'], 1)})" for x in r["rows"]]
        + [f"{r['chi2_median']:.2f}", f"{r['seconds']:.0f}"]
        for k, r in enumerate(rounds)
    ]
    head = (
        ["round", "converged pixels"]
        + [f"{p} within 3 se (median \\|relative error\\|)" for p in params]
        + ["reduced chi-square, median", "seconds"]
    )
    return markdown(head, rows, set(range(1, len(head))))


def tile_table(res: dict) -> str:
    """Per tile: the truth and the median estimate / truth of every parameter mapped."""
    from doc_tables import markdown

    tiles = res.get("tiles") or []
    if not tiles:
        return ""
    rho_keys = sorted(
        (k for k in tiles[0] if k.startswith("rho_true[")),
        key=lambda k: CHANNELS.index(k[len("rho_true[") : -1]),
    )
    chans = [k[len("rho_true[") : -1] for k in rho_keys]
    alpha_keys = [k for k in tiles[0] if k.startswith("alpha_ratio")]
    head = (
        ["tile (row, column)", "rho true (" + ", ".join(chans) + ")"]
        + [f"rho[{c}] estimate / true" for c in chans]
        + ["alpha true"]
        + [k.replace("alpha_ratio", "alpha estimate / true") for k in alpha_keys]
    )
    n = int(round(len(tiles) ** 0.5))
    rows = [
        [f"({t['tile'] // n}, {t['tile'] % n})", ", ".join(f"{t[k]:.2f}" for k in rho_keys)]
        + [f"{t[f'rho_ratio[{c}]']:.3f}" for c in chans]
        + [f"{t['alpha_true']:.2f}"]
        + [f"{t[k]:.3f}" for k in alpha_keys]
        for t in tiles
    ]
    return markdown(head, rows, set(range(2, len(head))))


def summary(res: dict) -> list[str]:
    bad = [r["param"] for r in res["rows"] if not r["within_3se"] >= 0.95]
    chi2 = ", ".join(f"{c:.2f}" for c in res["chi2_median"])
    return (
        [
            f"- {res['converged']} of {res['pixels']} pixel fits converged (status counts "
            f"{res['status_counts']}); reduced chi-square median {chi2}",
            "- within 3 standard errors on at least 95 % of the converged pixels: "
            + ("every parameter" if not bad else "not " + ", ".join(bad)),
            f"- `veil fit maps` took {res['seconds']:.0f} s wall (exit status {res['exit']})",
        ]
        + model_error_notes(res)
        + propagation_notes(res)
    )


def propagation_notes(res: dict) -> list[str]:
    """The last map's medium uncertainty (docs/maps-medium-error.md): the medium's
    parameters and each map parameter's median share of the standard error."""
    last = (res.get("rounds") or [res])[-1]
    entry = last.get("propagation")
    if not entry:
        return []
    shares = ", ".join(f"{n} {100 * m['median_share']:.0f} %" for n, m in entry["maps"].items())
    return [
        f"- the medium's uncertainty ({', '.join(entry['parameters'])}, first order): its "
        f"median share of the standard error {shares}"
    ]


def model_error_notes(res: dict) -> list[str]:
    """The last map's model error (docs/maps-model-error.md): per channel the median s and
    the lengths, and the tiles of the largest and smallest median s in each channel."""
    last = (res.get("rounds") or [res])[-1]
    term = last.get("model_error")
    if not term:
        return []
    notes = []
    for ch, c in term["channels"].items():
        key = f"s_median[{ch}]"
        tiles = sorted(last["tiles"], key=lambda t: t[key])
        lo, hi = tiles[0], tiles[-1]
        notes.append(
            f"- the model's error in {ch}: median s {c['median_sigma']:.3g} over the pixels "
            f"with a term ({100 * c['share_with_term']:.0f} %), lengths "
            + ", ".join(f"{v:g}" for v in c["lengths"])
            + f" deg; by tile from {lo[key]:.3g} (true albedo {lo[f'rho_true[{ch}]']:.2f}) to "
            f"{hi[key]:.3g} (true albedo {hi[f'rho_true[{ch}]']:.2f})"
        )
    return notes


def main(argv=None) -> int:
    global STACK
    import bench_validity as bv

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--medium", default=MEDIUM, help="the medium (default: %(default)s)")
    ap.add_argument("--json", default=JSON)
    ap.add_argument("--keep", default=None, metavar="DIR", help="write the store here")
    ap.add_argument("--table-only", action="store_true", help="run nothing: the table of --json")
    ap.add_argument(
        "--per-channel",
        action="store_true",
        help="three maps of one channel each (--channel r, g, b), each through its "
        "channel's medium, instead of one --channel rgb map; json "
        "results/rgb_maps_per_channel.json, table colour-maps-per-channel",
    )
    ap.add_argument(
        "--stack", default=None, help=f"the photo stack (default {os.path.relpath(STACK, ROOT)})"
    )
    ap.add_argument(
        "--channels",
        default="r,g,b",
        help="with --per-channel: the channels to map (default %(default)s)",
    )
    ap.add_argument(
        "--blur-rounds",
        type=int,
        default=0,
        help="then N maps more, each with --blur-from the one before (docs/maps-blur.md): "
        "json results/rgb_maps_blur.json, table colour-maps-blur, the last round's table "
        "and one row per round",
    )
    ap.add_argument(
        "--truth-medium",
        action="store_true",
        help="map through the stack's own medium (truth.json's tau, albedo, g written into "
        "--medium's result file) instead of the fitted one: what the maps reach when the "
        "medium is right (json and table names end in truth_medium; with --blur-rounds the "
        "table colour-maps-blur-truth-medium)",
    )
    ap.add_argument(
        "--model-error",
        default="off",
        choices=("off", "independent", "correlated"),
        help="the last map with --model-error KIND (docs/maps-model-error.md): json and "
        "table names end in model_error (with --blur-rounds the table "
        "colour-maps-blur-model-error); the table gains the noise-only columns",
    )
    ap.add_argument(
        "--propagation",
        default="off",
        choices=("off", "linear"),
        help="the last map with --propagation KIND (docs/maps-medium-error.md): json and "
        "table names end in propagation (with --blur-rounds and --model-error correlated "
        "the table colour-maps-blur-model-error-propagation); the table gains the columns "
        "without the medium's part",
    )
    ap.add_argument("extra", nargs="*", help="more options for veil fit maps (after --)")
    bv.add_doc_options(ap, "colour-maps")
    args = ap.parse_args(argv)
    if args.stack:
        STACK = os.path.abspath(args.stack)
    # the defaults of --json and --doc-table by what is run (given ones are kept)
    kinds = [
        (args.per_channel, "_per_channel", "-per-channel"),
        (args.blur_rounds, "_blur", "-blur"),
        (args.truth_medium, "_truth_medium", "-truth-medium"),
        (args.model_error != "off", "_model_error", "-model-error"),
        (args.propagation != "off", "_propagation", "-propagation"),
    ]
    if args.json == JSON:
        args.json = JSON.replace(".json", "".join(j for on, j, _ in kinds if on) + ".json")
    if args.doc_table == "colour-maps":
        args.doc_table += "".join(t for on, _, t in kinds if on)
    with open(os.path.join(STACK, "truth.json")) as f:
        truth = json.load(f)
    if args.table_only:
        with open(args.json) as f:
            res = json.load(f)
    else:
        noise = truth["render"]["relative_standard_error_after_black"]
        res = {
            "rows": [],
            "tiles": [],
            "noise_rel": {},
            "converged": 0,
            "pixels": 0,
            "status_counts": {},
            "seconds": 0.0,
            "exit": 0,
            "commands": [],
            "chi2_median": [],
        }
        with tempfile.TemporaryDirectory() as tmp:
            work = args.keep or tmp
            if args.truth_medium:
                args.medium = truth_medium(args.medium, truth, os.path.join(tmp, "medium.json"))
            for channel in args.channels.split(",") if args.per_channel else ("rgb",):
                os.makedirs(os.path.join(work, channel), exist_ok=True)
                store = os.path.join(work, channel, "maps.zarr")
                shutil.rmtree(store, ignore_errors=True)  # this script's own, of an earlier run
                # the render's noise: over every channel for --channel rgb (one --noise),
                # the channel's own for a map of one channel
                rel = noise["all" if channel == "rgb" else channel]["median"]
                res["noise_rel"][channel] = rel
                last = ["--model-error", args.model_error] if args.model_error != "off" else []
                last += ["--propagation", args.propagation] if args.propagation != "off" else []
                rounds = args.blur_rounds if channel == "rgb" else 0
                extra = [*args.extra, *(last if not rounds else [])]
                cmd = command(truth, os.path.abspath(args.medium), store, rel, extra, channel)
                code, seconds, _ = run_maps(cmd)
                one = compare(store, truth, channel)
                res["commands"].append(shown(cmd).replace(work, "OUT"))
                if args.blur_rounds and channel == "rgb":
                    res["rounds"] = [dict(one, seconds=seconds, exit=code)]
                for k in range(1, rounds + 1):
                    prior, store = store, os.path.join(work, channel, f"maps-blur{k}.zarr")
                    shutil.rmtree(store, ignore_errors=True)
                    extra = [*args.extra, "--blur-from", prior, *(last if k == rounds else [])]
                    cmd = command(truth, os.path.abspath(args.medium), store, rel, extra, channel)
                    code, more, _ = run_maps(cmd)
                    seconds += more
                    one = compare(store, truth, channel)
                    res["rounds"].append(dict(one, seconds=more, exit=code))
                    res["commands"].append(shown(cmd).replace(work, "OUT"))
                res["rows"] += one["rows"]
                for key in ("model_error", "propagation"):
                    if key in one:
                        res[key] = one[key]
                for t, rec in enumerate(one["tiles"]):
                    if len(res["tiles"]) <= t:
                        res["tiles"].append({"tile": t, "alpha_true": rec["alpha_true"]})
                    res["tiles"][t].update(
                        {k: v for k, v in rec.items() if k.startswith(("rho_", "s_median"))}
                    )
                    res["tiles"][t][f"alpha_ratio ({channel})"] = rec["alpha_ratio"]
                res["converged"] += one["converged"]
                res["pixels"] += one["pixels"]
                for k, v in one["status_counts"].items():
                    res["status_counts"][k] = res["status_counts"].get(k, 0) + v
                res["chi2_median"].append(one["chi2_median"])
                res["seconds"] += seconds
                res["exit"] = max(res["exit"], code)
        res.update(load_after=list(os.getloadavg()))
        from veil.io import write_text_atomic

        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        write_text_atomic(args.json, json.dumps(res, indent=1, default=float) + "\n")
    text = table(res)
    if res.get("rounds"):
        text = (
            "Round by round (round 0: the map without the blur; round k: --blur-from round "
            "k - 1), the share of converged pixels within 3 standard errors:\n\n"
            + rounds_table(res["rounds"])
            + "\n\nThe last round:\n\n"
            + text
        )
    tt = tile_table(res) if not res.get("rounds") else ""  # (the rounds: their table only)
    if tt:
        text += "\n\nPer tile, the median over its converged pixels:\n\n" + tt
    notes = summary(res)
    print(text + "\n\n" + "\n".join(notes))
    if args.doc:
        from doc_tables import write

        cmds = "\n".join(f"    {c}" for c in res["commands"])
        write(
            args.doc,
            args.doc_table,
            "The maps (REL of `--noise` the render's median relative standard error "
            "after the black photo's subtraction, "
            + ", ".join(f"{c} {v:.4g}" for c, v in res["noise_rel"].items())
            + f"):\n\n{cmds}\n\n"
            f"Load average (1 min) after them: {res['load_after'][0]:.1f}.\n\n"
            + text
            + "\n\n"
            + "\n".join(notes),
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
