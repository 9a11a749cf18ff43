"""benchmarks/bench_inverse_rendering.py: its pure helpers and its answer without Mitsuba."""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "benchmarks", "bench_inverse_rendering.py")


def _module():
    spec = importlib.util.spec_from_file_location("bench_inverse_rendering", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_rms_relative_by_hand():
    b = _module()
    # relative differences 0.1, -0.2, 0 -> sqrt((0.01 + 0.04 + 0) / 3)
    assert b.rms_relative([1.1, 1.6, 3.0], [1.0, 2.0, 3.0]) == pytest.approx(
        math.sqrt(0.05 / 3), rel=1e-12)


def test_time_to_within_counts_from_the_last_entry():
    b = _module()
    t = [0.0, 1.0, 2.0, 3.0, 4.0]
    assert b.time_to_within(t, [0.5, 0.01, 0.03, 0.015, 0.01]) == 3.0   # dips in, out, in
    assert b.time_to_within(t, [0.01] * 5) == 0.0
    assert b.time_to_within(t, [0.5, 0.01, 0.01, 0.01, 0.03]) is None   # not at the end


@pytest.mark.parametrize("name,value", [("alpha", 0.2), ("tau", 0.5), ("albedo", 0.99),
                                        ("g", 0.92)])
def test_latents_round_trip_with_their_derivative(name, value):
    b = _module()
    u = b.to_latent(name, value)
    v, dv = b.from_latent(name, u)
    assert v == pytest.approx(value, rel=1e-12)
    h = 1e-6
    numeric = (b.from_latent(name, u + h)[0] - b.from_latent(name, u - h)[0]) / (2 * h)
    assert dv == pytest.approx(numeric, rel=1e-6)


_BLOCK_MITSUBA = r"""
import importlib.abc, runpy, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('mitsuba', 'drjit'):
            raise ImportError(f'No module named {name!r} (blocked by the test)')
        return None
sys.meta_path.insert(0, Block())
sys.argv = [sys.argv[1], '--rows', 'known']
runpy.run_path(sys.argv[0], run_name='__main__')
"""


def test_without_mitsuba_it_says_how_to_install_and_exits_2():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [os.path.join(ROOT, "src"), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", _BLOCK_MITSUBA, SCRIPT], capture_output=True,
                          text=True, env=env, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "pip install 'veil[test]'" in proc.stderr
    assert "pip install mitsuba" in proc.stderr
    assert "Traceback" not in proc.stderr
