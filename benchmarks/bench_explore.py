"""Latency of ``veil explore`` (issue 15): how long a slider move takes to redraw the curves
(target < 300 ms) and the lit sphere (target < 2 s) on this machine.

Two measurements, after the engine has compiled (the page compiles before it serves):

* in the process, on the page object itself (no browser): each slider of the BRDF and the
  medium is moved to 5 positions; "curves" is the whole callback (engine along the curve,
  f_r, lobes, the state; the data panel's model too with --fit), "sphere" the render at the
  live accuracy that follows when the slider rests, "refined" the one after it;
* with --browser (Debian's chromium and chromium-driver, Selenium): the server in a
  subprocess, headless Chromium sets a slider and times until the new curve is in the page
  (websocket round trip, Python, the plot's data) and until the sphere is.

    python benchmarks/bench_explore.py              # in-process table
    python benchmarks/bench_explore.py --browser    # and the browser's round trip
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import veil
from veil.viz import explore as ex
from veil.viz import explore_fits as fits
from veil.viz.explore_page import ExplorePage

from doc_tables import add_options, printed_tables  # noqa: E402  (benchmarks/)

CURVES_TARGET = 0.300
VERBOSE = bool(os.environ.get("VEIL_BENCH_VERBOSE"))


def log(text):
    if VERBOSE:
        print(text, file=sys.stderr, flush=True)
SPHERE_TARGET = 2.0
POSITIONS = (0.2, 0.35, 0.5, 0.65, 0.8)


def in_process(fit: bool, refined: bool):
    state = ex.State.default()
    views = []
    if fit:
        views = [_fit_view()]
    page = ExplorePage(state, views, share_dir=tempfile.mkdtemp(), background=False)
    rows = []
    for controls in (page.brdf, page.medium):
        for name, (slider, spec) in controls.sliders.items():
            curves, spheres, fine = [], [], []
            for k, f in enumerate(POSITIONS):
                t0 = time.perf_counter()
                slider.value = spec.start + f * (spec.end - spec.start)
                curves.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                page._sphere_now()
                spheres.append(time.perf_counter() - t0)
                if refined and k == 0:
                    t0 = time.perf_counter()
                    page._render(page.state, ex.REFINED_ACCURACY)
                    fine.append(time.perf_counter() - t0)
            slider.value = spec.to_slider(getattr(getattr(state, controls.kind), name))
            rows.append((controls.kind, type(controls.model).NAME, spec.label, curves, spheres,
                         fine))
    print(f"\nIn the process: one slider at a time, {len(POSITIONS)} positions each "
          f"({'with' if fit else 'without'} a fit's data panel)\n")
    print("| model | slider | curves median (ms) | curves max (ms) | sphere median (s) "
          "| sphere max (s) | refined (s) |")
    print("|---|---|---:|---:|---:|---:|---:|")
    worst_c = worst_s = 0.0
    for kind, family, label, curves, spheres, fine in rows:
        worst_c, worst_s = max(worst_c, max(curves)), max(worst_s, max(spheres))
        print(f"| {family} | {label} | {1e3 * statistics.median(curves):.0f} | "
              f"{1e3 * max(curves):.0f} | {statistics.median(spheres):.2f} | "
              f"{max(spheres):.2f} | {(f'{fine[0]:.2f}' if fine else '-')} |")
    print(f"\nworst curves redraw {1e3 * worst_c:.0f} ms (target < {1e3 * CURVES_TARGET:.0f}: "
          f"{'met' if worst_c < CURVES_TARGET else 'MISSED'}); worst sphere {worst_s:.2f} s "
          f"(target < {SPHERE_TARGET:g}: {'met' if worst_s < SPHERE_TARGET else 'MISSED'})")


def _fit_view():
    from veil.fitting import fit_target

    small = dict(psi=(30, 60, 90), fine_step=2, coarse_step=10, glow=0.0, accuracy="fast")
    table = veil.simulate(veil.BRDF1, veil.BTDF2, noise=0.01, seed=31, **small)
    result = fit_target(table, veil.BTDF2, accuracy="fast")
    return fits.FitView(result, table, source="simulated target fit")


def browser(repeats: int = 3):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    proc = subprocess.Popen([sys.executable, "-m", "veil.cli", "explore", "--no-browser",
                             "--port", "0", "--share-dir", tempfile.mkdtemp()],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    url = None
    for line in proc.stdout:
        m = re.search(r"serving (http://\S+)", line)
        if m:
            url = m.group(1)
            break
    if url is None:
        raise SystemExit("veil explore did not start")
    # keep reading what the server prints: a full pipe would stop it
    threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1500,1300"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    try:
        driver.get(url)
        end = time.monotonic() + 180
        while time.monotonic() < end and not driver.execute_script(
                "return !!(window.Bokeh && Bokeh.documents.length && "
                "Bokeh.documents[0].get_model_by_name('veil-sphere'))"):
            time.sleep(0.2)
        time.sleep(2.0)
        # curves: the slider's value set in the page (what the browser sends while a slider
        # is dragged), timed in the browser's clock until the curve's new data has arrived;
        # sphere: the slider's handle dragged and released (ActionChains), timed until the
        # sphere's new image has arrived (this includes WebDriver's own round trips)
        driver.execute_script("""
