"""``veil reproduce``: the paper's simulation experiment (sec. 5.1, figs. 9-12) from the
presets of docs/model.md sec. 6, as figures, data and a report (docs/figures.md)."""

from __future__ import annotations

import os
import time

import click

from ._common import OutputPath, UserError, accuracy_option

#: Figure files (without suffix) by figure.
FIGURES = {
    "fig9": "fig09_reflection_lobes",
    "fig10": "fig10_transmission_lobes",
    "fig11": "fig11_observed_values",
    "fig12": "fig12_spheres",
}


#: Every entry ``veil reproduce`` writes at the top of its folder (a rerun replaces them all).
OWNED = tuple(f"{name}.{fmt}" for name in FIGURES.values() for fmt in ("png", "pdf")) + (
    "spheres",
    "fig11_curves.csv",
    "report.md",
    "report.html",
)


def curves_csv(exp) -> str:
    """The fig. 11 curves as CSV: theta_r, then one column per object/medium pair."""
    keys = list(exp.curves)
    theta = exp.curves[keys[0]].theta_r
    lines = ["theta_r_deg," + ",".join(f"{b}/{m}" for b, m in keys)]
    for k, t in enumerate(theta):
        lines.append(f"{t:g}," + ",".join(f"{exp.curves[key].values[k]:.9g}" for key in keys))
    return "\n".join(lines) + "\n"


@click.command(
    "reproduce", short_help="Regenerate the paper's simulation experiment (figs. 9-12, report)."
)
@click.option(
    "-o",
    "--output",
    "outdir",
    required=True,
    type=OutputPath(what="folder"),  # a file there is named by veil's own check
    help="Output directory (created if missing). Written as a whole at the end: "
    "veil's files in it are replaced together, other files are left alone; "
    "an interrupted run leaves it as it was.",
)
@click.option(
    "--size",
    type=int,
    default=256,
    show_default=True,
    help="Size of the rendered spheres (fig. 12), pixels.",
)
@accuracy_option("Quadrature of the fig. 11 curves.")
@click.option(
    "--render-accuracy",
    type=click.Choice(["fast", "default", "high"]),
    default="fast",
    show_default=True,
    help="Quadrature of the fig. 12 sphere tables.",
)
@click.option(
    "--check",
    type=int,
    default=64,
    show_default=True,
    help="Pixels per sphere evaluated directly to measure the interpolation error.",
)
@click.option(
    "--dpi",
    type=int,
    default=150,
    show_default=True,
    help="Resolution of the PNG figures (dots per inch).",
)
@click.option("--quiet", is_flag=True, help="No progress display.")
def reproduce_command(outdir, size, accuracy, render_accuracy, check, dpi, quiet):
    """Regenerate the paper's simulation experiment: figs. 9-12 (PNG and PDF), the fig. 11
    curves (CSV), the fig. 12 spheres (PNG) and report.md / report.html."""
    reproduce(
        outdir,
        size=size,
        accuracy=accuracy,
        render_accuracy=render_accuracy,
        check=check,
        dpi=dpi,
        quiet=quiet,
    )


def _write_spheres(folder, exp) -> None:
    """The rendered spheres: tone-mapped PNGs (their exposure in the metadata) and the
    linear images as float32 .npy."""
    import io

    import numpy as np

    from ..io import write_bytes_atomic
    from ..viz.render import png_bytes, tone_map

    folder.mkdir()
    for (b, m), st in exp.stats.items():
        img = tone_map(exp.renders[(b, m)].image, st.exposure, "reinhard")
        meta = {
            "veil:exposure": f"{st.exposure:.6g}",
            "veil:tone": "reinhard",
            "veil:brdf": str(exp.brdfs[b]),
            "veil:medium": "clear" if m == "clear" else str(exp.media[m]),
        }
        write_bytes_atomic(folder / f"{b}_{m}.png", png_bytes(img, meta))
        buf = io.BytesIO()
        np.save(buf, exp.renders[(b, m)].image.astype(np.float32))
        write_bytes_atomic(folder / f"{b}_{m}.npy", buf.getvalue())


