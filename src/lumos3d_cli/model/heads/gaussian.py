"""Gaussian head (AnySplat form): a DPT head that predicts raw Gaussian parameters per pixel."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from lumos3d_cli.model.architectures import Architecture
from lumos3d_cli.model.heads.dpt import DPTHead, decode_in_chunks
from lumos3d_cli.model.heads.uv_embedding import add_uv_embedding


class GaussianHead(DPTHead):
    """-> raw per-pixel parameters [B, S, K, H, W] (layout in `model.gaussian_adapter`).

    A 7x7 convolution of the RGB input in [0, 1] is added to the upsampled features, a shortcut
    that carries full-resolution colour detail past the 14-pixel patch grid.
    """

    def __init__(self, architecture: Architecture):
        super().__init__(architecture)
        half = architecture.dpt_features // 2
        self.input_merger = nn.Sequential(nn.Conv2d(3, half, kernel_size=7, padding=3), nn.ReLU())
        self.scratch.output_conv2 = nn.Sequential(
            nn.Conv2d(half, architecture.gaussian_head_hidden, kernel_size=3, padding=1),
            nn.ReLU(),
            nn.Conv2d(architecture.gaussian_head_hidden, architecture.gaussian_channels, kernel_size=1),
        )

    def decode(self, tokens: dict[int, torch.Tensor], images: torch.Tensor, frames: slice) -> torch.Tensor:
        """-> raw [B*s, K, H, W] for the frames in `frames`."""
        height, width = images.shape[-2:]
        out = self.fused_features(tokens, frames, (height, width))
        out = F.interpolate(out, size=(height, width), mode="bilinear", align_corners=True)
        out = out + self.input_merger(images[:, frames].reshape(-1, 3, height, width))
        return self.scratch.output_conv2(add_uv_embedding(out, height, width))

    def forward(self, tokens: dict[int, torch.Tensor], images: torch.Tensor) -> torch.Tensor:
        """tokens {layer: [B, S, P, 2C]}, images [B, S, 3, H, W] in [0, 1] -> [B, S, K, H, W]."""
        return decode_in_chunks(lambda frames: self.decode(tokens, images, frames), *images.shape[:2])
