"""The distribution: ``python -m build`` makes a wheel and an sdist, each installs into a fresh
environment and passes a smoke test (import, version, one apparent value, the command line).

Nothing is downloaded: the build uses this environment's setuptools (``--no-isolation``), the
fresh environments see this environment's packages through a .pth line (the dependencies
are not installed twice), and veil itself is installed from the built files with
``--no-deps --no-index``. The smoke test runs outside the checkout, so it imports the
installed copy (checked)."""

from __future__ import annotations

import os
import shutil
import site
import subprocess
import sys
import tarfile
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VERSION = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
SMOKE = """
import sys, numpy as np, veil
from importlib.metadata import version
assert veil.__file__.startswith(sys.prefix), veil.__file__
assert veil.__version__ == version("veil") == {version!r}, veil.__version__
v = veil.apparent(veil.BRDF1, veil.BTDF2, np.array([30.0]), np.array([30.0]), accuracy="fast")
assert np.all(np.isfinite(v)) and float(np.ravel(v)[0]) > 0
print("ok", veil.__version__, veil.__file__)
"""


def _env():
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.setdefault("VEIL_CACHE_DIR", str(ROOT / ".veil-cache"))
    return env


def _run(args, **kw):
    result = subprocess.run(args, capture_output=True, text=True, env=_env(), **kw)
    assert result.returncode == 0, (args, result.stdout[-2000:], result.stderr[-3000:])
    return result


@pytest.fixture(scope="module")
def dist(tmp_path_factory):
    """The sdist and the wheel, built from a copy of the checkout's files (no build/ or
    egg-info left in the checkout)."""
    if not (ROOT / ".git").exists():
        pytest.skip("builds from a git checkout")
    tmp = tmp_path_factory.mktemp("dist")
    files = _run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                 cwd=ROOT).stdout.split("\0")
    src = tmp / "src"
    for name in filter(None, files):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    out = tmp / "out"
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(src)])
    wheels, sdists = sorted(out.glob("*.whl")), sorted(out.glob("*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1, list(out.iterdir())
    return wheels[0], sdists[0]


def _fresh_env(path: Path) -> Path:
    """A new venv without pip whose packages are its own first, then this environment's."""
    venv.EnvBuilder(with_pip=False).create(path)
    python = path / "bin" / "python"
    purelib = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"]
                   ).stdout.strip()
    Path(purelib, "_veil_test_deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    return python


def _install_and_smoke(python: Path, what: Path, tmp: Path):
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet",
          "--no-deps", "--no-index", "--no-build-isolation", str(what)])
    out = _run([str(python), "-c", SMOKE.format(version=VERSION)], cwd=tmp).stdout
    assert out.startswith(f"ok {VERSION} "), out
    veil = python.parent / "veil"
    assert _run([str(veil), "--version"], cwd=tmp).stdout.strip().endswith(VERSION)


def test_wheel_contents(dist):
    wheel, _ = dist
    names = zipfile.ZipFile(wheel).namelist()
    assert "veil/__init__.py" in names and "veil/models/forward_series.py" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), names[-10:]
    meta = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("METADATA"))).decode()
    for line in ("Provides-Extra: maps", "Provides-Extra: explore", "Provides-Extra: ingest",
                 "Provides-Extra: all", "Classifier: ", "Author: ", "License-Expression: MIT"):
        assert line in meta, line
    assert 'Requires-Dist: zarr' in meta and 'extra == "maps"' in meta
    core = [r for r in meta.splitlines() if r.startswith("Requires-Dist:") and "extra ==" not in r]
    assert not any(h in r for r in core for h in ("dask", "zarr", "panel", "rawpy", "OpenEXR")), core


def test_sdist_contents(dist):
    _, sdist = dist
    names = {n.split("/", 1)[1] for n in tarfile.open(sdist).getnames() if "/" in n}
    for name in ("pyproject.toml", "README.md", "LICENSE", "src/veil/__init__.py"):
        assert name in names, name


def test_wheel_installs_and_runs(dist, tmp_path):
    _install_and_smoke(_fresh_env(tmp_path / "venv"), dist[0], tmp_path)


def test_sdist_installs_and_runs(dist, tmp_path):
    _install_and_smoke(_fresh_env(tmp_path / "venv"), dist[1], tmp_path)


def test_citation_matches_the_version():
    """CITATION.cff repeats the version for citation tools; it must be pyproject's."""
    text = (ROOT / "CITATION.cff").read_text()
    versions = {line.split(":", 1)[1].strip().strip('"')
                for line in text.splitlines() if line.strip().startswith("version:")}
    assert versions == {VERSION}, versions
    assert "Baba" in text and "Mukaigawa" in text and "Yagi" in text
