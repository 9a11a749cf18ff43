"""``veil ingest``: a folder of photos and a manifest of their geometry -> a measurement table."""

from __future__ import annotations

import warnings

import click

from ._common import FINITE, UserError, check_output_path, check_outside, photo_channel_option

ROI_HELP = (
    "pixel coordinates X,Y,W,H: x to the right, y down, origin at the top-left pixel; "
    "W, H in pixels"
)


@click.command("ingest")
@click.argument("photo_dir", type=click.Path(exists=True, file_okay=False))
@click.option(
    "--manifest",
    required=True,
    type=click.Path(exists=True, dir_okay=False),
    help="CSV naming each photo (column 'file', relative to PHOTO_DIR) and its "
    "geometry (theta_i,phi_i,theta_r,phi_r or signed theta_i,theta_r or "
    "psi,rho; degrees). Other columns are copied to the output.",
)
@click.option("--roi", required=True, help=f"Observed patch of the object: {ROI_HELP}.")
@click.option(
    "--black-roi",
    default=None,
    help=f"Patch of black cloth in the same photos (adds black, black_sigma): {ROI_HELP}.",
)
@click.option(
    "--dark",
    default=None,
    type=click.Path(exists=True, dir_okay=False),
    help="Dark frame (same camera, format and size; lens capped), subtracted pixel by pixel.",
)
@photo_channel_option(
    "Colour channel; gray = (R + G + B) / 3; rgb = r, g and b at once, one "
    "table with a 'channel' column (one row per photo and channel)."
)
@click.option(
    "--response",
    default=None,
    type=click.Path(exists=True, dir_okay=False),
    help="Camera response curve: CSV with columns code,linear mapping code values to "
    "linear values (interpolated); needed for JPEG to be linear.",
)
@click.option(
    "--saturation",
    type=FINITE,
    default=None,
    help="Code value at or above which a pixel is saturated [default: the format's "
    "maximum: 255, 65535, the raw white level; float TIFF: not checked].",
)
@click.option(
    "--keep-saturated",
    is_flag=True,
    help="Keep photos with saturated or clipped pixels in the ROIs (warned either way; "
    "default: exclude them).",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="Measurement table to write (CSV).",
)
def ingest_command(
    photo_dir, manifest, roi, black_roi, dark, channel, response, saturation, keep_saturated, output
):
    """Photos -> measurement table: the mean of an ROI in each photo.

    Reads the photos of PHOTO_DIR that the manifest lists and writes one row per photo: the
    manifest's columns, value (mean over the ROI after dark-frame subtraction), sigma (its
    standard error), black and black_sigma (with --black-roi), saturated and clipped (pixel
    counts in the ROIs) and n_pixels. With --channel rgb: one row per photo and channel,
    channel after channel, a column channel (r, g, b) and, for camera raw, white_balance
    (recorded, not applied). PNG, TIFF (integer or float), JPEG and camera raw (linear, per
    colour channel, via LibRaw). Nothing in PHOTO_DIR is modified. See docs/ingest.md.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from ..data import ingest as ingest_mod
    from ..data.measurements import save_measurements
    from .compile_display import console as shared_console

    try:
        rois = [ingest_mod.parse_roi(roi, "--roi")]
        if black_roi is not None:
            rois.append(ingest_mod.parse_roi(black_roi, "--black-roi"))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    check_output_path(output, [manifest, dark, response])
    check_outside(output, photo_dir, f"PHOTO_DIR {photo_dir}", "PHOTO_DIR")
    console = shared_console()

    def show(message, category, filename, lineno, file=None, line=None):
        console.print(
            f"Warning: {message}", style="yellow", markup=False, highlight=False, soft_wrap=True
        )

    with (
        warnings.catch_warnings(),
        Progress(
            TextColumn("ingest"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.description}"),
            console=console,
            transient=True,
            disable=not console.is_terminal,
        ) as bar,
    ):
        warnings.simplefilter("always", ingest_mod.IngestWarning)
        warnings.showwarning = show
        task = bar.add_task("", total=None)

        def progress(done, total, name):
            bar.update(task, completed=done, total=total, description=name)

        table = ingest_mod.ingest(
            photo_dir,
            manifest,
            rois[0],
            rois[1] if len(rois) > 1 else None,
            dark,
            channel,
            response=response,
            saturation=saturation,
            keep_saturated=keep_saturated,
            progress=progress,
        )
        _warn_zero_sigma(table, show)
    save_measurements(table, output)
    _say_written(table, output, channel == ingest_mod.ALL_RGB)


def _warn_zero_sigma(table, show) -> None:
    """A warning naming the photos whose ROI samples are all equal (sigma 0): a fit refuses
    a row of zero sigma (docs/measurements.md), so they are said here, where they come from."""
    flat = table[table["sigma"].to_numpy() == 0]
    if len(flat) == 0:
        return
    names = ", ".join(dict.fromkeys(map(str, flat["file"])))
    show(
        f"{len(flat)} row(s) have sigma 0, every sample in the ROI the same value ({names}): "
        f"a flat, synthetic or clipped image; veil fit refuses a zero sigma, so check these "
        f"photos (or fit without the sigma column)",
        UserWarning,
        "",
        0,
    )


def _say_written(table, output, rgb: bool) -> None:
    """The closing lines: rows written and, of colour raw photos, the white balance's note."""
    from ..data.ingest_channels import WHITE_BALANCE

    if not rgb:
        click.echo(f"{len(table)} measurement(s) written to {output}", err=True)
        return
    click.echo(
        f"{len(table)} measurement(s) written to {output}: {len(table) // 3} photo(s) "
        f"in channels r, g, b",
        err=True,
    )
    if WHITE_BALANCE in table.columns:
        click.echo(
            "camera raw: white balance not applied (linear camera channels); the "
            "camera's as-shot multipliers (green = 1) are in column white_balance",
            err=True,
        )
