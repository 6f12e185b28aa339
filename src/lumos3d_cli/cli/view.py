"""`lumos3d view`: turn a restored scene around in the browser (viser), until Ctrl-C."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer
from rich.text import Text

from lumos3d_cli.cli.console import say
from lumos3d_cli.cli.interrupts import library_imports
from lumos3d_cli.errors import Interrupted
from lumos3d_cli.viewer.availability import require_viser
from lumos3d_cli.viewer.defaults import DEFAULT_HOST, DEFAULT_MAX_SPLATS, DEFAULT_PORT

if TYPE_CHECKING:
    from lumos3d_cli.viewer.server import RunningViewer

EXAMPLES = """
  lumos3d view out/                       [dim]# a restore output folder: splats, cameras, photos, summary[/dim]
  lumos3d view scene.ply --port 8090
  lumos3d view out/ --host 0.0.0.0        [dim]# reachable from other machines on the network[/dim]
"""

# What a shell reports for a program ended by Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130


def announce(viewer: RunningViewer) -> None:
    """The URL on stdout (the command's result); the rest on stderr."""
    typer.echo(viewer.url)
    shown = f"{viewer.total:,} Gaussians" if viewer.shown == viewer.total else f"{viewer.shown:,} of {viewer.total:,} Gaussians"
    say(Text.assemble("viewer at ", (viewer.url, "bold"), f" ({shown}); open it in a browser, Ctrl-C to stop"))


def view_command(
    path: Path = typer.Argument(..., help="A restore output folder or a Gaussian scene (.ply)."),
    port: int = typer.Option(DEFAULT_PORT, "--port", help="Port to serve on (0: any free port)."),
    host: str = typer.Option(DEFAULT_HOST, "--host", help="Address to listen on; 0.0.0.0 for every network interface."),
    max_splats: int = typer.Option(DEFAULT_MAX_SPLATS, "--max-splats", help="Send at most this many Gaussians to the browser."),
) -> None:
    """Open a restored scene in an interactive 3D viewer in the browser (Ctrl-C stops it)."""
    serve_until_stopped(path, host, port, max_splats, "the viewer stopped")


def serve_until_stopped(path: Path, host: str, port: int, max_splats: int, stopped: str) -> NoReturn:
    """Serve the scene at `path` until a signal stops the viewer, then exit saying `stopped`
    (Ctrl-C is how a viewer ends, not a failure: there is nothing half-written to speak of)."""
    # The viewer imports viser, torch and the scene readers (seconds): imported here, when the
    # command runs, so that `--help` (which needs only the defaults above) stays fast.
    require_viser()
    with library_imports():
        from lumos3d_cli.viewer.server import serve_scene
    try:
        serve_scene(path, host, port, max_splats, on_ready=announce)
    except Interrupted as stop:
        raise Interrupted(stop.signum, stopped) from None
    raise typer.Exit(EXIT_INTERRUPTED)
