"""Which of the model's modules train: a stage may train some (e.g. only the illumination head
over the frozen tokens of a trained model) and keep the rest fixed."""

from __future__ import annotations

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.lumos3d import Lumos3D


def restrict_training(model: Lumos3D, trainable: list[str]) -> None:
    """Freeze (requires_grad False) every parameter outside the top-level modules named in
    `trainable` (e.g. ["illumination_head"]); an empty list trains everything. A frozen module
    gets no gradient, so autograd keeps no graph through it and the optimizer never moves it.
    InputError for a name that is not a module of `model` holding parameters."""
    if not trainable:
        return
    modules = {name for name, module in model.named_children() if any(True for _ in module.parameters())}
    unknown = sorted(set(trainable) - modules)
    if unknown:
        raise InputError(f"trainable: {', '.join(unknown)} is not a module of architecture "
                         f"'{model.architecture.name}' (modules: {', '.join(sorted(modules))})")
    for name, parameter in model.named_parameters():
        parameter.requires_grad_(name.partition(".")[0] in trainable)
