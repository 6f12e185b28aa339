"""Which training run a folder holds, so that runs never clobber runs.

A run writes `run.json` into its output folder when it starts: a random id, the config file and
the start time. Every checkpoint it saves carries the id (`checkpoints/step_*/run_id`), so that
the retention of the newest checkpoints and `--resume` touch only that run's own. A fresh run
into a folder that holds another run is refused (or, asked to, starts in the next free numbered
folder beside it: `runs/x-2`); `--resume` continues the run the folder holds and says which.
"""

from __future__ import annotations

import datetime
import json
import uuid
from dataclasses import asdict, dataclass
from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.atomic import remove_path, write_bytes_atomic
from lumos3d_cli.io.manifest import MANIFEST_NAME, Manifest
from lumos3d_cli.io.output_paths import check_output_path
from lumos3d_cli.io.output_set import check_not_inputs

RUN_FILE = "run.json"
FINAL_FILE = "final.safetensors"
# Everything a run writes in its folder (train/trainer.py, checkpointing, run_logs, validation,
# selection): any of these in a folder means a run was there.
RUN_OUTPUTS = ("run.json", "config.yaml", "metrics.jsonl", "validation.jsonl", "checkpoints", "validation",
               "tensorboard", "final.safetensors", "selected.safetensors")


@dataclass(frozen=True)
class RunIdentity:
    """run_id: random hex; config: the config file it was started with; started: ISO time."""

    run_id: str
    config: str
    started: str

    def describe(self) -> str:
        return f"run {self.run_id[:8]} (started {self.started} from {self.config})"


def read_run(output: Path) -> RunIdentity | None:
    """The run `output` holds, from its run.json (None: no run.json — no run, or one of an older
    lumos3d that wrote none)."""
    try:
        return RunIdentity(**json.loads((Path(output) / RUN_FILE).read_text()))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, TypeError) as error:
        raise InputError(f"{Path(output) / RUN_FILE}: cannot be read ({error}); choose another output") from None


def earlier_run(output: Path) -> str | None:
    """What of an earlier run `output` holds, in words (None: nothing)."""
    found = [name for name in RUN_OUTPUTS if (Path(output) / name).exists()]
    if not found:
        return None
    run = read_run(output)
    steps = sorted((Path(output) / "checkpoints").glob("step_*"))
    what = run.describe() if run is not None else "an earlier training run"
    return what + (f", checkpoints up to {steps[-1].name}" if steps else f" ({', '.join(found)})")


def other_outputs(output: Path) -> str | None:
    """The output sets of other lumos3d commands `output` holds (a restore's scene.ply, views,
    summary.json ...), in words (None: none): a training run needs a folder of its own."""
    manifest = Manifest.read(Path(output))
    sets = sorted({entry.output_set for name, entry in manifest.files.items()
                   if entry.command != "train" and (Path(output) / name).exists()})
    return ", ".join(f"the outputs of `{entry}`" for entry in sets) or None


def numbered_folder(output: Path) -> Path:
    """The first of `output`-2, `output`-3 ... that holds no run and no other command's outputs."""
    if output.name in ("", ".", ".."):  # "." or "..": the folder's own name
        output = output.resolve()
    if not output.name:
        raise InputError(f"{output}: a new run needs a named output folder beside which to number it; give one")
    number = 2
    while (earlier_run(output.with_name(f"{output.name}-{number}")) is not None
           or other_outputs(output.with_name(f"{output.name}-{number}")) is not None):
        number += 1
    return output.with_name(f"{output.name}-{number}")


def check_run_folder(output: Path, inputs: list[Path | None], resume: bool) -> None:
    """Before the run: InputError when `output` cannot be a run folder (a file, unwritable, an
    input or holding one), when a fresh run would write into another run's folder, or when
    `resume` finds no run there."""
    output = Path(output)
    check_output_path(output, None, folder=True)
    for given in inputs:
        if given is not None and Path(given).resolve().is_relative_to(output.resolve()):
            raise InputError(f"{given}: lies inside the run folder {output}, which the run writes; use a copy from outside "
                             "it, or choose another output")
    check_not_inputs([], [output], [Path(path) for path in inputs if path is not None])
    earlier = earlier_run(output)
    if resume and earlier is None:
        raise InputError(f"output {output}: holds no training run to resume; start without --resume")
    # a run that stopped before its first checkpoint (its logs kept) has nothing to resume from; a
    # checkpoints folder of any state is the resume's to judge (checkpointing.resume_candidates)
    checkpointed = (output / "checkpoints").exists()
    if resume and not checkpointed:
        raise InputError(f"output {output}: holds {earlier}, which saved no checkpoint, so there is nothing to resume; "
                         "start a new numbered run folder beside it with --new-run, or choose another output")
    others = None if resume else other_outputs(output)
    if others is not None:
        raise InputError(f"output {output}: holds {others}; a training run needs a folder of its own: choose another "
                         "output")
    if not resume and earlier is not None:
        continuing = "continue it with --resume, " if checkpointed else "it saved no checkpoint to resume from; "
        raise InputError(f"output {output}: holds {earlier}; {continuing}start a new numbered run folder beside it with "
                         "--new-run, or choose another output")


def start_run(output: Path, config_file: Path | str | None) -> RunIdentity:
    """Write run.json for a fresh run into `output` (created if needed) and return its identity."""
    run = RunIdentity(uuid.uuid4().hex, str(config_file) if config_file is not None else "(in memory)",
                      datetime.datetime.now().isoformat(timespec="seconds"))
    write_bytes_atomic(Path(output) / RUN_FILE, (json.dumps(asdict(run), indent=2) + "\n").encode())
    return run


def remove_unfinished_run(output: Path, created: bool) -> None:
    """Remove what a fresh run that stopped before any of its work counted (no step, no
    validation) wrote into `output` (RUN_OUTPUTS; the folder checks refused a fresh run into a
    folder holding any, so they are its own), and the folder itself when the run created it and
    nothing else is left there."""
    output = Path(output)
    for name in RUN_OUTPUTS:
        remove_path(output / name)
    manifest = Manifest.read(output)
    if all(name.split("/")[0] in RUN_OUTPUTS for name in manifest.files):  # it listed only the run's files
        remove_path(output / MANIFEST_NAME)
    if created and output.is_dir() and not any(output.iterdir()):
        output.rmdir()
