"""What the fit commands print besides each fit's report: the rankings of ``--models
auto`` and the pipeline's reports with its comparison against the direct fit."""

from __future__ import annotations

import click


def print_pipeline(result) -> None:
    """The rankings (``--models auto``), the fit reports of a
    :class:`veil.pipeline.PipelineResult` and its comparison."""
    for ranking in getattr(result, "rankings", {}).values():
        print_ranking(ranking)
    for r in (result.reference, result.medium, result.target, result.direct):
        if r is not None:
            click.echo(r.report())
            click.echo("")
    if result.comparison is not None:
        c = result.comparison
        click.echo("[[Estimated target f_r against the direct fit]]")
        for name, row in c["params"].items():
            z = "n/a" if row["z"] is None else f"{row['z']:+.2f}"
            click.echo(
                f"    {name:<4}: estimated {row['estimated']:.6g}, direct "
                f"{row['direct']:.6g}, difference {row['difference']:+.3g} "
                f"({z} combined stderr)"
            )
        click.echo(
            f"    rms f_r difference over {c['n_configurations']} protocol "
            f"configurations: {c['rms_fr_difference']:.4g} "
            f"({100 * c['rms_fr_relative']:.3g} % rms relative)"
        )


def print_ranking(ranking) -> None:
    """One step's ranking of ``--models auto`` as a table."""
    from ..fitting.selection import table_lines

    on = f" on {ranking.on}" if getattr(ranking, "on", None) else ""
    click.echo(
        f"[[Candidates of step '{ranking.step}', ranked{on} by BIC with the "
        f"model-discrepancy term; * the one used]]"
    )
    for line in table_lines(ranking):
        click.echo("    " + line)
    click.echo("")
