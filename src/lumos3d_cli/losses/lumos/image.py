"""Image-level restoration loss: L1 between renders and the normal-light images."""

from __future__ import annotations

import torch


def image_l1(renders: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """renders, targets [..., 3, H, W] -> mean absolute difference."""
    return torch.mean(torch.abs(renders - targets.detach()))
