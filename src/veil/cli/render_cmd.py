"""``veil render``: one sphere under a true or apparent BRDF (paper fig. 12; see
:mod:`veil.render` and docs/figures.md)."""

from __future__ import annotations

import io
import os

import click

from .._lazy import np
from ._common import UserError, check_file_target, model_options


def output_path(path: str, suffixes: tuple, what: str) -> str:
    """Check that ``path`` can be written as ``what`` (suffix and directory); UserError if not."""
    if not path.lower().endswith(suffixes):
        raise UserError(f"{what} {path!r} must end in {' or '.join(suffixes)}")
    check_file_target(path, f"{what} {path!r}", f"{what} {path!r}")
    return path


@click.command("render", short_help="Render a sphere under a true or apparent BRDF.")
@click.option("--brdf", required=True, help="Object: preset (BRDF1, BRDF2) or 'PD,PS,N,ETA'.")
@click.option("--medium", default="none", show_default=True,
              help="Medium: preset (BTDF1..3), 'TD,TT,G,ETA', or 'none' for the true BRDF.")
@click.option("--light-theta", type=float, default=45.0, show_default=True,
              help="Light's polar angle from the viewing direction, degrees, in [0, 120].")
@click.option("--light-phi", type=float, default=0.0, show_default=True,
              help="Light's azimuth, degrees (0: from the right, 90: from the top).")
@click.option("--size", type=int, default=256, show_default=True,
              help="Image size in pixels, 8 to 4096 (memory grows with its square: about "
                   "0.9 GB at 4096).")
@click.option("--exposure", type=float, default=None,
              help="Scale from linear value to display (1 = white). Default: automatic, the "
                   "median lit pixel maps to 0.18.")
@click.option("--tone", type=click.Choice(["clip", "reinhard"]), default="clip",
              show_default=True,
              help="clip: linear, clipped at white; reinhard: x/(1+x), never clips.")
@click.option("--samples", type=int, default=1, show_default=True,
              help="k x k samples per pixel, 1 to 8 (1: the pixel centre); the time grows "
                   "with k^2, the memory does not.")
@click.option("--accuracy", type=click.Choice(["fast", "default", "high"]), default="fast",
              show_default=True, help="Quadrature of the engine.")
@click.option("--check", type=int, default=64, show_default=True,
              help="Pixels evaluated directly to measure the interpolation error.")
@click.option("--linear", "linear_path", default=None,
              help="Also save the linear float values (float32) to this .npy file.")
@click.option("-o", "--output", required=True, help="Output PNG (8-bit greyscale, sRGB).")
@click.option("--quiet", is_flag=True, help="No progress display.")
@model_options()
def render_command(brdf, medium, light_theta, light_phi, size, exposure, tone, samples,
                   accuracy, check, linear_path, output, quiet, models):
    """Render a unit sphere lit by a distant point light, seen by an orthographic camera.

    Pixel value = f(I, R) cos(theta_i) at each visible, lit point with the sphere's local
    normal (paper eq. 1), f the object's BRDF or, with --medium, its apparent BRDF through
    the medium. Prints the exposure used, how many pixels clip and the measured
    interpolation error.
    """
    from ..io import write_many_atomic
    from ..viz.render import auto_exposure, check_memory, clipping, png_bytes, render, tone_map

    b = models.brdf_model(brdf)
    m = models.medium_model(medium)
    output_path(output, (".png",), "output")
    if linear_path is not None:
        output_path(linear_path, (".npy",), "--linear file")
        if os.path.abspath(linear_path) == os.path.abspath(output):
            raise UserError("--linear and -o name the same file")
    if exposure is not None and not (np.isfinite(exposure) and exposure > 0):
        raise UserError(f"--exposure {exposure:g} must be a positive number")
    if 8 <= size <= 4096 and 1 <= samples <= 8:  # render() words the range errors
        check_memory(size, samples, names=("--size", "--samples"))

    result = render(b, m, light_theta, light_phi, size, accuracy=accuracy, samples=samples,
                    check=check, progress=not quiet)
    auto = exposure is None
    exp_used = auto_exposure(result.image) if auto else exposure
    n_clip, frac, peak_fs = clipping(result.image, exp_used, tone)
    text = {"veil:brdf": str(b), "veil:medium": "clear" if m is None else str(m),
            "veil:light": f"theta {light_theta:g} deg, phi {light_phi:g} deg",
            "veil:pixel": "f(I,R) cos(theta_i), linear, then exposure, tone curve, sRGB",
            "veil:exposure": f"{exp_used:.6g}", "veil:tone": tone}
    files = {output: png_bytes(tone_map(result.image, exp_used, tone), text)}
    if linear_path is not None:
        buf = io.BytesIO()
        np.save(buf, result.image.astype(np.float32))
        files[linear_path] = buf.getvalue()
    write_many_atomic(files)  # both files or neither

    click.echo(result.summary())
    how = "automatic: median lit pixel -> 0.18" if auto else "given"
    click.echo(f"exposure {exp_used:.6g} ({how}), tone curve {tone}; peak = {peak_fs:.3g} x "
               f"full scale")
    if tone == "clip":
        if n_clip:
            click.echo(f"highlights clip: {n_clip} pixels ({100 * frac:.2g} % of the lit ones) "
                       f"are above white")
        else:
            click.echo("nothing clips")
    click.echo(f"wrote {output}" + (f" and {linear_path}" if linear_path else "")
               + f" in {result.seconds:.1f} s")
