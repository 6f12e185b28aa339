"""The `lumos3d` Typer application: global options, error handling, subcommand registration."""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable

import typer
from rich.text import Text

from lumos3d_cli import __version__
from lumos3d_cli.cli.console import configure_logging, state, stderr_console
from lumos3d_cli.cli.interrupts import Interrupted, interruption_behind, signals_raise_interrupted
from lumos3d_cli.errors import InputError, RunError

EXAMPLES = """
[bold]Examples[/bold]

  lumos3d degrade photos/ -o dark/ --mode low-light --seed 0   [dim]# synthesise a low-light set[/dim]
  lumos3d degrade photos/ -o bright/ --mode over-exposure     [dim]# synthesise over-exposure[/dim]
  lumos3d render scene.ply --orbit 60 -o frames/ --video a.mp4 [dim]# fly around a scene[/dim]
  lumos3d info scene.ply                                      [dim]# summarise a Gaussian scene[/dim]
  lumos3d info photos/ --json                                 [dim]# image folder summary as JSON[/dim]
"""

app = typer.Typer(
    name="lumos3d",
    help="Restore 3D scenes photographed in the dark or over-exposed: unposed photos in, "
    "cameras, depth and restored 3D Gaussians out.",
    epilog=EXAMPLES,
    rich_markup_mode="rich",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"lumos3d {__version__}")
        raise typer.Exit()


@app.callback()
def global_options(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks and debug logs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Only errors; no progress bars."),
) -> None:
    state.debug, state.quiet = debug, quiet
    configure_logging(debug, quiet)


def add_commands() -> typer.Typer:
    """Import the subcommands and add them to `app` (once); returns `app`. Their modules import
    torch, pycolmap and the rest (seconds), so `main` calls this only once its signal handlers
    are in place: Ctrl-C during start-up then ends in the same one line as later."""
    if app.registered_commands:
        return app
    from lumos3d_cli.cli import convert, degrade, eval, info, render, restore, train, view

    app.command("degrade", epilog=degrade.EXAMPLES, rich_help_panel="Data")(degrade.degrade_command)
    app.command("restore", epilog=restore.EXAMPLES, rich_help_panel="Scenes")(restore.restore_command)
    app.command("eval", epilog=eval.EXAMPLES, rich_help_panel="Scenes")(eval.eval_command)
    app.command("train", epilog=train.EXAMPLES, rich_help_panel="Models",
                context_settings={"allow_extra_args": False})(train.train_command)
    app.command("render", epilog=render.EXAMPLES, rich_help_panel="Scenes")(render.render_command)
    app.command("info", epilog=info.EXAMPLES, rich_help_panel="Inspect")(info.info_command)
    app.command("convert", epilog=convert.EXAMPLES, rich_help_panel="Models")(convert.convert_command)
    app.command("view", epilog=view.EXAMPLES, rich_help_panel="Scenes")(view.view_command)
    return app


_GLOBAL_FLAGS = ("--debug", "--quiet", "-q")
# Library parameters whose command-line name is not "--" + the parameter with dashes.
_ARGUMENT_NAMES = {"photos": "PHOTOS", "root": "ROOT", "output": "-o"}


def _for_command_line(error: InputError) -> str:
    """The error's message naming the command-line option or argument of its library parameter."""
    if error.parameter is None:
        return str(error)
    return error.with_option(_ARGUMENT_NAMES.get(error.parameter, "--" + error.parameter.replace("_", "-")))


def main(argv: list[str] | None = None) -> int:
    """Console entry point; returns the exit code.

    0: done. 2: bad input — one line on stderr (the traceback only with --debug); usage errors
    (unknown option, missing argument) also exit with 2, as click reports them. 1: a run that
    failed (RunError) or an internal error. 128 + signal number: stopped by SIGINT (130),
    SIGTERM (143) or SIGHUP (129), one line on stderr; unfinished outputs are removed on the way
    out as for any failure (cli/interrupts.py).
    """
    args = sys.argv[1:] if argv is None else list(argv)
    # Global flags are accepted anywhere on the line (`lumos3d degrade ... --debug`).
    flags = [a for a in args if a in _GLOBAL_FLAGS]
    args = flags + [a for a in args if a not in _GLOBAL_FLAGS]
    debug = "--debug" in flags
    with signals_raise_interrupted() as claim_signals:
        try:
            return _run(args, debug, claim_signals)
        except Interrupted as stop:
            if debug:
                traceback.print_exc()
            stderr_console().print(Text(stop.message(), style="bold yellow"))
            return stop.exit_code


def _run(args: list[str], debug: bool, claim_signals: Callable[[], None]) -> int:
    """Run the app; map its errors to messages and exit codes (interruptions pass through).
    `claim_signals` re-installs the CLI's signal handlers over those the imports installed."""
    try:
        command_line = add_commands()
        claim_signals()
        command_line(args=args, prog_name="lumos3d", standalone_mode=True)
    except SystemExit as done:
        return done.code if isinstance(done.code, int) else 0 if done.code is None else 1
    except InputError as error:
        if debug:
            raise
        stderr_console().print(f"[bold red]error:[/bold red] {_for_command_line(error)}", highlight=False)
        return 2
    except RunError as error:
        if debug:
            raise
        stderr_console().print(f"[bold red]error:[/bold red] {error}", highlight=False)
        return 1
    except Exception as error:  # noqa: BLE001 - the CLI's last line of defence
        stop = interruption_behind(error)
        if stop is not None:
            raise stop from error
        if debug:
            raise
        stderr_console().print(
            f"[bold red]internal error:[/bold red] {type(error).__name__}: {error} "
            "(run with --debug for the traceback and report it)",
            highlight=False,
        )
        return 1
    return 0


def run() -> None:
    sys.exit(main())
