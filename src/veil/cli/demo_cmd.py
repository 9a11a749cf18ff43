"""``veil demo``: a simulated acquisition of the paper's protocol, estimated end to end.

Sessions (docs/model.md sec. 6-7, relative noise ``--noise``): the reference BRDF2 in clear water,
the reference in BTDF2 with a black cloth, the target BRDF1 in BTDF2, and the target in clear
water (to score the estimate). The pipeline (:func:`veil.run_pipeline`) then recovers the
reference, the medium and the target; the recovered parameters are printed beside the true
ones. Each stage is one function, so further outputs (e.g. the paper's simulation figures)
are one more call in :func:`demo_command`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import click

from ..models import PRESETS
from ._common import OutputPath, accuracy_option, noise_option, seed_option

#: The demo's set-up: which preset plays which role.
SETUP = {"reference": "BRDF2", "medium": "BTDF2", "target": "BRDF1"}
#: Session files written under OUTDIR/data, by role.
SESSIONS = {
    "reference_clear": "reference_clear.csv",
    "reference_medium": "reference_medium.csv",
    "black": "black.csv",
    "target_medium": "target_medium.csv",
    "target_clear": "target_clear.csv",
}


def simulate_sessions(outdir: Path, seed: int, noise: float, accuracy: str, progress=None):
    """Simulate the four sessions into OUTDIR/data; returns {role: path}.

    Seeds: seed, seed+1, seed+2, seed+3 for reference clear, reference in the medium (and
    its black cloth), target in the medium, target clear. veil.simulate's glow depends on
    the medium only, so the one black cloth serves both sessions, as in the lab.
    """
    from ..data.measurements import save_measurements
    from ..data.simulate import simulate

    ref, med, tgt = (PRESETS[SETUP[k]] for k in ("reference", "medium", "target"))
    data = outdir / "data"
    data.mkdir(parents=True, exist_ok=True)
    paths = {role: data / name for role, name in SESSIONS.items()}

    def step(name):
        if progress:
            progress(f"simulating {name}", None, None)

    step("reference, clear water")
    save_measurements(
        simulate(ref, None, noise=noise, seed=seed, accuracy=accuracy), paths["reference_clear"]
    )
    step(f"reference in {SETUP['medium']} with the black cloth")
    table, black = simulate(ref, med, noise=noise, seed=seed + 1, black=True, accuracy=accuracy)
    save_measurements(table, paths["reference_medium"])
    save_measurements(black, paths["black"])
    step(f"target in {SETUP['medium']}")
    save_measurements(
        simulate(tgt, med, noise=noise, seed=seed + 2, accuracy=accuracy), paths["target_medium"]
    )
    step("target, clear water")
    save_measurements(
        simulate(tgt, None, noise=noise, seed=seed + 3, accuracy=accuracy), paths["target_clear"]
    )
    return paths


def fit_sessions(paths: dict, outdir: Path, accuracy: str, progress=None):
    """The whole estimation (veil.run_pipeline) on the simulated sessions."""
    from ..pipeline import run_pipeline

    truth = {k: PRESETS[v] for k, v in SETUP.items()}
    return run_pipeline(
        paths["reference_clear"],
        paths["reference_medium"],
        paths["target_medium"],
        black=paths["black"],
        target_clear=paths["target_clear"],
        outdir=outdir,
        accuracy=accuracy,
        progress=progress,
        truth=truth,
    )


def summary_table(result):
    """A rich table: every parameter, true value, recovered value +- total stderr, z."""
    from rich.table import Table

    table = Table(
        title="veil demo: recovered parameters against the truth",
        caption="stderr includes the uncertainty of the earlier steps; "
        "z = (recovered - true) / stderr",
    )
    for col, justify in (
        ("step", "left"),
        ("param", "left"),
        ("true", "right"),
        ("recovered", "right"),
        ("stderr", "right"),
        ("z", "right"),
    ):
        table.add_column(col, justify=justify)
    for step, key, fit in (
        ("0 reference", "reference", result.reference),
        ("1 medium", "medium", result.medium),
        ("2 target", "target", result.target),
    ):
        true_model = PRESETS[SETUP[key]]
        se_all = fit.stderr_total or fit.stderr
        for name, value in fit.params.items():
            true = getattr(true_model, name)
            se = se_all.get(name)
            z = (value - true) / se if se else math.nan
            table.add_row(
                f"{step} {SETUP[key]}",
                name,
                f"{true:.6g}",
                f"{value:.6g}",
                "n/a" if se is None else f"{se:.3g}",
                "n/a" if math.isnan(z) else f"{z:+.2f}",
            )
    return table


@click.command("demo", short_help="The paper's simulation experiment, then a whole estimation.")
@click.option(
    "-o",
    "--outdir",
    required=True,
    type=OutputPath(file_okay=False, path_type=Path),
    help="Directory for the simulated sessions (data/), the fit results, figures "
    "and report.md (created). Written as a whole at the end; an interrupted "
    "run leaves it as it was.",
)
@seed_option("Seed of the first session's noise (the others use seed+1, +2, +3).")
@noise_option("Relative noise of every measurement (0.01 = 1 %).", positive=True)
@accuracy_option("Quadrature of the simulation and of the fit results.")
@click.pass_context
def demo_command(ctx, outdir, seed, noise, accuracy):
    """The paper's simulation experiment (figs. 9-12, as `veil reproduce`), then a simulated
    acquisition (reference BRDF2 in water and in BTDF2 with a black cloth, target BRDF1 in
    BTDF2 and in water) estimated end to end.

    \b
        veil demo -o demo-out
    """
    from rich.console import Console

    from ..io import check_output_folder, output_folder
    from ..pipeline import FILES
    from ._common import fit_progress
    from .reproduce_cmd import reproduce

    check_output_folder(outdir)
    owned = ("paper-figures", "data", *FILES.values())
    with output_folder(outdir, owned=owned) as folder:
        # 1. the paper's simulation experiment (sec. 5.1): figs. 9-12 and report
        shown = os.path.join(outdir, "paper-figures")
        click.echo(f"The paper's simulation experiment (figs. 9-12) -> {shown}")
        reproduce(folder / "paper-figures", shown=shown)
        # 2. a simulated acquisition and the whole two-step estimation (sec. 5.2 / docs/model.md
        #    sec. 7)
        click.echo("A simulated acquisition, estimated end to end")
        with fit_progress("demo") as progress:
            paths = simulate_sessions(folder, seed, noise, accuracy, progress)
            result = fit_sessions(paths, folder, accuracy, progress)
    console = Console()
    console.print(summary_table(result))
    if result.comparison is not None:
        c = result.comparison
        console.print(
            f"Estimated target f_r against the target measured in clear water: rms "
            f"difference {100 * c['rms_fr_relative']:.3g} % over "
            f"{c['n_configurations']} protocol configurations."
        )
    console.print(f"Results, figures and report: {os.path.join(outdir, 'report.md')}")
    if not result.converged:
        click.echo("Error: a fit did not converge (see report.md)", err=True)
        ctx.exit(1)
