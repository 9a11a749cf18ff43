"""Forward error of the physical medium model (docs/model.md sec. 8.1) on the path-traced data: the
true plate (with Mitsuba's roughplastic numerics: rational G1, its t table and F_int rule) and
the true medium, evaluated by the independent reference tests/reference_physical.py (quasi
Monte Carlo), against every third configuration of the rendered session minus its black cloth.
No fit: what is left is the model's own error (docs/validity-orders.md).

    .venv/bin/python validation/forward_error.py [OBJECT] [plate|inf|none] [m01,m05,...] [--doc PAGE]

--doc PAGE writes the table of the media into PAGE's block <!-- table:forward-error ... -->
(--doc-table NAME another block; benchmarks/doc_tables.py).
"""
import json
import os
import sys
import time

import numpy as np
import pandas as pd

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
import reference_physical as rp  # noqa: E402

D = os.path.join(HERE, "data") + os.sep
with open(D + "truth.json") as f:
    truth = json.load(f)
sys.path.insert(0, os.path.join(HERE, "..", "benchmarks"))
from doc_tables import add_options, markdown, write  # noqa: E402
import argparse  # noqa: E402
_doc = argparse.ArgumentParser(add_help=False)
add_options(_doc, "forward-error")
_argv = list(sys.argv)
doc_args, sys.argv[1:] = _doc.parse_known_args()
obj = sys.argv[1] if len(sys.argv) > 1 else "ref"
geom = sys.argv[2] if len(sys.argv) > 2 else "plate"
media = sys.argv[3].split(",") if len(sys.argv) > 3 else ["m01", "m05", "m10", "m15"]
pl = truth["plates"][obj]
fn = rp.make_rough_plastic(pl["diffuse_reflectance"], pl["alpha"], pl["relative_index"], 1.0,
                           pl["distribution"], False, smith="rational", tables="mitsuba")
out = {}
for m in media:
    med = truth["media"][m]
    t = pd.read_csv(D + f"{m}_{obj}.csv")
    b = pd.read_csv(D + f"{m}_black.csv")
    y = t.value.to_numpy() - b.value.to_numpy()
    sig = np.hypot(t.sigma.to_numpy(), b.sigma.to_numpy())
    pred = []
    t0 = time.time()
    idx = np.arange(0, len(t), 3)
    for k in idx:
        ti, tr = t.theta_i[k], t.theta_r[k]
        pi_, pr = (180.0 if ti >= 0 else 0.0), (0.0 if tr >= 0 else 180.0)
        kw = dict(path_length=15.0, plate_half_width=2.5) if geom == "plate" else dict(path_length=15.0) if geom == "inf" else {}
        v, se = rp.forward_series_apparent(fn, med["tau"], med["albedo"], med["g"], 1.0, abs(ti), abs(tr), pi_, pr, n_qmc=2**12, n_rep=4, **kw)
        pred.append(v)
    pred = np.array(pred)
    rel = (pred - y[idx]) / y[idx]
    out[m] = dict(rms=float(np.sqrt(np.mean(rel**2))), max=float(np.max(np.abs(rel))), z=float(np.sqrt(np.mean(((pred-y[idx])/sig[idx])**2))))
    print(obj, geom, m, out[m], f"{time.time()-t0:.0f}s", flush=True)
if doc_args.doc:
    write(doc_args.doc, doc_args.doc_table, markdown(
        ["medium", "tau per pass", "RMS relative error", "largest", "RMS of error / renderer's sigma"],
        [[m, f"{truth['media'][m]['tau']:g}", f"{100 * out[m]['rms']:.2f} %",
          f"{100 * out[m]['max']:.2f} %", f"{out[m]['z']:.2f}"] for m in media], {1, 2, 3, 4}), _argv)
