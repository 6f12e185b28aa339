import math

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.model.geometry import pixel_centers, scene_scale, unproject_depth

from factories import random_cameras


def test_pixel_centres_are_at_half_integers():
    grid = pixel_centers(2, 3)
    assert grid.shape == (2, 3, 2)
    torch.testing.assert_close(grid[1, 2], torch.tensor([2.5, 1.5]))
    torch.testing.assert_close(grid[0, 0], torch.tensor([0.5, 0.5]))


def test_unproject_matches_a_hand_computation():
    # camera rotated 90 degrees about z, translated by t; pixel (row 1, column 2) of a 3x4 image
    rotation = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64)
    translation = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    extrinsics = torch.cat((rotation, translation[:, None]), dim=1)
    intrinsics = torch.tensor([[100.0, 0, 2], [0, 200, 1.5], [0, 0, 1]], dtype=torch.float64)
    depth = torch.full((3, 4), 2.0, dtype=torch.float64)
    points = unproject_depth(depth, extrinsics, intrinsics)
    # pixel centre (u, v) = (2.5, 1.5): camera point ((2.5-2)/100*2, (1.5-1.5)/200*2, 2) = (0.01, 0, 2)
    # world = R^T (p - t) = R^T (-0.99, -2, -1) = (-2, 0.99, -1)
    torch.testing.assert_close(points[1, 2], torch.tensor([-2.0, 0.99, -1.0], dtype=torch.float64))
    assert points.shape == (3, 4, 3)


def test_unprojected_points_project_back_to_their_pixel_centres():
    cameras = random_cameras(3, seed=2)
    height, width = 241, 320
    depth = 1 + torch.rand(3, height, width, dtype=torch.float64)
    points = unproject_depth(depth, cameras.extrinsics, cameras.intrinsics)
    for view in range(3):
        pixels, z = Cameras(cameras.extrinsics[view : view + 1], cameras.intrinsics[view : view + 1], [(width, height)]).project(
            points[view].reshape(-1, 3)
        )
        torch.testing.assert_close(pixels[0], pixel_centers(height, width, torch.float64).reshape(-1, 2))
        torch.testing.assert_close(z[0], depth[view].reshape(-1))


def test_scene_scale_is_the_median_depth_and_scales_with_the_scene():
    depth = torch.tensor([[[[1.0, 2.0], [3.0, 100.0]]], [[[0.5, 0.5], [0.5, 0.5]]]])  # [B=2, V=1, 2, 2]
    torch.testing.assert_close(scene_scale(depth), torch.tensor([2.0, 0.5]))  # lower median of 4 values
    torch.testing.assert_close(scene_scale(depth * 7.0), scene_scale(depth) * 7.0)
    assert scene_scale(torch.zeros(1, 1, 2, 2)).item() > 0
    assert not scene_scale(depth.requires_grad_()).requires_grad
    assert math.isclose(float(scene_scale(torch.ones(1, 3, 4, 4))), 1.0)
