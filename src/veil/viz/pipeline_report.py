"""report.md of the pipeline (:func:`veil.run_pipeline`): per step the parameter table
(value, standard errors, the truth when known), the fit's statistics and figure; the
target fitted directly against the estimate; with ``--models auto`` the rankings."""

from __future__ import annotations

import os

from ..analysis.comparison import true_values, truth_family
from ..fitting.result import FitResult
from ..numbers import format_number


def _param_table(result: FitResult, truth) -> list[str]:
    """The parameters' table; with ``truth`` (the step's true model, or {channel: model}) the
    true value and the deviation, channel by channel for a fit over several
    (:func:`veil.analysis.comparison.true_values`)."""
    head = "| parameter | value | stderr | stderr incl. given model |"
    rule = "|---|---:|---:|---:|"
    other = None if truth is None else truth_family(result, truth)
    trues = None if truth is None or other is not None else true_values(result, truth)
    if trues is not None:
        head += " true | (value - true) / stderr |"
        rule += "---:|---:|"
    lines = [head, rule]
    for name, value in result.params.items():
        if name in result.fixed:
            se = tot = "at its bound" if name in result.at_bound else "fixed"
        else:
            se = format_number(result.stderr.get(name), 3)
            tot = (
                format_number((result.stderr_total or {}).get(name), 3)
                if result.stderr_total is not None
                else "-"
            )
        line = f"| {name} | {format_number(value, 6)} | {se} | {tot} |"
        if trues is not None:
            true = trues.get(name)
            s = (result.stderr_total or result.stderr).get(name)
            z = (value - true) / s if s and true is not None else None
            shown = "differs per channel" if true is None else format_number(true, 6)
            line += f" {shown} | {format_number(z, 3)} |"
        lines.append(line)
    if other is not None:
        lines.append(
            f"\nThe truth is a {other} model and the fit a {result.model_class.NAME} model: "
            f"their parameters are not compared."
        )
    return lines


def _stats_lines(result: FitResult) -> list[str]:
    weight = (
        "weighted by sigma"
        if result.weighted
        else "unweighted (no sigma column): standard errors scaled by the reduced chi-square"
    )
    lines = [
        f"- {result.n_points} points, {weight}; reduced chi-square "
        f"{format_number(result.chi2_reduced, 4)}, rms relative residual "
        f"{format_number(100 * result.rms_relative, 3)} %",
        f"- converged: {'yes' if result.converged else '**NO**'} ({result.message})",
    ]
    if result.accuracy:
        lines.append(f"- quadrature accuracy of the result: {result.accuracy}")
    if result.variant:
        lines.append(f"- medium Fresnel variant: {result.variant} (docs/model.md sec. 3)")
    how = (result.stats or {}).get("propagation")
    if how and result.stderr_total is not None:
        lines.append(
            '- the given model\'s uncertainty in "stderr incl. given model": '
            + (
                f"through {how.get('refits')} refits at {how.get('points')} sigma points "
                f"({how.get('converged')} converged)"
                if how.get("method") == "sigma-points"
                else "to first order" + (f" ({how['fallback']})" if how.get("fallback") else "")
            )
        )
    term = getattr(result, "model_error", None)
    if term is not None and term.sigma > 0:
        length = (
            f", correlated over {format_number(term.length, 3)} deg"
            if term.length
            else ", independent between configurations"
        )
        where = {
            "own residuals": "shown by this fit's residuals: reduced chi-square above "
            f"{format_number(term.chi2_threshold, 4)}",
            "model's floor": "the model's declared error (MODEL_ERROR_FLOOR), more than "
            "this fit's residuals show",
            "given medium": "inherited from the medium's fit",
        }[term.source]
        lines.append(
            f"- model error: {format_number(100 * term.sigma, 3)} % of the model's "
            f"value{length} ({where}), included in the standard errors "
            f"(docs/validity.md)"
        )
    elif term is not None:
        lines.append(
            f"- model error: none shown by the residuals (reduced chi-square <= "
            f"{format_number(term.chi2_threshold, 4)})"
        )
    return lines


