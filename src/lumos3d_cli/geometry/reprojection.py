"""One view's surface seen from another camera: where world points land in a view, whether they
land inside it, and that view's map (depth, brightness) sampled where they land.

Pixel coordinates (u, v) have their origin at the top-left corner of the top-left pixel, so pixel
(i, j)'s centre is (j + 0.5, i + 0.5), as the cameras' intrinsics (in pixels of the map) place it.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from lumos3d_cli.io.cameras import Cameras


def land_in_view(world: torch.Tensor, cameras: Cameras, view: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """World points [N, 3] -> (u [N], v [N], z [N]) in `view`'s pixels and camera depth, computed
    in the points' dtype. A point on or behind the camera plane (z <= 0) gets finite but
    meaningless (u, v): test `inside_view` before using them."""
    extrinsics, intrinsics = cameras.extrinsics[view].to(world.dtype), cameras.intrinsics[view].to(world.dtype)
    camera = world @ extrinsics[:, :3].T + extrinsics[:, 3]
    z = camera[:, 2]
    safe = z.clamp_min(1e-12)
    u = intrinsics[0, 0] * camera[:, 0] / safe + intrinsics[0, 2]
    v = intrinsics[1, 1] * camera[:, 1] / safe + intrinsics[1, 2]
    return u, v, z


def inside_view(u: torch.Tensor, v: torch.Tensor, z: torch.Tensor | None, size: tuple[int, int]) -> torch.Tensor:
    """[N] bool: in front of the camera (z > 0; None: not tested) and on the h x w map `size`,
    its edges included."""
    height, width = size
    inside = (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    return inside if z is None else inside & (z > 0)


def sample_map(values: torch.Tensor, u: torch.Tensor, v: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """values [h, w] sampled at (u [N], v [N]) -> [N] in values' dtype ("bilinear" or "nearest";
    outside the map the border's value: mask with `inside_view`)."""
    height, width = values.shape
    grid = torch.stack([2 * u / width - 1, 2 * v / height - 1], dim=-1).to(values.dtype)
    return F.grid_sample(values[None, None], grid[None, None], mode=mode, align_corners=False,
                         padding_mode="border")[0, 0, 0]
