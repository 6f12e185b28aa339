"""`python -m lumos3d_cli` runs the CLI (torchrun uses this form)."""

from lumos3d_cli.cli.app import run

run()
