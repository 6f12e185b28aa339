"""Content-level feature loss: L1 between VGG features of renders and normal-light images."""

from __future__ import annotations

import torch
from torch import nn

from lumos3d_cli.losses.feature_networks import FeatureTrunk, imagenet_normalise

CONTENT_LAYERS = ("relu4_1", "relu5_1")


class ContentLoss(nn.Module):
    """Mean over `layers` of the L1 distance between VGG features; the trunk is frozen."""

    def __init__(self, trunk: FeatureTrunk, layers: tuple[str, ...] = CONTENT_LAYERS):
        super().__init__()
        self.trunk = trunk.eval().requires_grad_(False)
        self.layers = list(layers)

    def forward(self, renders: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """renders, targets [..., 3, H, W] in [0, 1]."""
        flat_renders = imagenet_normalise(renders.reshape(-1, *renders.shape[-3:]))
        with torch.no_grad():
            target_features = self.trunk(imagenet_normalise(targets.reshape(-1, *targets.shape[-3:])), self.layers)
        render_features = self.trunk(flat_renders, self.layers)
        losses = [torch.mean(torch.abs(render_features[n] - target_features[n])) for n in self.layers]
        return torch.stack(losses).mean()
