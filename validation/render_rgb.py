#!/usr/bin/env python3
"""Path-traced colour validation data for veil (issue 30): the lab set-up of render_lab.py in
Mitsuba 3's `llvm_ad_rgb` variant.

Two products, both through a water whose optical depth and albedo differ per channel (an
absorbing, scattering water):

1. goniometer sessions (`--sessions`): a coloured reference and a coloured target plate and
   the black cloth, in clear water and in that water, at the paper's 111 configurations, each
   written as one veil measurement table with a `channel` column r, g, b (channel after
   channel, the same configurations in every channel) into validation/data/rgb_*.csv, with a
   row per session in data/sessions.csv;
2. a registered photo stack (`--stack`): a 5 cm plate of 4 x 4 tiles, each its own rough
   plastic (its own RGB diffuse reflectance and roughness), seen through that water by a
   pinhole camera at distance D at every configuration of a small protocol, one ray from the
   pinhole to every pixel's plate point (the near-field geometry of docs/maps-geometry.md), the
   black cloth seen the same way; linear float32 RGB TIFFs, the manifest and the truth per
   pixel into validation/data/rgb_stack/.

The scene (cylinder, index-matched wall, collimated light of irradiance 1, radiance-meter rays,
seeds) is render_lab.py's; see validation/README.md "Colour". One render gives the three
channels of the same paths, as one exposure of a colour camera does.

    python validation/render_rgb.py --jobs 2                      # every goniometer session
    python validation/render_rgb.py --sessions rgb_cw_ref --jobs 2
    python validation/render_rgb.py --stack --jobs 2              # the photo stack
    python validation/render_rgb.py --quick --jobs 2              # smoke run into /tmp
    python validation/render_rgb.py --checks --doc validation/README.md   # checks, noise table
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

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import render_lab as lab

VARIANT = "llvm_ad_rgb"
CHANNELS = ("r", "g", "b")

PLATES = {
    # coloured reference: a warm white-ish acrylic, Beckmann (as render_lab's ref, alpha 0.1)
    "ref": {
        "type": "roughplastic",
        "distribution": "beckmann",
        "alpha": 0.10,
        "diffuse_reflectance": [0.6, 0.5, 0.4],
        "specular_reflectance": 1.0,
        "int_ior": lab.ACRYLIC_IOR,
        "ext_ior": lab.WATER_IOR,
        "nonlinear": False,
    },
    # coloured target: a blue acrylic, rougher (as render_lab's target, alpha 0.2)
    "target": {
        "type": "roughplastic",
        "distribution": "beckmann",
        "alpha": 0.20,
        "diffuse_reflectance": [0.15, 0.3, 0.5],
        "specular_reflectance": 1.0,
        "int_ior": lab.ACRYLIC_IOR,
        "ext_ior": lab.WATER_IOR,
        "nonlinear": False,
    },
    "black": {"type": "diffuse", "reflectance": 0.0},
}

# the coloured water: optical depth per pass and single-scattering albedo per channel
# (red absorbed most), one HG phase function
MEDIA = {"cw": {"tau": [0.9, 0.7, 0.5], "albedo": [0.95, 0.98, 0.99], "g": 0.9}}

# samples as render_lab's medium sessions: 8 passes of 65,536 per configuration
PASSES = 8
SPP_PER_PASS = {"water": 64, "cw": 65536}

SESSIONS = {
    f"rgb_{med}_{obj}": {"object": obj, "medium": med}
    for med in ("water", "cw")
    for obj in ("target", "ref", "black")
}

# ---- the photo stack ---------------------------------------------------------------------
STACK_DIR = "rgb_stack"
STACK_SIZE = 32  # pixels a side; the image covers the plate exactly
STACK_TILES = 4  # 4 x 4 tiles, STACK_SIZE / STACK_TILES pixels a side each
STACK_DISTANCE = 20.0  # pinhole distance from the plate centre (cm): render_lab's meter
STACK_PSI = (60.0, 30.0)
STACK_PASSES = 4
STACK_SPP_PER_PASS = 512  # per pixel and pass
STACK_CHUNK = 512  # pixels traced in one call (memory)
TILE_ALPHAS = (0.08, 0.12, 0.18, 0.26)  # per tile column (x)
TILE_COLOURS = (  # per tile (row, column), RGB diffuse reflectance
    ((0.70, 0.20, 0.15), (0.20, 0.60, 0.25), (0.15, 0.25, 0.70), (0.60, 0.55, 0.20)),
    ((0.30, 0.30, 0.30), (0.55, 0.25, 0.55), (0.20, 0.55, 0.60), (0.75, 0.45, 0.30)),
    ((0.10, 0.35, 0.20), (0.45, 0.45, 0.60), (0.65, 0.65, 0.65), (0.25, 0.15, 0.40)),
    ((0.50, 0.35, 0.10), (0.15, 0.15, 0.50), (0.40, 0.60, 0.30), (0.20, 0.40, 0.45)),
)


def tile_plate(row, col):
    """Rough plastic of tile (row, col); row 0 is the top of the image (plate +y)."""
    return {
        "type": "roughplastic",
        "distribution": "beckmann",
        "alpha": TILE_ALPHAS[col],
        "diffuse_reflectance": list(TILE_COLOURS[row][col]),
        "specular_reflectance": 1.0,
        "int_ior": lab.ACRYLIC_IOR,
        "ext_ior": lab.WATER_IOR,
        "nonlinear": False,
    }


mi = dr = None


def init(jobs):
    global mi, dr
    lab.init_mitsuba(VARIANT, jobs)
    mi, dr = lab.mi, lab.dr


def _spectrum(v):
    if isinstance(v, (list, tuple)):
        return {"type": "rgb", "value": [float(c) for c in v]}
    return {"type": "uniform", "value": float(v)}


def bsdf_dict(p):
    if p["type"] == "diffuse":
        return {"type": "diffuse", "reflectance": _spectrum(p["reflectance"])}
    return {
        "type": "roughplastic",
        "distribution": p["distribution"],
        "alpha": p["alpha"],
        "int_ior": p["int_ior"],
        "ext_ior": p["ext_ior"],
        "nonlinear": p["nonlinear"],
        "diffuse_reflectance": _spectrum(p["diffuse_reflectance"]),
        "specular_reflectance": _spectrum(p["specular_reflectance"]),
    }


def medium_dict(medium, r_c):
    m = MEDIA[medium]
    return {
        "type": "homogeneous",
        "sigma_t": _spectrum([t / r_c for t in m["tau"]]),
        "albedo": _spectrum(m["albedo"]),
        "phase": {"type": "hg", "g": m["g"]},
    }


def scene_dict(plate, medium, half_width=lab.HALF_WIDTH, r_c=lab.R_C, tiles=None):
    """render_lab's scene with an RGB plate (or a plate of tiles) and an RGB medium.

    tiles: {name: (centre x, centre y, half-width, plate dict)} replaces the one plate."""
    d = lab.scene_dict("black", "water", half_width, r_c)  # integrator, light, plate, no medium
    if tiles is None:
        d["plate"]["bsdf"] = bsdf_dict(plate)
    else:
        del d["plate"]
        T = mi.ScalarTransform4f
        for name, (cx, cy, hw, p) in tiles.items():
            d[name] = {
                "type": "rectangle",
                "bsdf": bsdf_dict(p),
                "to_world": T().translate([cx, cy, 0.0]).scale([hw, hw, 1.0]),
            }
    if medium != "water":
        # render_lab's wall and caps around this medium
        walls = lab.scene_dict("black", "m10", half_width, r_c)
        for k in ("wall", "cap_plus", "cap_minus"):
            d[k] = walls[k]
        d["medium"] = medium_dict(medium, r_c)
    return d


class Renderer(lab.Renderer):
    """render_lab's Renderer with three channels per sample and rays of any origin."""

    def __init__(self, scene):
        self.r_c = lab.R_C
        self.scene = mi.load_dict(scene)
        self.integrator = self.scene.integrator()
        self.params = mi.traverse(self.scene)
        self.sampler = mi.load_dict({"type": "independent"})

    def trace(self, origins, directions, seed):
        """One sample per ray: (3, n) float64 radiance."""
        o = [mi.Float(np.ascontiguousarray(origins[:, k], dtype=np.float32)) for k in range(3)]
        d = [mi.Float(np.ascontiguousarray(directions[:, k], dtype=np.float32)) for k in range(3)]
        ray = mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))
        return self._sample(ray, seed, len(origins))

    def _sample(self, ray, seed, n):
        """(3, n) float64: one evaluation for the three channels (evaluating each channel
        on its own would trace the paths three times), the seed opaque so that one compiled
        kernel serves every configuration and pass."""
        self.sampler.seed(dr.opaque(mi.UInt32, seed), n)
        spec, _, _ = self.integrator.sample(self.scene, self.sampler, ray, None, True)
        dr.eval(spec)
        return np.stack([np.asarray(spec[c], dtype=np.float64) for c in range(3)])

    def samples(self, theta_i, theta_r, n, seed):
        to_light, R = lab.directions(theta_i, theta_r)
        self.set_light(to_light)
        o = R * (self.r_c + lab.METER_GAP)
        ray = mi.Ray3f(
            mi.Point3f(*[dr.opaque(mi.Float, float(c)) for c in o]),
            mi.Vector3f(*[dr.opaque(mi.Float, float(-c)) for c in R]),
        )
        return self._sample(ray, seed, n)

    def config(self, theta_i, theta_r, passes, spp, seed_key):
        means = []
        for p in range(passes):
            seed = zlib.crc32(f"{seed_key}|{theta_i:.6f}|{theta_r:.6f}|{p}".encode())
            means.append(self.samples(theta_i, theta_r, spp, seed).mean(axis=1))
        means = np.array(means)  # (passes, 3)
        sigma = means.std(axis=0, ddof=1) / math.sqrt(passes)
        return means.mean(axis=0), sigma


