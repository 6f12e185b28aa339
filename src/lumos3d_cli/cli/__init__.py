"""The `lumos3d` command line (Typer + rich). No model math lives here."""
