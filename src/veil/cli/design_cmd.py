"""``veil design``: recommend a measurement plan (docs/model.md sec. 1, 7; docs/ambiguity.md).

Ranks goniometer configurations (psi, rho) under candidate medium conditions by how much
they shrink the target's parameter uncertainty (greedy D_s-optimal selection on the Fisher
information, :mod:`veil.design`), prints the plan and the conditions, and writes the plan as
CSV (angles in degrees, each row's medium in medium_* columns). Exit status 2 for input
mistakes.
"""

from __future__ import annotations

import math
from pathlib import Path

import click

from ._common import (
    FloatRange,
    OutputPath,
    UserError,
    accuracy_option,
    check_output_path,
    model_options,
    noise_option,
    options_named,
    rotation_options,
)


def _floats(text, option):
    values = []
    for part in text.split(","):
        part = part.strip()
        try:
            values.append(float(part))
        except ValueError:
            raise UserError(f"{option} {text!r}: {part!r} is not a number") from None
    return tuple(values)


def _se(info, name, value) -> str:
    """Relative for parameters fitted as logarithms (e.g. Ps/Pd, n), absolute for the others
    (e.g. eta); "*" marks a value at the level of the design's weak prior (the plan does not
    identify the parameter)."""
    from ..analysis.design import PRIOR_SD_LOG, PRIOR_SD_PLAIN

    plain = info.prior[info.names.index(name)] == 1.0 / PRIOR_SD_PLAIN**2
    prior = PRIOR_SD_PLAIN if plain else PRIOR_SD_LOG
    mark = " *" if value > 0.3 * prior else ""
    return (f"{value:.3g}" if plain else f"{100 * value:.3g} %") + mark


def _conditions(named: dict, factors) -> dict:
    """The media to compare, each at the concentration ``factors`` when given."""
    facs = _floats(factors, "--factors") if factors else None
    if facs is None:
        return named
    bad = [f for f in facs if not (math.isfinite(f) and f > 0)]
    if bad:
        raise UserError(
            f"--factors {factors!r}: {bad[0]:g} is not a concentration factor; "
            f"expected finite numbers > 0 (e.g. 0.5,1,2)"
        )
    from ..analysis.design import condition_medium

    out = {f"{label} x{f:g}": condition_medium(m, f) for label, m in named.items() for f in facs}
    if len(out) != len(named) * len(facs):
        raise UserError(f"--factors {factors!r}: a factor is repeated")
    return out


def _plan_table(plan):
    """The plan as a rich table, signed in-plane angles."""
    from rich.markup import escape
    from rich.table import Table

    table = Table(
        title=f"Plan of {len(plan)} measurements (greedy D_s-optimal, best first)",
        title_justify="left",
    )
    for col in ("step", "condition", "psi", "rho", "theta_i", "theta_r", "gain"):
        table.add_column(col, justify="left" if col == "condition" else "right")
    for row in plan.itertuples():
        ti = row.theta_i if row.phi_i == 180.0 else -row.theta_i
        tr = row.theta_r if row.phi_r == 0.0 else -row.theta_r
        table.add_row(
            str(row.step),
            escape(row.condition),
            f"{row.psi:g}",
            f"{row.rho:g}",
            f"{ti:g}",
            f"{tr:g}",
            f"{row.gain:.3g}",
        )
    return table


def _media(media, models) -> tuple[list[str], list]:
    """(labels, media) of the --medium options: scattering media, none twice."""
    chosen = []
    for text in media:
        m = models.medium_model(text)
        if m is None:
            raise UserError(
                "--medium none: the design compares scattering media; give a preset or literal"
            )
        chosen.append(m)
    labels = [t.strip().upper() if "," not in t else t.strip() for t in media]
    if len(set(labels)) != len(labels):
        raise UserError("a --medium is given twice")
    return labels, chosen


