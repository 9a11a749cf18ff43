"""Per-order Monte Carlo of the lab set-up's medium (validation/README.md), independent of veil:
numpy, seeded. Measures, order by order, what the forward series (docs/model.md 8.1) assumes.

Light side: adjoint paths from the plate centre (first direction d0 from a proposal q about I),
free-flight sampling in the cylinder (radius R_c about the y axis, |y| <= L), next-event
estimation to the directional light at every vertex (transmittance to the wall along I, the
plate's shadow), the plate (z = 0, |x|, |y| <= a) ends a path that meets it. Gives the incident
radiance L_k(I, d0) at the centre per order k, integrated against test functions.

View side: adjoint paths from the wall point R_c R along -R (the camera's ray), free-flight
sampling, HG scattering; a path that meets the plate's front at Q along d is tallied as order k
with R' = -d (the plate's outgoing direction). Gives the view kernel K_k(R'), to compare with
e^{-tau} (omega tau)^k / k! p(g^k; R'.R) J_v(R', R).

    python validation/mc_orders.py [--n 2000000] [--media m05,m10,m15,m10_w10,m10_r10]
"""
import argparse
import math
import time

import numpy as np

CASES = {  # name: tau per pass, g, R_c, a
    "m01": (0.1, 0.97, 15.0, 2.5), "m05": (0.5, 0.92, 15.0, 2.5), "m10": (1.0, 0.88, 15.0, 2.5),
    "m15": (1.5, 0.85, 15.0, 2.5), "m10_w10": (1.0, 0.88, 15.0, 5.0),
    "m10_r10": (1.0, 0.88, 10.0, 2.5),
}
OMEGA = 0.99
L_CYL = 30.0
KMAX = 12


def path_factors(tau, g, kmax=KMAX):
    """M_k of docs/physics-orders.md sec. 8 (numpy; veil.models.forward_series.path_factors)."""
    k = np.arange(1, kmax + 1, dtype=float)
    om = 1 - g ** k
    a = np.cumsum(om)
    b = a - np.cumsum(k * om) / (k + 1)
    return np.exp(a * (1 - tau / (k + 1)) - b * (1 - tau / (k + 2)))


def hg_pdf(g, cos):
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5)


def hg_cos(g, u):
    if abs(g) < 1e-6:
        return 1 - 2 * u
    s = (1 - g * g) / (1 - g + 2 * g * u)
    return np.clip((1 + g * g - s * s) / (2 * g), -1, 1)


def around(d, cos, phi):
    """Directions at angle acos(cos), azimuth phi about the unit vectors d (n, 3)."""
    sin = np.sqrt(np.maximum(0, 1 - cos * cos))
    a = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(d, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(d, t1)
    return (cos[:, None] * d + (sin * np.cos(phi))[:, None] * t1
            + (sin * np.sin(phi))[:, None] * t2)


def exit_distance(x, d, rc):
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (x[:, 0] * d[:, 0] + x[:, 2] * d[:, 2])
    c = x[:, 0] ** 2 + x[:, 2] ** 2 - rc * rc
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(a > 1e-15, (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0))) / (2 * a), np.inf)
        tc = np.where(np.abs(d[:, 1]) > 1e-15, (np.sign(d[:, 1]) * L_CYL - x[:, 1]) / d[:, 1], np.inf)
    return np.minimum(t, tc)


