"""``veil fit maps`` (per-pixel step 2 from a photo stack into a Zarr store) and ``veil maps``
(``show``: a figure; ``export``: float32 TIFF / OpenEXR and a JSON summary). docs/maps.md.

JAX, the engine and Dask are imported inside the commands, so that ``veil --help`` stays
fast."""

from __future__ import annotations

import json
from functools import partial
from pathlib import Path

import click

from ..maps.blur_rounds import MAX_ROUNDS
from ._common import (
    FINITE,
    OutputPath,
    UserError,
    accuracy_option,
    check_outside,
    echo_warnings,
    fit_progress,
    load_medium,
    model_options,
    parse_fix,
    photo_channel_option,
)
from ._model_options import model_error_choice

ROI_HELP = "X,Y,W,H in pixels (x to the right, y down, origin top-left)"


def _noise(text):
    if text is None:
        return None
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise UserError(
            f"--noise {text!r}: expected RELATIVE[,ABSOLUTE], e.g. 0.01 or 0.01,0.5"
        ) from None
    if len(values) not in (1, 2):
        raise UserError(f"--noise {text!r}: expected RELATIVE[,ABSOLUTE] >= 0, not both 0")
    from ..errors import InputError
    from ..maps.run import check_noise

    try:  # the maps' own check (veil.maps.run.check_noise), in the option's words
        check_noise(tuple(values))
    except InputError as exc:
        raise UserError(f"--noise {text!r}: {str(exc).partition(': ')[2]}") from None
    return tuple(values + [0.0])[:2]


