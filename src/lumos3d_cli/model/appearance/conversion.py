"""Switching a trained network's appearance: a colour-regression checkpoint initialises an
operator network of the same size (every tensor but the new illumination head is shared)."""

from __future__ import annotations

import dataclasses
import logging

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.architectures import APPEARANCES
from lumos3d_cli.model.lumos3d import Lumos3D

logger = logging.getLogger(__name__)


def with_appearance(model: Lumos3D, appearance: str, local_correction_channels: int | None = None) -> Lumos3D:
    """`model` itself if it already has `appearance` (and the requested local correction);
    otherwise a new network whose architecture differs only in `appearance` (named
    '<name>-operator' or '<name>-regression') and, when given, `local_correction_channels` (0: no
    per-view local gain grid), holding all of `model`'s tensors; the head only one of them has
    starts fresh (the illumination head starts as the identity operator). Provenance records the
    conversion."""
    if appearance not in APPEARANCES:
        raise InputError(f"unknown appearance '{appearance}'; choose one of: {', '.join(APPEARANCES)}")
    channels = model.architecture.local_correction_channels if local_correction_channels is None else local_correction_channels
    if model.architecture.appearance == appearance and model.architecture.local_correction_channels == channels:
        return model
    if model.architecture.appearance == appearance:
        raise InputError(f"architecture '{model.architecture.name}' already has its illumination head; "
                         "change the local correction when switching from regression")
    base = model.architecture.name.removesuffix("-operator").removesuffix("-regression")
    suffix = "" if channels == model.architecture.local_correction_channels else f"-local{channels}"
    try:
        architecture = dataclasses.replace(model.architecture, appearance=appearance, name=f"{base}-{appearance}{suffix}",
                                           local_correction_channels=channels)
    except ValueError as error:
        raise InputError(f"local_correction_channels={channels}: {error}") from error
    converted = Lumos3D(architecture).to(next(model.parameters()).device)
    state = {k: v for k, v in model.state_dict().items() if not k.startswith("illumination_head.")}
    missing, unexpected = converted.load_state_dict(state, strict=False)
    if unexpected or any(not key.startswith("illumination_head.") for key in missing):
        raise ValueError(f"appearance switch lost tensors: missing {missing}, unexpected {unexpected}")
    converted.provenance = {**model.provenance, "appearance_from": model.architecture.appearance}
    logger.info("architecture '%s' -> '%s': appearance %s, fresh illumination head", model.architecture.name,
                architecture.name, appearance)
    return converted.train(model.training)
