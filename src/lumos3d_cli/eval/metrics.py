"""Image-quality metrics: PSNR on [0, 1]; SSIM with an 11x11 Gaussian window (sigma 1.5),
K1 = 0.01, K2 = 0.03, population covariances, reflected borders cropped before averaging (the
settings of scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)`, which the tests use as the oracle); LPIPS (losses/lpips.py)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

SSIM_SIGMA = 1.5
SSIM_RADIUS = 5  # int(3.5 * sigma + 0.5): an 11 x 11 window
SSIM_K1 = 0.01
SSIM_K2 = 0.03


def _flatten(images: torch.Tensor) -> torch.Tensor:
    if images.dim() < 3 or images.shape[-3] != 3:
        raise ValueError(f"expected images [..., 3, H, W], got {tuple(images.shape)}")
    return images.reshape(-1, *images.shape[-3:]).double()


def psnr(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] -> [...] PSNR in dB (inf for identical images)."""
    mse = ((_flatten(images) - _flatten(references)) ** 2).mean(dim=(1, 2, 3))
    return (10 * torch.log10(1.0 / mse)).reshape(images.shape[:-3])


def _gaussian_window() -> torch.Tensor:
    positions = torch.arange(-SSIM_RADIUS, SSIM_RADIUS + 1, dtype=torch.float64)
    kernel = torch.exp(-(positions**2) / (2 * SSIM_SIGMA**2))
    return kernel / kernel.sum()


def _blur(x: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter with reflected borders; x [N, C, H, W] float64."""
    kernel = _gaussian_window().to(x.device)
    channels = x.shape[1]
    x = F.pad(x, (SSIM_RADIUS, SSIM_RADIUS, 0, 0), mode="reflect")
    x = F.conv2d(x, kernel.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    x = F.pad(x, (0, 0, SSIM_RADIUS, SSIM_RADIUS), mode="reflect")
    return F.conv2d(x, kernel.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)


def ssim(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] (H, W > 11) -> [...] mean SSIM over channels and pixels."""
    a, b = _flatten(images), _flatten(references)
    if min(a.shape[-2:]) <= 2 * SSIM_RADIUS:
        raise ValueError(f"SSIM needs images larger than {2 * SSIM_RADIUS + 1} pixels, got {tuple(a.shape[-2:])}")
    c1, c2 = (SSIM_K1 * 1.0) ** 2, (SSIM_K2 * 1.0) ** 2
    mean_a, mean_b = _blur(a), _blur(b)
    var_a = _blur(a * a) - mean_a**2
    var_b = _blur(b * b) - mean_b**2
    covariance = _blur(a * b) - mean_a * mean_b
    numerator = (2 * mean_a * mean_b + c1) * (2 * covariance + c2)
    denominator = (mean_a**2 + mean_b**2 + c1) * (var_a + var_b + c2)
    r = SSIM_RADIUS
    value = (numerator / denominator)[..., r:-r, r:-r].mean(dim=(1, 2, 3))
    return value.reshape(images.shape[:-3])


def auto_gamma(images: torch.Tensor, target_mean: float = 0.45) -> torch.Tensor:
    """The blind no-learning baseline: per image, x^g with g = log(target) / log(mean(x)), so the
    mean of the sRGB values goes to about `target`. images [..., 3, H, W] in [0, 1]."""
    flat = _flatten(images)
    means = flat.mean(dim=(1, 2, 3)).clamp(1e-6, 1 - 1e-6)
    gammas = math.log(target_mean) / torch.log(means)
    corrected = flat.clamp_min(0.0) ** gammas[:, None, None, None]
    return corrected.clamp(0, 1).to(images.dtype).reshape(images.shape)
