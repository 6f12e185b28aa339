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

# A resumed run may train longer (its schedule follows) and report differently. (Not `data.exclude`:
# a scene left out changes which samples validation scores, and selection compares scores across it.)
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
    if key in ("model", "teacher"):  # a checkpoint that moved, not another architecture or bundled model
        return _is_path(saved) and _is_path(current)
    return key in MAY_MOVE and saved is not None and current is not None


def read_run_config(saved_config: Path, config_type: type) -> dict[str, Any] | None:
    """The config a checkpoint was saved with (its config.yaml), flattened to dotted keys and read
    as a config is: the defaults of keys added since it was written filled in (of a config this
    release no longer reads, the keys it holds). None when the checkpoint has none; InputError
    when it cannot be read (the checkpoint is damaged)."""
    try:
        values = yaml.safe_load(saved_config.read_text(encoding="utf-8")) or {}
    except FileNotFoundError:
        return None
    except UnicodeDecodeError:
        raise InputError(f"{saved_config}: cannot be read (not UTF-8 text)") from None
    except (OSError, yaml.YAMLError) as error:
        raise InputError(f"{saved_config}: cannot be read ({' '.join(str(error).split())})") from None
    if not isinstance(values, dict):
        raise InputError(f"{saved_config}: holds no config")
    try:
        return _flat(to_dict(from_dict(config_type, values)))
    except (InputError, ValueError, TypeError):  # keys since removed, rules since added: compare what it holds
        return _flat(values)


def require_same_training(saved_config: Path, saved: dict[str, Any], config: Any) -> None:
    """InputError naming the keys in which `config` differs from `saved` (`read_run_config` of the
    checkpoint's `saved_config`), beyond what may change (module docstring). Where and what files
    lie at a path that may move is not checked against their content."""
    current = _flat(to_dict(config))
    changed = [f"{key} {saved.get(key)!r} -> {current.get(key)!r}" for key in sorted(saved)
               if saved.get(key) != current.get(key) and not _may_differ(key, saved.get(key), current.get(key))]
    if changed:
        raise InputError(f"{saved_config.parent}: this config differs from the run's in {listed(changed, 4)}; a resume "
                         "continues the run as it was (its optimizer keeps the old settings): resume with its "
                         "config.yaml, or start a new run with --new-run")
