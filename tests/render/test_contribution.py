"""Per-Gaussian rendered weights: the kernel's optional output against the pure-torch twin, and
the weights' own invariants."""

import pytest
import torch

from lumos3d_cli.io.cameras import Cameras
from lumos3d_cli.io.gaussians import SH_C0, Gaussians
from lumos3d_cli.render.contribution import rendered_weights
from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def _two_cameras(width: int, height: int) -> Cameras:
    first = camera_at_origin(width, height)
    shifted = first.extrinsics.clone()
    shifted[0, 0, 3] = 0.4  # a second view from 0.4 to the left
    return Cameras.concatenate([first, Cameras(shifted, first.intrinsics, first.sizes)])


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("antialiased", [False, True])
def test_kernel_weights_equal_the_twin(dtype, antialiased):
    gaussians = random_scene(80, 0, degree=1, dtype=dtype)
    gaussians.opacities[:4] = 0.0
    cameras = _two_cameras(37, 29)  # sizes that are not tile multiples
    ours = render(gaussians, cameras, weights=True, antialiased=antialiased)
    twin = render(gaussians, cameras, weights=True, antialiased=antialiased, backend="reference")
    tolerance = 1e-9 if dtype == torch.float64 else 1e-4
    torch.testing.assert_close(ours.weights, twin.weights, atol=tolerance, rtol=tolerance)
    assert ours.weights.shape == (2, 80) and ours.weights.dtype == dtype
    assert (ours.weights[:, :4] == 0).all()  # zero opacity: never drawn
    assert (ours.weights > 0).any(dim=0).sum() > 40


def test_weights_of_a_view_sum_to_its_alpha():
    gaussians = random_scene(60, 1, degree=0)
    output = render(gaussians, _two_cameras(40, 30), weights=True)
    # alpha = 1 - prod(1 - a_i) telescopes into the sum of a_i T_i
    torch.testing.assert_close(output.weights.sum(dim=1), output.alphas.sum(dim=(1, 2)), atol=1e-9, rtol=1e-9)


def test_asking_for_weights_changes_no_other_output():
    gaussians = random_scene(50, 2, degree=2, dtype=torch.float32)
    cameras = _two_cameras(33, 21)
    plain = render(gaussians, cameras)
    weighted = render(gaussians, cameras, weights=True)
    assert plain.weights is None
    for name in ("images", "alphas", "depths", "radii"):
        assert torch.equal(getattr(plain, name), getattr(weighted, name)), name


def test_a_hidden_gaussian_weighs_almost_nothing():
    gaussians = random_scene(2, 3, degree=0)
    gaussians.means[:] = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 5.0]], dtype=torch.float64)
    gaussians.scales[0] = 5.0  # a wall in front, opaque over the whole image
    gaussians.scales[1] = 0.05
    gaussians.opacities[:] = 1.0
    weights = render(gaussians, camera_at_origin(24, 18), weights=True).weights[0]
    assert weights[0] > 0.95 * 24 * 18 and 0 < weights[1] < 0.01 * weights[0]


def test_weights_are_the_gradient_of_the_image_sum_by_each_colour():
    """The identity gsplat's weights rely on (render/gsplat_backend.py): a pixel is
    sum_i c_i alpha_i T_i, so d(sum of the image)/d(c_i) is Gaussian i's weight. Checked with the
    CPU kernel's backward against its own forward weights: colours at 0.5 + C0 dc = 1 in every
    channel (no clamping), so each channel's gradient of dc is C0 x the weight."""
    gaussians = random_scene(60, 2, degree=0)
    gaussians.sh[:] = (1.0 - 0.5) / SH_C0
    camera = camera_at_origin(33, 25)
    expected = render(gaussians, camera, weights=True).weights[0]
    dc = gaussians.sh.clone().requires_grad_(True)
    image = render(Gaussians(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities, dc), camera).images
    (gradient,) = torch.autograd.grad(image.sum(), dc)
    torch.testing.assert_close(gradient[:, 0, :] / SH_C0, expected[:, None].expand(-1, 3), atol=1e-9, rtol=1e-7)


def test_rendered_weights_add_the_views_and_estimate_full_resolution_at_half():
    gaussians = random_scene(200, 4, degree=1, spread=0.5)
    gaussians.scales[:] = gaussians.scales.clamp_min(0.08)  # several pixels wide at half resolution too
    cameras = _two_cameras(64, 48)
    total = rendered_weights(gaussians, cameras)
    torch.testing.assert_close(total, render(gaussians, cameras, weights=True).weights.sum(dim=0))
    half = rendered_weights(gaussians, cameras, resolution=0.5)
    assert abs(half.sum() / total.sum() - 1) < 0.05  # the 2D dilation is a larger share of a coarser pixel
    big = total > 5
    assert ((half[big] / total[big]) - 1).abs().median() < 0.1
    with pytest.raises(ValueError, match="resolution"):
        rendered_weights(gaussians, cameras, resolution=0.0)
