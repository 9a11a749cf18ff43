"""Every command of the command line on valid input (issue 33): the commands are read from
the command table (``veil.cli.COMMANDS``, groups expanded to their subcommands), so a new
command without a case here fails :func:`test_every_command_has_a_case`; each case runs the
command on small valid input and checks exit status 0 and the outputs it names.

The inputs are tiny (coarse protocols, 4 x 4 photos, "fast" quadrature) and made once for
the module; the commands run in one process, sharing the engine's compiled programs.
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np
import pytest

import veil
from support.cli import run
from support.maps import configurations, write_stack
from veil.cli import COMMANDS, main

COARSE = ["--fine-step", "5", "--coarse-step", "15", "--accuracy", "fast"]


def leaf_commands() -> set:
    """Every runnable command of ``veil`` as "group sub" names, from the command table."""
    out = set()

    def walk(command, prefix):
        if isinstance(command, click.Group):
            ctx = click.Context(command)
            for name in command.list_commands(ctx):
                walk(command.get_command(ctx, name), prefix + [name])
        else:
            out.add(" ".join(prefix))

    ctx = click.Context(main)
    for name in COMMANDS:
        walk(main.get_command(ctx, name.split()[0]), [name.split()[0]])
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Sessions (reference clear and through BTDF2, target through BTDF2, black cloth), the
    fit results of the three steps, a photo stack with its manifest, a maps store."""
    root = tmp_path_factory.mktemp("commands")
    proto = dict(fine_step=5.0, coarse_step=15.0, accuracy="fast")
    paths = {}
    tables = {"reference_clear": veil.simulate(veil.BRDF2, None, seed=1, **proto),
              "reference_medium": veil.simulate(veil.BRDF2, veil.BTDF2, seed=2, **proto)}
    target, black = veil.simulate(veil.BRDF1, veil.BTDF2, seed=3, black=True, **proto)
    tables.update(target_medium=target, black=black)
    for name, table in tables.items():
        paths[name] = root / f"{name}.csv"
        veil.save_measurements(table, paths[name])
    for name, args in (("reference", ["fit", "reference", paths["reference_clear"]]),
                       ("medium", ["fit", "medium", paths["reference_medium"], "--reference",
                                   root / "reference.json", "--accuracy", "fast"]),
                       ("target", ["fit", "target", paths["target_medium"], "--medium",
                                   root / "medium.json", "--black", paths["black"],
                                   "--accuracy", "fast"])):
        result = run(*args, "-o", root / f"{name}.json")
        assert result.exit_code == 0, result.output
        paths[name] = root / f"{name}.json"
    h, w = 4, 4
    pm = np.repeat(veil.BRDF1.to_vector()[:, None, None], h, 1).repeat(w, 2)
    paths["manifest"] = write_stack(root / "photos", veil.BRDF1, veil.BTDF2,
                                    configurations(8), pm, noise=0.0)
    paths["photos"] = root / "photos"
    paths["store"] = root / "maps.zarr"
    result = run(*maps_args(paths, paths["store"]))
    assert result.exit_code == 0, result.output
    return paths


def maps_args(p, out):
    return ["fit", "maps", p["photos"], "--manifest", p["manifest"], "--medium", "BTDF2",
            "--fix", "eta=1.5", "--grid", "n=0.3:3:6", "--tile", 8, "--accuracy", "fast",
            "-o", out]


