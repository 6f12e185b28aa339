"""The optimiser's parameterisation: the Gaussians come back unchanged, degenerate values land
inside finite bounds, positions move freely, along rays or not at all."""

import math

import pytest
import torch

from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.parameters import (
    MAX_RELATIVE_SCALE,
    MIN_RELATIVE_SCALE,
    OPACITY_BOUND,
    GaussianParameters,
    scene_extent,
)

from factories import random_scene

CENTRES = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)


def _unit(gaussians: Gaussians) -> Gaussians:
    return Gaussians(gaussians.means, gaussians.quats / gaussians.quats.norm(dim=-1, keepdim=True), gaussians.scales,
                     gaussians.opacities, gaussians.sh)


@pytest.mark.parametrize("positions", ["free", "ray", "fixed"])
def test_the_gaussians_come_back_unchanged(positions):
    gaussians = _unit(random_scene(50, 0, degree=2))
    back = GaussianParameters(gaussians, positions, CENTRES, extent=3.0).gaussians()
    for name, tensor in gaussians.tensors().items():
        torch.testing.assert_close(getattr(back, name), tensor, msg=name)


def test_degenerate_values_are_bounded_and_finite():
    gaussians = random_scene(4, 1, degree=0)
    gaussians.opacities = torch.tensor([0.0, 1.0, 0.5, 0.5], dtype=torch.float64)
    gaussians.scales = torch.tensor([[1e-6] * 3, [1e3] * 3, [0.0] * 3, [0.1] * 3], dtype=torch.float64)
    gaussians.quats = torch.tensor([[0.0] * 4, [2.0, 0, 0, 0], [0, 1e-20, 0, 0], [0, 0, 3.0, 0]], dtype=torch.float64)
    parameters = GaussianParameters(gaussians, "free", CENTRES, extent=2.0)
    back = parameters.gaussians()
    back.require_finite()
    for leaf in (parameters.log_scales, parameters.opacity_logits, parameters.quats):
        assert torch.isfinite(leaf).all()
    assert back.scales[0].min() >= 2.0 * MIN_RELATIVE_SCALE * (1 - 1e-9)
    assert back.scales[1].max() <= 2.0 * MAX_RELATIVE_SCALE * (1 + 1e-9)
    assert OPACITY_BOUND * 0.99 <= back.opacities.min() and back.opacities.max() <= 1 - OPACITY_BOUND * 0.99
    torch.testing.assert_close(back.quats[:3], torch.tensor([[1.0, 0, 0, 0]] * 3, dtype=torch.float64))
    torch.testing.assert_close(back.quats[3], torch.tensor([0, 0, 1.0, 0], dtype=torch.float64))


def test_a_step_outside_the_bounds_is_pulled_back():
    parameters = GaussianParameters(random_scene(3, 2, degree=0), "free", CENTRES, extent=1.0)
    with torch.no_grad():
        parameters.log_scales.fill_(100.0)
        parameters.opacity_logits.fill_(-1e4)
        parameters.quats.zero_()
    parameters.normalise()
    back = parameters.gaussians()
    back.require_finite()
    assert back.scales.max() <= MAX_RELATIVE_SCALE * (1 + 1e-9) and back.opacities.min() > 0


def test_ray_positions_move_along_the_ray_from_the_nearest_camera():
    gaussians = random_scene(20, 3, degree=0)
    parameters = GaussianParameters(gaussians, "ray", CENTRES, extent=1.0)
    assert parameters.offsets.shape == (20, 1)
    with torch.no_grad():
        parameters.offsets.normal_()
    moved = parameters.means() - gaussians.means
    nearest = CENTRES[torch.cdist(gaussians.means, CENTRES).argmin(dim=1)]
    rays = gaussians.means - nearest
    torch.testing.assert_close(torch.linalg.cross(moved, rays, dim=-1), torch.zeros_like(moved), atol=1e-12, rtol=0)


def test_scene_extent_is_the_median_camera_distance():
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 4.0], [0.0, 0.0, 6.0]])
    assert scene_extent(means, torch.zeros(1, 3)) == pytest.approx(4.0)
    assert scene_extent(means[:0], torch.zeros(1, 3)) == 1.0
    assert math.isfinite(scene_extent(torch.zeros(5, 3), torch.zeros(1, 3)))
