"""Filling the pixels no Gaussian covers (render.hole_filling), against analytic images and a render."""

import numpy as np
import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.render.hole_filling import FILL_SIDE, OBSERVED_ALPHA, fill_unobserved, render_shown, splat_colours
from lumos3d_cli.render.render import render

from factories import camera_at_origin, random_scene


def _ramp(height: int, width: int) -> torch.Tensor:
    """[3, H, W] a smooth colour ramp: what inpainting should extrapolate almost exactly."""
    y, x = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    return torch.stack([0.2 + 0.6 * x, 0.3 + 0.4 * y, 0.5 + 0.2 * (x - y)])


def test_fully_covered_pixels_are_unchanged():
    image = torch.rand(3, 20, 30)
    filled = fill_unobserved(image, torch.ones(20, 30))
    torch.testing.assert_close(filled.image, image)
    assert filled.unobserved == 0


def test_partly_covered_pixels_take_their_splats_colour():
    colour = torch.tensor([0.8, 0.4, 0.1])[:, None, None].expand(3, 12, 16)
    alpha = torch.linspace(OBSERVED_ALPHA, 1, 16).expand(12, 16)
    filled = fill_unobserved(colour * alpha, alpha)  # composited over black: darker where alpha is lower
    torch.testing.assert_close(filled.image, colour.contiguous(), atol=1e-6, rtol=0)
    assert filled.unobserved == 0


