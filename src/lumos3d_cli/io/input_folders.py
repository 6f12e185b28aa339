"""An input that must be a folder (a dataset root, a folder of LOM scenes): named as a file when
the user gave one, as missing when it is not there."""

from __future__ import annotations

from pathlib import Path

from lumos3d_cli.errors import InputError


def require_folder(path: Path | str, what: str) -> None:
    """InputError unless `path` is a folder; `what` says what the folder holds (e.g. "that holds
    the training scenes")."""
    path = Path(path)
    if path.is_dir():
        return
    if path.exists():
        raise InputError(f"{path}: is a file, not a folder; give the folder {what}")
    raise InputError(f"{path}: no such folder; give the folder {what}")
