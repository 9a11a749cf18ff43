"""veil against inverse rendering with Mitsuba 3 on the path-traced sessions (issue 28, item 5).

A researcher with the measurements of validation/data could skip veil and recover the target
plate by differentiable rendering: the lab scene of validation/render_lab.py (a square plate
in a cylinder of medium, a directional light, one camera ray a configuration; its scene
builders are imported), Mitsuba's ``prbvolpath`` integrator (variant ``llvm_ad_mono``),
``mi.ad.Adam`` on the plate's ``roughplastic`` parameters, loss = mean squared relative
difference between the rendered and the measured values over the sessions'
configurations. Rows, side by side in one run:

- ``veil``: ``veil.run_pipeline`` on the same tables, as ``veil fit pipeline --brdf-model
  rough-plastic --medium-model forward-series --path-length 15 --plate-width 5`` runs it
  (reference in clear water, reference and black cloth in the medium, target in the medium;
  no target_clear: the direct fit is not part of the estimate; veil fits rho, alpha, eta and
  ks of every plate and tau, omega, g of the medium, with standard errors). The first run in
  this process (JAX traces; the program store in VEIL_CACHE_DIR supplies the compiled
  programs: the table says whether it had entries before the run), then ``--veil-runs`` - 1
  warm runs. ``veil-lean``: the same with the model-discrepancy term off.
- ``IR, medium known``: the target session alone, the medium set to the TRUTH
  (validation/data/truth.json); alpha and diffuse_reflectance optimized, int_ior at the truth
  and specular_reflectance at 1 (Mitsuba's default, the physical value, also the truth;
  ``--plate-params alpha,rho,ks`` frees it). The best case for inverse rendering: nothing about
  the medium and the index is left to find.
- ``IR, medium too``: the reference plate's session in the medium and the target's, one
  medium for both: sigma_t (as tau = sigma_t R_c), albedo and HG g optimized with the target's
  parameters, the reference plate's BSDF held at the truth (veil fits it from the clear-water
  session). The analogue of veil's steps 1-2. The raw tables are used: the renderer models the
  medium's own glow, so no black cloth is needed.

Optimizer: Adam on latents (log of alpha, diffuse_reflectance, tau; logit of the albedo; atanh
of g), starting at Mitsuba's defaults for the plate (alpha 0.1, diffuse 0.5) and at tau 1,
albedo 0.95, g 0.8 for the medium; lr 0.1, beta_1 0.5, beta_2 0.9 (Mitsuba's 0.9 / 0.999
carry the first, 50 times larger gradients of the relative loss for tens of iterations and
overshoot: docs/inverse-rendering.md), the rate x 0.3 from half the iterations and x 0.1 from
three quarters. Every iteration renders every configuration once at --spp samples (primal
and PRB's adjoint pass), each render and its backward pass one ``dr.freeze``-recorded
function (6-10 times faster than plain ``mi.render`` calls here; --no-freeze).

Accuracy, for every row the same: relative RMS over the 111 configurations of the estimate's
clear-water curve against the rendered clear-water session of the target (water_target.csv),
as benchmarks/bench_validity.py measures veil (its ``_against_truth``). veil's curve is its
model's f_r; inverse rendering's is Mitsuba's own ``roughplastic.eval`` at the current
parameters (what rendered the truth: equal to the clear-water session to 3e-7), so a perfect
IR estimate scores 0.

Times: wall and process CPU seconds (both cores) to the final estimate; for IR the
optimization iterations only (scene loading and the metric's evaluation after each
iteration are not counted; the first iteration, which records the frozen kernels, is).
"first <= 2 %": the first estimate within 2 % RMS of the truth; "for good": the time from
which every later estimate is. IR/veil: IR's time over veil's (first row's) time.

Run:  PYTHONPATH=src nice -n 10 .venv/bin/python benchmarks/bench_inverse_rendering.py
      [--media m05,m10] [--rows veil,veil-lean,known,joint] [--iterations 100] [--spp 256]
      [--lr 0.1] [--no-freeze] [--veil-runs 2] [--json out.json]
Needs Mitsuba 3 (pip install 'veil[test]' or pip install mitsuba) and, for the LLVM
variants, libLLVM 19 (apt-get install -y libllvm19); without them it says so and exits 2.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "validation"))
sys.path.insert(0, HERE)

import bench_validity as bv

LLVM_PATH = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
MISSING_MITSUBA = ("bench_inverse_rendering: Mitsuba 3 is not installed in this environment "
                   "({err}).\nInstall it with the project's test extra:  pip install "
                   "'veil[test]'\nor on its own:                        pip install mitsuba")
MISSING_LLVM = ("bench_inverse_rendering: Mitsuba's LLVM variant {variant!r} cannot start: "
                "{err}\nInstall LLVM 19 (Debian/Ubuntu, as root):  apt-get update && "
                "apt-get install -y libllvm19\nand, if it lives elsewhere, set "
                "DRJIT_LIBLLVM_PATH to its libLLVM.so (default {path}).")

#: The plate's parameters (name -> Mitsuba key) and their starts: Mitsuba's own defaults of
#: roughplastic (alpha 0.1, diffuse 0.5, specular 1), what a user gets without a guess.
#: Latents are logs (positive parameters; Adam's steps are relative).
PLATE_KEYS = {"alpha": "plate.bsdf.alpha",
              "rho": "plate.bsdf.diffuse_reflectance.value",
              "ks": "plate.bsdf.specular_reflectance.value"}
PLATE_START = {"alpha": 0.1, "rho": 0.5, "ks": 1.0}
#: The medium's (row "medium too"): sigma_t as the optical depth of one pass tau = sigma_t R_c
#: (log latent), albedo (logit), g (atanh). Start: tau 1, albedo 0.95, g 0.8, away from every
#: medium of the data set in at least two parameters.
MEDIUM_KEYS = {"tau": "medium.sigma_t.value.value", "albedo": "medium.albedo.value.value",
               "g": "medium.phase_function.g"}
MEDIUM_START = {"tau": 1.0, "albedo": 0.95, "g": 0.8}
TWO_PERCENT = 0.02


# ------------------------------------------------------------------------------------------
# pure helpers (tests/test_bench_inverse_rendering.py)
# ------------------------------------------------------------------------------------------


def rms_relative(estimate, truth) -> float:
    """sqrt(mean(((estimate - truth) / truth)^2)): bench_validity's estimate-vs-truth."""
    e, t = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    return float(np.sqrt(np.mean(((e - t) / t) ** 2)))


