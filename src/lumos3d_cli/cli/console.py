"""Shared CLI state: consoles, logging, progress bars and JSON output."""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass

from rich.console import Console
from rich.logging import RichHandler
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.text import Text

from lumos3d_cli.io.json_text import json_text


@dataclass
class CliState:
    debug: bool = False
    quiet: bool = False


state = CliState()


def stderr_console() -> Console:
    """Messages, logs and progress go to stderr so that stdout carries only results (--json).
    The console looks up sys.stderr when it writes, so it follows later redirections. No markup:
    the lines quote paths and values as the user wrote them ("IMG [edited].jpg"); emphasis is
    given as styled Text."""
    return Console(stderr=True, soft_wrap=True, markup=False)


def stdout_console() -> Console:
    return Console(soft_wrap=True, markup=False)


def configure_logging(debug: bool, quiet: bool) -> None:
    level = logging.DEBUG if debug else logging.ERROR if quiet else logging.WARNING
    if sys.stderr.isatty():
        handler = RichHandler(console=stderr_console(), show_time=False, show_path=debug, markup=False)
        line_format = "%(message)s"
    else:
        # Piped or captured (CI, log files, scripts): rich would wrap every record at 80 columns,
        # splitting paths and one-line warnings; plain lines keep them whole and greppable.
        handler = logging.StreamHandler(sys.stderr)
        line_format = "%(levelname)s %(message)s"
    logging.basicConfig(level=logging.WARNING, handlers=[handler], format=line_format, force=True)
    logging.getLogger("lumos3d_cli").setLevel(level)


class _ProgressShownOnceUsed(Progress):
    """A Progress drawn from its first task on: one that a refused command leaves unused draws
    nothing, so its error stays the one line on stderr (a started, empty display ends in a blank
    line)."""

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exception) -> None:
        if self.live.is_started:
            self.stop()

    def add_task(self, *args, **kwargs):
        if not self.live.is_started:
            self.start()
        return super().add_task(*args, **kwargs)


def progress_bar() -> Progress:
    """A rich progress bar on stderr; silent under --quiet."""
    return _ProgressShownOnceUsed(
        TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
        TimeElapsedColumn(), TimeRemainingColumn(),
        console=stderr_console(), disable=state.quiet, transient=False,
    )


def print_json(document: dict) -> None:
    """One JSON document on stdout."""
    # strict JSON: non-finite values as null (the files written beside it said which)
    sys.stdout.write(json_text(document))
    sys.stdout.flush()


def say(message: str | Text) -> None:
    """A human-readable line on stderr unless --quiet (plain text: see `stderr_console`)."""
    if not state.quiet:
        stderr_console().print(message)


class ProgressBars:
    """A job's progress (pipeline.progress.JobProgress) drawn as rich progress bars, one per stage."""

    def __init__(self, progress: Progress):
        self._progress = progress
        self._tasks: dict[str, int] = {}

    def start(self, stage: str, total: int) -> None:
        self._tasks[stage] = self._progress.add_task(stage, total=total)

    def advance(self, stage: str, steps: int = 1) -> None:
        if stage in self._tasks:
            self._progress.advance(self._tasks[stage], steps)
