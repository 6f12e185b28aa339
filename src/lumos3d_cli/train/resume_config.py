"""What a resumed run may change of the run it continues.

A resume restores the optimizer's and scheduler's state, which carry the learning rates, betas,
weight decay and parameter groups of the run that saved them: a config that changed those (or the
model, the data, the losses) would be written into `config.yaml` while the run went on with the
old ones, or would fail inside torch. So a resume takes the config of the checkpoint it continues,
except for what changes how long the run goes, where its files lie and how it reports, not what it
learns or how its validations are scored.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from lumos3d_cli.errors import InputError, listed
from lumos3d_cli.typed_config import from_dict, to_dict

# A resumed run may train longer (its schedule follows) and report differently.
MAY_CHANGE = frozenset({
    "output", "optim.steps", "device", "gradient_checkpointing", "log_every", "checkpoint_every",
    "validate_every", "validate_at_start", "validation_views", "max_nonfinite_steps", "tensorboard",
})
# Files that may move with the data: another path is fine, but not a file where there was none (the
# bracket loss switched on mid-run) or none where there was one. `model` also names architectures
# ("tiny"), which may not change.
MAY_MOVE = frozenset({"model", "teacher", "data.root", "brackets.root", "loss.lpips_weights", "loss.vgg_weights"})


def _flat(values: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(values, dict):
        return {prefix: values}
    flat: dict[str, Any] = {}
    for key, value in values.items():
        flat.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return flat


def _is_path(value: Any) -> bool:
    return isinstance(value, str) and ("/" in value or bool(Path(value).suffix) or Path(value).exists())


def _may_differ(key: str, saved: Any, current: Any) -> bool:
    if key in MAY_CHANGE:
        return True
    return key in MAY_MOVE and _is_path(saved) and _is_path(current)


def require_same_training(saved_config: Path, config_type: type, config: Any) -> None:
    """InputError naming the keys in which `config` (of the dataclass `config_type`) differs from
    `saved_config` (the config.yaml of the checkpoint it resumes), beyond what may change (module
    docstring); nothing when the checkpoint has no config.yaml. The saved config is read as a
    config is (the defaults of keys added since it was written filled in)."""
    try:
        values = yaml.safe_load(saved_config.read_text()) or {}
        saved = _flat(to_dict(from_dict(config_type, values)))
    except FileNotFoundError:
        return
    except (OSError, yaml.YAMLError, InputError, ValueError, TypeError) as error:
        raise InputError(f"{saved_config}: cannot be read as the run's config ({error}); resume from another "
                         "checkpoint") from None
    current = _flat(to_dict(config))
    changed = [f"{key} {saved.get(key)!r} -> {current.get(key)!r}" for key in sorted(set(saved) | set(current))
               if saved.get(key) != current.get(key) and not _may_differ(key, saved.get(key), current.get(key))]
    if changed:
        raise InputError(f"{saved_config.parent}: this config differs from the run's in {listed(changed, 4)}; a resume "
                         "continues the run as it was (its optimizer keeps the old settings): resume with its "
                         "config.yaml, or start a new run with --new-run")