def _print_design(plan, result: dict, info, mapping: dict) -> None:
    """The plan, the conditions (each alone) and the predicted standard errors as tables."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    console.print(_plan_table(plan))
    names = [info.names[k] for k in info.interest]
    ctab = Table(
        title="Conditions (predicted stderr of the interest parameters, plan of the "
        "same size from one condition alone)",
        title_justify="left",
    )
    ctab.add_column("condition")
    ctab.add_column("in plan", justify="right")
    for n in names:
        ctab.add_column(escape(f"{n} alone"), justify="right")
    for row in result["conditions"].to_dict("records"):
        ctab.add_row(
            escape(mapping[row["condition"]]),
            str(row["in_plan"]),
            *[_se(info, n, row[f"alone_se_{n}"]) for n in names],
        )
    console.print(ctab)
    se = result["stderr"]
    console.print(
        "predicted stderr with the plan: "
        + ", ".join(f"{n} {_se(info, n, se[n])}" for n in names)
        + " (relative for parameters fitted as logarithms, else absolute)"
    )
    if "*" in "".join(_se(info, n, se[n]) for n in names) or any(
        "*" in _se(info, n, r[f"alone_se_{n}"])
        for r in result["conditions"].to_dict("records")
        for n in names
    ):
        console.print(
            "* at the level of the weak prior: not identified by such a plan "
            "(more measurements, or other media)"
        )


@click.command("design")
@click.option(
    "--brdf",
    required=True,
    metavar="MODEL",
    help="The expected target: preset (BRDF1, BRDF2) or a literal list of the "
    "--brdf-model's parameters ('PD,PS,N,ETA' for the paper's).",
)
@click.option(
    "--medium",
    "media",
    required=True,
    multiple=True,
    metavar="MODEL",
    help="A candidate medium: preset (BTDF1..3) or a literal list of the "
    "--medium-model's parameters ('TD,TT,G,ETA' for the paper's); repeat for "
    "several (e.g. concentrations).",
)
@click.option(
    "--factors",
    default=None,
    metavar="C,...",
    help="Concentration factors of every --medium (e.g. 0.5,1,2; the paper's medium "
    "scales Td and Tt).",
)
@click.option(
    "--size",
    type=click.IntRange(min=1),
    default=60,
    show_default=True,
    help="Number of measurements in the plan.",
)
@click.option(
    "--psi",
    default="30,45,60,75,90,105,120",
    show_default=True,
    metavar="DEG,...",
    help="Candidate relative angles between light and camera, degrees.",
)
@rotation_options(candidate=True)
@noise_option("Relative noise of a measurement (0.01 = 1 %).")
@click.option(
    "--noise-floor",
    type=FloatRange(min=0),
    default=0.0,
    show_default=True,
    help="Absolute noise floor, in value units (added in quadrature).",
)
@click.option(
    "--known-medium",
    is_flag=True,
    help="Treat the media as exactly known (two-step view); default: their "
    "parameters are estimated too, as in 'veil fit joint'.",
)
@click.option(
    "--interest",
    default=None,
    metavar="NAMES",
    help="Target parameters whose uncertainty the plan should shrink (default: the "
    "ratios of the BRDF's scales and its other parameters, Ps/Pd,n,eta for the "
    "paper's).",
)
@accuracy_option("Quadrature of the Jacobians.", default="fast")
@click.option(
    "-o",
    "--output",
    type=OutputPath(dir_okay=False, path_type=Path),
    help="CSV file for the plan (written atomically).",
)
@model_options()
@options_named(
    {"noise": "--noise", "noise floor": "--noise-floor", "size": "--size", "psi": "--psi"}
)
def design_command(
    brdf,
    media,
    factors,
    size,
    psi,
    fine_step,
    window,
    coarse_step,
    limit,
    noise,
    noise_floor,
    known_medium,
    interest,
    accuracy,
    output,
    models,
):
    """Recommend which configurations and media to measure.

    \b
        veil design --brdf BRDF1 --medium BTDF1 --medium BTDF2 --medium BTDF3 --size 60 \\
            -o plan.csv
    """
    from ..analysis.design import design
    from ..io import write_text_atomic

    model_b = models.brdf_model(brdf)
    labels, chosen = _media(media, models)
    if output is not None:
        check_output_path(output)
    named = _conditions(dict(zip(labels, chosen)), factors)
    from ._common import echo_warnings

    with echo_warnings():
        result = design(
            model_b,
            list(named.values()),
            size,
            psi=_floats(psi, "--psi"),
            noise=noise,
            floor=noise_floor,
            mode="known" if known_medium else "joint",
            interest=None
            if interest is None
            else [t.strip() for t in interest.split(",") if t.strip()],
            accuracy=accuracy,
            fine_step=fine_step,
            coarse_step=coarse_step,
            window=window,
            limit=limit,
        )
    plan, info = result["plan"], result["information"]
    mapping = dict(zip(info.conditions, named))
    plan["condition"] = [mapping[c] for c in plan["condition"]]
    _print_design(plan, result, info, mapping)
    if output is not None:
        write_text_atomic(output, plan.to_csv(index=False, lineterminator="\n"))
        click.echo(f"wrote {output}", err=True)
