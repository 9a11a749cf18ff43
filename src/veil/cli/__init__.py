"""The ``veil`` command line.

Each command lives in its own module of this package, named in :data:`COMMANDS` and imported
only when that command runs or shows its help: ``veil --help``, a command's ``--help``, an
argument error and the commands that do no numerics never import JAX or the engine
(docs/architecture.md "Adding a command"; tests/test_cli_startup.py)."""

from __future__ import annotations

import click

from . import interrupts
from ._common import VeilGroup

#: Every command: its name (a subcommand of a group as "group name") -> "module:attribute"
#: in this package. A command module imports only click and ``._common`` at its top; what a
#: command computes with is imported inside its function.
COMMANDS = {
    "eval": "eval_cmd:eval_command",
    "ingest": "ingest_cmd:ingest_command",
    "simulate": "simulate_cmd:simulate_command",
    "render": "render_cmd:render_command",
    "plot": "plot_cmd:plot_command",
    "reproduce": "reproduce_cmd:reproduce_command",
    "fit": "fit_cmd:fit_command",
    "fit joint": "joint_cmd:joint_command",
    "diagnose": "diagnose_cmd:diagnose_command",
    "design": "design_cmd:design_command",
    "demo": "demo_cmd:demo_command",
    "models": "models_cmd:models_command",
    "warmup": "warmup_cmd:warmup_command",
    "export": "export_cmd:export_command",
    "fit maps": "maps_cmd:fit_maps_command",
    "maps": "maps_cmd:maps_command",
    "explore": "explore_cmd:explore_command",
}


class CommandLine(VeilGroup):
    """:class:`VeilGroup` that, run as the ``veil`` program (arguments from ``sys.argv``),
    first installs the Ctrl-C / SIGTERM handling of :mod:`veil.cli.interrupts` and ends the
    process through :func:`veil.cli.interrupts.finish` (no window at the end in which a
    signal goes unanswered). Tests that call ``main.main([...])`` or click's CliRunner pass
    the arguments and get none of it."""

    def main(self, args=None, *more, **options):
        if args is None:
            interrupts.install()
            try:
                super().main(args, *more, **options)
            except SystemExit as done:
                interrupts.finish(done.code)
            interrupts.finish(0)
        return super().main(args, *more, **options)


@click.group(
    cls=CommandLine, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]}
)
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
