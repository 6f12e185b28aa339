"""DPT's multi-scale fusion: residual conv units and feature-fusion blocks."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class ResidualConvUnit(nn.Module):
    """relu(x) + conv2(relu(conv1(relu(x)))).

    The skip adds relu(x), not x: VGGT's unit applies an in-place ReLU to its input before the
    convolutions, so the stored skip is already rectified, and its weights were trained that way.
    """

    def __init__(self, features: int):
        super().__init__()
        self.conv1 = nn.Conv2d(features, features, kernel_size=3, padding=1)
        self.conv2 = nn.Conv2d(features, features, kernel_size=3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # [N, F, h, w]
        rectified = F.relu(x)
        return rectified + self.conv2(F.relu(self.conv1(rectified)))


class FeatureFusionBlock(nn.Module):
    """(x + unit1(skip)) -> unit2 -> bilinear resize (to `size`, else 2x) -> 1x1 conv."""

    def __init__(self, features: int, has_residual: bool = True):
        super().__init__()
        self.out_conv = nn.Conv2d(features, features, kernel_size=1)
        # The coarsest block has nothing to fuse and so no resConfUnit1 (no checkpoint keys either).
        self.resConfUnit1 = ResidualConvUnit(features) if has_residual else None
        self.resConfUnit2 = ResidualConvUnit(features)

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None = None, size: tuple[int, int] | None = None) -> torch.Tensor:
        """x [N, F, h, w] (+ skip of the same shape) -> [N, F, *size] (default [N, F, 2h, 2w])."""
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        size = size if size is not None else (2 * x.shape[-2], 2 * x.shape[-1])
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class FusionScratch(nn.Module):
    """Project the four pyramid levels to `features` channels and fuse them coarse to fine.

    Input: levels at 4x, 2x, 1x and 1/2x the patch grid; output [N, features/2, 8h, 8w].
    """

    def __init__(self, in_channels: tuple[int, int, int, int], features: int):
        super().__init__()
        self.layer1_rn = nn.Conv2d(in_channels[0], features, kernel_size=3, padding=1, bias=False)
        self.layer2_rn = nn.Conv2d(in_channels[1], features, kernel_size=3, padding=1, bias=False)
        self.layer3_rn = nn.Conv2d(in_channels[2], features, kernel_size=3, padding=1, bias=False)
        self.layer4_rn = nn.Conv2d(in_channels[3], features, kernel_size=3, padding=1, bias=False)
        self.refinenet1 = FeatureFusionBlock(features)
        self.refinenet2 = FeatureFusionBlock(features)
        self.refinenet3 = FeatureFusionBlock(features)
        self.refinenet4 = FeatureFusionBlock(features, has_residual=False)
        self.output_conv1 = nn.Conv2d(features, features // 2, kernel_size=3, padding=1)

    def forward(self, levels: list[torch.Tensor]) -> torch.Tensor:
        level1, level2, level3, level4 = (
            self.layer1_rn(levels[0]), self.layer2_rn(levels[1]), self.layer3_rn(levels[2]), self.layer4_rn(levels[3])
        )
        out = self.refinenet4(level4, size=level3.shape[-2:])
        out = self.refinenet3(out, level3, size=level2.shape[-2:])
        out = self.refinenet2(out, level2, size=level1.shape[-2:])
        out = self.refinenet1(out, level1)
        return self.output_conv1(out)
