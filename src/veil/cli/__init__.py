"""The ``veil`` command line. Each subcommand lives in its own module of this package and is
registered on :data:`main` at the bottom of this file."""

from __future__ import annotations

import click

from . import interrupts
from ._common import VeilGroup


class CommandLine(VeilGroup):
    """:class:`VeilGroup` that, run as the ``veil`` program (arguments from ``sys.argv``),
    first installs the Ctrl-C / SIGTERM handling of :mod:`veil.cli.interrupts`. Tests that
    call ``main.main([...])`` or click's CliRunner pass the arguments and get none of it."""

    def main(self, args=None, *more, **options):
        if args is None:
            interrupts.install()
        return super().main(args, *more, **options)


@click.group(cls=CommandLine, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="veil")
@click.option("--debug", is_flag=True, help="Print the full traceback of an internal error.")
@click.pass_context
def main(ctx, debug):
    """veil: reflectance of objects seen through scattering media.

    Angles are in degrees everywhere. Models are given as preset names (BRDF1, BRDF2,
    BTDF1, BTDF2, BTDF3) or as literal parameter lists of the families chosen with
    --brdf-model / --medium-model ('veil models' lists them).
    Exit status: 0 done, 1 a fit did not converge, 2 a mistake in the input, 3 a bug in
    veil, 130/143 interrupted (docs/errors.md).
    """
    ctx.ensure_object(dict)["debug"] = debug


# Subcommands: one module each, registered here.
from . import eval_cmd  # noqa: E402
from . import ingest_cmd  # noqa: E402
from . import simulate_cmd  # noqa: E402
from . import render_cmd, plot_cmd, reproduce_cmd  # noqa: E402
from . import fit_cmd, demo_cmd  # noqa: E402
from . import joint_cmd, diagnose_cmd, design_cmd  # noqa: E402
from . import models_cmd  # noqa: E402
from . import explore_cmd  # noqa: E402

main.add_command(eval_cmd.eval_command)
main.add_command(ingest_cmd.ingest_command)
main.add_command(simulate_cmd.simulate_command)
main.add_command(render_cmd.render_command)
main.add_command(plot_cmd.plot_command)
main.add_command(reproduce_cmd.reproduce_command)
main.add_command(fit_cmd.fit_command)
fit_cmd.fit_command.add_command(joint_cmd.joint_command)
main.add_command(diagnose_cmd.diagnose_command)
main.add_command(design_cmd.design_command)
main.add_command(demo_cmd.demo_command)
main.add_command(models_cmd.models_command)
main.add_command(explore_cmd.explore_command)
