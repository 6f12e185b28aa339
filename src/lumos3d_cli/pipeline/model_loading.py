"""The model a job runs, on a device that exists (which weights: model.bundled_models.resolve_checkpoint)."""

from __future__ import annotations

from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3D

DEVICES = ("cpu", "cuda")


def load_restoration_model(checkpoint: Path, device: str) -> Lumos3D:
    """The network of `checkpoint` in eval mode on `device` ("cpu" or "cuda")."""
    if device not in DEVICES:
        raise InputError(f"{device!r}: use cpu or cuda", parameter="device")
    return load_model(checkpoint, device=device)