# ---- goniometer sessions -------------------------------------------------------------------


def session_row(name, spp, passes, seconds):
    s = SESSIONS[name]
    med = s["medium"]

    def per(vals):
        return ";".join(lab.fmt(v) for v in vals)

    water = med == "water"
    return {
        "file": f"{name}.csv",
        "object": f"rgb_{s['object']}",
        "medium": med,
        "plate_width_cm": lab.fmt(2 * lab.HALF_WIDTH),
        "path_length_cm": lab.fmt(lab.R_C),
        "tau_per_pass": "0.0" if water else per(MEDIA[med]["tau"]),
        "sigma_t_per_cm": "0.0" if water else per([t / lab.R_C for t in MEDIA[med]["tau"]]),
        "g": "" if water else lab.fmt(MEDIA[med]["g"]),
        "albedo": "" if water else per(MEDIA[med]["albedo"]),
        "spp": passes * spp,
        "passes": passes,
        "seconds": f"{seconds:.1f}",
    }


def render_session(name, out, passes, spp, configs, log):
    s = SESSIONS[name]
    r = Renderer(scene_dict(PLATES[s["object"]], s["medium"]))
    t0 = time.time()
    rows = []
    for k, (psi, rho, ti, tr) in enumerate(configs):
        v, e = r.config(ti, tr, passes, spp, name)
        rows.append((psi, rho, ti, tr, v, e))
        if (k + 1) % 20 == 0 or k + 1 == len(configs):
            log(f"  {name}: {k + 1}/{len(configs)} configurations, {time.time() - t0:.0f} s")
    lines = ["psi,rho,theta_i,theta_r,channel,value,sigma"]
    for c, ch in enumerate(CHANNELS):  # channel after channel
        for psi, rho, ti, tr, v, e in rows:
            lines.append(
                ",".join(
                    [
                        lab.fmt(psi),
                        lab.fmt(rho),
                        lab.fmt(ti),
                        lab.fmt(tr),
                        ch,
                        lab.fmt(v[c]),
                        lab.fmt(e[c]),
                    ]
                )
            )
    lab.write_atomic(os.path.join(out, f"{name}.csv"), "\n".join(lines) + "\n")
    return session_row(name, spp, passes, time.time() - t0)


