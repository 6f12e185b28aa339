"""A synthetic scene with exact depth: a tilted plane seen by cameras in a row, all looking at it."""

from __future__ import annotations

import math

import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.io.sparse_points import SparsePoints
from lumos3d_cli.model.geometry import pixel_centers
from lumos3d_cli.rotations import quaternion_to_matrix

# The plane n . x = d in world coordinates (tilted, so depth varies across each view).
PLANE_NORMAL = torch.tensor([0.15, -0.1, 1.0], dtype=torch.float64) / math.sqrt(0.15**2 + 0.1**2 + 1)
PLANE_OFFSET = 6.0


def plane_cameras(views: int, width: int = 48, height: int = 32, seed: int = 0) -> Cameras:
    """Cameras spread along x with small random rotations, all facing +z towards the plane."""
    generator = torch.Generator().manual_seed(seed)
    axis_angles = 0.08 * torch.randn(views, 3, generator=generator, dtype=torch.float64)
    half = axis_angles.norm(dim=1, keepdim=True) / 2
    quats = torch.cat([half.cos(), axis_angles / (2 * half).clamp_min(1e-12) * half.sin()], dim=1)
    rotation = quaternion_to_matrix(quats)
    centres = torch.stack([torch.linspace(-1.5, 1.5, views, dtype=torch.float64),
                           0.2 * torch.randn(views, generator=generator, dtype=torch.float64),
                           0.3 * torch.randn(views, generator=generator, dtype=torch.float64)], dim=1)
    translation = -(rotation @ centres[:, :, None])[..., 0]
    focal = 0.9 * width
    intrinsics = make_intrinsics([focal] * views, [focal] * views, [width / 2] * views, [height / 2] * views)
    return Cameras(torch.cat([rotation, translation[:, :, None]], dim=2), intrinsics, [(width, height)] * views,
                   [f"{i:03d}.png" for i in range(views)])


def plane_depth(cameras: Cameras) -> torch.Tensor:
    """[V, h, w] exact camera-z depth of the plane at every pixel centre."""
    width, height = cameras.sizes[0]
    uv = pixel_centers(height, width, torch.float64)
    depths = []
    for view in range(len(cameras)):
        k = cameras.intrinsics[view]
        rays = torch.stack([(uv[..., 0] - k[0, 2]) / k[0, 0], (uv[..., 1] - k[1, 2]) / k[1, 1],
                            torch.ones_like(uv[..., 0])], dim=-1)  # camera rays with z = 1
        rotation, translation = cameras.extrinsics[view, :, :3], cameras.extrinsics[view, :, 3]
        centre = -rotation.T @ translation
        world_rays = rays @ rotation  # R^T ray, row-wise
        depths.append((PLANE_OFFSET - PLANE_NORMAL @ centre) / (world_rays @ PLANE_NORMAL))
    return torch.stack(depths)


def plane_texture(world: torch.Tensor, seed: int = 0) -> torch.Tensor:
    """[..., 3] world points -> [..., 3] colours in [0, 1]: a sum of sinusoids on the plane's x, y
    (about 3-10 pixels a period at these cameras), the same wherever a camera sees the point."""
    generator = torch.Generator().manual_seed(seed)
    frequencies = 6 + 14 * torch.rand(12, 2, generator=generator, dtype=torch.float64)
    phases = 2 * math.pi * torch.rand(12, generator=generator, dtype=torch.float64)
    weights = torch.rand(12, 3, generator=generator, dtype=torch.float64)
    waves = torch.sin(world[..., :2] @ frequencies.T + phases)  # [..., 12]
    return (0.5 + 0.4 * (waves @ weights) / weights.sum(0)).clamp(0, 1)


def plane_points(cameras: Cameras, count: int, seed: int = 0) -> SparsePoints:
    """`count` points on the plane, observed by every camera whose image they fall into."""
    generator = torch.Generator().manual_seed(seed)
    xy = (torch.rand(count, 2, generator=generator, dtype=torch.float64) - 0.5) * torch.tensor([4.0, 2.5], dtype=torch.float64)
    z = (PLANE_OFFSET - xy @ PLANE_NORMAL[:2]) / PLANE_NORMAL[2]
    xyz = torch.cat([xy, z[:, None]], dim=1)
    pixels, depth = cameras.project(xyz)
    width, height = cameras.sizes[0]
    seen = (depth > 0) & (pixels[..., 0] > 0) & (pixels[..., 0] < width) & (pixels[..., 1] > 0) & (pixels[..., 1] < height)
    view, point = torch.nonzero(seen, as_tuple=True)
    return SparsePoints(xyz, torch.full((count, 3), 128, dtype=torch.uint8), torch.zeros(count, dtype=torch.float64),
                        view, point, pixels[view, point])
