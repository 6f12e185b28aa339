"""The `lumos3d` command line (Typer + rich). No model math lives here. (OpenMP's wait policy,
which the command line relies on, is set when the package is imported: lumos3d_cli/__init__.py.)"""
