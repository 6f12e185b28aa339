"""Training checkpoints: one folder per save (model weights in our safetensors format, optimizer /
scheduler / generator state, the resolved config), written into a staging folder and renamed,
so a checkpoint is complete or absent. `latest` names the newest."""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import atomic_directory, write_bytes_atomic
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint
from lumos3d_cli.model.lumos3d import Lumos3D

MODEL_FILE = "model.safetensors"
STATE_FILE = "training_state.pt"
CONFIG_FILE = "config.yaml"
LATEST_FILE = "latest"

logger = logging.getLogger(__name__)


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
    """Write checkpoints/step_<step>/ atomically (a folder of that step is replaced whole), point
    `latest` at it, keep the newest `keep`."""
    parent = output / "checkpoints"
    final = checkpoint_folder(output, step)
    with atomic_directory(parent, replace_folders=True) as staging:
        folder = staging / final.name
        folder.mkdir()
        save_checkpoint(model, folder / MODEL_FILE, provenance)
        torch.save(state.__dict__, folder / STATE_FILE)
        (folder / CONFIG_FILE).write_text(config_yaml)
    write_bytes_atomic(parent / LATEST_FILE, (final.name + "\n").encode())
    for old in _step_folders(parent)[keep:]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _step_folders(parent: Path) -> list[Path]:
    """The checkpoint folders in `parent`, newest step first."""
    return sorted((p for p in parent.glob("step_*") if p.is_dir()), key=lambda p: p.name, reverse=True)


def resume_candidates(output: Path) -> list[Path]:
    """The checkpoints to try when resuming, in order: the one `checkpoints/latest` names, then
    every other step folder, newest first (a damaged newest save falls back to an older one).
    InputError when there is nothing to try; a missing folder `latest` names is logged."""
    parent = output / "checkpoints"
    pointer = parent / LATEST_FILE
    folders = _step_folders(parent) if parent.is_dir() else []
    name = pointer.read_text().strip() if pointer.is_file() else ""
    named = parent / name if name else None
    if named is not None and named not in folders:
        logger.warning("%s names %s, which is missing", pointer, named)
    if not folders:
        if named is not None:
            raise InputError(f"{pointer} names {named.name}, but the folder {named} is missing and no other "
                             "checkpoint is there; start without --resume")
        raise InputError(f"{output}: no checkpoint to resume from ({parent} holds no step_* folders); start without --resume")
    return ([named] + [f for f in folders if f != named]) if named in folders else folders


def load_training_checkpoint(folder: Path, model: Lumos3D) -> TrainingState:
    """Load the weights into `model` (same architecture) and return the rest of the state.
    A missing or unreadable file is an InputError naming it; `model` is untouched then."""
    for name in (MODEL_FILE, STATE_FILE):
        if not (folder / name).is_file():
            raise InputError(f"{folder / name}: missing; the checkpoint is incomplete")
    checkpoint = read_checkpoint(folder / MODEL_FILE)
    if checkpoint.architecture != model.architecture:
        raise InputError(f"{folder}: checkpoint architecture '{checkpoint.architecture.name}' differs from the configured model")
    try:
        values = torch.load(folder / STATE_FILE, map_location="cpu", weights_only=True)
        state = TrainingState(**values)
    except Exception as error:  # noqa: BLE001 - any failure to unpickle means a damaged file
        # The first sentence only: torch's archive errors go on for a paragraph.
        reason = str(error).split(". ")[0].strip()
        raise InputError(f"{folder / STATE_FILE}: cannot be read ({type(error).__name__}: {reason}); the checkpoint is damaged") from None
    model.load_state_dict(checkpoint.tensors)
    return state
