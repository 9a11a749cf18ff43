"""How the engine is compiled and run: one executable for all CPU devices, and the
persistent compilation cache (src/veil/_jax.py, docs/performance.md "Compilation").

Cache tests run in subprocesses with their own cache directory, so they neither depend on
nor disturb the user's cache.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import veil
from veil._jax import jax
from veil.apparent import RULES
from veil.forward import Forward

BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


def _child(script: str, env: dict) -> str:
    full_env = {k: v for k, v in os.environ.items()
                if k not in ("VEIL_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")}
    full_env.update(env)
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], env=full_env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("env, expected", [
    ({"VEIL_CACHE_DIR": "off"}, "None"),
    ({"VEIL_CACHE_DIR": "0"}, "None"),
    ({"VEIL_CACHE_DIR": "{tmp}/mine"}, "{tmp}/mine"),
    ({"XDG_CACHE_HOME": "{tmp}/xdg"}, "{tmp}/xdg/veil/jax"),
    ({"JAX_COMPILATION_CACHE_DIR": "{tmp}/jaxown", "VEIL_CACHE_DIR": "{tmp}/ignored"},
     "{tmp}/jaxown"),
])
def test_cache_directory_settings(tmp_path, env, expected):
    env = {k: v.format(tmp=tmp_path) for k, v in env.items()}
    out = _child("""
        import veil
        from veil._jax import jax, cache_directory
        print(cache_directory(), jax.config.jax_compilation_cache_dir)
    """, env)
    expected = expected.format(tmp=tmp_path)
    assert out == f"{expected} {expected}"


_HASH_SCRIPT = """
    import hashlib
    import numpy as np
    import veil
    from veil._jax import jax
    from veil.apparent import RULES
    from veil.forward import Forward
    events = []
    jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
    b, m = veil.preset("BRDF1"), veil.preset("BTDF2")
    th = np.linspace(0.0, 80.0, 24)
    f = Forward(b, m, th, th[::-1], 0.0, 30.0, rule=RULES["fast"])
    v, j = f.value_and_jacobian(b.to_vector(), m.to_vector(), range(4), range(4))
    digest = hashlib.sha256(v.tobytes() + j.tobytes()).hexdigest()
    print(digest, events.count("/jax/compilation_cache/cache_hits"))
"""


def test_persistent_cache_fills_loads_and_changes_nothing(tmp_path):
    cache = tmp_path / "cache"
    first = _child(_HASH_SCRIPT, {"VEIL_CACHE_DIR": str(cache)}).split()
    entries = [p.name for p in cache.iterdir() if p.name.endswith("-cache")]
    assert entries, "the first process wrote nothing to the compilation cache"
    second = _child(_HASH_SCRIPT, {"VEIL_CACHE_DIR": str(cache)}).split()
    uncached = _child(_HASH_SCRIPT, {"VEIL_CACHE_DIR": "off"}).split()
    assert first[1] == "0" and int(second[1]) >= 1 and uncached[1] == "0"
    # the same executable, loaded or compiled: bit for bit the same values and Jacobian
    assert first[0] == second[0] == uncached[0]


def test_one_executable_for_all_devices():
    """A Forward spread over every CPU device compiles one program, not one per device."""
    if len(jax.devices()) < 2:
        pytest.skip("needs two CPU devices")
    b, m = veil.preset("BRDF2"), veil.preset("BTDF3")
    th = np.linspace(5.0, 75.0, 40)
    rule = RULES["fast"].scaled(1.07)  # a rule no other test compiles
    f = Forward(b, m, th, th, 180.0, 10.0, rule=rule)
    assert len(f.devices) == len(jax.devices())
    compiles = []

    def listen(name, secs, **kw):
        if name == BACKEND_COMPILE:
            compiles.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        value = f(b.to_vector(), m.to_vector())
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert compiles.count("jit(fn)") == 1, compiles
    single = Forward(b, m, th[:7], th[:7], 180.0, 10.0, rule=rule)  # below 8 a device: one
    assert len(single.devices) == 1
    np.testing.assert_allclose(single(b.to_vector(), m.to_vector()), value[:7], rtol=1e-13)


def test_prepare_compiles_in_the_background_once():
    """prepare() starts the compilations; a call made before they finish waits for them
    instead of compiling the same program again, and the values are unchanged."""
    b, m = veil.preset("BRDF1"), veil.preset("BTDF3")
    th = np.linspace(10.0, 70.0, 20)
    rule = RULES["fast"].scaled(0.93)  # a rule no other test compiles
    f = Forward(b, m, th, th, 180.0, 0.0, rule=rule)
    compiles = []

    def listen(name, secs, **kw):
        if name == BACKEND_COMPILE:
            compiles.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        futures = f.prepare(values=True, jacobian=((2,), (2,)))
        assert len(futures) == 2
        value, jac = f.value_and_jacobian(b.to_vector(), m.to_vector(), (2,), (2,))
        terms = f.terms(b.to_vector(), m.to_vector())
        for fut in futures:
            fut.result()
        assert f.prepare(values=True, jacobian=((2,), (2,)))[0] is futures[0]
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert compiles.count("jit(fn)") == 2, compiles  # terms and Jacobian, once each
    np.testing.assert_array_equal(f.combine(terms, b.to_vector(), m.to_vector()), value)
    assert jac.shape == (20, 2) and np.all(np.isfinite(jac))
