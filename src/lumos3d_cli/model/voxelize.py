"""Differentiable voxel fusion of per-pixel Gaussians (AnySplat's confidence-weighted merge).

Every point falls into the voxel round(x / voxel_size); within a voxel the members' confidence
logits go through a softmax, and every attribute (position included) becomes the weighted mean.
The voxel assignment is discrete, the weights and means are differentiable, so gradients reach
every member's attributes and (in voxels with more than one member) its confidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lumos3d_cli.checks import require_finite

_KEY_LIMIT = 1 << 62  # voxel keys must stay below this to fit int64 with room for the arithmetic


@dataclass
class VoxelFusion:
    """Result of `voxelize` for N input points and M occupied voxels.

    points [M, 3]; features [M, C]; inverse [N] voxel of every input; counts [M] members per
    voxel; weights [N] each input's softmax weight within its voxel (they sum to 1 per voxel).
    """

    points: torch.Tensor
    features: torch.Tensor
    inverse: torch.Tensor
    counts: torch.Tensor
    weights: torch.Tensor

    def __len__(self) -> int:
        return self.points.shape[0]


def voxel_cells(points: torch.Tensor, voxel_size: float | torch.Tensor) -> torch.Tensor:
    """[N, 3] -> [N, 3] int64 cell indices round(x / voxel_size) (ties to even, as torch.round)."""
    return torch.round(points / voxel_size).long()


def _cell_keys(cells: torch.Tensor) -> torch.Tensor:
    """[N, 3] int64 cells -> [N] int64 keys, equal exactly when the cells are equal (and ordered
    lexicographically), so a 1-D `unique` replaces the much slower row-wise `unique(dim=0)`."""
    cells = cells - cells.min(dim=0).values
    extents = [int(e) + 1 for e in cells.max(dim=0).values]
    if extents[0] * extents[1] * extents[2] >= _KEY_LIMIT:
        # Coordinates spread too far to pack: replace each by its rank among the occupied values,
        # pairing two axes first so no product can exceed N^2 < 2^62.
        ranks = [torch.unique(cells[:, axis], return_inverse=True)[1] for axis in range(3)]
        pair = torch.unique(ranks[0] * (int(ranks[1].max()) + 1) + ranks[1], return_inverse=True)[1]
        return pair * (int(ranks[2].max()) + 1) + ranks[2]
    return (cells[:, 0] * extents[1] + cells[:, 1]) * extents[2] + cells[:, 2]


def voxelize(
    points: torch.Tensor, features: torch.Tensor, confidence: torch.Tensor, voxel_size: float | torch.Tensor
) -> VoxelFusion:
    """points [N, 3], features [N, C], confidence logits [N], voxel edge length (world units)."""
    require_finite("voxelize: points", points, "the predicted depth or cameras are degenerate")
    require_finite("voxelize: confidence", confidence)
    if points.shape[0] == 0:
        raise ValueError("voxelize needs at least one point")
    _, inverse, counts = torch.unique(_cell_keys(voxel_cells(points, voxel_size)), return_inverse=True, return_counts=True)
    voxels = counts.shape[0]
    # Softmax per voxel, shifted by the voxel's maximum for stability (the shift cancels, so it
    # is detached and carries no gradient).
    maximum = torch.zeros(voxels, dtype=confidence.dtype, device=confidence.device).scatter_reduce(
        0, inverse, confidence.detach(), reduce="amax", include_self=False
    )
    exponentials = torch.exp(confidence - maximum[inverse])
    totals = torch.zeros(voxels, dtype=confidence.dtype, device=confidence.device).index_add(0, inverse, exponentials)
    weights = exponentials / totals[inverse]  # the voxel's maximum contributes 1, so totals >= 1

    def weighted_mean(values: torch.Tensor) -> torch.Tensor:
        fused = torch.zeros((voxels, values.shape[1]), dtype=values.dtype, device=values.device)
        return fused.index_add(0, inverse, values * weights[:, None].to(values.dtype))

    return VoxelFusion(weighted_mean(points), weighted_mean(features), inverse, counts, weights)
