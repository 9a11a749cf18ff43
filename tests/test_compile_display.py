"""The compile display (issue 28): what the engine compiles is announced with a rough
estimate, shown as a live row on a terminal and as one line per program otherwise; the
store learns its compile rate; ``veil warmup`` runs (issue 33, item 1)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest

import veil

from support.compiles import compilations
from veil._jax import jax
from veil.cli import compile_display
from veil.engine import compiling, programs


def _double_program(tag: str) -> programs.Program:
    return programs.Program(jax.jit(lambda x: 2.0 * x + float(len(tag))), f"test {tag}",
                            label=f"a test program ({tag})")


def test_a_compilation_is_announced_with_an_estimate_and_the_rate_is_learned(
        tmp_path, monkeypatch):
    monkeypatch.setenv("VEIL_CACHE_DIR", str(tmp_path))
    events = []
    stop = compiling.listen(lambda e, c, s: events.append((e, c.label, c.lines, c.estimate, s)))
    try:
        out = _double_program("announce")(np.arange(3.0))
        _double_program("announce")(np.arange(3.0))  # a new Program object: loaded, not built
    finally:
        stop()
    assert np.array_equal(np.asarray(out), 2.0 * np.arange(3.0) + 8.0)
    assert [e[0] for e in events] == ["start", "end"]
    (_, label, lines, estimate, _), (_, _, _, _, seconds) = events
    assert label == "a test program (announce)"
    default = compiling.SECONDS_PER_LINE["values"]
    assert lines > 3 and estimate == pytest.approx(lines * default)
    assert seconds > 0
    with open(tmp_path / "programs" / compiling.TIMES_FILE) as fh:
        rates = json.load(fh)["seconds_per_line"]
    expected = (1 - compiling.LEARNING_RATE) * default + compiling.LEARNING_RATE * seconds / lines
    assert rates["values"] == pytest.approx(expected, rel=1e-9)
    assert rates["jacobian"] == compiling.SECONDS_PER_LINE["jacobian"]  # not measured yet
    assert compiling.seconds_per_line("values") == pytest.approx(rates["values"])
    assert compiling.kind_of("terms+jacobian (1,) () | x") == "jacobian"
    assert compiling.kind_of("f_r jacobian | x") == "jacobian"
    assert compiling.kind_of("terms | x") == "values"


def test_without_a_store_compilations_are_still_announced(monkeypatch):
    monkeypatch.setenv("VEIL_CACHE_DIR", "off")
    events = []
    stop = compiling.listen(lambda e, c, s: events.append(e))
    try:
        _double_program("no store")(np.ones(2))
    finally:
        stop()
    assert events == ["start", "end"]


def _compilation(label="rough-plastic x forward-series: values, fast rule", estimate=12.0):
    return compiling.Compilation(label, label, 1000, estimate, 0.0)


def test_the_programs_of_the_plane_of_incidence_are_named_apart():
    """Configurations all in the plane of incidence run programs of their own (half the
    azimuths, docs/engine.md); their labels say so, so that the display and the suite's
    census do not show one program compiled twice."""
    from veil.engine.apparent import RULES
    from veil.engine.channel_programs import _channel_terms_fn
    from veil.engine.forward import Forward, _terms_fn, jacobian_program
    from veil_test_models import FisherTest, LambertianTest

    b, m = LambertianTest(rho=0.8), FisherTest(Td=2e-3, Tt=0.2, kappa=150.0)
    th = np.linspace(10.0, 70.0, 5)
    labels = {}
    for psi in (0.0, 10.0):
        f = Forward(b, m, th, th, 180.0, psi, rule=RULES["fast"])
        labels[f.half] = [
            _terms_fn(f._kb, f._km, f.rule, f.half, f._mesh).label,
            jacobian_program(None, f._kb, f._km, f.rule, f.half, (), (2,), f._mesh).label,
            _channel_terms_fn(f._kb, f._km, f.rule, f.half, 3, f._mesh).label,
        ]
    assert sorted(labels) == [False, True]
    assert labels[True][0] == ("lambertian-test x fisher-test: values, fast rule, in the plane "
                               "of incidence")
    assert labels[True][1].endswith("values and d/d(kappa), fast rule, in the plane of incidence")
    assert labels[True][2].endswith("values of 3 channels, fast rule, in the plane of incidence")
    assert [label + ", in the plane of incidence" for label in labels[False]] == labels[True]
    # the medium's parameter of a name the BRDF's has too is named as the medium's
    tp, hg = veil.preset("BRDF1"), veil.preset("BTDF1")
    f = Forward(tp, hg, th, th, 180.0, 10.0, rule=RULES["fast"])
    both = jacobian_program(None, f._kb, f._km, f.rule, f.half, (2, 3), (2, 3), f._mesh).label
    assert "values and d/d(n, eta, g, medium's eta), fast rule" in both, both


def test_lines_when_not_on_a_terminal(capsys):
    display = compile_display.CompileDisplay(live=False)
    c = _compilation()
    display("start", c, 0.0)
    display("end", c, 11.2)
    display("start", _compilation("b", 0.3), 0.0)
    display("failed", _compilation("b", 0.3), 0.1)
    display.close()
    err = capsys.readouterr().err.splitlines()
    assert err[0] == ("veil: compiling rough-plastic x forward-series: values, fast rule "
                      "(about 12 s; once: kept in the program store for later runs)")
    assert err[1].startswith("veil: compiling b (under a second")
    assert err[2] == ("veil: compiled 1 engine program in 11 s of compile time; later runs "
                      "load them")
    assert len(err) == 3


def test_live_rows_on_a_terminal(monkeypatch):
    from rich.console import Console

    screen = io.StringIO()
    monkeypatch.setattr(compile_display, "_CONSOLE",
                        Console(file=screen, force_terminal=True, width=120))
    display = compile_display.CompileDisplay(live=None)  # decided at the first compilation
    c = _compilation()
    display("start", c, 0.0)
    assert display.live is True and len(display._rows) == 1
    display("end", c, 11.2)
    assert display._rows == {}
    display.close()
    assert "compiled rough-plastic x forward-series: values, fast rule in 11.2 s" in \
        screen.getvalue()


def test_nested_blocks_share_one_display():
    with compile_display.shown(live=False) as outer, compile_display.shown() as inner:
        assert inner is outer


def test_warmup_runs(tmp_path):
    """``veil warmup`` of one family pair at the fits' accuracy (issue 33, item 1: it exited 3).
    Uses the suite's program store (the fits compile the same programs)."""
    env = dict(os.environ)
    run = subprocess.run([sys.executable, "-m", "veil.cli", "warmup", "--models",
                          "torrance-sparrow", "--accuracy", "fast", "--quiet"],
                         capture_output=True, text=True, env=env, timeout=900)
    assert run.returncode == 0, run.stderr
    assert "veil warmup: 3 of 3 tasks ready" in run.stderr


