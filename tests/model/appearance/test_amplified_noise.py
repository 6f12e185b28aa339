"""A one-photo restore's amplified noise (model/appearance/amplified_noise.py): the level measured
against the noise that was added, removal that brings
a noisy photo back towards the clean one in proportion to its noise, clean photos left untouched,
and the extremes (black, saturated, tiny, bf16, NaN)."""

import numpy as np
import pytest
import torch

from lumos3d_cli.errors import NonFiniteError
from lumos3d_cli.eval.metrics import psnr, ssim
from lumos3d_cli.model.appearance.amplified_noise import MIN_NOISE_LEVEL, denoise_photo, noise_level


def _scene(height=200, width=300, seed=0) -> torch.Tensor:
    """[3, H, W] a photo-like clean image: smooth shading, hard-edged coloured shapes, fine stripes."""
    generator = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    image = torch.stack([0.3 + 0.4 * x, 0.2 + 0.5 * y, 0.5 - 0.3 * x * y])
    for _ in range(12):
        top, left = int(torch.randint(0, height - 40, (1,), generator=generator)), int(torch.randint(0, width - 40, (1,), generator=generator))
        image[:, top : top + 35, left : left + 35] = torch.rand(3, 1, 1, generator=generator) * 0.8 + 0.1
    image[:, 150:190, 20:120] = 0.5 + 0.3 * torch.sign(torch.sin(x[150:190, 20:120] * 600))  # 3-px stripes
    return image


def _noisy(clean: torch.Tensor, sigma: float, seed=1) -> torch.Tensor:
    return (clean + sigma * torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed))).clamp(0, 1)


@pytest.mark.parametrize("sigma", [2 / 255, 6 / 255, 15 / 255])
def test_the_level_is_the_added_noise(sigma):
    noisy = _noisy(_scene(), sigma)
    level = noise_level(noisy)
    # grey noise on every channel: the luminance carries sigma * |(0.299, 0.587, 0.114)| of it
    expected = sigma * float(np.linalg.norm([0.299, 0.587, 0.114]))
    assert level == pytest.approx(expected, rel=0.15)


def test_a_clean_photo_is_untouched_and_edges_do_not_count_as_noise():
    clean = _scene()
    assert noise_level(clean) < MIN_NOISE_LEVEL
    result = denoise_photo(clean)
    assert result.image is clean and not result.filtered


@pytest.mark.parametrize("sigma", [6 / 255, 15 / 255])
def test_removal_brings_a_noisy_photo_back_towards_the_clean_one(sigma):
    clean = _scene()
    noisy = _noisy(clean, sigma)
    result = denoise_photo(noisy)
    assert result.filtered and result.image.shape == noisy.shape and result.image.dtype == noisy.dtype
    assert float(psnr(result.image, clean)) > float(psnr(noisy, clean)) + 3.0
    assert float(ssim(result.image, clean)) > float(ssim(noisy, clean)) + 0.1
    # the stripes (3 px) survive: detail is not what it removes
    stripes = result.image[:, 160:180, 30:110]
    assert float(stripes.std()) > 0.2
    assert result.summary()["noise_level"] == pytest.approx(noise_level(noisy), abs=1e-5)


def test_black_saturated_tiny_and_bf16_photos():
    for flat in (torch.zeros(3, 40, 50), torch.ones(3, 40, 50)):
        assert denoise_photo(flat).image is flat
    tiny = torch.rand(3, 3, 3)
    assert denoise_photo(tiny).image.shape == (3, 3, 3)
    noisy = _noisy(_scene(60, 80), 12 / 255).to(torch.bfloat16)
    result = denoise_photo(noisy)
    assert result.filtered and result.image.dtype == torch.bfloat16 and bool(torch.isfinite(result.image.float()).all())
    with pytest.raises(ValueError, match="at least 3x3"):
        noise_level(torch.rand(3, 2, 50))


def test_non_finite_pixels_are_refused():
    image = torch.rand(3, 20, 20)
    image[1, 4, 4] = float("nan")
    with pytest.raises(NonFiniteError, match="restored photo"):
        denoise_photo(image)
