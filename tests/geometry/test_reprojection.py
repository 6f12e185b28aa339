"""Where world points land in a view and what its map holds there (geometry/reprojection.py),
against a pinhole projection written out by hand and OpenCV's bilinear remap."""

import cv2
import numpy as np
import torch

from lumos3d_cli.geometry.confirmed_depth import neighbours_by_distance
from lumos3d_cli.geometry.reprojection import inside_view, land_in_view, sample_map
from lumos3d_cli.io.cameras import Cameras


def _camera(translation=(0.0, 0.0, 0.0)) -> Cameras:
    extrinsics = torch.cat([torch.eye(3, dtype=torch.float64), torch.tensor(translation, dtype=torch.float64)[:, None]], 1)
    intrinsics = torch.tensor([[100.0, 0, 32], [0, 90.0, 24], [0, 0, 1]], dtype=torch.float64)
    return Cameras(extrinsics[None], intrinsics[None], [(64, 48)], ["a"])


def test_points_land_where_the_pinhole_puts_them():
    world = torch.tensor([[0.1, -0.2, 2.0], [0.0, 0.0, 1.0], [1.0, 1.0, -1.0]], dtype=torch.float64)
    u, v, z = land_in_view(world, _camera((0.0, 0.0, 0.5)), 0)
    assert torch.allclose(z, torch.tensor([2.5, 1.5, -0.5], dtype=torch.float64))
    assert torch.allclose(u[:2], torch.tensor([100 * 0.1 / 2.5 + 32, 32], dtype=torch.float64))
    assert torch.allclose(v[:2], torch.tensor([90 * -0.2 / 2.5 + 24, 24], dtype=torch.float64))
    assert torch.isfinite(u).all() and torch.isfinite(v).all()  # behind the camera: finite, then masked
    assert inside_view(u, v, z, (48, 64)).tolist() == [True, True, False]


def test_inside_counts_the_edges_and_nothing_beyond():
    u = torch.tensor([0.0, 64.0, -1e-6, 64.000001, 10.0], dtype=torch.float64)
    v = torch.tensor([48.0, 0.0, 10.0, 10.0, 48.1], dtype=torch.float64)
    assert inside_view(u, v, None, (48, 64)).tolist() == [True, True, False, False, False]
    assert inside_view(u, v, torch.tensor([1.0, -1.0, 1.0, 1.0, 1.0]), (48, 64)).tolist() == [True, False, False, False, False]


def test_bilinear_samples_match_opencv_and_nearest_takes_the_pixel():
    values = torch.rand(48, 64, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    # fractions in 32nds, which OpenCV's fixed-point weights hold exactly
    u = torch.tensor([0.5, 10.25, 33.71875, 63.5, 20.0], dtype=torch.float64)
    v = torch.tensor([0.5, 7.75, 40.09375, 47.5, 30.90625], dtype=torch.float64)
    # OpenCV's remap puts pixel centres at integers: ours are at +0.5
    expected = cv2.remap(values.numpy(), (u - 0.5).numpy().astype(np.float32)[None], (v - 0.5).numpy().astype(np.float32)[None],
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    assert np.allclose(sample_map(values, u, v).numpy(), expected, atol=1e-6)
    nearest = sample_map(values, u, v, mode="nearest")
    assert torch.equal(nearest, values[v.long(), u.long()])


def test_equally_near_neighbours_come_in_index_order():
    centres = torch.tensor([[0.0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0]], dtype=torch.float64)
    extrinsics = torch.cat([torch.eye(3, dtype=torch.float64).expand(4, 3, 3), -centres[:, :, None]], 2)
    intrinsics = torch.eye(3, dtype=torch.float64).expand(4, 3, 3)
    cameras = Cameras(extrinsics, intrinsics, [(8, 8)] * 4, list("abcd"))
    assert neighbours_by_distance(cameras, 3)[0].tolist() == [1, 2, 3]
