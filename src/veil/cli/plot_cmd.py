"""``veil plot lobe|transmission|curve``: single figures of the experiment with the user's
parameters (docs/figures.md; :mod:`veil.figures`)."""

from __future__ import annotations

import click

from ._common import FINITE, UserError, accuracy_option, echo_warnings, model_options
from .render_cmd import output_path

FIGURE_SUFFIXES = (".png", ".pdf", ".svg")


_theta_i_option = click.option(
    "--theta-i", type=FINITE, default=45.0, show_default=True, help="Incidence angle, degrees."
)
_output_option = click.option(
    "-o", "--output", required=True, help="Output figure (.png, .pdf or .svg)."
)


def _check(theta_i, output) -> None:
    """The incidence angle in [0, 90) and the figure's file name (FIGURE_SUFFIXES)."""
    if not 0.0 <= theta_i < 90.0:
        raise UserError(f"--theta-i {theta_i:g} deg is outside [0, 90)")
    output_path(output, FIGURE_SUFFIXES, "output")


def _save(fig, output):
    import matplotlib.pyplot as plt

    from ..viz.figures import save_figure

    try:
        save_figure(fig, output)
    finally:
        plt.close(fig)
    click.echo(f"wrote {output}")


def _repeatable(name: str, dest: str, help_text: str):
    """A model option given at least once, repeatable (the models of one figure)."""
    return click.option(name, dest, multiple=True, required=True, help=help_text)


def _draw(figure, models: list, theta_i: float, output) -> None:
    """``figure(models, theta_i)`` (a lobe figure) checked and saved to ``output``; its
    warnings (a lobe that is 0 everywhere) as "Warning: ..." lines on stderr."""
    _check(theta_i, output)
    with echo_warnings():
        _save(figure(models, theta_i), output)


def _summary(curve) -> str:
    """One line on a curve of ``veil plot curve``: its peak, width and off-peak value."""
    med = "clear" if curve.medium is None else str(curve.medium)
    mt = curve.metrics
    if mt.zero:
        return f"{curve.brdf} / {med}: f = 0 at every angle (no peak or width to measure)"
    return (
        f"{curve.brdf} / {med}: peak {mt.peak:.4g} at {mt.peak_angle:.2f} deg, "
        f"{mt.fwhm_text()}, f({mt.off_angle:g} deg) {mt.off_peak:.4g}"
    )


@click.group("plot")
def plot_command():
    """Single figures: reflection lobe, transmission lobe, observed-value curve."""


@plot_command.command("lobe")
@_repeatable("--brdf", "brdfs", "Object (repeatable): preset or 'PD,PS,N,ETA'.")
@_theta_i_option
@_output_option
@model_options(("brdf",))
def lobe(brdfs, theta_i, output, models):
    """Reflection lobe f_r (as the paper's fig. 9): in and out of the plane of incidence."""
    from ..viz.figures import fig9

    _draw(fig9, [models.brdf_model(b) for b in brdfs], theta_i, output)


@plot_command.command("transmission")
@_repeatable("--medium", "media", "Medium (repeatable): preset or 'TD,TT,G,ETA'.")
@_theta_i_option
@_output_option
@model_options(("medium",))
def transmission(media, theta_i, output, models):
    """Transmission lobe f_t (as the paper's fig. 10) against the transmitted direction."""
    from ..viz.figures import fig10

    models = [models.medium_model(m) for m in media]
    if any(m is None for m in models):
        raise UserError("--medium none has no transmission lobe; give a preset or 'TD,TT,G,ETA'")
    _draw(fig10, models, theta_i, output)


@plot_command.command("curve")
@_repeatable("--brdf", "brdfs", "Object (repeatable): preset or 'PD,PS,N,ETA'.")
@click.option(
    "--medium",
    "media",
    multiple=True,
    default=("none",),
    show_default=True,
    help="Medium (repeatable): preset, 'TD,TT,G,ETA' or 'none' (clear).",
)
@_theta_i_option
@click.option(
    "--scale",
    type=click.Choice(["log", "linear", "peak", "tt2"]),
    default="log",
    show_default=True,
    help="y axis: log or linear f; peak: each curve over its own peak; tt2: f / T_t^2.",
)
@accuracy_option("Quadrature of the engine.")
@_output_option
@model_options()
def curve(brdfs, media, theta_i, scale, accuracy, output, models):
    """Observed value against reflection angle in the plane of incidence (as fig. 11)."""
    from ..viz.figures import fig_curve, inplane_curve

    b_models = [models.brdf_model(b) for b in brdfs]
    m_models = [models.medium_model(m) for m in media]
    _check(theta_i, output)
    curves = [inplane_curve(b, m, theta_i, accuracy=accuracy) for b in b_models for m in m_models]
    for c in curves:
        click.echo(_summary(c))
    with echo_warnings():
        _save(fig_curve(curves, scale), output)
