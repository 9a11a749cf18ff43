"""The table of docs/interop.md ("--verify"): exported models rendered by Mitsuba 3 against
veil's values, as ``veil export --to mitsuba --verify`` does it (veil.interop.verify), for four
exports:

- ``plastic``: rough-plastic rho 0.5, alpha 0.1, eta 1.5, ks 2 (a surface, 1 spp);
- ``conductor``: rough-conductor alpha 0.1, n 0.2, k 3, ks 3 (a surface, 1 spp);
- ``closest``: the paper's BRDF1 (Torrance-Sparrow), which Mitsuba has no plugin for, as the
  closest rough-plastic: the closest fit's own RMS difference (no render);
- ``medium``: the rough plastic above through forward-series tau 0.3, omega 0.99, g 0.9 in
  the cylinder of the set-up (path 15, 5 cm plate), path-traced (volpath, 4096 spp in 4
  passes; several minutes), and ``medium-psi60`` the same at psi 60 only with 32768 spp.

    PYTHONPATH=src python validation/interop_table.py [--rows plastic,conductor,closest,medium]
        [--doc docs/interop.md]
"""
import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
from doc_tables import add_options, printed_tables  # noqa: E402

PSI = (30.0, 60.0, 90.0)
MEDIUM_SPP, PASSES = 4096, 4  # as veil export --verify through a medium


def _pct(x: float) -> str:
    """A relative difference: in percent, or as a plain number where it is below 1e-4."""
    return f"{100 * x:.3g} %" if x >= 1e-4 else f"{x:.2g}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rows", default="plastic,conductor,closest,medium,medium-psi60")
    add_options(ap, "interop-verify")
    args = ap.parse_args(argv)
    doc = printed_tables(args).start()

    import veil
    from veil.data.protocol import protocol
    from veil.engine.apparent import apparent, reflectance
    from veil.interop.export import export
    from veil.interop.verify import verify
    from veil.models import REGISTRY
    from veil.models.renderers import Setting

    table = protocol(PSI, fine_step=2.0, coarse_step=10.0)
    configs = table[["theta_i", "theta_r", "phi_i", "phi_r"]].to_numpy()
    plastic = REGISTRY["rough-plastic"](rho=0.5, alpha=0.1, eta=1.5, ks=2.0)
    medium = REGISTRY["forward-series"](tau=0.3, omega=0.99, g=0.9, path_length=15.0,
                                        plate_width=5.0)
    psis = ", ".join(f"{p:g}" for p in PSI)
    rows = []
    for row in args.rows.split(","):
        if row in ("plastic", "conductor"):
            brdf = plastic if row == "plastic" else REGISTRY["rough-conductor"](
                alpha=0.1, n=0.2, k=3.0, ks=3.0)
            done = export([brdf], "mitsuba", None, Setting(), "")
            check = verify(done.text, done.scale, reflectance(brdf, *configs.T), configs, 1)
            used, n = int(check.used.sum()), len(configs)
            where = f"{n} (psi {psis}), 1 spp" if used == n else f"{used} of {n}"
            label = (f"rough-plastic rho 0.5, alpha 0.1, eta 1.5, ks 2" if row == "plastic"
                     else "rough-conductor alpha 0.1, n 0.2, k 3, ks 3")
            rows.append([label, where, _pct(check.rms_relative), _pct(check.max_relative)])
        elif row == "closest":
            done = export([veil.preset("BRDF1")], "mitsuba", None, Setting(), "")
            c = done.item("brdf").closest
            p = c.model
            rows.append([f"torrance-sparrow BRDF1 -> closest rough-plastic (rho {p.rho:.3g}, "
                         f"alpha {p.alpha:.3g}, eta {p.eta:.3g}, ks {p.ks:.4g})",
                         f"{c.n} in-plane, fit", _pct(c.rms_relative), _pct(c.max_relative)])
        elif row in ("medium", "medium-psi60"):
            here = configs if row == "medium" else protocol(
                (60.0,), fine_step=2.0, coarse_step=10.0)[
                ["theta_i", "theta_r", "phi_i", "phi_r"]].to_numpy()
            spp = MEDIUM_SPP if row == "medium" else 8 * MEDIUM_SPP
            done = export([plastic, medium], "mitsuba", None, Setting(), "")
            item = done.item("medium")
            geometry = item.plugin.geometry
            predicted = apparent(done.item("brdf").model, item.model, *here.T)
            check = verify(done.text, done.scale, predicted, here, spp,
                           passes=PASSES, medium={"path_length": geometry["path_length"],
                                                  "half_width": geometry["plate_half_width"],
                                                  "max_depth": 64})
            rows.append(["rough-plastic through forward-series tau 0.3, omega 0.99, g 0.9, "
                         "path 15, plate 5" if row == "medium" else "the same, psi 60 only",
                         f"{len(here)}, {spp} spp ({PASSES} passes), volpath",
                         f"{_pct(check.rms_relative)} (noise {_pct(check.rms_noise)})",
                         _pct(check.max_relative)])
        else:
            ap.error(f"--rows: unknown row {row!r}")
        print(f"  {row} done", file=sys.stderr, flush=True)
    print("| export | configurations | RMS | largest |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")
    doc.finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