def time_to_within(times, errors, level=TWO_PERCENT):
    """The first time from which every later error is <= level (None: the last is not)."""
    times, errors = list(times), list(errors)
    if not errors or errors[-1] > level:
        return None
    k = len(errors) - 1
    while k > 0 and errors[k - 1] <= level:
        k -= 1
    return times[k]


def parse_schedule(text: str) -> list[tuple[float, float]]:
    """'0.5:0.3,0.75:0.1' -> [(0.5, 0.3), (0.75, 0.1)] (fraction of the iterations, factor)."""
    out = []
    for part in (p for p in text.split(",") if p.strip()):
        at, _, factor = part.partition(":")
        out.append((float(at), float(factor)))
    return sorted(out)


def first_within(times, errors, level=TWO_PERCENT):
    """The first time the error is <= level (None: never)."""
    return next((t for t, e in zip(times, errors) if e <= level), None)


def to_latent(name: str, value: float) -> float:
    if name == "albedo":
        return math.log(value / (1.0 - value))
    if name == "g":
        return math.atanh(value)
    return math.log(value)


def from_latent(name: str, u: float) -> tuple[float, float]:
    """(value, d value / d latent)."""
    if name == "albedo":
        v = 1.0 / (1.0 + math.exp(-u))
        return v, v * (1.0 - v)
    if name == "g":
        v = math.tanh(u)
        return v, 1.0 - v * v
    v = math.exp(u)
    return v, v


# ------------------------------------------------------------------------------------------
# Mitsuba
# ------------------------------------------------------------------------------------------

mi = dr = rl = None


def start_mitsuba(variant: str) -> None:
    """Import Mitsuba and set the variant, or say what to install and exit 2."""
    global mi, dr, rl
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ \
            and os.path.exists(LLVM_PATH):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM_PATH
    try:
        import drjit as _dr
        import mitsuba as _mi
    except ImportError as e:
        print(MISSING_MITSUBA.format(err=e), file=sys.stderr)
        raise SystemExit(2)
    try:
        _mi.set_variant(variant)
    except Exception as e:
        if "llvm" in str(e).lower() or variant.startswith("llvm"):
            print(MISSING_LLVM.format(variant=variant, err=e, path=LLVM_PATH), file=sys.stderr)
            raise SystemExit(2)
        raise
    import render_lab

    mi, dr, rl = _mi, _dr, render_lab
    rl.mi, rl.dr = _mi, _dr  # render_lab's scene builders use its module globals


