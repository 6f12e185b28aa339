"""Differentiable SSIM for losses: the evaluation's definition (11x11 Gaussian window, sigma 1.5,
K1 = 0.01, K2 = 0.03, population covariances, reflected borders cropped before averaging) in the
input's float dtype, so that training optimises what `eval.metrics.ssim` reports."""

from __future__ import annotations

import torch
import torch.nn.functional as F

SIGMA = 1.5
RADIUS = 5  # int(3.5 * sigma + 0.5): an 11 x 11 window
K1, K2 = 0.01, 0.03


def _kernel() -> list[float]:
    """The 11 normalised taps of the Gaussian window (computed in float64)."""
    positions = torch.arange(-RADIUS, RADIUS + 1, dtype=torch.float64)
    kernel = torch.exp(-(positions**2) / (2 * SIGMA**2))
    return (kernel / kernel.sum()).tolist()


_TAPS = _kernel()


def _blur(x: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian filter with reflected borders; x [N, C, H, W]. Each pass is a sum of
    the 11 shifted copies weighted by the taps, whose backward is as cheap as their forward: on
    the CPU torch's depthwise convolution was slower (SSIM and its gradient at 500x375, a
    refinement step's loss: 58-98 ms against 52-58 ms, measured in turns on an idle machine)."""
    height, width = x.shape[-2:]
    padded = F.pad(x, (RADIUS, RADIUS, 0, 0), mode="reflect")
    rows = sum(tap * padded[..., offset : offset + width] for offset, tap in enumerate(_TAPS))
    padded = F.pad(rows, (0, 0, RADIUS, RADIUS), mode="reflect")
    return sum(tap * padded[..., offset : offset + height, :] for offset, tap in enumerate(_TAPS))


def ssim_map_mean(images: torch.Tensor, references: torch.Tensor) -> torch.Tensor:
    """images, references [..., 3, H, W] in [0, 1] (H, W > 11) -> [...] mean SSIM, differentiable
    in both arguments. Float32 at least (bf16 variances cancel catastrophically)."""
    if images.shape != references.shape or images.dim() < 3:
        raise ValueError(f"SSIM needs two images [..., C, H, W] of one shape, got {tuple(images.shape)} and {tuple(references.shape)}")
    if min(images.shape[-2:]) <= 2 * RADIUS:
        raise ValueError(f"SSIM needs images larger than {2 * RADIUS + 1} pixels, got {tuple(images.shape[-2:])}")
    dtype = torch.promote_types(images.dtype, torch.float32)
    with torch.autocast(images.device.type, enabled=False):
        a = images.reshape(-1, *images.shape[-3:]).to(dtype)
        b = references.reshape(-1, *references.shape[-3:]).to(dtype)
        mean_a, mean_b = _blur(a), _blur(b)
        var_a = _blur(a * a) - mean_a**2
        var_b = _blur(b * b) - mean_b**2
        covariance = _blur(a * b) - mean_a * mean_b
        numerator = (2 * mean_a * mean_b + K1**2) * (2 * covariance + K2**2)
        denominator = (mean_a**2 + mean_b**2 + K1**2) * (var_a + var_b + K2**2)
        value = (numerator / denominator)[..., RADIUS:-RADIUS, RADIUS:-RADIUS].mean(dim=(1, 2, 3))
    return value.reshape(images.shape[:-3])
