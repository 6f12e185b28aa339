"""The models shipped in lumos3d_cli/weights/, and the one resolver from what a caller names (a
checkpoint path, a bundled model's mode, or nothing but a mode) to the weights file to load.

Errors name the library parameter the bad value came from (`checkpoint` or `mode`); a front end
puts its own option in its place (`InputError.with_option`).
"""

from __future__ import annotations

from pathlib import Path

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.architectures import ARCHITECTURES

BUNDLED_MODELS = {"low-light": "lumos3d-low-light", "over-exposure": "lumos3d-over-exposure"}
"""Restoration mode -> file stem of the model shipped for it in lumos3d_cli/weights/."""


def bundled_weights_path(name: str) -> Path:
    """Where the packaged weights `name` live: lumos3d_cli/weights/<name>.safetensors."""
    return Path(__file__).resolve().parents[1] / "weights" / f"{name}.safetensors"


def _bundled(mode: str, parameter: str) -> Path:
    path = bundled_weights_path(BUNDLED_MODELS[mode])
    if not path.is_file():
        raise InputError(f"{mode}: no bundled model ({path} is missing from this installation); "
                         "reinstall lumos3d or give a checkpoint", parameter=parameter)
    return path


def resolve_checkpoint(checkpoint: str | Path | None, mode: str | None = None) -> Path:
    """The weights file or folder to load.

    checkpoint: a checkpoint file or folder (ours, VGGT's, AnySplat's), the name of a bundled
    model ('low-light', 'over-exposure'), or None for the bundled model of `mode`. An existing
    path wins over a bundled name. An architecture's name ('tiny', ...) is refused: it names a
    network size, not trained weights.
    """
    bundled_names = ", ".join(f"'{name}'" for name in BUNDLED_MODELS)
    if checkpoint is None:
        if mode not in BUNDLED_MODELS:
            raise InputError(f"{mode!r}: no bundled model for it; use one of {bundled_names}", parameter="mode")
        return _bundled(mode, "mode")
    path = Path(checkpoint)
    if path.exists():
        return path
    name = str(checkpoint)
    if name in BUNDLED_MODELS:
        return _bundled(name, "checkpoint")
    if name in ARCHITECTURES:
        raise InputError(
            f"{name}: is a model architecture (a network size), not trained weights: give a checkpoint file "
            f"(ours, VGGT's model.pt/model.safetensors or AnySplat's model.safetensors) or a bundled model "
            f"({bundled_names}); build_model('{name}') gives random weights for experiments", parameter="checkpoint")
    raise InputError(f"{name}: no such file or folder, and not a bundled model ({bundled_names})", parameter="checkpoint")
