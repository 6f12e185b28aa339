"""Hand-made scenes written to .ply and rendered; pixel values checked against closed forms."""

import math

import pytest
import torch

from lumos3d_cli.io.gaussians import Gaussians, rgb_to_sh_dc
from lumos3d_cli.io.ply import read_ply, write_ply
from lumos3d_cli.render.constants import EPS2D, MAX_ALPHA
from lumos3d_cli.render.render import render

from factories import camera_at_origin

FOCAL = 40.0
SIZE = 31  # odd, so that the principal point (15.5, 15.5) is the centre of pixel (15, 15)


def _scene(tmp_path, means, scales, opacities, colours) -> Gaussians:
    n = len(means)
    gaussians = Gaussians(
        means=torch.tensor(means, dtype=torch.float32),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
        scales=torch.tensor(scales, dtype=torch.float32),
        opacities=torch.tensor(opacities, dtype=torch.float32),
        sh=rgb_to_sh_dc(torch.tensor(colours, dtype=torch.float32))[:, None, :],
    )
    write_ply(tmp_path / "scene.ply", gaussians)
    return read_ply(tmp_path / "scene.ply")


def test_single_gaussian_profile(tmp_path):
    z, s, opacity, colour = 4.0, 0.2, 0.7, [0.9, 0.3, 0.1]
    gaussians = _scene(tmp_path, [[0.0, 0.0, z]], [[s, s, s]], [opacity], [colour])
    background = torch.tensor([0.0, 0.0, 1.0])
    output = render(gaussians, camera_at_origin(SIZE, SIZE, FOCAL), background=background)
    variance = (FOCAL * s / z) ** 2 + EPS2D  # projected variance in pixels^2, plus the dilation
    for offset in (0, 1, 3, 5):
        alpha = opacity * math.exp(-0.5 * offset**2 / variance)
        if alpha < 1 / 255:
            alpha = 0.0
        expected = alpha * torch.tensor(colour) + (1 - alpha) * background
        torch.testing.assert_close(output.images[0, :, 15, 15 + offset], expected, atol=2e-6, rtol=0)
        torch.testing.assert_close(output.images[0, :, 15 - offset, 15], expected, atol=2e-6, rtol=0)
        assert output.alphas[0, 15, 15 + offset].item() == pytest.approx(alpha, abs=2e-6)
    assert output.depths[0, 15, 15].item() == pytest.approx(z, rel=1e-6)
    assert output.alphas[0, 0, 0].item() == 0.0 and output.depths[0, 0, 0].item() == 0.0
    torch.testing.assert_close(output.images[0, :, 0, 0], background)


def test_two_gaussians_composite_front_to_back(tmp_path):
    near, far = (0.2, 0.8, 0.2), (0.9, 0.1, 0.1)
    gaussians = _scene(
        tmp_path,
        [[0.0, 0.0, 6.0], [0.0, 0.0, 3.0]],  # the far one first: order in the file must not matter
        [[0.3] * 3, [0.1] * 3],
        [0.8, 0.6],
        [far, near],
    )
    output = render(gaussians, camera_at_origin(SIZE, SIZE, FOCAL), background=(1.0, 1.0, 1.0))
    weight_near = 0.6
    weight_far = (1 - 0.6) * 0.8
    expected = weight_near * torch.tensor(near) + weight_far * torch.tensor(far) + (1 - weight_near - weight_far)
    torch.testing.assert_close(output.images[0, :, 15, 15], expected, atol=2e-6, rtol=0)
    expected_depth = (weight_near * 3.0 + weight_far * 6.0) / (weight_near + weight_far)
    assert output.depths[0, 15, 15].item() == pytest.approx(expected_depth, rel=1e-6)


def test_opaque_gaussian_hides_what_is_behind(tmp_path):
    gaussians = _scene(
        tmp_path,
        [[0.0, 0.0, 2.0], [0.0, 0.0, 5.0], [0.0, 0.0, 8.0]],
        [[0.3] * 3] * 3,
        [1.0, 0.9, 0.95],
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    )
    output = render(gaussians, camera_at_origin(SIZE, SIZE, FOCAL))
    # alpha is capped at MAX_ALPHA; the second one (alpha 0.9) adds (1 - MAX_ALPHA) * 0.9 of green
    # and leaves T = 1e-3; the third would take T to 5e-5 <= 1e-4, so compositing stops before it.
    # (Not two Gaussians at MAX_ALPHA: their T = (1 - 0.99)^2 is the threshold exactly, and which
    # side of it a float lands on is rounding: float32 stops there, float64 does not.)
    expected = torch.tensor([MAX_ALPHA, (1 - MAX_ALPHA) * 0.9, 0.0])
    torch.testing.assert_close(output.images[0, :, 15, 15], expected, atol=2e-6, rtol=0)
    assert output.visible.all()


def test_view_dependent_colour_uses_the_camera_centre():
    """A degree-1 coefficient on the 'z' basis function changes colour with the view direction."""
    sh = torch.zeros(1, 4, 3)
    sh[0, 2, :] = 1.0  # Y_2 = C1 * z, z the unit direction from the camera to the Gaussian
    gaussians = Gaussians(torch.tensor([[0.0, 0.0, 4.0]]), torch.tensor([[1.0, 0, 0, 0]]), torch.full((1, 3), 0.2), torch.tensor([0.5]), sh)
    output = render(gaussians, camera_at_origin(SIZE, SIZE, FOCAL))
    expected = 0.5 * (0.5 + 0.4886025119029199)
    assert output.images[0, 0, 15, 15].item() == pytest.approx(expected, rel=1e-5)