@click.command("maps")
@click.argument("photo_dir", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--manifest",
    required=True,
    type=click.Path(exists=True, dir_okay=False),
    help="CSV naming each photo (column 'file', relative to PHOTO_DIR) and its "
    "geometry, as 'veil ingest' reads it.",
)
@click.option(
    "--medium",
    "medium",
    required=True,
    metavar="MEDIUM",
    help="The medium: a JSON file from 'veil fit medium', a preset or a literal "
    "list of the medium's parameters.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=OutputPath(what="folder"),
    help="Zarr store for the maps (a folder; an existing partial store of the same "
    "inputs is resumed).",
)
@click.option(
    "--black-photos",
    type=click.Path(exists=True, file_okay=False),
    help="Folder with a black-cloth photo of each manifest row (same file name), "
    "subtracted pixel by pixel.",
)
@click.option(
    "--black-frame",
    type=click.Path(exists=True, dir_okay=False),
    help="One frame subtracted from every photo pixel by pixel (a dark frame).",
)
@click.option("--roi", default=None, help=f"Region to map: {ROI_HELP} [default: the photos].")
@click.option(
    "--mask",
    type=click.Path(exists=True, dir_okay=False),
    help="Image of the photos' size; its nonzero pixels are fitted.",
)
@photo_channel_option(
    "Colour channel; gray = (R + G + B) / 3; rgb = every channel at once, the "
    "scales per channel and the rest shared, through each channel's medium "
    "(docs/maps-channels.md)."
)
@click.option(
    "--saturation",
    type=FINITE,
    default=None,
    help="Code value at or above which a sample is saturated [default: the "
    "format's maximum]; saturated samples are left out of that pixel's fit.",
)
@click.option(
    "--noise",
    default=None,
    metavar="REL[,ABS]",
    help="Noise model sigma = sqrt((REL value)^2 + ABS^2) for a weighted fit and a "
    "true reduced chi-square [default: unweighted, standard errors from the "
    "residuals].",
)
@click.option(
    "--fix",
    "fix",
    multiple=True,
    metavar="NAME=VALUE",
    help="Hold a parameter of the BRDF at VALUE; repeatable.",
)
@click.option(
    "--free",
    "free",
    multiple=True,
    metavar="NAME",
    help="Fit a parameter the family holds by default; repeatable.",
)
@click.option(
    "--grid",
    "grid",
    multiple=True,
    metavar="NAME=LO:HI[:N]",
    help="Tabulated range of a nonlinear parameter [default: the range of the "
    "model's starting grids]; repeatable.",
)
@accuracy_option("Quadrature of the tables.")
@click.option(
    "--tile",
    type=click.IntRange(8, 4096),
    default=128,
    show_default=True,
    help="Tile size in pixels; memory is bounded by it.",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="dask.distributed scheduler to run on (default: $VEIL_DASK_SCHEDULER, "
    "else local threads).",
)
@click.option(
    "--workers",
    type=click.IntRange(1, 256),
    default=2,
    show_default=True,
    help="Local threads (without a scheduler).",
)
@click.option(
    "--camera-distance",
    type=FINITE,
    default=None,
    help="Camera distance to the plate centre, in the units of --pixel-pitch: with "
    "it the angular spread across the field is reported and checked (distant "
    "geometry), or used for per-pixel angles (--near-field).",
)
@click.option(
    "--pixel-pitch",
    type=FINITE,
    default=None,
    help="Size of one pixel on the plate (same units as --camera-distance).",
)
@click.option(
    "--near-field",
    is_flag=True,
    default=False,
    help="Per-pixel angles: a pinhole camera at --camera-distance from the plate "
    "centre, pixels --pixel-pitch apart on the plate, collimated light "
    '(docs/maps.md "Geometry") [default: distant light and camera, every '
    "pixel at the manifest's angles].",
)
@click.option(
    "--blur-from",
    type=click.Path(),
    default=None,
    help="A maps store of these photos: correct the photos for the medium's blur across "
    "the plate at that map's parameters, then fit (near field, forward-series medium; "
    "run it again from its own result for a further round; docs/maps-blur.md).",
)
@click.option(
    "--blur-rounds",
    type=click.IntRange(0, MAX_ROUNDS),
    default=0,
    show_default=True,
    help="Correct for the medium's blur in N rounds in one run: a map (or --blur-from's), "
    "then N maps each from the photos corrected at the one before, the tables built once; "
    "-o gets the last (docs/maps-blur.md).",
)
@model_error_choice(
    "off",
    "Add the model's own error to each pixel's standard errors (weighted maps, "
    "--noise): a relative error per pixel and channel from its residuals, 'correlated' "
    "with a correlation length over the angles chosen per tile (docs/maps-model-error.md).",
)
@click.option(
    "--propagation",
    type=click.Choice(["off", "linear"]),  # veil.maps.medium_error.METHODS (test_maps_medium_error)
    default="off",
    show_default=True,
    help="Add the step-1 medium's uncertainty (its result's total covariance, to first "
    "order) to each pixel's standard errors: the tables are built once more per medium "
    "parameter, so this costs that many tables' time (docs/maps-medium-error.md).",
)
@model_options()
@click.pass_context
def fit_maps_command(ctx, photo_dir, manifest, medium, output, models, **opts):
    """Per-pixel step 2: the target's BRDF at every pixel of a photo stack, through the
    fitted medium, with standard errors, reduced chi-square and a status per pixel, into a
    Zarr store (docs/maps.md).

    \b
        veil fit maps photos/ --manifest manifest.csv --medium medium.json \\
            --black-frame dark.tif --fix eta=1.5 -o maps.zarr
        veil maps show maps.zarr -o maps.png
        veil maps export maps.zarr -o maps/

    Exit status 0 when every pixel (inside the ROI and the mask) converged, 1 when the
    store is complete but some pixels were not fitted (their number by status is printed;
    the status map flags them), 2 for input mistakes; a rerun after an interruption
    computes only the missing tiles.
    """
    out = _output(output, photo_dir)  # before anything is loaded or computed
    from ..maps.grid import parse_grid
    from ..maps.run import fit_maps

    distance, pitch = opts.pop("camera_distance"), opts.pop("pixel_pitch")
    _check_options(opts["black_photos"], opts["black_frame"], distance, pitch, opts["near_field"])
    settings = dict(
        brdf_model=models.brdf.NAME,
        options=models.brdf_options,
        fixed=parse_fix(opts.pop("fix"), models.brdf),
        free=list(opts.pop("free")),
        grid=parse_grid(opts.pop("grid"), models.brdf),
        noise=_noise(opts.pop("noise")),
        geometry=(distance, pitch) if distance is not None else None,
    )
    med = _medium(medium, models)

    def log(message):
        click.echo(message, err=True)

    fit, rounds = fit_maps, opts.pop("blur_rounds")
    if rounds:
        from ..maps.blur_rounds import fit_maps_rounds

        fit = partial(fit_maps_rounds, rounds=rounds)
    with echo_warnings(), fit_progress("maps") as progress:
        run = fit(photo_dir, manifest, med, out, progress=progress, log=log, **settings, **opts)
    _print_run(ctx, run)


