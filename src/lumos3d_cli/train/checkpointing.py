"""Training checkpoints: one folder per save (model weights in our safetensors format, optimizer /
scheduler / generator state, the resolved config, the id of the run that saved it), written into
a staging folder and renamed, so a checkpoint is complete or absent. `latest` names the newest.
Retention and resuming see only the checkpoints of one run (train/run_folder.py)."""

from __future__ import annotations

import logging
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import current_umask, remove_leftovers, temporary_prefix, write_bytes_atomic
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint
from lumos3d_cli.model.lumos3d import Lumos3D

MODEL_FILE = "model.safetensors"
STATE_FILE = "training_state.pt"
CONFIG_FILE = "config.yaml"
LATEST_FILE = "latest"
RUN_ID_FILE = "run_id"
STEP_FOLDER = re.compile(r"step_\d{8}")  # checkpoint_folder's names

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
    output: Path, step: int, model: Lumos3D, state: TrainingState, config_yaml: str, provenance: dict,
    run_id: str | None, keep: int = 3,
) -> Path:
    """Write checkpoints/step_<step>/ atomically (a folder of that step of the same run is replaced
    whole), point `latest` at it, keep the newest `keep` of the run `run_id`'s checkpoints."""
    parent = output / "checkpoints"
    final = checkpoint_folder(output, step)
    parent.mkdir(parents=True, exist_ok=True)
    remove_leftovers(parent)
    staging = Path(tempfile.mkdtemp(prefix=temporary_prefix(final.name), suffix=".tmp", dir=parent))
    try:
        save_checkpoint(model, staging / MODEL_FILE, provenance)
        torch.save(state.__dict__, staging / STATE_FILE)
        (staging / CONFIG_FILE).write_text(config_yaml)
        (staging / RUN_ID_FILE).write_text(f"{run_id or ''}\n")
        os.chmod(staging, 0o777 & ~current_umask())
        if final.exists():
            if _run_of(final) != run_id:
                raise InputError(f"{final}: belongs to another run; choose another output")
            replaced = Path(tempfile.mkdtemp(prefix=temporary_prefix(final.name), suffix=".tmp", dir=parent))
            os.replace(final, replaced / final.name)
            os.replace(staging, final)
            shutil.rmtree(replaced, ignore_errors=True)
        else:
            os.replace(staging, final)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    write_bytes_atomic(parent / LATEST_FILE, (final.name + "\n").encode())
    for old in _step_folders(parent, run_id)[keep:]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _run_of(folder: Path) -> str | None:
    """The id of the run that saved the checkpoint `folder` (None: saved by a lumos3d that wrote no ids)."""
    try:
        return (folder / RUN_ID_FILE).read_text().strip() or None
    except FileNotFoundError:
        return None


def _step_folders(parent: Path, run_id: str | None) -> list[Path]:
    """The checkpoint folders of the run `run_id` in `parent`, newest step first: named exactly
    as a save names them (a copy such as step_00000078_keep is the user's) and holding weights."""
    folders = (p for p in parent.glob("step_*") if STEP_FOLDER.fullmatch(p.name) and p.is_dir() and not p.is_symlink()
               and (p / MODEL_FILE).is_file() and _run_of(p) == run_id)
    return sorted(folders, key=lambda p: p.name, reverse=True)


def resume_candidates(output: Path, run_id: str | None) -> list[Path]:
    """The checkpoints of the run `run_id` to try when resuming, in order: the one
    `checkpoints/latest` names, then every other one, newest first (a damaged newest save falls
    back to an older one). InputError when there is nothing to try; a missing folder `latest`
    names is logged."""
    parent = output / "checkpoints"
    pointer = parent / LATEST_FILE
    folders = _step_folders(parent, run_id) if parent.is_dir() else []
    name = pointer.read_text().strip() if pointer.is_file() else ""
    named = parent / name if name else None
    if named is not None and named not in folders:
        logger.warning("%s names %s, which is missing or not of this run", pointer, named)
    if not folders:
        if named is not None:
            raise InputError(f"{pointer} names {named.name}, but the folder {named} is missing and no other "
                             "checkpoint of the run is there; start without --resume")
        raise InputError(f"{output}: no checkpoint to resume from ({parent} holds no step_* folders of the run); "
                         "start without --resume")
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
