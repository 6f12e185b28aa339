"""A small real scene for refinement tests: buu's COLMAP cameras and sparse points (1090 of them,
coloured by COLMAP from the photos) as Gaussians, and three of its normal-light photos at 64x48
as targets."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch
import torch.nn.functional as F

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.colmap import read_colmap_model, read_colmap_points
from lumos3d_cli.io.gaussians import Gaussians, rgb_to_sh_dc
from lumos3d_cli.io.images import load_images

VIEWS = ("1.JPG", "7.JPG", "13.JPG")
SIZE = (64, 48)


@dataclass
class SparseScene:
    gaussians: Gaussians
    cameras: Cameras  # at the photos' size (500 x 375)
    targets: torch.Tensor  # [V, 3, 48, 64]


def points_as_gaussians(xyz: torch.Tensor, rgb: torch.Tensor) -> Gaussians:
    """3DGS's initialisation: isotropic Gaussians as wide as the mean distance to the 3 nearest
    points, opacity 0.5, the point's colour."""
    distances = torch.cdist(xyz, xyz)
    nearest = distances.topk(4, largest=False).values[:, 1:].mean(dim=1)
    count = xyz.shape[0]
    return Gaussians(
        xyz.float(), torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(count, 1), nearest[:, None].repeat(1, 3).float(),
        torch.full((count,), 0.5), rgb_to_sh_dc(rgb.float() / 255)[:, None, :],
    )


@pytest.fixture(scope="session")
def sparse_buu(buu) -> SparseScene:
    model = buu / "colmap_text"
    cameras = read_colmap_model(model)
    points = read_colmap_points(model / "points3D.txt")
    chosen = cameras[[cameras.names.index(name) for name in VIEWS]]
    photos = load_images([buu / "high" / name for name in VIEWS]).images
    targets = F.interpolate(photos, size=(SIZE[1], SIZE[0]), mode="area")
    return SparseScene(points_as_gaussians(torch.from_numpy(points.xyz), torch.from_numpy(points.rgb)), chosen, targets)
