"""``veil explore``: an interactive page (docs/explore.md). A local Panel server shows a BRDF
through a medium with controls built from the model declarations; given fit results and
their data, the fit against the data. ``--static -o page.html`` writes a self-contained page
instead. Heavy imports (JAX, the engine, Panel) happen inside the command."""

from __future__ import annotations

import errno
import os
import socket
from pathlib import Path

import click

from .._extras import require
from ._common import OutputPath, UserError, check_output_path

IN_FILE = click.Path(exists=True, dir_okay=False, path_type=Path)
#: Port tried first (Panel's usual one).
DEFAULT_PORT = 5006
#: Loopback only: the page runs veil on this machine for whoever reaches the port.
ADDRESS = "127.0.0.1"


def port_free(port: int, address: str = ADDRESS) -> bool:
    """Whether a server can listen on ``address:port`` now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((address, port))
        except OSError:
            return False
    return True


def free_port(address: str = ADDRESS) -> int:
    """A port the system reports free on ``address``."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((address, 0))
        return s.getsockname()[1]


def choose_port(port: int | None, echo=None) -> int:
    """``port`` if it is free (0 or None: any free port), else another free one, saying so
    through ``echo``."""
    if not port:
        return free_port()
    if port_free(port):
        return port
    other = free_port()
    if echo:
        echo(f"port {port} is in use; serving on port {other} instead")
    return other


def open_browser(url: str, echo) -> bool:
    """Open ``url`` in the machine's browser; without one, print the address to open."""
    import webbrowser

    try:
        browser = webbrowser.get()
        opened = browser.open(url)
    except webbrowser.Error:
        opened = False
    if not opened:
        echo(f"no web browser found on this machine: open {url} in a browser that can reach it")
    return opened


def _said_unconverged(result, path):
    """``result``, with a warning when it did not converge (as veil export and render say)."""
    if not getattr(result, "converged", True):
        from ._result_models import unconverged_warning

        click.echo(unconverged_warning(result, path), err=True)
    return result


def load_inputs(files, data, black):
    """(state, fit views) from the command's files: fit results (each sets the model of its
    kind) or one state file written by the page's share button; ``data`` must be the table
    of one of the results."""
    from ..errors import InputError
    from ..fitting.result import load_result
    from ..viz import explore as ex
    from ..viz import explore_fits as fits

    files = [os.fspath(f) for f in files]
    states = [f for f in files if ex.is_state_file(f)]
    if states:
        if len(files) > 1:
            raise UserError(
                f"{states[0]} is a saved page state: give it alone (it names its "
                f"own results and data)"
            )
        state = ex.State.load(states[0])
        for path in state.results + [p for p in (state.data, state.black) if p]:
            if not os.path.isfile(path):
                raise UserError(f"{states[0]} names {path}, which does not exist")
        if data is None and state.data:
            data = state.data
        if black is None and state.black:
            black = state.black
        files = list(state.results)
    else:
        state = None
    results = []
    for f in files:
        results.append(_said_unconverged(fits.check_result_kind(load_result(f), f), f))
    if data is not None and not results:
        raise UserError(f"--data {data}: give the fit result it belongs to (RESULT.json)")
    channels = fits.result_channels(results, files)
    if channels and data is not None:
        raise UserError(
            f"--data {data}: the data panel shows a fit of one channel; the "
            f"results are fitted over channels {', '.join(channels)} (the page "
            f"shows their models without --data)"
        )
    if black is not None and data is None:
        raise UserError("--black needs --data (the black cloth of the fit's table)")
    views = []
    if data is not None:
        errors = []
        for result, f in zip(results, files):
            try:
                views.append(
                    fits.FitView(
                        result,
                        os.fspath(data),
                        None if black is None else os.fspath(black),
                        source=f,
                        table_name=os.fspath(data),
                    )
                )
                break
            except InputError as exc:
                errors.append(str(exc))
        if not views:
            raise UserError(f"--data {data} belongs to none of the results: " + "; ".join(errors))
    if state is None:
        by_channel = {c: fits.models_of(results, files, c) for c in channels} or None
        brdf, medium = (
            fits.models_of(results, files) if by_channel is None else by_channel[channels[0]]
        )
        state = ex.State(
            brdf,
            medium,
            results=files,
            data=None if data is None else os.fspath(data),
            black=None if black is None else os.fspath(black),
            channels=by_channel,
        )
    return state, views


