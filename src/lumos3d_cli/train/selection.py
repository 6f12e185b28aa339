"""Model selection: the weights of the validation with the best held-out score so far, kept as
output/selected.safetensors beside the run's final.safetensors, so a run that overfits late
ships its best step rather than its last. The score is one key of validation.jsonl, higher is
better; the selected file's provenance names the key, the score and the step."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

from lumos3d_cli.model.checkpoints import read_provenance

logger = logging.getLogger(__name__)

SELECTED_FILE = "selected.safetensors"
# validation.jsonl keys a run can be selected on (all higher-is-better); bracket_* need brackets.root
SELECTION_SCORES = ("psnr", "bracket_psnr", "bracket_ssim", "bracket_well_exposed_psnr", "bracket_well_exposed_ssim")


def best_earlier_score(validation_log: Path, key: str, before_step: int) -> float | None:
    """The highest `key` among validation.jsonl's lines of steps before `before_step` (None: none)."""
    if not validation_log.is_file():
        return None
    scores = [line[key] for line in map(json.loads, filter(None, validation_log.read_text().splitlines()))
              if line["step"] < before_step and key in line]
    return max(scores) if scores else None


def is_improvement(score: float, best_so_far: float | None) -> bool:
    """Whether `score` (finite) beats every earlier one; a non-finite score never does."""
    return math.isfinite(score) and (best_so_far is None or score > best_so_far)


def drop_stale_selection(output: Path, start: int) -> bool:
    """Remove output/selected.safetensors when it is not the selection of the steps kept: a fresh
    run (start 0) inherits none, and a resumed run drops one chosen after `start` (its
    validation lines were dropped with the work about to be redone, which validates again).
    Returns whether it was removed."""
    path = output / SELECTED_FILE
    if not path.is_file():
        return False
    if start == 0 or int(read_provenance(path).get("steps", start + 1)) > start:
        logger.info("removing %s: chosen by a run or steps this one does not continue", path)
        path.unlink()
        return True
    return False
