"""Non-overlapping patches -> tokens by one strided convolution."""

from __future__ import annotations

import torch
from torch import nn


class ConvPatchEmbed(nn.Module):
    def __init__(self, patch_size: int, embed_dim: int, in_channels: int = 3):
        super().__init__()
        self.patch_size = patch_size
        self.proj = nn.Conv2d(in_channels, embed_dim, kernel_size=patch_size, stride=patch_size)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """[N, 3, H, W] -> [N, (H/p)*(W/p), C], patches in row-major order."""
        return self.proj(images).flatten(2).transpose(1, 2)