def _look(origin, target):
    return mi.Transform4f(mi.ScalarTransform4f().look_at(
        origin=[float(c) for c in origin], target=[float(c) for c in target], up=[0, 1, 0]))


class Session:
    """One measured session: the configurations' light and camera transforms, the measured
    values, and the plate parameters it holds fixed (``fixed``: Mitsuba key -> value; the
    sessions of a row share one scene, whose plate is set per session)."""

    def __init__(self, stem: str, r_c: float, fixed: dict | None = None):
        t = bv.table(stem)
        self.stem, self.fixed = stem, dict(fixed or {})
        self.values = t["value"].to_numpy(dtype=float)
        self.n = len(self.values)
        self.lights, self.cameras = [], []
        for ti, tr in zip(t["theta_i"], t["theta_r"]):
            I, R = rl.directions(ti, tr)
            self.lights.append(_look([0, 0, 0], -I))
            self.cameras.append(_look(R * (r_c + rl.METER_GAP), [0, 0, 0]))


def lab_scene(obj: str, medium: str, half_width: float, r_c: float, integrator: str,
              spp: int, max_depth: int):
    """render_lab's scene with a 1-pixel pinhole camera of negligible field (0.001 deg: 0.3
    micrometres at the plate) on the radiance meter's ray, and the differentiable
    integrator. One scene per row: Dr.Jit 1.5 cannot freeze renders of two scenes whose
    hg phase function's g is optimized (a memcpy from an untraversed buffer)."""
    sensor = {"type": "perspective", "fov": 0.001,
              "film": {"type": "hdrfilm", "width": 1, "height": 1,
                       "rfilter": {"type": "box"}, "pixel_format": "luminance"},
              "sampler": {"type": "independent", "sample_count": spp}}
    d = rl.scene_dict(obj, medium, half_width, r_c, max_depth=max_depth, sensor=sensor)
    d["integrator"] = {"type": integrator, "max_depth": max_depth, "rr_depth": rl.RR_DEPTH}
    return mi.load_dict(d)


def _render_loss(scene, params, measured, weight, seed, spp, leaves):
    """Render one configuration, its loss term, and backpropagate it (PRB's second pass).
    ``leaves``: the optimized values, passed so that dr.freeze sees them among its inputs
    (the hg phase function's g is not traversed with the scene)."""
    img = mi.render(scene, params, spp=spp, seed=seed)
    loss = dr.sum(dr.square(img.array / measured - 1.0)) * weight
    dr.backward(loss)
    return dr.detach(loss)


class InverseRendering:
    """Adam on latent parameters; every iteration renders every configuration of every
    session once (spp samples, forward and PRB's backward pass).

    ``optimized``: name -> (start value, [Mitsuba key or None per session], scale of the
    key's value to the named value's)."""

    def __init__(self, scene, spp: int, sessions, optimized: dict, lr: float, freeze: bool,
                 seed: int, betas=(0.9, 0.999)):
        self.scene, self.spp, self.sessions, self.seed = scene, spp, sessions, seed
        self.names = list(optimized)
        self.keys = {n: optimized[n][1] for n in self.names}
        self.scale = {n: optimized[n][2] for n in self.names}
        self.opt = mi.ad.Adam(lr=lr, beta_1=betas[0], beta_2=betas[1])
        for n in self.names:
            self.opt[n] = mi.Float(to_latent(n, optimized[n][0]))
        keys = {"light.to_world", "sensor.to_world"}
        for si, s in enumerate(sessions):
            keys |= set(s.fixed) | {self.keys[n][si] for n in self.names if self.keys[n][si]}
        self.params = mi.traverse(scene)
        self.params.keep(sorted(keys))
        self.render = dr.freeze(_render_loss) if freeze else _render_loss
        self.total = sum(s.n for s in sessions)
        self.it = 0

    def values(self) -> dict:
        return {n: from_latent(n, float(self.opt[n][0]))[0] for n in self.names}

    def step(self) -> float:
        vals = {n: from_latent(n, float(self.opt[n][0])) for n in self.names}
        leaves = {}
        for n in self.names:
            leaves[n] = dr.opaque(mi.Float, vals[n][0] * self.scale[n])
            dr.enable_grad(leaves[n])
        p = self.params
        loss = 0.0
        for si, s in enumerate(self.sessions):
            for key, v in s.fixed.items():
                p[key] = dr.opaque(mi.Float, v)
            mine = {n: leaves[n] for n in self.names if self.keys[n][si]}
            for n, leaf in mine.items():
                p[self.keys[n][si]] = leaf
            for k in range(s.n):
                p["light.to_world"] = s.lights[k]
                p["sensor.to_world"] = s.cameras[k]
                p.update()
                seed = mi.UInt32((self.seed * 7919 + self.it * 1_000_003 + si * 4099 + k)
                                 & 0x7FFFFFFF)
                loss += float(self.render(self.scene, p, mi.Float(float(s.values[k])),
                                          1.0 / self.total, seed, self.spp, mine)[0])
        for n in self.names:
            dr.set_grad(self.opt[n], dr.grad(leaves[n]) * self.scale[n] * vals[n][1])
        self.opt.step()
        self.it += 1
        return loss


