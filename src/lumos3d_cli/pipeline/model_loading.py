"""The model a job runs: the bundled model of its mode or a checkpoint, on a device that exists."""

from __future__ import annotations

from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.checkpoints import BUNDLED_MODELS, bundled_weights_path
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3D

DEVICES = ("cpu", "cuda")


def resolve_checkpoint(checkpoint: Path | str | None, mode: str) -> Path:
    """The given checkpoint, or the bundled model of `mode` (InputError naming what is missing)."""
    if checkpoint is not None:
        path = Path(checkpoint)
        if not path.exists():
            raise InputError(f"{path}: no such file or folder", parameter="checkpoint")
        return path
    path = bundled_weights_path(BUNDLED_MODELS[mode])
    if not path.is_file():
        raise InputError(f"{mode}: no bundled model ({path.name} is missing from the package); give a checkpoint",
                         parameter="mode")
    return path


def load_restoration_model(checkpoint: Path, device: str) -> Lumos3D:
    """The network of `checkpoint` in eval mode on `device` ("cpu" or "cuda")."""
    if device not in DEVICES:
        raise InputError(f"{device!r}: use cpu or cuda", parameter="device")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("cuda: CUDA is not available on this machine; use cpu", parameter="device")
    return load_model(checkpoint, device=device)

