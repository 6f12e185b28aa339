"""The SH degree a scene keeps: 0 unless the higher bands lower the photometric loss."""

import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import Gaussians
from lumos3d_cli.refine.sh_degree import choose_sh_degree, degree_losses
from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def _scene(rest_scale: float) -> tuple[Gaussians, Cameras]:
    gaussians = random_scene(300, 4, degree=1, dtype=torch.float32)
    gaussians.sh[:, 1:] *= rest_scale
    shifted = camera_at_origin(32, 24)
    shifted.extrinsics[0, 0, 3] = 0.3
    return gaussians, Cameras.concatenate([camera_at_origin(32, 24), shifted])


def _targets(gaussians: Gaussians, cameras: Cameras, degree: int) -> torch.Tensor:
    with torch.no_grad():
        return torch.cat([render(gaussians, cameras[[v]], sh_degree=degree).images for v in range(len(cameras))])


def test_zero_bands_mean_degree_zero():
    gaussians, cameras = _scene(rest_scale=0.0)
    assert choose_sh_degree(gaussians, cameras, _targets(gaussians, cameras, 1), 0.2, 1e-3) == 0


def test_bands_that_explain_the_views_are_kept():
    gaussians, cameras = _scene(rest_scale=2.0)
    targets = _targets(gaussians, cameras, 1)
    losses = degree_losses(gaussians, cameras, targets, 0.2)
    assert losses[1] < 1e-6 < losses[0]
    assert choose_sh_degree(gaussians, cameras, targets, 0.2, 1e-3) == 1


def test_bands_that_do_not_lower_the_loss_are_dropped():
    gaussians, cameras = _scene(rest_scale=2.0)
    assert choose_sh_degree(gaussians, cameras, _targets(gaussians, cameras, 0), 0.2, 1e-3) == 0
