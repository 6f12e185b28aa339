"""Pixel-Gaussian colours from restored full-resolution photos: each network pixel's colour is
the mean of the photo pixels it covers, so the Gaussians carry the photo's own colours, averaged
(and so denoised) over their footprint rather than resampled from a blurred network image."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def footprint_colours(restored: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """restored [V, 3, H, W] (full resolution, the whole photo) -> [V, 3, height, width]: the
    mean over each network pixel's footprint (exact box averages when H, W are multiples of
    height, width; otherwise the boxes of adaptive average pooling, which cover every photo pixel).

    For network images made by resizing the whole photo (`prepare_images(mode="resize")`); a
    centre crop needs the photo cropped the same way first. Enlarging (a photo smaller than the
    network grid) is bilinear.
    """
    if restored.shape[-2] < height or restored.shape[-1] < width:
        return F.interpolate(restored.float(), size=(height, width), mode="bilinear", align_corners=False)
    return F.adaptive_avg_pool2d(restored.float(), (height, width))
