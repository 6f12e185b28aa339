"""`load_model`: a trained network from a checkpoint file or a bundled model's name.

Inference never silently runs on random weights: a name that is not a bundled model (an
architecture's name included: an architecture is a network size, not trained weights) is an error
saying what to pass.
Random weights come only from `build_model`, which says so.
"""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.checkpoints import BUNDLED_MODELS, FORMAT_VGGT, Checkpoint, bundled_weights_path, read_checkpoint
from lumos3d_cli.io.state_dicts import check_tensors
from lumos3d_cli.model.architectures import ARCHITECTURES, Architecture
from lumos3d_cli.model.heads.gaussian import GaussianHead
from lumos3d_cli.model.lumos3d import Lumos3D

logger = logging.getLogger(__name__)


def _checkpoint_for(source: str | Path, architecture: Architecture | None) -> Checkpoint:
    path = Path(source)
    if path.exists():
        return read_checkpoint(path, architecture)
    bundled_names = ", ".join(f"'{mode}'" for mode in BUNDLED_MODELS)
    if isinstance(source, str) and source in BUNDLED_MODELS:
        bundled = bundled_weights_path(BUNDLED_MODELS[source])
        if not bundled.is_file():
            raise InputError(f"the bundled {source} model is missing from this installation ({bundled}); "
                             "reinstall lumos3d or pass a checkpoint file")
        return read_checkpoint(bundled)
    if isinstance(source, str) and source in ARCHITECTURES:
        raise InputError(
            f"'{source}' is a model architecture (a network size), not trained weights: pass a checkpoint file "
            f"(ours, VGGT's model.pt/model.safetensors or AnySplat's model.safetensors) or a bundled model "
            f"({bundled_names}); build_model('{source}') gives random weights for experiments"
        )
    raise InputError(f"'{source}' is neither a checkpoint file nor a bundled model ({bundled_names})")


def model_from_checkpoint(checkpoint: Checkpoint) -> Lumos3D:
    """Build the checkpoint's network and load its tensors (strict key and shape check).

    The network is first built on the meta device, so no memory or time goes into a random
    initialisation the checkpoint would overwrite; modules the file lacks are built for real.
    """
    with torch.device("meta"):
        model = Lumos3D(checkpoint.architecture)
    for name in checkpoint.fresh_modules:
        setattr(model, name, GaussianHead(checkpoint.architecture))
    fresh = tuple(f"{name}." for name in checkpoint.fresh_modules)
    expected = {key: tuple(t.shape) for key, t in model.state_dict().items() if not key.startswith(fresh)}
    check_tensors(expected, checkpoint.tensors, str(checkpoint.path))
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
    (VGGT/AnySplat) checkpoint; it defaults to vggt-1b and must not be given for our own files,
    which carry theirs."""
    model = model_from_checkpoint(_checkpoint_for(source, architecture))
    logger.info("loaded architecture '%s' from %s", model.architecture.name, model.provenance.get("path"))
    return model.to(device).eval()
