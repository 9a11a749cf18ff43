"""Fast start (issue 16): help, version, argument errors and the commands that do no numerics
never import numpy, JAX or the engine. Each case runs in a fresh interpreter, since this test
process has long imported JAX. (Speed itself is measured in benchmarks/bench_startup.py.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

HEAVY = ("numpy", "jax", "jaxlib", "veil._jax", "veil.engine.forward", "veil.engine.integrator",
         "scipy", "pandas", "matplotlib")

#: Run the command line in-process and report which heavy modules it imported.
PROBE = """
import json, sys
from veil.cli import main
try:
    main.main(sys.argv[1:], prog_name="veil")
    code = 0
except SystemExit as exc:
    code = exc.code
sys.stdout.flush()
sys.stderr.write("\\nPROBE " + json.dumps({"code": code,
    "loaded": [m for m in %r if m in sys.modules]}) + "\\n")
""" % (HEAVY,)


def probe(*args, env=None):
    run = subprocess.run([sys.executable, "-c", PROBE, *map(str, args)], capture_output=True,
                         text=True, env={**os.environ, **(env or {})}, timeout=120)
    line = [x for x in run.stderr.splitlines() if x.startswith("PROBE ")]
    assert line, run.stderr
    return json.loads(line[-1][6:]), run.stdout, run.stderr


def command_paths():
    from veil.cli import COMMANDS

    return sorted(COMMANDS) + ["plot lobe", "plot curve", "fit pipeline", "fit medium"]


@pytest.mark.parametrize("words", [[]] + [c.split() for c in command_paths()],
                         ids=lambda w: " ".join(w) or "veil")
def test_help_imports_no_numerics(words):
    result, out, err = probe(*words, "--help")
    assert result["code"] == 0, err
    assert "Usage:" in out
    assert result["loaded"] == [], f"veil {' '.join(words)} --help imported {result['loaded']}"


@pytest.mark.parametrize("args", [
    ["--version"],
    ["eval", "--brdf"],                              # option without its value
    ["eval", "--brdf", "BRDF1", "--medium", "BTDF1", "--accuracy", "best"],
    ["fit", "nonsense"],
    ["simulate", "--form", "polar", "--brdf", "BRDF1", "--medium", "BTDF1", "-o", "x.csv"],
    ["eval", "--brdf-model", "no-such-family", "--brdf", "1", "--medium", "none"],
], ids=lambda a: " ".join(a))
def test_version_and_argument_errors_import_no_numerics(args):
    result, out, err = probe(*args)
    assert result["code"] in (0, 2), err
    assert result["loaded"] == []


def test_models_command_imports_no_numerics():
    result, out, err = probe("models", "--json")
    assert result["code"] == 0, err
    assert result["loaded"] == []
    listed = json.loads(out[: out.rindex("}") + 1] if out.strip().startswith("{")
                        else out[: out.rindex("]") + 1])
    assert listed
    # the declared model error is listed where a model has one
    floors = {e["name"]: e["model_error_floor"] for e in listed}
    assert floors["forward-series"] == {"sigma": 0.005, "length": 40.0}
    assert floors["henyey-greenstein"] is None


def test_model_declarations_import_without_jax():
    code = ("import sys, veil.models as m, veil.engine.angles\n"
            "assert m.names() and m.PRESETS['BRDF1'].to_vector().size\n"
            "print(sorted(x for x in ('jax', 'veil._jax') if x in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_deferred_jax_is_veils_jax():
    """The models' stand-in gives veil's JAX set-up (float64) whatever was imported first."""
    code = ("import veil.models.fresnel as f, numpy as np\n"
            "from veil.models.base import BRDF\n"
            "x = f.jnp.asarray(np.float64(1) / 3)\n"
            "print(x.dtype, f.jnp.exp is __import__('jax').numpy.exp)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.split() == ["float64", "True"]


def test_command_line_constants_match_their_sources():
    from veil.cli import _common
    from veil.data.measurements import FORMS
    from veil.data.simulate import GLOW_LEVEL
    from veil.engine.quadrature import RULES

    assert _common.ACCURACIES == tuple(RULES)
    assert _common.TABLE_FORMS == tuple(FORMS)
    assert _common.GLOW_LEVEL == GLOW_LEVEL


def test_every_command_of_the_table_loads():
    """Each name -> "module:attribute" entry names a click command of that name."""
    import click
    from click.testing import CliRunner

    from veil.cli import COMMANDS, main

    for name in COMMANDS:
        *group, last = name.split()
        ctx = click.Context(main)
        cmd = main
        for word in name.split():
            cmd = cmd.get_command(ctx, word)
        assert isinstance(cmd, click.Command) and cmd.name == last, name
    r = CliRunner().invoke(main, ["--help"])
    for name in COMMANDS:
        if " " not in name:
            assert f"  {name} " in r.output


def test_every_short_help_is_a_whole_sentence():
    """click cuts a docstring's first line at its first ". ", so `veil --help` listed demo as
    "The paper's simulation experiment (figs." (and fit, fit joint, simulate at "sec."):
    every command's short help, as click takes it before fitting it to a width, closes its
    parentheses."""
    import click

    from veil.cli import COMMANDS, main

    for name in COMMANDS:
        ctx = click.Context(main)
        cmd = main
        for word in name.split():
            cmd = cmd.get_command(ctx, word)
        short = cmd.get_short_help_str(limit=300)
        assert short.count("(") == short.count(")"), f"veil {name}: {short!r}"


def test_ingest_imports_no_jax(tmp_path):
    """veil ingest does no numerics of the engine: photographs in, a table out, no JAX."""
    import numpy as np

    from test_ingest import ROI_TEXT, write_manifest, write_png

    photos = tmp_path / "photos"
    photos.mkdir()
    write_png(photos / "a.png", np.full((64, 96), 500, np.uint16))
    write_png(photos / "b.png", np.full((64, 96), 700, np.uint16))
    manifest = write_manifest(tmp_path / "m.csv", ["a.png", "b.png"])
    result, out, err = probe("ingest", photos, "--manifest", manifest, "--roi", ROI_TEXT,
                             "-o", tmp_path / "out.csv")
    assert result["code"] == 0, err
    assert (tmp_path / "out.csv").exists()
    assert not {"jax", "jaxlib", "veil._jax", "veil.engine.forward"} & set(result["loaded"])
