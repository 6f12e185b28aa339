"""Depth maps + cameras -> world points, and the scene scale that makes lengths unit-free."""

from __future__ import annotations

import torch

# Lower bound of the scene scale, so that an all-zero depth map cannot divide by zero.
MIN_SCENE_SCALE = 1e-6


def pixel_centers(height: int, width: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """[H, W, 2] (u, v) of every pixel centre: pixel (row i, column j) is at (j + 0.5, i + 0.5)."""
    v = torch.arange(height, dtype=dtype, device=device) + 0.5
    u = torch.arange(width, dtype=dtype, device=device) + 0.5
    return torch.stack(torch.meshgrid(u, v, indexing="xy"), dim=-1)


def unproject_depth(depth: torch.Tensor, extrinsics: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """depth [..., H, W] (camera z), extrinsics [..., 3, 4] world->camera, intrinsics [..., 3, 3]
    (pinhole, no skew) -> world points [..., H, W, 3] of the pixel centres."""
    height, width = depth.shape[-2:]
    uv = pixel_centers(height, width, depth.dtype, depth.device)  # [H, W, 2]
    fx, fy = intrinsics[..., 0, 0, None, None], intrinsics[..., 1, 1, None, None]
    cx, cy = intrinsics[..., 0, 2, None, None], intrinsics[..., 1, 2, None, None]
    camera = torch.stack(((uv[..., 0] - cx) / fx * depth, (uv[..., 1] - cy) / fy * depth, depth), dim=-1)
    rotation, translation = extrinsics[..., :3, :3], extrinsics[..., :3, 3]
    # world = R^T (camera - t), written as a row-vector product over the pixel grid
    offset = camera - translation[..., None, None, :]
    return torch.einsum("...hwi,...ij->...hwj", offset, rotation)


def scene_scale(depth: torch.Tensor) -> torch.Tensor:
    """depth [B, V, H, W] -> [B]: the median depth over all pixels of all views of each scene.

    It is the unit in which voxel size and Gaussian sizes are given, so a scene and the same
    scene in other world units (or predicted at another overall scale) voxelize alike. Detached:
    it converts units and is not something the network should learn to move.
    """
    return depth.detach().flatten(1).median(dim=1).values.clamp_min(MIN_SCENE_SCALE)