def update_index(out, rows):
    """Add or replace rows of data/sessions.csv, keeping the others and their order."""
    path = os.path.join(out, "sessions.csv")
    head, recs = lab.INDEX_COLUMNS, {}
    if os.path.exists(path):
        with open(path) as f:
            lines = f.read().splitlines()
        head = lines[0].split(",")
        for ln in lines[1:]:
            if ln.strip():
                rec = dict(zip(head, ln.split(",")))
                recs[rec["file"]] = rec
    for r in rows:
        recs[r["file"]] = {k: str(r[k]) for k in lab.INDEX_COLUMNS}
    text = (
        ",".join(lab.INDEX_COLUMNS)
        + "\n"
        + "".join(",".join(r.get(k, "") for k in lab.INDEX_COLUMNS) + "\n" for r in recs.values())
    )
    lab.write_atomic(path, text)


def truth():
    return {
        "mitsuba": {
            "version": mi.__version__,
            "drjit": dr.__version__,
            "variant": VARIANT,
            "integrator": {"type": "volpath", "max_depth": lab.MAX_DEPTH, "rr_depth": lab.RR_DEPTH},
            "sampler": "independent",
        },
        "channels": list(CHANNELS),
        "path_length_cm": lab.R_C,
        "plate_half_width_cm": lab.HALF_WIDTH,
        "geometry": "render_lab.py's (validation/README.md 'The scene'): plate half-width "
        f"{lab.HALF_WIDTH} cm, cylinder radius {lab.R_C} cm",
        "plates": {
            k: dict(p, relative_index=p["int_ior"] / p["ext_ior"])
            if p["type"] == "roughplastic"
            else dict(p)
            for k, p in PLATES.items()
        },
        "media": {
            k: dict(
                m,
                phase="hg",
                sigma_t_per_cm=[t / lab.R_C for t in m["tau"]],
                note="sigma_t = tau / R_c per channel: tau is the optical depth of ONE pass",
            )
            for k, m in MEDIA.items()
        },
        "sessions": {n: dict(file=f"{n}.csv", **s) for n, s in SESSIONS.items()},
    }


