"""Tables of docs/physics.md and docs/physics-view-weighting.md computed by the independent
reference (tests/reference_physical.py; numpy/scipy, deterministic, a few seconds):

- ``fint``: the rough interface's internal reflectance F_int, exact and by Mitsuba 3's
  64-node rule, Beckmann and GGX at alpha 0.05 / 0.2 / 0.5, eta 1.5 and 1.12;
- ``plate-weight`` (Table J): the view weighting J_v of docs/model.md (8.1b) for the paper's
  5 x 5 cm plate in a 15 cm cylinder at tau 0.5 / 1 / 2, the infinite plate at tau 1, and the
  plate lit by a light at theta_i = 45 deg (phi 180) against the closed form; the largest
  difference between the closed form and direct integration is printed under it;
- ``view-term``: the view-side term of a rough plastic with J = 1, J_v and J_v with the light's
  path across the plate ("lit"), the light at each row's theta_i;
- ``mitsuba``: the reference's rough plastic against Mitsuba 3's roughplastic (needs
  ``import mitsuba``), each choice of Smith G1 and of the t(mu)/F_int numerics.

    PYTHONPATH=src python validation/physics_tables.py [--doc PAGE --doc-table NAMES]
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
import reference_physical as rp  # noqa: E402
from doc_tables import add_options, printed_tables  # noqa: E402

ROWS_J = [(0, -20), (0, -5), (0, 5), (0, 20), (30, 10), (30, 25), (30, 35), (30, 50),
          (60, 40), (60, 55), (60, 65), (60, 80), (80, 60), (80, 75), (80, 85)]


def fint_table() -> None:
    print("| distribution, alpha | F_int exact, eta = 1.5 | Mitsuba's rule | "
          "F_int exact, eta = 1.12 | Mitsuba's rule |")
    print("|---|---:|---:|---:|---:|")
    for dist, label in (("beckmann", "Beckmann"), ("ggx", "GGX")):
        for alpha in (0.05, 0.2, 0.5):
            cells = [f"{rp.internal_reflectance(alpha, eta, dist, rule=rule):.5f}"
                     for eta in (1.5, 1.12) for rule in ("exact", "mitsuba")]
            print(f"| {label} {alpha:g} | " + " | ".join(cells) + " |")


def plate_table(path_length: float = 15.0, half_width: float = 2.5) -> None:
    light = rp.direction(45.0, 180.0)
    worst = 0.0
    print("| theta_r | theta_R' | J tau=0.5 | J tau=1 | J tau=2 | J infinite plate, tau=1 "
          "| lit/closed - 1, tau = 0.5 / 1 / 2 |")
    print("|---:|---:|---:|---:|---:|---:|---|")
    for theta_r, theta_p in ROWS_J:
        R = rp.direction(theta_r, 0.0)
        Rp = rp.direction(abs(theta_p), 0.0 if theta_p >= 0 else 180.0)
        closed, lit = [], []
        for tau in (0.5, 1.0, 2.0):
            j = float(rp.plate_weight(Rp, R, tau, path_length, half_width))
            direct = rp.plate_weight_direct(Rp, R, tau, path_length, half_width)
            worst = max(worst, abs(direct / j - 1.0))
            closed.append(j)
            lit.append(rp.plate_weight_direct(Rp, R, tau, path_length, half_width, light=light)
                       / j - 1.0)
        infinite = float(rp.plate_weight(Rp, R, 1.0, path_length, None))
        print(f"| {theta_r} | {theta_p:+d} | " + " | ".join(f"{j:.4f}" for j in closed)
              + f" | {infinite:.4f} | " + " / ".join(f"{x:+.3f}" for x in lit) + " |")
    print(f"\nlargest |direct / closed - 1| over the rows: {worst:.1e}")


def view_term_table(path_length: float = 15.0, half_width: float = 2.5) -> None:
    """The view-side term Int f_r(I, X) J(X, R) L(X, R) dX (no boundary, eta_u = 1) of a GGX
    rough plastic (rho 0.5, alpha 0.1, eta 1.12, ks 1) through tau 1, omega 0.95, g 0.93, with
    J = 1, J_v's closed form, and J_v with the illumination path of the light at I across the
    plate ("lit")."""
    brdf = rp.make_rough_plastic(0.5, 0.1, 1.12, 1.0, "ggx")
    tau, omega, g = 1.0, 0.95, 0.93
    print("| theta_i | theta_r | view term, J_v = 1 | J_v closed | J_v lit | lit/closed - 1 |")
    print("|---:|---:|---:|---:|---:|---:|")
    for theta_i, theta_r in ((15, 15), (30, 30), (45, 45), (60, 0), (0, 60), (70, 10)):
        wi, R = rp.direction(theta_i, 180.0), rp.direction(theta_r, 0.0)
        weights = {
            "one": lambda X: np.ones(X.shape[:-1]),
            "closed": lambda X: rp.plate_weight(X, R, tau, path_length, half_width),
            "lit": lambda X: rp.plate_weight_lit(X, R, wi, tau, path_length, half_width)}
        out = []
        for weight in weights.values():
            def fn(X, weight=weight):
                return (brdf(np.broadcast_to(wi, X.shape), X) * weight(X)
                        * rp.scattered_lobe(tau, omega, g, x=1.0 - X @ R))
            value, _ = rp.sphere_integral(fn, [R, rp._mirror(wi)],
                                          [rp._lobe_scale(g), rp._brdf_scale(brdf)], rtol=1e-7)
            out.append(value)
        print(f"| {theta_i} | {theta_r} | " + " | ".join(f"{v:.5f}" for v in out)
              + f" | {out[2] / out[1] - 1:+.4f} |")


def mitsuba_table() -> None:
    """The reference's rough plastic (each choice of G1 and of the t/F_int numerics) against
    Mitsuba 3's roughplastic (scalar_rgb ``eval``: si.wi = R, wo = I, cos theta_I included):
    the largest relative difference where Mitsuba's float32 value is above 1e-6 of its peak."""
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    sweep = [(ti, tr, pr) for ti in (0, 20, 45, 70, 85) for tr in (0, 10, 30, 60, 80, 88)
             for pr in (0, 90, 170)]
    wi = rp.direction([s[0] for s in sweep], 180.0)
    wo = rp.direction([s[1] for s in sweep], [s[2] for s in sweep])
    ctx, rho, eta, ks = mi.BSDFContext(), 0.6, 1.5, 1.0
    combos = [("exact", "exact"), ("exact", "mitsuba"), ("rational", "exact"),
              ("rational", "mitsuba")]
    print("| | smith exact, tables exact | exact, mitsuba | rational, exact | rational, mitsuba |")
    print("|---|---:|---:|---:|---:|")
    for dist, label in (("beckmann", "Beckmann"), ("ggx", "GGX")):
        for nonlinear in (False, True):
            worst = [0.0] * len(combos)
            for alpha in (0.05, 0.2, 0.5):
                bsdf = mi.load_dict({"type": "roughplastic", "distribution": dist,
                                     "alpha": alpha, "int_ior": eta, "ext_ior": 1.0,
                                     "diffuse_reflectance": rho, "specular_reflectance": ks,
                                     "nonlinear": nonlinear})
                m = []
                for i, r in zip(wi, wo):
                    si = mi.SurfaceInteraction3f()
                    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
                    si.wi = mi.Vector3f(*map(float, r))
                    m.append(float(bsdf.eval(ctx, si, mi.Vector3f(*map(float, i)))[0]))
                m = np.asarray(m)
                ok = m > 1e-6 * m.max()
                for k, (smith, tables) in enumerate(combos):
                    ref = rp.rough_plastic_vec(wi, wo, rho, alpha, eta, ks, dist, nonlinear,
                                               smith, tables)
                    worst[k] = max(worst[k], float(np.max(np.abs(ref[ok] / m[ok] - 1.0))))
            print(f"| {label}, {'nonlinear' if nonlinear else 'linear'} | "
                  + " | ".join(f"{w:.1e}" for w in worst) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tables", default="fint,plate-weight,view-term,mitsuba",
                    help="which tables to compute, in this order")
    add_options(ap, "fint,plate-weight,view-term,mitsuba")
    args = ap.parse_args(argv)
    doc = printed_tables(args).start()
    for name in args.tables.split(","):
        {"fint": fint_table, "plate-weight": plate_table, "view-term": view_term_table,
         "mitsuba": mitsuba_table}[name]()
        print()
    doc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
