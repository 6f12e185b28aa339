"""Bake the network's pixel grid into the scene's Gaussians (a Mip-Splatting-style 3D filter).

The network predicts one Gaussian per pixel of its own, smaller grid (224 px for `tiny`) and is
trained on renders at that grid, where the rasterizer's 2D dilation (EPS2D px² on every projected
covariance) gives even sub-pixel Gaussians a footprint of about a pixel. Rendered at the photos'
resolution (2-3x larger) or in any 3DGS viewer, the same Gaussians become sparse dots on a black
background. Adding to each Gaussian's 3D variance the world-space size of EPS2D px² of the finest
network view that sees it keeps the footprint the network meant, at every resolution.
"""

from __future__ import annotations

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.render.constants import EPS2D, NEAR_PLANE

_CHUNK = 262_144  # Gaussians per step: bounds the [V, chunk, 3] camera-space buffer


def sampling_rate(means: torch.Tensor, cameras: Cameras) -> torch.Tensor:
    """means [N, 3] -> [N] the highest pixels-per-world-unit over the cameras whose image holds
    the mean in front of the near plane (0 where none does)."""
    rotations = cameras.extrinsics[:, :, :3].to(means)
    translations = cameras.extrinsics[:, :, 3].to(means)
    intrinsics = cameras.intrinsics.to(means)
    focal = (intrinsics[:, 0, 0] * intrinsics[:, 1, 1]).sqrt()
    sizes = torch.tensor(cameras.sizes, dtype=means.dtype, device=means.device)
    rates = []
    for start in range(0, means.shape[0], _CHUNK):
        local = torch.einsum("vij,nj->vni", rotations, means[start:start + _CHUNK]) + translations[:, None]
        depth = local[..., 2]
        safe = depth.clamp_min(NEAR_PLANE)
        u = intrinsics[:, 0, 0, None] * local[..., 0] / safe + intrinsics[:, 0, 2, None]
        v = intrinsics[:, 1, 1, None] * local[..., 1] / safe + intrinsics[:, 1, 2, None]
        inside = (depth > NEAR_PLANE) & (u >= 0) & (u < sizes[:, 0, None]) & (v >= 0) & (v < sizes[:, 1, None])
        rate = torch.where(inside, focal[:, None] / safe, torch.zeros_like(safe))
        rates.append(rate.amax(dim=0))
    return torch.cat(rates) if rates else means.new_zeros(0)


def apply_sampling_filter(gaussians: Gaussians, network_cameras: Cameras, variance_px: float = EPS2D) -> Gaussians:
    """Scales s -> sqrt(s² + variance_px / rate²) with `rate` from `sampling_rate` at the
    network's cameras (their intrinsics at the network's resolution). Opacities are kept, as
    the training renders' dilation kept them. Gaussians no network view sees are unchanged."""
    rate = sampling_rate(gaussians.means, network_cameras)
    seen = rate > 0
    filter_variance = torch.where(seen, variance_px / rate.clamp_min(1e-30).square(), torch.zeros_like(rate))
    scales = (gaussians.scales.square() + filter_variance[:, None]).sqrt()
    return Gaussians(gaussians.means, gaussians.quats, scales, gaussians.opacities, gaussians.sh)