def clear_curve(truth_plate: dict, values: dict, angles) -> np.ndarray:
    """Mitsuba's roughplastic f_r x cos theta_i at the clear-water configurations for the
    plate ``truth_plate`` with the optimized ``values`` (one wavefront)."""
    p = dict(truth_plate)
    d = {"type": "roughplastic", "distribution": p["distribution"],
         "alpha": values.get("alpha", p["alpha"]), "int_ior": p["int_ior"],
         "ext_ior": p["ext_ior"], "nonlinear": p["nonlinear"],
         "diffuse_reflectance": {"type": "uniform",
                                 "value": values.get("rho", p["diffuse_reflectance"])},
         "specular_reflectance": {"type": "uniform",
                                  "value": values.get("ks", p["specular_reflectance"])}}
    bsdf = mi.load_dict(d)
    I = np.array([rl.directions(a, b)[0] for a, b in zip(*angles)])
    R = np.array([rl.directions(a, b)[1] for a, b in zip(*angles)])
    si = dr.zeros(mi.SurfaceInteraction3f, len(I))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Normal3f(0, 0, 1)
    si.wi = mi.Vector3f(R[:, 0], R[:, 1], R[:, 2])
    val = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(I[:, 0], I[:, 1], I[:, 2]))
    return np.asarray(val, dtype=float).reshape(-1)[: len(I)]


# ------------------------------------------------------------------------------------------
# rows
# ------------------------------------------------------------------------------------------


def _clear_truth(names: dict):
    clear = bv.table(names["target_clear"], True)
    return ((clear["theta_i"].to_numpy(float), clear["theta_r"].to_numpy(float)),
            clear["value"].to_numpy(float))