def check_bsdf(out):
    """Clear-water sessions against bsdf.eval per channel (render_lab's check 1)."""
    res = {}
    for obj in ("ref", "target"):
        path = os.path.join(out, f"rgb_water_{obj}.csv")
        if not os.path.exists(path):
            continue
        import pandas as pd

        t = pd.read_csv(path)
        bsdf = mi.load_dict(bsdf_dict(PLATES[obj]))
        rel = []
        for _, row in t.iterrows():
            to_light, R = lab.directions(row["theta_i"], row["theta_r"])
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            si.n = mi.Normal3f(0, 0, 1)
            si.wi = mi.Vector3f(*[float(c) for c in R])
            val = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*[float(c) for c in to_light]))
            ev = float(np.asarray(val[CHANNELS.index(row["channel"])]).ravel()[0])
            rel.append(abs(row["value"] / ev - 1))
        res[obj] = {"n": len(rel), "max_rel_diff": float(max(rel))}
    return res


def noise_rows(out):
    """Per medium session and channel: the relative standard error of the values (median,
    at |rho| <= 3 deg, largest)."""
    import pandas as pd

    rows = []
    for name, s in SESSIONS.items():
        path = os.path.join(out, f"{name}.csv")
        if s["medium"] == "water" or not os.path.exists(path):
            continue
        t = pd.read_csv(path)
        for ch in CHANNELS:
            u = t[t["channel"] == ch]
            rel = u["sigma"] / u["value"]
            rows.append(
                {
                    "session": name,
                    "channel": ch,
                    "median": float(rel.median()),
                    "near_peak_median": float(rel[u["rho"].abs() <= 3].median()),
                    "max": float(rel.max()),
                }
            )
    return rows


