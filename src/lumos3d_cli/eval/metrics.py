"""Image-quality metrics: PSNR on [0, 1]; SSIM with an 11x11 Gaussian window (sigma 1.5),
K1 = 0.01, K2 = 0.03, population covariances, reflected borders cropped before averaging (the
settings of scikit-image's `structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)`, which the tests use as the oracle); LPIPS (losses/lpips.py)."""

from __future__ import annotations

import math

import torch

from lumos3d_cli.losses.ssim import ssim_map_mean


def _flatten(images: torch.Tensor) -> torch.Tensor:
    if images.dim() < 3 or images.shape[-3] != 3:
        raise ValueError(f"expected images [..., 3, H, W], got {tuple(images.shape)}")
    return images.reshape(-1, *images.shape[-3:]).double()


def psnr(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] -> [...] PSNR in dB (inf for identical images)."""
    mse = ((_flatten(images) - _flatten(references)) ** 2).mean(dim=(1, 2, 3))
    return (10 * torch.log10(1.0 / mse)).reshape(images.shape[:-3])


def ssim(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """[..., 3, H, W] in [0, 1] (H, W > 11) -> [...] mean SSIM over channels and pixels, in float64
    (the training loss's definition, losses/ssim.py, so that training optimises what is reported)."""
    a, b = _flatten(images), _flatten(references)
    return ssim_map_mean(a, b).reshape(images.shape[:-3])


def auto_gamma(images: torch.Tensor, target_mean: float = 0.45) -> torch.Tensor:
    """The blind no-learning baseline: per image, x^g with g = log(target) / log(mean(x)), so the
    mean of the sRGB values goes to about `target`. images [..., 3, H, W] in [0, 1]."""
    flat = _flatten(images)
    means = flat.mean(dim=(1, 2, 3)).clamp(1e-6, 1 - 1e-6)
    gammas = math.log(target_mean) / torch.log(means)
    corrected = flat.clamp_min(0.0) ** gammas[:, None, None, None]
    return corrected.clamp(0, 1).to(images.dtype).reshape(images.shape)
