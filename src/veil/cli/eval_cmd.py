"""``veil eval``: the apparent reflectance (docs/model.md eq. 1) at one configuration or at every
row of a CSV file, next to the object's own reflectance and an error estimate."""

from __future__ import annotations

import io
import json
import math
import time

import click

from .._lazy import np
from ..io import write_text_atomic
from ._common import FINITE, UserError, accuracy_option, check_output_path, model_options

ANGLES = ("theta_i", "phi_i", "theta_r", "phi_r")  # the --configs columns, degrees
ADDED = ("apparent", "clear", "error")  # the columns veil eval adds
FORMS_TEXT = (
    "theta_i, phi_i, theta_r, phi_r (or signed in-plane theta_i, theta_r, or goniometer psi, rho)"
)
DEFAULT_PHI_I = 180.0
DEFAULT_PHI_R = 0.0

BRDF_HELP = (
    "Object's reflection model, of the --brdf-model family: a preset name, BRDF1 or "
    "BRDF2, or a literal list of the family's parameters in declared order - for the "
    "paper's Torrance-Sparrow (docs/model.md sec. 2) 'PD,PS,N,ETA': PD, PS diffuse and "
    "specular coefficients (relative units, >= 0), N smoothness (1/deg, > 0; larger "
    "is smoother), ETA refractive index of the surface (> 0). 'veil models' lists "
    "every family's parameters."
)
MEDIUM_HELP = (
    "Scattering medium, of the --medium-model family: a preset name, BTDF1, BTDF2 "
    "or BTDF3, a literal list of its parameters - for the paper's medium (docs/model.md "
    "sec. 3) 'TD,TT,G,ETA': TD, TT isotropic and single-scattering coefficients "
    "(relative units, >= 0), G asymmetry (in (-1, 1)), ETA refractive index of the "
    "medium (> 0) - or 'none' for a clear medium (apparent = clear)."
)


def _check_option_angle(option: str, value: float, polar: bool) -> None:
    if not math.isfinite(value):
        raise UserError(f"{option} = {value!r} is not a finite number of degrees")
    if polar and not 0.0 <= value < 90.0:
        raise UserError(
            f"{option} = {value:g} deg is outside [0, 90): it is the polar angle "
            f"from the surface normal; for a direction on the other side of the "
            f"normal use the azimuth (phi + 180)"
        )


def _parse_models(brdf_text, medium_text, models):
    return models.brdf_model(brdf_text, "--brdf"), models.medium_model(medium_text, "--medium")


def _model_json(model):
    if model is None:
        return None
    return {"model": model.NAME, **model.as_dict(), **model.options()}


def _labelled(text, model):
    """'BRDF1 = TorranceSparrow(...)' for a preset, just the model for a literal."""
    return str(model) if "," in text else f"{text.strip().upper()} = {model}"


def _format_table(brdf_text, medium_text, brdf, medium, angles, accuracy, value, clear, error):
    ti, pi_, tr, pr = angles
    medium_line = "none (clear medium)" if medium is None else _labelled(medium_text, medium)
    with np.errstate(over="ignore"):
        quotient = np.float64(value) / np.float64(clear) if clear != 0.0 else None
    if quotient is None:
        ratio = "undefined (clear = 0)"
    elif not np.isfinite(quotient):
        ratio = "beyond float64 (above 1.8e308)"
    else:
        ratio = f"{quotient:.12g}"
    rows = [
        ("apparent", f"{value:.12g}", "f(I, R) seen through the medium (1/sr, relative units)"),
        ("clear", f"{clear:.12g}", "object's own f_r(I, R), no medium (1/sr, relative units)"),
        ("error", f"{error:.3g}", "estimated absolute error of apparent (same units)"),
        ("ratio", ratio, "apparent / clear"),
    ]
    width = max(len(r[1]) for r in rows)
    lines = [
        f"object    {_labelled(brdf_text, brdf)}",
        f"medium    {medium_line}",
        f"light     theta_i = {ti:g} deg, phi_i = {pi_:g} deg",
        f"camera    theta_r = {tr:g} deg, phi_r = {pr:g} deg",
        f"accuracy  {accuracy}",
        "",
    ]
    lines += [f"{name:<9} {text:<{width}}  {meaning}" for name, text, meaning in rows]
    return "\n".join(lines) + "\n"


