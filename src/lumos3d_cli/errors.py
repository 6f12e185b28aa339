"""Exceptions that the CLI turns into one-line messages and exit code 2."""


class InputError(Exception):
    """Bad user input. The message names the file or value and says what to do."""


class NonFiniteError(InputError):
    """A tensor or file holds NaN or Inf where finite values are required."""


class RunError(Exception):
    """A long run stopped for a reason its message explains (e.g. training diverged)."""