def _check_options(black_photos, black_frame, camera_distance, pixel_pitch, near_field) -> None:
    if black_photos and black_frame:
        raise UserError("give --black-photos or --black-frame, not both")
    if (camera_distance is None) != (pixel_pitch is None):
        raise UserError("--camera-distance and --pixel-pitch go together")
    if near_field and camera_distance is None:
        raise UserError(
            "--near-field needs --camera-distance D and --pixel-pitch P (the "
            "camera's distance from the plate centre and a pixel's size on the "
            "plate, same units)"
        )


def _medium(medium, models):
    """The medium result or model of --medium, of the --medium-model family if given."""
    med = load_medium(medium, models)
    family = med.model_class if hasattr(med, "as_model") else type(med)
    if "medium-model" in models.explicit and family is not models.medium:
        raise UserError(
            f"--medium-model {models.medium.NAME} but {medium} is a {family.NAME} medium"
        )
    return med


def _output(output, photo_dir) -> Path:
    """--output checked: not inside PHOTO_DIR, and no file (a store is a folder)."""
    from ..maps.store import check_store_path

    check_outside(output, photo_dir, f"PHOTO_DIR {photo_dir}", "PHOTO_DIR")
    check_store_path(output)
    return Path(output)


def _print_run(ctx, run) -> None:
    """The run's notes and summary; exit status 1 when some pixels were not fitted."""
    for line in run.notes:  # the warnings among them were printed as warnings already
        if not line.startswith("warning: "):
            click.echo(line, err=True)
    s = run.summary
    click.echo(
        f"{run.store}: {s['pixels']} pixels, {s['converged']} converged "
        f"({100 * s['converged'] / max(s['pixels'], 1):.1f} %); tiles: "
        f"{run.tiles_computed} computed, {run.tiles_reused} reused of "
        f"{run.tiles_total}"
    )
    if s.get("outside_mask"):
        click.echo(
            f"    outside the mask (status 1, not fitted): {s['outside_mask']} pixels", err=True
        )
    for name, entry in s["params"].items():
        if "median" in entry:
            click.echo(
                f"    {name}: median {entry['median']:.6g} (5-95 %: {entry['p05']:.4g}"
                f" .. {entry['p95']:.4g}), median stderr {entry['median_stderr']:.3g}"
            )
    _print_model_error(run)
    _print_propagation(run.summary.get("propagation"))
    for stage, sec in run.seconds.items():
        click.echo(f"    {stage}: {sec:.1f} s", err=True)
    if s["failed"]:
        # the convention of every fit (docs/errors.md): results written, exit status 1
        fitted = s["pixels"] - s.get("outside_mask", 0)
        click.echo(
            f"Error: {s['failed']} of {fitted} pixels were not fitted (the maps were "
            f"written; their status map says why, and their values and standard "
            f"errors are not estimates): "
            + "; ".join(
                f"status {name} - {count} pixels" for name, count in s["failed_by_status"].items()
            ),
            err=True,
        )
        ctx.exit(1)


