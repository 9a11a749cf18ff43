"""``veil warmup``: compile and store ahead of time the engine programs this machine needs,
so that the first real run of eval, simulate, fit or the pipeline starts fast too."""

from __future__ import annotations

import time

import click

from ._common import ACCURACIES
from ._errors import UserError
from ._model_options import family_options

#: Most channels --channels prepares for (a colour camera has 3 or 4; a program's memory
#: and compile time grow with the channels it runs together).
MAX_CHANNELS = 64


@click.command("warmup", short_help="Compile and store the engine programs ahead of time.")
@click.option(
    "--models",
    "selected",
    multiple=True,
    metavar="NAME",
    help="A model family to prepare (repeatable; 'veil models' lists them; 'all' "
    "for every registered family). A kind not named gets the paper's family. "
    "Default: the paper's pair, torrance-sparrow x henyey-greenstein.",
)
@click.option(
    "--accuracy",
    "accuracies",
    multiple=True,
    type=click.Choice(ACCURACIES),
    help="Accuracy of the results to prepare for (repeatable; default: fast and "
    "default). The fits iterate at 'fast' whatever they report.",
)
@click.option(
    "--channels",
    type=click.IntRange(min=1, max=MAX_CHANNELS),
    default=1,
    show_default=True,
    help="Also prepare the programs that run this many colour channels together (a "
    "measurement table with a channel column, fitted through a forward-series water "
    "whose optical depth or albedo differ per channel; docs/channels.md). Other media "
    f"run each channel with the one-channel programs. At most {MAX_CHANNELS}: a camera has "
    "a handful of channels, and the programs' size grows with their number.",
)
@family_options
@click.option("--quiet", is_flag=True, help="No progress display.")
def warmup_command(selected, accuracies, channels, family_options, quiet):
    """Compile the engine for the chosen model families and keep it: the lowered programs
    in the program store and the compiled executables in the compilation cache (both under
    VEIL_CACHE_DIR, default ~/.cache/veil; docs/performance-startup.md "Start-up"). Each model pair
    takes a few seconds to a minute or two per program the first time; a second warmup
    only checks the entries and takes seconds. Entries made by another veil, JAX or CPU
    are built again. A model option (for example a plate's --path-length and
    --plate-width, --orders, --distribution) changes the programs: give the ones the fits
    will be given. Example:

    \b
        veil warmup
        veil warmup --models rough-plastic --models forward-series --accuracy high
        veil warmup --models rough-plastic --models forward-series \\
            --path-length 15 --plate-width 5 --channels 3
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from ..engine import programs
    from ..engine.forward import wait_for_compilations
    from ..engine.warmup import tasks
    from ..errors import InputError
    from .compile_display import console as shared_console

    _check_options(list(selected) or None, family_options)
    todo = tasks(
        list(selected) or None,
        tuple(accuracies) or ("fast", "default"),
        *family_options,
        channels=channels,
    )
    store = programs.directory()
    if store is None:
        click.echo(
            "veil warmup: VEIL_CACHE_DIR is off, so nothing is kept: this only "
            "compiles, for this process",
            err=True,
        )
    start = time.perf_counter()
    skipped = []
    console = shared_console()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=quiet,
    ) as bar:
        track = bar.add_task("warmup", total=len(todo))
        for k, task in enumerate(todo):
            bar.update(track, description=f"warmup: {task.label}")
            t0 = time.perf_counter()
            try:
                task.run()
                wait_for_compilations()
            except InputError as exc:
                skipped.append(f"{task.label}: {exc}")
                continue
            finally:
                bar.update(track, completed=k + 1)
            if not quiet:
                console.print(f"  {task.label}: {time.perf_counter() - t0:.1f} s", highlight=False)
    for line in skipped:
        click.echo(f"Warning: skipped {line}", err=True)
    where = f"in {store} and the compilation cache" if store else "for this process only"
    click.echo(
        f"veil warmup: {len(todo) - len(skipped)} of {len(todo)} tasks ready {where} "
        f"({time.perf_counter() - start:.1f} s)",
        err=True,
    )


def _check_options(selected, family_options) -> None:
    """A model option that none of the families to prepare declares is a UserError."""
    from ..engine.warmup import families
    from ..models import model_class

    brdfs, media = families(selected)
    classes = [model_class(n, "brdf") for n in brdfs] + [model_class(n, "medium") for n in media]
    for given in family_options:
        for name in given:
            if not any(name in cls.option_names() for cls in classes):
                flag = "--" + name.replace("_", "-")
                raise UserError(
                    f"{flag} applies to none of the families to prepare "
                    f"({', '.join(c.NAME for c in classes)}); name one that declares it "
                    f"with --models"
                )