def noise_table(rows):
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks"))
    from doc_tables import markdown

    return markdown(
        ["session", "channel", "median relative se", "median, abs(rho) <= 3 deg", "largest"],
        [
            [
                f"`{r['session']}.csv`",
                r["channel"],
                f"{100 * r['median']:.2f} %",
                f"{100 * r['near_peak_median']:.2f} %",
                f"{100 * r['max']:.2f} %",
            ]
            for r in rows
        ],
        {2, 3, 4},
    )


# ---- the photo stack ----------------------------------------------------------------------


def stack_geometry(size=STACK_SIZE, half_width=lab.HALF_WIDTH):
    """Pixel pitch and the plate point of every pixel, row-major (docs/maps-geometry.md):
    p = ((x + 1/2 - cx) P, -(y + 1/2 - cy) P, 0), cx = cy = size / 2."""
    P = 2 * half_width / size
    y, x = np.mgrid[0:size, 0:size]
    c = size / 2
    p = np.stack([(x + 0.5 - c) * P, -(y + 0.5 - c) * P, np.zeros_like(x, dtype=float)], axis=-1)
    return P, p.reshape(-1, 3).astype(np.float64)


#: The control stack (--stack --uniform): every tile of this one material (tile (2, 1)'s), so
#: that the medium's blur across tiles has nothing to mix.
UNIFORM_TILE = (2, 1)


def _tile_of(row, col, uniform):
    return UNIFORM_TILE if uniform else (row, col)


def stack_tiles(half_width=lab.HALF_WIDTH, uniform=False):
    w = 2 * half_width / STACK_TILES
    tiles = {}
    for row in range(STACK_TILES):
        for col in range(STACK_TILES):
            cx = -half_width + (col + 0.5) * w
            cy = half_width - (row + 0.5) * w
            tiles[f"tile_{row}_{col}"] = (cx, cy, w / 2, tile_plate(*_tile_of(row, col, uniform)))
    return tiles