def run_ir(truth: dict, medium: str, target: str, row: str, a, log) -> dict:
    names = bv.sessions_of(truth, medium, target)
    sess = truth["sessions"][names["session"]]
    base = medium.partition("_")[0]
    hw, r_c = sess["plate_half_width_cm"], sess["path_length_cm"]
    true_medium = truth["media"][base]
    t_load = time.perf_counter()
    plate = truth["plates"][target]
    if row == "known":
        sessions = [Session(names["target_medium"], r_c)]
    else:
        ref = truth["plates"][bv.REFERENCE]
        if ref["distribution"] != plate["distribution"]:
            raise SystemExit(f"bench_inverse_rendering: the joint row shares one plate BSDF "
                             f"between the reference ({ref['distribution']}) and the target "
                             f"({plate['distribution']}): same distribution only")
        fixed = {PLATE_KEYS["alpha"]: ref["alpha"], PLATE_KEYS["rho"]: ref["diffuse_reflectance"],
                 PLATE_KEYS["ks"]: ref["specular_reflectance"]}
        sessions = [Session(names["reference_medium"], r_c, fixed),
                    Session(names["target_medium"], r_c)]
    scene = lab_scene(target, base, hw, r_c, a.integrator, a.spp, a.max_depth)
    load_s = time.perf_counter() - t_load
    tgt = len(sessions) - 1
    start = dict(PLATE_START, **MEDIUM_START)
    start.update({k: float(v) for k, v in (x.split("=") for x in a.start.split(",") if x)})
    optimized = {n: (start[n], [PLATE_KEYS[n] if i == tgt else None
                                      for i in range(len(sessions))], 1.0)
                 for n in a.plate_params.split(",")}
    if row == "joint":
        optimized.update({n: (start[n], [MEDIUM_KEYS[n]] * len(sessions),
                              1.0 / r_c if n == "tau" else 1.0) for n in MEDIUM_KEYS})
    ir = InverseRendering(scene, a.spp, sessions, optimized, a.lr, not a.no_freeze, a.seed,
                          (a.beta1, a.beta2))
    level = dr.log_level()
    if row == "joint":
        # switching the plate between a held and an optimized BSDF makes Dr.Jit re-record the
        # frozen function twice an iteration and say so on every iteration after the tenth;
        # the results are those of plain mi.render (docs/inverse-rendering.md)
        dr.set_log_level(dr.LogLevel.Error)
    angles, rendered = _clear_truth(names)
    schedule = parse_schedule(a.lr_schedule)
    trace = []
    wall = cpu = 0.0
    first = None
    rms0 = rms_relative(clear_curve(plate, ir.values(), angles), rendered)
    trace.append({"it": 0, "wall": 0.0, "cpu": 0.0, "rms": rms0, "loss": math.nan,
                  **ir.values()})
    for it in range(a.iterations):
        for at, factor in schedule:
            if it == int(round(a.iterations * at)):
                ir.opt.set_learning_rate(a.lr * factor)
        w0, c0 = time.perf_counter(), time.process_time()
        loss = ir.step()
        dw, dc = time.perf_counter() - w0, time.process_time() - c0
        wall, cpu = wall + dw, cpu + dc
        if first is None:
            first = (dw, dc)
        vals = ir.values()
        rms = rms_relative(clear_curve(plate, vals, angles), rendered)
        trace.append({"it": it + 1, "wall": wall, "cpu": cpu, "rms": rms, "loss": loss, **vals})
        if log:
            log(f"  {row} it {it + 1:3d}: loss {loss:.4g}, RMS {100 * rms:.2f} %, "
                + ", ".join(f"{n} {v:.4g}" for n, v in vals.items())
                + f" ({wall:.1f} s wall, {cpu:.1f} s CPU)")
    dr.set_log_level(level)
    final = trace[-1]
    t2 = time_to_within([t["wall"] for t in trace], [t["rms"] for t in trace])
    c2 = time_to_within([t["cpu"] for t in trace], [t["rms"] for t in trace])
    f2 = first_within([t["wall"] for t in trace], [t["rms"] for t in trace])
    fi2 = first_within([t["it"] for t in trace], [t["rms"] for t in trace])
    est = {n: final[n] for n in ir.names}  # tau: sigma_t x R_c
    return {"row": "IR, medium known" if row == "known" else "IR, medium too",
            "medium": medium, "target": target, "wall": wall, "cpu": cpu, "rms": final["rms"],
            "wall_2pct": t2, "cpu_2pct": c2, "wall_first_2pct": f2, "it_first_2pct": fi2,
            "it_2pct": time_to_within([t["it"] for t in trace], [t["rms"] for t in trace]),
            "iterations": a.iterations, "spp": a.spp,
            "first_iteration": first, "load_s": load_s, "estimate": est,
            "truth": {"alpha": plate["alpha"], "rho": plate["diffuse_reflectance"],
                      "ks": plate["specular_reflectance"], "tau": true_medium["tau"],
                      "albedo": true_medium["albedo"], "g": true_medium["g"]},
            "trace": trace}


def _store_entries() -> int:
    """Compiled programs in veil's program store (veil.engine.programs, VEIL_CACHE_DIR)."""
    from veil.engine.programs import SUFFIX, directory

    d = directory()
    if not d or not os.path.isdir(d):
        return 0
    return sum(1 for e in os.listdir(d) if e.endswith(SUFFIX))


_VEIL_RUNS = [0]