def _print_model_error(run) -> None:
    """The model's error of the map, or, for a weighted map without it whose residuals
    exceed the noise, that its standard errors count the noise alone."""
    from ..fitting.model_error import chi2_threshold
    from ..maps.store import store_info

    s, info = run.summary, store_info(run.store) or {}
    term = s.get("model_error")
    if term:
        for name, c in term["channels"].items():
            lengths = ", ".join(f"{v:g}" for v in c["lengths"]) or "-"
            click.echo(
                f"    model error ({term['kind']}, {name}): on "
                f"{100 * c['share_with_term']:.0f} % of the converged pixels, median s "
                f"{c['median_sigma']:.3g}, ell {lengths} deg"
            )
        return
    chi2 = s.get("chi2_reduced", {}).get("median")
    channels = max(1, len(info.get("channels") or ()))
    per = set(info.get("channel_params") or ())  # fitted in every channel
    fitted = sum(channels if name in per else 1 for name in info.get("free") or ())
    dof = int(info.get("photos", 0)) * channels - fitted
    if info.get("weighted") and chi2 is not None and dof > 0 and chi2 > chi2_threshold(dof):
        click.echo(
            f"note: the reduced chi-square's median {chi2:.3g} is above "
            f"{chi2_threshold(dof):.3g}: the model misses the data by more than the noise, "
            f"and the standard errors count the noise "
            + ("and the medium's uncertainty only" if info.get("propagation") else "alone")
            + "; --model-error correlated adds the model's error (docs/maps-model-error.md)",
            err=True,
        )


def _print_propagation(entry) -> None:
    """The medium's part of the standard errors (``summary["propagation"]``), if any."""
    if not entry:
        return
    parts = ", ".join(
        f"{name} {100 * m['median_share']:.0f} %" for name, m in entry["maps"].items()
    )
    click.echo(
        f"    the medium's uncertainty ({', '.join(entry['parameters']) or 'none'}): its part "
        f"of the standard error, median over the converged pixels: {parts or '-'}"
    )


@click.group("maps")
def maps_command():
    """Look at and export the maps of 'veil fit maps' (docs/maps.md)."""


@maps_command.command("show")
@click.argument("store", type=click.Path(exists=True))
@click.option(
    "-o",
    "--output",
    required=True,
    type=OutputPath(dir_okay=False),
    help="Figure to write: .png, .pdf or .svg (outside the store).",
)
def show_command(store, output):
    """One figure: every fitted parameter, its standard error, the reduced chi-square and
    the status of each pixel."""
    from ..maps.show import maps_figure
    from .plot_cmd import FIGURE_SUFFIXES
    from .render_cmd import output_path

    check_outside(output, store, f"the maps store {store}")
    output_path(output, FIGURE_SUFFIXES, "--output")
    path = maps_figure(store, output)
    click.echo(f"wrote {path}", err=True)


@maps_command.command("export")
@click.argument("store", type=click.Path(exists=True))
@click.option(
    "-o",
    "--output",
    required=True,
    type=OutputPath(file_okay=False),
    help="Folder for the images and summary.json (created).",
)
@click.option(
    "--format",
    "formats",
    multiple=True,
    type=click.Choice(["tiff", "exr"]),
    help="Image format(s) [default: both].",
)
def export_command(store, output, formats):
    """Every map as float32 TIFF and OpenEXR, plus summary.json (medians, percentiles,
    undetermined fraction)."""
    from ..maps.show import FORMATS, export_maps

    check_outside(output, store, f"the maps store {store}")
    with echo_warnings():
        written = export_maps(store, output, formats or FORMATS)
    click.echo(f"wrote {len(written)} files to {output}", err=True)
    with open(Path(output) / "summary.json") as fh:
        summary = json.load(fh)
    click.echo(
        json.dumps({k: summary[k] for k in ("pixels", "converged", "undetermined_fraction")})
    )
