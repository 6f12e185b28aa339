import torch

from lumos3d_cli.geometry.consistency import depth_consistency
from lumos3d_cli.geometry.depth_correction import MAX_LOG_CORRECTION, correct_depth, fit_log_correction

from synthetic_scene import plane_cameras, plane_depth, plane_points


def _warp(width: int, height: int, strength: float) -> torch.Tensor:
    """[h, w] a smooth multiplicative error: a tilt and a bow across the image."""
    x = torch.linspace(-1, 1, width, dtype=torch.float64)[None, :].expand(height, width)
    y = torch.linspace(-1, 1, height, dtype=torch.float64)[:, None].expand(height, width)
    return torch.exp(strength * (0.6 * x - 0.3 * y + 0.5 * x * x))


def test_a_smooth_depth_error_is_removed_by_the_points():
    cameras = plane_cameras(5)
    truth = plane_depth(cameras)
    width, height = cameras.sizes[0]
    warped = truth * _warp(width, height, 0.15)[None]
    points = plane_points(cameras, 400)
    result = correct_depth(warped, cameras, points)
    assert bool(result.corrected.all())
    before = ((warped - truth).abs() / truth).median()
    after = ((result.depth - truth).abs() / truth).median()
    assert before > 0.03 and after < 0.4 * before
    assert (result.residual_after < 0.3 * result.residual_before).all()
    assert depth_consistency(result.depth, cameras).share > depth_consistency(warped, cameras).share + 0.05


def test_outlier_points_do_not_pull_the_field_and_it_is_bounded():
    generator = torch.Generator().manual_seed(1)
    pixels = torch.rand(300, 2, generator=generator, dtype=torch.float64) * torch.tensor([64.0, 48.0], dtype=torch.float64)
    log_ratio = torch.full((300,), 0.05, dtype=torch.float64)
    log_ratio[:30] = 2.0  # wrong matches
    nodes = fit_log_correction(pixels, log_ratio, (64, 48))
    assert torch.allclose(nodes, torch.full_like(nodes, 0.05), atol=0.01)
    far = fit_log_correction(pixels, torch.full((300,), 3.0, dtype=torch.float64), (64, 48))
    assert torch.allclose(far, torch.full_like(far, MAX_LOG_CORRECTION))


def test_views_with_too_few_points_are_left_alone():
    cameras = plane_cameras(3)
    depth = plane_depth(cameras)
    points = plane_points(cameras, 5)
    result = correct_depth(depth * 1.1, cameras, points)
    assert not bool(result.corrected.any()) and torch.equal(result.depth, depth * 1.1)