def _read_configs(configs):
    """Angles (degrees, canonical) and the table of strings of a --configs file, in any of
    the three angle forms of measurement tables (docs/model.md sec. 1): the four angles, signed
    in-plane theta_i, theta_r, or goniometer psi, rho."""
    from ._csv_input import read_csv_table

    def four_angles(header):  # the four-angle form is parsed here, the others below
        return ANGLES if any(c in header for c in ("phi_i", "phi_r")) else ()

    table, numbers, rows = read_csv_table(
        configs, four_angles, unit="an angle in degrees", expected=FORMS_TEXT
    )
    clash = [c for c in ADDED if c in table.columns]
    if clash:
        raise UserError(
            f"{configs}: already has a column {clash[0]!r}, which veil eval "
            f"adds; rename or remove it"
        )
    from ..data.measurements import MeasurementError, canonical_angles

    named = table.copy()
    named.attrs = {"veil_source": str(configs), "veil_lines": [int(r) for r in rows]}
    if numbers and any(c in table.columns for c in ("psi", "rho")):
        # a second angle form beside the four angles: the check veil fit makes (both forms
        # complete and giving the same configurations, or "ambiguous angles")
        try:
            canonical_angles(named)
        except MeasurementError as exc:
            raise UserError(str(exc)) from None
    if numbers:
        for c in ("theta_i", "theta_r"):
            bad = np.flatnonzero((numbers[c] < 0.0) | (numbers[c] >= 90.0))
            if bad.size:
                j = bad[0]
                raise UserError(
                    f"{configs}: row {rows[j]} (rows counted as lines of the file, "
                    f"header = row 1), column {c!r}: {numbers[c][j]:g} deg is "
                    f"outside [0, 90) (polar angle from the surface normal)"
                )
        return (*(numbers[c] for c in ANGLES), table)
    try:
        canonical = canonical_angles(named)
    except MeasurementError as exc:
        raise UserError(str(exc)) from None
    return (*(canonical[c].to_numpy(dtype=float) for c in ANGLES), table)


#: Configurations per engine call of ``--configs``: every call has this shape (the last one
#: padded), so the engine compiles once, and progress is shown between calls.
CHUNK = 512
#: Show a progress bar when the remaining calls would take longer than this (seconds).
PROGRESS_AFTER = 3.0


def evaluate_configs(brdf, medium, ti, tr, pi_, pr, accuracy, progress=None):
    """apparent() with its error estimate at every configuration: in one call up to CHUNK
    configurations, else CHUNK at a time; ``progress(done, total, seconds_per_chunk)`` is
    called after each chunk."""
    from ..engine.apparent import apparent

    n = len(ti)
    if n <= CHUNK:
        return apparent(brdf, medium, ti, tr, pi_, pr, accuracy=accuracy, return_error=True)
    value, error = np.empty(n), np.empty(n)
    for start in range(0, n, CHUNK):
        t0 = time.perf_counter()
        idx = np.minimum(np.arange(start, start + CHUNK), n - 1)
        k = min(CHUNK, n - start)
        v, e = apparent(
            brdf, medium, ti[idx], tr[idx], pi_[idx], pr[idx], accuracy=accuracy, return_error=True
        )
        value[start : start + k], error[start : start + k] = v[:k], e[:k]
        if progress is not None:
            progress(start + k, n, time.perf_counter() - t0)
    return value, error


