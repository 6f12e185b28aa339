"""The appearance loss of bracket samples (a photo restored by the predicted operator against
the bracket's well-exposed frame): (1 - w) * L1 + w * (1 - SSIM), w = 0.2 as in 3D Gaussian
Splatting's photometric loss.

L1 sets exposure and colour; the SSIM term rewards local contrast, which a curve fitted to mean
brightness alone can flatten.
"""

from __future__ import annotations

import torch

from lumos3d_cli.losses.ssim import ssim_map_mean

SSIM_WEIGHT = 0.2


def appearance_loss(restored: torch.Tensor, targets: torch.Tensor, ssim_weight: float = SSIM_WEIGHT) -> torch.Tensor:
    """restored, targets [..., 3, H, W] in [0, 1] -> scalar (1 - w) L1 + w (1 - mean SSIM)."""
    targets = targets.detach()
    l1 = torch.mean(torch.abs(restored.float() - targets.float()))
    if ssim_weight == 0:
        return l1
    return (1 - ssim_weight) * l1 + ssim_weight * (1 - ssim_map_mean(restored, targets).mean())
