"""The `lumos3d` Typer application: global options, error handling, subcommand registration."""

from __future__ import annotations

import importlib
import logging
import os
import sys
import traceback
from collections.abc import Callable

import typer
from rich.text import Text

import lumos3d_cli
from lumos3d_cli.cli.console import configure_logging, state, stderr_console
from lumos3d_cli.cli.interrupts import interruption_behind, signals_raise_interrupted
from lumos3d_cli.errors import InputError, Interrupted, RunError
from lumos3d_cli.io.work_folders import remove_work_folders

EXAMPLES = """
[bold]Examples[/bold]

  lumos3d restore dark_photos/ -o out/scene.ply                [dim]# restore a scene shot in the dark[/dim]
  lumos3d eval lom/ --scenes buu --protocol holdout            [dim]# score against LOM's references[/dim]
  lumos3d degrade photos/ -o dark/ --mode low-light --seed 0   [dim]# synthesise a low-light set[/dim]
  lumos3d degrade photos/ -o bright/ --mode over-exposure      [dim]# synthesise over-exposure[/dim]
  lumos3d render scene.ply --orbit 60 -o frames/ --video a.mp4 [dim]# fly around a scene[/dim]
  lumos3d info scene.ply                                       [dim]# summarise a Gaussian scene[/dim]
  lumos3d info photos/ --json                                  [dim]# image folder summary as JSON[/dim]
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
        typer.echo(f"lumos3d {lumos3d_cli.__version__}")
        raise typer.Exit()


@app.callback()
def global_options(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
    debug: bool = typer.Option(False, "--debug", help="Show full tracebacks and debug logs."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Only errors; no progress bars."),
) -> None:
    state.debug, state.quiet = debug, quiet
    configure_logging(debug, quiet)


# Subcommand name (also its module under lumos3d_cli.cli) -> its help panel, in `--help`'s order.
_COMMAND_PANELS = {
    "degrade": "Data", "restore": "Scenes", "eval": "Scenes", "train": "Models",
    "render": "Scenes", "info": "Inspect", "convert": "Models", "view": "Scenes",
}


def add_commands(args: list[str] | None = None) -> typer.Typer:
    """Import subcommands and add them to `app`; returns `app`. A command line that names a
    subcommand imports only that one's module, `--version` (without `--help`) none, any other
    (`--help`) them all. Their modules import only what their options need (`--help` takes a
    fraction of a second); each command imports the library (torch, pycolmap, trimesh, viser:
    seconds) when it runs, inside `interrupts.library_imports`, which claims the signals back
    from a library that took them (Ctrl-C during those imports ends in the same one line as later:
    `main`'s signal handlers are in place before any of this runs)."""
    named = next((arg for arg in args or () if not arg.startswith("-")), None)
    if named is None and "--version" in (args or ()) and not any(arg in ("-h", "--help") for arg in args):
        return app  # the eager --version prints and exits before any command is looked up
    wanted = [named] if named in _COMMAND_PANELS else list(_COMMAND_PANELS)
    registered = {info.name for info in app.registered_commands}
    for name in wanted:
        if name in registered:
            continue
        module = importlib.import_module(f"lumos3d_cli.cli.{name}")
        settings = {"context_settings": {"allow_extra_args": False}} if name == "train" else {}
        app.command(name, epilog=module.EXAMPLES, rich_help_panel=_COMMAND_PANELS[name], **settings)(getattr(module, f"{name}_command"))
    return app


def _hide_flag_metavars(command) -> None:
    """Flags take no value: `--help` shows none for them (typer shows `<bool>`, which reads as if
    `--view` wanted one), `--help` itself included (click makes it when the help is drawn)."""
    for param in command.params:
        if getattr(param, "is_flag", False):
            param.metavar = ""
    make_help_option = command.get_help_option

    def help_option(context):
        option = make_help_option(context)
        if option is not None:
            option.metavar = ""
        return option

    command.get_help_option = help_option
    for sub in getattr(command, "commands", {}).values():
        _hide_flag_metavars(sub)


_GLOBAL_FLAGS = ("--debug", "--quiet", "-q")
# Library parameters whose command-line name is not "--" + the parameter with dashes.
_ARGUMENT_NAMES = {"photos": "PHOTOS", "root": "ROOT", "output": "-o"}


def _refuse_empty_arguments(args: list[str]) -> None:
    """InputError for an empty argument, or an option given an empty value (`--output=`): no
    option takes one, and click reads an empty path as the current folder, so `-o "$OUT"` with
    OUT unset wrote every output there and `degrade ""` read it as the input. (A training
    override `key=` is no option: it is left to the config's checks.)"""
    for index, arg in enumerate(args):
        if arg == "--":
            return
        if not arg:
            where = f"after '{args[index - 1]}'" if index else "first"
            raise InputError(f"an empty argument ({where} on the command line; an unset shell variable?): give a value")
        if arg.startswith("--") and arg.endswith("=") and arg.count("=") == 1:
            raise InputError(f"{arg}: gives the option an empty value (an unset shell variable?): give a value")


def _error_line(label: str, message: str) -> None:
    """`label: message` on stderr, the label in bold red; the message as plain text (it quotes
    paths and values the user typed, which may hold rich markup such as "IMG [edited].jpg")."""
    stderr_console().print(Text.assemble((f"{label}:", "bold red"), " ", message), highlight=False)


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
    try:
        with signals_raise_interrupted() as claim_signals:
            return _run(args, debug, claim_signals)
    except Interrupted as stop:  # also one that lands as the handlers come off (torchrun's SIGTERM to the ranks)
        if debug:
            traceback.print_exc()
        stderr_console().print(Text(stop.message(), style="bold yellow"))
        return stop.exit_code


def _run(args: list[str], debug: bool, claim_signals: Callable[[], None]) -> int:
    """Run the app; map its errors to messages and exit codes (interruptions pass through).
    `claim_signals` re-installs the CLI's signal handlers over any the imports installed."""
    try:
        _refuse_empty_arguments(args)
        command_line = add_commands(args)
        claim_signals()
        # Not standalone: click returns the code of typer.Exit and `--help`, and raises its usage
        # errors here, so that they read as one line like every other bad input.
        command = typer.main.get_command(command_line)
        _hide_flag_metavars(command)
        result = command.main(args=args, prog_name="lumos3d", standalone_mode=False)
        return result if isinstance(result, int) else 0
    except SystemExit as done:
        return done.code if isinstance(done.code, int) else 0 if done.code is None else 1
    except typer.Abort:  # end of input at a prompt; a signal raises Interrupted instead
        _error_line("error", "aborted")
        return 1
    except typer.TyperException as error:  # a usage error: unknown option, missing argument, a value of the wrong type
        where = error.ctx.command_path if getattr(error, "ctx", None) is not None else "lumos3d"
        message = error.format_message().rstrip(".")
        if message:  # `lumos3d` alone has shown its help: nothing is wrong to say
            _error_line("error", f"{message}; see '{where} --help'")
        return getattr(error, "exit_code", 2)
    except InputError as error:
        if debug:  # the traceback, then the same line and exit code as without --debug
            traceback.print_exc()
        _error_line("error", _for_command_line(error))
        return 2
    except RunError as error:
        if debug:
            traceback.print_exc()
        _error_line("error", str(error))
        return 1
    except Exception as error:  # noqa: BLE001 - the CLI's last line of defence
        stop = interruption_behind(error)
        if stop is not None:
            raise stop from error
        if debug:
            raise
        _error_line("internal error",
                    f"{type(error).__name__}: {error} (run with --debug for the traceback and report it)")
        return 1
    return 0


def run() -> None:
    """The `lumos3d` script: `main`, then the process ends without the interpreter's teardown.

    When `main` returns, every output is committed and closed and every temporary folder removed
    (each by its own context manager); what Python would still do is unload torch, numba and
    pycolmap and free the scene, about 1 s after a restore of 25 photos on 2 cores (measured:
    33.7 s wall for 32.6 s to the last atexit handler). So the streams and log handlers are flushed
    and the process exits at once. An exception out of `main` (only with --debug) takes the usual
    way, with its traceback."""
    try:
        code = main()
    finally:
        remove_work_folders()  # what threads still working had in use: os._exit runs none of their cleanup
    logging.shutdown()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:  # a closed pipe: what was written is all the reader takes; the code stands
        pass
    os._exit(code)