def stack_truth_maps(size=STACK_SIZE, uniform=False):
    """Per pixel: rho (3, H, W), alpha (H, W), the tile index (H, W)."""
    per = size // STACK_TILES
    rho = np.zeros((3, size, size))
    alpha = np.zeros((size, size))
    tile = np.zeros((size, size), dtype=int)
    for y in range(size):
        for x in range(size):
            row, col = _tile_of(y // per, x // per, uniform)
            rho[:, y, x] = TILE_COLOURS[row][col]
            alpha[y, x] = TILE_ALPHAS[col]
            tile[y, x] = (y // per) * STACK_TILES + x // per
    return rho, alpha, tile


def stack_configs(psis=STACK_PSI):
    return lab.protocol(psis)


def render_stack(out, passes, spp, psis, log, medium="cw", uniform=False):
    import tifffile

    folder = os.path.join(out, STACK_DIR + ("_uniform" if uniform else ""))
    os.makedirs(os.path.join(folder, "photos"), exist_ok=True)
    os.makedirs(os.path.join(folder, "black"), exist_ok=True)
    P, pts = stack_geometry()
    n = len(pts)
    configs = stack_configs(psis)
    objs = {
        "photos": Renderer(scene_dict(None, medium, tiles=stack_tiles(uniform=uniform))),
        "black": Renderer(scene_dict(PLATES["black"], medium)),
    }
    t0 = time.time()
    rel_se = []
    manifest = ["file,psi,rho"]
    for k, (psi, rho, ti, tr) in enumerate(configs):
        to_light, R = lab.directions(ti, tr)
        C = R * STACK_DISTANCE  # the pinhole of this configuration
        d = pts - C
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        fname = f"psi{int(psi):02d}_rho{int(rho):+03d}.tif"
        imgs, ses = {}, {}
        for what, r in objs.items():
            r.set_light(to_light)
            means = np.zeros((passes, 3, n))
            for p in range(passes):
                for c0 in range(0, n, STACK_CHUNK):  # STACK_CHUNK pixels, spp rays each
                    m = min(n - c0, STACK_CHUNK)
                    seed = zlib.crc32(f"{STACK_DIR}|{what}|{ti:.6f}|{tr:.6f}|{p}|{c0}".encode())
                    v = r.trace(
                        np.repeat(C[None, :], m * spp, axis=0),
                        np.repeat(d[c0 : c0 + m], spp, axis=0),
                        seed,
                    )  # (3, m * spp)
                    means[p, :, c0 : c0 + m] = v.reshape(3, m, spp).mean(axis=2)
            img = means.mean(axis=0)  # (3, n)
            imgs[what] = img
            ses[what] = means.std(axis=0, ddof=1) / math.sqrt(passes)
            # (H, W, 3) linear float32: row y of the image is plate y = +(c - y - 1/2) P
            arr = img.T.reshape(STACK_SIZE, STACK_SIZE, 3).astype(np.float32)
            tmp = os.path.join(folder, what, ".tmp-" + fname)
            tifffile.imwrite(tmp, arr, photometric="rgb")
            os.replace(tmp, os.path.join(folder, what, fname))
        # the relative standard error of a pixel's value after the black photo's subtraction
        rel_se.append(np.hypot(ses["photos"], ses["black"]) / (imgs["photos"] - imgs["black"]))
        manifest.append(f"{fname},{lab.fmt(psi)},{lab.fmt(rho)}")  # relative to photos/
        log(f"  stack {k + 1}/{len(configs)} (psi {psi}, rho {rho}): {time.time() - t0:.0f} s")
    lab.write_atomic(os.path.join(folder, "manifest.csv"), "\n".join(manifest) + "\n")
    rel_se = np.array(rel_se)  # (configs, 3, n)
    rho_t, alpha_t, tile = stack_truth_maps(uniform=uniform)
    tr = {
        "size": STACK_SIZE,
        "tiles": STACK_TILES,
        "uniform": uniform,
        "pixel_pitch_cm": P,
        "camera_distance_cm": STACK_DISTANCE,
        "plate_half_width_cm": lab.HALF_WIDTH,
        "path_length_cm": lab.R_C,
        "medium": dict(MEDIA[medium], name=medium),
        "optical_centre": [STACK_SIZE / 2, STACK_SIZE / 2],
        "brdf_model": "rough-plastic (Beckmann)",
        "eta": lab.ACRYLIC_IOR / lab.WATER_IOR,
        "ks": 1.0,
        "tile_alphas_by_column": list(TILE_ALPHAS),
        "tile_colours_by_row_column": [[list(c) for c in row] for row in TILE_COLOURS],
        "alpha": alpha_t.tolist(),
        "rho": {ch: rho_t[c].tolist() for c, ch in enumerate(CHANNELS)},
        "tile": tile.tolist(),
        "render": {
            "variant": VARIANT,
            "passes": passes,
            "spp_per_pass": spp,
            "spp_per_pixel": passes * spp,
            "psi": list(psis),
            "configurations": len(configs),
            "seconds": round(time.time() - t0, 1),
            "relative_standard_error_after_black": {
                ch: {
                    "median": float(np.median(rel_se[:, c])),
                    "p95": float(np.percentile(rel_se[:, c], 95)),
                }
                for c, ch in enumerate(CHANNELS)
            }
            | {
                "all": {"median": float(np.median(rel_se)), "p95": float(np.percentile(rel_se, 95))}
            },
            "black_photos": "black/ (same names): the black cloth through the same water "
            "at the same pixel rays",
        },
    }
    lab.write_atomic(os.path.join(folder, "truth.json"), json.dumps(tr, indent=1) + "\n")
    log(f"stack: {len(configs)} configurations in {time.time() - t0:.0f} s -> {folder}")
    return tr


def main(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", default=None, help="output folder (default validation/data)")
    ap.add_argument(
        "--sessions", default=None, help="comma-separated (default all): " + ", ".join(SESSIONS)
    )
    ap.add_argument("--stack", action="store_true", help="render the photo stack instead")
    ap.add_argument(
        "--uniform",
        action="store_true",
        help="with --stack: the control stack, every tile of one material, into "
        "data/rgb_stack_uniform",
    )
    ap.add_argument("--stack-psi", default=",".join(str(int(p)) for p in STACK_PSI))
    ap.add_argument("--passes", type=int, default=None)
    ap.add_argument(
        "--spp", type=int, default=None, help="samples per pass (per pixel for --stack)"
    )
    ap.add_argument("--jobs", type=int, default=2, help="Dr.Jit worker threads (default 2)")
    ap.add_argument(
        "--quick", action="store_true", help="psi 60, few samples, into /tmp unless --out"
    )
    ap.add_argument("--checks", action="store_true", help="clear-water tables against bsdf.eval")
    ap.add_argument(
        "--doc",
        default=None,
        metavar="PAGE",
        help="with --checks: write the noise table into PAGE between its markers "
        "<!-- table:rgb-noise ... --> (benchmarks/doc_tables.py)",
    )
    ap.add_argument("--truth-only", action="store_true", help="only write data/truth_rgb.json")
    a = ap.parse_args(argv)
    here = os.path.dirname(os.path.abspath(__file__))
    out = a.out or (
        os.path.join(tempfile.gettempdir(), "veil-rgb-quick")
        if a.quick
        else os.path.join(here, "data")
    )
    os.makedirs(out, exist_ok=True)
    init(a.jobs)

    def log(msg):
        print(msg, flush=True)

    if a.checks:
        res = {"bsdf_eval_vs_clear_water": check_bsdf(out), "relative_sigma": noise_rows(out)}
        lab.write_atomic(os.path.join(out, "checks_rgb.json"), json.dumps(res, indent=1) + "\n")
        text = noise_table(res["relative_sigma"])
        log(json.dumps(res["bsdf_eval_vs_clear_water"]) + "\n\n" + text)
        if a.doc:
            from doc_tables import write

            checks = "; ".join(
                f"`{o}` {v['max_rel_diff']:.1e}" for o, v in res["bsdf_eval_vs_clear_water"].items()
            )
            write(
                a.doc,
                "rgb-noise",
                f"Clear water against bsdf.eval, largest relative "
                f"difference over the 333 values: {checks}.\n\n" + text,
            )
        return 0
    if a.stack:
        psis = tuple(float(p) for p in a.stack_psi.split(","))
        if a.quick:
            psis = (60.0,)
        render_stack(
            out,
            a.passes or (2 if a.quick else STACK_PASSES),
            a.spp or (16 if a.quick else STACK_SPP_PER_PASS),
            psis,
            log,
            uniform=a.uniform,
        )
        return 0
    lab.write_atomic(os.path.join(out, "truth_rgb.json"), json.dumps(truth(), indent=1) + "\n")
    if a.truth_only:
        return 0
    names = list(SESSIONS) if not a.sessions else [x.strip() for x in a.sessions.split(",")]
    bad = [x for x in names if x not in SESSIONS]
    if bad:
        ap.error(f"unknown sessions: {', '.join(bad)}")
    configs = lab.protocol((60.0,) if a.quick else (30.0, 60.0, 90.0))
    for name in names:
        med = SESSIONS[name]["medium"]
        passes = a.passes or (4 if a.quick else PASSES)
        spp = a.spp or (min(256, SPP_PER_PASS[med]) if a.quick else SPP_PER_PASS[med])
        log(f"session {name}: {len(configs)} configurations x {passes} passes x {spp} samples")
        row = render_session(name, out, passes, spp, configs, log)
        update_index(out, [row])
        log(f"  wrote {row['file']} in {row['seconds']} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
