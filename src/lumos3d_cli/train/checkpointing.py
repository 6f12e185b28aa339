"""Training checkpoints: one folder per save (model weights in our safetensors format, optimizer /
scheduler / generator state, the resolved config, the id of the run that saved it), written into
a staging folder and renamed, so a checkpoint is complete or absent. `latest` names the newest.
Retention and resuming see only the checkpoints of one run (train/run_folder.py)."""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import SafetensorError

from lumos3d_cli.errors import DiskError, InputError
from lumos3d_cli.io.atomic import current_umask, remove_leftovers, temporary_prefix, write_bytes_atomic
from lumos3d_cli.io.output_set import DISK_ERRORS
from lumos3d_cli.model.checkpoints import read_checkpoint, save_checkpoint
from lumos3d_cli.model.lumos3d import Lumos3D
from lumos3d_cli.train.run_folder import RUN_FILE

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
    final = checkpoint_folder(output, step)
    earlier = final.parent.is_dir() and bool(_step_folders(final.parent, run_id))
    then = ("continue with --resume" if earlier
            else "start again with --new-run (no checkpoint of this run was written whole)")
    with disk_errors_named(final.parent, f"the checkpoint of step {step}", then):
        _write_checkpoint(final, model, state, config_yaml, provenance, run_id)
    for old in _step_folders(final.parent, run_id)[keep:]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _write_checkpoint(final: Path, model: Lumos3D, state: TrainingState, config_yaml: str, provenance: dict,
                      run_id: str | None) -> None:
    """The checkpoint folder `final`, staged and renamed, and `latest` naming it."""
    parent = final.parent
    parent.mkdir(parents=True, exist_ok=True)
    remove_leftovers(parent)
    staging = Path(tempfile.mkdtemp(prefix=temporary_prefix(final.name), suffix=".tmp", dir=parent))
    try:
        save_checkpoint(model, staging / MODEL_FILE, provenance)
        # through a Python file: torch's own file writer reports a full disk without its errno
        with open(staging / STATE_FILE, "wb") as handle:
            torch.save(state.__dict__, handle)
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


def _disk_problem(error: BaseException) -> str | None:
    """What `DISK_ERRORS` calls the full or unwritable disk behind `error`, None for any other
    failure: an OSError; torch's RuntimeError, which keeps the OSError of the file it wrote as
    its context; or safetensors' error, which keeps only the system's words ("No space left on
    device (os error 28)")."""
    while error is not None:
        if isinstance(error, OSError) and error.errno in DISK_ERRORS:
            return DISK_ERRORS[error.errno]
        code = re.search(r"\(os error (\d+)\)", str(error)) if isinstance(error, SafetensorError) else None
        if code is not None and int(code.group(1)) in DISK_ERRORS:
            return DISK_ERRORS[int(code.group(1))]
        error = error.__cause__ or error.__context__
    return None


@contextlib.contextmanager
def disk_errors_named(folder: Path, writing: str, then: str = "continue with --resume") -> Iterator[None]:
    """A full or unwritable disk met while `writing` (e.g. "the checkpoint of step 8") into
    `folder` as an InputError naming both and saying what to do `then`: the user's to fix, not
    an internal error. The writers stage what they write, so nothing half-written is left to be
    taken for whole."""
    try:
        yield
    except (OSError, RuntimeError, SafetensorError) as error:
        problem = _disk_problem(error)
        if problem is None:
            raise
        raise DiskError(f"{folder}: {problem} while writing {writing}, which was not kept; make room or make the "
                        f"folder writable, then {then}") from error


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
        others = sorted({_run_of(p) for p in parent.glob("step_*") if p not in folders and (p / MODEL_FILE).is_file()}
                        - {None, run_id}) if parent.is_dir() else []
        if others:  # run.json gone or replaced: the checkpoints are there, of another run id
            recorded = f"run {run_id}" if run_id else f"no run (its {output / RUN_FILE} is missing)"
            raise InputError(f"{parent}: its checkpoints were saved by run {', '.join(others)}, but {output} records "
                             f"{recorded}; put back the run's run.json, or start from a checkpoint's weights with "
                             "model=.../model.safetensors --new-run")
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


def newest_checkpoint_before(output: Path, run_id: str | None, step: int) -> Path | None:
    """The run `run_id`'s newest checkpoint of fewer than `step` steps (None: none)."""
    parent = output / "checkpoints"
    folders = _step_folders(parent, run_id) if parent.is_dir() else []
    return next((folder for folder in folders if int(folder.name.removeprefix("step_")) < step), None)
