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
from support.compiles import compilations
from support.held_nodes import held_values
from veil._jax import jax
from veil.engine import forward
from veil.engine.apparent import RULES
from veil.engine.forward import Forward, _mesh, _terms_fn, wait_for_compilations


def _child(script: str, env: dict, cwd=None) -> str:
    full_env = {k: v for k, v in os.environ.items()
                if k not in ("VEIL_CACHE_DIR", "JAX_COMPILATION_CACHE_DIR", "XDG_CACHE_HOME")}
    full_env.update(env)
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], env=full_env,
                          capture_output=True, text=True, timeout=600, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("env, expected", [
    ({"VEIL_CACHE_DIR": "off"}, "None"),
    ({"VEIL_CACHE_DIR": "0"}, "None"),
    ({"VEIL_CACHE_DIR": ""}, "None"),
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


def test_relative_cache_directory_is_made_absolute(tmp_path):
    out = _child("""
        import os
        import veil
        from veil._jax import jax
        print(jax.config.jax_compilation_cache_dir, os.path.isdir("rel/cache"))
    """, {"VEIL_CACHE_DIR": "rel/cache", "PWD": str(tmp_path)}, cwd=tmp_path)
    assert out == f"{tmp_path}/rel/cache True"


def test_unwritable_cache_directory_warns_and_runs_without(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    out = _child("""
        import warnings
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            import veil  # JAX is set up on first use, not at import (fast start)
            value = veil.apparent("BRDF1", "BTDF2", 30.0, 40.0, accuracy="fast")
        from veil._jax import jax
        messages = [str(w.message) for w in caught if "veil" in str(w.message)]
        print(len(messages), "VEIL_CACHE_DIR" in messages[0], jax.config.jax_compilation_cache_dir,
              float(value) > 0)
    """, {"VEIL_CACHE_DIR": str(blocker / "cache")})
    assert out == "1 True None True"


_HASH_SCRIPT = """
    import hashlib
    import numpy as np
    import veil
    from veil._jax import jax
    from veil.engine.apparent import RULES
    from veil.engine.forward import Forward, _mesh, _terms_fn, wait_for_compilations
    events = []
    jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, secs, **kw: events.append(name))
    from veil_test_models import FisherTest, LambertianTest  # (a quick compilation)
    b, m = LambertianTest(rho=0.8), FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    th = np.linspace(0.0, 80.0, 24)
    f = Forward(b, m, th, th[::-1], 0.0, 30.0, rule=RULES["fast"])
    v = f(b.to_vector(), m.to_vector())
    digest = hashlib.sha256(v.tobytes()).hexdigest()
    print(digest, events.count("/jax/compilation_cache/cache_hits"),
          events.count("/jax/core/compile/backend_compile_duration"))
"""


_OFF_SCRIPT = """
    import numpy as np
    import veil
    from veil._jax import jax
    events = []
    jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
    value = veil.reflectance("BRDF1", np.linspace(0.0, 80.0, 24), 30.0)
    assert np.all(np.isfinite(value))
    print(events.count("/jax/compilation_cache/cache_hits"), jax.config.jax_compilation_cache_dir)
"""


def test_persistent_cache_fills_loads_and_changes_nothing(tmp_path):
    cache = tmp_path / "cache"
    # the engine on the test-only families (tests/plugins, on the children's path)
    env = {"VEIL_CACHE_DIR": str(cache), "PYTHONPATH": os.pathsep.join(
        [os.path.join(os.path.dirname(os.path.abspath(__file__)), "plugins"),
         os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    first = _child(_HASH_SCRIPT, env).split()
    assert list((cache / "programs").iterdir()), "the first process stored no program"
    assert first[1] == "0" and int(first[2]) >= 1          # compiled, nothing found
    # a second process loads the stored executables: no compilation, no cache lookup
    second = _child(_HASH_SCRIPT, env).split()
    assert second[1:] == ["0", "0"]
    # the engine's executables live in the program store, none in JAX's cache (one that
    # JAX loaded from there could not be stored again): without the store they are built
    for entry in (cache / "programs").iterdir():
        entry.unlink()
    third = _child(_HASH_SCRIPT, env).split()
    assert third[1] == "0" and int(third[2]) >= 1
    fourth = _child(_HASH_SCRIPT, env).split()
    assert fourth[1:] == ["0", "0"]                       # ... and stored again
    # the same executable, loaded or compiled: bit for bit the same values
    assert first[0] == second[0] == third[0] == fourth[0]
    # with the cache off nothing is looked up (a small program: f_r alone, not the engine,
    # whose third compilation would cost about a minute of the suite)
    uncached = _child(_OFF_SCRIPT, {"VEIL_CACHE_DIR": "off"}).split()
    assert uncached == ["0", "None"]


def test_one_executable_for_all_devices(tmp_path, monkeypatch):
    """A Forward spread over every CPU device compiles one program, not one per device."""
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))  # an empty program store: compiles
    if len(jax.devices()) < 2:
        pytest.skip("needs two CPU devices")
    from veil_test_models import FisherTest, LambertianTest  # (tests/plugins: a quick compile)

    b, m = LambertianTest(rho=0.8), FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    th = np.linspace(5.0, 75.0, 40)
    rule = RULES["fast"].scaled(1.07)  # a rule no other test compiles
    f = Forward(b, m, th, th, 180.0, 10.0, rule=rule)
    assert len(f.devices) == len(jax.devices())
    with compilations() as compiles:
        value = f(b.to_vector(), m.to_vector())
    assert compiles.count("jit(fn)") == 1, compiles
    single = Forward(b, m, th[:7], th[:7], 180.0, 10.0, rule=rule)
    assert len(single.devices) == len(jax.devices())
    with compilations() as compiles:  # a smaller call runs the same program
        few = single(b.to_vector(), m.to_vector())
    assert compiles.count("jit(fn)") == 0, compiles
    np.testing.assert_array_equal(few, value[:7])


def test_prepare_compiles_in_the_background_once(tmp_path, monkeypatch):
    """prepare() starts the compilations; a call made before they finish waits for them
    instead of compiling the same program again, and the values are unchanged."""
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))  # an empty program store: compiles
    # the test-only families (tests/plugins): the mechanism is the same for every pair, and
    # theirs compile in about a second where the paper's took 25 s of the suite
    from veil_test_models import FisherTest, LambertianTest

    b, m = LambertianTest(rho=0.8), FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    th = np.linspace(10.0, 70.0, 20)
    rule = RULES["fast"].scaled(0.93)  # a rule no other test compiles
    f = Forward(b, m, th, th, 180.0, 0.0, rule=rule)
    with compilations() as compiles:
        futures = f.prepare(values=True, jacobians=[((), (2,))])  # d/d(kappa)
        assert len(futures) == 2
        value, jac = f.value_and_jacobian(b.to_vector(), m.to_vector(), (), (2,))
        terms = f.terms(b.to_vector(), m.to_vector())
        for fut in futures:
            fut.result()
        assert f.prepare(values=True, jacobians=[((), (2,))])[0] is futures[0]
        assert all(fut.result() is None for fut in futures)
    assert compiles.count("jit(fn)") == 2, compiles  # terms and Jacobian, once each
    np.testing.assert_array_equal(f.combine(terms, b.to_vector(), m.to_vector()), value)
    assert jac.shape == (20, 1) and np.all(np.isfinite(jac))


def test_small_calls_share_one_program():
    """Forwards of 20 and 64 configurations run one program (padded to CHUNK, every device):
    preparing the second finds the first's compilation, and a configuration's value is the
    same bit for bit in both; 150 configurations pad to the next multiple of CHUNK."""
    b, m = veil.preset("BRDF2"), veil.preset("BTDF1")
    rule = RULES["fast"]
    th = np.linspace(10, 60, 150)
    # out of the plane of incidence: the programs of tests/test_cli_eval.py's azimuths (64)
    # and of the split over devices below (192), none of their own
    made = [Forward(b, m, th[:n], th[::-1][:n], 180.0, 30.0, rule=rule) for n in (20, 64, 150)]
    assert [f._wi.shape[0] for f in made] == [forward.CHUNK, forward.CHUNK, 3 * forward.CHUNK]
    assert all(len(f.devices) == len(jax.devices()) for f in made)
    futures = [f.prepare(values=True)[0] for f in made]
    assert futures[1] is futures[0] and futures[2] is not futures[0]
    wait_for_compilations()
    values = [f(b.to_vector(), m.to_vector()) for f in made]
    np.testing.assert_array_equal(values[0], values[1][:20])
    np.testing.assert_allclose(values[1], values[2][:64], rtol=1e-14)


@pytest.mark.parametrize("size", [17, 130])
def test_split_over_devices_equals_one_device(size):
    """Every configuration, including the second device's share and the padding's
    neighbours, matches the same program run on one device."""
    if len(jax.devices()) < 2:
        pytest.skip("needs two CPU devices")
    b, m = veil.preset("BRDF1"), veil.preset("BTDF2")
    rng = np.random.default_rng(size)
    ti, tr = rng.uniform(0, 80, size), rng.uniform(0, 80, size)
    pi_, pr = rng.uniform(0, 360, size), rng.uniform(0, 360, size)
    rule = RULES["fast"]
    f = Forward(b, m, ti, tr, pi_, pr, rule=rule)
    assert len(f.devices) == 2
    split = f.terms(b.to_vector(), m.to_vector())
    one = _terms_fn(f._kb, f._km, rule, f.half, _mesh(1))
    whole = np.asarray(one(b.to_vector(), m.to_vector(), np.asarray(f._wi), np.asarray(f._wr)))
    np.testing.assert_allclose(split, whole[:size], rtol=1e-12, atol=0)


def test_jacobian_matches_central_differences():
    """Every parameter of both models, in scrambled and negative index order, in and out of
    the plane of incidence: the Jacobian agrees with the central differences of the
    quadrature whose phase grids stay at the Jacobian's point (docs/engine.md "Derivatives")."""
    b, m = veil.preset("BRDF1"), veil.preset("BTDF2")
    ti = np.array([0.0, 20.0, 45.0, 60.0, 30.0, 70.0])
    tr = np.array([30.0, 25.0, 45.0, 10.0, 50.0, 65.0])
    phi_r = np.array([0.0, 0.0, 0.0, 40.0, 200.0, 90.0])
    f = Forward(b, m, ti, tr, 180.0, phi_r, rule=RULES["fast"])
    vb, vm = b.to_vector(), m.to_vector()
    free_b, free_m = (3, 0, -2, 1), (-1, 2, 0, 1)
    value, jac = f.value_and_jacobian(vb, vm, free_b, free_m)
    np.testing.assert_allclose(value, f(vb, vm), rtol=1e-13)
    held = held_values(f, vm)
    columns = [("b", i % 4) for i in free_b] + [("m", i % 4) for i in free_m]
    for k, (which, i) in enumerate(columns):
        x = vb if which == "b" else vm
        h = 1e-5 * abs(x[i])
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        pair = [(up, vm), (down, vm)] if which == "b" else [(vb, up), (vb, down)]
        fd = (held(*pair[0]) - held(*pair[1])) / (2 * h)
        scale = np.max(np.abs(fd))
        assert scale > 0
        np.testing.assert_allclose(jac[:, k], fd, rtol=0, atol=1e-6 * scale,
                                   err_msg=f"column {k}: {which} parameter {i}")
    # the same free parameters in another order: the same program, its columns permuted
    assert f._jacobian_fn(free_b, free_m)[0] is f._jacobian_fn((0, 1, 2, 3), (0, 1, 2, 3))[0]
    _, again = f.value_and_jacobian(vb, vm, (0, 1, 2, 3), (0, 1, 2, 3))
    np.testing.assert_array_equal(again, jac[:, [1, 3, 2, 0, 6, 7, 5, 4]])
    # a parameter named twice: its column twice, from the same program
    assert f._jacobian_fn((3, 0, 2, 1, 2), free_m)[0] is f._jacobian_fn(free_b, free_m)[0]
    _, twice = f.value_and_jacobian(vb, vm, (3, 0, 2, 1, 2), free_m)
    np.testing.assert_array_equal(twice, jac[:, [0, 1, 2, 3, 2, 4, 5, 6, 7]])


def test_lobe_half_width_compiles_its_phase_once():
    """The render table's width search (200 phase evaluations per call, a call per explorer
    state) runs one compiled phase law per medium structure: a phase built on lax.cond
    evaluated eagerly compiled again at every evaluation (the explorer's first page of a
    forward-series result took 500 s). Same value as the eager bisection, to the last bit."""
    from veil.models.registry import model_class

    cls = model_class("forward-series", "medium")
    medium = cls(tau=0.6, omega=0.98, g=0.95, path_length=15.0, plate_width=5.0)
    medium.lobe_half_width()  # the first call may compile
    with compilations() as compiles:
        widths = [medium.replace(g=g).lobe_half_width() for g in (0.9, 0.95, 0.99)]
    assert len(compiles) <= 1, compiles
    assert widths[0] > widths[1] > widths[2] > 0  # a sharper lobe for a larger g
    v = medium.to_vector()  # reference: the phase on a dense grid of angles, one evaluation
    gamma = np.linspace(0.0, 10.0, 200_001)
    phase = np.asarray(medium.phase(v, 1.0 - np.cos(np.radians(gamma))))
    k = int(np.argmax(phase <= 0.5 * phase[0]))
    assert k > 0
    assert abs(medium.lobe_half_width() - widths[1]) == 0.0  # deterministic
    assert gamma[k - 1] <= widths[1] <= gamma[k]


def test_f_r_padding_keeps_every_row_and_shares_small_programs():
    """f_r (veil.reflectance, DirectModel) at 0, 1, 256, 257, 1024 and 1025 configurations:
    every row is that configuration's own value (against one call per configuration, within
    1e-14; bit for bit up to 256, which all run one program), the Jacobian rows match the
    values' central differences, and no configurations give empty arrays of the right
    shape."""
    from veil.engine.apparent import DIRECT_CHUNK, direct_padded
    from veil.engine.evaluator import DirectModel

    b = veil.preset("BRDF1")
    rng = np.random.default_rng(3)
    ti, tr = rng.uniform(0, 80, 1025), rng.uniform(0, 80, 1025)
    pr = rng.uniform(0, 360, 1025)
    single = np.array([veil.reflectance(b, ti[k], tr[k], 180.0, pr[k]) for k in range(0, 1025, 97)])
    for n in (1, 256, 257, 1024, 1025):
        got = veil.reflectance(b, ti[:n], tr[:n], 180.0, pr[:n])
        assert got.shape == (n,)
        want = single[: len(range(0, n, 97))]
        if n <= DIRECT_CHUNK:
            np.testing.assert_array_equal(got[::97], want)
        np.testing.assert_allclose(got[::97], want, rtol=1e-14)
        assert direct_padded(np.zeros((n, 3)), np.zeros((n, 3)))[0].shape[0] == \
            max(DIRECT_CHUNK, 1 << (n - 1).bit_length())
    angles = (ti[:300], np.full(300, 180.0), tr[:300], pr[:300])
    direct = DirectModel(b, angles)
    v = b.to_vector()
    values, jac = direct.value_and_jacobian(v)
    np.testing.assert_array_equal(values, direct.values(v))
    assert jac.shape == (300, len(v))
    h = 1e-6 * np.abs(v[0])
    up, down = v.copy(), v.copy()
    up[0] += h
    down[0] -= h
    np.testing.assert_allclose(jac[:, 0], (direct.values(up) - direct.values(down)) / (2 * h),
                               rtol=1e-6, atol=1e-12)
    empty = DirectModel(b, tuple(np.zeros(0) for _ in range(4)))
    values, jac = empty.value_and_jacobian(v)
    assert values.shape == (0,) and jac.shape == (0, len(v))
    assert empty.values(v).shape == (0,)
