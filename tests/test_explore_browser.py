"""``veil explore`` in a real browser: the server on a free local port, headless Chromium
(Debian's chromium and chromium-driver) driven by Selenium. A slider is dragged, and the
curve the page then plots must be the engine's: its peak equals veil.apparent at the new
parameter. The share button writes a state that reopens as the page's state. A screenshot
is written to test-artifacts/ (VEIL_TEST_ARTIFACTS moves it).

Skipped when Chromium, its driver or Selenium is missing, except under CI (CI=true), where
.ci/run installs them and their absence is a failure."""

from __future__ import annotations

import os
import pathlib
import queue
import re
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

CHROMIUM = os.environ.get("VEIL_CHROMIUM", "/usr/bin/chromium")
DRIVER = os.environ.get("VEIL_CHROMEDRIVER", "/usr/bin/chromedriver")
ROOT = pathlib.Path(__file__).resolve().parents[1]
ARTIFACTS = pathlib.Path(os.environ.get("VEIL_TEST_ARTIFACTS", ROOT / "test-artifacts"))


def _missing() -> str | None:
    for path in (CHROMIUM, DRIVER):
        if not (os.path.isfile(path) and os.access(path, os.X_OK)):
            return f"{path} is not installed (apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    return None


def _need_browser():
    why = _missing()
    if why is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"the browser test needs Chromium under CI: {why}")
    pytest.skip(why)


# -- the server --------------------------------------------------------------------------

class Server:
    """``veil explore --no-browser`` in a subprocess; ``url`` once it serves."""

    def __init__(self, args, cwd):
        self.proc = subprocess.Popen([sys.executable, "-m", "veil.cli", "explore", "--no-browser",
                                      *args], cwd=cwd, stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.lines: queue.Queue = queue.Queue()
        self.output: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.output.append(line)
            self.lines.put(line)

    def wait_url(self, timeout=120.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.5)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            m = re.search(r"serving (http://\S+)", line)
            if m:
                return m.group(1)
        raise AssertionError("veil explore did not start serving:\n" + "".join(self.output))

    def stop(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage",
                "--window-size=1500,1300"):
        opts.add_argument(arg)
    return webdriver.Chrome(service=Service(DRIVER), options=opts)


# -- reading the page ----------------------------------------------------------------------

def _source(driver, name):
    """The columns of the page's data source ``name`` (None until it exists)."""
    return driver.execute_script(
        "const d = window.Bokeh && Bokeh.documents && Bokeh.documents[0];"
        "const m = d ? d.get_model_by_name(arguments[0]) : null;"
        "if (!m) return null; const out = {};"
        "for (const [k, v] of (m.data instanceof Map ? m.data : Object.entries(m.data)))"
        "  out[k] = Array.from(v);"
        "return out;", name)


def _state(driver) -> dict:
    data = _source(driver, "veil-state")
    return dict(zip(data["key"], data["value"]))


def _wait(predicate, timeout, what):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        last = predicate()
        if last:
            return last
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


DEEP = """
function* walk(node) {
  yield node;
  if (node.shadowRoot) for (const k of node.shadowRoot.children) yield* walk(k);
  for (const k of node.children) yield* walk(k);
}
"""


def _slider_handle(driver, label=None):
    """The drag handle of the slider titled ``label`` (inside Bokeh's shadow roots); the
    first slider's when ``label`` is None."""
    return driver.execute_script(DEEP + """
for (const el of walk(document.body)) {
  if (!el.shadowRoot) continue;
  const title = el.shadowRoot.querySelector('.bk-slider-title');
  if (title && (arguments[0] === null || title.textContent.trim().startsWith(arguments[0] + ':')))
    return el.shadowRoot.querySelector('.noUi-handle');
}
return null;""", label)


def _button(driver, text):
    return driver.execute_script(DEEP + """
for (const el of walk(document.body)) {
  if (el.tagName === 'BUTTON' && el.textContent.trim().startsWith(arguments[0])) return el;
}
return null;""", text)


def _settled(driver, timeout=30.0) -> dict:
    """The page's state once it and the curve stop changing (two reads 0.5 s apart)."""
    def read():
        return _state(driver), _curve(driver)[1].tolist()

    end = time.monotonic() + timeout
    last = read()
    while time.monotonic() < end:
        time.sleep(0.5)
        now = read()
        if now == last:
            return now[0]
        last = now
    raise AssertionError("the page kept changing for {timeout} s")


def _models(state: dict):
    from veil.models import model_class

    out = []
    for kind in ("brdf", "medium"):
        name = state[f"{kind}.model"]
        if not name:
            out.append(None)
            continue
        cls = model_class(name, kind)
        params = {p: float(state[f"{kind}.{p}"]) for p in cls.param_names()}
        options = {o.name: type(o.default)(state[f"{kind}.option.{o.name}"]) if not o.choices
                   else next(c for c in o.choices if str(c) == state[f"{kind}.option.{o.name}"])
                   for o in cls.OPTIONS}
        out.append(cls.from_params(params, options))
    return out


def _curve(driver):
    data = _source(driver, "veil-curve-medium")
    return np.asarray(data["x"], dtype=float), np.asarray(data["y"], dtype=float)


def _peak(driver):
    x, y = _curve(driver)
    k = int(np.argmax(y))
    return float(x[k]), float(y[k])


def _engine(brdf, medium, theta_i, x):
    """veil.apparent along the page's curve at fixed incidence (signed theta_r ``x``), at
    the page's live accuracy."""
    import veil
    from veil.viz import explore as ex

    x = np.asarray(x, dtype=float)
    return np.asarray(veil.apparent(brdf, medium, theta_i, np.abs(x), 180.0,
                                    np.where(x >= 0, 0.0, 180.0), accuracy=ex.LIVE_ACCURACY))


def _check_curve(driver, state):
    """The page's curve is the engine's, point by point and at its peak."""
    brdf, medium = _models(state)
    x, y = _curve(driver)
    engine = _engine(brdf, medium, float(state["theta_i"]), x)
    np.testing.assert_allclose(y, engine, rtol=1e-9, atol=0)
    k = int(np.argmax(y))
    assert y[k] == pytest.approx(float(np.max(engine)), rel=1e-12)
    return float(x[k]), float(y[k])


# -- the test ------------------------------------------------------------------------------

def test_slider_moves_the_plotted_curve_as_the_engine_says(tmp_path):
    _need_browser()
    from selenium.webdriver.common.action_chains import ActionChains

    from veil.viz import explore as ex

    t0 = time.monotonic()
    phases = {}
    share = tmp_path / "share"
    share.mkdir()
    server = Server(["--port", str(_free_port()), "--share-dir", str(share)], cwd=tmp_path)
    driver = None
    try:
        url = server.wait_url()
        phases["serving"] = time.monotonic() - t0
        driver = _browser()
        driver.set_page_load_timeout(300)
        driver.get(url)
        _wait(lambda: (_source(driver, "veil-curve-medium") or {}).get("y"), 60,
              "the page's first curve")
        phases["page"] = time.monotonic() - t0
        before_state = _state(driver)
        brdf, medium = _models(before_state)
        # the BRDF's first parameter that is not a scale: it changes the curve's shape
        cls = type(brdf)
        name = next(p.name for p in cls.PARAMS if p.name not in cls.scale_names())
        spec = ex.slider_spec(cls, name, getattr(brdf, name))
        x0, y0 = _check_curve(driver, before_state)

        handle = _slider_handle(driver, spec.label)
        assert handle is not None, f"no slider titled {spec.label!r} on the page"
        ActionChains(driver).click_and_hold(handle).move_by_offset(-45, 0).release().perform()
        key = f"brdf.{name}"
        after = _wait(lambda: (s := _state(driver))[key] != before_state[key] and s, 30,
                      f"the page's state to follow the slider ({key})")
        # the curve is redrawn in the same callback as the state; a drag sends several
        # values: wait until the page settles
        after = _settled(driver)
        brdf2, medium2 = _models(after)
        assert getattr(brdf2, name) < getattr(brdf, name)  # dragged to the left
        x1, y1 = _check_curve(driver, after)
        assert y1 != pytest.approx(y0, rel=1e-6)
        phases["moved"] = time.monotonic() - t0

        # the sphere follows when the slider rests: live accuracy first, then refined
        _wait(lambda: (_source(driver, "veil-sphere") or {}).get("accuracy") ==
              [ex.REFINED_ACCURACY], 180, "the refined sphere")
        phases["refined"] = time.monotonic() - t0

        # share: the written state is the page's
        button = _button(driver, "share")
        assert button is not None
        button.click()
        written = _wait(lambda: sorted(share.glob("veil-explore-*.json")), 20,
                        "the shared state file")
        saved = ex.State.load(written[0])
        assert saved.brdf == brdf2 and saved.medium == medium2

        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "explore.png"))
        assert (ARTIFACTS / "explore.png").stat().st_size > 10_000
    finally:
        if driver is not None:
            driver.quit()
        server.stop()
    print(f"browser test: {time.monotonic() - t0:.1f} s; "
          + ", ".join(f"{k} at {v:.1f} s" for k, v in phases.items()))