def _cases(p, out: Path) -> dict:
    """name -> (arguments, outputs that must exist and be non-empty)."""
    s = p
    return {
        "eval": (["eval", "--brdf", "BRDF1", "--medium", "BTDF2", "--theta-i", 30,
                  "--theta-r", 30, "--accuracy", "fast", "--json", "-o", out / "eval.json"],
                 ["eval.json"]),
        "ingest": (["ingest", s["photos"], "--manifest", s["manifest"], "--roi", "0,0,2,2",
                    "-o", out / "ingested.csv"], ["ingested.csv"]),
        "simulate": (["simulate", "--brdf", "BRDF1", "--medium", "BTDF2", "-o",
                      out / "sim.csv", "--black", out / "sim_black.csv", *COARSE],
                     ["sim.csv", "sim_black.csv"]),
        "render": (["render", "--brdf", "BRDF1", "--medium", "BTDF2", "--size", 16,
                    "--check", 4, "--quiet", "--linear", out / "sphere.npy", "-o",
                    out / "sphere.png"], ["sphere.png", "sphere.npy"]),
        "plot curve": (["plot", "curve", "--brdf", "BRDF1", "--medium", "BTDF2",
                        "--accuracy", "fast", "-o", out / "curve.png"], ["curve.png"]),
        "plot lobe": (["plot", "lobe", "--brdf", "BRDF1", "-o", out / "lobe.png"],
                      ["lobe.png"]),
        "plot transmission": (["plot", "transmission", "--medium", "BTDF2", "-o",
                               out / "trans.png"], ["trans.png"]),
        "reproduce": (["reproduce", "-o", out / "repro", "--size", 16, "--check", 4,
                       "--accuracy", "fast", "--dpi", 40, "--quiet"], ["repro"]),
        "fit reference": (["fit", "reference", s["reference_clear"], "-o", out / "r.json"],
                          ["r.json"]),
        "fit medium": (["fit", "medium", s["reference_medium"], "--reference",
                        s["reference"], "--accuracy", "fast", "-o", out / "m.json"],
                       ["m.json"]),
        "fit target": (["fit", "target", s["target_medium"], "--medium", s["medium"],
                        "--black", s["black"], "--accuracy", "fast", "-o", out / "t.json"],
                       ["t.json"]),
        "fit pipeline": (["fit", "pipeline", "--reference-clear", s["reference_clear"],
                          "--reference-medium", s["reference_medium"], "--target-medium",
                          s["target_medium"], "--black", s["black"], "--accuracy", "fast",
                          "-o", out / "pipeline"], ["pipeline/report.md"]),
        "fit joint": (["fit", "joint", "--session", f"m={s['target_medium']}",
                       "--black", f"m={s['black']}", "--reference-session",
                       f"m={s['reference_medium']}", "--reference", s["reference"],
                       "--accuracy", "fast", "-o", out / "joint.json"], ["joint.json"]),
        "fit maps": (maps_args(s, out / "maps.zarr"), ["maps.zarr/summary.json"]),
        "maps show": (["maps", "show", s["store"], "-o", out / "maps.png"], ["maps.png"]),
        "maps export": (["maps", "export", s["store"], "-o", out / "maps"],
                        ["maps/summary.json"]),
        "diagnose": (["diagnose", s["target"], "--data", s["target_medium"], "--black",
                      s["black"], "--medium", s["medium"], "-o", out / "diag"],
                     ["diag/diagnostics.json", "diag/diagnostics.png"]),
        "design": (["design", "--brdf", "BRDF1", "--medium", "BTDF2", "--size", 8, "--psi",
                    "60", *COARSE, "-o", out / "plan.csv"], ["plan.csv"]),
        "demo": (["demo", "-o", out / "demo", "--accuracy", "fast"], ["demo"]),
        "models": (["models"], []),
        "warmup": (["warmup", "--models", "torrance-sparrow", "--accuracy", "fast",
                    "--quiet"], []),
        "export": (["export", s["target"], s["medium"], "--to", "csv", "-o",
                    out / "curves.csv"], ["curves.csv"]),
        "explore": (["explore", s["target"], "--static", "--points", 2, "-o",
                     out / "page.html"], ["page.html"]),
    }


def test_every_command_has_a_case(tmp_path):
    """A command added to the table without a case here fails this test."""
    cases = set(_cases({k: tmp_path for k in ("photos", "manifest", "store", "reference",
                                               "medium", "target", "reference_clear",
                                               "reference_medium", "target_medium",
                                               "black")}, tmp_path))
    commands = leaf_commands()
    assert commands == cases, (f"commands without a case: {sorted(commands - cases)}; "
                               f"cases of no command: {sorted(cases - commands)}")
    assert {"fit maps", "maps show", "plot lobe", "warmup", "demo"} <= commands


def _spy_on_locks(monkeypatch) -> list:
    """The folders committed under veil.io's commit lock and the maps stores written under
    their store lock, as they happen."""
    import veil.maps.run as maps_run
    from veil import io as vio

    locked = []
    commit, store = vio._commit_lock, maps_run.store_lock

    def commit_spy(path):
        locked.append(Path(path))
        return commit(path)

    def store_spy(path, say=None):
        locked.append(Path(path).absolute())
        return store(path, say)

    monkeypatch.setattr(vio, "_commit_lock", commit_spy)
    monkeypatch.setattr(maps_run, "store_lock", store_spy)
    return locked


