"""The degradation modes: what `degrade` synthesises and which model `restore` and `eval` use.
A module of its own so that the command line names them in its options and `--help` without
importing torch (data.degradations, which synthesises them, imports it)."""

MODES: tuple[str, ...] = ("low-light", "over-exposure")
