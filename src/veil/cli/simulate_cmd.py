"""``veil simulate``: a simulated measurement session following the paper's protocol
(docs/model.md sec. 1 and 7; table format and glow model in docs/measurements.md)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from ..errors import InputError
from ._common import (
    FINITE,
    GLOW_LEVEL,
    TABLE_FORMS,
    OutputPath,
    UserError,
    accuracy_option,
    check_output_path,
    model_options,
    options_named,
    parse_psi,
    rotation_options,
    seed_option,
)


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def _nonneg(name):
    def check(ctx, param, value):
        if value is not None and not value >= 0:
            raise click.BadParameter(f"{value!r}: expected a number >= 0", param_hint=name)
        return value

    return check


def _merl_model(merl, channel, models, channels=None):
    """The --brdf-model family fitted to a MERL file's f_r (every in-plane configuration);
    prints the fit's RMS relative difference. With ``channels`` (--channels r,g,b): those
    channels fitted at once, {channel: model}."""
    from ..data.merl import channels_table, measurement_table, read_merl
    from ..fitting import fit_reference

    if channels is not None:
        names = channel_names(channels)
        table = channels_table(read_merl(merl), names, "inplane")
        result = fit_reference(table, brdf_model=models.brdf.NAME, options=models.brdf_options)
        click.echo(
            f"{merl}: channels {', '.join(names)} fitted at once, represented by "
            f"{models.brdf.NAME} (RMS relative difference "
            f"{100 * result.rms_relative:.3g} % over {result.n_points} points)",
            err=True,
        )
        return {c: result.as_model(channel=c) for c in names}
    table = measurement_table(read_merl(merl), channel, "inplane")
    result = fit_reference(table, brdf_model=models.brdf.NAME, options=models.brdf_options)
    click.echo(
        f"{merl}: channel {channel} represented by {result.as_model()} (RMS relative "
        f"difference {100 * result.rms_relative:.3g} % over {result.n_points} in-plane "
        f"configurations)",
        err=True,
    )
    return result.as_model()


def channel_names(channels: str) -> list[str]:
    """The channels of ``--channels`` (labels as measurement tables write them): a
    UserError naming an empty entry, an unknown name, a wavelength out of range, a
    channel given twice (``r,R``, ``650,650.0``) or names mixed with wavelengths."""
    from ..data.channels import WAVELENGTH_RANGE, channel_label

    names: list[str] = []
    for item in channels.split(","):
        label = channel_label(item)
        if label is None or label in names:
            lo, hi = WAVELENGTH_RANGE
            why = f"{item.strip()!r} is not r, g, b or a wavelength from {lo:g} to {hi:g} nm"
            if not item.strip():
                why = "an empty entry"
            elif label is not None:
                why = f"{item.strip()!r} names channel {label} a second time"
            raise UserError(
                f"--channels {channels!r}: {why}; expected distinct channels, "
                f"comma-separated (r,g,b or wavelengths in nm such as 450,550,650)"
            )
        names.append(label)
    return names


def _unmixed(channels: str, names: list[str]) -> None:
    """A UserError for ``--channels`` mixing colour names with wavelengths (a table's
    channels are one or the other, docs/measurements.md "Channels")."""
    from ..data.channels import RGB

    if len({name in RGB for name in names}) > 1:
        raise UserError(
            f"--channels {channels!r}: colour channels mixed with wavelengths; expected "
            f"r, g, b or wavelengths in nm, not both"
        )


def _channel_models(model_b, model_m, channels: str | None, per_channel) -> dict | None:
    """{channel: (brdf, medium)} of ``--channels`` with the ``--per-channel NAME=V1,V2,...``
    values (a parameter of the BRDF or, by its name next to the BRDF's, of the medium);
    None without ``--channels``. ``model_b`` may be {channel: BRDF} (a MERL file's)."""
    if channels is None:
        if per_channel:
            raise UserError("--per-channel needs --channels (e.g. --channels r,g,b)")
        return None
    names = channel_names(channels)
    _unmixed(channels, names)
    by_channel = model_b if isinstance(model_b, dict) else dict.fromkeys(names, model_b)
    model_b = by_channel[names[0]]
    values: dict = {}
    for item in per_channel:
        name, sep, text = item.partition("=")
        name = name.strip()
        try:
            numbers = [float(v) for v in text.split(",")] if sep else []
        except ValueError:
            numbers = []
        if len(numbers) != len(names):
            raise UserError(
                f"--per-channel {item!r}: expected NAME=V1,...,V{len(names)}, one "
                f"number per channel of --channels ({', '.join(names)})"
            )
        owner = next((m for m in (model_b, model_m) if m is not None and name in m.keys()), None)
        if owner is None:
            known = [k for m in (model_b, model_m) if m is not None for k in m.keys()]
            raise UserError(
                f"--per-channel {item!r}: {name!r} is not a parameter of the "
                f"object or the medium ({', '.join(known)})"
            )
        if name in values:
            raise UserError(f"--per-channel: {name} is given twice")
        values[name] = (owner.KIND, type(owner).param(name).name, numbers)
    out = {}
    for k, channel in enumerate(names):
        pair = []
        for model in (by_channel[channel], model_m):
            changes = {
                own: vals[k]
                for kind, own, vals in values.values()
                if model is not None and kind == model.KIND
            }
            try:
                pair.append(None if model is None else model.replace(**changes))
            except InputError as exc:
                raise UserError(f"--per-channel, channel {channel}: {exc}") from None
        out[channel] = tuple(pair)
    return out


@click.command("simulate", short_help="Simulate a measurement session of the paper's protocol.")
@click.option(
    "--brdf",
    default=None,
    metavar="MODEL",
    help="The object: preset BRDF1 or BRDF2, or a literal list of the --brdf-model's "
    "parameters ('PD,PS,N,ETA' for the paper's Torrance-Sparrow, docs/model.md "
    "sec. 2; N in 1/deg).",
)
@click.option(
    "--medium",
    required=True,
    metavar="MODEL",
    help="The medium: preset BTDF1, BTDF2 or BTDF3, a literal list of the "
    "--medium-model's parameters ('TD,TT,G,ETA' for the paper's, docs/model.md "
    "sec. 3), or 'none' for clear water.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=OutputPath(dir_okay=False, path_type=Path),
    help="CSV file to write the session to (written atomically).",
)
@click.option(
    "--black",
    "black_path",
    type=OutputPath(dir_okay=False, path_type=Path),
    help="Also write the black-cloth (medium-only glow) session, same "
    "configurations, to this CSV file.",
)
@click.option(
    "--psi",
    default="30,60,90",
    show_default=True,
    metavar="DEG,...",
    help="Relative angles between light and camera, degrees, comma-separated.",
)
@click.option(
    "--noise",
    type=FINITE,
    default=0.01,
    show_default=True,
    callback=_nonneg("--noise"),
    help="Relative standard deviation of the Gaussian noise (0.01 = 1 % of each "
    "value); written to the sigma column.",
)
@seed_option("Seed of the noise generator (same seed, same files, bit for bit).")
@click.option(
    "--glow",
    type=FINITE,
    default=GLOW_LEVEL,
    show_default=True,
    callback=_nonneg("--glow"),
    help="Medium glow level, a fraction of the reference object's (BRDF2's) "
    "signal through the same medium at theta_i = 0, theta_r = 60 deg: the same "
    "glow for every object in a medium (docs/measurements.md); 0 for none.",
)
@click.option(
    "--form",
    type=click.Choice(list(TABLE_FORMS)),
    default="goniometer",
    show_default=True,
    help="Angle columns to write: goniometer = psi,rho plus the signed in-plane "
    "theta_i,theta_r they imply; inplane = signed theta_i,theta_r; full = "
    "theta_i,phi_i,theta_r,phi_r. All in degrees.",
)
@rotation_options()
@accuracy_option("Quadrature level of the apparent reflectance.")
@click.option(
    "--merl",
    "merl",
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
    help="A measured BRDF (MERL binary file) instead of --brdf: the --brdf-model "
    "family is fitted to it (every in-plane configuration, --channel) and "
    "simulated through the medium; the fit's RMS difference is printed "
    "(docs/interop.md).",
)
@click.option(
    "--channel",
    type=click.Choice(["r", "g", "b"]),
    default="g",
    show_default=True,
    help="Colour channel of the --merl file (with --channels r,g,b: those channels "
    "of the file, fitted at once).",
)
@click.option(
    "--channels",
    default=None,
    metavar="C1,C2,...",
    help="Write several channels (r,g,b, or wavelengths in nm): the session once per "
    'channel, with a channel column (docs/measurements.md, "Channels").',
)
@click.option(
    "--per-channel",
    "per_channel",
    multiple=True,
    metavar="NAME=V1,V2,...",
    help="With --channels: a parameter of the object or the medium (names as in "
    "'veil models'; the medium's index is eta_u) that takes one value per "
    "channel, e.g. Pd=0.3,0.5,0.8; repeatable. Other parameters are those of "
    "--brdf and --medium in every channel.",
)
@model_options()
@options_named({"psi": "--psi", "noise": "--noise", "glow": "--glow"})
def simulate_command(
    brdf,
    medium,
    output,
    black_path,
    psi,
    noise,
    seed,
    glow,
    form,
    fine_step,
    window,
    coarse_step,
    limit,
    accuracy,
    merl,
    channel,
    channels,
    per_channel,
    models,
):
    """Simulate a measurement session of the paper's protocol (docs/model.md sec. 7).

    For each relative angle psi the object is rotated by rho (theta_i = psi/2 + rho,
    theta_r = psi/2 - rho): every --fine-step degrees within --window of the mirror
    configuration, every --coarse-step degrees beyond, while both |theta| < --limit.
    Each value is the apparent reflectance plus the medium's glow, with relative
    Gaussian noise. Example:

    \b
        veil simulate --brdf BRDF1 --medium BTDF2 -o meas.csv --black black.csv
        veil simulate --brdf BRDF1 --medium none --channels r,g,b \\
            --per-channel Pd=400,1000,2500 -o rgb.csv
    """
    if (brdf is None) == (merl is None):
        raise UserError("give the object as --brdf MODEL or --merl FILE (one of the two)")
    model_m = models.medium_model(medium)
    model_b, brdf = _object(brdf, merl, channel, models, channels)
    by_channel = _channel_models(model_b, model_m, channels, per_channel)
    psis = parse_psi(psi)
    if black_path is not None and _same_file(output, black_path):
        raise UserError(f"--output and --black are the same file ({output}); give two files")
    for path in (output, black_path):
        if path is not None:
            check_output_path(path)
    from ..data.protocol import protocol
    from ..data.simulate import SimulatedOverflowError, simulate, simulate_channels

    try:
        configs = protocol(
            psis, fine_step=fine_step, coarse_step=coarse_step, window=window, limit=limit
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None

    what = "clear water" if model_m is None else medium.strip()
    with _bar() as bar:
        task = bar.add_task(f"{brdf.strip()} through {what}", total=len(configs))
        protocol_args = dict(
            noise=noise,
            seed=seed,
            black=black_path is not None,
            fine_step=fine_step,
            coarse_step=coarse_step,
            window=window,
            limit=limit,
            glow=glow,
            accuracy=accuracy,
            progress=lambda done, total: bar.update(task, completed=done, total=total),
        )
        try:
            result = (
                simulate(model_b, model_m, psis, **protocol_args)
                if by_channel is None
                else simulate_channels(by_channel, psis, **protocol_args)
            )
        except SimulatedOverflowError as exc:
            raise _overflow(exc, _object_options(brdf, merl, per_channel), noise, glow) from None
    _write(result, output, black_path, form, by_channel)


def _overflow(exc, given_object: str, noise: float, glow: float) -> UserError:
    """The UserError of a simulation that overflowed, naming the option to blame."""
    given = {"brdf": given_object, "noise": f"--noise {noise:g}", "glow": f"--glow {glow:g}"}
    return UserError(f"{given[exc.argument]}: {exc.detail}")


def _object_options(brdf, merl, per_channel) -> str:
    """The options that gave the object, as typed: --brdf or --merl, and --per-channel."""
    head = f"--merl {merl}" if merl is not None else f"--brdf {brdf}"
    return head + "".join(f" --per-channel {item}" for item in per_channel)


def _write(result, output, black_path, form: str, by_channel) -> None:
    """The session (and its black cloth) in ``form``, both files or neither."""
    from ..data.measurements import measurements_text, to_form
    from ..io import write_many_atomic

    table, cloth = result if black_path is not None else (result, None)
    files = {output: measurements_text(to_form(table, form)).encode("utf-8")}
    if cloth is not None:
        files[black_path] = measurements_text(to_form(cloth, form)).encode("utf-8")
    write_many_atomic(files)  # both files or neither
    click.echo(
        f"wrote {len(table)} "
        + ("configurations" if by_channel is None else f"rows ({len(by_channel)} channels)")
        + f" to {output}"
        + (f" and the black cloth to {black_path}" if cloth is not None else ""),
        err=True,
    )


def _object(brdf, merl, channel, models, channels) -> tuple:
    """(the object's BRDF, how the progress names it): --brdf MODEL or fitted to --merl."""
    if merl is not None:
        return (
            _merl_model(merl, channel, models, channels),
            f"{models.brdf.NAME} fitted to {merl.name}",
        )
    return models.brdf_model(brdf), brdf


def _bar():
    """The progress bar of the configurations simulated."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from .compile_display import console

    return Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console(),
        transient=True,
    )
