"""Reference values of the apparent reflectance (docs/model.md sec. 5) from tests/reference.py.

The reference is independent of veil's engine (numpy/scipy, deterministic quadrature for all
low-dimensional pieces, multiple importance sampling on scrambled Sobol points for the
four-dimensional single-scattering x specular term). Writes a CSV with columns
brdf, medium, theta_i, phi_i, theta_r, phi_r, reference, stderr (degrees; stderr absolute),
atomically (temporary file + os.replace).

    .venv/bin/python benchmarks/make_reference.py BRDF1 BTDF1
    .venv/bin/python benchmarks/make_reference.py BRDF2 BTDF3 --configs my.csv --m 17 --reps 16
    .venv/bin/python benchmarks/make_reference.py BRDF1 BTDF2 --variant exit -o out.csv

Without --configs the built-in set is used: in-plane, theta_i in {0, 30, 45, 60, 75}, theta_r
at the mirror angle, 2 deg past it, and far off. A --configs CSV needs columns theta_i,
theta_r and optionally phi_i (default 180), phi_r (default 0).
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

import reference

COLUMNS = ["brdf", "medium", "theta_i", "phi_i", "theta_r", "phi_r", "reference", "stderr"]
FAR = {0.0: 30.0, 30.0: 60.0, 45.0: 10.0, 60.0: 25.0, 75.0: 40.0}


def builtin_configs():
    """(theta_i, phi_i, theta_r, phi_r): mirror, mirror + 2 deg, far off, per theta_i."""
    out = []
    for ti in (0.0, 30.0, 45.0, 60.0, 75.0):
        for tr in (ti, ti + 2.0, FAR[ti]):
            out.append((ti, 180.0, tr, 0.0))
    return out


def read_configs(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [(float(r["theta_i"]), float(r.get("phi_i") or 180.0), float(r["theta_r"]),
             float(r.get("phi_r") or 0.0)) for r in rows]


def write_atomic(path, rows):
    """The reference table as CSV, written through veil's atomic writer."""
    import io as _io

    from veil.io import write_text_atomic

    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([r[0], r[1]] + [repr(float(x)) for x in r[2:]])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, buf.getvalue())


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("brdf", help="BRDF preset (docs/model.md sec. 6), e.g. BRDF1")
    p.add_argument("medium", help="BTDF preset, e.g. BTDF3")
    p.add_argument("--configs", help="CSV with theta_i, theta_r[, phi_i, phi_r] (degrees)")
    p.add_argument("--m", type=int, default=16, help="2^m Sobol points per strategy and scramble")
    p.add_argument("--reps", type=int, default=16, help="independent scrambles (stderr)")
    p.add_argument("--variant", default="paper", choices=("paper", "exit"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", help="default benchmarks/data/reference_<brdf>_<medium>.csv")
    a = p.parse_args(argv)

    brdf, medium = a.brdf.upper(), a.medium.upper()
    configs = read_configs(a.configs) if a.configs else builtin_configs()
    suffix = "" if a.variant == "paper" else "_exit"
    out = a.output or HERE / "data" / f"reference_{brdf}_{medium}{suffix}.csv"

    t0 = time.perf_counter()
    reference._spec_tables(reference._params(brdf))  # one-off per BRDF, reported apart
    setup = time.perf_counter() - t0
    print(f"{brdf} x {medium} ({a.variant}): {len(configs)} configurations, 3 x 2^{a.m} x "
          f"{a.reps} samples each; setup {setup:.1f} s")
    rows, times = [], []
    for c in configs:
        t = time.perf_counter()
        val, err = reference.reference_apparent(brdf, medium, *c, variant=a.variant, m=a.m,
                                                n_rep=a.reps, seed=a.seed)
        times.append(time.perf_counter() - t)
        rows.append((brdf, medium, *c, val, err))
        print(f"  theta_i {c[0]:5.1f} phi_i {c[1]:5.1f} theta_r {c[2]:5.1f} phi_r {c[3]:5.1f}: "
              f"{val:.9g} +- {err:.2g} (rel {err / val:.1e}) {times[-1]:.1f} s", flush=True)
    write_atomic(out, rows)
    worst = max(r[-1] / r[-2] for r in rows)
    print(f"wrote {out}: total {time.perf_counter() - t0:.1f} s, mean {sum(times) / len(times):.1f}"
          f" s per configuration, worst relative stderr {worst:.1e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
