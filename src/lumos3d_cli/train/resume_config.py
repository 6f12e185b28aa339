"""What a resumed run may change of the run it continues.

A resume restores the optimizer's and scheduler's state, which carry the learning rates, betas,
weight decay and parameter groups of the run that saved them: a config that changed those (or the
model, the data, the losses) would be written into `config.yaml` while the run went on with the
old ones, or would fail inside torch. So a resume takes the config of the checkpoint it continues,
except for the keys below, which change how long the run goes and how it reports, not what it
learns.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from lumos3d_cli.errors import InputError, listed

# `optim.steps`: a resumed run may train longer (its schedule follows); where the data, the
# teacher or the bracket photos lie may move with the files; the rest is bookkeeping and speed.
MAY_CHANGE = frozenset({
    "output", "optim.steps", "data.root", "brackets.root", "teacher", "device", "gradient_checkpointing",
    "log_every", "checkpoint_every", "validate_every", "validate_at_start", "validation_views",
    "validation_samples", "brackets.validation_samples", "select", "max_nonfinite_steps", "tensorboard",
})


def _flat(values: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(values, dict):
        return {prefix: values}
    flat: dict[str, Any] = {}
    for key, value in values.items():
        flat.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def require_same_training(saved_config: Path, config_yaml: str) -> None:
    """InputError naming the keys in which `config_yaml` (the resolved config of this run, as
    checkpoints write it) differs from `saved_config` (the config.yaml of the checkpoint it
    resumes) other than MAY_CHANGE; nothing when the checkpoint has no config.yaml."""
    try:
        saved = _flat(yaml.safe_load(saved_config.read_text()) or {})
    except FileNotFoundError:
        return
    except (OSError, yaml.YAMLError) as error:
        raise InputError(f"{saved_config}: cannot be read ({error}); resume from another checkpoint") from None
    current = _flat(yaml.safe_load(config_yaml) or {})
    changed = [f"{key} {saved.get(key)!r} -> {current.get(key)!r}" for key in sorted(set(saved) | set(current))
               if key not in MAY_CHANGE and saved.get(key) != current.get(key)]
    if changed:
        raise InputError(f"{saved_config.parent}: this config differs from the run's in {listed(changed, 4)}; a resume "
                         "continues the run as it was (its optimizer keeps the old settings): resume with its "
                         "config.yaml, or start a new run with --new-run")
