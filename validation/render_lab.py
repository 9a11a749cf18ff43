#!/usr/bin/env python3
"""Path-traced validation data for veil: the paper's lab set-up rendered with Mitsuba 3.

A flat square plate at the centre of a cylinder of radius R_c filled with a homogeneous,
forward-scattering medium (index-matched wall), lit by a collimated beam of unit irradiance
and seen by a one-ray radiance meter, at every configuration of the goniometer protocol
(docs/model.md sec. 1).  Each session (object x medium x geometry) is written as a CSV table
(psi, rho, theta_i, theta_r, value, sigma) that veil reads; see validation/README.md.

This script is NOT used by veil or its tests: veil reads only the committed tables.
It needs Mitsuba 3 (pip install mitsuba numpy), outside the project's environment, and for
the LLVM variants Debian's libLLVM 19 (DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1).

    python validation/render_lab.py                 # the full data set into validation/data
    python validation/render_lab.py --quick         # smoke run (psi 60 only, few samples) into /tmp
    python validation/render_lab.py --sessions water_ref,m10_black
    python validation/render_lab.py --checks        # the sanity checks -> data/checks.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import zlib

import numpy as np

# ----------------------------------------------------------------------------------------
# Everything the data set is made of.  Scene units: centimetres (sigma_t in 1/cm).
# ----------------------------------------------------------------------------------------

UNITS = "cm"
WATER_IOR = 1.333
ACRYLIC_IOR = 1.49
ALBEDO = 0.99
R_C = 15.0            # cylinder radius = path length of one in-plane pass (cm)
HALF_WIDTH = 2.5      # plate half-width a (cm): a 5 cm x 5 cm plate
CYL_HALF_LENGTH = 30.0  # the cylinder runs y = -30..30 cm, closed by end caps
METER_GAP = 5.0       # the radiance meter's origin is this far outside the wall (cm)
MAX_DEPTH = 128       # volpath max_depth (medium scatterings + surface bounces; null walls don't count)
RR_DEPTH = 5          # volpath's default Russian-roulette depth (unbiased)

PLATES = {
    # reference: white-ish acrylic, Beckmann
    "ref": {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.10,
            "diffuse_reflectance": 0.5, "specular_reflectance": 1.0,
            "int_ior": ACRYLIC_IOR, "ext_ior": WATER_IOR, "nonlinear": False},
    # target in veil's family (rough-plastic, Beckmann), rougher and darker
    "target": {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.20,
               "diffuse_reflectance": 0.2, "specular_reflectance": 1.0,
               "int_ior": ACRYLIC_IOR, "ext_ior": WATER_IOR, "nonlinear": False},
    # target outside veil's families when veil fits Beckmann: GGX (longer tails)
    "ggx": {"type": "roughplastic", "distribution": "ggx", "alpha": 0.15,
            "diffuse_reflectance": 0.3, "specular_reflectance": 1.0,
            "int_ior": ACRYLIC_IOR, "ext_ior": WATER_IOR, "nonlinear": False},
    # a smooth, dark plastic whose specular peak stands out of the diffuse floor (facet
    # half-width at half maximum about 1.4 deg, like the paper's BRDF1), a second reference
    "smooth": {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.03,
               "diffuse_reflectance": 0.1, "specular_reflectance": 1.0,
               "int_ior": ACRYLIC_IOR, "ext_ior": WATER_IOR, "nonlinear": False},
    # a plate outside every family veil has (issue 29): Mitsuba's principled BSDF with a
    # clear coat over a rough base, two specular lobes (the coat's GTR1 and the base's GGX)
    # over a Disney diffuse; eta is the base's index relative to the water around it
    "clearcoat": {"type": "principled", "base_color": 0.3, "roughness": 0.4,
                  "metallic": 0.0, "clearcoat": 0.8, "clearcoat_gloss": 0.9,
                  "eta": ACRYLIC_IOR / WATER_IOR},
    # black cloth: a perfectly black diffuse plate (reflectance 0)
    "black": {"type": "diffuse", "reflectance": 0.0},
}

MEDIA = {
    "m01": {"tau": 0.1, "g": 0.97, "albedo": ALBEDO},
    "m05": {"tau": 0.5, "g": 0.92, "albedo": ALBEDO},
    "m10": {"tau": 1.0, "g": 0.88, "albedo": ALBEDO},
    "m15": {"tau": 1.5, "g": 0.85, "albedo": ALBEDO},
}

# Samples: passes x spp_per_pass per configuration.  Clear water is deterministic (the
# meter ray hits the plate, next-event estimation towards a delta light), so few samples.
# In the media the noise near the peak is dominated by light scattered on the illumination
# side (a diffusely sampled bounce must fall into the narrow HG lobe of the light), worst
# for the thinnest, most forward medium, so every medium gets the same budget.
PASSES = 8
SPP_PER_PASS = {"water": 64, "m01": 65536, "m05": 65536, "m10": 65536, "m15": 65536}


def _sessions():
    """name -> dict(object, medium, half_width, r_c), in rendering order (priority order:
    the required sessions first, the optional ones last)."""
    s = {}
    for obj in ("ref", "target", "ggx", "smooth", "black"):
        s[f"water_{obj}"] = dict(object=obj, medium="water", half_width=HALF_WIDTH, r_c=R_C)
    for med in ("m01", "m05", "m10"):
        for obj in ("ref", "target", "ggx", "black"):
            s[f"{med}_{obj}"] = dict(object=obj, medium=med, half_width=HALF_WIDTH, r_c=R_C)
    # geometry variations in the tau = 1 medium: a 10 cm plate; a 10 cm cylinder radius with
    # the same tau per pass (sigma_t = tau / R_c is then 1.5 x larger)
    for obj in ("ref", "target", "black"):
        s[f"m10_{obj}_w10"] = dict(object=obj, medium="m10", half_width=5.0, r_c=R_C)
    for obj in ("ref", "target", "black"):
        s[f"m10_{obj}_r10"] = dict(object=obj, medium="m10", half_width=HALF_WIDTH, r_c=10.0)
    for med in ("m05", "m10", "m01"):
        s[f"{med}_smooth"] = dict(object="smooth", medium=med, half_width=HALF_WIDTH, r_c=R_C)
    for obj in ("ref", "target", "smooth", "black", "ggx"):
        s[f"m15_{obj}"] = dict(object=obj, medium="m15", half_width=HALF_WIDTH, r_c=R_C)
    # the smooth reference in the two geometry variations (step 1 on a plate with a clear
    # specular peak, docs/validity.md)
    s["m10_smooth_w10"] = dict(object="smooth", medium="m10", half_width=5.0, r_c=R_C)
    s["m10_smooth_r10"] = dict(object="smooth", medium="m10", half_width=HALF_WIDTH, r_c=10.0)
    # the plate outside every family (issue 29), in clear water and in m05
    for med in ("water", "m05"):
        s[f"{med}_clearcoat"] = dict(object="clearcoat", medium=med, half_width=HALF_WIDTH,
                                     r_c=R_C)
    return s


SESSIONS = _sessions()

# ----------------------------------------------------------------------------------------
# The protocol (docs/model.md sec. 1; same sampling as veil.protocol.protocol, reimplemented so
# that this script does not depend on veil).
# ----------------------------------------------------------------------------------------


def rho_values(psi, fine_step=1.0, coarse_step=5.0, window=10.0, limit=85.0):
    reach = limit - psi / 2.0
    n_fine = int(math.floor(window / fine_step + 1e-9))
    pos = [k * fine_step for k in range(1, n_fine + 1) if k * fine_step < reach]
    last = n_fine * fine_step
    j = 1
    while last + j * coarse_step < reach:
        pos.append(last + j * coarse_step)
        j += 1
    return [-p for p in reversed(pos)] + [0.0] + pos


def protocol(psis=(30.0, 60.0, 90.0)):
    """List of (psi, rho, theta_i, theta_r), signed in-plane angles in degrees."""
    return [(psi, rho, psi / 2.0 + rho, psi / 2.0 - rho) for psi in psis for rho in rho_values(psi)]


def directions(theta_i, theta_r):
    """Unit vectors I (to the light, azimuth 180 deg) and R (to the camera, azimuth 0)."""
    ti, tr = math.radians(theta_i), math.radians(theta_r)
    return (np.array([-math.sin(ti), 0.0, math.cos(ti)]),
            np.array([math.sin(tr), 0.0, math.cos(tr)]))


# ----------------------------------------------------------------------------------------
# Mitsuba
# ----------------------------------------------------------------------------------------

mi = dr = None


def init_mitsuba(variant, jobs=None):
    global mi, dr
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        cand = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
        if os.path.exists(cand):
            os.environ["DRJIT_LIBLLVM_PATH"] = cand
    import drjit as _dr
    import mitsuba as _mi
    mi, dr = _mi, _dr
    mi.set_variant(variant)
    if jobs:
        dr.set_thread_count(jobs)


def bsdf_dict(obj):
    p = PLATES[obj]
    if p["type"] == "diffuse":
        return {"type": "diffuse", "reflectance": {"type": "uniform", "value": p["reflectance"]}}
    if p["type"] == "principled":
        return {"type": "principled",
                "base_color": {"type": "uniform", "value": p["base_color"]},
                **{k: v for k, v in p.items() if k not in ("type", "base_color")}}
    return {"type": "roughplastic", "distribution": p["distribution"], "alpha": p["alpha"],
            "int_ior": p["int_ior"], "ext_ior": p["ext_ior"], "nonlinear": p["nonlinear"],
            "diffuse_reflectance": {"type": "uniform", "value": p["diffuse_reflectance"]},
            "specular_reflectance": {"type": "uniform", "value": p["specular_reflectance"]}}


def medium_dict(medium, r_c, albedo=None):
    m = MEDIA[medium]
    return {"type": "homogeneous", "sigma_t": m["tau"] / r_c,
            "albedo": m["albedo"] if albedo is None else albedo,
            "phase": {"type": "hg", "g": m["g"]}}


def scene_dict(obj, medium, half_width, r_c, max_depth=MAX_DEPTH, albedo=None, sensor=None):
    T = mi.ScalarTransform4f
    d = {"type": "scene",
         "integrator": {"type": "volpath", "max_depth": max_depth, "rr_depth": RR_DEPTH},
         # collimated light, irradiance 1 on a surface facing it; direction set per configuration
         "light": {"type": "directional", "direction": [0.0, 0.0, -1.0], "irradiance": 1.0},
         # the plate: Mitsuba's rectangle is [-1, 1]^2 in z = 0 with normal +z
         "plate": {"type": "rectangle", "to_world": T().scale([half_width, half_width, 1.0]),
                   "bsdf": bsdf_dict(obj)}}
    if sensor is not None:
        d["sensor"] = sensor
    if medium != "water":
        med = medium_dict(medium, r_c, albedo)
        d["medium"] = med
        ref = {"type": "ref", "id": "medium"}
        L = CYL_HALF_LENGTH
        # index-matched wall: null BSDF, the medium inside; outward normals everywhere
        d["wall"] = {"type": "cylinder", "p0": [0.0, -L, 0.0], "p1": [0.0, L, 0.0], "radius": r_c,
                     "bsdf": {"type": "null"}, "interior": ref}
        d["cap_plus"] = {"type": "disk", "bsdf": {"type": "null"}, "interior": ref,
                         "to_world": T().translate([0.0, L, 0.0]).rotate([1, 0, 0], -90).scale(r_c)}
        d["cap_minus"] = {"type": "disk", "bsdf": {"type": "null"}, "interior": ref,
                          "to_world": T().translate([0.0, -L, 0.0]).rotate([1, 0, 0], 90).scale(r_c)}
    return d


class Renderer:
    """One scene; renders one configuration at a time (kernels are reused between them)."""

    def __init__(self, obj, medium, half_width, r_c, max_depth=MAX_DEPTH, albedo=None):
        self.r_c = r_c
        self.scene = mi.load_dict(scene_dict(obj, medium, half_width, r_c, max_depth, albedo))
        self.integrator = self.scene.integrator()
        self.params = mi.traverse(self.scene)
        self.sampler = mi.load_dict({"type": "independent"})

    def set_light(self, I):
        # directional emitter: local +z is the direction of travel, here -I
        self.params["light.to_world"] = mi.ScalarTransform4f().look_at(
            origin=[0.0, 0.0, 0.0], target=[float(-c) for c in I],
            up=[0.0, 1.0, 0.0] if abs(I[1]) < 0.9 else [1.0, 0.0, 0.0])
        self.params.update()

    def samples(self, theta_i, theta_r, n, seed):
        """n radiance samples (float64 numpy) of the meter ray for one configuration."""
        I, R = directions(theta_i, theta_r)
        self.set_light(I)
        # the radiance meter's ray: from outside the cylinder on the line of R, towards the
        # plate centre (exactly what Mitsuba's radiancemeter sensor emits; see check_meter)
        o = R * (self.r_c + METER_GAP)
        ray = mi.Ray3f(mi.Point3f(*[dr.opaque(mi.Float, float(c)) for c in o]),
                       mi.Vector3f(*[dr.opaque(mi.Float, float(-c)) for c in R]))
        self.sampler.seed(seed, n)
        spec, _, _ = self.integrator.sample(self.scene, self.sampler, ray, None, True)
        return np.asarray(spec[0], dtype=np.float64)

    def config(self, theta_i, theta_r, passes, spp, seed_key):
        means = []
        for p in range(passes):
            seed = zlib.crc32(f"{seed_key}|{theta_i:.6f}|{theta_r:.6f}|{p}".encode())
            means.append(self.samples(theta_i, theta_r, spp, seed).mean())
        means = np.array(means)
        sigma = means.std(ddof=1) / math.sqrt(passes) if passes > 1 else float("nan")
        return float(means.mean()), float(sigma)


# ----------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------


def write_atomic(path, text):
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".tmp-", suffix=os.path.basename(path))
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def fmt(x):
    return repr(float(x))


INDEX_COLUMNS = ["file", "object", "medium", "plate_width_cm", "path_length_cm", "tau_per_pass",
                 "sigma_t_per_cm", "g", "albedo", "spp", "passes", "seconds"]


def update_index(out, rows):
    path = os.path.join(out, "sessions.csv")
    old = {}
    if os.path.exists(path):
        with open(path) as f:
            lines = f.read().splitlines()
        head = lines[0].split(",")
        for ln in lines[1:]:
            if ln.strip():
                rec = dict(zip(head, ln.split(",")))
                old[rec["file"]] = rec
    for r in rows:
        old[r["file"]] = {k: str(r[k]) for k in INDEX_COLUMNS}
    order = {f"{n}.csv": i for i, n in enumerate(SESSIONS)}
    recs = sorted(old.values(), key=lambda r: order.get(r["file"], 1e9))
    text = ",".join(INDEX_COLUMNS) + "\n" + "".join(
        ",".join(r.get(k, "") for k in INDEX_COLUMNS) + "\n" for r in recs)
    write_atomic(path, text)


def truth(variant):
    media = {}
    for k, m in MEDIA.items():
        media[k] = dict(m, phase="hg", sigma_t_per_cm={str(R_C): m["tau"] / R_C, "10.0": m["tau"] / 10.0},
                        note="sigma_t = tau / R_c: tau is the optical depth of ONE pass")
    plates = {}
    for k, p in PLATES.items():
        q = dict(p)
        if p["type"] == "roughplastic":
            q["relative_index"] = p["int_ior"] / p["ext_ior"]
            q["alpha_meaning"] = "RMS slope (Mitsuba alpha)"
            q["mitsuba_defaults"] = {"sample_visible": True}
        plates[k] = q
    sessions = {}
    for n, s in SESSIONS.items():
        sessions[n] = dict(file=f"{n}.csv", object=s["object"], medium=s["medium"],
                           plate_width_cm=2 * s["half_width"], plate_half_width_cm=s["half_width"],
                           path_length_cm=s["r_c"],
                           sigma_t_per_cm=(MEDIA[s["medium"]]["tau"] / s["r_c"]
                                           if s["medium"] != "water" else 0.0),
                           tau_per_pass=MEDIA[s["medium"]]["tau"] if s["medium"] != "water" else 0.0)
    return {
        "units": {"length": UNITS, "sigma_t": "1/" + UNITS, "angles": "degrees",
                  "value": "radiance per unit irradiance (BRDF x cos theta_i), 1/sr"},
        "mitsuba": {"version": mi.__version__, "drjit": dr.__version__, "variant": variant,
                    "integrator": {"type": "volpath", "max_depth": MAX_DEPTH, "rr_depth": RR_DEPTH},
                    "sampler": "independent"},
        "geometry": {"plate": "square, centred at the origin, normal +z, sides along x and y",
                     "plate_half_width_cm_default": HALF_WIDTH,
                     "cylinder": "axis y, radius R_c, y in [-L, L], closed by end caps; index-matched "
                                 "(null BSDF), the medium inside; the medium surrounds the plate",
                     "cylinder_radius_cm_default": R_C, "cylinder_half_length_cm": CYL_HALF_LENGTH,
                     "light": "Mitsuba directional emitter, irradiance 1, travelling along -I; "
                              "I = (-sin theta_i, 0, cos theta_i) (azimuth 180 deg)",
                     "camera": "one radiance-meter ray from R*(R_c + %g cm) towards the plate centre; "
                               "R = (sin theta_r, 0, cos theta_r) (azimuth 0)" % METER_GAP,
                     "plane_of_incidence": "xz",
                     "clear_water": "no medium and no cylinder (index-matched, eta_u = 1)"},
        "protocol": {"psi": [30, 60, 90], "fine_step": 1, "coarse_step": 5, "window": 10, "limit": 85,
                     "theta_i": "psi/2 + rho", "theta_r": "psi/2 - rho"},
        "water_ior": WATER_IOR, "plates": plates, "media": media, "sessions": sessions,
    }


def render_session(name, out, variant, passes, spp, configs, log):
    s = SESSIONS[name]
    r = Renderer(s["object"], s["medium"], s["half_width"], s["r_c"])
    t0 = time.time()
    lines = ["psi,rho,theta_i,theta_r,value,sigma"]
    for k, (psi, rho, ti, tr) in enumerate(configs):
        v, e = r.config(ti, tr, passes, spp, name)
        lines.append(",".join(fmt(x) for x in (psi, rho, ti, tr, v, e)))
        if (k + 1) % 20 == 0 or k + 1 == len(configs):
            log(f"  {name}: {k + 1}/{len(configs)} configurations, {time.time() - t0:.0f} s")
    write_atomic(os.path.join(out, f"{name}.csv"), "\n".join(lines) + "\n")
    sec = time.time() - t0
    med = s["medium"]
    return {"file": f"{name}.csv", "object": s["object"], "medium": med,
            "plate_width_cm": fmt(2 * s["half_width"]), "path_length_cm": fmt(s["r_c"]),
            "tau_per_pass": fmt(MEDIA[med]["tau"] if med != "water" else 0.0),
            "sigma_t_per_cm": fmt(MEDIA[med]["tau"] / s["r_c"] if med != "water" else 0.0),
            "g": fmt(MEDIA[med]["g"]) if med != "water" else "",
            "albedo": fmt(MEDIA[med]["albedo"]) if med != "water" else "",
            "spp": passes * spp, "passes": passes, "seconds": f"{sec:.1f}"}


# ----------------------------------------------------------------------------------------
# Sanity checks
# ----------------------------------------------------------------------------------------


def read_table(path):
    with open(path) as f:
        head = f.readline().strip().split(",")
        rows = [list(map(float, ln.split(","))) for ln in f if ln.strip()]
    a = np.array(rows)
    return {h: a[:, i] for i, h in enumerate(head)}


def check_bsdf(out):
    """(1) clear-water renders against bsdf.eval (which includes cos theta_o = cos theta_i)."""
    res = {}
    for obj in ("ref", "target", "ggx", "smooth"):
        path = os.path.join(out, f"water_{obj}.csv")
        if not os.path.exists(path):
            continue
        t = read_table(path)
        bsdf = mi.load_dict(bsdf_dict(obj))
        ev = []
        for ti, tr in zip(t["theta_i"], t["theta_r"]):
            I, R = directions(ti, tr)
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.n = mi.Normal3f(0, 0, 1)
            si.wi = mi.Vector3f(*[float(c) for c in R])           # towards the camera
            val = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*[float(c) for c in I]))  # towards the light
            ev.append(float(np.asarray(val[0]).ravel()[0]))
        ev = np.array(ev)
        rel = np.abs(t["value"] / ev - 1)
        res[obj] = {"n": int(len(ev)), "max_rel_diff": float(rel.max()),
                    "max_abs_diff": float(np.abs(t["value"] - ev).max()),
                    "max_sigma": float(t["sigma"].max()),
                    "peak_value": float(t["value"].max())}
    return res


def check_black_water(out):
    path = os.path.join(out, "water_black.csv")
    if not os.path.exists(path):
        return None
    t = read_table(path)
    return {"max_abs_value": float(np.abs(t["value"]).max()), "max_sigma": float(t["sigma"].max())}


FAR = [(90.0, -35.0), (90.0, 35.0), (60.0, -50.0), (30.0, 65.0), (30.0, -65.0), (60.0, 50.0)]


def check_unscattered_tables(out):
    """medium / clear-water ratios of the reference far from the peak."""
    configs = []
    w = read_table(os.path.join(out, "water_ref.csv")) if os.path.exists(
        os.path.join(out, "water_ref.csv")) else None
    for med in ("m01", "m05", "m10", "m15"):
        path = os.path.join(out, f"{med}_ref.csv")
        if w is None or not os.path.exists(path):
            continue
        t = read_table(path)
        tau = MEDIA[med]["tau"]
        for psi, rho in FAR:
            ii = np.where((t["psi"] == psi) & (t["rho"] == rho))[0]
            jj = np.where((w["psi"] == psi) & (w["rho"] == rho))[0]
            if len(ii) == 0 or len(jj) == 0:
                continue
            i, j = int(ii[0]), int(jj[0])
            configs.append({"medium": med, "psi": psi, "rho": rho,
                                   "theta_i": t["theta_i"][i], "theta_r": t["theta_r"][i],
                                   "ratio": t["value"][i] / w["value"][j],
                                   "ratio_sigma": t["sigma"][i] / w["value"][j],
                                   "exp_minus_2tau": math.exp(-2 * tau)})
    return configs


def check_unscattered(out, log, spp):
    """(3) medium / clear-water ratios far from the peak, and the same with albedo 0."""
    res = {"configs": check_unscattered_tables(out), "absorber_only": []}
    # the same medium with albedo 0 (pure absorber): only the unscattered beam survives
    r = Renderer("ref", "m01", HALF_WIDTH, R_C, albedo=0.0)
    rw = Renderer("ref", "water", HALF_WIDTH, R_C)
    for psi, rho in FAR[:3]:
        ti, tr = psi / 2 + rho, psi / 2 - rho
        v, e = r.config(ti, tr, PASSES, spp, "check-absorber")
        vw, _ = rw.config(ti, tr, 2, 16, "check-absorber-water")
        res["absorber_only"].append({"medium": "m01 with albedo 0", "psi": psi, "rho": rho,
                                     "ratio": v / vw, "ratio_sigma": e / vw,
                                     "exp_minus_2tau": math.exp(-0.2)})
        log(f"  absorber-only psi {psi} rho {rho}: ratio {v / vw:.5f} +- {e / vw:.5f}"
            f" (e^-2tau = {math.exp(-0.2):.5f})")
    return res


def check_depth(log, spp):
    """(4) truncation: the same samples (same seeds) at several max_depth."""
    res = []
    for med, obj in (("m15", "ref"), ("m15", "black"), ("m10", "target")):
        for psi, rho in ((60.0, 0.0), (60.0, -30.0)):
            ti, tr = psi / 2 + rho, psi / 2 - rho
            row = {"medium": med, "object": obj, "psi": psi, "rho": rho}
            for md in (4, 8, 16, 32, MAX_DEPTH, 1024):
                r = Renderer(obj, med, HALF_WIDTH, R_C, max_depth=md)
                v, e = r.config(ti, tr, 4, spp, "check-depth")
                row[f"depth_{md}"] = v
                row["sigma"] = e
            row["rel_diff_%d_vs_1024" % MAX_DEPTH] = row[f"depth_{MAX_DEPTH}"] / row["depth_1024"] - 1
            row["rel_diff_16_vs_1024"] = row["depth_16"] / row["depth_1024"] - 1
            log("  depth " + json.dumps(row))
            res.append(row)
    return res


def check_meter(log, spp):
    """The direct ray construction against Mitsuba's radiancemeter sensor + mi.render."""
    ti, tr = 40.0, 20.0
    I, R = directions(ti, tr)
    sensor = {"type": "radiancemeter", "origin": [float(c) for c in R * (R_C + METER_GAP)],
              "direction": [float(-c) for c in R],
              "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
                       "pixel_format": "luminance"},
              "sampler": {"type": "independent", "sample_count": spp}}
    d = scene_dict("ref", "m05", HALF_WIDTH, R_C, sensor=sensor)
    scene = mi.load_dict(d)
    params = mi.traverse(scene)
    params["light.to_world"] = mi.ScalarTransform4f().look_at(
        origin=[0.0, 0.0, 0.0], target=[float(-c) for c in I], up=[0.0, 1.0, 0.0])
    params.update()
    vals = [float(np.asarray(mi.render(scene, spp=spp, seed=s)).ravel()[0]) for s in range(4)]
    r = Renderer("ref", "m05", HALF_WIDTH, R_C)
    v, e = r.config(ti, tr, 4, spp, "check-meter")
    res = {"theta_i": ti, "theta_r": tr, "radiancemeter_mean": float(np.mean(vals)),
           "radiancemeter_sigma": float(np.std(vals, ddof=1) / 2), "direct_mean": v, "direct_sigma": e}
    log("  meter " + json.dumps(res))
    return res


