"""Reconstruction loss: renders of the views against the normal-light images."""

from __future__ import annotations

import torch

from lumos3d_cli.losses.lpips import LPIPS


def mse_loss(renders: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """renders, targets [..., 3, H, W] -> mean squared error."""
    return torch.mean((renders - targets.detach()) ** 2)


def lpips_loss(lpips: LPIPS, renders: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
    """Mean LPIPS distance over all views; renders, targets [..., 3, H, W] in [0, 1]."""
    flat_renders = renders.reshape(-1, *renders.shape[-3:])
    flat_targets = targets.detach().reshape(-1, *targets.shape[-3:])
    return lpips(flat_renders, flat_targets).mean()