def plate_distance(x, d, a, front_only=None):
    """Distance along d to the plate square (inf if missed); front_only: +1 (from above)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(d[:, 2]) > 1e-15, -x[:, 2] / d[:, 2], np.inf)
    t = np.where(t > 1e-9, t, np.inf)
    tf = np.where(np.isfinite(t), t, 0.0)
    px = x[:, 0] + tf * d[:, 0]
    py = x[:, 1] + tf * d[:, 1]
    hit = (np.abs(px) <= a) & (np.abs(py) <= a) & np.isfinite(t)
    return np.where(hit, t, np.inf)


def light_side(tau, g, rc, a, theta_i, n, rng, plate=True):
    """Per order k = 1..KMAX: MC and model integrals of L_k(I, d) h(d) over d, h in
    {1, d_z+, 1(d_z>0), I.d}. Returns dict of arrays (KMAX, nh)."""
    sig = tau / rc
    I = np.array([-math.sin(math.radians(theta_i)), 0.0, math.cos(math.radians(theta_i))])
    # proposal: 0.1 uniform + 0.9 mixture of HG(g^m), m = 1..8, about I
    ms = np.arange(1, 9)
    comp = rng.integers(-1, len(ms), n)
    u1, u2 = rng.random(n), rng.random(n)
    cos = np.where(comp < 0, 1 - 2 * u1, 0.0)
    for j, m in enumerate(ms):
        sel = comp == j
        cos[sel] = hg_cos(g ** m, u1[sel])
    d0 = around(np.tile(I, (n, 1)), cos, 2 * np.pi * u2)
    cg = d0 @ I
    q = 0.1 / (4 * np.pi) + 0.9 * np.mean([hg_pdf(g ** m, cg) for m in ms], axis=0)
    hs = np.stack([np.ones(n), np.maximum(d0[:, 2], 0), (d0[:, 2] > 0) * 1.0, cg], axis=1)
    if plate:
        hs = hs * (d0[:, 2] > 0)[:, None]
    contrib = np.zeros((KMAX, n))
    x = np.zeros((n, 3))
    d = d0.copy()
    w = np.ones(n)
    alive = np.ones(n, bool) if not plate else d0[:, 2] > 0
    idx = np.arange(n)
    for k in range(1, KMAX + 1):
        ii = idx[alive]
        xs, ds = x[ii], d[ii]
        s = rng.exponential(1.0 / sig, len(ii))
        lim = exit_distance(xs, ds, rc)
        if plate:
            lim = np.minimum(lim, plate_distance(xs, ds, a))
        ok = s < lim
        alive[ii[~ok]] = False
        ii, xs, ds, s = ii[ok], xs[ok], ds[ok], s[ok]
        xs = xs + s[:, None] * ds
        w[ii] *= OMEGA
        # NEE towards the light along +I
        tl = exit_distance(xs, np.tile(I, (len(ii), 1)), rc)
        tr = np.exp(-sig * tl)
        if plate:
            blocked = np.isfinite(plate_distance(xs, np.tile(I, (len(ii), 1)), a))
            tr = np.where(blocked, 0.0, tr)
        contrib[k - 1, ii] = w[ii] * hg_pdf(g, ds @ I) * tr
        # next direction
        cs = hg_cos(g, rng.random(len(ii)))
        ds = around(ds, cs, 2 * np.pi * rng.random(len(ii)))
        x[ii], d[ii] = xs, ds
    ks = np.arange(1, KMAX + 1)
    pois = np.exp(-tau) * (OMEGA * tau) ** ks / np.array([math.factorial(k) for k in ks])
    model = pois[:, None] * np.stack([hg_pdf(g ** k, cg) for k in ks])
    mc = (contrib / q) @ hs / n
    mo = (model / q) @ hs / n
    mc2 = ((contrib / q) ** 2) @ (hs ** 2) / n
    se = np.sqrt(np.maximum(mc2 - mc ** 2, 0) / n)
    return mc, mo, se


def jv(tau, rc, a, rp, r):
    sig = tau / rc
    mu_p = np.maximum(rp[:, 2], 1e-12)
    ratio = r[2] / mu_p
    beta = sig * (ratio - 1)
    vx = r[0] - ratio * rp[:, 0]
    vy = r[1] - ratio * rp[:, 1]
    m = np.maximum(np.abs(vx), np.abs(vy))
    S = np.minimum(rc, a / np.maximum(m, a / rc))
    xx = beta * S
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(np.abs(xx) < 1e-8, 1 - xx / 2, -np.expm1(-xx) / xx)
    return S / rc * f


def view_paths(tau, g, rc, a, R, n, rng):
    """Per order k = 0..KMAX, yield (R', weights) of the adjoint paths from the camera's wall
    point R_c R along -R that meet the plate's front at that order (R' = the plate's
    outgoing direction)."""
    sig = tau / rc
    x = np.tile(R * rc * (1 - 1e-12), (n, 1))
    d = np.tile(-R, (n, 1))
    w = np.ones(n)
    alive = np.ones(n, bool)
    idx = np.arange(n)
    for _ in range(KMAX + 1):
        ii = idx[alive]
        xs, ds = x[ii], d[ii]
        s = rng.exponential(1.0 / sig, len(ii))
        te = exit_distance(xs, ds, rc)
        tp = plate_distance(xs, ds, a)
        front = ds[:, 2] < 0
        hitp = (tp < te) & (s >= tp) & front
        yield -ds[hitp], w[ii[hitp]]
        scat = s < np.minimum(te, tp)
        alive[ii[~scat]] = False
        ii, xs, ds, s = ii[scat], xs[scat], ds[scat], s[scat]
        xs = xs + s[:, None] * ds
        w[ii] *= OMEGA
        cs = hg_cos(g, rng.random(len(ii)))
        ds = around(ds, cs, 2 * np.pi * rng.random(len(ii)))
        x[ii], d[ii] = xs, ds


def model_directions(g, R, m, rng):
    """Per order k = 1..KMAX, yield (k, R' drawn from p(g^k) about R, R' above the plate):
    the samples of the model's view term e^{-tau} w_k Int p(g^k) J_v dR'."""
    for k in range(1, KMAX + 1):
        cs = hg_cos(g ** k, rng.random(m))
        rp = around(np.tile(R, (m, 1)), cs, 2 * np.pi * rng.random(m))
        yield k, rp, rp[:, 2] > 0


def view_side(tau, g, rc, a, theta_r, n, rng):
    """Per order k = 0..KMAX: MC tallies of K_k(R') h(R') (h in {1, R'.R, R'_z, cos to R > c})
    and the model's e^{-tau} w_k Int p(g^k) J_v h, and with J_v = 1."""
    R = np.array([math.sin(math.radians(theta_r)), 0.0, math.cos(math.radians(theta_r))])
    tally = np.zeros((KMAX + 1, 3))
    tally2 = np.zeros((KMAX + 1, 3))
    for k, (rp, w) in enumerate(view_paths(tau, g, rc, a, R, n, rng)):
        hh = np.stack([np.ones(len(rp)), rp @ R, rp[:, 2]], axis=1) * w[:, None]
        tally[k] += hh.sum(0)
        tally2[k] += (hh ** 2).sum(0)
    mc = tally / n
    se = np.sqrt(np.maximum(tally2 / n - mc ** 2, 0) / n)
    mo = np.zeros((KMAX + 1, 3))
    mo1 = np.zeros((KMAX + 1, 3))
    mo[0] = mo1[0] = np.exp(-tau) * np.array([1, 1, R[2]])
    for k, rp, up in model_directions(g, R, 400000, rng):
        h = np.stack([up * 1.0, (rp @ R) * up, rp[:, 2] * up], axis=1)
        wk = np.exp(-tau) * (OMEGA * tau) ** k / math.factorial(k)
        mo[k] = wk * (h * jv(tau, rc, a, rp, R)[:, None]).mean(0)
        mo1[k] = wk * h.mean(0)
    return mc, mo, mo1, se


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=2_000_000)
    ap.add_argument("--media", default="m05,m10,m15,m10_w10,m10_r10")
    ap.add_argument("--angles", default="0,40,70")
    ap.add_argument("--side", default="light,view")
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "benchmarks"))
    from doc_tables import add_options, markdown, write
    add_options(ap, "mc-orders")
    a = ap.parse_args()
    light_irr, view_all, view_orders = {}, {}, {}  # ratios MC / model, for --doc
    for med in a.media.split(","):
        tau, g, rc, hw = CASES[med]
        for th in [float(t) for t in a.angles.split(",")]:
            if "light" in a.side:
                t0 = time.time()
                rng = np.random.default_rng(1)
                mc, mo, se = light_side(tau, g, rc, hw, th, a.n, rng)
                print(f"LIGHT {med} theta_i={th:g} ({time.time()-t0:.0f}s) per order k: "
                      "MC/model of Int L_k [front], Int L_k mu [irradiance]; mean cos to I MC vs g^k")
                for k in range(6):
                    print(f"  k={k+1}: front {mc[k,2]:.4e}/{mo[k,2]:.4e} = {mc[k,2]/mo[k,2]:.3f}+-{se[k,2]/mo[k,2]:.3f}"
                          f"  irr {mc[k,1]/mo[k,1]:.3f}  gk {mc[k,3]/mc[k,0]:.4f} vs {mo[k,3]/mo[k,0]:.4f}")
                e0 = np.exp(-tau) * math.cos(math.radians(th))
                mk = path_factors(tau, g)
                print("  M_k (cylinder):", " ".join(f"{m:.3f}" for m in mk[:6]))
                print(f"  scattered irradiance, all orders: MC/cylinder = {mc[:, 1].sum() / (mk * mo[:, 1]).sum():.4f},"
                      f" front: {mc[:, 2].sum() / (mk * mo[:, 2]).sum():.4f}")
                light_irr.setdefault(med, []).append(f"{mc[:, 1].sum() / mo[:, 1].sum():.3f}")
                print(f"  scattered irradiance, all orders: MC/model = {mc[:, 1].sum() / mo[:, 1].sum():.4f}"
                      f" (+-{np.sqrt((se[:, 1]**2).sum()) / mo[:, 1].sum():.4f}); with the unscattered beam: "
                      f"{(mc[:, 1].sum() + e0) / (mo[:, 1].sum() + e0):.4f}")
            if "view" in a.side:
                t0 = time.time()
                rng = np.random.default_rng(2)
                mc, mo, mo1, se = view_side(tau, g, rc, hw, th, a.n, rng)
                print(f"VIEW {med} theta_r={th:g} ({time.time()-t0:.0f}s) per order k: "
                      "MC / model(J_v) / model(J_v=1) of Int K_k dR'; mean cos R'.R MC vs model")
                for k in range(7):
                    print(f"  k={k}: {mc[k,0]:.4e} / {mo[k,0]:.4e} / {mo1[k,0]:.4e}  ratio {mc[k,0]/mo[k,0]:.3f}+-{se[k,0]/mo[k,0]:.3f}"
                          f"  cos {mc[k,1]/max(mc[k,0],1e-30):.4f} vs {mo[k,1]/mo[k,0]:.4f}")
                print(f"  all orders: MC {mc[:,0].sum():.4f} model {mo[:,0].sum():.4f} ratio {mc[:,0].sum()/mo[:,0].sum():.4f}")
                view_all.setdefault(med, []).append(f"{mc[:, 0].sum() / mo[:, 0].sum():.4f}")
                view_orders.setdefault(med, {})[th] = " / ".join(
                    f"{mc[k, 0] / mo[k, 0]:.3f}" for k in (2, 3, 4))
    if a.doc:
        angles = a.angles.split(",")
        middle = float(angles[len(angles) // 2])
        write(a.doc, a.doc_table, markdown(
            ["case (tau, g)", f"light irr., theta_i {' / '.join(angles)}",
             f"view, theta_r {' / '.join(angles)}", f"view order 2 / 3 / 4 at theta_r = {middle:g}"],
            [[f"{med} ({CASES[med][0]:g}, {CASES[med][1]:g}"
              + (f", {2 * CASES[med][3]:g} cm plate" if CASES[med][3] != 2.5 else "")
              + (f", R_c {CASES[med][2]:g} cm" if CASES[med][2] != 15.0 else "") + ")",
              " / ".join(light_irr.get(med, [])),
              " / ".join(view_all.get(med, [])), view_orders.get(med, {}).get(middle, "-")]
             for med in a.media.split(",")]))
