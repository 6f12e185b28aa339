"""The photometric loss of refinement (3DGS's: L1 and SSIM) and the images it is measured on."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.losses.ssim import RADIUS, ssim_map_mean


def photometric_loss(renders: torch.Tensor, targets: torch.Tensor, ssim_weight: float) -> torch.Tensor:
    """renders, targets [V, 3, H, W] -> scalar (1 - w) mean|r - t| + w (1 - SSIM(r, t)), the
    project's SSIM (the one `eval` reports), averaged over the views."""
    l1 = (renders - targets).abs().mean()
    return (1 - ssim_weight) * l1 + ssim_weight * (1 - ssim_map_mean(renders, targets).mean())


def working_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """(width, height) with the longer side at most `max_side` (the aspect ratio kept, never
    enlarged), except that the shorter side keeps room for SSIM's window (2 * RADIUS + 1 pixels:
    a panorama of 4000x50 works at 880x11, not 256x3); ValueError when the targets themselves
    have no such room."""
    window = 2 * RADIUS + 1
    factor = min(1.0, max(max_side / max(width, height), window / min(width, height)))
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    if min(size) <= 2 * RADIUS:
        raise ValueError(f"targets of {width}x{height} work at {size[0]}x{size[1]}: SSIM needs at least "
                         f"{2 * RADIUS + 1} pixels a side (raise max_side or give larger targets)")
    return size


def working_views(targets: torch.Tensor, cameras: Cameras, max_side: int) -> tuple[torch.Tensor, Cameras]:
    """targets [V, 3, H, W] and their cameras -> the targets area-downsampled to `working_size`
    [V, 3, h, w] (float32) and the cameras rescaled to it."""
    height, width = targets.shape[-2:]
    size = working_size(width, height, max_side)
    images = targets.float()
    if size != (width, height):
        images = F.interpolate(images, size=(size[1], size[0]), mode="area")
    return images, cameras.rescaled(*size)
