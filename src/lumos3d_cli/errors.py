"""Exceptions that the CLI turns into one-line messages and exit codes: bad input (2), a failed
run (1), a run stopped by a signal (128 + the signal's number); and how those messages list names."""

from __future__ import annotations

import signal
from collections.abc import Sequence

# The signals that stop a command cleanly (Ctrl-C, `kill`, a closed terminal).
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def listed(items: Sequence[str], limit: int = 5) -> str:
    """The first `limit` items, comma-separated, and how many more: for one-line messages."""
    return ", ".join(items[:limit]) + (f" and {len(items) - limit} more" if len(items) > limit else "")


class InputError(Exception):
    """Bad user input. The message names the file or value and says what to do.

    `parameter` names the library parameter the bad value came from (e.g. "checkpoint"): the
    message then reads "checkpoint <detail>", and a front end names its own option instead
    (`with_option("--checkpoint")`), so library errors never speak of command-line flags.
    """

    def __init__(self, message: str, parameter: str | None = None):
        self.parameter = parameter
        self.detail = message
        super().__init__(f"{parameter} {message}" if parameter else message)

    def with_option(self, option: str) -> str:
        """The message with `option` (a flag such as "--checkpoint") in place of the parameter."""
        return f"{option} {self.detail}" if self.parameter else str(self)


class NonFiniteError(InputError):
    """A tensor or file holds NaN or Inf where finite values are required."""


class DiskError(InputError):
    """A full or unwritable disk met while writing: the user's to fix (exit 2), but no fault of
    the data being read, which a caller that skips bad data must not take it for."""


class RunError(Exception):
    """A long run stopped for a reason its message explains (e.g. training diverged)."""


class Interrupted(BaseException):
    """A command stopped by a signal. Like KeyboardInterrupt it is no `Exception`, so the
    `except Exception` blocks on its way out do not swallow it, while `finally` blocks run.

    `detail` says what was kept (e.g. the checkpoint a stopped training run saved)."""

    def __init__(self, signum: int, detail: str = ""):
        super().__init__(signum, detail)
        self.signum = signum
        self.detail = detail

    @property
    def exit_code(self) -> int:
        """The shell's code for a process ended by this signal: 128 + its number."""
        return 128 + self.signum

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name

    def message(self) -> str:
        """The one line the CLI prints."""
        return f"interrupted by {self.signal_name}" + (
            f": {self.detail}" if self.detail else "; nothing half-written was left behind"
        )
