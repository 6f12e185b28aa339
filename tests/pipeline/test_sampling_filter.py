import math

import torch

from lumos3d_cli.io.cameras import Cameras, make_intrinsics
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.pipeline.sampling_filter import apply_sampling_filter
from lumos3d_cli.render.constants import EPS2D
from lumos3d_cli.render.render import render
from tests.factories import camera_at_origin


def _gaussians(means: torch.Tensor, scale: float, opacity: float = 0.9) -> Gaussians:
    n = means.shape[0]
    return Gaussians(means, torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1), torch.full((n, 3), scale),
                     torch.full((n,), opacity), torch.full((n, 1, 3), 1.0))


def test_the_finest_view_that_sees_a_gaussian_sets_its_filter():
    near = camera_at_origin(64, 48, focal=50.0)
    far_extrinsics = torch.eye(4, dtype=torch.float64)[:3].clone()
    far_extrinsics[2, 3] = 3.0  # the same axis, three units further back
    cameras = Cameras(torch.stack([near.extrinsics[0], far_extrinsics]),
                      torch.cat([near.intrinsics, make_intrinsics(50.0, 50.0, 32.0, 24.0).reshape(1, 3, 3)]), [(64, 48)] * 2)
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, -5.0], [100.0, 0.0, 2.0]])  # seen by both; behind both; outside
    filtered = apply_sampling_filter(_gaussians(means, 1e-3), cameras)
    expected = math.sqrt(1e-6 + EPS2D * (2.0 / 50.0) ** 2)  # the near camera: depth 2, focal 50
    torch.testing.assert_close(filtered.scales[0], torch.full((3,), expected))
    torch.testing.assert_close(filtered.scales[1:], torch.full((2, 3), 1e-3))
    assert torch.equal(filtered.opacities, torch.full((3,), 0.9)) and torch.equal(filtered.means, means)


def test_pixel_gaussians_cover_a_magnified_view():
    """One tiny Gaussian per pixel of a 32x24 grid, as the network predicts them, rendered at 3x:
    unfiltered they are dots on the background, filtered they cover the image as at 1x."""
    grid = camera_at_origin(32, 24, focal=30.0)
    v, u = torch.meshgrid(torch.arange(24) + 0.5, torch.arange(32) + 0.5, indexing="ij")
    depth = 2.0
    means = torch.stack([(u - 16) / 30.0 * depth, (v - 12) / 30.0 * depth, torch.full_like(u, depth)], -1).reshape(-1, 3)
    gaussians = _gaussians(means, 1e-4)
    magnified = camera_at_origin(96, 72, focal=90.0)
    filtered = apply_sampling_filter(gaussians, grid)
    coverage_grid = render(gaussians, grid).alphas.mean()
    coverage_raw = render(gaussians, magnified).alphas.mean()
    coverage_filtered = render(filtered, magnified).alphas.mean()
    assert coverage_grid > 0.9 and coverage_raw < 0.6
    assert coverage_filtered > 0.9