class _Progress:
    """A rich progress bar on stderr, started only once the rest would take PROGRESS_AFTER
    seconds or more (estimated from the chunk just done)."""

    def __init__(self):
        self.bar = None

    def __call__(self, done, total, seconds):
        if self.bar is None:
            if done >= total or seconds * (total - done) / CHUNK < PROGRESS_AFTER:
                return
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            from .compile_display import console

            self.bar = Progress(
                TextColumn("veil eval: configurations"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                console=console(),
                transient=True,
            )
            self.bar.start()
            self.task = self.bar.add_task("", total=total)
        self.bar.update(self.task, completed=done)

    def stop(self):
        if self.bar is not None:
            self.bar.stop()


def _emit(text: str, output) -> None:
    if output is None:
        click.echo(text, nl=False)
    else:
        write_text_atomic(output, text)


def _check_angle_options(theta_i, theta_r, phi_i, phi_r, configs, output, as_json) -> None:
    """One configuration (--theta-i and --theta-r) or --configs, not both; -o with one
    configuration only with --json."""
    single = {"--theta-i": theta_i, "--theta-r": theta_r, "--phi-i": phi_i, "--phi-r": phi_r}
    if configs is not None:
        given = [name for name, v in single.items() if v is not None]
        if given:
            raise UserError(
                f"{', '.join(given)} cannot be combined with --configs: the angles "
                f"come from the columns of {configs}"
            )
        return
    missing = [name for name in ("--theta-i", "--theta-r") if single[name] is None]
    if missing:
        raise UserError(
            f"missing {' and '.join(missing)} (degrees); give --theta-i and "
            f"--theta-r for one configuration, or --configs FILE.csv"
        )
    if output is not None and not as_json:
        raise UserError(
            "-o/--output writes the CSV of --configs or the object of --json; "
            "a single configuration's table goes to standard output (add "
            "--json to write it to a file)"
        )


def _option_angles(theta_i, theta_r, phi_i, phi_r) -> tuple:
    """The one configuration of --theta-i, --theta-r (--phi-i, --phi-r), checked."""
    phi_i = DEFAULT_PHI_I if phi_i is None else phi_i
    phi_r = DEFAULT_PHI_R if phi_r is None else phi_r
    _check_option_angle("--theta-i", theta_i, polar=True)
    _check_option_angle("--theta-r", theta_r, polar=True)
    _check_option_angle("--phi-i", phi_i, polar=False)
    _check_option_angle("--phi-r", phi_r, polar=False)
    return tuple(np.array([x]) for x in (theta_i, phi_i, theta_r, phi_r))


def _evaluate(brdf, medium, ti, tr, pi_, pr, accuracy: str) -> tuple:
    """(apparent, its error, clear) at the configurations, flat arrays; the object's own
    f_r on a worker thread, its program loading while the engine's do."""
    from concurrent.futures import ThreadPoolExecutor

    from ..engine.apparent import reflectance

    progress = _Progress()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="veil-clear") as pool:
        clear_future = pool.submit(reflectance, brdf, ti, tr, pi_, pr)
        try:
            value, error = evaluate_configs(brdf, medium, ti, tr, pi_, pr, accuracy, progress)
        finally:
            progress.stop()
        clear = clear_future.result()
    return tuple(np.asarray(a, dtype=float).reshape(-1) for a in (value, error, clear))