const doc = Bokeh.documents[0];
for (const name of ['veil-curve-medium', 'veil-sphere']) {
  doc.get_model_by_name(name).properties.data.change.connect(
    () => { window['t_' + name] = performance.now(); });
}""")
        move = """
const slider = [...Bokeh.documents[0].all_models].filter(m => m.title === arguments[0])
  [arguments[2]];
window['t_veil-curve-medium'] = null; window['t_veil-sphere'] = null;
window.t0 = performance.now();
if (arguments[1] !== null) slider.value = arguments[1];"""
        read = "return [window['t_veil-curve-medium'], window['t_veil-sphere'], window.t0];"

        def wait(k, timeout=60.0):
            end = time.monotonic() + timeout
            while time.monotonic() < end:
                got = driver.execute_script(read)
                if got[k] is not None:
                    return got[k] - got[2]
                time.sleep(0.01)
            return None

        from selenium.webdriver.common.action_chains import ActionChains

        handles = driver.execute_script("""
function* walk(node) {
  yield node;
  if (node.shadowRoot) for (const k of node.shadowRoot.children) yield* walk(k);
  for (const k of node.children) yield* walk(k);
}
const out = [];
for (const el of walk(document.body)) {
  if (!el.shadowRoot) continue;
  const t = el.shadowRoot.querySelector('.bk-slider-title');
  const h = el.shadowRoot.querySelector('.noUi-handle');
  if (t && h) out.push([t.textContent.split(':')[0].trim(), h]);
}
return out;""")
        rows = []
        seen = {}
        state = ex.State.default()
        for kind in ("brdf", "medium"):
            model = getattr(state, kind)
            for p in model.PARAMS:
                spec = ex.slider_spec(type(model), p.name, getattr(model, p.name))
                nth = seen.get(spec.label, 0)
                seen[spec.label] = nth + 1
                handle = [h for label, h in handles if label == spec.label][nth]
                curves, spheres = [], []
                for k in range(repeats):
                    f = POSITIONS[k % len(POSITIONS)]
                    log(f"{spec.label} #{nth}: move {k}")
                    driver.execute_script(move, spec.label,
                                          spec.start + f * (spec.end - spec.start), nth)
                    curves.append(wait(0))
                    log(f"  curves {curves[-1]}")
                    time.sleep(0.3)
                    driver.execute_script(move, spec.label, None, nth)
                    ActionChains(driver).click_and_hold(handle).move_by_offset(
                        15 if k % 2 else -15, 0).release().perform()
                    spheres.append(wait(1))
                    log(f"  sphere {spheres[-1]}")
                    time.sleep(0.3)
                rows.append((model.NAME, spec.label, list(zip(curves, spheres))))
        print(f"\nIn headless Chromium: slider set in the page, until the new data is in the "
              f"page ({repeats} moves each)\n")
        print("| model | slider | curves median (ms) | curves max (ms) | sphere median (s) "
              "| sphere max (s) |")
        print("|---|---|---:|---:|---:|---:|")
        for family, label, times in rows:
            c = [t[0] for t in times if t[0] is not None]
            s = [t[1] / 1e3 for t in times if t[1] is not None]
            print(f"| {family} | {label} | {statistics.median(c):.0f} | {max(c):.0f} | "
                  f"{statistics.median(s):.2f} | {max(s):.2f} |")
        print("\n(the sphere waits 0.25 s for the slider to rest before it renders)")
    finally:
        driver.quit()
        proc.terminate()
        proc.wait(timeout=30)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--browser", action="store_true", help="also time it in Chromium")
    parser.add_argument("--fit", action="store_true", help="with a fit's data panel")
    parser.add_argument("--no-refined", action="store_true", help="skip the refined sphere")
    add_options(parser, "explore-process,explore-browser")
    args = parser.parse_args()
    doc = printed_tables(args).start()
    print(f"veil explore latency, {os.cpu_count()} CPU(s); accuracy {ex.LIVE_ACCURACY!r} live,"
          f" {ex.REFINED_ACCURACY!r} refined")
    in_process(args.fit, not args.no_refined)
    if args.browser:
        browser()
    doc.finish()


if __name__ == "__main__":
    sys.stdout.reconfigure(line_buffering=True)
    main()