def _comparison_lines(direct: FitResult, comparison: dict, figures: dict) -> list[str]:
    """report.md's section on the target fitted directly, against the estimate."""
    out = [
        "## The target measured directly, against the estimate",
        "",
        "The target's clear-medium data fitted directly (no medium); the estimate of "
        "step 2 against it. z = difference / sqrt(stderr_est^2 + stderr_direct^2), "
        "with the estimate's stderr including the given model's.",
        "",
        "| parameter | estimated (step 2) | direct | difference | z |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, row in comparison["params"].items():
        out.append(
            f"| {name} | {format_number(row['estimated'], 6)} | "
            f"{format_number(row['direct'], 6)} | "
            f"{format_number(row['difference'], 3)} | {format_number(row['z'], 3)} |"
        )
    out += [
        "",
        f"Over the {comparison['n_configurations']} configurations of the paper's "
        f"protocol (psi = 30, 60, 90 deg): rms of f_r(estimated) - f_r(direct) = "
        f"{format_number(comparison['rms_fr_difference'], 4)} (relative units), rms "
        f"relative difference {format_number(100 * comparison['rms_fr_relative'], 3)} "
        f"%, largest "
        f"{format_number(100 * comparison['max_fr_relative'], 3)} %.",
        "",
    ]
    if comparison.get("fr_max_z") is not None:
        out += [
            f"In units of the curves' own standard error (both fits' covariances "
            f"through f_r's Jacobian, per configuration): largest |difference| / se "
            f"{format_number(comparison['fr_max_z'], 3)}, "
            f"{format_number(100 * comparison['fr_within_2se'], 3)} % of the "
            f"configurations within two standard errors.",
            "",
        ]
    out += _stats_lines(direct) + [""]
    if "direct_fig" in figures:
        out += [f"![direct fit]({figures['direct_fig']})", ""]
    return out


def pipeline_report(ref, med, tgt, direct, comparison, truth, figures, inputs) -> str:
    """report.md: the parameter tables per step (value +- stderr), statistics, figures."""
    out = ["# veil fit: two-step estimation (docs/model.md sec. 7)", ""]
    listed = [
        f"- {k.replace('_', ' ')}: `{os.fspath(v)}`"
        for k, v in inputs.items()
        if isinstance(v, (str, os.PathLike))
    ]
    if listed:
        out += ["Inputs:", ""] + listed + [""]
    if inputs.get("black") is not None:
        out += ["The black-cloth session was subtracted from both sessions in the medium.", ""]
    out += [
        "Uncertainties are one standard error from the Jacobian at the solution. "
        '"stderr" holds the model given to the step (the reference f_r in step 1, the '
        'medium in step 2) exact; "stderr incl. given model" adds that model\'s own '
        "uncertainty (to first order, or through refits at sigma points where it is large; "
        "each step below says which; docs/fitting.md).",
        "",
    ]
    sections = [
        (
            "Step 0: reference object in a clear medium (f_r directly)",
            ref,
            "reference",
            "reference_fig",
        ),
        (
            "Step 1: the medium, through the reference object (f_r fixed)",
            med,
            "medium",
            "medium_fig",
        ),
        ("Step 2: the target object, through the medium (f_t fixed)", tgt, "target", "target_fig"),
    ]
    for title, result, key, fig in sections:
        out += [f"## {title}", "", f"Model: {result.model}.", ""]
        out += _param_table(result, (truth or {}).get(key)) + [""]
        out += _stats_lines(result) + [""]
        if fig in figures:
            out += [f"![{title}]({figures[fig]})", ""]
    if direct is not None and comparison is not None:
        out += _comparison_lines(direct, comparison, figures)
    return "\n".join(out)


def ranking_section(rankings: dict) -> list[str]:
    """report.md's lines for ``--models auto``: per step the candidates ranked by BIC with
    the model-discrepancy term (:mod:`veil.fitting.selection`), best first."""
    from ..fitting.selection import table_lines

    titles = {
        "reference": "Step 0: the reference's BRDF, on its clear-medium data",
        "medium": "Step 1: the medium, through the chosen reference model",
        "target": "Step 2: the target's BRDF, through the chosen medium",
    }
    out = [
        "## The data choose the model (--models auto)",
        "",
        "Every registered family with every value of its discrete options (values that make "
        "the same model fitted once), fitted to the same data and ranked by "
        "BIC = -2 ln L + k ln N, L the likelihood of the weighted "
        "residuals under each fit's model-discrepancy term (the chi-square when it has "
        "none), k its free parameters (with the term's when fitted from its own "
        "residuals); weight exp(-dBIC/2), normalized. * marks the model used. A "
        "candidate that failed or did not converge is listed and not ranked; one screened "
        "out (its quick fit misses by more than the fast quadrature can explain) is listed "
        "with its quick fit's numbers.",
        "",
    ]
    for step, ranking in rankings.items():
        title = titles.get(step, step)
        if getattr(ranking, "on", None):
            title = f"{title.partition(',')[0]}, ranked on {ranking.on}; the chosen one fitted "
            title += "through the chosen medium"
        out += [f"### {title}", ""] + table_lines(ranking, markdown=True) + [""]
    return out


def channels_section(channels, comparison: dict | None) -> str:
    """report.md's section on a pipeline over several ``channels``: what was tied, and the
    estimate against the direct fit per channel (when ``comparison`` has them)."""
    out = (
        f"## Channels\n\nEvery step fitted the channels {', '.join(channels)} at once, the "
        "parameters declared per channel one per channel and the others tied "
        "(docs/channels.md). The figures draw every channel in its colour.\n"
    )
    by_channel = (comparison or {}).get("rms_fr_relative_by_channel")
    if not by_channel:
        return out
    rows = [f"| {c} | {100 * v:.3g} |" for c, v in by_channel.items()]
    return (
        out + "\nThe estimate against the target measured directly, per channel (rms relative "
        "difference of f_r over the paper's protocol):\n\n| channel | rms [%] |\n|---|---|\n"
        + "\n".join(rows)
        + "\n"
    )


__all__ = ["pipeline_report", "ranking_section", "channels_section"]