@click.command(
    "eval",
    short_help="Apparent reflectance through a medium at given angles "
    "(degrees), one configuration or a CSV of them.",
)
@click.option("--brdf", "brdf_text", required=True, metavar="MODEL", help=BRDF_HELP)
@click.option("--medium", "medium_text", required=True, metavar="MODEL", help=MEDIUM_HELP)
@click.option(
    "--theta-i",
    type=FINITE,
    metavar="DEG",
    help="Polar angle of the light direction I from the surface normal, in degrees, "
    "in [0, 90). Required unless --configs is given.",
)
@click.option(
    "--theta-r",
    type=FINITE,
    metavar="DEG",
    help="Polar angle of the camera direction R from the surface normal, in degrees, "
    "in [0, 90). Required unless --configs is given.",
)
@click.option(
    "--phi-i",
    type=FINITE,
    metavar="DEG",
    help="Azimuth of the light direction I, in degrees. [default: 180, the light "
    "opposite the camera in the plane of incidence]",
)
@click.option(
    "--phi-r",
    type=FINITE,
    metavar="DEG",
    help="Azimuth of the camera direction R, in degrees. [default: 0]",
)
@click.option(
    "--configs",
    type=click.Path(exists=True, dir_okay=False, readable=True),
    metavar="FILE.csv",
    help="Evaluate every row of this CSV file instead of one configuration. Angles "
    "in degrees in any form of a measurement table: theta_i, phi_i, theta_r, "
    "phi_r; signed in-plane theta_i, theta_r; or goniometer psi, rho. Other "
    "columns are copied unchanged. Output: the input's columns in the same row "
    "order plus apparent, clear and error (1/sr, relative units) as CSV.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    metavar="OUT",
    help="Write the --configs CSV (or, with --json, the JSON object) to this file "
    "instead of standard output ('-': standard output). Written atomically; never the "
    "--configs file.",
)
@accuracy_option(
    "Quadrature level: fast (coarse rule, quick previews), default (about 1e-3 "
    "relative error for the paper's presets at angles below 80 deg), high "
    "(twice as fine, slower). The error column estimates what is left."
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print a JSON object instead of the table or CSV: the models, the lists "
    "theta_i, phi_i, theta_r, phi_r (degrees) and apparent, clear, error "
    "(1/sr, relative units), one entry per configuration in input order.",
)
@model_options()
def eval_command(
    brdf_text,
    medium_text,
    theta_i,
    theta_r,
    phi_i,
    phi_r,
    configs,
    output,
    accuracy,
    as_json,
    models,
):
    """Apparent reflectance of an object seen through a scattering medium (docs/model.md eq. 1).

    For one configuration give --theta-i and --theta-r (and optionally --phi-i, --phi-r);
    the result is a short table: apparent (through the medium), clear (the object's own
    f_r), error (estimated absolute error of apparent) and their ratio apparent/clear.
    With --configs FILE.csv every row is evaluated and a CSV is written. All angles are in
    degrees; reflectances are per steradian, on the relative scale of the model coefficients.

    \b
    Examples:
      veil eval --brdf BRDF1 --medium BTDF2 --theta-i 45 --theta-r 50
      veil eval --brdf 200,5e5,0.8,1.55 --medium none --theta-i 30 --theta-r 30 --json
      veil eval --brdf BRDF2 --medium BTDF3 --configs angles.csv -o result.csv
    """
    output = None if output == "-" else output  # '-': standard output, as without -o
    _check_angle_options(theta_i, theta_r, phi_i, phi_r, configs, output, as_json)
    brdf, medium = _parse_models(brdf_text, medium_text, models)
    if output is not None:
        check_output_path(output, [configs])

    if configs is not None:
        ti, pi_, tr, pr, table = _read_configs(configs)
    else:
        ti, pi_, tr, pr = _option_angles(theta_i, theta_r, phi_i, phi_r)
    value, error, clear = _evaluate(brdf, medium, ti, tr, pi_, pr, accuracy)

    if as_json:
        obj = {
            "brdf": _model_json(brdf),
            "medium": _model_json(medium),
            "accuracy": accuracy,
            "angle_unit": "deg",
            "theta_i": ti.tolist(),
            "phi_i": pi_.tolist(),
            "theta_r": tr.tolist(),
            "phi_r": pr.tolist(),
            "apparent": value.tolist(),
            "clear": clear.tolist(),
            "error": error.tolist(),
        }
        _emit(json.dumps(obj, indent=2, allow_nan=False) + "\n", output)
    elif configs is not None:
        out = table.copy()
        out["apparent"], out["clear"], out["error"] = value, clear, error
        buf = io.StringIO()
        out.to_csv(buf, index=False, lineterminator="\n")
        _emit(buf.getvalue(), output)
    else:
        click.echo(
            _format_table(
                brdf_text,
                medium_text,
                brdf,
                medium,
                (ti[0], pi_[0], tr[0], pr[0]),
                accuracy,
                value[0],
                clear[0],
                error[0],
            ),
            nl=False,
        )
    if output is not None:
        click.echo(
            f"wrote {len(value)} configuration{'s' if len(value) != 1 else ''} to {output}",
            err=True,
        )
