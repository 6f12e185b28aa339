"""Training checkpoints: one folder per save (model weights in our safetensors format, optimizer /
scheduler / generator state, the resolved config), written into a staging folder and renamed,
so a checkpoint is complete or absent. `latest` names the newest."""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import write_bytes_atomic
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint
from lumos3d_cli.model.lumos3d import Lumos3D

MODEL_FILE = "model.safetensors"
STATE_FILE = "training_state.pt"
CONFIG_FILE = "config.yaml"
LATEST_FILE = "latest"


@dataclass
class TrainingState:
    """Everything besides the weights needed to continue exactly where a run stopped."""

    step: int
    optimizer: dict
    scheduler: dict
    torch_rng: torch.Tensor
    nonfinite_in_a_row: int
    nonfinite_total: int


def checkpoint_folder(output: Path, step: int) -> Path:
    return output / "checkpoints" / f"step_{step:08d}"


def save_training_checkpoint(
    output: Path, step: int, model: Lumos3D, state: TrainingState, config_yaml: str, provenance: dict, keep: int = 3
) -> Path:
    """Write checkpoints/step_<step>/ atomically, point `latest` at it, keep the newest `keep`."""
    parent = output / "checkpoints"
    parent.mkdir(parents=True, exist_ok=True)
    final = checkpoint_folder(output, step)
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=parent))
    try:
        save_checkpoint(model, staging / MODEL_FILE, provenance)
        torch.save(state.__dict__, staging / STATE_FILE)
        (staging / CONFIG_FILE).write_text(config_yaml)
        if final.exists():
            shutil.rmtree(final)
        os.replace(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    write_bytes_atomic(parent / LATEST_FILE, (final.name + "\n").encode())
    for old in sorted(p for p in parent.glob("step_*") if p.is_dir())[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(output: Path) -> Path | None:
    pointer = output / "checkpoints" / LATEST_FILE
    if not pointer.is_file():
        return None
    folder = output / "checkpoints" / pointer.read_text().strip()
    return folder if (folder / STATE_FILE).is_file() and (folder / MODEL_FILE).is_file() else None


def load_training_checkpoint(folder: Path, model: Lumos3D) -> TrainingState:
    """Load the weights into `model` (same architecture) and return the rest of the state."""
    checkpoint = read_checkpoint(folder / MODEL_FILE)
    if checkpoint.architecture != model.architecture:
        raise InputError(f"{folder}: checkpoint architecture '{checkpoint.architecture.name}' differs from the configured model")
    model.load_state_dict(checkpoint.tensors)
    values = torch.load(folder / STATE_FILE, map_location="cpu", weights_only=True)
    return TrainingState(**values)