def run_veil(truth: dict, medium: str, target: str, runs: int, log, lean: bool = False
             ) -> list[dict]:
    """veil's pipeline ``runs`` times; ``lean``: without the model-discrepancy term
    (model_error "off", linear propagation): the estimate without most of its uncertainty
    work."""
    from veil import run_pipeline

    names, kw = bv._case(truth, medium, target, "physical")
    if lean:
        kw.update(model_error="off", propagation="linear")
    label = "veil, model error off" if lean else "veil"
    out = []
    for k in range(runs):
        entries = _store_entries()
        with tempfile.TemporaryDirectory() as tmp:
            w0, c0 = time.perf_counter(), time.process_time()
            res = run_pipeline(bv.table(names["reference_clear"], True),
                               bv.table(names["reference_medium"]),
                               bv.table(names["target_medium"]), black=bv.table(names["black"]),
                               outdir=os.path.join(tmp, "fit"), figures=False, **kw)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        rms = bv._against_truth(names, res.target.as_model())[4]
        state = ("first pipeline in the process, program store "
                 + (f"warm ({entries} programs)" if entries else "cold (empty)")
                 if _VEIL_RUNS[0] == 0 else
                 f"warm: after {_VEIL_RUNS[0]} pipeline(s) in this process")
        _VEIL_RUNS[0] += 1
        med = res.medium.params
        out.append({"row": label + ("" if k == 0 else f" (run {k + 1})"), "medium": medium,
                    "target": target, "wall": wall, "cpu": cpu, "rms": rms,
                    "wall_2pct": wall if rms <= TWO_PERCENT else None,
                    "cpu_2pct": cpu if rms <= TWO_PERCENT else None, "state": state,
                    "estimate": {**res.target.params, "tau": med.get("tau"),
                                 "omega": med.get("omega"), "g": med.get("g")},
                    "converged": res.converged})
        if log:
            log(f"  {label} run {k + 1}: RMS {100 * rms:.2f} %, {wall:.1f} s wall, "
                f"{cpu:.1f} s CPU ({state})")
    return out


# ------------------------------------------------------------------------------------------
# output
# ------------------------------------------------------------------------------------------


def _s(x) -> str:
    return "never" if x is None else f"{x:.1f}"


def _ratio(ir, veil) -> str:
    if veil is None or veil["wall_2pct"] is None:
        return "-"
    if ir is None:
        return "never"
    return f"{ir / veil['wall_2pct']:.1f} x"


def print_table(rows: list[dict], header: str) -> list[list[str]]:
    """One table per medium: the rows, their times and accuracy, IR's time over veil's.
    Returns the rows of all media (medium first, without the notes) for --doc."""
    print(header)
    doc = []
    cols = ("row", "wall s", "CPU s", "RMS vs truth", "first <= 2 %: wall s (it.)",
            "<= 2 % for good: wall s (it.)", "CPU s", "IR/veil: final", "first 2 %",
            "for good", "notes")
    for medium in dict.fromkeys(r["medium"] for r in rows):
        rs = [r for r in rows if r["medium"] == medium]
        veil = next((r for r in rs if r["row"] == "veil"), None)
        lines = []
        for r in rs:
            ir = r["row"].startswith("IR")
            if ir:
                fw, _ = r["first_iteration"]
                first = f"{_s(r['wall_first_2pct'])} ({r['it_first_2pct'] or '-'})"
                good = f"{_s(r['wall_2pct'])} ({'-' if r['it_2pct'] is None else r['it_2pct']})"
                ratios = (f"{r['wall'] / veil['wall']:.1f} x" if veil else "-",
                          _ratio(r["wall_first_2pct"], veil), _ratio(r["wall_2pct"], veil))
                note = (f"{r['iterations']} it. x {r['spp']} spp, first it. {fw:.1f} s; "
                        + ", ".join(f"{n} {v:.4g} ({r['truth'][n]:g})"
                                    for n, v in r["estimate"].items()))
            else:
                first = good = _s(r["wall_2pct"])
                ratios = ("-", "-", "-")
                e = r["estimate"]
                note = (f"{r['state']}; rho {e['rho']:.4g}, alpha {e['alpha']:.4g}, eta "
                        f"{e['eta']:.4g}, ks {e['ks']:.3g}; tau {e['tau']:.4g}, g {e['g']:.4g}")
            lines.append((r["row"], f"{r['wall']:.1f}", f"{r['cpu']:.1f}",
                          f"{100 * r['rms']:.2f} %", first, good, _s(r["cpu_2pct"]),
                          *ratios, note))
        print(f"\nmedium {medium}, target {rs[0]['target']}:")
        widths = [max(len(c), *(len(x[i]) for x in lines)) for i, c in enumerate(cols)]
        fmt = " | ".join("{:<%d}" % w if i in (0, len(cols) - 1) else "{:>%d}" % w
                         for i, w in enumerate(widths))
        print("| " + fmt.format(*cols) + " |")
        print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
        for x in lines:
            print("| " + fmt.format(*x) + " |")
        doc += [[medium, *x[:-1]] for x in lines]
    return doc


