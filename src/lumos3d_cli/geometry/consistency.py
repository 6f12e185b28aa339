"""Multi-view consistency of depth maps: do two views agree on where the surface is?

Every pixel of a view is unprojected with its depth, projected into a neighbouring view (the one
with the nearest camera centre), and compared with that view's depth there (bilinear). It agrees
when the two depths differ by less than `tolerance` (relative to the neighbour's depth). Pixels
that fall outside the neighbour or behind it are not counted; pixels the neighbour cannot see
(occlusion) count as disagreeing, so even exact depth of an occluded scene scores below 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from lumos3d_cli.errors import InputError
from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import unproject_depth

DEFAULT_TOLERANCE = 0.02


@dataclass
class DepthConsistency:
    """share: agreeing pixels / checked pixels over all views; per_view [V] the same per view
    (nan where nothing was checked); neighbour [V] int64 the view each was compared with;
    checked [V] share of each view's pixels that landed in front of and inside its neighbour."""

    share: float
    per_view: torch.Tensor
    neighbour: torch.Tensor
    checked: torch.Tensor


def nearest_neighbours(cameras: Cameras) -> torch.Tensor:
    """[V] int64: for each camera the other camera with the nearest centre."""
    centres = cameras.centers().double()
    distances = torch.cdist(centres, centres)
    distances.fill_diagonal_(float("inf"))
    return distances.argmin(dim=1)


def _agreement(depth: torch.Tensor, cameras: Cameras, view: int, other: int, tolerance: float) -> tuple[int, int]:
    """(agreeing, checked) pixel counts of `view`'s depth against `other`'s."""
    height, width = depth.shape[-2:]
    extrinsics, intrinsics = cameras.extrinsics.to(depth.dtype), cameras.intrinsics.to(depth.dtype)
    world = unproject_depth(depth[view], extrinsics[view], intrinsics[view]).reshape(-1, 3)
    camera = world @ extrinsics[other, :, :3].T + extrinsics[other, :, 3]
    in_front = camera[:, 2] > 0
    z = camera[:, 2].clamp_min(1e-12)
    u = intrinsics[other, 0, 0] * camera[:, 0] / z + intrinsics[other, 0, 2]
    v = intrinsics[other, 1, 1] * camera[:, 1] / z + intrinsics[other, 1, 2]
    inside = in_front & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    grid = torch.stack([2 * u / width - 1, 2 * v / height - 1], dim=-1)
    sampled = F.grid_sample(depth[other][None, None], grid[None, None], mode="bilinear", align_corners=False,
                            padding_mode="border")[0, 0, 0]
    agree = inside & ((z - sampled).abs() < tolerance * sampled.abs())
    return int(agree.sum()), int(inside.sum())


def depth_consistency(
    depth: torch.Tensor, cameras: Cameras, tolerance: float = DEFAULT_TOLERANCE, neighbours: torch.Tensor | None = None
) -> DepthConsistency:
    """depth [V, h, w] (positive) with cameras whose intrinsics are in pixels of the depth maps;
    neighbours [V] (default: `nearest_neighbours`). InputError for fewer than 2 views,
    mismatched shapes or non-finite / non-positive depth."""
    if depth.dim() != 3 or depth.shape[0] != len(cameras):
        raise InputError(f"depth must be [V, h, w] for {len(cameras)} cameras, got {tuple(depth.shape)}")
    if len(cameras) < 2:
        raise InputError(f"multi-view consistency needs at least 2 views, got {len(cameras)}")
    if not (torch.isfinite(depth).all() and (depth > 0).all()):
        raise InputError("multi-view consistency needs finite, positive depth everywhere")
    neighbours = nearest_neighbours(cameras) if neighbours is None else neighbours.long()
    per_view = torch.full((len(cameras),), float("nan"), dtype=torch.float64)
    checked = torch.zeros(len(cameras), dtype=torch.float64)
    total_agree = total_checked = 0
    for view in range(len(cameras)):
        agree, count = _agreement(depth, cameras, view, int(neighbours[view]), tolerance)
        total_agree, total_checked = total_agree + agree, total_checked + count
        checked[view] = count / depth[view].numel()
        if count:
            per_view[view] = agree / count
    share = total_agree / total_checked if total_checked else float("nan")
    return DepthConsistency(share, per_view, neighbours, checked)
