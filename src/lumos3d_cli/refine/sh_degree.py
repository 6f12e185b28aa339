"""The SH degree a scene needs: the lowest whose photometric loss over the views is within a
relative tolerance of the best degree's (0 when the view-dependent bands do not help)."""

from __future__ import annotations

import logging

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.photometric import photometric_loss
from lumos3d_cli.render.render import render

logger = logging.getLogger(__name__)

# The comparison renders at most this many views (spread evenly): the bands' effect is a
# property of the scene, and every view costs a render per degree (on buu's demo, 7 views at two
# degrees took 6 s, as long as 9 refinement steps).
MAX_COMPARED_VIEWS = 4


def degree_losses(gaussians: Gaussians, cameras: Cameras, targets: torch.Tensor, ssim_weight: float) -> list[float]:
    """The photometric loss at each SH degree 0..d of `gaussians`, over cameras [V] and targets
    [V, 3, H, W] of the cameras' size (up to MAX_COMPARED_VIEWS of them, spread evenly)."""
    views = torch.linspace(0, len(cameras) - 1, min(len(cameras), MAX_COMPARED_VIEWS)).round().long().unique()
    losses = []
    with torch.no_grad():
        for degree in range(gaussians.sh_degree + 1):
            renders = torch.cat([render(gaussians, cameras[[int(v)]], sh_degree=degree).images for v in views])
            losses.append(float(photometric_loss(renders, targets[views], ssim_weight)))
    return losses


def choose_sh_degree(gaussians: Gaussians, cameras: Cameras, targets: torch.Tensor, ssim_weight: float,
                     tolerance: float) -> int:
    """The lowest degree whose loss against `targets` [V, 3, H, W] (the `cameras`' views, sRGB in
    [0, 1]) is at most (1 + tolerance) x the lowest loss of any degree; 0 without rendering when
    the view-dependent coefficients are all zero."""
    if gaussians.sh_degree == 0 or not bool(gaussians.sh[:, 1:].any()):
        return 0
    losses = degree_losses(gaussians, cameras, targets, ssim_weight)
    best = min(losses)
    degree = next(d for d, loss in enumerate(losses) if loss <= best * (1 + tolerance))
    logger.info("SH degree %d chosen: photometric loss per degree %s", degree, ", ".join(f"{v:.5f}" for v in losses))
    return degree