@pytest.mark.parametrize("name", sorted(leaf_commands()),
                         ids=lambda n: n.replace(" ", "-"))
def test_command_runs_on_valid_input(name, inputs, tmp_path, monkeypatch):
    if name == "demo":  # `veil reproduce` at full size, then the paper's protocol fitted:
        # both smaller here (each is run as it is by its own case)
        import functools

        import veil.cli.reproduce_cmd as reproduce_cmd
        import veil.data.simulate as simulate

        monkeypatch.setattr(reproduce_cmd, "reproduce", functools.partial(
            reproduce_cmd.reproduce, size=16, accuracy="fast", check=4, dpi=40, quiet=True))
        monkeypatch.setattr(simulate, "simulate", functools.partial(
            simulate.simulate, fine_step=5.0, coarse_step=15.0))
    locked = _spy_on_locks(monkeypatch)
    args, outputs = _cases(inputs, tmp_path)[name]
    result = run(*args)
    assert result.exit_code == 0, result.output
    for rel in outputs:
        path = tmp_path / rel
        assert path.exists(), f"{name}: {rel} not written"
        top = tmp_path / Path(rel).parts[0]
        if top.is_dir():  # a folder or a store: written under a lock another process
            # respects (test_hardening2.py runs two writers at once)
            assert top in locked, f"{name}: {top.name} written without the commit lock"
        if path.is_dir():
            assert any(path.iterdir()), f"{name}: {rel} is empty"
        else:
            assert path.stat().st_size > 0, f"{name}: {rel} is empty"
            if path.suffix == ".json":
                json.loads(path.read_text())
    assert not list(tmp_path.rglob("*.tmp")) and not list(tmp_path.glob(".*veil-partial*"))


def test_a_long_stage_off_a_terminal_says_its_count_again(capsys):
    """One line per stage, and within a stage one more only when its count moved and the
    last line is STAGE_LINE_SECONDS old (a fake clock): a log of a long stage is not silent,
    and a fast one is not flooded."""
    from veil.cli._common import STAGE_LINE_SECONDS, _stage_lines

    now = [0.0]
    progress = _stage_lines("maps", clock=lambda: now[0])
    for t, stage, done in [(0, "tables", 0), (1, "tables", 1),
                           (STAGE_LINE_SECONDS - 1, "tables", 2),
                           (STAGE_LINE_SECONDS + 0.5, "tables", 3),
                           (2 * STAGE_LINE_SECONDS + 1, "tables", 3),
                           (2 * STAGE_LINE_SECONDS + 2, "solving tiles", 0)]:
        now[0] = t
        progress(stage, done, 48 if stage == "tables" else 4)
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["veil maps: tables (0/48)", "veil maps: tables (3/48)",
                     "veil maps: solving tiles (0/4)"]


def test_a_fit_off_a_terminal_says_each_stage_on_a_line(tmp_path, monkeypatch):
    """A fit run in a log or CI (not a terminal) is not silent: one stderr line per stage of
    its progress (the starts, each start's iterations), none of them a rich display's."""
    monkeypatch.setattr("veil.cli._common.STAGE_LINE_SECONDS", float("inf"))
    for forcing in ("FORCE_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE"):  # (rich's, in CI)
        monkeypatch.delenv(forcing, raising=False)
    monkeypatch.setattr("veil.cli.compile_display._CONSOLE", None)  # made afresh, not a tty
    table = tmp_path / "clear.csv"
    assert run("simulate", "--brdf", "BRDF1", "--medium", "none", "-o", table).exit_code == 0
    result = run("fit", "reference", table, "-o", tmp_path / "ref.json")
    assert result.exit_code == 0, result.output
    lines = [ln for ln in result.stderr.splitlines() if ln.startswith("veil ")]
    stages = [ln.split(": ", 1)[1] for ln in lines]
    assert stages[0].startswith("starting")
    assert any(s.startswith("start 1/") for s in stages), stages
    assert len(stages) == len(set(stages)) >= 3  # a line per stage, not per evaluation
    assert "\x1b[" not in result.stderr  # no terminal control sequences in a log
