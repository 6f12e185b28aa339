"""Exceptions that the CLI turns into one-line messages and exit code 2."""

from __future__ import annotations


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


class RunError(Exception):
    """A long run stopped for a reason its message explains (e.g. training diverged)."""