@pytest.mark.parametrize("size", [(60, 80), (2 * FILL_SIDE, 3 * FILL_SIDE // 2)])
def test_a_hole_is_filled_with_what_surrounds_it(size):
    height, width = size
    truth = _ramp(height, width)
    alpha = torch.ones(height, width)
    hole = (slice(height // 3, height // 2), slice(width // 4, width // 2))
    alpha[hole] = 0
    rendered = truth * alpha
    filled = fill_unobserved(rendered, alpha)
    assert filled.unobserved == pytest.approx((alpha == 0).float().mean().item())
    error = (filled.image - truth)[:, hole[0], hole[1]].abs()
    assert error.mean() < 0.02 and error.max() < 0.08  # black would be off by 0.2-0.8
    observed = alpha > 0
    torch.testing.assert_close(filled.image[:, observed], truth[:, observed], atol=1e-6, rtol=0)


@pytest.mark.parametrize("size", [(3, 2000), (1, 40), (2000, 3), (40, 1)])
def test_a_thin_view_is_filled_with_what_surrounds_it_every_time(size):
    """A 3x2000 view shrinks to one row for the fill; OpenCV's inpainting of a one-row image read
    memory it never wrote: NaN in 42 to 3117 of its 18000 values, different on every run."""
    height, width = size
    truth = _ramp(height, width)
    alpha = torch.ones(height, width)
    if width > height:
        alpha[:, width // 4:] = 0
    else:
        alpha[height // 4:] = 0
    fills = [fill_unobserved(truth * alpha, alpha).image for _ in range(4)]
    for filled in fills:
        torch.testing.assert_close(filled, fills[0], atol=0, rtol=0)
    # the hole carries on the observed edge's colour (averaged across the thin side, which the
    # fill's reduced resolution does)
    if width > height:
        edge, hole = truth[:, :, width // 4 - 1].mean(dim=1), fills[0][:, :, width // 4:]
    else:
        edge, hole = truth[:, height // 4 - 1].mean(dim=1), fills[0][:, height // 4:]
    assert (hole - edge[:, None, None]).abs().max() < 0.05


def test_observed_detail_survives_the_reduced_fill_on_large_views():
    height, width = FILL_SIDE * 2, FILL_SIDE * 2
    checker = ((torch.arange(height)[:, None] + torch.arange(width)[None]) % 2).float().expand(3, -1, -1) * 0.5 + 0.25
    alpha = torch.ones(height, width)
    alpha[:40, :40] = 0
    filled = fill_unobserved(checker * alpha, alpha)
    torch.testing.assert_close(filled.image[:, 40:, 40:], checker[:, 40:, 40:])  # pixel-level detail kept
    assert (filled.image[:, :30, :30] - 0.5).abs().max() < 0.1  # the fill sees the checker's mean


def test_a_view_with_nothing_covered_stays_as_rendered():
    image = torch.zeros(3, 10, 10)
    filled = fill_unobserved(image, torch.zeros(10, 10))
    assert filled.unobserved == 1 and torch.equal(filled.image, image)


def test_saturated_and_bf16_views_stay_in_range():
    alpha = torch.ones(24, 32)
    alpha[:, :8] = 0
    image = torch.ones(3, 24, 32) * alpha
    filled = fill_unobserved(image.bfloat16(), alpha.bfloat16())
    assert filled.image.dtype == torch.bfloat16 and filled.image.shape == (3, 24, 32)
    assert torch.isfinite(filled.image.float()).all() and filled.image.float().min() > 0.99


def test_non_finite_renders_are_refused():
    image = torch.rand(3, 8, 8)
    image[0, 2, 2] = float("nan")
    with pytest.raises(NonFiniteError, match="rendered image"):
        fill_unobserved(image, torch.ones(8, 8))


def test_a_render_with_an_empty_half_is_filled_from_the_covered_half():
    gaussians = random_scene(200, 5, degree=0, dtype=torch.float32, spread=0.25)
    gaussians.means[:, 0] = gaussians.means[:, 0].abs() + 0.05  # only the right half of the view
    gaussians.scales[:] = 0.08
    gaussians.opacities[:] = 0.99
    camera = camera_at_origin(64, 48)
    output = render(gaussians, camera)
    alpha = output.alphas[0]
    assert (alpha[:, :16] < OBSERVED_ALPHA).all() and (alpha > 0.99).any()
    filled = fill_unobserved(output.images[0], alpha)
    covered = alpha > 0.99
    left = filled.image[:, :, :16]
    assert left.min() > 0.05  # no black left
    # the fill continues what borders it: each row's fill is near the row's first covered colour
    rows = covered.any(dim=1)
    first = covered.float().argmax(dim=1)
    edge = filled.image[:, rows, first[rows]]
    assert np.abs((left[:, rows, 0] - edge).numpy()).mean() < 0.15


def test_splat_colours_are_what_the_fill_shows_where_covered():
    """The differentiable colour refinement fits (refine.settings.splat_colours) equals the filled
    view wherever the alpha reaches OBSERVED_ALPHA, and its gradient reaches the alpha."""
    colour = torch.rand(3, 10, 12) * 0.8
    alpha = torch.linspace(0.1, 1, 12).expand(10, 12).clone()
    rendered = colour * alpha
    filled = fill_unobserved(rendered, alpha).image
    covered = alpha >= OBSERVED_ALPHA
    splats = splat_colours(rendered[None], alpha[None])[0]
    torch.testing.assert_close(splats[:, covered], filled[:, covered], atol=1e-6, rtol=0)
    torch.testing.assert_close(splats[:, covered], colour[:, covered], atol=1e-6, rtol=0)
    alpha_leaf = alpha.clone().double().requires_grad_(True)
    torch.autograd.gradcheck(lambda a: splat_colours(rendered.double(), a), (alpha_leaf,))


def test_render_shown_is_the_fill_of_the_render_or_the_render_over_its_background():
    gaussians, camera = random_scene(80, 3, degree=0, dtype=torch.float32), camera_at_origin(40, 30)
    output = render(gaussians, camera)
    filled = render_shown(gaussians, camera, fill=True)
    expected = fill_unobserved(output.images[0], output.alphas[0])
    torch.testing.assert_close(filled.image, expected.image)
    assert filled.unobserved == expected.unobserved
    plain = render_shown(gaussians, camera, fill=False, background=(0.2, 0.4, 0.6))
    torch.testing.assert_close(plain.image, render(gaussians, camera, background=(0.2, 0.4, 0.6)).images[0])
    assert plain.unobserved == float((output.alphas[0] < OBSERVED_ALPHA).float().mean())
