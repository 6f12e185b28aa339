import pytest
import torch

from lumos3d_cli.errors import InputError
from lumos3d_cli.geometry.consistency import depth_consistency

from synthetic_scene import plane_cameras, plane_depth


def test_exact_depth_is_consistent():
    cameras = plane_cameras(6)
    result = depth_consistency(plane_depth(cameras), cameras)
    assert result.share > 0.99
    assert (result.checked > 0.3).all()
    assert result.neighbour.tolist() != list(range(6))


def test_perturbed_depth_is_not():
    cameras = plane_cameras(6)
    depth = plane_depth(cameras)
    scaled = depth.clone()
    scaled[::2] *= 1.05  # every other view 5 % too far: beyond the 2 % tolerance
    assert depth_consistency(scaled, cameras).share < 0.05
    noisy = depth * (1 + 0.03 * torch.randn(depth.shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64))
    share = depth_consistency(noisy, cameras).share
    assert 0.2 < share < 0.8


def test_two_views_and_a_looser_tolerance():
    cameras = plane_cameras(2)
    depth = plane_depth(cameras) * torch.tensor([1.0, 1.03], dtype=torch.float64)[:, None, None]
    assert depth_consistency(depth, cameras).share < 0.05
    assert depth_consistency(depth, cameras, tolerance=0.05).share > 0.99
    assert depth_consistency(depth, cameras).neighbour.tolist() == [1, 0]


def test_bad_input_is_refused():
    cameras = plane_cameras(3)
    depth = plane_depth(cameras)
    with pytest.raises(InputError):
        depth_consistency(depth[:1], cameras[[0]])
    with pytest.raises(InputError):
        depth_consistency(depth[:2], cameras)
    depth[0, 0, 0] = 0.0
    with pytest.raises(InputError):
        depth_consistency(depth, cameras)