def test_warmup_prepares_the_geometry_and_the_channels_the_fits_will_run():
    """``veil warmup`` with a plate's geometry and ``--channels``: the tasks carry the
    geometry to the programs, and the channels' task of a forward-series water prepares
    the very program a colour fit's channels then run (nothing left to compile); a medium
    whose channels run one at a time gets no such task."""
    from veil.engine import warmup
    from veil.engine.evaluator import CHUNK, ApparentModel
    from veil.engine.forward import wait_for_compilations
    from veil.engine.quadrature import RULES
    from veil.models import model_class

    geometry = {"path_length": 15.0, "plate_width": 5.0}
    todo = warmup.tasks(["torrance-sparrow", "forward-series", "henyey-greenstein"],
                        ("default",), medium_options=geometry, channels=2)
    labels = [t.label for t in todo]
    water = "torrance-sparrow x forward-series (path_length=15, plate_width=5)"
    assert f"{water}: 2 channels together (fast, values and Jacobians)" in labels
    assert f"{water}: 2 channels together (default, values)" in labels
    assert not [label for label in labels if "henyey-greenstein: 2 channels" in label]
    assert "torrance-sparrow x henyey-greenstein: fit iterations (fast, values and Jacobian)" \
        in labels  # the geometry goes to the families that declare it only

    next(t for t in todo if t.label == f"{water}: 2 channels together (default, values)").run()
    wait_for_compilations()
    brdf = model_class("torrance-sparrow", "brdf").template()
    medium = model_class("forward-series", "medium").template(**geometry)
    model = ApparentModel(brdf, medium, warmup._angles(CHUNK), RULES["default"])
    vm = medium.to_vector()
    waters = [vm, medium.replace(tau=0.5 * medium.tau).to_vector()]
    with compilations() as compiled:
        model.anticipate([brdf.to_vector()] * 2, waters)
    assert compiled == []


@pytest.mark.parametrize("args, message", [
    (["--path-length", "15"], "--path-length applies to none of the families to prepare"),
    (["--models", "forward-series", "--channels", "0"], "Invalid value for '--channels'"),
    # a camera has a handful of channels: 100000 used to run away (1.2 GB, killed)
    (["--models", "forward-series", "--accuracy", "fast", "--channels", "65"],
     "Invalid value for '--channels': 65 is not in the range 1<=x<=64"),
    (["--models", "forward-series", "--path-length", "-1"], "path_length"),
])
def test_bad_options_of_the_ahead_of_time_compilation_exit_2(args, message):
    from click.testing import CliRunner

    from veil.cli import main

    result = CliRunner().invoke(main, ["warmup", "--quiet", *args])
    assert result.exit_code == 2, result.output
    assert message in result.output


def test_warmup_help_gives_the_channels_bound():
    from click.testing import CliRunner

    from veil.cli import main

    result = CliRunner().invoke(main, ["warmup", "--help"])
    assert result.exit_code == 0
    assert "At most 64: a camera has a handful of channels" in " ".join(result.output.split())
