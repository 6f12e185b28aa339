"""The sensor noise a restoration amplifies, measured and removed from a one-photo restore.

The operator lifts a dark photo by a gain of 10-30 in linear light, and its sensor noise with it:
a multi-view scene averages that noise over the views that see a point, a single photo has
nothing to average it with (LOL eval15's one-photo restores came out grainy: SSIM 0.610 against
the gamma curve's 0.637). So the noise is measured on the restoration itself, after the gain,
and removed in proportion to it: OpenCV's non-local means with its filter strength equal to the
measured standard deviation. A photo the operator barely lifts carries a noise level under one
8-bit step and is left untouched.

The level is Immerkaer's (1996) Laplacian-difference estimate on the luminance, taken as the
median absolute response so that edges and texture do not count as noise: for white noise of
standard deviation s the 3x3 mask's response has standard deviation 6 s, and the median of its
absolute value is 0.6745 times that.

Chosen on the development sources' one-photo restores (benchmarks/appearance_dev.py; the
model card's ablation): strength 1.0 x sigma for luminance and colour, OpenCV's 5x5 patches in an
11x11 search window (as good as 7x7 in 21x21 and 1.7x faster), a floor of one 8-bit step.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from lumos3d_cli.checks import require_finite
from lumos3d_cli.io.colour import luma

# Immerkaer's mask: a difference of Laplacians that cancels every smooth (quadratic) image.
_NOISE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
_MASK_NORM = 6.0  # sqrt of the sum of its squared taps
_MAD_TO_SIGMA = 1 / 0.6745  # median |x| of a zero-mean normal is 0.6745 sigma

STRENGTH = 1.0  # the filter strength h, in units of the measured noise level
MIN_NOISE_LEVEL = 1.0 / 255  # below one 8-bit step nothing is filtered
TEMPLATE_SIZE = 5  # px: the patches compared
SEARCH_SIZE = 11  # px: the window searched for similar patches


@dataclass(frozen=True)
class DenoisedPhoto:
    """image [3, H, W] sRGB in [0, 1]; noise_level: the measured standard deviation (sRGB, 0-1)
    of the restoration before filtering; filtered: whether it was above MIN_NOISE_LEVEL."""

    image: torch.Tensor
    noise_level: float
    filtered: bool

    def summary(self) -> dict:
        """summary.json's account of the one-photo denoising."""
        return {"noise_level": round(self.noise_level, 5), "filtered": self.filtered, "strength": STRENGTH}


def noise_level(image: torch.Tensor) -> float:
    """image [3, H, W] sRGB in [0, 1] (at least 3 px a side) -> the standard deviation of its
    pixel noise (sRGB units), from the luminance's Laplacian-difference response (module docstring)."""
    if image.dim() != 3 or image.shape[0] != 3 or min(image.shape[-2:]) < 3:
        raise ValueError(f"noise_level needs an image [3, H, W] of at least 3x3 pixels, got {tuple(image.shape)}")
    luminance = luma(image.detach().float().cpu())[0].numpy()  # the grey OpenCV's own Lab conversion starts from
    response = cv2.filter2D(luminance, -1, _NOISE_MASK)[1:-1, 1:-1]
    return float(np.median(np.abs(response))) * _MAD_TO_SIGMA / _MASK_NORM


def denoise_photo(image: torch.Tensor) -> DenoisedPhoto:
    """image [3, H, W] sRGB in [0, 1] (a restored photo) -> the image with its measured noise
    removed by non-local means (module docstring), same dtype and device; unchanged (the same
    tensor) when the noise is under MIN_NOISE_LEVEL. The filter works on 8-bit values, which is
    finer than any noise it is asked to remove."""
    require_finite("restored photo", image)
    level = noise_level(image)
    if level < MIN_NOISE_LEVEL:
        return DenoisedPhoto(image, level, False)
    pixels = (image.detach().float().cpu().clamp(0, 1).permute(1, 2, 0).numpy() * 255.0 + 0.5).astype(np.uint8)
    strength = STRENGTH * level * 255.0
    # OpenCV's coloured variant filters luminance (h) and colour (hColor) apart, in CIELAB, from BGR.
    filtered = cv2.fastNlMeansDenoisingColored(np.ascontiguousarray(pixels[..., ::-1]), None, strength, strength,
                                               TEMPLATE_SIZE, SEARCH_SIZE)[..., ::-1]
    result = torch.from_numpy(filtered.astype(np.float32) / 255.0).permute(2, 0, 1).contiguous()
    return DenoisedPhoto(result.to(dtype=image.dtype, device=image.device), level, True)