def test_static_page_switches_precomputed_states(tmp_path):
    """The --static page works without a server: its slider switches between embedded
    states, and each state's curve is the engine's at that parameter value."""
    _need_browser()
    from click.testing import CliRunner

    from veil.cli import main

    page = tmp_path / "page.html"
    run = CliRunner().invoke(main, ["explore", "--static", "--points", "3", "-o", str(page)])
    assert run.exit_code == 0, run.output
    assert page.stat().st_size > 100_000
    assert "cdn.bokeh.org" not in page.read_text()  # Bokeh inline: no server, no network
    driver = _browser()
    try:
        driver.get(page.as_uri())
        first = _wait(lambda: (_source(driver, "veil-curve-medium") or {}).get("y") and
                      _state(driver), 30, "the static page")
        handle = _wait(lambda: _slider_handle(driver), 10, "the static page's slider")
        from selenium.webdriver.common.action_chains import ActionChains

        ActionChains(driver).click_and_hold(handle).move_by_offset(300, 0).release().perform()
        key = "brdf." + first_param(first)
        after = _wait(lambda: (s := _state(driver))[key] != first[key] and s, 20,
                      "the static page to switch state")
        _check_curve(driver, after)
    finally:
        driver.quit()


def first_param(state: dict) -> str:
    from veil.models import model_class

    cls = model_class(state["brdf.model"], "brdf")
    return next(p.name for p in cls.PARAMS if p.name not in cls.scale_names())