DOC_COLUMNS = ("medium", "row", "wall s", "CPU s", "RMS vs truth", "first <= 2 %: wall s (it.)",
               "<= 2 % for good: wall s (it.)", "CPU s to 2 %", "IR/veil: final", "first 2 %",
               "for good")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--media", default="m05", help="comma-separated media (m01,m05,m10,m15)")
    ap.add_argument("--target", default="target", choices=("target", "ggx"))
    ap.add_argument("--rows", default="veil,veil-lean,known,joint",
                    help="veil, veil-lean (model-discrepancy term off), known (IR, medium "
                         "known), joint (IR, medium optimized too)")
    ap.add_argument("--iterations", type=int, default=100, help="Adam iterations per IR row")
    ap.add_argument("--spp", type=int, default=256,
                    help="samples per configuration and iteration (forward and backward)")
    ap.add_argument("--lr", type=float, default=0.1, help="Adam's learning rate (latents)")
    ap.add_argument("--beta1", type=float, default=0.5,
                    help="Adam's beta_1 (Mitsuba's default 0.9 overshoots here)")
    ap.add_argument("--beta2", type=float, default=0.9, help="Adam's beta_2 (Mitsuba's "
                    "default 0.999 remembers the first, large gradients for hundreds of steps)")
    ap.add_argument("--lr-schedule", default="0.5:0.3,0.75:0.1",
                    help="AT:FACTOR,...: from the fraction AT of the iterations on, the rate is "
                         "lr x FACTOR ('' for a constant rate)")
    ap.add_argument("--integrator", default="prbvolpath", choices=("prbvolpath", "volpath"))
    ap.add_argument("--variant", default="llvm_ad_mono")
    ap.add_argument("--max-depth", type=int, default=32,
                    help="path depth (render_lab's checks: 32 equals 128 here)")
    ap.add_argument("--no-freeze", action="store_true",
                    help="plain mi.render per configuration (no dr.freeze: about 6x slower)")
    ap.add_argument("--plate-params", default="alpha,rho",
                    help="the target's optimized parameters among alpha, rho, ks (default: "
                         "alpha and diffuse_reflectance; specular_reflectance stays at "
                         "Mitsuba's default 1, the physical value, which the truth has)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--start", default="",
                    help="start values other than the defaults, e.g. alpha=0.2,rho=0.2,ks=1")
    ap.add_argument("--veil-runs", type=int, default=1)
    ap.add_argument("--json", default=None)
    ap.add_argument("--quiet", action="store_true")
    bv.add_doc_options(ap, "inverse-rendering")
    a = ap.parse_args(argv)
    rows_wanted = [x.strip() for x in a.rows.split(",") if x.strip()]
    bad = set(rows_wanted) - {"veil", "veil-lean", "known", "joint"}
    if bad:
        ap.error(f"unknown rows {sorted(bad)}")
    if {"known", "joint"} & set(rows_wanted):
        start_mitsuba(a.variant)
    header = (f"command: {' '.join([os.path.basename(sys.executable)] + sys.argv)}\n"
              f"date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}, "
              f"machine: nproc {os.cpu_count()}, load average at start "
              f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if mi is not None:
        header += f", Mitsuba {mi.__version__} {a.variant}, Dr.Jit {dr.__version__}"
    log = None if a.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    truth = bv.load_truth()
    rows = []
    for medium in [m.strip() for m in a.media.split(",") if m.strip()]:
        if "veil" in rows_wanted:
            rows += run_veil(truth, medium, a.target, a.veil_runs, log)
        if "veil-lean" in rows_wanted:
            rows += run_veil(truth, medium, a.target, a.veil_runs, log, lean=True)
        for row in ("known", "joint"):
            if row in rows_wanted:
                rows.append(run_ir(truth, medium, a.target, row, a, log))
    header += f"; load average at end {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    doc = print_table(rows, header)
    if a.doc:
        from doc_tables import markdown, write

        write(a.doc, a.doc_table, markdown(list(DOC_COLUMNS), doc, set(range(2, 11))))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