def peak_precision(out):
    """Relative standard error at the mirror configurations (rho = 0) of every session."""
    res = {}
    for name in SESSIONS:
        p = os.path.join(out, f"{name}.csv")
        if not os.path.exists(p):
            continue
        t = read_table(p)
        m = t["rho"] == 0
        res[name] = {f"psi{int(ps)}": float(s / v) if v != 0 else None
                     for ps, s, v in zip(t["psi"][m], t["sigma"][m], t["value"][m])}
    return res


def black_fraction(out):
    """Black-cloth value over the object's value, per medium and object."""
    res = {}
    for name, s in SESSIONS.items():
        if s["object"] == "black" or s["medium"] == "water":
            continue
        suffix = name[len(s["medium"]) + 1 + len(s["object"]):]
        pb = os.path.join(out, f"{s['medium']}_black{suffix}.csv")
        po = os.path.join(out, f"{name}.csv")
        if not (os.path.exists(pb) and os.path.exists(po)):
            continue
        b, o = read_table(pb), read_table(po)
        f = b["value"] / o["value"]
        res[name] = {"median": float(np.median(f)), "max": float(f.max()),
                     "at_mirror_psi60": float(f[(o["psi"] == 60) & (o["rho"] == 0)][0]),
                     "black_max": float(b["value"].max()), "black_min": float(b["value"].min())}
    return res


