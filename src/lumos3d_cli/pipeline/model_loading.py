"""The model a job runs, on a device that exists (which weights: model.bundled_models.resolve_checkpoint)."""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from lumos3d_cli.data.modes import MODES
from lumos3d_cli.errors import InputError
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3D

logger = logging.getLogger(__name__)

DEVICES = ("cpu", "cuda")


def load_restoration_model(checkpoint: Path, device: str, mode: str | None = None) -> Lumos3D:
    """The network of `checkpoint` in eval mode on `device` ("cpu" or "cuda"); a warning when the
    checkpoint says it was trained for another degradation than `mode` (the low-light model
    brightens what the over-exposure mode asks to darken)."""
    if device not in DEVICES:
        raise InputError(f"{device!r}: use cpu or cuda", parameter="device")
    if torch.get_default_dtype() != torch.float32:  # tensors made without a dtype would not match the photos'
        raise InputError(f"torch's default dtype is {torch.get_default_dtype()}; lumos3d computes in float32: call "
                         "torch.set_default_dtype(torch.float32) first")
    model = load_model(checkpoint, device=device)
    trained_for = model.provenance.get("degradation")
    if mode is not None and trained_for in MODES and trained_for != mode:
        logger.warning("%s: was trained for %s photos but the mode is %s; use the %s model (--checkpoint %s) or "
                       "--mode %s", checkpoint, trained_for, mode, mode, mode, trained_for)
    return model

