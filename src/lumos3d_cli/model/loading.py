"""`load_model`: a trained network from a checkpoint file or a bundled model's name.

Inference never silently runs on random weights: a name that is not a bundled model (an
architecture's name included: an architecture is a network size, not trained weights) is an error
saying what to pass (`model.bundled_models.resolve_checkpoint`).
Random weights come only from `build_model`, which says so.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.bundled_models import resolve_checkpoint
from lumos3d_cli.model.checkpoints import FORMAT_VGGT, Checkpoint, read_checkpoint
from lumos3d_cli.model.heads.gaussian import GaussianHead
from lumos3d_cli.model.lumos3d import Lumos3D

logger = logging.getLogger(__name__)


def model_from_checkpoint(checkpoint: Checkpoint) -> Lumos3D:
    """Build the checkpoint's network and load its tensors (`read_checkpoint` checked every key and shape).

    The network is first built on the meta device, so no memory or time goes into a random
    initialisation the checkpoint would overwrite; modules the file lacks are built for real.
    """
    with torch.device("meta"):
        model = Lumos3D(checkpoint.architecture)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)  # the same file gives the same fresh modules (a converted VGGT file is reproducible)
        for name in checkpoint.fresh_modules:
            setattr(model, name, GaussianHead(checkpoint.architecture))
    model.load_state_dict(checkpoint.tensors, strict=False, assign=True)
    model.provenance = {**checkpoint.provenance, "format": checkpoint.format, "path": str(checkpoint.path)}
    if checkpoint.fresh_modules:
        logger.warning(
            "%s: %s checkpoint has no %s; it is freshly initialised (random) and needs training before its output means anything",
            checkpoint.path.name, "VGGT" if checkpoint.format == FORMAT_VGGT else checkpoint.format, ", ".join(checkpoint.fresh_modules),
        )
    return model


def load_model(source: str | Path, device: str | torch.device = "cpu", architecture: Architecture | None = None) -> Lumos3D:
    """A network in eval mode on `device`, from a checkpoint path (file or folder) or the name of a
    bundled model ('low-light', 'over-exposure'). `architecture` sets the size of a foreign
    (VGGT/AnySplat) checkpoint (default: the first architecture its shapes fit, vggt-1b tried
    first); it must not be given for our own files, which carry theirs."""
    device = usable_device(device)
    model = model_from_checkpoint(read_checkpoint(resolve_checkpoint(source), architecture))
    logger.info("loaded architecture '%s' from %s", model.architecture.name, model.provenance.get("path"))
    return model.to(device).eval()


def usable_device(device: str | torch.device) -> torch.device:
    """`device` as a torch.device that this machine has; InputError naming it otherwise."""
    try:
        parsed = torch.device(device)
    except (RuntimeError, TypeError):
        raise InputError(f"{device!r}: not a device; use cpu or cuda", parameter="device") from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"{device}: CUDA is not available on this machine; use cpu", parameter="device")
    if parsed.type == "cuda" and parsed.index is not None and parsed.index >= torch.cuda.device_count():
        raise InputError(f"{device}: this machine has {torch.cuda.device_count()} CUDA device(s), numbered from 0",
                         parameter="device")
    if parsed.type not in ("cpu", "cuda"):
        raise InputError(f"{device}: lumos3d runs on cpu or cuda", parameter="device")
    return parsed