# ----------------------------------------------------------------------------------------


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: psi = 60 only, 4 passes of 256 samples, into /tmp unless --out")
    ap.add_argument("--out", default=None, help="output folder (default validation/data next to this script)")
    ap.add_argument("--variant", default="llvm_ad_mono", help="Mitsuba variant (default llvm_ad_mono)")
    ap.add_argument("--spp", type=int, default=None,
                    help="samples per pass for every session (default: per medium, see SPP_PER_PASS)")
    ap.add_argument("--passes", type=int, default=None, help=f"independent passes (default {PASSES})")
    ap.add_argument("--sessions", default=None, help="comma-separated session names (default all): "
                    + ", ".join(SESSIONS))
    ap.add_argument("--jobs", type=int, default=None, help="Dr.Jit worker threads (default: all cores)")
    ap.add_argument("--checks", action="store_true", help="run the sanity checks on the tables in --out "
                    "(and a few extra renders) and write checks.json there")
    ap.add_argument("--summary", action="store_true", help="only the checks computed from the tables "
                    "(no rendering); merged into an existing checks.json")
    ap.add_argument("--list", action="store_true", help="list the sessions and exit")
    a = ap.parse_args(argv)

    if a.list:
        for n, s in SESSIONS.items():
            print(n, s)
        return 0
    here = os.path.dirname(os.path.abspath(__file__))
    out = a.out or (os.path.join(tempfile.gettempdir(), "veil-validation-quick") if a.quick
                    else os.path.join(here, "data"))
    names = list(SESSIONS) if not a.sessions else [x.strip() for x in a.sessions.split(",") if x.strip()]
    bad = [n for n in names if n not in SESSIONS]
    if bad:
        ap.error(f"unknown sessions: {', '.join(bad)} (see --list)")

    def log(msg):
        print(msg, flush=True)

    init_mitsuba(a.variant, a.jobs)
    if a.variant.startswith("scalar"):
        ap.error("use a vectorized (llvm_* or cuda_*) variant: this script traces a wavefront of rays")
    os.makedirs(out, exist_ok=True)
    write_atomic(os.path.join(out, "truth.json"), json.dumps(truth(a.variant), indent=1) + "\n")

    if a.checks or a.summary:
        spp = 1024 if a.quick else 131072
        log(f"checks on {out}")
        path = os.path.join(out, "checks.json")
        res = {}
        if a.summary and os.path.exists(path):
            with open(path) as f:
                res = json.load(f)
        res.update({"bsdf_eval_vs_clear_water": check_bsdf(out),
                    "black_cloth_clear_water": check_black_water(out),
                    "peak_relative_sigma": peak_precision(out),
                    "black_over_object": black_fraction(out)})
        log(json.dumps(res["bsdf_eval_vs_clear_water"]))
        if a.checks:
            res["radiancemeter_vs_direct"] = check_meter(log, spp // 4)
            res["unscattered"] = check_unscattered(out, log, spp // 4)
            res["max_depth"] = check_depth(log, spp)
        elif "unscattered" in res:
            res["unscattered"]["configs"] = check_unscattered_tables(out)
        write_atomic(os.path.join(out, "checks.json"), json.dumps(res, indent=1) + "\n")
        log("wrote " + os.path.join(out, "checks.json"))
        return 0

    configs = protocol((60.0,) if a.quick else (30.0, 60.0, 90.0))
    t_all = time.time()
    for name in names:
        med = SESSIONS[name]["medium"]
        passes = a.passes or (4 if a.quick else PASSES)
        spp = a.spp or (min(256, SPP_PER_PASS[med]) if a.quick else SPP_PER_PASS[med])
        log(f"session {name} ({SESSIONS[name]}): {len(configs)} configurations x {passes} passes "
            f"x {spp} samples")
        row = render_session(name, out, a.variant, passes, spp, configs, log)
        update_index(out, [row])
        log(f"  wrote {row['file']} in {row['seconds']} s (total {time.time() - t_all:.0f} s)")
    log(f"done: {len(names)} sessions in {time.time() - t_all:.0f} s -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
