"""Whether the viewer can start: viser, which it is built on, is a dependency of lumos3d, but an
environment can lack it (installed with --no-deps, or removed since). Checked without importing
it (an import takes seconds), before a command does any work."""

from __future__ import annotations

import importlib.util

from lumos3d_cli.errors import InputError


def require_viser() -> None:
    """InputError saying how to install viser when it cannot be imported."""
    if importlib.util.find_spec("viser") is None:
        raise InputError("the viewer needs viser, which is not installed here; install it with `pip install viser` "
                         "(a dependency of lumos3d: `pip install lumos3d` brings it)")
