"""``veil fit joint``: one fit over several sessions and media (docs/model.md sec. 7;
docs/ambiguity.md).

Registered on the ``fit`` group from :mod:`veil.cli`. Exit status 0 when the fit converged,
1 when it did not (the result is written anyway, ``"converged": false``), 2 for input
mistakes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import click

from ._common import (
    OutputPath,
    UserError,
    accuracy_option,
    check_output_path,
    fix_value,
    model_error_option,
    model_options,
    options_named,
    propagation_option,
)

OUT_FILE = OutputPath(dir_okay=False, path_type=Path)

#: The options giving the sessions of each object (veil.fitting.Session's ``object``).
SESSION_OPTIONS = {"target": "--session", "reference": "--reference-session"}


def session_words(text: str) -> str:
    """``text`` (a message of the joint fit) with its sessions said as the options that give
    them: ``(object 'reference', medium 'none')`` -> ``(--reference-session none=PATH)``,
    ``object 'reference'`` -> ``--reference-session LABEL=PATH``, ``object target`` (a
    list of what the data tie together) -> ``the target (--session)``."""
    obj = "object '?(target|reference)'?"
    text = re.sub(
        obj + r", medium '([^']*)'", lambda m: f"{SESSION_OPTIONS[m[1]]} {m[2]}=PATH", text
    )
    text = re.sub(rf"\b{obj}(?=[\s,:;)]|$)", lambda m: _object_said(m[0], m[1]), text)
    return text


def _object_said(said: str, obj: str) -> str:
    if "'" in said:  # object 'target': a session to add
        return f"{SESSION_OPTIONS[obj]} LABEL=PATH"
    return f"the {obj} ({SESSION_OPTIONS[obj]})"


def parse_sessions(items, option: str) -> list[tuple[str, str]]:
    """``LABEL=PATH`` strings -> [(label, path)]; the file must exist."""
    out = []
    for item in items:
        label, sep, path = item.partition("=")
        label, path = label.strip(), path.strip()
        if not sep or not label or not path:
            raise UserError(
                f"{option} {item!r}: expected LABEL=PATH, e.g. low=target_low.csv "
                f"(LABEL names the medium; 'none' is clear water)"
            )
        if not os.path.exists(path):
            raise UserError(f"{option} {item!r}: file {path} does not exist")
        if os.path.isdir(path):
            raise UserError(f"{option} {item!r}: {path} is a directory, not a CSV file")
        out.append((label, path))
    return out


def parse_black(items) -> dict:
    blacks = {}
    for label, path in parse_sessions(items, "--black"):
        if label.lower() in ("none", "clear"):
            raise UserError(f"--black {label}={path}: clear water has no black-cloth session")
        if label in blacks:
            raise UserError(f"--black: medium {label!r} given twice")
        blacks[label] = path
    return blacks


def load_sessions(target_items, reference_items, black_items) -> tuple[list, list]:
    """Sessions (black cloth subtracted per medium; from a table with a channel column
    channel by channel, by the fit) and every input path."""
    from ..data.black_cloth import subtract_black
    from ..data.channels import CHANNEL
    from ..data.measurements import load_measurements
    from ..fitting.joint import Session

    targets = parse_sessions(target_items, "--session")
    refs = parse_sessions(reference_items, "--reference-session")
    blacks = parse_black(black_items)
    labels = {label for label, _ in targets + refs}
    unused = [label for label in blacks if label not in labels]
    if unused:
        raise UserError(
            f"--black given for medium {', '.join(map(repr, unused))} but no session "
            f"is in that medium"
        )
    sessions, inputs = [], []
    for obj, items in (("target", targets), ("reference", refs)):
        for label, path in items:
            table = load_measurements(path)
            black = load_measurements(blacks[label]) if label in blacks else None
            name = f"{obj} in {label} ({path})"
            inputs.append(path)  # every table is an input, never an output's place
            if CHANNEL in table.columns:
                sessions.append(Session(table, label, obj, name, black))
                continue
            if black is not None:
                table = subtract_black(table, black)
            sessions.append(Session(table, label, obj, name=name))
    return sessions, inputs + list(blacks.values())


def parse_joint_fix(items) -> dict:
    fixed: dict[str, float] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UserError(f"--fix {item!r}: expected NAME=VALUE, e.g. 'Td[low]=1e-3' or eta=1.5")
        fixed[name] = fix_value("--fix", item, name, text, fixed)
    return fixed


def _names(text, option):
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise UserError(
            f"{option} {text!r}: expected a comma-separated list of parameter "
            f"names (the medium's shareable ones, e.g. g,eta_u)"
        )
    return names


def _ranked_joint(ctx, loaded, ranked, kw: dict):
    """``--brdf-model auto`` / ``--medium-model auto``: every candidate's joint fit ranked
    (veil.fitting.joint_selection), the table printed; exit 1 with it when every candidate
    failed."""
    from ..fitting.joint_selection import fit_joint_ranked
    from ..fitting.selection import NoCandidateError
    from ._common import echo_warnings, fit_progress
    from ._fit_reports import print_ranking

    try:
        with echo_warnings(), fit_progress("joint fit") as progress:
            result, ranking = fit_joint_ranked(loaded, ranked, progress=progress, **kw)
    except NoCandidateError as exc:
        print_ranking(exc.ranking)
        click.echo(f"Error: {exc}; nothing was written", err=True)
        ctx.exit(1)
    print_ranking(ranking)
    return result


@click.command("joint", short_help="Fit the target (and the reference) over several media at once.")
@click.option(
    "--session",
    "sessions",
    multiple=True,
    metavar="LABEL=PATH",
    help="The target measured in medium LABEL (e.g. low=target_low.csv); repeat for "
    "each medium. LABEL 'none' is clear water.",
)
@click.option(
    "--reference-session",
    "reference_sessions",
    multiple=True,
    metavar="LABEL=PATH",
    help="The reference object measured in medium LABEL ('none' = clear water); repeatable.",
)
@click.option(
    "--black",
    "blacks",
    multiple=True,
    metavar="LABEL=PATH",
    help="Black-cloth session of medium LABEL, subtracted from every session in "
    "that medium; repeatable.",
)
@click.option(
    "--reference",
    "reference",
    metavar="REF",
    help="The reference's f_r, held fixed: a JSON file from 'veil fit reference', a "
    "preset or a literal list of the BRDF's parameters. Without it a "
    "clear-water reference session makes the reference's parameters free.",
)
@click.option(
    "--shared",
    default=None,
    metavar="NAMES",
    help="Medium parameters shared by all media (among those the medium model "
    "declares shareable; the paper's: g, eta_u). Default: as the model declares "
    "(the paper's: eta_u shared, g per medium).",
)
@click.option(
    "--per-medium",
    default=None,
    metavar="NAMES",
    help="Medium parameters free per medium (among the shareable ones); scale "
    "parameters (the paper's Td and Tt) always are.",
)
@click.option(
    "--fix",
    "fix",
    multiple=True,
    metavar="NAME=VALUE",
    help="Hold a parameter, named as in the result: the target's (Pd, Ps, n, eta for "
    "the paper's), ref.NAME for the reference, 'NAME[LABEL]' per medium (e.g. "
    "'Td[low]') or NAME when shared (e.g. eta_u); repeatable.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=OUT_FILE,
    help="JSON file for the joint result (written atomically).",
)
@accuracy_option(
    "Quadrature of the reported result; iterations run at 'fast' and are polished at this accuracy."
)
@click.option(
    "--max-nfev",
    type=click.IntRange(min=1),
    default=None,
    help="Limit on function evaluations of each least-squares run.",
)
@click.option(
    "--channel",
    default=None,
    metavar="NAME",
    help="The one channel to fit of tables with a channel column (r, g, b or a wavelength "
    "in nm); without it every channel is fitted at once, the parameters each family "
    "declares per channel one per channel (docs/channels.md).",
)
@model_error_option
@propagation_option
@click.pass_context
@model_options(auto_kinds=("brdf", "medium"))
@options_named({"reference": "--reference", "fixed": "--fix"}, session_words)
def joint_command(
    ctx,
    sessions,
    reference_sessions,
    blacks,
    reference,
    shared,
    per_medium,
    fix,
    output,
    accuracy,
    max_nfev,
    channel,
    model_error,
    propagation,
    models,
):
    """Fit the target (and the reference) over several media at once (docs/model.md sec. 7).

    The object's parameters are shared by all its sessions, each medium has its own Td and
    Tt, g and eta_u are shared or per medium as declared. Example, three concentrations
    plus the reference:

    \b
        veil fit joint --session low=t_low.csv --session mid=t_mid.csv \\
            --session high=t_high.csv --reference-session none=ref_water.csv \\
            --reference-session low=r_low.csv --reference-session mid=r_mid.csv \\
            --reference-session high=r_high.csv -o joint.json

    Without reference sessions fix one scale (e.g. --fix 'Td[low]=1e-3'): the data only
    determine Pd, Ps and Td, Tt up to a common factor.

    Tables with a channel column (r, g, b) are fitted in every channel at once: a
    parameter per channel is named NAME[channel] after its name ('Pd[r]', 'Td[low][r]'),
    and --fix 'Td[low]=1e-3' holds it in every channel (docs/channels.md).
    """
    from ._common import echo_warnings, finish_fits, fit_progress, load_reference

    if not sessions:
        raise UserError(
            "no --session given: a joint fit needs the target measured in at "
            "least one medium (--session LABEL=PATH)"
        )
    fixed = parse_joint_fix(fix)
    loaded, inputs = load_sessions(sessions, reference_sessions, blacks)
    ref = None
    if reference is not None:
        ref = load_reference(reference, models)
        if os.path.exists(reference):
            inputs.append(reference)
    check_output_path(output, inputs)
    kw = dict(
        reference=ref,
        shared=_names(shared, "--shared"),
        per_medium=_names(per_medium, "--per-medium"),
        fixed=fixed or None,
        accuracy=accuracy,
        max_nfev=max_nfev,
        brdf_model=models.brdf.NAME,
        medium_model=models.medium.NAME,
        brdf_options=models.brdf_options,
        medium_options=models.medium_options,
        model_error=model_error,
        propagation=propagation,
        channel=channel,
    )
    if models.ranked:
        result = _ranked_joint(ctx, loaded, models.ranked, kw)
    else:
        with echo_warnings(), fit_progress("joint fit") as progress:
            from ..fitting.joint import fit_joint

            result = fit_joint(loaded, progress=progress, **kw)
    result.to_json(output)
    click.echo(result.report())
    finish_fits(ctx, [result], [output])