def _write_figures(folder, exp, dpi: int, step) -> dict:
    """Figs. 9-12 as PNG and PDF in ``folder``: {figure key: its PNG's name}."""
    import matplotlib.pyplot as plt

    from ..io import write_bytes_atomic
    from ..viz.figures import fig9, fig10, fig11, fig12, figure_bytes

    drawers = {
        "fig9": lambda: fig9(list(exp.brdfs.values()), exp.theta_i, list(exp.brdfs)),
        "fig10": lambda: fig10(list(exp.media.values()), exp.theta_i, list(exp.media)),
        "fig11": lambda: fig11(exp),
        "fig12": lambda: fig12(exp),
    }
    n_steps = 2 * len(exp.curves)
    files = {}
    for k, (key, draw) in enumerate(drawers.items()):
        step(f"drawing {key}", n_steps + k, n_steps)
        fig = draw()
        try:
            for fmt in ("png", "pdf"):
                name = f"{FIGURES[key]}.{fmt}"
                write_bytes_atomic(folder / name, figure_bytes(fig, fmt, dpi))
            files[key] = f"{FIGURES[key]}.png"
        finally:
            plt.close(fig)
    return files


def _print_curves(exp) -> None:
    """Each curve's peak, its angle, FWHM and value at 0 deg."""
    for (b, m), c in exp.curves.items():
        mt = c.metrics
        click.echo(
            f"{b:6s} {m:6s} peak {mt.peak:10.4g} at {mt.peak_angle:5.2f} deg  "
            f"FWHM {mt.fwhm:5.1f} deg  f(0 deg) {mt.off_peak:9.4g}"
        )


def reproduce(
    outdir,
    *,
    size=256,
    accuracy="default",
    render_accuracy="fast",
    check=64,
    dpi=150,
    quiet=False,
    shown=None,
) -> None:
    """The work of ``veil reproduce`` (options as there); messages name the folder
    ``shown`` (default ``outdir``)."""

    from ..io import check_output_folder, output_folder, write_bytes_atomic
    from ..viz.documents import write_report
    from ..viz.figures import run_experiment

    if not 16 <= size <= 2048:
        raise UserError(f"--size {size} must be between 16 and 2048 pixels")
    if not 0 <= check <= 4096:
        raise UserError(f"--check {check} must be between 0 and 4096 pixels")
    if not 30 <= dpi <= 600:
        raise UserError(f"--dpi {dpi} must be between 30 and 600")
    outdir = check_output_folder(outdir)
    t0 = time.perf_counter()

    progress = task = None
    if not quiet:
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from .compile_display import console

        progress = Progress(
            TextColumn("{task.description:<40}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TimeElapsedColumn(),
            console=console(),
            transient=True,
        )
        progress.start()
        task = progress.add_task("starting", total=20)

    def step(message, done, total):
        if progress is not None:
            progress.update(task, description=message, completed=done, total=total + 4)

    try:
        exp = run_experiment(
            size=size,
            accuracy=accuracy,
            render_accuracy=render_accuracy,
            check=check,
            progress=step,
        )
        with output_folder(outdir, owned=OWNED) as folder:
            files = _write_figures(folder, exp, dpi, step)
            _write_spheres(folder / "spheres", exp)
            write_bytes_atomic(folder / "fig11_curves.csv", curves_csv(exp).encode())
            md, page = write_report(exp, folder, files)
    finally:
        if progress is not None:
            progress.stop()

    _print_curves(exp)
    worst = max((r.max_rel_error for r in exp.renders.values()), default=0.0)
    click.echo(f"spheres: worst interpolation error {100 * worst:.2g} % (angles <= 80 deg)")
    click.echo(
        f"wrote figures, spheres/, fig11_curves.csv, {os.path.basename(md)} and "
        f"{os.path.basename(page)} to {shown or outdir} in "
        f"{time.perf_counter() - t0:.0f} s"
    )
