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
from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.confirmed_depth import neighbours_by_distance
from lumos3d_cli.geometry.reprojection import inside_view, land_in_view, sample_map
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


def _agreement(depth: torch.Tensor, cameras: Cameras, view: int, other: int, tolerance: float) -> tuple[int, int]:
    """(agreeing, checked) pixel counts of `view`'s depth against `other`'s."""
    extrinsics, intrinsics = cameras.extrinsics.to(depth.dtype), cameras.intrinsics.to(depth.dtype)
    world = unproject_depth(depth[view], extrinsics[view], intrinsics[view]).reshape(-1, 3)
    u, v, z = land_in_view(world, cameras, other)
    inside = inside_view(u, v, z, depth.shape[-2:])
    sampled = sample_map(depth[other], u, v)
    agree = inside & ((z - sampled).abs() < tolerance * sampled.abs())
    return int(agree.sum()), int(inside.sum())


def depth_consistency(
    depth: torch.Tensor, cameras: Cameras, tolerance: float = DEFAULT_TOLERANCE, neighbours: torch.Tensor | None = None
) -> DepthConsistency:
    """depth [V, h, w] (positive) with cameras whose intrinsics are in pixels of the depth maps;
    neighbours [V] (default: each camera's nearest by centre distance). InputError for fewer than 2 views,
    mismatched shapes or non-finite / non-positive depth."""
    if depth.dim() != 3 or depth.shape[0] != len(cameras):
        raise InputError(f"depth must be [V, h, w] for {len(cameras)} cameras, got {tuple(depth.shape)}")
    if len(cameras) < 2:
        raise InputError(f"multi-view consistency needs at least 2 views, got {len(cameras)}")
    if not (torch.isfinite(depth).all() and (depth > 0).all()):
        raise InputError("multi-view consistency needs finite, positive depth everywhere")
    neighbours = neighbours_by_distance(cameras, 1)[:, 0] if neighbours is None else neighbours.long()
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
