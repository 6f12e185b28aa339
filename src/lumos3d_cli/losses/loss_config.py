"""The weights and settings of every training-loss term: the training config's `loss` section
(built from YAML by `typed_config.from_dict`), read by `losses.objective.TrainingObjective`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal


@dataclass
class LossConfig:
    """Weights of every term (0 turns a term off). Paper defaults."""

    reconstruction: float = 1.0  # MSE of renders vs normal-light images
    lpips: float = 0.0
    lpips_network: Literal["vgg", "alex"] = "vgg"
    lpips_weights: str | None = None  # torchvision-layout trunk weights
    distill: float = 1.0  # omega_distill
    distill_pose: float = 1.0
    distill_depth: float = 1.0
    lumos: float = 1.0  # omega_lumos
    content: float = 0.1
    image: float = 1.0
    voxel: float = 0.01
    vgg_weights: str | None = None  # torchvision vgg19 file for the content (and voxel) features
    voxel_scale_weights: tuple[float, float, float, float, float] = (1.0, 1.0, 1.0, 1.0, 1.0)
    voxel_size: float = 0.002  # relative to the scene scale, at full resolution
    supervised_pose: float = 5.0  # teacher stage; VGGT's camera-loss weight
    supervised_depth: float = 1.0  # teacher stage, sparse COLMAP depth
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        # a negative weight would reward its term's error (a negative total, the term "optimised" away)
        for name in ("reconstruction", "lpips", "distill", "distill_pose", "distill_depth", "lumos", "content", "image",
                     "voxel", "supervised_pose", "supervised_depth"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"loss.{name}: {value} must be a weight of at least 0 (0 turns the term off)")
        if not all(math.isfinite(weight) and weight >= 0 for weight in self.voxel_scale_weights):
            raise ValueError(f"loss.voxel_scale_weights: {list(self.voxel_scale_weights)} must be weights of at least 0")
        if not (math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise ValueError(f"loss.voxel_size: {self.voxel_size} must be positive")
