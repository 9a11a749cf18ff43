"""Benchmark of the joint fit (veil.fit_joint, docs/ambiguity.md; docs/performance-fitting.md "Joint fit").

Three media sessions of about 120 configurations each (the paper's protocol, psi 30/60/90,
with a 12 deg dense window): BRDF1 through BTDF1, BTDF2 and BTDF3, 1 % noise; the target's
four parameters, each medium's Td, Tt, g and a shared eta_u are fitted (the scale fixed by
Td of the first medium). Per accuracy, with a persistent JAX compilation cache in a new
temporary directory (VEIL_CACHE_DIR): "first run" is a fresh process with that cache empty
(the fit including every engine compilation it triggers; imports and the simulation of the
sessions not timed), "fresh process" a second process that finds the executables in the
cache, "warm" a second fit in a process that has compiled everything. Target: at most 30 s.

    .venv/bin/python benchmarks/bench_joint.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

PROTOCOL = dict(psi=(30, 60, 90), window=12.0)
MEDIA = ("BTDF1", "BTDF2", "BTDF3")


def sessions():
    import veil

    return {m: veil.simulate(veil.BRDF1, m, noise=0.01, seed=k, glow=0.0, accuracy="default",
                             **PROTOCOL)
            for k, m in enumerate(MEDIA)}


def one_fit(tables, accuracy):
    import veil

    t0 = time.perf_counter()
    r = veil.fit_joint(tables, fixed={"Td[BTDF1]": 1e-3}, accuracy=accuracy)
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "converged": r.converged, "n": r.params["n"],
            "n_se": r.stderr["n"], "nfev": r.stats["nfev"], "njev": r.stats["njev"],
            "starts": r.stats["starts"], "points": r.n_points, "free": len(r.free),
            "chi2": r.chi2_reduced}


def cold(accuracy):
    """Fresh process: import, simulate (not timed), fit (timed with its compilations)."""
    t0 = time.perf_counter()
    import veil  # noqa: F401
    t_import = time.perf_counter() - t0
    tables = sessions()
    out = one_fit(tables, accuracy)
    out["import"] = t_import
    print(json.dumps(out))


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--cold":
        cold(sys.argv[2])
        return
    import argparse

    from doc_tables import add_options, printed_tables
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_options(parser, "joint")
    doc = printed_tables(parser.parse_args()).start()
    rows = []
    for accuracy in ("fast", "default"):
        with tempfile.TemporaryDirectory(prefix="bench-joint-jax-cache-") as cache:
            env = {**os.environ, "VEIL_CACHE_DIR": cache}
            for kind in ("first run", "fresh process"):
                proc = subprocess.run([sys.executable, __file__, "--cold", accuracy], env=env,
                                      capture_output=True, text=True, check=True)
                rows.append((kind, accuracy, json.loads(proc.stdout.strip().splitlines()[-1])))
    tables = sessions()
    for accuracy in ("fast", "default"):
        one_fit(tables, accuracy)  # warm-up: every compilation of this accuracy
        rows.append(("warm", accuracy, one_fit(tables, accuracy)))
    sizes = "+".join(str(len(t)) for t in tables.values())
    print(f"joint fit benchmark: BRDF1 through {', '.join(MEDIA)}, {sizes} configurations, "
          f"1 % noise, {os.cpu_count()} cores")
    print()
    print("| run | accuracy | points | free params | starts | function / Jacobian evals "
          "| seconds | n +/- stderr | converged |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|")
    for kind, accuracy, r in rows:
        print(f"| {kind} | {accuracy} | {r['points']} | {r['free']} | {r['starts']} "
              f"| {r['nfev']} / {r['njev']} | {r['seconds']:.1f} "
              f"| {r['n']:.4f} +/- {r['n_se']:.4f} | {'yes' if r['converged'] else 'NO'} |")
    doc.finish()


if __name__ == "__main__":
    main()
