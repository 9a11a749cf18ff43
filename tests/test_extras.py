"""The optional dependencies (veil._extras, pyproject's extras): the core works without them,
and a command that needs a missing one exits 2 with the pip line to run."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner

from veil._extras import EXTRA_OF, pip_line, require
from veil.cli import main
from veil.errors import InputError, MissingExtraError

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
#: pip distribution name -> top-level module, where they differ
MODULE_OF = {"dask[array]": "dask"}
HEAVY = sorted(EXTRA_OF)


def _names(requirements):
    """Top-level module names of requirement strings ('dask[array]>=2024.8' -> 'dask')."""
    out = set()
    for req in requirements:
        name = req.split(";")[0].split(">")[0].split("<")[0].split("=")[0].strip()
        out.add(MODULE_OF.get(name, name.split("[")[0]))
    return out


def test_core_dependencies_are_light():
    core = _names(PYPROJECT["project"]["dependencies"])
    assert not core & set(HEAVY), f"heavy packages in the core: {core & set(HEAVY)}"
    assert {"numpy", "scipy", "jax", "pandas", "click", "rich", "matplotlib"} <= core


def _extra(name, seen=()):
    """Module names an extra installs, its own "veil[...]" references followed."""
    out = set()
    for req in PYPROJECT["project"]["optional-dependencies"][name]:
        if req.startswith("veil["):
            for inner in req[5:].split("]")[0].split(","):
                if inner not in seen:
                    out |= _extra(inner.strip(), seen + (name,))
        else:
            out |= _names([req])
    return out


@pytest.mark.parametrize("module", HEAVY)
def test_every_optional_module_is_in_its_extra(module):
    """The pip line a missing module prints installs it, and veil[all] has it too."""
    wanted = "panel" if module == "bokeh" else module  # bokeh comes with panel
    assert wanted in _extra(EXTRA_OF[module]), (module, EXTRA_OF[module])
    assert wanted in _extra("all")


@pytest.mark.parametrize("module", HEAVY)
def test_require_names_the_pip_line(monkeypatch, module):
    monkeypatch.setitem(sys.modules, module, None)  # import of it fails as if not installed
    with pytest.raises(MissingExtraError) as info:
        require(module, "this test")
    assert pip_line(EXTRA_OF[module]) in str(info.value)
    assert isinstance(info.value, InputError) and isinstance(info.value, ImportError)


def test_require_returns_the_module():
    import json
    assert require("json") is json


def test_a_command_without_its_extra_exits_2_with_the_pip_line(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "zarr", None)
    store = tmp_path / "maps.zarr"  # the arguments are right but for the missing extra
    store.mkdir()
    result = CliRunner().invoke(main, ["maps", "show", str(store), "-o", str(tmp_path / "m.png")])
    assert result.exit_code == 2, result.output
    assert "pip install 'veil[maps]'" in result.output
    assert "Traceback" not in result.output


def test_explore_without_panel_exits_2(monkeypatch, tmp_path):
    for name in ("panel", "bokeh"):
        monkeypatch.setitem(sys.modules, name, None)
    result = CliRunner().invoke(main, ["explore", "--static", "-o", str(tmp_path / "page.html")])
    assert result.exit_code == 2, result.output
    assert "pip install 'veil[explore]'" in result.output


#: A meta-path finder that makes the heavy packages uninstallable for one interpreter.
BLOCKER = """
import sys
BLOCKED = {blocked!r}
class Blocker:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in BLOCKED:
            raise ModuleNotFoundError(f'No module named {{name!r}} (blocked)', name=name)
        return None
sys.meta_path.insert(0, Blocker())
"""


def _blocked_run(code: str, timeout: float = 300):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep
               + os.environ.get("PYTHONPATH", ""))
    script = BLOCKER.format(blocked=HEAVY) + code
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          env=env, timeout=timeout)


def test_core_computes_without_the_extras():
    """``pip install veil`` (no extras): import veil and compute veil.apparent."""
    result = _blocked_run(
        "import veil, numpy as np\n"
        "v = veil.apparent(veil.BRDF1, veil.BTDF2, np.array([30.0]), np.array([30.0]),"
        " accuracy='fast')\n"
        "assert np.all(np.isfinite(v)) and float(np.ravel(v)[0]) > 0, v\n"
        f"assert not set(sys.modules) & set({HEAVY!r}), sorted(set(sys.modules) & set({HEAVY!r}))\n"
        "print('ok', float(np.ravel(v)[0]), veil.__version__)\n")
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.startswith("ok ")


def test_cli_without_the_extras():
    """The command line starts, lists its models, and a command needing an extra says which."""
    result = _blocked_run(
        "from veil.cli import main\n"
        "import sys\n"
        "sys.argv = ['veil', 'maps', 'show', sys.prefix, '-o', '/tmp/veil-extras-out.png']\n"
        "main()\n")
    assert result.returncode == 2, (result.stdout, result.stderr[-3000:])
    assert "pip install 'veil[maps]'" in result.stderr + result.stdout


def test_a_broken_optional_package_names_the_extra_too(monkeypatch):
    """zarr installed but one of its own dependencies missing: the extra's pip line mends it."""
    import importlib

    def broken(name, *args, **kwargs):
        raise ModuleNotFoundError("No module named 'numcodecs'", name="numcodecs")

    monkeypatch.setattr(importlib, "import_module", broken)
    with pytest.raises(MissingExtraError) as info:
        require("zarr", "a maps store")
    assert "numcodecs" in str(info.value) and pip_line("maps") in str(info.value)


def test_require_of_a_core_module_is_not_an_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "json", None)
    with pytest.raises(ImportError) as info:
        require("json")
    assert not isinstance(info.value, MissingExtraError)