@click.command("explore")
@click.argument("files", nargs=-1, type=IN_FILE, metavar="[RESULT.json ...]")
@click.option(
    "--data",
    type=IN_FILE,
    metavar="TABLE.csv",
    help="The measurement table of one of the results: drawn with error bars over "
    "the fitted model, its uncertainty band and residuals.",
)
@click.option(
    "--black",
    type=IN_FILE,
    metavar="TABLE.csv",
    help="The black-cloth table the fit subtracted from --data.",
)
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=DEFAULT_PORT,
    show_default=True,
    help="Port of the local server (0: any free port; a port in use: another).",
)
@click.option("--no-browser", is_flag=True, help="Print the address instead of opening it.")
@click.option(
    "--share-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=".",
    show_default=True,
    help="Folder where the page's share button writes states.",
)
@click.option(
    "--static",
    "static",
    is_flag=True,
    help="Write a self-contained page (-o) instead of serving: the views "
    "precomputed over a grid of one parameter (--param), switched by a slider.",
)
@click.option(
    "-o",
    "--output",
    type=OutputPath(dir_okay=False, path_type=Path),
    help="The page --static writes (HTML).",
)
@click.option(
    "--param",
    "param",
    metavar="NAME",
    help="--static: the parameter on the slider (brdf.NAME or medium.NAME where "
    "both models have one). Default: the BRDF's first shape parameter.",
)
@click.option(
    "--points",
    type=click.IntRange(2, 41),
    default=9,
    show_default=True,
    help="--static: values of the parameter on the slider.",
)
@click.pass_context
def explore_command(
    ctx, files, data, black, port, no_browser, share_dir, static, output, param, points
):
    """An interactive page: a BRDF through a medium, and a fit against its data.

    \b
        veil explore                                  # the paper's BRDF1 through BTDF1
        veil explore target.json --data target_medium.csv --black black.csv
        veil explore veil-explore-20261201-120000.json   # a state the share button wrote
        veil explore target.json --static --param n -o page.html

    Controls come from the model declarations ('veil models'); the curves follow each slider
    move, the lit sphere is rendered when the sliders rest.
    """
    if static and output is None:
        raise UserError("--static writes a page: give -o PAGE.html")
    require("panel", "veil explore")  # before any work: the page is Panel's
    if output is not None and not static:
        raise UserError("-o is for --static (the server needs no output file)")
    if (param is not None) and not static:
        raise UserError("--param is for --static")
    if output is not None:
        check_output_path(output, [*files, data, black])
    if not static:
        share = os.fspath(share_dir)
        if not os.path.isdir(share):
            raise UserError(f"--share-dir {share}: folder does not exist")
        if not os.access(share, os.W_OK):
            raise UserError(f"--share-dir {share}: folder is not writable")
    state, views = load_inputs(files, data, black)
    if static and state.channels is not None:
        raise UserError(
            "--static precomputes one channel's page; results fitted over "
            "several channels are shown by the server (without --static)"
        )
    if static:
        _write_static(state, views, param, points, output)
        return
    _serve(state, views, port, no_browser, share_dir)


def _default_param(state) -> str:
    """The BRDF's first parameter that is not a scale (its shape), else its first."""
    cls = type(state.brdf)
    scales = set(cls.scale_names())
    for p in cls.PARAMS:
        if p.name not in scales:
            return f"brdf.{p.name}"
    return f"brdf.{cls.PARAMS[0].name}"


def _write_static(state, views, param, points, output):
    from ..viz.explore_static import save_static, static_page

    def progress(done, total):
        click.echo(f"\rprecomputing {done}/{total}", err=True, nl=done == total)

    body, values = static_page(
        state, param or _default_param(state), points, views, progress=progress
    )
    save_static(body, output)
    click.echo(
        f"wrote {output} ({len(values)} states of {param or _default_param(state)})", err=True
    )


def _serve(state, views, port, no_browser, share_dir):
    pn = require("panel", "veil explore")

    from ..viz.explore import warm_up
    from ..viz.explore_page import ExplorePage

    echo = lambda text: click.echo(text, err=True)  # noqa: E731
    live, _ = warm_up(state)  # compiles in the background what the page needs
    chosen = choose_port(port, echo)

    def page():
        for future in live:  # the first page waits for the engine's compilation
            future.result()
        return ExplorePage(state, views, share_dir).layout()

    pn.extension()
    try:
        server = pn.serve(
            {"/": page},
            port=chosen,
            address=ADDRESS,
            show=False,
            start=False,
            title="veil explore",
            verbose=False,
            websocket_origin=[f"{ADDRESS}:{chosen}", f"localhost:{chosen}"],
        )
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise UserError(
                f"port {chosen} was taken before the server could use it; run again"
            ) from None
        raise
    url = f"http://{ADDRESS}:{chosen}/"
    server.start()
    echo(f"veil explore: serving {url} (Ctrl-C stops)")
    if not no_browser:
        server.io_loop.add_callback(lambda: open_browser(url, echo))
    server.io_loop.start()
