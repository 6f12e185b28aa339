"""Differentiable voxel fusion of per-pixel Gaussians (AnySplat's confidence-weighted merge).

Every point falls into the voxel round(x / voxel_size); within a voxel the members' confidence
logits go through a softmax, and every attribute (position included) becomes the weighted mean.
The voxel assignment is discrete, the weights and means are differentiable, so gradients reach
every member's attributes and (in voxels with more than one member) its confidence.

The voxel size is one number (one grid) or one per point: then each distinct size is a grid of
its own and two points share a voxel only when they have the same size and the same cell
(`model.pixel_footprint` gives sizes from a few powers of two, so a handful of nested grids).
Voxels larger than the pixel spacing merge neighbouring pixels of one view; the mean of their
shapes would then be one pixel's size and leave holes, so `covering_shapes` gives such voxels the
shape that spans their members instead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.model.symmetric_eigen import symmetric_eigen_3x3
from lumos3d_cli.rotations import matrix_to_quaternion, quaternion_to_matrix

_KEY_LIMIT = 1 << 62  # voxel keys must stay below this to fit int64 with room for the arithmetic
_CELL_LIMIT = 2.0**61  # |cell index| below this: differences of two cells (`_cell_keys`) stay below 2^62


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


class PointsBeyondVoxelGrid(ValueError):
    """Points so far out for their voxel size that no int64 cell index holds them: a scene of
    extreme extent, or the geometry of a diverged model (training skips such a step)."""


def voxel_cells(points: torch.Tensor, voxel_size: float | torch.Tensor) -> torch.Tensor:
    """[N, 3] -> [N, 3] int64 cell indices round(x / voxel_size) (ties to even, as torch.round);
    voxel_size a number or [N] per point."""
    sizes = torch.as_tensor(voxel_size, dtype=torch.float64)
    if not bool(torch.isfinite(sizes).all()) or not bool((sizes > 0).all()):
        bad = sizes[~(torch.isfinite(sizes) & (sizes > 0))].view(-1)[0]
        raise ValueError(f"voxel size {float(bad):g}: must be positive and finite")
    if isinstance(voxel_size, torch.Tensor) and voxel_size.dim() == 1:
        voxel_size = voxel_size[:, None]
    cells = torch.round(points.detach() / voxel_size)
    if cells.numel() and float(cells.abs().max()) >= _CELL_LIMIT:  # .long() would wrap and merge far points
        raise PointsBeyondVoxelGrid(f"points {float(points.detach().abs().max()):g} from the origin lie beyond 2^61 "
                                    "voxels of the voxel size: the size is too small for the scene's extent")
    return cells.long()


def _cell_keys(cells: torch.Tensor) -> torch.Tensor:
    """[N, D] int64 cells -> [N] int64 keys, equal exactly when the rows are equal (and ordered
    lexicographically), so a 1-D `unique` replaces the much slower row-wise `unique(dim=0)`."""
    cells = cells - cells.min(dim=0).values
    extents = [int(e) + 1 for e in cells.max(dim=0).values]
    if math.prod(extents) >= _KEY_LIMIT:
        # Coordinates spread too far to pack: replace each by its rank among the occupied values
        # and pack one column at a time, re-ranking in between, so no product can exceed N^2 < 2^62.
        ranks = [torch.unique(cells[:, axis], return_inverse=True)[1] for axis in range(cells.shape[1])]
        keys = ranks[0]
        for axis, rank in enumerate(ranks[1:], start=1):
            if axis > 1:
                keys = torch.unique(keys, return_inverse=True)[1]
            keys = keys * (int(rank.max()) + 1) + rank
        return keys
    keys = cells[:, 0]
    for axis in range(1, cells.shape[1]):
        keys = keys * extents[axis] + cells[:, axis]
    return keys


def _voxel_keys(points: torch.Tensor, voxel_size: float | torch.Tensor) -> torch.Tensor:
    """[N] int64 keys of the voxels of points [N, 3]: the cell, and with per-point sizes [N]
    also the size (its rank among the distinct sizes, as the first column)."""
    cells = voxel_cells(points, voxel_size)
    if isinstance(voxel_size, torch.Tensor) and voxel_size.dim() == 1:
        grid = torch.unique(voxel_size, return_inverse=True)[1]
        cells = torch.cat([grid[:, None], cells], dim=1)
    return _cell_keys(cells)


def voxelize(
    points: torch.Tensor, features: torch.Tensor, confidence: torch.Tensor, voxel_size: float | torch.Tensor
) -> VoxelFusion:
    """points [N, 3], features [N, C], confidence logits [N], voxel edge length (world units):
    one number, or [N] one per point (each distinct size a grid of its own)."""
    require_finite("voxelize: points", points, "the predicted depth or cameras are degenerate")
    require_finite("voxelize: confidence", confidence)
    if points.shape[0] == 0:
        raise ValueError("voxelize needs at least one point")
    if isinstance(voxel_size, torch.Tensor) and voxel_size.dim() == 1:
        if voxel_size.shape[0] != points.shape[0]:
            raise ValueError(f"{voxel_size.shape[0]} voxel sizes for {points.shape[0]} points")
        require_finite("voxelize: voxel sizes", voxel_size)
    _, inverse, counts = torch.unique(_voxel_keys(points, voxel_size), return_inverse=True, return_counts=True)
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


def covering_shapes(voxels: Gaussians, members: Gaussians, fusion: VoxelFusion, min_scale: float | torch.Tensor) -> Gaussians:
    """Fused Gaussians `voxels` [M] with the shape of each multi-member voxel replaced by the
    moment-matched one of its members [N] (the input rows of `fusion`): the covariance
    sum_i w_i (R_i S_i^2 R_i^T + d_i d_i^T), d_i a member's offset from the fused position, as
    scales (standard deviations, at least `min_scale`) along its eigenvectors. Single-member
    voxels keep their shape. Computed in float64 and not differentiated (an eigendecomposition
    has no stable gradient for the near-isotropic shapes common here): for inference."""
    with torch.no_grad():
        shared = fusion.counts > 1
        in_shared = shared[fusion.inverse]
        index = fusion.inverse[in_shared]
        axes = quaternion_to_matrix(members.quats[in_shared].double()) * members.scales[in_shared].double()[:, None, :]
        offsets = (members.means[in_shared] - fusion.points[index]).double()
        spread = axes @ axes.transpose(1, 2) + offsets[:, :, None] * offsets[:, None, :]
        covariance = torch.zeros(len(fusion), 3, 3, dtype=torch.float64, device=spread.device).index_add(
            0, index, spread * fusion.weights[in_shared].double()[:, None, None]
        )[shared]
        # Not torch.linalg.eigh: cuSOLVER fails on CUDA batches this large (see symmetric_eigen);
        # the eigenvectors come back as rotations (det +1), ready for a quaternion.
        variances, vectors = symmetric_eigen_3x3(covariance)
        quats, scales = voxels.quats.detach().clone(), voxels.scales.detach().clone()
        quats[shared] = matrix_to_quaternion(vectors).to(quats.dtype)
        scales[shared] = variances.clamp_min(0).sqrt().clamp_min(min_scale).to(scales.dtype)
    return Gaussians(voxels.means, quats, scales, voxels.opacities, voxels.sh)
